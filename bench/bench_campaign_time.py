"""The campaign's vehicle time: the full comparison beside the verified short campaign, in one run.

"compare" is the campaign as it was (``companion rehearse --full-comparison``: the quick
identification, then ±20° heading steps with the original, the constant and the scheduled gains at
every thrust); "verify" is the default (the designed gains' step flown at the lowest and the
highest speed, the rest predicted on the accepted models: companion.procedures.verified_design).
Same seeds for both.

- Vehicle time per phase and total, accuracy, R², kept: the product path, ``companion rehearse
  --behaviors none --json`` over MAVLink on loopback (yaw + pitch at 5 thrusts, STARFISH), the
  accuracy against the simulator's linearisation at the physics' own speed.
- Predicted against flown, and the written gains flown *after* the campaign: the verified campaign
  (yaw) on the in-process autopilot (``harness.inprocess``, no MAVLink), then one decided ±step
  (``behaviors.verification.VerificationStep``) with the scheduled and with the original gains at
  every identified speed, each beside the model's prediction over the same duration.

    python bench/bench_campaign_time.py                # 20 seeds, 2 jobs (~25 min on 2 idle cores)
    python bench/bench_campaign_time.py --seeds 4 --jobs 1
"""
from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from companion.records.store import Store

PROCEDURES = {"compare": ["--full-comparison"], "verify": []}
PHASES = ("settle", "excitation", "validation", "verification", "heading_steps", "design_writes")
NAN = float("nan")


def rehearse(seed: int, procedure: str) -> dict:
    """One yaw + pitch campaign at 5 thrusts over MAVLink with its checks (no behaviours); its figures."""
    with tempfile.TemporaryDirectory() as out:
        command = [sys.executable, "-m", "companion", "rehearse", "--behaviors", "none", "--json", "--no-report",
                   "--seed", str(seed), "--out", out, *PROCEDURES[procedure]]
        done = subprocess.run(command, capture_output=True, text=True, check=False, timeout=3600)
        try:
            summary = json.loads(done.stdout)
        except json.JSONDecodeError:
            return {"status": f"crashed ({done.returncode}): {done.stderr.strip()[-200:]}", "vehicle_time_s": NAN,
                    "a22": [], "b2": [], "r2_yaw": [], "r2_pitch": [], "phases": {}, "kept": False, "flights": 0}
        with Store(Path(out) / "store.sqlite") as store:
            runs = store.runs(summary["campaign_id"]) if summary.get("campaign_id") else []
    yaw = summary.get("runs", [])
    verified = summary.get("verified") or {}
    return {
        "status": summary.get("status"),
        "vehicle_time_s": summary.get("vehicle_time_s", NAN),
        "phases": summary.get("vehicle_time_by_phase") or {},
        "a22": [abs(100 * (r["a22"] / r["true_a22"] - 1)) for r in yaw],
        "b2": [abs(100 * (r["b2"] / r["true_b2"] - 1)) for r in yaw],
        "r2_yaw": [r["r2"] for r in runs if r["accepted"] and r["axis"] == "yaw"],
        "r2_pitch": [r["r2"] for r in runs if r["accepted"] and r["axis"] == "pitch"],
        "kept": bool(summary.get("final_gains")),
        "flights": sum(s.get("flights", 1) for s in verified.get("flown", [])) or len(summary.get("heading_steps") or []),
    }


