"""Peak memory of reading (and analysing) a large navigation CSV, relative to the file's size.

Writes a CSV of ``--rows`` rows (the ten navigation columns of ``companion analyze``, values with
9 significant digits, a straight run with a slow heading drift), then, in a fresh child process
each, measures the peak resident set size (``VmHWM``) of:

* ``read``: :func:`companion.records.logs.read_log` alone;
* ``squares`` and ``squares-cut`` (with ``--analyze``): the whole ``companion analyze squares --json``,
  with ``--no-cut`` and with its default transient cutting;
* ``turns`` (with ``--analyze``): the whole ``companion analyze turns --json`` on a second file of
  ``--turn-rows`` rows, one slow steady turn (the turn fit scans 121 rates over every sample, so its
  time, not its memory, grows fastest with the length: 200 000 rows take ~30 s).

The child's RSS after its imports (before the file is opened) is the baseline; the figures printed
are peak RSS, peak minus baseline, and both divided by the file size. Prints figures, never pass/fail.

    .venv/bin/python bench/bench_csv_memory.py [--rows 2000000] [--analyze] [--turn-rows 200000] [--keep FILE]
"""
from __future__ import annotations

import argparse
import math
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

COLUMNS = ("t", "north", "east", "down", "roll", "pitch", "yaw", "u", "v", "w")

CHILD = r"""
import sys

def rss(field):
    with open("/proc/self/status") as status:
        for line in status:
            if line.startswith(field):
                return int(line.split()[1]) * 1024
from companion.records.logs import read_log
from companion.cli.main import main
import companion.cli.commands.analyze  # noqa: F401 - imported before the baseline
baseline = rss("VmRSS:")
if sys.argv[2] == "read":
    nav = read_log(sys.argv[1])
    assert len(nav) > 0
else:
    import contextlib, io
    kind = "turns" if sys.argv[2] == "turns" else "squares"
    cut = ["--no-cut"] if sys.argv[2] == "squares" else []
    with contextlib.redirect_stdout(io.StringIO()):
        code = main(["analyze", kind, "--input", sys.argv[1], "--json", *cut])
    assert code == 0, code
print(baseline, rss("VmHWM:"))
"""


def write_csv(path: str, rows: int, turn_rate: float = 0.0, block: int = 200_000) -> None:
    """A run at 1.5 m/s and 10 Hz, small noise on every column, written in blocks: nearly straight
    (the heading drifts 1e-5 rad/s) or, with ``turn_rate`` (rad/s), one steady turn."""
    rng = np.random.default_rng(1)
    with open(path, "w", encoding="utf-8") as handle:
        handle.write(",".join(COLUMNS) + "\n")
        for start in range(0, rows, block):
            n = min(block, rows - start)
            t = (start + np.arange(n)) * 0.1
            if turn_rate:
                heading = 0.3 + turn_rate * t
                yaw = np.arctan2(np.sin(heading), np.cos(heading))
                north, east = 1.5 / turn_rate * np.sin(heading), -1.5 / turn_rate * np.cos(heading)
            else:
                yaw = 0.3 + 1e-5 * t
                north, east = 1.5 * t * np.cos(yaw), 1.5 * t * np.sin(yaw)
            data = np.column_stack([
                t, north + rng.normal(0, 0.05, n), east + rng.normal(0, 0.05, n), 2.0 + rng.normal(0, 0.01, n),
                rng.normal(0, 0.002, n), rng.normal(0, 0.002, n), yaw + rng.normal(0, 0.001, n),
                1.5 + rng.normal(0, 0.01, n), rng.normal(0, 0.01, n), rng.normal(0, 0.005, n)])
            np.savetxt(handle, data, fmt="%.9g", delimiter=",")


def measure(path: str, what: str) -> tuple[int, int, float]:
    """(baseline RSS, peak RSS, wall seconds) of one child reading/analysing ``path``."""
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", CHILD, path, what], capture_output=True, text=True, check=True)
    baseline, peak = (int(v) for v in done.stdout.split())
    return baseline, peak, time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rows", type=int, default=2_000_000)
    parser.add_argument("--analyze", action="store_true", help="also measure `companion analyze squares`")
    parser.add_argument("--turn-rows", type=int, default=200_000, help="rows of the turn file (--analyze)")
    parser.add_argument("--keep", metavar="FILE", help="write (or reuse) the CSV here instead of a temporary file")
    args = parser.parse_args()
    folder = tempfile.mkdtemp(prefix="bench_csv_")
    path = args.keep or os.path.join(folder, "big.csv")
    if not os.path.exists(path):
        write_csv(path, args.rows)
    size = os.path.getsize(path)
    print(f"file: {args.rows} rows x {len(COLUMNS)} columns, {size / 1e6:.1f} MB")
    for what in ("read", "squares", "squares-cut") if args.analyze else ("read",):
        report(what, path, size)
    if args.analyze:
        turn_path = os.path.join(folder, "turn.csv")
        write_csv(turn_path, args.turn_rows, turn_rate=math.radians(1.0))
        turn_size = os.path.getsize(turn_path)
        print(f"turn file: {args.turn_rows} rows, {turn_size / 1e6:.1f} MB")
        report("turns", turn_path, turn_size)
        os.remove(turn_path)
    if not args.keep:
        os.remove(path)
    os.rmdir(folder)


def report(what: str, path: str, size: int) -> None:
    baseline, peak, wall = measure(path, what)
    print(f"{what:11s}: peak RSS {peak / 1e6:7.1f} MB = {peak / size:.2f} x file; above the "
          f"{baseline / 1e6:.0f} MB after imports: {(peak - baseline) / 1e6:7.1f} MB = "
          f"{(peak - baseline) / size:.2f} x file; {wall:.1f} s")


if __name__ == "__main__":
    main()
