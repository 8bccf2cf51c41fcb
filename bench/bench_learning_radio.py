"""Tuning during an ordinary survey over a telemetry radio that loses bytes: ``companion run --learn``
through a 57600-baud serial link (``harness/serial_bridge.py``) while a ground station of its own flies
the survey directly.

Each case: a ``--lockstep`` simulator (STARFISH, TCP) whose heading gains are made poor (HDG_P 0.4,
HDG_I 0.02); a ground station (``harness.survey_gcs.SurveyGroundStation``) flying heading set-points, a
course change every 30 s at thrust 0.7; ``companion run --connect /dev/pts/N,57600 --lockstep --learn``
through a pseudo-terminal pair bridged to the simulator by a radio model each way (5760 B/s, a
2048-byte buffer that drops what does not fit, ``--loss`` of the bytes lost on the air in runs of
``--burst`` bytes on average, seeded). Printed per case: the session's outcome and phase, when the
design was written and verified, the course changes' step error after against before, what the radio
lost, and the frames the companion counted lost. ``--loss 0`` is the clean radio.

    python bench/bench_learning_radio.py [--loss 0.02] [--burst 32] [--seeds 1,2,3]
"""
from __future__ import annotations

import argparse
import logging
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from companion.records.store import Store
from harness.fault_schedule import TO_COMPANION
from harness.missions import SurveyPlan
from harness.serial_bridge import RadioConditions, SerialBridge, add_radio_arguments, radio_from
from harness.simulator import start_sim
from harness.survey_gcs import SurveyGroundStation

log = logging.getLogger("bench_learning_radio")

PLAN = SurveyPlan(thrusts=(0.7,), seconds_per_thrust=1e9, course_changes_deg=(30.0, -45.0, 20.0, -30.0, 40.0, -15.0))
POOR = {"HDG_P": 0.4, "HDG_I": 0.02}
MAX_VEHICLE_S = 300.0


def run_case(folder: Path, conditions: RadioConditions, seed: int) -> dict:
    """One survey with learning over the radio (module docstring); what the store and the radio say."""
    sim = start_sim(transport="tcp", speedup=0, seed=3, lockstep=True)
    station = SurveyGroundStation(sim.endpoint, PLAN, parameters=POOR)
    try:
        station.start()
        store_path = folder / f"store-{seed}.sqlite"
        with SerialBridge(sim.port, conditions=conditions, seed=seed) as bridge:
            started = time.monotonic()
            done = subprocess.run([sys.executable, "-m", "companion", "run", "--connect", bridge.endpoint, "--lockstep",
                                   "--learn", "--no-health", "--store", str(store_path),
                                   "--max-vehicle-time", f"{MAX_VEHICLE_S:g}"],
                                  capture_output=True, text=True, timeout=900, stdin=subprocess.DEVNULL)
            wall = time.monotonic() - started
            radio = bridge.stats()
    finally:
        station.stop()
        sim.stop()
    row: dict = {"seed": seed, "exit": done.returncode, "wall_s": wall, "radio": radio,
                 "stderr": done.stderr[-600:] if done.returncode else ""}
    with Store(store_path, read_only=True) as store:
        sessions = [c for c in store.campaigns() if c["kind"] == "learning"]
        if not sessions:
            return {**row, "status": "no session", "reason": done.stderr[-300:]}
        campaign = sessions[-1]
        results = store.behavior_results(campaign["id"], "learning")
    learned = results[-1]["result"] if results else {}
    design = [w for w in learned.get("writes", []) if w.get("why") == "design"]
    verdict = learned.get("verdict") or {}
    return {**row, "status": campaign["status"], "reason": campaign.get("reason"), "phase": learned.get("phase"),
            "written_s": design[0]["time_s"] if design else None, "verdict_s": learned.get("verdict_at_s"),
            "after": verdict.get("after_error"), "before": verdict.get("before_error")}


def _fmt(value, spec: str = ".1f") -> str:
    return format(value, spec) if isinstance(value, (int, float)) else "-"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_radio_arguments(parser)
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING, format="%(message)s", stream=sys.stdout)
    log.setLevel(logging.INFO)
    conditions, seeds = radio_from(args)
    log.info("radio each way: %s; survey: a course change every 30 s at thrust 0.7, gains %s", conditions.describe(),
             POOR)
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        for seed in seeds:
            row = run_case(Path(folder), conditions, seed)
            rows.append(row)
            radio = row["radio"].get(TO_COMPANION, {})
            log.info("seed %d: %s%s, phase %s; written at %s s, verdict at %s s; step error after %s / before %s s; "
                     "radio to the companion: %s frames hit of %s; wall %.0f s%s", seed, row["status"],
                     f" ({row['reason']})" if row.get("reason") else "", row.get("phase"),
                     _fmt(row.get("written_s"), ".0f"), _fmt(row.get("verdict_s"), ".0f"), _fmt(row.get("after"), ".2f"),
                     _fmt(row.get("before"), ".2f"), radio.get("frames_hit", "-"), radio.get("frames_in", "-"),
                     row["wall_s"], f"; exit {row['exit']}: {row['stderr']}" if row["exit"] else "")
    kept = [r for r in rows if r.get("phase") == "kept"]
    log.info("%d of %d kept verified gains", len(kept), len(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
