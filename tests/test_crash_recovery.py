"""A companion killed in the middle of a campaign (``kill -9``: no handler runs) leaves a trail in its
store; the next start finds it, says what is still changed, and puts the vehicle back — the
override it held released (with the vehicle's override timeout off it would never expire), the
trial gains and thrust restored — and closes the campaign ``interrupted`` (harness/crash_cases.py)."""
from __future__ import annotations

import sys

import pytest

from harness.crash_cases import run_crash_case

pytestmark = [pytest.mark.e2e, pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")]


def _in_doublet(changes, found) -> bool:
    """The RC channel is recorded as held just before the override goes out."""
    return any(kind == "ChannelHeld" for kind, _ in changes)


def _trial_gains(changes, found) -> bool:
    """A write is recorded before it is sent and the next only once it was echoed: the trial gain is
    surely on the vehicle once the change after its write was recorded."""
    trial = [i for i, (kind, detail) in enumerate(changes)
             if kind == "ParamWrite" and detail["name"] == "HDG_P" and abs(detail["value"] - found["params"]["HDG_P"]) > 1e-6]
    return bool(trial) and len(changes) > trial[0] + 1


@pytest.mark.slow
@pytest.mark.parametrize("kill_point, until", [("doublet", _in_doublet), ("trial gains", _trial_gains)])
def test_a_killed_companion_leaves_a_trail_the_next_start_follows(sim_factory, tmp_path, kill_point, until):
    sim = sim_factory(transport="tcp", speedup=0, seed=4, lockstep=True)  # vehicle time as each companion reads it
    result = run_crash_case(sim, tmp_path / "store.sqlite", kill_point, until)
    assert result.killed, result.problems
    if kill_point == "doublet":
        assert result.damaged["rudder"] > 0.2  # the doublet's override is still held
    else:
        assert result.damaged["params"] != {}  # read back
        assert result.damaged["params"]["HDG_P"] != result.after["params"]["HDG_P"]  # trial gains were left on it
    assert result.refused  # the next start says so and does not fly a changed vehicle
    assert result.recovery["recovered"] == result.recovery["interrupted"] == [1] and result.recovery["left"] == []
    assert result.problems == []
