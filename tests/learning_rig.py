"""What the SITL tests of ``companion run --learn`` share: the companion run beside a ground station
flying a survey, and the learning session's record in the store."""
from __future__ import annotations

import sys
from pathlib import Path

from companion.records.store import Store
from harness.rover_mission import MissionGroundStation, SurveyRun, fly_survey_beside

SPEEDUP = 10.0


def learn_beside(endpoint: str, station: MissionGroundStation, store_path: Path,
                 max_vehicle_s: float = 1500.0) -> SurveyRun:
    """``companion run --learn`` on ``endpoint`` while ``station`` flies its survey (at most 3000
    vehicle seconds of wall time at :data:`SPEEDUP`)."""
    return fly_survey_beside([sys.executable, "-m", "companion", "run", "--connect", endpoint, "--learn",
                              "--no-health", "--store", str(store_path), "--max-vehicle-time", f"{max_vehicle_s:g}"],
                             station, 3000.0 / SPEEDUP)


def learning_record(store_path: Path) -> tuple[dict, dict, list[dict]]:
    """The session's campaign row, its result and its events, from the store."""
    with Store(store_path) as store:
        (campaign,) = [c for c in store.campaigns() if c["kind"] == "learning"]
        (result,) = store.behavior_results(campaign["id"], "learning")
        events = [e["result"] for e in store.behavior_results(campaign["id"], "learning_event")]
    return campaign, result["result"], events
