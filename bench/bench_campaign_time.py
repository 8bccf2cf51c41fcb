"""Vehicle time of the identification campaign (issue 10): the thesis' fixed timings against the
quick procedure (`--quick`: settle until steady, short validation records, yaw and pitch together),
on the same seeds, with the accuracy that must not suffer (median a22/b2 error, validation R²) and
the time to convergence (eq. 3.39).

    python bench/bench_campaign_time.py --seeds 6
"""
from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from companion.records.store import Store

GOALS = {"vehicle_time_s": 240.0, "a22": 3.0, "b2": 2.0, "r2": 0.9, "converged_s": 8.0}


def run(seed: int, quick: bool) -> dict:
    """One yaw + pitch campaign at 5 thrusts (no step checks, no behaviours); its figures."""
    with tempfile.TemporaryDirectory() as out:
        command = [sys.executable, "-m", "companion", "rehearse", "--no-steps", "--behaviors", "none", "--json",
                   "--seed", str(seed), "--out", out, *(["--quick"] if quick else [])]
        done = subprocess.run(command, capture_output=True, text=True, check=False, timeout=900)
        summary = json.loads(done.stdout)
        with Store(Path(out) / "store.sqlite") as store:
            runs = store.runs(summary["campaign_id"]) if summary.get("campaign_id") else []
    yaw = summary.get("runs", [])
    return {
        "status": summary.get("status"),
        "vehicle_time_s": summary.get("vehicle_time_s") or float("nan"),
        "a22": [abs(100 * (r["a22"] / r["true_a22"] - 1)) for r in yaw],
        "b2": [abs(100 * (r["b2"] / r["true_b2"] - 1)) for r in yaw],
        "r2": [r["r2"] for r in runs if r["accepted"]],
        "pitch_models": sum(1 for r in runs if r["accepted"] and r["axis"] == "pitch"),
        "attempts": len(runs),
        "converged_s": [r["converged_s"] for r in yaw if r.get("converged_s") is not None],
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    args = parser.parse_args()
    rows = {}
    for label, quick in (("thesis", False), ("quick", True)):
        results = [run(seed, quick) for seed in range(1, args.seeds + 1)]
        rows[label] = results
        for seed, r in enumerate(results, 1):
            print(f"{label:6s} seed {seed:2d}: {r['status']:9s} {r['vehicle_time_s']:6.1f} s, "
                  f"{r['attempts']} attempts, {r['pitch_models']} pitch models")

    def pooled(label: str, key: str) -> list[float]:
        return [v for r in rows[label] for v in r[key]]

    print()
    print(f"{'metric':32s} {'thesis':>10s} {'quick':>10s} {'goal':>8s}")
    med = statistics.median
    time_t = med(r["vehicle_time_s"] for r in rows["thesis"])
    time_q = med(r["vehicle_time_s"] for r in rows["quick"])
    print(f"{'vehicle time, median (s)':32s} {time_t:10.1f} {time_q:10.1f} {'≤ 240':>8s}   ratio {time_q / time_t:.2f}")
    print(f"{'vehicle time, max (s)':32s} {max(r['vehicle_time_s'] for r in rows['thesis']):10.1f} "
          f"{max(r['vehicle_time_s'] for r in rows['quick']):10.1f}")
    for key, text, goal in (("a22", "a22 error, median (%)", "≤ 3"), ("b2", "b2 error, median (%)", "≤ 2")):
        print(f"{text:32s} {med(pooled('thesis', key)):10.2f} {med(pooled('quick', key)):10.2f} {goal:>8s}")
    print(f"{'validation R², min (yaw+pitch)':32s} {min(pooled('thesis', 'r2')):10.3f} {min(pooled('quick', 'r2')):10.3f} "
          f"{'≥ 0.9':>8s}")
    print(f"{'convergence, median (s)':32s} {med(pooled('thesis', 'converged_s')):10.2f} "
          f"{med(pooled('quick', 'converged_s')):10.2f} {'≤ 8':>8s}")
    print(f"{'campaigns completed':32s} {sum(r['status'] == 'completed' for r in rows['thesis']):10d} "
          f"{sum(r['status'] == 'completed' for r in rows['quick']):10d}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
