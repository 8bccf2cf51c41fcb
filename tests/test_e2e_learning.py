"""End to end: ``companion run --learn`` beside our simulator over MAVLink (lockstep), while a
separate ground station flies an ordinary survey of heading set-points on a vehicle with poor gains.
Nothing is asked of the vehicle but the gains: they are written on a straight, verified by the
survey's own course changes, announced by STATUSTEXT and kept in the store."""
from __future__ import annotations

import subprocess
import sys

import pytest

from companion.records.store import Store
from harness.missions import SurveyPlan
from harness.survey_gcs import SurveyGroundStation

pytestmark = pytest.mark.e2e

PLAN = SurveyPlan(thrusts=(0.7,), seconds_per_thrust=1e9, course_changes_deg=(30.0, -45.0, 20.0, -30.0, 40.0, -15.0))
POOR = {"HDG_P": 0.4, "HDG_I": 0.02}


def test_run_learn_tunes_a_vehicle_flying_its_own_survey(sim_factory, tmp_path):
    sim = sim_factory(transport="tcp", speedup=50, seed=3, lockstep=True)
    station = SurveyGroundStation(sim.endpoint, PLAN, parameters=POOR)
    station.start()
    try:
        store_path = tmp_path / "store.sqlite"
        run = subprocess.run([sys.executable, "-m", "companion", "run", "--connect", sim.endpoint, "--lockstep",
                              "--learn", "--no-health", "--store", str(store_path), "--max-vehicle-time", "260"],
                             capture_output=True, text=True, timeout=300)
    finally:
        station.stop()
    assert run.returncode == 0, run.stderr[-2000:]
    with Store(store_path) as store:
        (campaign,) = [c for c in store.campaigns() if c["kind"] == "learning"]
        (result,) = store.behavior_results(campaign["id"], "learning")
    learned = result["result"]
    assert campaign["status"] == "completed" and learned["phase"] == "kept", campaign["reason"]
    design = [w for w in learned["writes"] if w["why"] == "design"]
    assert design and design[0]["time_s"] < 150.0  # written after the first validated band, on a straight
    verdict = learned["verdict"]
    assert verdict["after_error"] < 0.8 * verdict["before_error"]
    assert learned["mode_left_s"] < 2.0  # only the first second, before the ground station chose its mode
    assert len(station.sent) >= 8  # the survey was flown throughout (a course change every 30 s)
