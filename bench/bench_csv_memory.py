"""Peak memory of reading (and analysing) a large navigation CSV, relative to the file's size.

Writes a CSV of ``--rows`` rows (the ten navigation columns of ``companion analyze``, values with
9 significant digits, a straight run with a slow heading drift), then, in a fresh child process
each, measures the peak resident set size (``VmHWM``) of:

* ``read``: :func:`companion.records.logs.read_log` alone;
* ``squares`` (with ``--analyze``): the whole ``companion analyze squares --json --no-cut``.

The child's RSS after its imports (before the file is opened) is the baseline; the figures printed
are peak RSS, peak minus baseline, and both divided by the file size. Prints figures, never pass/fail.

    .venv/bin/python bench/bench_csv_memory.py [--rows 2000000] [--analyze] [--keep FILE]
"""
from __future__ import annotations

import argparse
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
    with contextlib.redirect_stdout(io.StringIO()):
        code = main(["analyze", "squares", "--input", sys.argv[1], "--json", "--no-cut"])
    assert code == 0, code
print(baseline, rss("VmHWM:"))
"""


def write_csv(path: str, rows: int, block: int = 200_000) -> None:
    """A long straight run (1.5 m/s, heading drifting slowly, small noise) at 10 Hz, in blocks."""
    rng = np.random.default_rng(1)
    with open(path, "w", encoding="utf-8") as handle:
        handle.write(",".join(COLUMNS) + "\n")
        for start in range(0, rows, block):
            n = min(block, rows - start)
            t = (start + np.arange(n)) * 0.1
            yaw = 0.3 + 1e-5 * t
            data = np.column_stack([
                t, 1.5 * t * np.cos(yaw), 1.5 * t * np.sin(yaw), 2.0 + rng.normal(0, 0.01, n),
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
    parser.add_argument("--keep", metavar="FILE", help="write (or reuse) the CSV here instead of a temporary file")
    args = parser.parse_args()
    folder = tempfile.mkdtemp(prefix="bench_csv_")
    path = args.keep or os.path.join(folder, "big.csv")
    if not os.path.exists(path):
        write_csv(path, args.rows)
    size = os.path.getsize(path)
    print(f"file: {args.rows} rows x {len(COLUMNS)} columns, {size / 1e6:.1f} MB")
    for what in ("read", "squares") if args.analyze else ("read",):
        baseline, peak, wall = measure(path, what)
        print(f"{what:8s}: peak RSS {peak / 1e6:7.1f} MB = {peak / size:.2f} x file; above the "
              f"{baseline / 1e6:.0f} MB after imports: {(peak - baseline) / 1e6:7.1f} MB = "
              f"{(peak - baseline) / size:.2f} x file; {wall:.1f} s")
    if not args.keep:
        os.remove(path)
        os.rmdir(folder)


if __name__ == "__main__":
    main()
