"""Running a sweep: the cases on a ``dask.distributed`` cluster, every finished row recorded at once.

* **Engine.** :class:`DaskEngine` starts a local cluster on this machine (one single-threaded worker
  per core by default, bound to 127.0.0.1, nothing to start by hand; its workers are threads of the
  sweep's process, since every case runs in a child process of its own) or connects to an existing
  scheduler (``tcp://HOST:PORT``). Each case is one task (:func:`dask_case`), which runs
  one isolated child rehearsal (:mod:`companion.sweep.case`). Dask does the distribution, the
  queueing and the recovery of tasks whose worker died; nothing here is a pool of our own.
* **Recording.** :class:`SweepRecorder` writes each finished case to the store (table
  ``sweep_cases``, one transaction per case) and appends it to the CSV as it arrives, so an
  interrupted sweep keeps every finished row; the CSV is rewritten in case order at the end.
* **Resume.** Cases whose key (the hash of their inputs) the store already holds are skipped
  (``retry_failed`` runs the failed ones again).
* **Stop.** :meth:`SweepRun.stop` (the command's Ctrl-C) sets a ``distributed.Event`` every task
  watches: queued cases return at once without running, running cases get SIGINT (their rehearsal
  aborts and restores) and come back ``stopped``; stopped cases are not recorded, so a resume runs
  them. A failing case never stops the sweep: its failure is its row.
"""
from __future__ import annotations

import csv
import logging
import math
import os
import threading
import time
import uuid
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, TextIO

from companion.sweep.case import ERROR, STOPPED, CaseOptions, CaseResult, figure_columns, row_from_summary, run_case
from companion.sweep.spec import Case

if TYPE_CHECKING:
    import dask.config
    from distributed import Client, LocalCluster

log = logging.getLogger(__name__)

#: the row columns before the per-perturbation ones and the figures (the CSV's order)
INPUT_COLUMNS = ("case_key", "preset", "seed", "current_north", "current_east", "noise", "perturb", "thrusts",
                 "axes", "steps", "behaviors", "steady_state", "schedules", "thesis_estimator", "quick")
OUTCOME_COLUMNS = ("status", "reason", "failure")
#: recorded beside the row, not part of it (they differ between two runs of one case)
RUN_COLUMNS = ("wall_s", "host", "command")


def columns_for(cases: Sequence[Case]) -> list[str]:
    """The CSV columns of a sweep over ``cases`` (one ``perturb_NAME`` column per perturbed parameter)."""
    names = sorted({name for case in cases for name, _ in case.perturb})
    return [*INPUT_COLUMNS, *(f"perturb_{name}" for name in names), *OUTCOME_COLUMNS, *figure_columns(), *RUN_COLUMNS]


# ============================================================================================ tasks
def _stopped(case: Case, reason: str) -> CaseResult:
    row = row_from_summary(case, None, STOPPED, reason)
    return CaseResult(key=case.key, status=STOPPED, reason=reason, row=row)


def dask_case(case: Case, options: CaseOptions, stop_event: str | None = None) -> CaseResult:
    """The Dask task of one case: :func:`run_case`, watching the sweep's stop event about once a second."""
    should_stop = None
    if stop_event:
        from distributed import Event

        event = Event(stop_event)
        checked, stop_set = -math.inf, False

        def should_stop() -> bool:
            nonlocal checked, stop_set
            now = time.monotonic()
            if not stop_set and now - checked >= 1.0:
                checked = now
                try:
                    stop_set = bool(event.is_set())
                except Exception as exc:  # noqa: BLE001 - a scheduler unreachable for a moment: keep running
                    log.debug("stop event not readable: %s", exc)
            return stop_set

        if should_stop():
            return _stopped(case, "the sweep was stopped before this case started")
    return run_case(case, options, should_stop)


# ============================================================================================ engines
#: Dask settings of the local cluster: its tasks only wait on a child process, so the worker's
#: sampling profiler (every 10 ms), memory monitor (every 100 ms: a case's memory is its child's),
#: work stealing and the 20 ms event-loop tick would be all the CPU it spends — measured on an idle
#: 2-worker cluster running two 10 s tasks: 0.43 s of CPU with Dask's defaults, 0.06 s with these
LOCAL_CLUSTER_CONFIG = {
    "distributed.worker.profile.enabled": False,
    "distributed.worker.memory.target": False,
    "distributed.worker.memory.spill": False,
    "distributed.worker.memory.pause": False,
    "distributed.worker.memory.terminate": False,
    "distributed.worker.memory.monitor-interval": "1s",
    "distributed.scheduler.active-memory-manager.start": False,
    "distributed.scheduler.work-stealing": False,
    "distributed.admin.tick.interval": "1s",
    "distributed.admin.system-monitor.interval": "2s",
}


