"""The README's test command on a busy machine: the whole suite beside ``--busy`` CPU-bound processes
(two by default, on this 2-core machine: every core already taken), and its wall time beside the same
suite on the idle machine (``--idle`` too).

    python bench/bench_suite_under_load.py            # under load only
    python bench/bench_suite_under_load.py --idle     # idle first, then under load

The busy processes are ``python -c 'while True: pass'``, started here and stopped here by their PIDs.
It prints the pytest summary line and the wall time of each run and exits with the suite's exit code
under load (a benchmark: the numbers are for docs/development.md, nothing here judges them).
"""
from __future__ import annotations

import argparse
import logging
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
log = logging.getLogger("bench_suite_under_load")


def run_suite(extra: list[str], keep: Path | None = None) -> tuple[int, float, str]:
    """The README's test command (pytest -q, its configured two workers); (exit code, wall s, summary)."""
    started = time.monotonic()
    done = subprocess.run([sys.executable, "-m", "pytest", "-q", *extra], cwd=ROOT, capture_output=True, text=True)
    wall = time.monotonic() - started
    if keep is not None:  # the whole output, for a failure's traceback
        keep.parent.mkdir(parents=True, exist_ok=True)
        keep.write_text(done.stdout + done.stderr)
    lines = [line for line in done.stdout.splitlines() if line.strip()]
    summary = lines[-1] if lines else done.stderr[-500:]
    if done.returncode != 0:
        failures = [line for line in done.stdout.splitlines() if line.startswith(("FAILED", "ERROR"))]
        for line in failures:
            log.warning("%s", line)
    return done.returncode, wall, summary


def main() -> int:
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--busy", type=int, default=2, help="CPU-bound processes beside the suite (default 2)")
    parser.add_argument("--idle", action="store_true", help="run the suite on the idle machine first")
    parser.add_argument("--keep", type=Path, default=None,
                        help="write each run's whole output to DIR/idle.txt and DIR/busy.txt")
    parser.add_argument("pytest_args", nargs="*", help="extra pytest arguments (default: none, the README's command)")
    args = parser.parse_args()
    if args.idle:
        code, wall, summary = run_suite(args.pytest_args, args.keep / "idle.txt" if args.keep else None)
        log.info("idle: %s in %.0f s of wall time (exit %d)", summary, wall, code)
    busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(args.busy)]
    try:
        code, wall, summary = run_suite(args.pytest_args, args.keep / "busy.txt" if args.keep else None)
    finally:
        for process in busy:
            process.kill()
            process.wait()
    log.info("beside %d busy processes: %s in %.0f s of wall time (exit %d)", args.busy, summary, wall, code)
    return code


if __name__ == "__main__":
    sys.exit(main())
