"""Faults tried and survived (the fault-injection suite): the matrix fault kind × phase × seed,
one fault per case, each through ``harness.fault_proxy.FaultProxy`` (TCP) or
``harness.udp_relay.UdpRelay`` (UDP) between the companion and a ``--lockstep`` simulator
(``harness/fault_cases.py`` runs and checks a case), over each transport asked for.

A case *survived* when no exception escaped the procedure, the vehicle was found again as it was
(every autopilot parameter, the mode unless the pilot took it, the thrust, the last heading
set-point, no RC override held) and the store passed ``PRAGMA integrity_check`` with every
committed row and a closed campaign row. The seed moves where in its phase the fault starts (0–4
frames after the phase's trigger) and which byte a corruption flips.

Restores are counted twice: **confirmed by state** (what the vehicle held afterwards on a direct
reconnection: every parameter, mode, armed, the thrust it runs at, the heading it steers to, matched
what it was found with) and **claimed** (the companion ended the procedure and its
``restore_problems`` were empty); a restore claimed but not confirmed is the dangerous kind and is
listed.

Columns: ``drop``, ``delay``, ``duplicate``, ``reorder``, ``corrupt`` (bounded to 3 frames of
either direction within 2 s), ``cut`` (silent: every frame dropped for 0.3 s, sockets open) and
``cut-closed`` (the connections close; the companion is accepted again 0.5 s later; over UDP there
is no connection to close: the link is silent for 0.5 s). Prints, per transport, the table of cases
survived / tried, the outcomes, the restores confirmed by state and claimed, the faults that never
met their phase (the run ended first), and for every case that did not survive what failed and the
command that reruns it.

    python bench/bench_faults.py [--transport tcp,udp] [--seeds 2] [--procedures campaign,roll,min_speed]
        [--kinds drop,delay,duplicate,reorder,corrupt,cut,cut-closed] [--speedup 50] [--json]
    python bench/bench_faults.py --case campaign/excitation:drop:seed1 [--transport udp] [-v]   # rerun one case
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

from harness.fault_cases import (CASE_PROCEDURES, FRAME_KINDS, PHASES, TRANSPORTS, Case, CaseResult, run_case,
                                 single_case)
from harness.simulator import SimulatorError, start_sim

log = logging.getLogger("bench_faults")

KINDS = (*FRAME_KINDS, "cut", "cut-closed")
SIM_SEED = 5


def case_for(phase_label: str, kind: str, seed: int) -> Case:
    """The bench's cell ``kind`` at ``phase_label`` with ``seed`` (``cut-closed``: a closing cut)."""
    closed = kind == "cut-closed"
    return single_case(PHASES[phase_label], "cut" if closed else kind, seed, reconnect=closed)


def parse_case(label: str) -> Case:
    """``campaign/excitation:drop:seed1`` → its case."""
    try:
        phase, kind, seed = label.split(":")
        return case_for(phase, kind, int(seed.removeprefix("seed")))
    except (ValueError, KeyError) as exc:
        raise SystemExit(f"--case {label!r}: expected PHASE:KIND:seedN with a phase of {', '.join(PHASES)} "
                         f"and a kind of {', '.join(KINDS)} ({exc})") from None


def matrix(procedures: list[str], kinds: list[str], seeds: int) -> list[tuple[str, str, Case]]:
    """(phase label, kind, case) for every cell and seed, procedure by procedure."""
    return [(label, kind, case_for(label, kind, seed)) for label, phase in PHASES.items()
            if phase.procedure in procedures for kind in kinds for seed in range(seeds)]


class Runner:
    """Runs cases on one simulator of ``transport``, started again if it died."""

    def __init__(self, speedup: float, workdir: Path, transport: str = "tcp") -> None:
        self.speedup, self.workdir, self.transport = speedup, workdir, transport
        self.sim = None
        self.count = 0

    def run(self, case: Case) -> CaseResult:
        if self.sim is None or not self.sim.alive():
            self.close()
            self.sim = start_sim(transport=self.transport, speedup=self.speedup, seed=SIM_SEED, lockstep=True)
        self.count += 1
        try:
            return run_case(self.sim, case, self.workdir / f"store-{self.transport}-{self.count}.sqlite",
                            transport=self.transport)
        except Exception as exc:  # noqa: BLE001 - the harness itself failed (e.g. no simulator): a finding too
            result = CaseResult(case, crash=f"harness: {type(exc).__name__}: {exc}", transport=self.transport,
                                state_problems=["not checked: the harness failed"])
            self.close()  # the vehicle may be left in any state: the next case gets a fresh simulator
            return result

    def close(self) -> None:
        if self.sim is not None:
            self.sim.stop()
            self.sim = None


def table(rows: list[tuple[str, str, CaseResult]], kinds: list[str]) -> str:
    """Survived / tried per phase and kind, with totals."""
    cells: dict[tuple[str, str], list[CaseResult]] = {}
    for label, kind, result in rows:
        cells.setdefault((label, kind), []).append(result)
    phases = list(dict.fromkeys(label for label, _, _ in rows))
    width = max(len(p) for p in phases + ["total"]) + 2
    lines = [f"{'phase':<{width}}" + "".join(f"{k:>12}" for k in kinds) + f"{'all':>10}"]
    for label in phases:
        line = f"{label:<{width}}"
        for kind in kinds:
            results = cells.get((label, kind), [])
            line += f"{_ratio(results):>12}"
        line += f"{_ratio([r for (p, _), rs in cells.items() if p == label for r in rs]):>10}"
        lines.append(line)
    total = f"{'total':<{width}}" + "".join(f"{_ratio([r for (_, k), rs in cells.items() if k == kind for r in rs]):>12}"
                                            for kind in kinds)
    lines.append(total + f"{_ratio([r for _, _, r in rows]):>10}")
    return "\n".join(lines)


