"""What the SITL tests cannot hold, stated once: ArduPilot's SITL is not in lockstep with the companion.

ArduPilot SITL runs its own scheduler at ``--speedup`` (20× in these tests), and its JSON backend is
lockstepped to our physics, not to the companion: the companion's latency, in vehicle time, is its
wall-clock latency times 20, and on a busy machine the closed loop it flies is another loop. Measured
on 2 cores beside two CPU-bound processes (``bench/bench_suite_under_load.py tests/test_ardupilot_*.py
tests/test_ardusub_sitl.py``): 3–8 of 16 SITL tests failed — a step error 25.9 s against 20.3 s, a
speed step overshooting 51 %, a steady-state speed off by 1.1 m/s — where none fails on the idle
machine, and where one SITL test at a time beside the same load (``-n 0``) still passed 11 of 11.

So on a busy machine (load average above 2 per core when the tests are collected: the suite itself with one SITL keeps it near 1.5) these tests are
expected to fail (``xfail``, not strict: a pass still counts as one), with this reason. The tests run
one at a time on one worker (``xdist_group("sitl")``) either way. PX4 SITL free-runs the same way
(``lockstep`` off); not measured here.
"""
from __future__ import annotations

import os

import pytest

#: load average per core above which the SITL tests' closed loops are not the vehicle's (module docstring)
BUSY_LOAD_PER_CORE = 2.0


def machine_busy() -> bool:
    try:
        return os.getloadavg()[0] / (os.cpu_count() or 1) > BUSY_LOAD_PER_CORE
    except OSError:  # no load average on this platform: assume idle
        return False


#: the mark every SITL test module carries (beside its skip without a SITL binary)
SITL_UNDER_LOAD = pytest.mark.xfail(
    machine_busy(), strict=False,
    reason="SITL is not in lockstep with the companion: on a busy machine its closed loop is another "
           "(beside two CPU-bound processes 3-8 of 16 SITL tests failed, none idle; tests/sitl_limits.py)")
