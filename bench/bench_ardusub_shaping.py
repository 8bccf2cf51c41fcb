"""ArduSub's flown heading steps against their prediction with and without the set-point shaping (eq. A.2s).

Reads the runs kept by ``bench/bench_ardupilot.py --autopilot ardusub --physics nomoto --keep DIR``
(each ``DIR/run-N`` holds the campaign's store, with every flown verification step's record, and its
summary, with the limits the campaign predicted with) and predicts each flown step again on the
accepted model of its speed, with the gains it was flown with:

* with AC_AttitudeControl's input shaping and target-rate feed-forward (eq. A.2s, what the campaign
  uses), and
* without them (eq. A.2 alone, what the campaign used before),

printing the step error (IAE, s) and overshoot of each against the flight. Usage::

    python bench/bench_ardupilot.py --autopilot ardusub --physics nomoto --repeats 5 --keep /tmp/sub
    python bench/bench_ardusub_shaping.py /tmp/sub
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sqlite3
import sys
from pathlib import Path

from companion.numerics.identification import YawModel
from companion.procedures.verified_design import CONTROLLERS, HeadingLimits, predicted_step


def _limits(summary: dict) -> HeadingLimits:
    stored = (summary.get("verified") or {}).get("limits")
    if not stored:
        raise SystemExit("this run's summary holds no prediction limits (kept before they were recorded): run again")
    values = {k: (math.inf if v is None and k not in ("output_scale_base", "skid") else v) for k, v in stored.items()}
    return HeadingLimits(**values)


def _flights(folder: Path) -> list[tuple[float, dict, YawModel, float, dict]]:
    """(thrust, gains, model, speed, flown step) of every verification step flown in the run."""
    store = sqlite3.connect(folder / "store.sqlite")
    models = {thrust: (speed, json.loads(model)) for thrust, speed, model in
              store.execute("select thrust, speed, model_json from runs where axis='yaw' and accepted=1")}
    out = []
    for (text,) in store.execute("select result_json from behavior_results where kind='heading_steps'"):
        record = json.loads(text)
        speed, model = models[record["thrust"]]
        for step in record["steps"]:
            out.append((record["thrust"], record["gains"], YawModel(model["a22"], model["b2"], model["delta0"]),
                        speed, step))
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", help="the folder given to bench_ardupilot.py --keep")
    args = parser.parse_args()
    folders = sorted(p for p in Path(args.runs).glob("run-*") if (p / "store.sqlite").is_file())
    if not folders:
        print(f"no kept run in {args.runs}", file=sys.stderr)
        return 2
    print(f"{'run':>4} {'thrust':>6} {'flown IAE':>9} {'A.2s':>6} {'err%':>6} {'A.2':>6} {'err%':>6} | "
          f"{'overshoot':>9} {'A.2s':>5} {'A.2':>5}")
    errors: dict[str, list[float]] = {"A.2s": [], "A.2": []}
    for folder in folders:
        limits = _limits(json.loads((folder / "summary.json").read_text()))
        controller = CONTROLLERS["cascade"]
        for thrust, gains, model, speed, step in _flights(folder):
            duration = step.get("duration_s") or 25.0
            size = math.radians(step.get("step_deg", 40.0))
            shaped = predicted_step(controller, model, gains, limits, size, duration, speed)
            plain = predicted_step(controller, model, gains, dataclasses.replace(limits, input_tc=0.0), size,
                                   duration, speed)
            flown = step["iae_s"]
            row = []
            for name, predicted in (("A.2s", shaped), ("A.2", plain)):
                error = 100.0 * (predicted.figures.iae_s / flown - 1.0)
                errors[name].append(error)
                row.append(f"{predicted.figures.iae_s:6.2f} {error:+6.1f}")
            print(f"{folder.name[4:]:>4} {thrust:6.2f} {flown:9.2f} {row[0]} {row[1]} | {step['overshoot_pct']:9.1f} "
                  f"{shaped['overshoot_pct']:5.1f} {plain['overshoot_pct']:5.1f}")
    for name, values in errors.items():
        worst = max(values, key=abs)
        print(f"{name}: predicted minus flown step error, median {sorted(values)[len(values) // 2]:+.1f} %, worst "
              f"{worst:+.1f} % over {len(values)} steps")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
