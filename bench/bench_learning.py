"""Tuning during an ordinary survey (``companion run --learn``) on the simulator, in-process and in
lockstep: when verified gains are in force, and how the survey's later legs compare with the same
legs flown on the poor gains alone.

Per preset and seed, two runs of the same survey (a course change every 30 s, taken in turn from
30, −45, 20, −30, 40, −15°, at thrust 0.7, by the autopilot's own heading hold), with the heading
gains scaled down to ``--gain-scale`` of the preset's:

* **baseline**: :class:`companion.procedures.resident.Companion` without learning (it only watches);
* **learning**: the same loop with ``learn=True``.

Figures: vehicle time of the design's write and of the verdict, the verdict, reverts; over the legs
after the verdict (the same vehicle-time interval in both runs): the heading error RMS (deg) and the
course changes' mean normalised step error (IAE/|Δψ|, s) and worst overshoot. The survey is timed by
vehicle seconds, so the mission's length is the same by construction; nothing but gains is asked of
the vehicle (``mode_changes`` is printed: it must be 0). Never pass/fail.

    python bench/bench_learning.py --presets starfish,boat-3dof --seeds 3
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from companion.interface import SetHeading, SetThrust  # noqa: E402
from companion.numerics.angles import wrap_pi  # noqa: E402
from companion.numerics.mission_turns import TurnRecorder  # noqa: E402
from companion.procedures.app import AbortFlag  # noqa: E402
from companion.procedures.resident import Companion, ServeConfig  # noqa: E402
from companion.records.store import Store  # noqa: E402
from harness.inprocess import InProcessLink  # noqa: E402
from harness.missions import SurveyPlan  # noqa: E402

PLAN = SurveyPlan(thrusts=(0.7,), seconds_per_thrust=1e9, course_changes_deg=(30.0, -45.0, 20.0, -30.0, 40.0, -15.0))


def fly(preset: str, seed: int, gain_scale: float, learn: bool, seconds: float) -> dict:
    link = InProcessLink(preset=preset, seed=seed)
    for name in ("HDG_P", "HDG_I"):
        link.simulated.set_param(name, gain_scale * link.simulated.params[name])
    read = link.next_telemetry
    samples: list[tuple[float, float, float, float]] = []
    last: list = []

    def mission(timeout_s: float = 5.0):
        telemetry = read(timeout_s)
        setpoint = PLAN.setpoints(telemetry.time_s)
        if setpoint not in last:
            link.execute([SetThrust(setpoint[0]), SetHeading(setpoint[1])])
            last[:] = [setpoint]
        samples.append((telemetry.time_s, telemetry.yaw, telemetry.heading_target, telemetry.speed_water))
        return telemetry

    link.next_telemetry = mission
    with tempfile.TemporaryDirectory() as folder, Store(Path(folder) / "store.sqlite") as store:
        config = ServeConfig(max_vehicle_s=seconds, health=False, learn=learn, schedule_gains=False)
        companion = Companion(link, store, store.add_vehicle("v"), config, AbortFlag())
        companion.run()
        result = companion.learning.result if learn and companion.learning is not None else None
    return {"samples": np.asarray(samples), "result": result, "mode_changes": len(link.mode_changes)}


def legs_after(samples: np.ndarray, start_s: float) -> dict:
    """Heading error RMS and the course changes' figures from ``start_s`` on."""
    t, yaw, target, speed = samples.T
    later = t >= start_s
    error = np.degrees([wrap_pi(a - b) for a, b in zip(target[later], yaw[later])])
    recorder = TurnRecorder()
    turns = []
    for row in samples[later]:
        turn = recorder.add(*row)
        if turn is not None:
            turns.append(turn.figures())
    return {"heading_rms_deg": float(np.sqrt(np.mean(error ** 2))) if error.size else math.nan,
            "turn_iae_s": float(np.mean([f.iae_s for f in turns])) if turns else math.nan,
            "turn_overshoot_pct": float(max(f.overshoot_pct for f in turns)) if turns else math.nan,
            "turns": len(turns)}


def one(preset: str, seed: int, gain_scale: float, seconds: float) -> dict:
    wall = time.perf_counter()
    learned = fly(preset, seed, gain_scale, True, seconds)
    baseline = fly(preset, seed, gain_scale, False, seconds)
    result = learned["result"]
    design = next((w.time_s for w in result.writes if w.why == "design"), math.nan)
    verdict_s = math.nan
    if result.verdict is not None:
        judged = sorted(t.t_start for t in result.turns if t.gains == "learned")[:3]
        verdict_s = judged[-1] + 25.0 if len(judged) == 3 else math.nan
    start = verdict_s if math.isfinite(verdict_s) else seconds
    return {"preset": preset, "seed": seed, "phase": result.phase.value, "reason": result.reason,
            "design_write_s": design, "verified_s": verdict_s,
            "reverts": sum(1 for w in result.writes if w.why == "revert"),
            "learned": legs_after(learned["samples"], start), "baseline": legs_after(baseline["samples"], start),
            "mode_changes": learned["mode_changes"], "wall_s": time.perf_counter() - wall}


def _clean(value):
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    return value


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--presets", default="starfish,boat-3dof")
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--gain-scale", type=float, default=0.6, help="the poor gains: this fraction of the preset's")
    parser.add_argument("--seconds", type=float, default=600.0, help="vehicle seconds of survey per run")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    rows = [one(preset, seed, args.gain_scale, args.seconds)
            for preset in args.presets.split(",") for seed in range(1, args.seeds + 1)]
    if args.json:
        print(json.dumps([_clean(r) for r in rows], indent=1, allow_nan=False))
        return 0
    print(f"{'preset':10} {'seed':>4} {'outcome':9} {'write s':>7} {'verified s':>10} {'rev':>3} "
          f"{'hdg RMS learned/base':>21} {'turn IAE learned/base':>22} {'overshoot l/b %':>16} {'modes':>5}")
    for r in rows:
        lrn, base = r["learned"], r["baseline"]
        print(f"{r['preset']:10} {r['seed']:4d} {r['phase']:9} {r['design_write_s']:7.1f} {r['verified_s']:10.1f} "
              f"{r['reverts']:3d} {lrn['heading_rms_deg']:9.2f}/{base['heading_rms_deg']:<6.2f} ({lrn['heading_rms_deg'] / base['heading_rms_deg']:.2f}) "
              f"{lrn['turn_iae_s']:9.2f}/{base['turn_iae_s']:<6.2f} ({lrn['turn_iae_s'] / base['turn_iae_s']:.2f}) "
              f"{lrn['turn_overshoot_pct']:6.1f}/{base['turn_overshoot_pct']:<6.1f}   {r['mode_changes']:5d}")
        if r["phase"] != "kept":
            print(f"{'':15} reason: {r['reason']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