class SweepEngine(Protocol):
    """What :meth:`SweepRun.run` asks of an engine: :class:`DaskEngine`, or one with nothing to run."""

    @property
    def description(self) -> str: ...

    def new_stop_event(self) -> tuple[str, Callable[[], None]]: ...

    def submit(self, case: Case, options: CaseOptions, stop_event: str) -> Any: ...

    def wait_any(self, pending: set, timeout_s: float) -> tuple[set, set]: ...

    def result(self, future: Any, case: Case) -> CaseResult: ...

    def cancel(self, futures: Iterable) -> None: ...


class DaskEngine:
    """A ``dask.distributed`` client: on a local cluster it starts (``scheduler`` None) or on an
    existing one. Use as a context manager; the local cluster is closed on exit."""

    def __init__(self, scheduler: str | None = None, workers: int | None = None,
                 connect_timeout_s: float = 30.0) -> None:
        self.scheduler = scheduler
        self.requested_workers = workers
        self.connect_timeout_s = connect_timeout_s
        self.client: Client | None = None
        self.cluster: LocalCluster | None = None
        self._config: dask.config.set | None = None

    def __enter__(self) -> DaskEngine:
        import dask
        from distributed import Client, LocalCluster

        if self.scheduler:
            log.info("connecting to the Dask scheduler at %s", self.scheduler)
            try:
                self.client = Client(self.scheduler, timeout=f"{self.connect_timeout_s}s")
            except (OSError, TimeoutError) as exc:
                from companion.errors import UserError

                raise UserError(f"no Dask scheduler answered at {self.scheduler} ({exc})") from None
        else:
            workers = self.requested_workers or os.cpu_count() or 1
            # workers as threads of this process: each case is a child process of its own already
            # (companion.sweep.case), so a worker process would isolate nothing and cost a start-up
            log.info("starting a local Dask cluster: %d worker(s), 1 thread each", workers)
            # in one process Dask talks over inproc:// (no network port); its HTTP endpoints on loopback
            self._config = dask.config.set(LOCAL_CLUSTER_CONFIG)  # undone in __exit__
            self.cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=False,
                                        dashboard_address="127.0.0.1:0", worker_dashboard_address="127.0.0.1:0",
                                        silence_logs=logging.ERROR)
            self.client = Client(self.cluster)
        return self

    def __exit__(self, *exc) -> None:
        try:
            if self.client is not None:
                self.client.close()
            if self.cluster is not None:
                self.cluster.close()
        finally:
            if self._config is not None:
                self._config.__exit__(None, None, None)
                self._config = None

    def _client(self) -> Client:
        if self.client is None:
            raise RuntimeError("the Dask engine is not started (use it as a context manager)")
        return self.client

    @property
    def description(self) -> str:
        where = self.scheduler or f"local cluster {self._client().scheduler.address}"
        return f"Dask {where}, {self.workers()} worker(s)"

    def workers(self) -> int:
        return len(self._client().scheduler_info().get("workers", {}))

    def new_stop_event(self) -> tuple[str, Callable[[], None]]:
        """(name, set) of a fresh ``distributed.Event`` the tasks of one run watch."""
        from distributed import Event

        name = f"companion-sweep-stop-{uuid.uuid4().hex}"
        event = Event(name, client=self.client)
        return name, event.set

    def submit(self, case: Case, options: CaseOptions, stop_event: str):
        return self._client().submit(dask_case, case, options, stop_event, pure=False,
                                  key=f"sweep-case-{case.key[:16]}-{uuid.uuid4().hex[:8]}")

    def wait_any(self, pending: set, timeout_s: float) -> tuple[set, set]:
        """(done, not done) after the first of ``pending`` finished, or after ``timeout_s``."""
        from distributed import wait

        if self._client().status in ("closing", "closed"):
            from companion.errors import UserError

            raise UserError(f"lost the Dask scheduler{' at ' + self.scheduler if self.scheduler else ''}; the rows "
                            "recorded so far are kept: run the same command again to resume")
        try:
            result = wait(list(pending), timeout=timeout_s, return_when="FIRST_COMPLETED")
        except TimeoutError:
            return set(), pending
        return set(result.done), set(result.not_done)

    @staticmethod
    def result(future, case: Case) -> CaseResult:
        """The task's result; a task that raised (its worker died, say) becomes an ``error`` row, a task
        the cluster cancelled a ``stopped`` one (not the case's doing: a resume runs it)."""
        if future.status == "cancelled":
            return _stopped(case, "cancelled on the cluster")
        try:
            return future.result()
        except Exception as exc:  # noqa: BLE001 - the failure is the case's outcome
            reason = f"the task failed on the cluster: {type(exc).__name__}: {exc}"[:500]
            row = row_from_summary(case, None, ERROR, reason)
            return CaseResult(key=case.key, status=ERROR, reason=reason, row=row)

    def cancel(self, futures: Iterable) -> None:
        self._client().cancel(list(futures))


