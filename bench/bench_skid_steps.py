"""A skid boat's flown heading steps against their prediction with and without its mixer, thrust and speed (eq. A.2k).

Reads the runs kept by ``bench/bench_ardupilot.py --frame skid --physics 3dof --keep DIR`` (each
``DIR/run-N`` holds the campaign's store, with every flown verification step's record, and its
summary) and predicts each flown step again on the accepted model of its speed, with the gains it
was flown with:

* ``A.2``: the autopilot's controller (ArduPilot's cascade; our simulator's PI, eq. A.1) on the
  identified model alone (what the campaign predicted before);
* ``mix``: eq. A.2k with the mixer's steering room only (q = 1: the yaw moment does not follow the
  throttle), the speed held;
* ``thr``: eq. A.2k with the mixer and the thrust map (the moment follows the throttle the mixer
  leaves), the speed held;
* ``A.2k``: eq. A.2k whole: the speed through the surge model, a22 and b2 through the speed law, and
  ArduRover's speed loop as found (what the campaign predicts now; built by the campaign's own
  ``skid_plant`` from the run's store).

It prints the step error (IAE, s) and overshoot of each against the flight, the worst gaps against
the keep rule's tolerances (20 % of IAE, 3 points of overshoot), then each run's own record: what
the campaign predicted at the time, which steps it flew, its heading outcome and vehicle time.
Usage::

    python bench/bench_ardupilot.py --frame skid --physics 3dof --repeats 3 --keep /tmp/skid
    python bench/bench_skid_steps.py /tmp/skid
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
from companion.numerics.skid_step import SkidMixer, SkidPlant
from companion.numerics.surge import SurgeModel
from companion.procedures.verified_design import HeadingLimits, KeepRule, predicted_step, skid_plant

VARIANTS = ("A.2", "mix", "thr", "A.2k")


def _limits(summary: dict) -> HeadingLimits:
    stored = dict((summary.get("verified") or {}).get("limits") or {})
    if not stored:
        raise SystemExit("this run's summary holds no prediction limits (kept before they were recorded): run again")
    stored.pop("skid", None)  # rebuilt from the store below, the same way the campaign builds it
    values = {k: (math.inf if v is None and k != "output_scale_base" else v) for k, v in stored.items()}
    return HeadingLimits(**values)


def _plant(folder: Path, summary: dict, store: sqlite3.Connection, models: dict) -> SkidPlant | None:
    """The run's eq. A.2k knowledge: what the campaign predicted with (its summary's limits), or for
    a run kept before the campaign had one, built as the campaign builds it (``skid_plant``): its
    mixer (the stored configuration's, else ArduRover's defaults), the surge model the speed loop
    fitted on the same settles, the accepted yaw models and the speed loop as found."""
    stored = ((summary.get("verified") or {}).get("limits") or {}).get("skid")
    if stored:
        return SkidPlant.from_dict(stored)
    (config_text,) = store.execute("select config_json from campaigns").fetchone()
    config = json.loads(config_text)
    mixer = SkidMixer(**config["skid_mixer"]) if config.get("skid_mixer") else SkidMixer()
    speed_loop = summary.get("speed_loop") or {}
    fitted = speed_loop.get("surge")
    surge = SurgeModel(fitted["gain"], fitted["exponent"], fitted["gamma"], fitted.get("lag", 0.0)) if fitted else None
    levels = [(level["throttle"], level["speed"]) for level in (fitted or {}).get("levels", [])]
    points = sorted(models.values(), key=lambda p: p[0])
    return skid_plant(mixer, levels, surge, [u for u, _ in points], [m.a22 for _, m in points],
                      [m.b2 for _, m in points], config.get("speed_law") or "u", speed_loop.get("original") or {})


def _variants(plant: SkidPlant) -> dict[str, SkidPlant | None]:
    held = dataclasses.replace(plant, gamma=0.0, a22_slope=0.0, b2_exponent=0.0, b2_intercept_ratio=0.0,
                               speed_loop=None)
    # q = 2p = 1: F linear, the moment 2s whatever the throttle (the steering room alone)
    return {"A.2": None, "mix": dataclasses.replace(held, throttle_exponent=0.5), "thr": held, "A.2k": plant}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", help="the folder given to bench_ardupilot.py --keep (or one rehearsal's --out)")
    args = parser.parse_args()
    root = Path(args.runs)
    folders = sorted(p for p in [root, *root.glob("run-*")] if (p / "store.sqlite").is_file()
                     and (p / "summary.json").is_file())
    if not folders:
        print(f"no kept run in {args.runs}", file=sys.stderr)
        return 2
    rule = KeepRule()
    print(f"{'run':>4} {'thrust':>6} {'label':>9} | {'IAE flown':>9} " + " ".join(f"{v:>12}" for v in VARIANTS)
          + f" | {'OS flown':>8} " + " ".join(f"{v:>5}" for v in VARIANTS))
    gaps: dict[str, list[tuple[float, float]]] = {v: [] for v in VARIANTS}
    records = []
    for folder in folders:
        summary = json.loads((folder / "summary.json").read_text())
        limits = _limits(summary)
        store = sqlite3.connect(folder / "store.sqlite")
        models = {thrust: (speed, YawModel(**{k: json.loads(m)[k] for k in ("a22", "b2", "delta0")}))
                  for thrust, speed, m in store.execute("select thrust, speed, model_json from runs "
                                                        "where axis='yaw' and accepted=1")}
        plant = _plant(folder, summary, store, models)
        if plant is None:
            print(f"{folder.name}: no throttle known at any speed, no eq. A.2k", file=sys.stderr)
            continue
        variants = _variants(plant)
        controller = (summary.get("verified") or {}).get("controller") or "cascade"
        for (text,) in store.execute("select result_json from behavior_results where kind='heading_steps'"):
            record = json.loads(text)
            speed, model = models[record["thrust"]]
            for step in record["steps"]:
                duration, size = step.get("duration_s") or 25.0, math.radians(step.get("step_deg", 40.0))
                row_iae, row_os = [], []
                for name, skid in variants.items():
                    predicted = predicted_step(controller, model, record["gains"],
                                               dataclasses.replace(limits, skid=skid), size, duration, speed)
                    gap = (predicted.figures.iae_s / step["iae_s"] - 1.0, predicted.figures.overshoot_pct - step["overshoot_pct"])
                    gaps[name].append(gap)
                    row_iae.append(f"{predicted.figures.iae_s:5.2f} {100 * gap[0]:+5.0f}%")
                    row_os.append(f"{predicted.figures.overshoot_pct:5.1f}")
                run = folder.name.removeprefix("run-")[:4]
                print(f"{run:>4} {record['thrust']:6.2f} {record['label']:>9} | {step['iae_s']:9.2f} "
                      + " ".join(row_iae) + f" | {step['overshoot_pct']:8.1f} " + " ".join(row_os))
        verified = summary.get("verified") or {}
        records.append((folder.name, summary, verified))
    print("\npredicted minus flown (step error relative, overshoot in points); the keep rule allows 20 % and 3 points")
    for name, values in gaps.items():
        if not values:
            continue
        iae = sorted(v[0] for v in values)
        overshoot = sorted(v[1] for v in values)
        agree = sum(1 for a, o in values if abs(a) <= rule.iae_tolerance and abs(o) <= rule.overshoot_tolerance_pct)
        print(f"{name:>5}: IAE median {100 * iae[len(iae) // 2]:+.0f} %, worst {100 * max(iae, key=abs):+.0f} %; "
              f"overshoot median {overshoot[len(overshoot) // 2]:+.1f}, worst {max(overshoot, key=abs):+.1f} points; "
              f"{agree}/{len(values)} steps within the keep rule's tolerances")
    print("\nthe campaigns' own records (what each predicted when it flew, eq. A.2k if its limits held one)")
    for name, summary, verified in records:
        skid = "A.2k" if (verified.get("limits") or {}).get("skid") else "A.2"
        flown = verified.get("flown") or []
        steps = ", ".join(f"{s['thrust']:.2f} {s['label']}: IAE {s['iae_s']:.2f}/{s['predicted']['iae_s']:.2f} "
                          f"OS {s['max_overshoot_pct']:.1f}/{s['predicted']['overshoot_pct']:.1f}"
                          for s in flown if s.get("predicted"))
        loops = summary.get("loops") or {}
        heading = loops.get("heading") or {}
        print(f"{name}: predicted with {skid}; {len(flown)} steps flown ({steps}); heading {heading.get('outcome')} "
              f"({heading.get('why')}); design {(summary.get('heading_design') or {}).get('chosen')}; "
              f"vehicle time {summary.get('vehicle_time_s', math.nan):.0f} s "
              f"(verification {(summary.get('vehicle_time_by_phase') or {}).get('verification', math.nan):.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
