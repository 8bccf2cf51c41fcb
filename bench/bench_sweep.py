"""Sweep throughput on Dask: cases per minute with 1 and 2 local workers, and the per-task
overhead of the engine against running the very same cases in a plain loop.

The cases are those ``companion sweep`` runs (one isolated ``companion rehearse`` child process each,
:func:`companion.sweep.case.run_case`). Three ways, repeated ``--repeats`` times in turn:

* **loop** — ``run_case`` on each case one after the other, in this process: no engine at all;
* **dask 1** — the same cases through :class:`companion.sweep.engine.SweepRun` on a local Dask cluster
  of 1 worker (recording each row to a store and the CSV, as a sweep does);
* **dask 2** — the same on 2 workers.

The cluster's start-up is timed apart from the tasks. Printed: wall time, cases per minute, the
2-worker speed-up over 1 worker (goal ≥ 1.7× on 2 cores), and the engine's overhead per task,
(dask 1 − loop) / cases, absolute and relative to a case (goal ≤ 5 %): in wall time, in CPU time
(this process and every child it waited for: the cases, their simulators) and in the CPU time of
this process alone — the engine itself (scheduler, workers, recording) against the bare loop, the
one figure the rest of the machine hardly moves. The load average is printed too: on a shared
machine other processes take cores, and the wall-clock figures move with them.

    python bench/bench_sweep.py [--cases 8] [--repeats 2] [--speedup 50] [--full]
"""
from __future__ import annotations

import argparse
import logging
import os
import resource
import statistics
import sys
import tempfile
import time
from pathlib import Path

from companion.sweep.case import CaseOptions, run_case
from companion.sweep.engine import DaskEngine, SweepProgress, SweepRecorder, SweepRun
from companion.sweep.spec import spec_from_dict

#: a short case: yaw at two thrusts, no step checks, no behaviours (~85 s of vehicle time each)
SHORT = {"axes": "yaw", "thrusts": [[0.7, 0.9]], "steps": False, "behaviors": "none"}


def cpu_s() -> float:
    """CPU seconds of this process and of every child process it waited for (and theirs)."""
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own_cpu_s() + children.ru_utime + children.ru_stime


def own_cpu_s() -> float:
    """CPU seconds of this process alone: the engine (scheduler, workers, recording) or the loop."""
    own = resource.getrusage(resource.RUSAGE_SELF)
    return own.ru_utime + own.ru_stime


def loop(cases, options) -> tuple[float, list[str]]:
    started = time.monotonic()
    results = [run_case(case, options) for case in cases]
    wall = time.monotonic() - started
    say_failures("loop", [result.row for result in results])
    return wall, [result.status for result in results]


def say_failures(way: str, rows: list[dict]) -> None:
    for row in rows:
        if row["status"] != "completed":
            print(f"  ({way}: seed {row['seed']} {row['status']}: {row['reason']})", flush=True)


def on_dask(cases, options, workers: int) -> tuple[float, float, list[str]]:
    """(cluster start-up s, tasks s, statuses) of one sweep run on a fresh local cluster and store."""
    with tempfile.TemporaryDirectory(prefix="bench-sweep-") as tmp, \
            SweepRecorder(Path(tmp) / "s.sqlite", Path(tmp) / "s.csv", "bench", cases) as recorder:
        run = SweepRun(cases, recorder, options, SweepProgress(total=len(cases)))
        started = time.monotonic()
        with DaskEngine(workers=workers) as engine:
            up = time.monotonic() - started
            started = time.monotonic()
            outcome = run.run(engine)
            tasks = time.monotonic() - started
        rows = recorder.rows()
        statuses = [row["status"] for row in rows]
        say_failures(f"dask {workers}", rows)
    assert outcome.ran == len(cases), outcome
    return up, tasks, statuses


def _nothing(index: int) -> int:
    return index


