"""``companion sweep``: many independent rehearsals on Dask, one summary row per case.

What varies comes from ``--spec FILE`` (JSON or YAML, :mod:`companion.sweep.spec`) and/or the flags
below (a flag overrides the file's field). The cases run on a local Dask cluster by default or on
an existing one (``--scheduler tcp://HOST:PORT``); rows go to the store (``sweep_cases``), to
``sweep.csv`` and into ``report.html``. Running the same sweep again resumes it: recorded cases are
skipped. Ctrl-C stops cleanly and keeps every finished row (twice: leave the running cases).
"""
from __future__ import annotations

import argparse
import logging
import signal
import sys
from pathlib import Path

from companion.cli.commands._common import print_json


def add_parser(subparsers) -> None:
    parser = subparsers.add_parser(
        "sweep", help="run many rehearsals (seeds, currents, noise, vehicle variants) on Dask; rows, CSV, report",
        description="Monte-Carlo rehearsals: every combination of the given presets, seeds, currents, noise levels, "
                    "vehicle perturbations and thrust lists is one independent `companion rehearse`, run on a local "
                    "Dask cluster (default) or on an existing one (--scheduler). One row per case goes to the store "
                    "and a CSV; an HTML report shows the distributions, the failures and the worst cases.",
        epilog="Example: companion sweep --seeds 1..8 --currents '0,0;0.05,-0.02' --axes yaw --thrusts 0.6,0.8,1.0. "
               "Spec files: see companion/sweep/spec.py.")
    what = parser.add_argument_group("what varies (lists; a flag overrides the spec file's field)")
    what.add_argument("--spec", metavar="FILE", default=None, help="sweep specification, .json or .yaml")
    what.add_argument("--name", default=None, help="the sweep's name (default: the spec file's name, or 'sweep')")
    what.add_argument("--presets", default=None, metavar="NAMES", help="simulator presets, e.g. starfish,starfish-tla")
    what.add_argument("--seeds", default=None, metavar="SEEDS", help="seeds: 1..8, 1,2,5 (default: 1)")
    what.add_argument("--currents", default=None, metavar="VN,VE;...",
                      help="water currents north,east in m/s separated by ';' (default: each preset's)")
    what.add_argument("--noise", default=None, metavar="FACTORS", help="sensor-noise factors, e.g. 1,2 (default: 1)")
    what.add_argument("--perturb", action="append", default=None, metavar="NAME=FACTORS",
                      help="vehicle perturbation factors, e.g. mass=0.9,1.1 or b2=±20%% (mass, b2, a22, trim, "
                           "elevator, drag, thrust or SECTION.FIELD; repeatable: the cross product is swept)")
    what.add_argument("--thrusts", default=None, metavar="LIST[;LIST]",
                      help="thrust list(s), e.g. 0.6,0.8,1.0 or 0.8;0.6,1.0 (default: 60..100%%)")
    what.add_argument("--axes", default=None, help="axes to identify: yaw and/or pitch (default: yaw,pitch)")
    what.add_argument("--no-steps", dest="steps", action="store_const", const=False, default=None,
                      help="skip the heading-step checks")
    what.add_argument("--behaviors", default=None,
                      help="roll,min-speed or none (default: each preset's, as companion rehearse)")
    what.add_argument("--steady-state", dest="steady_state", action=argparse.BooleanOptionalAction, default=None,
                      help="the steady-state squares and turns (default: each preset's)")
    what.add_argument("--schedules", default=None, metavar="NAMES", help="gain schedules: heading and/or pitch")
    what.add_argument("--thesis-estimator", dest="thesis_estimator", action="store_const", const=True, default=None,
                      help="the seeds' exact estimator")
    what.add_argument("--quick", dest="quick", action="store_const", const=True, default=None,
                      help="the quick procedure (companion rehearse --procedure quick); without it a sweep "
                           "runs the thesis procedure, as its earlier cases did")
    what.add_argument("--speedup", default=None, help="simulation speed-up of every case (default: 50; "
                                                      "the numbers do not depend on it)")
    what.add_argument("--timeout", default=None, metavar="S", help="wall-clock limit of one case (default: 1800)")
    run = parser.add_argument_group("where and how it runs")
    run.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT",
                     help="an existing dask.distributed scheduler (default: a local cluster on this machine)")
    run.add_argument("--workers", type=int, default=None, metavar="N",
                     help="workers of the local cluster, i.e. cases run at once (default: one per core)")
    run.add_argument("--out", default="sweep", help="output folder: store, CSV, report (default: %(default)s)")
    run.add_argument("--store", default=None, help="the store (default: OUT/sweep.sqlite)")
    run.add_argument("--retry-failed", action="store_true", help="run recorded cases that did not complete again")
    run.add_argument("--keep-cases", action="store_true",
                     help="keep each case's files (store, summary, logs) in OUT/cases/KEY on the machine that ran it")
    run.add_argument("--no-report", action="store_true", help="do not write the HTML report")
    run.add_argument("--dry-run", action="store_true", help="list the cases and their commands, run nothing")
    run.add_argument("--json", action="store_true", help="print the outcome as one JSON object")
    parser.set_defaults(func=run_command)


_FLAG_FIELDS = ("name", "presets", "seeds", "currents", "noise", "thrusts", "axes", "steps", "behaviors",
                "steady_state", "schedules", "thesis_estimator", "quick", "speedup")


