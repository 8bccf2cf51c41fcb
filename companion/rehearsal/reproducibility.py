"""What a rehearsal can say about its own reproducibility ("same seed, same numbers").

On the built-in simulator in lockstep a rehearsal is a function of its seed and options alone: the
same command gives the same summary, bit for bit, apart from ``wall_time_s``
(``tests/test_reproducible.py``, ``bench/bench_reproducibility.py``). That holds only if lockstep
held for the whole run, which the simulator reports at exit (its ``STATS`` line,
``companion.rehearsal.launcher``). This module turns that report into the summary's ``reproducibility``
record: ``exact`` and, when it is not, ``varied`` says what could have varied and why.

A real autopilot (ArduPilot SITL) is never exact: it runs its own scheduler, and when the
companion's commands land in its loops depends on the two processes' timing (README, "Same seed,
same numbers").
"""
from __future__ import annotations

ARDUPILOT_TIMING = ("ArduPilot runs its own scheduler: the vehicle time at which each of the companion's "
                    "commands lands in its loops, and which samples its streams carry, depend on how the "
                    "two processes are scheduled")
PX4_TIMING = ("PX4 runs its own scheduler on the simulator's clock, which is paced on the wall clock: the vehicle "
              "time at which each of the companion's commands lands, and how far the companion lags the stream, "
              "depend on how the processes are scheduled")


def reproducibility_record(autopilot: str, lockstep: bool, simulator_stats: dict | None,
                           snapshots_dropped: int, wall_timeouts: int = 0) -> dict:
    """The summary's ``reproducibility``: ``exact`` (bool), ``varied`` (reasons, empty when exact)
    and the simulator's lockstep record (``engaged_at_s``, ``interruptions``, ``free_ticks``)."""
    if autopilot != "builtin":
        return {"exact": False, "varied": [PX4_TIMING if autopilot.startswith("px4-") else ARDUPILOT_TIMING],
                "lockstep": None}
    varied: list[str] = []
    record = (simulator_stats or {}).get("lockstep") if lockstep else None
    if not lockstep:
        varied.append("the simulator ran without lockstep: it paced vehicle time on the wall clock")
    elif not isinstance(record, dict):
        varied.append("the simulator did not report its lockstep record (it did not exit cleanly)")
        record = None
    else:
        record = {key: record.get(key) for key in ("engaged_at_s", "interruptions", "free_ticks")}
        if record["engaged_at_s"] != 0:
            varied.append(f"lockstep engaged at t = {record['engaged_at_s']} s, not at the start")
        if record["interruptions"]:
            varied.append(f"lockstep was interrupted {record['interruptions']} time(s) (the companion was silent "
                          f"for 30 s of wall clock): {record['free_ticks']} physics ticks ran free, paced on the "
                          "wall clock")
    dropped = (simulator_stats or {}).get("dropped") or 0
    if dropped:
        varied.append(f"the simulator dropped {dropped} frames for a client that fell behind")
    if snapshots_dropped:
        varied.append(f"the companion dropped {snapshots_dropped} unread telemetry snapshots")
    if wall_timeouts:
        varied.append(f"{wall_timeouts} of the companion's waits ended on their wall-clock guard (the vehicle "
                      "clock stalled for seconds: an overloaded machine)")
    return {"exact": not varied, "varied": varied, "lockstep": record}


#: the summary's fields that are wall-clock measurements, not results (everything else must repeat)
WALL_FIELDS = ("wall_time_s",)


def comparable(summary: dict) -> dict:
    """The summary without its wall-clock fields: what two runs of one command must share exactly."""
    return {key: value for key, value in summary.items() if key not in WALL_FIELDS}


def differences(first: object, second: object, path: str = "") -> list[str]:
    """Where two JSON values differ, as ``path: a != b`` lines (exact comparison, no tolerance)."""
    if isinstance(first, dict) and isinstance(second, dict):
        found = []
        for key in sorted(set(first) | set(second), key=str):
            found += differences(first.get(key), second.get(key), f"{path}.{key}")
        return found
    if isinstance(first, list) and isinstance(second, list) and len(first) == len(second):
        found = []
        for index, (a, b) in enumerate(zip(first, second)):
            found += differences(a, b, f"{path}[{index}]")
        return found
    return [] if first == second and type(first) is type(second) else [f"{path or '.'}: {first!r} != {second!r}"]


def numeric_leaves(value: object, path: str = "") -> dict[str, float]:
    """Every number in a JSON value by its path (booleans excluded)."""
    if isinstance(value, dict):
        leaves: dict[str, float] = {}
        for key, item in value.items():
            leaves.update(numeric_leaves(item, f"{path}.{key}"))
        return leaves
    if isinstance(value, list):
        leaves = {}
        for index, item in enumerate(value):
            leaves.update(numeric_leaves(item, f"{path}[{index}]"))
        return leaves
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return {path: float(value)}
    return {}
