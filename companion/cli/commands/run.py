"""``companion run``: stay beside the vehicle — gain scheduling, ground-station procedures (SPEC C1, C5),
optionally as a service: a configuration file, a status page, reports (``companion.service``)."""
from __future__ import annotations

import argparse
import logging
import os
import sys

from companion.cli.commands._common import (ConnectFailed, add_connect_arguments, add_procedure_argument,
                                            add_recovery_argument, add_store_argument, connected_vehicle,
                                            follow_interrupted_trails, thrust_list)

log = logging.getLogger(__name__)


def _procedure_names() -> tuple[str, ...]:
    from companion.procedures.registry import COMMANDS

    return tuple(COMMANDS.values())


def procedure_list(text: str) -> tuple[str, ...]:
    """``identification,roll`` → the procedures a ground station may start (argparse type)."""
    known = _procedure_names()
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    unknown = [n for n in names if n not in known]
    if not names or unknown:
        raise argparse.ArgumentTypeError(f"procedures are {', '.join(known)} (got {text!r})")
    return names


def listen_argument(text: str) -> str:
    from companion.service.config import split_listen

    try:
        host, port = split_listen(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return f"{host}:{port}"


def add_parser(subparsers) -> None:
    parser = subparsers.add_parser(
        "run", help="run beside the vehicle: keep gains matched to speed, serve ground-station commands",
        description="The resident companion. Keeps the heading gains matched to speed with the schedule "
                    "of the store's latest identification campaign, and runs procedures on COMMAND_LONG "
                    "aimed at component 191: MAV_CMD_USER_1 identification campaign, USER_2 roll "
                    "stabilisation, USER_3 minimum-speed seeking, USER_4 abort, USER_5 steady-state "
                    "manoeuvres. Ctrl-C or SIGTERM stops (aborting and restoring whatever runs). Settings "
                    "come from --config FILE (TOML; the flags override it): see deploy/companion.toml.")
    parser.add_argument("--config", metavar="FILE", default=None,
                        help="TOML configuration file (example: deploy/companion.toml); flags override it")
    add_connect_arguments(parser, required=False)
    add_store_argument(parser)
    add_recovery_argument(parser)
    parser.add_argument("--report-dir", metavar="DIR", default=None,
                        help="write each identification campaign's HTML report into DIR/campaign-N (default: none)")
    parser.add_argument("--no-scheduling", action="store_true", default=None,
                        help="do not write scheduled gains between procedures")
    parser.add_argument("--no-health", action="store_true", default=None,
                        help="do not watch the vehicle's health (passive identification against the stored models, "
                             "STATUSTEXT warning on a drift of a22 or b2)")
    parser.add_argument("--learn", action="store_true", default=None,
                        help="tune during ordinary missions: learn the yaw model from the mission's own course "
                             "changes, write the designed heading gains on a steady straight (never in a turn or a "
                             "hand-flown mode), verify them on the next course changes and revert if they are worse "
                             "or not as predicted (USER_4 param1=1 accepts, 0 reverts); on ArduRover the speed loop "
                             "too, from the mission's speed changes. Replaces --scheduling of stored designs while on")
    parser.add_argument("--preset", default=None,
                        help="simulator preset (analytic minimum speed: the levelled start of minimum-speed seeking "
                             "and the results)")
    add_procedure_argument(parser)
    parser.add_argument("--thrusts", type=thrust_list, default=None, metavar="LIST",
                        help="thrust levels of a campaign started from the ground station, e.g. 0.6,0.8,1.0 "
                             "(default: the autopilot's)")
    parser.add_argument("--procedures", type=procedure_list, default=None, metavar="NAMES",
                        help="the procedures a ground station may start (default: all): identification, roll, "
                             "min_speed, steady_state; the others are answered DENIED")
    parser.add_argument("--http", type=listen_argument, default=None, metavar="HOST:PORT",
                        help="serve the read-only status page on HOST:PORT (default: none; loopback only unless "
                             "--http-allow-remote; port 0 picks a free port, printed at start)")
    parser.add_argument("--http-allow-remote", action="store_true", default=None,
                        help="allow --http on an address other than loopback (no authentication: anyone who "
                             "reaches the port reads the vehicle's state)")
    parser.add_argument("--max-vehicle-time", type=float, default=None, metavar="S",
                        help="stop after S seconds of vehicle time (default: run until interrupted)")
    parser.set_defaults(func=run, store=None, procedure=None)


def settings_from(args: argparse.Namespace):
    """The merged settings (``companion.service.settings``): the configuration file, then the flags."""
    from companion.cli.endpoints import check_endpoint
    from companion.link.autopilots import MODULES
    from behaviors.schedules import GAIN_SCHEDULES
    from companion.service.config import keys, load_config
    from companion.service.settings import DEFAULT_STORE, merge

    from_file = {}
    if args.config:
        from_file = load_config(args.config, keys(MODULES, _procedure_names(), tuple(GAIN_SCHEDULES), check_endpoint))
    verbose = getattr(args, "verbose", 0)
    flags = {name: getattr(args, name, None) for name in (
        "connect", "profile", "signing_key", "rudder_full_scale", "rudder_rate", "preset", "store", "report_dir",
        "procedures", "procedure", "thrusts", "http", "http_allow_remote", "max_vehicle_time", "log_format")}
    flags["schedule_gains"] = False if args.no_scheduling else None
    flags["health"] = False if args.no_health else None
    flags["learn"] = True if args.learn else None
    flags["log_level"] = {1: "info", 2: "debug"}.get(min(verbose, 2)) if verbose else None
    flags["yes"] = True if getattr(args, "yes", False) else None
    return merge(from_file, flags, {"store": os.environ.get("COMPANION_STORE", DEFAULT_STORE)})


def run(args: argparse.Namespace) -> int:
    from companion.link.errors import LinkError
    from companion.service.http import HttpConfigError

    try:
        settings = settings_from(args)
        config = settings.serve_config()  # every value checked before anything connects
    except ValueError as exc:
        print(f"companion run: error: {exc}", file=sys.stderr)
        return 2
    if settings.log_format is not None or settings.log_level is not None:
        from companion.service.logs import configure_logging

        configure_logging(settings.log_format or "auto", settings.log_level_number or logging.getLogger().level)
    if settings.connect is None:
        print("companion run: error: no vehicle to connect to: give --connect ENDPOINT or connect in the "
              "[connection] section of --config FILE", file=sys.stderr)
        return 2
    for name in ("connect", "profile", "signing_key", "rudder_full_scale", "rudder_rate", "yes"):
        setattr(args, name, getattr(settings, name))  # what connected_vehicle and the recovery read
    try:
        return _serve(args, settings, config)
    except HttpConfigError as exc:
        print(f"companion run: error: {exc}", file=sys.stderr)
        return 2
    except (ConnectFailed, LinkError) as exc:
        print(exc if isinstance(exc, ConnectFailed) else f"error: {exc}", file=sys.stderr)
        return 1


def _serve(args: argparse.Namespace, settings, config) -> int:
    from companion.cli.main import package_version
    from companion.procedures.app import vehicle_record
    from companion.procedures.resident import Companion
    from companion.records.store import Store
    from companion.service.feed import StatusFeed, latest_report
    from companion.service.http import StatusServer
    from companion.service.status import StatusBoard

    board = StatusBoard()
    server = None
    report_dir = settings.report_dir
    if settings.http_address is not None:
        host, port = settings.http_address
        server = StatusServer(board, host, port, allow_remote=settings.http_allow_remote,
                              report=lambda: _report_path(board) or latest_report(_path(report_dir)))
        server.start()
        print(f"status page: {server.url}", file=sys.stderr, flush=True)
    try:
        with connected_vehicle(args) as (link, stop), Store(settings.store) as store:
            if not follow_interrupted_trails(link, store, args, guard=getattr(stop, "guard", None)):
                return 1
            link.ground.allowed_senders.update(settings.allowed_senders)
            feed = None
            if server is not None or report_dir is not None:
                feed = StatusFeed(board, link, store, endpoint=settings.connect, report_dir=report_dir)
            companion = Companion(link, store, vehicle_record(store, link), config, stop, observer=feed)
            if feed is not None:
                feed.watch(companion, package_version())
            print(f"companion running on {settings.connect} (system {link.transport.system_id}, component 191, "
                  f"profile {link.profile.name}); Ctrl-C to stop", file=sys.stderr, flush=True)
            history = companion.run()
    finally:
        if server is not None:
            server.close()
    for entry in history:
        print(entry)
    return 0


def _path(text: str | None):
    from pathlib import Path

    return Path(text) if text else None


def _report_path(board):
    from pathlib import Path

    report = board.get("report")
    return Path(report["path"]) if isinstance(report, dict) and report.get("path") else None