def build_spec(args: argparse.Namespace):
    """The spec: the file's fields, then the flags given."""
    from companion.sweep.spec import SweepSpec, load_spec_file, perturbation_strings, spec_from_dict

    data = load_spec_file(args.spec) if args.spec else {}
    if args.spec and "name" not in data:
        data["name"] = Path(args.spec).stem
    spec = spec_from_dict(data, SweepSpec())
    flags = {key: getattr(args, key) for key in _FLAG_FIELDS if getattr(args, key) is not None}
    if args.perturb is not None:
        flags["perturb"] = perturbation_strings(args.perturb)
    if args.timeout is not None:
        flags["timeout_s"] = args.timeout
    return spec_from_dict(flags, spec) if flags else spec


def run_command(args: argparse.Namespace) -> int:
    from companion.errors import UserError
    from companion.sweep.case import CaseOptions

    if args.workers is not None and args.workers < 1:
        raise UserError("--workers must be at least 1")
    if args.workers is not None and args.scheduler:
        raise UserError("--workers sizes the local cluster; with --scheduler the cluster's own workers run the cases")
    if args.scheduler and not args.scheduler.startswith(("tcp://", "tls://", "inproc://", "ws://", "wss://")):
        raise UserError(f"--scheduler takes a Dask scheduler address such as tcp://127.0.0.1:8786, not {args.scheduler!r}")
    spec = build_spec(args)
    cases = spec.cases()
    if args.dry_run:
        listing = [{"key": case.key, "inputs": case.inputs(), "command": case.command()} for case in cases]
        if args.json:
            print_json({"spec": spec.as_json(), "cases": listing})
        else:
            for item in listing:
                print(f"{item['key'][:12]}  {item['command']}")
            print(f"{len(listing)} case(s)")
        return 0
    if not getattr(args, "verbose", 0):  # the cluster's own start/stop chatter, unless -v
        import distributed  # noqa: F401 - its import sets up its loggers; quieten them after it

        logging.getLogger("distributed").setLevel(logging.WARNING)
    out = Path(args.out)
    store = Path(args.store) if args.store else out / "sweep.sqlite"
    options = CaseOptions(speedup=spec.speedup, timeout_s=spec.timeout_s,
                          keep_dir=str((out / "cases").resolve()) if args.keep_cases else None)
    outcome, rows = execute(spec, cases, options, out, store, scheduler=args.scheduler, workers=args.workers,
                            retry_failed=args.retry_failed, progress_stream=sys.stderr,
                            report=not args.no_report)
    result = {"sweep": spec.name, **outcome.as_json(),
              "statuses": _statuses(rows), "store": str(store), "csv": str(out / "sweep.csv"),
              "report": None if args.no_report else str(out / "report.html")}
    if args.json:
        print_json(result)
    else:
        print(f"sweep {spec.name}: {len(rows)} of {len(cases)} case(s) recorded "
              f"({', '.join(f'{k} {v}' for k, v in result['statuses'].items()) or 'none'}); "
              f"{outcome.ran} run now, {outcome.skipped} already recorded"
              + (f", {outcome.unfinished} not run (stopped: run the same command again to resume)"
                 if outcome.unfinished else ""))
        print(f"rows:   {result['csv']}\nstore:  {result['store']}" + (f"\nreport: {result['report']}"
                                                                        if result["report"] else ""))
    return 130 if outcome.stopped else 0


def _statuses(rows: list[dict]) -> dict:
    out: dict = {}
    for row in rows:
        out[row["status"]] = out.get(row["status"], 0) + 1
    return dict(sorted(out.items()))


def execute(spec, cases, options, out: Path, store: Path, *, scheduler: str | None = None, workers: int | None = None,
            retry_failed: bool = False, progress_stream=None, report: bool = True):
    """Run (or resume) the sweep on Dask with Ctrl-C handled; returns (outcome, the sweep's rows)."""
    from companion.sweep.engine import DaskEngine, SweepProgress, SweepRecorder, SweepRun
    from companion.sweep.report import write_sweep_report

    with SweepRecorder(store, out / "sweep.csv", spec.name, cases) as recorder:
        run = SweepRun(cases, recorder, options, SweepProgress(total=len(cases), stream=progress_stream),
                       retry_failed=retry_failed)
        todo, _ = run.todo()
        undo = _install_stop_handlers(run)
        try:
            if todo:
                with DaskEngine(scheduler=scheduler, workers=workers) as engine:
                    outcome = run.run(engine)
            else:
                outcome = run.run(_NoEngine())
        finally:
            undo()
        rows = recorder.rows()
    if report:
        write_sweep_report(rows, out, name=spec.name, spec=spec.as_json(), outcome=outcome.as_json(),
                           csv_name="sweep.csv")
    return outcome, rows


class _NoEngine:
    """Every case already recorded: nothing to start (no cluster for nothing)."""

    description = "nothing to run"

    def new_stop_event(self):
        return "", lambda: None

    def submit(self, *args):  # pragma: no cover - never called without cases
        raise RuntimeError("nothing to run")

    def wait_any(self, pending, timeout_s):  # pragma: no cover - never called without cases
        raise RuntimeError("nothing to run")

    def result(self, future, case):  # pragma: no cover - never called without cases
        raise RuntimeError("nothing to run")

    def cancel(self, futures) -> None:
        pass


def _install_stop_handlers(run):
    """SIGINT/SIGTERM: the first stops the sweep cleanly, the second leaves the running cases, the third
    raises KeyboardInterrupt. Returns the undo function."""
    previous = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    received = [0]

    def handler(signum, _frame):
        received[0] += 1
        if received[0] == 1:
            run.stop()
        elif received[0] == 2:
            sys.stderr.write("\nsweep: leaving the running cases (they end on their own)\n")
            run.force()
        else:
            raise KeyboardInterrupt

    from companion.procedures.app import handle_stop_signals

    return handle_stop_signals(handler, previous)

