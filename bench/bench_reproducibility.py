"""Same seed, same numbers: the spread of a rehearsal's results over repeats of one seed,
beside their spread over seeds. The first must be zero; the second shows what the seed moves.

Runs ``companion rehearse --json`` as a user does (a child process each time) and compares the
summaries without their wall-clock fields (``companion.rehearsal.reproducibility``). Prints, per key
figure, max − min over the repeats and over the seeds, then how many of the summary's numbers
differ at all. ``--load N`` keeps N CPU-bound processes running beside the rehearsals (the
condition the fix must survive on a small machine); they are ended by their process ids.

    python bench/bench_reproducibility.py [--repeats 5] [--seeds 1,2,3,4,5] [--speedup 50] [--load 2]
        [--full]   # the whole default rehearsal instead of the short one (~1 min a run at 50x)
"""
from __future__ import annotations

import argparse
import json
import logging
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from companion.rehearsal.reproducibility import comparable, differences, numeric_leaves

log = logging.getLogger("bench_reproducibility")

SHORT = ["--axes", "yaw", "--thrusts", "0.7", "--no-steps", "--behaviors", "min-speed"]
#: the figures the table shows (summary paths; absent ones are skipped)
KEY_FIGURES = (".runs[0].a22", ".runs[0].b2", ".runs[0].r2", ".runs[0].converged_s", ".runs[2].a22", ".runs[4].b2",
               ".min_speed.thrust_ratio_final", ".min_speed.settle_time_s", ".min_speed.max_depth_error_m",
               ".roll.std_closed_deg", ".vehicle_time_s")


class RehearsalFailed(RuntimeError):
    pass


def rehearse(seed: int, speedup: float, options: list[str], workdir: Path) -> dict:
    """One ``companion rehearse --json`` in its own directory (same relative --out every time)."""
    workdir.mkdir(parents=True)
    command = [sys.executable, "-m", "companion", "rehearse", "--seed", str(seed), "--speedup", f"{speedup:g}",
               "--json", "--out", "rehearsal", *options]
    done = subprocess.run(command, cwd=workdir, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise RehearsalFailed(f"rehearsal failed ({done.returncode}): {done.stderr[-800:]}")
    return json.loads(done.stdout)


def spread(summaries: list[dict]) -> dict[str, float]:
    """max − min of every number common to all summaries."""
    leaves = [numeric_leaves(comparable(s)) for s in summaries]
    common = set(leaves[0]).intersection(*leaves[1:])
    return {path: max(l[path] for l in leaves) - min(l[path] for l in leaves) for path in common}


def start_load(count: int) -> list[subprocess.Popen]:
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(count)]


def stop_load(hogs: list[subprocess.Popen]) -> None:
    for hog in hogs:  # by process id, each one we started
        hog.terminate()
        hog.wait(timeout=10)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5, help="runs of the first seed")
    parser.add_argument("--seeds", default="1,2,3,4,5", help="seeds, one run each (the first is the repeated one)")
    parser.add_argument("--speedup", type=float, default=50.0)
    parser.add_argument("--load", type=int, default=0, help="CPU-bound processes beside the rehearsals")
    parser.add_argument("--full", action="store_true", help="the whole default rehearsal (default: the short one)")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    seeds = [int(s) for s in args.seeds.split(",")]
    options = [] if args.full else SHORT
    print(f"companion rehearse {' '.join(options)} --speedup {args.speedup:g}; {args.repeats} repeats of seed "
          f"{seeds[0]}, seeds {seeds}; {args.load} CPU-bound processes beside")
    hogs = start_load(args.load)
    repeats: list[dict] = []
    by_seed: list[dict] = []
    walls: list[float] = []
    failures: list[str] = []  # a failed run is a result too: reported, never hidden
    try:
        with tempfile.TemporaryDirectory(prefix="bench-repro-") as tmp:
            for index in range(args.repeats):
                started = time.monotonic()
                try:
                    repeats.append(rehearse(seeds[0], args.speedup, options, Path(tmp) / f"repeat{index}"))
                except RehearsalFailed as exc:
                    failures.append(f"repeat {index + 1}: {exc}")
                    continue
                walls.append(time.monotonic() - started)
                log.info("repeat %d: %.1f s wall", index + 1, walls[-1])
            if repeats:
                by_seed.append(repeats[0])
            for seed in seeds[1:]:
                try:
                    by_seed.append(rehearse(seed, args.speedup, options, Path(tmp) / f"seed{seed}"))
                except RehearsalFailed as exc:
                    failures.append(f"seed {seed}: {exc}")
                    continue
                log.info("seed %d done", seed)
    finally:
        stop_load(hogs)
    for failure in failures:
        print("FAILED", failure[-600:])
    if len(repeats) < 2 or len(by_seed) < 2:
        print("not enough completed runs to compare")
        return 1
    over_repeats, over_seeds = spread(repeats), spread(by_seed)
    print(f"\n{'figure':36s} {'spread over repeats':>20s} {'spread over seeds':>18s}")
    for path in KEY_FIGURES:
        if path in over_repeats and path in over_seeds:
            print(f"{path:36s} {over_repeats[path]:20.3g} {over_seeds[path]:18.3g}")
    differing = [p for p, v in over_repeats.items() if v != 0.0]
    mismatches = [line for other in repeats[1:] for line in differences(comparable(repeats[0]), comparable(other))]
    print(f"\nnumbers in the summary: {len(over_repeats)}; differing over repeats: {len(differing)}; "
          f"over seeds: {sum(1 for v in over_seeds.values() if v != 0.0)}")
    print(f"summaries identical to the first repeat (all fields but wall_time_s): "
          f"{sum(1 for other in repeats[1:] if not differences(comparable(repeats[0]), comparable(other)))} "
          f"of {len(repeats) - 1}")
    print(f"reproducibility records: {[r.get('reproducibility', {}).get('exact') for r in repeats]}")
    print(f"wall time per repeat: {', '.join(f'{w:.1f}' for w in walls)} s")
    for line in mismatches[:20]:
        print("  differs:", line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