# ============================================================================================ recording
class SweepRecorder:
    """Finished cases into the store and the CSV (module docstring)."""

    def __init__(self, store_path: str | Path, csv_path: str | Path, sweep: str, cases: Sequence[Case]) -> None:
        from companion.records.store import Store

        self.store = Store(store_path)
        self.csv_path = Path(csv_path)
        self.sweep = sweep
        self.cases = list(cases)
        self.columns = columns_for(self.cases)
        self._keys = {case.key for case in self.cases}
        self._csv: TextIO | None = None
        self._writer: csv.DictWriter | None = None

    def close(self) -> None:
        if self._csv is not None:
            self._csv.close()
            self._csv = None
        self.store.close()

    def __enter__(self) -> SweepRecorder:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def recorded(self) -> dict[str, dict]:
        """This sweep's cases the store already holds (by key; recorded by any sweep): their stored records."""
        return {item["case_key"]: item for item in self.store.sweep_cases() if item["case_key"] in self._keys}

    def rows(self) -> list[dict]:
        """The recorded rows of this sweep's cases, in case order."""
        recorded = self.recorded()
        return [recorded[case.key]["row"] for case in self.cases if case.key in recorded]

    def start_csv(self) -> None:
        """Write the CSV afresh with the rows recorded so far; later rows are appended as they come."""
        self.csv_path.parent.mkdir(parents=True, exist_ok=True)
        self._csv = open(self.csv_path, "w", newline="", encoding="utf-8")  # noqa: SIM115 - closed in close()
        self._writer = csv.DictWriter(self._csv, fieldnames=self.columns, extrasaction="ignore")
        self._writer.writeheader()
        for row in self.rows():
            self._writer.writerow(_csv_row(row))
        self._csv.flush()

    def record(self, case: Case, result: CaseResult) -> dict:
        """Store one finished case (never a stopped one) and append it to the CSV; returns its row."""
        row = {**result.row, "wall_s": result.wall_s, "host": result.host, "command": case.command()}
        self.store.put_sweep_case(case.key, self.sweep, result.status, result.reason, case.inputs(), row,
                                  result.summary, None if result.status == "completed" else result.log_tail)
        if self._writer is not None and self._csv is not None:
            self._writer.writerow(_csv_row(row))
            self._csv.flush()
        return row

    def finish_csv(self) -> None:
        """Rewrite the CSV in case order (rows arrive in completion order)."""
        if self._csv is not None:
            self._csv.close()
            self._csv = None
        tmp = self.csv_path.with_suffix(".csv.tmp")
        with open(tmp, "w", newline="", encoding="utf-8") as handle:
            writer = csv.DictWriter(handle, fieldnames=self.columns, extrasaction="ignore")
            writer.writeheader()
            for row in self.rows():
                writer.writerow(_csv_row(row))
        os.replace(tmp, self.csv_path)


def _csv_row(row: dict) -> dict:
    """Booleans as true/false, None as an empty cell, floats at full precision."""
    out = {}
    for key, value in row.items():
        if value is None:
            out[key] = ""
        elif isinstance(value, bool):
            out[key] = "true" if value else "false"
        elif isinstance(value, float):
            out[key] = repr(value)
        else:
            out[key] = value
    return out


# ============================================================================================ progress
def _duration(seconds: float | None) -> str:
    if seconds is None or not math.isfinite(seconds):
        return "?"
    seconds = round(seconds)
    hours, rest = divmod(seconds, 3600)
    minutes, secs = divmod(rest, 60)
    return f"{hours}h{minutes:02d}m" if hours else f"{minutes}m{secs:02d}s" if minutes else f"{secs}s"


