"""Test and bench plumbing shared by ``tests/`` and ``bench/``, importable without pytest.

* :mod:`harness.inprocess` — the simulator's physics and autopilot in-process, driven by companion
  commands (``InProcessLink``, ``ClosedLoop``, ``HuginLoop``; one command dispatch).
* :mod:`harness.simulator` — ``start_sim``: the simulator as a child process on loopback through
  the companion's one launcher (:class:`companion.rehearsal.launcher.SimulatorProcess`), with the tests'
  defaults.
* :mod:`harness.mavlink_clients` — pymavlink clients of that simulator (``connect_client``).
* :mod:`harness.fault_proxy` — a MAVLink-aware TCP proxy that injects link faults (drop, delay,
  duplicate, reorder, corrupt, cut) between the companion and the vehicle, at phases recognised
  from the companion's traffic, with an optional byte-rate cap; :mod:`harness.udp_relay` — the same
  faults over UDP plus seeded link conditions (loss, delay, jitter, reordering, duplication, a
  byte-rate cap); both built from :mod:`harness.mavlink_frames` (frames in a stream or a datagram),
  :mod:`harness.fault_schedule` (triggers and faults), :mod:`harness.link_conditions` and
  :mod:`harness.delivery_log` (what the vehicle was last told). :mod:`harness.fault_cases` runs a
  procedure through either and checks that the vehicle and the store come back as found
  (``tests/test_fault_injection.py``, ``bench/bench_faults.py``).
* :mod:`harness.serial_bridge` — a serial link: a pseudo-terminal pair at 57600 baud (the companion
  connects ``/dev/pts/N,57600``) bridged to the simulator's TCP port through a telemetry radio model
  each way (byte rate, a buffer that drops what does not fit, bytes lost on the air in runs), counting
  what it dropped; :mod:`harness.serial_campaign` runs ``companion identify`` over it and checks the
  vehicle afterwards (``tests/test_serial_link.py``, ``bench/bench_serial_link.py``).
* :mod:`harness.datasets` — synthetic data sets (ROMEO regime points and surge, steady-state
  squares and turns).

Like the tests, the harness may import both ``sim`` and ``companion``; neither of them imports the
harness.
"""
