"""One sweep case: ``companion rehearse --json`` in a child process, reduced to one summary row.

Each case is isolated: its own child process (``python -m companion rehearse``), its own temporary
directory (its store, summary and the simulator's log), its own simulator on a port the system
picks (the launcher binds port 0) and its own log file (the child's stderr). So a case that
crashes, hangs or leaks cannot disturb another, and a case runs exactly the command that reproduces
it alone (:meth:`companion.sweep.spec.Case.command`). The child runs in a session of its own: a
Ctrl-C at the terminal reaches the sweep, which stops its cases through ``should_stop``; a stopped
case gets SIGINT (the rehearsal aborts and restores as for a user's Ctrl-C), then SIGKILL after a
grace period.

:func:`row_from_summary` is the one reduction of a rehearsal summary to a row: the sweep applies it
to its cases and a test to a single ``companion rehearse`` of the same case.
"""
from __future__ import annotations

import json
import logging
import math
import os
import re
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from companion.procedures.registry import sweep_columns, sweep_row
from companion.sweep.spec import Case

log = logging.getLogger(__name__)

#: case statuses: the rehearsal's own (completed/failed/aborted), ``error`` when it gave no summary
#: (it could not run, crashed or timed out), ``stopped`` when the sweep was interrupted (not recorded)
STOPPED = "stopped"
ERROR = "error"
#: seconds a stopped or timed-out case has to abort and restore after SIGINT before SIGKILL
GRACE_S = 30.0


@dataclass(frozen=True)
class CaseOptions:
    """How a case runs (not part of its inputs: none of these change its numbers)."""

    speedup: float = 50.0
    timeout_s: float = 1800.0
    #: keep the case's files under ``keep_dir/<key>`` (on the machine that ran it); None: delete them
    keep_dir: str | None = None
    poll_s: float = 0.5  # how often a running case looks at ``should_stop`` and its deadline


@dataclass
class CaseResult:
    """What one case gave: its row (inputs, outcome, figures), the rehearsal's summary (None without
    one), where it ran and the tail of its log."""

    key: str
    status: str
    reason: str | None
    row: dict
    summary: dict | None = None
    host: str = ""
    wall_s: float = 0.0
    log_tail: str = ""
    extra: dict = field(default_factory=dict)

    @property
    def finished(self) -> bool:
        """Whether the case ran to an outcome worth recording (a stopped case is run again on resume)."""
        return self.status != STOPPED


def _finite(value) -> float | None:
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) \
        and math.isfinite(value) else None


def _rel_error_pct(value, truth) -> float | None:
    value, truth = _finite(value), _finite(truth)
    if value is None or truth is None or truth == 0:
        return None
    return 100.0 * abs(value - truth) / abs(truth)


def _max(values) -> float | None:
    values = [v for v in values if v is not None]
    return max(values) if values else None


def _min(values) -> float | None:
    values = [v for v in values if v is not None]
    return min(values) if values else None


def _median(values) -> float | None:
    values = [v for v in values if v is not None]
    return statistics.median(values) if values else None


def failure_kind(reason: str | None) -> str | None:
    """A reason without its numbers and quoted names, so like failures group together (the report's
    failure rate by reason): "simulator did not start (preset 'nope'): …" → "simulator did not start"."""
    if not reason:
        return None
    text = reason.split(": ", 1)[0]
    text = re.sub(r"\s*\([^)]*\)", "", text)
    text = re.sub(r"'[^']*'|\"[^\"]*\"", "…", text)
    text = re.sub(r"[-+]?\d+(\.\d+)?(e[-+]?\d+)?", "#", text)
    return text.strip()[:120] or "unknown"


#: the campaign's figure columns, in order; each procedure's follow (its registry entry's), then
#: :data:`CLOSING` (inputs and outcome come first, :func:`row_from_summary`, :func:`figure_columns`)
CAMPAIGN_FIGURES = (
    "models", "a22_error_max_pct", "a22_error_median_pct", "b2_error_max_pct", "b2_error_median_pct",
    "r2_min", "r2_median", "converged_max_s",
    "overshoot_scheduled_max_pct", "overshoot_constant_max_pct", "overshoot_original_max_pct",
)
CLOSING = ("exact", "vehicle_time_s")


def figure_columns() -> tuple[str, ...]:
    """The row's figure columns, in order: the campaign's, every registered procedure's, the closing ones."""
    return CAMPAIGN_FIGURES + sweep_columns() + CLOSING


