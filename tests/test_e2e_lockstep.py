"""SPEC C2: "Results must not depend on N (within noise)". A closed loop through MAVLink (the roll
stabilisation moving the rolling mass with DO_SET_SERVO) at 20x and at 100x with the simulator in
lockstep: without it, the companion's wall-clock latency scales with N (bench/bench_lockstep.py
shows the roll loop becoming worse than open loop at 100x)."""
from __future__ import annotations

import pytest

from companion.procedures.app import AbortFlag
from companion.procedures.roll import RollProcedureConfig, roll_procedure
from companion.link.vehicle import VehicleLink
from companion.rehearsal.launcher import SimulatorProcess

pytestmark = pytest.mark.e2e

CONFIG = RollProcedureConfig(settle_s=5.0, open_s=30.0, closed_s=40.0, kick_deg=0.0)


def roll_std(speedup: float) -> tuple[float, float]:
    with SimulatorProcess(speedup=speedup, seed=3, lockstep=True) as sim:
        link = VehicleLink.connect(sim.endpoint, lockstep=True)
        try:
            link.arm(True)
            result = roll_procedure(link, AbortFlag(), CONFIG, simulator=True).to_json()
        finally:
            link.close()
    assert result["status"] == "completed"
    return result["std_open_deg"], result["std_closed_deg"]


@pytest.mark.slow
def test_closed_loop_result_does_not_depend_on_the_speedup():
    open_slow, closed_slow = roll_std(20.0)
    open_fast, closed_fast = roll_std(100.0)
    assert closed_slow < open_slow / 2.5 and closed_fast < open_fast / 2.5
    assert closed_fast == pytest.approx(closed_slow, rel=0.15)
    assert open_fast == pytest.approx(open_slow, rel=0.15)
