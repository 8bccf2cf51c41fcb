"""Test and bench plumbing shared by ``tests/`` and ``bench/``, importable without pytest.

* :mod:`harness.inprocess` — the simulator's physics and autopilot in-process, driven by companion
  commands (``InProcessLink``, ``ClosedLoop``, ``HuginLoop``; one command dispatch).
* :mod:`harness.simulator` — ``start_sim``: the simulator as a child process on loopback through
  the companion's one launcher (:class:`companion.rehearsal.launcher.SimulatorProcess`), with the tests'
  defaults.
* :mod:`harness.mavlink_clients` — pymavlink clients of that simulator (``connect_client``).
* :mod:`harness.fault_proxy` — a MAVLink-aware TCP proxy that injects link faults (drop, delay,
  duplicate, reorder, corrupt, cut) between the companion and the vehicle, at phases recognised
  from the companion's traffic; :mod:`harness.fault_cases` runs a procedure through it and checks
  that the vehicle and the store come back as found (``tests/test_fault_injection.py``,
  ``bench/bench_faults.py``).
* :mod:`harness.datasets` — synthetic data sets (ROMEO regime points and surge, steady-state
  squares and turns).

Like the tests, the harness may import both ``sim`` and ``companion``; neither of them imports the
harness.
"""