def row_from_summary(case: Case, summary: dict | None, status: str | None = None, reason: str | None = None) -> dict:
    """One flat row: the case's inputs, its outcome (``status``, ``reason``, ``failure``) and its
    figures from the rehearsal's summary (None where the summary has none). Wall-clock figures are
    not in the row (they differ between two runs of one case); the sweep records them beside it."""
    summary = summary or {}
    inputs = case.inputs()
    row: dict = {"case_key": case.key, **{k: v for k, v in inputs.items() if k != "perturb"},
                 "perturb": " ".join(f"{name}={factor:g}" for name, factor in case.perturb), "quick": case.quick}
    for name, factor in case.perturb:
        row[f"perturb_{name}"] = factor
    row["thrusts"] = " ".join(f"{t:g}" for t in case.thrusts)
    for key in ("axes", "behaviors", "schedules"):
        row[key] = ",".join(inputs[key]) or "none"
    status = status or summary.get("status") or ERROR
    reason = reason if reason is not None else summary.get("reason")
    row.update(status=status, reason=reason, failure=failure_kind(reason) if status != "completed" else None)

    runs = summary.get("runs") or []
    a22 = [_rel_error_pct(r.get("a22"), r.get("true_a22")) for r in runs]
    b2 = [_rel_error_pct(r.get("b2"), r.get("true_b2")) for r in runs]
    r2 = [_finite(r.get("r2")) for r in runs]
    row.update(models=len(runs), a22_error_max_pct=_max(a22), a22_error_median_pct=_median(a22),
               b2_error_max_pct=_max(b2), b2_error_median_pct=_median(b2), r2_min=_min(r2), r2_median=_median(r2),
               converged_max_s=_max(_finite(r.get("converged_s")) for r in runs))
    steps = summary.get("heading_steps") or []
    for label in ("scheduled", "constant", "original"):
        row[f"overshoot_{label}_max_pct"] = _max(_finite(s.get("max_overshoot_pct")) for s in steps
                                                 if s.get("label") == label)

    row.update(sweep_row(summary))
    row.update(exact=(summary.get("reproducibility") or {}).get("exact"),
               vehicle_time_s=_finite(summary.get("vehicle_time_s")))
    return row


def _tail(path: Path, limit: int = 2000) -> str:
    try:
        return path.read_text(errors="replace")[-limit:]
    except OSError:
        return ""


def _error_reason(stderr: str, returncode: int | None) -> str:
    """The rehearsal's own one-sentence error (its last ``error:`` line), else the exit code and the last line."""
    lines = [line.strip() for line in stderr.splitlines() if line.strip()]
    for line in reversed(lines):
        match = re.search(r"(?:^|: )error: (.*)$", line)
        if match:
            return match.group(1)
    last = lines[-1] if lines else "no output"
    return f"the rehearsal exited with code {returncode} without a summary: {last}"[:500]


def _end(process: subprocess.Popen, grace_s: float) -> None:
    """SIGINT (the rehearsal aborts and restores), then SIGKILL of its whole session after ``grace_s``."""
    if process.poll() is not None:
        return
    try:
        os.killpg(process.pid, signal.SIGINT)
        process.wait(timeout=grace_s)
    except subprocess.TimeoutExpired:
        try:
            os.killpg(process.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        process.wait()
    except ProcessLookupError:
        pass


def run_case(case: Case, options: CaseOptions = CaseOptions(),
             should_stop: Callable[[], bool] | None = None) -> CaseResult:
    """Run one case to its row. Never raises for a case that fails: the failure is the result."""
    started = time.monotonic()
    host = socket.gethostname()
    keep = Path(options.keep_dir) / case.key[:16] if options.keep_dir else None
    if keep is not None:
        shutil.rmtree(keep, ignore_errors=True)
        keep.mkdir(parents=True)
        workdir = keep
    else:
        workdir = Path(tempfile.mkdtemp(prefix=f"sweep-{case.key[:12]}-"))
    out = workdir / "rehearsal"
    command = [sys.executable, "-m", "companion", "rehearse", *case.rehearse_args(),
               "--speedup", repr(float(options.speedup)), "--json", "--no-report", "--out", str(out)]
    log_path, stdout_path = workdir / "companion.log", workdir / "summary.out"
    status, reason, summary = None, None, None
    try:
        with open(log_path, "w") as err, open(stdout_path, "w") as std:
            log.info("case %s: %s", case.key[:12], " ".join(command))
            process = subprocess.Popen(command, cwd=workdir, stdout=std, stderr=err, stdin=subprocess.DEVNULL,
                                       start_new_session=True,
                                       env={**os.environ, "PYTHONUNBUFFERED": "1", "MPLBACKEND": "Agg"})
            deadline = started + options.timeout_s
            try:
                while process.poll() is None:
                    try:
                        process.wait(timeout=options.poll_s)
                    except subprocess.TimeoutExpired:
                        pass
                    if process.poll() is not None:
                        break
                    if should_stop is not None and should_stop():
                        status, reason = STOPPED, "the sweep was stopped"
                        _end(process, GRACE_S)
                    elif time.monotonic() > deadline:
                        status, reason = ERROR, f"timed out after {options.timeout_s:g} s"
                        _end(process, GRACE_S)
            finally:  # an exception here (e.g. the worker shutting down) must not leave the child running
                _end(process, 5.0)
        log_text = _tail(log_path, 20000)
        if status is None:
            try:
                summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
            except (OSError, ValueError):
                summary = None
            if summary is None:
                status, reason = ERROR, _error_reason(log_text, process.returncode)
    except OSError as exc:  # the child could not even start (no such interpreter, no temp space)
        status, reason, log_text = ERROR, f"the case could not start: {exc}", ""
    finally:
        if keep is None:
            shutil.rmtree(workdir, ignore_errors=True)
    row = row_from_summary(case, summary, status, reason)
    return CaseResult(key=case.key, status=row["status"], reason=row["reason"], row=row, summary=summary, host=host,
                      wall_s=round(time.monotonic() - started, 3), log_tail=log_text[-2000:])