def _ratio(results: list[CaseResult]) -> str:
    return f"{sum(r.survived for r in results)}/{len(results)}" if results else "-"


def report(rows: list[tuple[str, str, CaseResult]], kinds: list[str], wall_s: float, transport: str = "tcp") -> str:
    results = [r for _, _, r in rows]
    outcomes = Counter(r.status or "crash" for r in results)
    fired = sum(1 for r in results if not r.untriggered)
    confirmed = sum(r.restored_by_state for r in results)
    claimed = sum(r.restore_claimed for r in results)
    untrue = [r for r in results if r.restore_claimed and not r.restored_by_state]
    lines = [f"== {transport.upper()} ==", table(rows, kinds), "",
             f"{len(results)} cases, {sum(r.survived for r in results)} survived (no crash, vehicle restored, store "
             f"intact); outcomes: " + ", ".join(f"{k} {v}" for k, v in sorted(outcomes.items())),
             f"restores confirmed by state: {confirmed} of {len(results)} (the vehicle held what it was found with); "
             f"claimed by the companion (restore_problems empty): {claimed} of {len(results)}; claimed but not "
             f"confirmed: {len(untrue)}",
             f"the fault met its phase in {fired} of {len(results)} cases; the companion broke "
             f"{sum(r.wall_decisions for r in results)} lockstep stalls; {wall_s:.0f} s wall"]
    for result in results:
        if result.untriggered:
            lines.append(f"  never met its phase: {result.case.label} ({result.status}: {result.reason})")
    rerun = f" --transport {transport}" if transport != "tcp" else ""
    for result in results:
        if not result.survived:
            lines.append(f"NOT SURVIVED {result.case.label}: {result.status} ({result.reason})"
                         + (" [restore claimed, state differs]" if result in untrue else ""))
            lines += [f"    {p}" for p in result.problems]
            if result.restore_problems:
                lines.append(f"    the companion said: {result.restore_problems}")
            if result.crash:
                lines.append(f"    crash: {result.crash.splitlines()[0]}")
            lines.append(f"    rerun: python bench/bench_faults.py --case {result.case.label}{rerun} -v")
    return "\n".join(lines)


def run_matrix(cells: list[tuple[str, str, Case]], transport: str, speedup: float, workdir: Path,
               as_json: bool) -> list[tuple[str, str, CaseResult]]:
    """Every cell over one transport, on one simulator (started again if it died)."""
    rows: list[tuple[str, str, CaseResult]] = []
    runner = Runner(speedup, workdir, transport)
    try:
        for number, (label, kind, case) in enumerate(cells, start=1):
            result = runner.run(case)
            rows.append((label, kind, result))
            if as_json:
                print(json.dumps({"transport": transport, "case": case.label, "survived": result.survived,
                                  "status": result.status, "reason": result.reason, "problems": result.problems,
                                  "state_problems": result.state_problems, "crash": result.crash,
                                  "restored_by_state": result.restored_by_state,
                                  "restore_claimed": result.restore_claimed,
                                  "restore_problems": result.restore_problems, "faults": result.faults,
                                  "before": result.before, "after": result.after, "link": result.link,
                                  "wall_s": round(result.wall_s, 2)}), flush=True)
            else:
                print(f"[{transport} {number}/{len(cells)}] {case.label}: "
                      f"{'survived' if result.survived else 'NOT SURVIVED'}"
                      f" ({result.status}{': ' + result.reason if result.reason else ''})"
                      + "".join(f"\n    {p}" for p in result.problems), file=sys.stderr, flush=True)
    finally:
        runner.close()
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--transport", default="tcp", help="tcp, udp or both: tcp,udp (default: %(default)s)")
    parser.add_argument("--seeds", type=int, default=2)
    parser.add_argument("--procedures", default=",".join(CASE_PROCEDURES))
    parser.add_argument("--kinds", default=",".join(KINDS))
    parser.add_argument("--speedup", type=float, default=50.0)
    parser.add_argument("--case", help="rerun one case, e.g. campaign/excitation:drop:seed1")
    parser.add_argument("--json", action="store_true", help="one JSON object per case instead of the table")
    parser.add_argument("-v", "--verbose", action="store_true")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.CRITICAL, stream=sys.stderr,
                        format="%(relativeCreated)8.0f %(name)s %(levelname)s %(message)s")
    kinds = [k for k in args.kinds.split(",") if k]
    unknown = set(kinds) - set(KINDS)
    if unknown:
        parser.error(f"unknown kinds {sorted(unknown)} (known: {', '.join(KINDS)})")
    transports = [t for t in args.transport.split(",") if t]
    if not transports or set(transports) - set(TRANSPORTS):
        parser.error(f"--transport: one or more of {', '.join(TRANSPORTS)}, not {args.transport!r}")
    if args.case:
        label = args.case.split(":")
        cells = [(label[0], label[1] if len(label) > 1 else "?", parse_case(args.case))]
    else:
        cells = matrix([p for p in args.procedures.split(",") if p], kinds, args.seeds)
    reports = []
    with tempfile.TemporaryDirectory(prefix="bench-faults-") as workdir:
        for transport in transports:
            started = time.monotonic()
            try:
                rows = run_matrix(cells, transport, args.speedup, Path(workdir), args.json)
            except SimulatorError as exc:
                print(f"simulator did not start: {exc}", file=sys.stderr)
                return 1
            reports.append(report(rows, list(dict.fromkeys(kind for _, kind, _ in rows)), time.monotonic() - started,
                                  transport))
    if not args.json:
        print("\n\n".join(reports))
    return 0  # a benchmark prints figures, it does not pass or fail


if __name__ == "__main__":
    sys.exit(main())