def round_trip_ms(tasks: int = 200) -> float:
    """Milliseconds per task of the engine's own path (submit, wait for the first finished, result)
    with tasks that do nothing, one local worker: what Dask adds to each case, without the case."""
    with DaskEngine(workers=1) as engine:
        started = time.monotonic()
        pending = {engine.client.submit(_nothing, i, pure=False) for i in range(tasks)}
        while pending:
            done, pending = engine.wait_any(pending, timeout_s=0.5)
            for future in done:
                future.result()
        return 1000 * (time.monotonic() - started) / tasks


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=8, help="cases per run (seeds 1..N; default %(default)s)")
    parser.add_argument("--repeats", type=int, default=2, help="repeats of the three ways (default %(default)s)")
    parser.add_argument("--speedup", type=float, default=50.0, help="speed-up of every case (default %(default)s)")
    parser.add_argument("--full", action="store_true", help="the whole default rehearsal per case (~1 min at 50x)")
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING)
    import distributed  # noqa: F401 - quieten the cluster's start/stop chatter after its own set-up

    logging.getLogger("distributed").setLevel(logging.WARNING)

    spec = spec_from_dict({"name": "bench", "seeds": f"1..{args.cases}", **({} if args.full else SHORT)})
    cases = spec.cases()
    options = CaseOptions(speedup=args.speedup, timeout_s=3600)
    print(f"{len(cases)} cases ({'full rehearsal' if args.full else 'yaw at 0.7 and 0.9, no steps, no behaviours'}) "
          f"at {args.speedup:g}x, {os.cpu_count()} cores; load average before {os.getloadavg()[0]:.2f}")
    times: dict[str, list[float]] = {"loop": [], "dask 1": [], "dask 2": []}
    cpu: dict[str, list[float]] = {"loop": [], "dask 1": [], "dask 2": []}
    own: dict[str, list[float]] = {"loop": [], "dask 1": [], "dask 2": []}
    startups: dict[str, list[float]] = {"dask 1": [], "dask 2": []}
    for repeat in range(args.repeats):
        before, before_own = cpu_s(), own_cpu_s()
        wall, statuses = loop(cases, options)
        times["loop"].append(wall)
        cpu["loop"].append(cpu_s() - before)
        own["loop"].append(own_cpu_s() - before_own)
        print(f"repeat {repeat + 1}: loop    {wall:7.1f} s wall, {cpu['loop'][-1]:6.1f} s CPU  "
              f"({statuses.count('completed')}/{len(cases)} completed; load {os.getloadavg()[0]:.1f})", flush=True)
        for workers in (1, 2):
            before, before_own = cpu_s(), own_cpu_s()
            up, wall, statuses = on_dask(cases, options, workers)
            times[f"dask {workers}"].append(wall)
            cpu[f"dask {workers}"].append(cpu_s() - before)
            own[f"dask {workers}"].append(own_cpu_s() - before_own)
            startups[f"dask {workers}"].append(up)
            print(f"repeat {repeat + 1}: dask {workers}  {wall:7.1f} s wall, {cpu[f'dask {workers}'][-1]:6.1f} s CPU  "
                  f"(+ {up:.1f} s cluster start-up; {statuses.count('completed')}/{len(cases)} completed; "
                  f"load {os.getloadavg()[0]:.1f})", flush=True)
    print(f"load average after {os.getloadavg()[0]:.2f}\n")
    median = {way: statistics.median(values) for way, values in times.items()}
    median_cpu = {way: statistics.median(values) for way, values in cpu.items()}
    median_own = {way: statistics.median(values) for way, values in own.items()}
    print(f"{'way':8} {'median s':>9} {'min s':>7} {'max s':>7} {'cases/min':>10} {'s/case':>7} {'CPU s/case':>11} "
          f"{'own CPU ms/case':>16}")
    for way, values in times.items():
        print(f"{way:8} {median[way]:9.1f} {min(values):7.1f} {max(values):7.1f} "
              f"{60 * len(cases) / median[way]:10.2f} {median[way] / len(cases):7.2f} "
              f"{median_cpu[way] / len(cases):11.2f} {1000 * median_own[way] / len(cases):16.0f}")
    speedup = median["dask 1"] / median["dask 2"]
    per_task = (median["dask 1"] - median["loop"]) / len(cases)
    relative = per_task / (median["loop"] / len(cases))
    per_task_cpu = (median_cpu["dask 1"] - median_cpu["loop"]) / len(cases)
    relative_cpu = per_task_cpu / (median_cpu["loop"] / len(cases))
    print(f"\nthroughput, 2 workers over 1: {speedup:.2f}x (goal >= 1.7x)")
    per_task_own = (median_own["dask 1"] - median_own["loop"]) / len(cases)
    print(f"engine overhead per task (dask 1 - loop), goal <= 5 % of a case:\n"
          f"  wall           {per_task * 1000:+6.0f} ms = {100 * relative:+5.1f} %\n"
          f"  CPU, all       {per_task_cpu * 1000:+6.0f} ms = {100 * relative_cpu:+5.1f} %\n"
          f"  CPU, engine    {per_task_own * 1000:+6.0f} ms = "
          f"{100 * per_task_own / (median_cpu['loop'] / len(cases)):+5.1f} % (this process alone)")
    trip = round_trip_ms()
    print(f"  engine path    {trip:6.1f} ms per task with no-op tasks = "
          f"{100 * trip / 1000 / (median['loop'] / len(cases)):+5.2f} % of a case (wall)")
    print(f"cluster start-up (once per sweep): {statistics.median(startups['dask 1']):.1f} s (1 worker), "
          f"{statistics.median(startups['dask 2']):.1f} s (2 workers)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
