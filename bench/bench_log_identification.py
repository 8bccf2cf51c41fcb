"""Identification from a recorded mission against the live campaign on the same vehicle.

Per seed: (1) the live campaign (doublets, ``run_campaign``, yaw, thrusts 0.6/0.8/1.0) on the
simulator; (2) a survey mission on the same vehicle — course changes by its own heading hold at the
same thrusts, no doublet — recorded as a tlog over MAVLink (``harness.missions.record_survey_tlog``)
and identified with ``companion identify --log``'s code. Printed per thrust: the live model, the
mean of the log's accepted segment models at that thrust, their difference, and both against the
simulator's linearised truth. Never pass/fail.

    python bench/bench_log_identification.py --seeds 3
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from behaviors.identification import ManoeuvreConfig  # noqa: E402
from companion.rehearsal.launcher import SimulatorProcess  # noqa: E402
from companion.procedures.campaign import CampaignConfig  # noqa: E402
from harness.missions import SurveyPlan, record_survey_tlog  # noqa: E402

THRUSTS = (0.6, 0.8, 1.0)


def live(seed: int, store_path: Path) -> dict[float, dict]:
    from companion.link.vehicle import VehicleLink
    from companion.procedures.app import AbortFlag, run_campaign, vehicle_record
    from companion.records.store import Store

    config = CampaignConfig(thrusts=THRUSTS, axes=("yaw",), step_labels=(), write_gains=False, yaw=ManoeuvreConfig())
    with SimulatorProcess(preset="starfish", speedup=0.0, seed=seed, lockstep=True) as sim, Store(store_path) as store:
        link = VehicleLink.connect(sim.endpoint, lockstep=True)
        try:
            link.arm(True)
            campaign, _, _ = run_campaign(link, store, config, vehicle_id=vehicle_record(store, link), abort=AbortFlag())
        finally:
            link.close()
    return {a.thrust: {"speed": a.speed, "a22": a.model.a22, "b2": a.model.b2} for a in campaign.accepted}


def from_log(seed: int, folder: Path) -> tuple[dict[float, dict], dict]:
    from companion.procedures.log_identification import identify_log
    from companion.records.flight_logs import read_steering_log

    tlog = record_survey_tlog(folder / f"survey-{seed}.tlog", SurveyPlan(thrusts=THRUSTS), seed=seed)
    result = identify_log(read_steering_log(str(tlog)))
    out: dict[float, dict] = {}
    for thrust in THRUSTS:
        models = [a for a in result.accepted if a.thrust is not None and abs(a.thrust - thrust) < 0.01]
        if models:
            out[thrust] = {"speed": float(np.mean([a.speed for a in models])), "segments": len(models),
                           "a22": float(np.mean([a.model.a22 for a in models])),
                           "b2": float(np.mean([a.model.b2 for a in models])),
                           "a22_spread": float(np.ptp([a.model.a22 for a in models])),
                           "b2_spread": float(np.ptp([a.model.b2 for a in models]))}
    verdicts = {}
    for s in result.segments:
        key = s.segment.reason.split(":")[0]
        verdicts[key] = verdicts.get(key, 0) + 1
    return out, verdicts


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    from sim.linearize import linearized_yaw
    from sim.preset import load_preset

    preset = load_preset("starfish")
    rows, worst = [], {"a22": 0.0, "b2": 0.0}
    with tempfile.TemporaryDirectory(prefix="bench-logid-") as tmp:
        for seed in range(1, args.seeds + 1):
            campaign = live(seed, Path(tmp) / f"live-{seed}.sqlite")
            logged, verdicts = from_log(seed, Path(tmp))
            for thrust in THRUSTS:
                if thrust not in campaign or thrust not in logged:
                    rows.append({"seed": seed, "thrust": thrust, "missing": True})
                    continue
                a, b = campaign[thrust], logged[thrust]
                truth = linearized_yaw(preset, b["speed"])
                row = {"seed": seed, "thrust": thrust, "speed_live": a["speed"], "speed_log": b["speed"],
                       "segments": b["segments"], "live": a, "log": b,
                       "diff_pct": {k: 100 * (b[k] / a[k] - 1) for k in ("a22", "b2")},
                       "log_vs_truth_pct": {k: 100 * (b[k] / truth[k] - 1) for k in ("a22", "b2")},
                       "live_vs_truth_pct": {k: 100 * (a[k] / linearized_yaw(preset, a["speed"])[k] - 1)
                                             for k in ("a22", "b2")},
                       "verdicts": verdicts}
                for k in worst:
                    worst[k] = max(worst[k], abs(row["diff_pct"][k]))
                rows.append(row)
                if not args.json:
                    print(f"seed {seed} T{thrust:.1f}: live a22 {a['a22']:.4f} b2 {a['b2']:.4f} | log ({b['segments']} "
                          f"segments) a22 {b['a22']:.4f} b2 {b['b2']:.4f} | log−live a22 {row['diff_pct']['a22']:+.1f} % "
                          f"b2 {row['diff_pct']['b2']:+.1f} % | vs truth: log {row['log_vs_truth_pct']['a22']:+.1f}/"
                          f"{row['log_vs_truth_pct']['b2']:+.1f} %, live {row['live_vs_truth_pct']['a22']:+.1f}/"
                          f"{row['live_vs_truth_pct']['b2']:+.1f} %", flush=True)
    summary = {"worst_log_vs_live_pct": worst, "rows": rows}
    print(json.dumps(summary if args.json else {"worst_log_vs_live_pct": worst}, allow_nan=False))
    return 0


if __name__ == "__main__":
    sys.exit(main())
