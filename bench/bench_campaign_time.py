"""The quick procedure's campaign goals: the thesis procedure beside the quick one, in one run.

"thesis" is the seeds' procedure (``companion rehearse --procedure thesis``: fixed 40/15 s settles,
16.5 s records, eq. 3.39, eq. 3.57 gains); "quick" is the quick procedure (the default: settle until steady,
yaw and pitch together, short validation records, the noise-aware stopping rule, gains for ζ = 0.75).
Same seeds for both.

- Vehicle time, accuracy, R², convergence: the product path, ``companion rehearse --no-steps
  --behaviors none --json`` over MAVLink on loopback (yaw + pitch at 5 thrusts, STARFISH), the
  accuracy against the simulator's linearisation at the physics' own speed.
- Heading-step overshoot with the scheduled gains: the same campaign (yaw, with the step checks)
  on the in-process autopilot (``harness.inprocess``, no MAVLink: ~2 s per seed), as
  ``bench/bench_identification.py`` measures it.

    python bench/bench_campaign_time.py                # 20 seeds, 2 jobs (~8 min on 2 idle cores)
    python bench/bench_campaign_time.py --seeds 6 --jobs 1
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

PROCEDURES = ("thesis", "quick")


def rehearse(seed: int, procedure: str) -> dict:
    """One yaw + pitch campaign at 5 thrusts over MAVLink (no step checks, no behaviours); its figures."""
    with tempfile.TemporaryDirectory() as out:
        command = [sys.executable, "-m", "companion", "rehearse", "--no-steps", "--behaviors", "none", "--json",
                   "--no-report", "--seed", str(seed), "--out", out, "--procedure", procedure]
        done = subprocess.run(command, capture_output=True, text=True, check=False, timeout=1800)
        try:
            summary = json.loads(done.stdout)
        except json.JSONDecodeError:
            return {"status": f"crashed ({done.returncode}): {done.stderr.strip()[-200:]}", "vehicle_time_s": float("nan"),
                    "a22": [], "b2": [], "r2_yaw": [], "r2_pitch": [], "converged_s": [], "attempts": 0, "phases": {}}
        with Store(Path(out) / "store.sqlite") as store:
            runs = store.runs(summary["campaign_id"]) if summary.get("campaign_id") else []
    yaw = summary.get("runs", [])
    return {
        "status": summary.get("status"),
        "vehicle_time_s": (summary.get("vehicle_time_by_phase") or {}).get("identification", float("nan")),
        "phases": summary.get("identification_stage_s") or {},
        "a22": [abs(100 * (r["a22"] / r["true_a22"] - 1)) for r in yaw],
        "b2": [abs(100 * (r["b2"] / r["true_b2"] - 1)) for r in yaw],
        "r2_yaw": [r["r2"] for r in runs if r["accepted"] and r["axis"] == "yaw"],
        "r2_pitch": [r["r2"] for r in runs if r["accepted"] and r["axis"] == "pitch"],
        "attempts": len(runs),
        "converged_s": [r["converged_s"] for r in yaw if r.get("converged_s") is not None],
    }


def overshoots(seed: int, procedure: str) -> dict[float, float]:
    """Max overshoot (%) of the scheduled gains' ±20° heading steps per thrust, in-process."""
    from companion.procedures.campaign import CampaignConfig, IdentificationCampaign
    from companion.procedures.runner import RestorePoint, run_procedure
    from harness.inprocess import InProcessLink

    config = CampaignConfig(axes=("yaw",), step_labels=("original", "scheduled")).for_procedure(procedure)
    link = InProcessLink(preset="starfish", seed=seed)
    campaign = IdentificationCampaign(config)
    campaign.original_gains = dict(RestorePoint.capture(link, campaign.footprint).parameters)
    run_procedure(link, campaign)
    return {s["thrust"]: s["max_overshoot_pct"] for s in campaign.step_results if s["label"] == "scheduled"}


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
                print(f"{procedure:6s} seed {seed:2d}: {r['status']:9s} {r['vehicle_time_s']:6.1f} s, "
                      f"{r['attempts']} attempts, stages {json.dumps(r['phases'])}", flush=True)
    steps = {p: [overshoots(seed, p) for seed in seeds] for p in PROCEDURES}
    wall = time.monotonic() - started

    def pooled(procedure: str, key: str) -> list[float]:
        return [v for r in rows[procedure] for v in r[key]]

    def both(fn, fmt: str) -> str:
        return " ".join(f"{format(fn(p), fmt):>10s}" for p in PROCEDURES)

    med = statistics.median
    print(f"\n{args.seeds} seeds, STARFISH, yaw + pitch at 5 thrusts; overshoot in-process (yaw)")
    print(f"{'metric':40s} {'thesis':>10s} {'quick':>10s} {'goal':>8s}")
    print(f"{'vehicle time, median (s)':40s} {both(lambda p: med(r['vehicle_time_s'] for r in rows[p]), '.1f')} "
          f"{'≤ 240':>8s}")
    print(f"{'vehicle time, max (s)':40s} {both(lambda p: max(r['vehicle_time_s'] for r in rows[p]), '.1f')}")
    print(f"{'a22 error, median (%)':40s} {both(lambda p: med(pooled(p, 'a22')), '.2f')} {'≤ 3':>8s}")
    print(f"{'a22 error, max (%)':40s} {both(lambda p: max(pooled(p, 'a22')), '.2f')}")
    print(f"{'b2 error, median (%)':40s} {both(lambda p: med(pooled(p, 'b2')), '.2f')} {'≤ 2':>8s}")
    print(f"{'validation R², yaw, min':40s} {both(lambda p: min(pooled(p, 'r2_yaw')), '.3f')} {'≥ 0.9':>8s}")
    def below(p: str) -> str:
        values = pooled(p, "r2_yaw")
        return f"{sum(v < 0.9 for v in values)}/{len(values)}"

    def pitch_r2(p: str) -> str:
        values = pooled(p, "r2_pitch")
        return f"{min(values):.2f}/{med(values):.2f}" if values else "-"

    print(f"{'validation R², yaw, models < 0.9':40s} {both(below, 's')}")
    print(f"{'validation R², pitch, min / median':40s} {both(pitch_r2, 's')} {'≥ 0.9':>8s}")
    print(f"{'convergence (yaw), median (s)':40s} {both(lambda p: med(pooled(p, 'converged_s')), '.2f')} {'≤ 8':>8s}")
    def overshoot_medians(p: str) -> str:
        per_thrust = [med(s[t] for s in steps[p]) for t in steps[p][0]]
        return f"{min(per_thrust):.1f}-{max(per_thrust):.1f}"

    print(f"{'overshoot, scheduled, median per thrust (%)':40s} {both(overshoot_medians, 's')} {'≤ 6':>8s}")
    print(f"{'overshoot, scheduled, worst (%)':40s} {both(lambda p: max(v for s in steps[p] for v in s.values()), '.2f')} "
          f"{'≤ 7':>8s}")
    print(f"{'campaigns completed':40s} {both(lambda p: sum(r['status'] == 'completed' for r in rows[p]), 'd')}")
    print(f"\nwall time {wall:.0f} s")
    if args.json:
        Path(args.json).write_text(json.dumps({"rehearsals": rows, "overshoot": {p: [{str(k): v for k, v in s.items()}
                                                                                    for s in steps[p]] for p in PROCEDURES}},
                                              indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