@dataclass
class SweepProgress:
    """Cases done, failed and left, with an ETA from this run's throughput; one updating line on a
    terminal, one line per finished case otherwise (logs, pipes). ``stream`` None: silent."""

    total: int
    skipped: int = 0
    stream: TextIO | None = None
    done: int = 0
    failed: int = 0
    started: float = field(default_factory=time.monotonic)

    @property
    def left(self) -> int:
        return self.total - self.skipped - self.done - self.failed

    def eta_s(self) -> float | None:
        finished = self.done + self.failed
        if not finished:
            return None
        return (time.monotonic() - self.started) / finished * self.left

    def line(self) -> str:
        return (f"sweep: {self.done} done, {self.failed} failed, {self.left} left"
                + (f" ({self.skipped} already recorded)" if self.skipped else "")
                + f", elapsed {_duration(time.monotonic() - self.started)}, ETA {_duration(self.eta_s())}")

    def update(self, case: Case, result: CaseResult) -> None:
        if result.status == "completed":
            self.done += 1
        else:
            self.failed += 1
        if self.stream is None:
            return
        if self.stream.isatty():
            self.stream.write("\r\x1b[2K" + self.line())
        else:
            detail = f"{result.status}" + (f" ({result.reason})" if result.reason else "")
            self.stream.write(f"{self.line()} | {case.key[:12]} seed {case.seed}: {detail}\n")
        self.stream.flush()

    def say(self, text: str) -> None:
        if self.stream is None:
            return
        if self.stream.isatty():
            self.stream.write("\r\x1b[2K")
        self.stream.write(text + "\n")
        self.stream.flush()

    def close(self) -> None:
        if self.stream is not None and self.stream.isatty():
            self.stream.write("\n")
            self.stream.flush()


# ============================================================================================ the run
@dataclass
class SweepOutcome:
    """What a run of a sweep did."""

    total: int
    skipped: int
    ran: int
    completed: int
    failed: int
    stopped: bool
    unfinished: int  # cases neither recorded before nor finished in this run (a resume runs them)
    wall_s: float
    engine: str = ""

    def as_json(self) -> dict:
        return dict(self.__dict__)


class SweepRun:
    """One run of a sweep's cases on an engine, recording as they finish. :meth:`stop` may be called
    from a signal handler: the run then ends cleanly (module docstring)."""

    def __init__(self, cases: Sequence[Case], recorder: SweepRecorder, options: CaseOptions,
                 progress: SweepProgress | None = None, retry_failed: bool = False) -> None:
        self.cases = list(cases)
        self.recorder = recorder
        self.options = options
        self.retry_failed = retry_failed
        self.progress = progress
        self._stop = threading.Event()
        self._forced = threading.Event()

    def stop(self) -> None:
        """Ask the run to stop: no new case starts, running ones are stopped and not recorded."""
        self._stop.set()

    def force(self) -> None:
        """Stop without waiting for running cases to end (the second Ctrl-C)."""
        self._stop.set()
        self._forced.set()

    @property
    def stopping(self) -> bool:
        return self._stop.is_set()

    def todo(self) -> tuple[list[Case], int]:
        """(cases to run, cases skipped because the store holds them)."""
        recorded = self.recorder.recorded()
        todo = [case for case in self.cases
                if case.key not in recorded or (self.retry_failed and recorded[case.key]["status"] != "completed")]
        return todo, len(self.cases) - len(todo)

    def run(self, engine: SweepEngine) -> SweepOutcome:
        started = time.monotonic()
        todo, skipped = self.todo()
        progress = self.progress or SweepProgress(total=len(self.cases))
        progress.total, progress.skipped = len(self.cases), skipped
        self.recorder.start_csv()
        ran = completed = failed = 0
        if todo:
            progress.say(f"sweep: {len(todo)} case(s) to run, {skipped} already recorded; {engine.description}")
        progress.started = time.monotonic()  # the ETA counts from the first case, not the cluster's start
        stop_name, set_stop = engine.new_stop_event()
        order = {case.key: index for index, case in enumerate(self.cases)}
        futures = {engine.submit(case, self.options, stop_name): case for case in todo}
        pending = set(futures)
        stop_sent = False
        try:
            while pending:
                if self._stop.is_set() and not stop_sent:
                    progress.say("sweep: stopping: no new case starts; running cases are being stopped "
                                 "(Ctrl-C again to leave them)")
                    set_stop()
                    stop_sent = True
                if self._forced.is_set():
                    break
                done, pending = engine.wait_any(pending, timeout_s=0.5)
                for future in sorted(done, key=lambda f: order[futures[f].key]):
                    case = futures[future]
                    result = engine.result(future, case)
                    if result.status == STOPPED:
                        continue
                    self.recorder.record(case, result)
                    ran += 1
                    completed += result.status == "completed"
                    failed += result.status != "completed"
                    progress.update(case, result)
        finally:
            if pending:
                engine.cancel(pending)
            progress.close()
            self.recorder.finish_csv()
        unfinished = len(todo) - ran
        return SweepOutcome(total=len(self.cases), skipped=skipped, ran=ran, completed=completed, failed=failed,
                            stopped=self._stop.is_set(), unfinished=unfinished,
                            wall_s=round(time.monotonic() - started, 2), engine=engine.description)

