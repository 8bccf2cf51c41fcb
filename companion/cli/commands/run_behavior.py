"""``companion run-behavior roll|min-speed``: one closed-loop behaviour against any vehicle (SPEC C6, C7)."""
from __future__ import annotations

import argparse
import sys
from dataclasses import replace

from companion.cli.commands._common import (ConnectFailed, add_connect_arguments, add_store_argument, connected_vehicle,
                                       print_json)


def add_parser(subparsers) -> None:
    parser = subparsers.add_parser(
        "run-behavior", help="run roll stabilisation or minimum-speed seeking on a vehicle",
        description="roll: records roll with the rolling mass centred, then stabilises it for --duration s "
                    "(vehicle time). min-speed: settles at the nominal thrust in the heading-and-depth hold "
                    "mode, then lowers the thrust to the least that still holds depth for --duration s. "
                    "Ctrl-C aborts: mass centred / nominal thrust, mode and gains restored.")
    parser.add_argument("behavior", choices=("roll", "min-speed"))
    add_connect_arguments(parser)
    add_store_argument(parser)
    parser.add_argument("--duration", type=float, default=None,
                        help="vehicle seconds of closed-loop operation (default: roll 60, min-speed 200)")
    parser.add_argument("--thrust", type=float, default=0.70, help="cruise / nominal thrust ratio (default: %(default)s)")
    parser.add_argument("--period", type=float, default=None, help="min-speed: decision period Ts in s (default: 1)")
    parser.add_argument("--preset", default=None,
                        help="min-speed: simulator preset whose vehicle data give the analytic TR* and Vmin")
    parser.add_argument("--simulator-hooks", action="store_true",
                        help="roll: use the simulator's SIM_ROLL_DIST disturbance and SIM_ROLL_KICK impulses")
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from companion.procedures.app import vehicle_record
    from companion.procedures.app import run_named_behavior
    from companion.procedures.min_speed import MinSpeedProcedureConfig
    from companion.procedures.roll import RollProcedureConfig
    from companion.records.store import Store

    name = args.behavior.replace("-", "_")
    roll = RollProcedureConfig(thrust=args.thrust)
    min_speed = MinSpeedProcedureConfig(nominal_thrust=args.thrust, period_s=args.period)
    if args.duration is not None:
        if args.duration <= 0:
            print("--duration must be positive", file=sys.stderr)
            return 2
        roll = replace(roll, closed_s=args.duration)
        min_speed = replace(min_speed, duration_s=args.duration)
    try:
        with connected_vehicle(args) as (link, abort), Store(args.store) as store:
            outcome = run_named_behavior(name, link, store, vehicle_id=vehicle_record(store, link), campaign_id=None,
                                         abort=abort, preset=args.preset, simulator=args.simulator_hooks,
                                         roll_config=roll, min_speed_config=min_speed)
    except ConnectFailed as exc:
        print(exc, file=sys.stderr)
        return 1
    summary = outcome["summary"]
    if args.json:
        print_json(summary)
    else:
        for key, value in summary.items():
            print(f"{key:28s} {value if not isinstance(value, float) else format(value, '.4g')}")
    return 0 if summary.get("status") == "completed" else 1