def after_campaign(seed: int) -> dict:
    """The verified campaign in-process, then the scheduled and the original gains flown at every
    identified speed: flown against predicted overshoot (points) and step error (IAE, relative)."""
    from behaviors.verification import VerificationStep
    from companion.procedures.campaign import CampaignConfig, IdentificationCampaign
    from companion.procedures.runner import RestorePoint, run_behavior, run_procedure
    from harness.inprocess import InProcessLink

    link = InProcessLink(preset="starfish", seed=seed)
    campaign = IdentificationCampaign(CampaignConfig(axes=("yaw",)).quick())
    campaign.original_gains = dict(RestorePoint.capture(link, campaign.footprint).parameters)
    outcome = run_procedure(link, campaign)
    verifier, design = campaign.verifier, campaign.heading_design
    rows: list[dict] = []
    if outcome.status != "completed" or verifier is None or design is None:
        return {"status": outcome.status, "rows": rows, "flown_in_campaign": []}
    original = campaign.original_heading()
    for point in design.points:
        model = verifier.model_at(campaign.accepted, point.thrust)
        for label, gains in (("scheduled", dict(point.scheduled)), ("original", original)):
            step = VerificationStep(point.thrust, gains, verifier.config, rudder_max=verifier.limits.rudder_max,
                                    label=label)
            run_behavior(link, step)
            if not step.decided:
                rows.append({"thrust": point.thrust, "label": label, "decided": False})
                continue
            predicted = verifier.step_prediction(model, gains, step.metrics.duration_s)
            rows.append({"thrust": point.thrust, "label": label, "decided": True,
                         "overshoot": step.metrics.figures.overshoot_pct, "predicted_overshoot": predicted.figures.overshoot_pct,
                         "iae": step.metrics.figures.iae_s, "predicted_iae": predicted.figures.iae_s})
    in_campaign = [{"overshoot": s.max_overshoot_pct, "predicted_overshoot": s.predicted.figures.overshoot_pct,
                    "iae": s.iae_s, "predicted_iae": s.predicted.figures.iae_s}
                   for s in verifier.flown if s.predicted and s.decided]
    return {"status": outcome.status, "rows": rows, "flown_in_campaign": in_campaign}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--jobs", type=int, default=2, help="rehearsals run at once (default: %(default)s)")
    parser.add_argument("--json", metavar="FILE", help="also write the raw figures to FILE")
    args = parser.parse_args()
    seeds = range(1, args.seeds + 1)
    started = time.monotonic()
    rows: dict[str, list[dict]] = {}
    with ThreadPoolExecutor(max_workers=args.jobs) as pool:
        futures = {p: [pool.submit(rehearse, seed, p) for seed in seeds] for p in PROCEDURES}
        for procedure in PROCEDURES:
            rows[procedure] = [f.result() for f in futures[procedure]]
            for seed, r in zip(seeds, rows[procedure]):
                phases = " ".join(f"{k} {v:.0f}" for k, v in r["phases"].items())
                print(f"{procedure:7s} seed {seed:2d}: {r['status']:9s} {r['vehicle_time_s']:6.1f} s "
                      f"({phases}), kept {r['kept']}, {r['flights']} steps flown", flush=True)
    after = [after_campaign(seed) for seed in seeds]
    wall = time.monotonic() - started

    med = statistics.median

    def pooled(procedure: str, key: str) -> list[float]:
        return [v for r in rows[procedure] for v in r[key]]

    def both(fn, fmt: str) -> str:
        def one(p: str) -> str:
            try:
                return format(fn(p), fmt)
            except (ValueError, statistics.StatisticsError):
                return "-"
        return " ".join(f"{one(p):>10s}" for p in PROCEDURES)

    print(f"\n{args.seeds} seeds, STARFISH, yaw + pitch at 5 thrusts over MAVLink")
    print(f"{'metric':44s} {'compare':>10s} {'verify':>10s} {'goal':>8s}")
    print(f"{'vehicle time, median (s)':44s} {both(lambda p: med(r['vehicle_time_s'] for r in rows[p]), '.1f')} "
          f"{'≤ 240':>8s}")
    print(f"{'vehicle time, max (s)':44s} {both(lambda p: max(r['vehicle_time_s'] for r in rows[p]), '.1f')}")
    for phase in PHASES:
        print(f"{'  ' + phase.replace('_', ' ') + ', median (s)':44s} "
              f"{both(lambda p: med(r['phases'].get(phase, 0.0) for r in rows[p]), '.1f')}")
    print(f"{'heading steps flown per campaign, median':44s} {both(lambda p: med(r['flights'] for r in rows[p]), '.0f')}")
    print(f"{'a22 error, median (%)':44s} {both(lambda p: med(pooled(p, 'a22')), '.2f')} {'≤ 3':>8s}")
    print(f"{'b2 error, median (%)':44s} {both(lambda p: med(pooled(p, 'b2')), '.2f')} {'≤ 2':>8s}")
    print(f"{'validation R², yaw, min':44s} {both(lambda p: min(pooled(p, 'r2_yaw')), '.3f')} {'≥ 0.9':>8s}")
    print(f"{'gains kept (campaigns)':44s} {both(lambda p: sum(r['kept'] for r in rows[p]), 'd')} "
          f"{'/' + str(args.seeds):>8s}")
    print(f"{'campaigns completed':44s} {both(lambda p: sum(r['status'] == 'completed' for r in rows[p]), 'd')}")

    flown = [row for a in after for row in a["rows"] if row["decided"]]
    scheduled = [row for row in flown if row["label"] == "scheduled"]
    print(f"\nafter the verified campaign, in-process (yaw, 5 speeds, {len(after)} seeds): a decided step at every speed")
    if scheduled:
        per_thrust = {}
        for row in scheduled:
            per_thrust.setdefault(row["thrust"], []).append(row["overshoot"])
        medians = {t: med(v) for t, v in sorted(per_thrust.items())}
        print("  written (scheduled) gains, overshoot median per speed (%): "
              + ", ".join(f"{t:.2f}: {v:.1f}" for t, v in medians.items()) + "   goal ≤ 6")
        print(f"  written gains, overshoot worst (%): {max(r['overshoot'] for r in scheduled):.1f}")
    undecided = sum(not row["decided"] for a in after for row in a["rows"])
    print(f"  steps that could not decide: {undecided}")
    for label in ("scheduled", "original"):
        chosen = [r for r in flown if r["label"] == label]
        if chosen:
            gaps = [r["overshoot"] - r["predicted_overshoot"] for r in chosen]
            ratios = [r["iae"] / r["predicted_iae"] - 1 for r in chosen]
            print(f"  {label:9s} flown - predicted overshoot (points): median {med(gaps):+.2f}, "
                  f"range {min(gaps):+.2f} .. {max(gaps):+.2f}; IAE flown/predicted - 1: median {med(ratios):+.1%}, "
                  f"range {min(ratios):+.1%} .. {max(ratios):+.1%}")
    in_campaign = [row for a in after for row in a["flown_in_campaign"]]
    if in_campaign:
        gaps = [r["overshoot"] - r["predicted_overshoot"] for r in in_campaign]
        print(f"  the campaign's own verification steps: flown - predicted overshoot median {med(gaps):+.2f} points "
              f"(max |gap| {max(abs(g) for g in gaps):.2f}; the keep rule allows 3)")
    print(f"\nwall time {wall:.0f} s")
    if args.json:
        Path(args.json).write_text(json.dumps({"rehearsals": rows, "after": after}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
