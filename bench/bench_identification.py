"""Identification accuracy, convergence and heading-step overshoot over many seeds.

Runs the whole campaign (five thrusts, yaw) per seed and compares every accepted model with the
simulator's linearised truth at the measured speed. Two paths:

- ``--path inprocess`` (default): the simulator's autopilot and physics in-process, no MAVLink
  (deterministic, ~6 s per seed);
- ``--path mavlink``: the product path, ``companion rehearse`` machinery over MAVLink on loopback
  with the simulator at ``--speedup`` (~40 s of wall time per seed).

Prints, per thrust and overall: median / 90th percentile of |a22| and |b2| relative errors, median
R², median convergence time (eq. 3.39 held for 20 samples: when training stops), the median time
from which eq. 3.39 held ("from med", the thesis' Fig. 3.11 figure: "met from 12 s onward"), and the median time after which the estimates stay within 2 %
of their final values ("2% med"), and the heading-step overshoot with the scheduled gains against one
constant gain tuned at 60 % thrust. Goals: median error ≤ 5 %, R² ≥ 0.9, convergence
≤ 10 s (the seed: 12 s), overshoot ≤ 6 % everywhere.

    python bench/bench_identification.py --seeds 20
    python bench/bench_identification.py --seeds 20 --path mavlink --speedup 50
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from dataclasses import replace
from pathlib import Path

from companion.procedures.campaign import CampaignConfig, IdentificationCampaign
from companion.procedures.runner import RestorePoint, run_procedure
from sim.linearize import linearized_yaw
from sim.preset import load_preset

CONFIG = CampaignConfig(axes=("yaw",), step_labels=("constant", "scheduled"))


def run_inprocess(seed: int, preset: str) -> dict:
    from harness.inprocess import InProcessLink

    link = InProcessLink(preset=preset, seed=seed)
    campaign = IdentificationCampaign(CONFIG)
    campaign.original_gains = dict(RestorePoint.capture(link, campaign.footprint).parameters)
    outcome = run_procedure(link, campaign)
    return {"status": outcome.status, "accepted": _rows(campaign.accepted), "steps": campaign.step_results}


def _rows(attempts) -> list[dict]:
    """The accepted attempts as plain dicts (their summary plus the training series)."""
    return [dict(attempt.summary(), training=attempt.training) for attempt in attempts]


def run_mavlink(seed: int, preset: str, speedup: float) -> dict:
    from companion.procedures.app import AbortFlag, run_campaign, vehicle_record
    from companion.link.vehicle import VehicleLink
    from companion.rehearsal.launcher import SimulatorProcess
    from companion.records.store import Store

    out = Path(f"/tmp/bench-identification-{seed}")
    out.mkdir(exist_ok=True)
    with Store(out / "store.sqlite") as store, SimulatorProcess(preset, speedup, seed) as sim:
        link = VehicleLink.connect(sim.endpoint, lockstep=sim.lockstep)
        try:
            link.arm(True)
            campaign, outcome, _ = run_campaign(link, store, CONFIG, vehicle_id=vehicle_record(store, link),
                                                abort=AbortFlag())
        finally:
            link.close()
    return {"status": outcome.status, "accepted": _rows(campaign.accepted), "steps": campaign.step_results}


def settled_s(history: dict | None, band: float = 0.02) -> float | None:
    """Time from the start of training after which a22 and b2 stay within ``band`` of their final values."""
    if not history or not history.get("time_s"):
        return None
    last = None
    for t, a22, b2 in zip(history["time_s"], history["a22"], history["b2"]):
        if abs(a22 - history["a22"][-1]) > band * abs(history["a22"][-1]) or \
                abs(b2 - history["b2"][-1]) > band * abs(history["b2"][-1]):
            last = t
    return last


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    if not ordered:
        return float("nan")
    index = min(len(ordered) - 1, max(0, round(q * (len(ordered) - 1))))
    return ordered[index]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--first-seed", type=int, default=1)
    parser.add_argument("--preset", default="starfish")
    parser.add_argument("--path", choices=("inprocess", "mavlink"), default="inprocess")
    parser.add_argument("--speedup", type=float, default=50.0)
    parser.add_argument("--integral-ratio", type=float, default=None, help="PI zero at ωn/N (default: GainBounds')")
    parser.add_argument("--damping", type=float, default=None,
                        help="design ζ of the heading pair (default: the campaign's, GainBounds.damping)")
    parser.add_argument("--quick", action="store_true", help="the quick procedure (CampaignConfig.quick)")
    parser.add_argument("--p0", type=float, default=None, help="RLS initial covariance scale (default: the campaign's)")
    parser.add_argument("--json", metavar="FILE", help="also write the raw rows to FILE")
    args = parser.parse_args()
    global CONFIG
    if args.integral_ratio is not None:
        CONFIG = replace(CONFIG, bounds=replace(CONFIG.bounds, integral_ratio=args.integral_ratio))
    if args.damping is not None:
        CONFIG = replace(CONFIG, bounds=replace(CONFIG.bounds, damping=args.damping))
    if args.quick:
        CONFIG = CONFIG.quick()
    if args.p0 is not None:
        CONFIG = replace(CONFIG, yaw=replace(CONFIG.yaw, p0=args.p0))

    preset = load_preset(args.preset)
    rows, steps, failures = [], [], 0
    started = time.monotonic()
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        result = run_inprocess(seed, args.preset) if args.path == "inprocess" else run_mavlink(seed, args.preset, args.speedup)
        if result["status"] != "completed":
            failures += 1
        for attempt in result["accepted"]:
            truth = linearized_yaw(preset, attempt["speed"])
            model = attempt["model"]
            rows.append({"seed": seed, "thrust": attempt["thrust"], "speed": attempt["speed"],
                         "a22_err": abs(model["a22"] / truth["a22"] - 1), "b2_err": abs(model["b2"] / truth["b2"] - 1),
                         "delta0_err": abs(model["delta0"] - truth["delta0"]), "r2": attempt["r2"],
                         "converged_s": attempt["converged_s"], "training_s": attempt["training_s"],
                         "settled_s": settled_s((attempt.get("training") or {}).get("history")),
                         "met_from_s": attempt.get("criterion_met_from_s"),
                         "attempt": attempt["attempt"]})
        for s in result["steps"]:
            steps.append({"seed": seed, "thrust": s.thrust, "label": s.label, "overshoot": s.max_overshoot_pct})
        print(f"seed {seed}: {result['status']}, {len(result['accepted'])} models", file=sys.stderr, flush=True)
    wall = time.monotonic() - started

    print(f"\nidentification on '{args.preset}' over {args.seeds} seeds, path {args.path}"
          + (f" at {args.speedup:g}x" if args.path == "mavlink" else "") + f"; {failures} campaigns not completed")
    print(f"{'thrust':>6} {'n':>3} {'a22 med':>8} {'a22 p90':>8} {'b2 med':>7} {'b2 p90':>7} {'R2 med':>7} {'R2 min':>7} "
          f"{'conv med':>8} {'conv p90':>8} {'unconv':>6} {'from med':>8} {'2% med':>7}")
    for thrust in sorted({r["thrust"] for r in rows}) + [None]:
        sel = [r for r in rows if thrust is None or r["thrust"] == thrust]
        conv = [r["converged_s"] for r in sel if r["converged_s"] is not None]
        label = "all" if thrust is None else f"{thrust:.2f}"
        print(f"{label:>6} {len(sel):>3} {100 * statistics.median(r['a22_err'] for r in sel):7.2f}% "
              f"{100 * percentile([r['a22_err'] for r in sel], 0.9):7.2f}% {100 * statistics.median(r['b2_err'] for r in sel):6.2f}% "
              f"{100 * percentile([r['b2_err'] for r in sel], 0.9):6.2f}% {statistics.median(r['r2'] for r in sel):7.3f} "
              f"{min(r['r2'] for r in sel):7.3f} {statistics.median(conv) if conv else float('nan'):8.2f} "
              f"{percentile(conv, 0.9):8.2f} {len(sel) - len(conv):>6} "
              f"{statistics.median(r['met_from_s'] for r in sel if r['met_from_s'] is not None):8.2f} "
              f"{statistics.median(r['settled_s'] for r in sel if r['settled_s'] is not None):7.2f}")
    print("\nheading steps ±20°: max overshoot % (median / worst over seeds)")
    print(f"{'thrust':>6} {'scheduled':>16} {'constant@60%':>16}")
    for thrust in sorted({s["thrust"] for s in steps}):
        cells = []
        for label in ("scheduled", "constant"):
            values = [s["overshoot"] for s in steps if s["thrust"] == thrust and s["label"] == label]
            cells.append(f"{statistics.median(values):6.2f} / {max(values):6.2f}" if values else "-")
        print(f"{thrust:6.2f} {cells[0]:>16} {cells[1]:>16}")
    print(f"\nwall time {wall:.1f} s ({wall / args.seeds:.1f} s per seed)")
    if args.json:
        Path(args.json).write_text(json.dumps({"rows": rows, "steps": steps}, indent=1))


if __name__ == "__main__":
    main()
