"""``companion run``: stay beside the vehicle — gain scheduling, ground-station procedures (SPEC C1, C5)."""
from __future__ import annotations

import argparse
import sys

from companion.cli.commands._common import (ConnectFailed, add_connect_arguments, add_procedure_argument,
                                            add_recovery_argument, add_store_argument, connected_vehicle,
                                            follow_interrupted_trails)


def add_parser(subparsers) -> None:
    parser = subparsers.add_parser(
        "run", help="run beside the vehicle: keep gains matched to speed, serve ground-station commands",
        description="The resident companion. Keeps the heading gains matched to speed with the schedule "
                    "of the store's latest identification campaign, and runs procedures on COMMAND_LONG "
                    "aimed at component 191: MAV_CMD_USER_1 identification campaign, USER_2 roll "
                    "stabilisation, USER_3 minimum-speed seeking, USER_4 abort. Ctrl-C stops (aborting "
                    "and restoring whatever runs).")
    add_connect_arguments(parser)
    add_store_argument(parser)
    add_recovery_argument(parser)
    parser.add_argument("--no-scheduling", action="store_true", help="do not write scheduled gains between procedures")
    parser.add_argument("--no-health", action="store_true",
                        help="do not watch the vehicle's health (passive identification against the stored models, "
                             "STATUSTEXT warning on a drift of a22 or b2)")
    parser.add_argument("--preset", default=None,
                        help="simulator preset (analytic minimum speed: the governed start of minimum-speed seeking "
                             "and the results)")
    add_procedure_argument(parser)
    parser.add_argument("--max-vehicle-time", type=float, default=None, metavar="S",
                        help="stop after S seconds of vehicle time (default: run until interrupted)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from companion.procedures.app import vehicle_record
    from companion.link.errors import LinkError
    from companion.procedures.campaign import CampaignConfig
    from companion.procedures.min_speed import MinSpeedProcedureConfig
    from companion.procedures.resident import Companion, ServeConfig
    from companion.records.store import Store

    config = ServeConfig(schedule_gains=not args.no_scheduling, preset=args.preset, max_vehicle_s=args.max_vehicle_time,
                         health=not args.no_health, campaign=CampaignConfig().for_procedure(args.procedure),
                         min_speed=MinSpeedProcedureConfig.governed())
    try:
        with connected_vehicle(args) as (link, stop), Store(args.store) as store:
            if not follow_interrupted_trails(link, store, args, guard=getattr(stop, "guard", None)):
                return 1
            companion = Companion(link, store, vehicle_record(store, link), config, stop)
            print(f"companion running on {args.connect} (system {link.transport.system_id}, component 191, profile "
                  f"{link.profile.name}); Ctrl-C to stop", file=sys.stderr)
            history = companion.run()
    except (ConnectFailed, LinkError) as exc:
        print(exc if isinstance(exc, ConnectFailed) else f"error: {exc}", file=sys.stderr)
        return 1
    for entry in history:
        print(entry)
    return 0
