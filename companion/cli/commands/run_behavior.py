"""``companion run-behavior roll|min-speed|steady-state``: one closed-loop procedure against any
vehicle (SPEC C6, C7, C8)."""
from __future__ import annotations

import argparse
import math
import sys
from dataclasses import replace

from companion.cli.commands._common import (ConnectFailed, add_connect_arguments, add_recovery_argument,
                                            add_store_argument, connected_vehicle, follow_interrupted_trails,
                                            print_json)
from companion.procedures.registry import PROCEDURES


def add_parser(subparsers) -> None:
    parser = subparsers.add_parser(
        "run-behavior", help="run roll stabilisation, minimum-speed seeking or the steady-state squares and turns",
        description="roll: records roll with the rolling mass centred, then stabilises it for --duration s "
                    "(vehicle time). min-speed: settles at the nominal thrust in the heading-and-depth hold "
                    "mode, then lowers the thrust to the least that still holds depth for --duration s. "
                    "steady-state: a square of four legs of --duration s at --thrust, then steady turns with "
                    "the rudder held at +-12.5 deg for --duration s each; prints the water-relative speed, the "
                    "current and the turning radius. Ctrl-C aborts: mass centred / thrust, rudder, mode and "
                    "gains restored.")
    parser.add_argument("behavior", choices=[spec.cli_name for spec in PROCEDURES.values()])
    add_connect_arguments(parser)
    add_store_argument(parser)
    add_recovery_argument(parser)
    parser.add_argument("--duration", type=float, default=None,
                        help="vehicle seconds of closed-loop operation (default: roll 60, min-speed 200); "
                             "steady-state: per leg and per turn (default 120 and 150)")
    parser.add_argument("--thrust", type=float, default=None,
                        help="cruise / nominal thrust ratio (default: 0.7; steady-state 0.6 on the legs, 0.5 in "
                             "the turns); on ArduRover a fraction of WP_SPEED")
    parser.add_argument("--period", type=float, default=None, help="min-speed: decision period Ts in s (default: 1)")
    parser.add_argument("--start", choices=("governed", "levelled", "ramp", "nominal"), default=None,
                        help="min-speed: where seeking starts. levelled (default with --preset): move to the analytic "
                             "TR* + 0.008 at 0.02/s with the level-flight pitch change fed forward on the depth "
                             "set-point; governed: the same move as fast as the autopilot's depth integrator carries "
                             "the pitch change (0.22 m depth budget, a slower settle); ramp: move at 0.005/s to TR* + "
                             "--start-margin; nominal: seek from the nominal thrust (the thesis). Without --preset "
                             "there is no TR*: nominal")
    parser.add_argument("--start-margin", type=float, default=None, metavar="TR",
                        help="min-speed: the margin over the analytic TR* the move aims at (default: levelled and governed 0.008, "
                             "ramp 0.04); given alone it selects the ramp")
    parser.add_argument("--preset", default=None,
                        help="min-speed: simulator preset whose vehicle data give the analytic TR* and Vmin")
    parser.add_argument("--simulator-hooks", action="store_true",
                        help="roll: use the simulator's SIM_ROLL_DIST disturbance and SIM_ROLL_KICK impulses")
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")
    parser.set_defaults(func=run)


def min_speed_start(start: str | None, margin: float | None, *, analytic: bool, **fields):
    """The minimum-speed procedure's configuration for ``--start`` / ``--start-margin`` (see their help)."""
    from companion.procedures.min_speed import MinSpeedProcedureConfig

    if margin is not None and not (math.isfinite(margin) and 0.0 <= margin < 0.5):
        raise ValueError(f"--start-margin must be in [0, 0.5), not {margin!r}")
    if start is None:
        start = "ramp" if margin is not None else ("levelled" if analytic else "nominal")
    if start == "nominal":
        if margin is not None:
            raise ValueError("--start-margin needs --start levelled, governed or ramp")
        return MinSpeedProcedureConfig(**fields)
    if not analytic:
        raise ValueError(f"--start {start} needs --preset (the vehicle data that give the analytic TR*)")
    if start in ("governed", "levelled"):
        build = MinSpeedProcedureConfig.governed if start == "governed" else MinSpeedProcedureConfig.levelled
        return build(**fields, **({"start_margin": margin} if margin is not None else {}))
    return MinSpeedProcedureConfig(start_margin=0.04 if margin is None else margin, **fields)


def run(args: argparse.Namespace) -> int:
    from companion.procedures.app import vehicle_record
    from companion.procedures.app import run_named_behavior
    from companion.procedures.roll import RollProcedureConfig
    from companion.procedures.steady_state import SteadyStateConfig
    from companion.records.store import Store

    name = args.behavior.replace("-", "_")
    if args.thrust is not None and not (0.0 < args.thrust <= 1.0):
        print(f"--thrust must be in (0, 1], not {args.thrust!r}", file=sys.stderr)
        return 2
    thrust = 0.70 if args.thrust is None else args.thrust
    roll = RollProcedureConfig(thrust=thrust)
    try:
        min_speed = min_speed_start(args.start, args.start_margin, nominal_thrust=thrust, period_s=args.period,
                                    analytic=args.preset is not None)
    except ValueError as exc:
        print(exc, file=sys.stderr)
        return 2
    steady = SteadyStateConfig()
    if args.thrust is not None:
        steady = replace(steady, squares=replace(steady.squares, thrust_ratio=args.thrust),
                         turns=replace(steady.turns, thrust_ratio=args.thrust))
    if args.duration is not None:
        if not args.duration > 0:  # also refuses NaN
            print("--duration must be positive", file=sys.stderr)
            return 2
        roll = replace(roll, closed_s=args.duration)
        min_speed = replace(min_speed, duration_s=args.duration)
        steady = replace(steady, squares=replace(steady.squares, leg_s=args.duration),
                         turns=replace(steady.turns, turn_s=args.duration))
    try:
        with connected_vehicle(args) as (link, abort), Store(args.store) as store:
            if not follow_interrupted_trails(link, store, args, guard=getattr(abort, "guard", None)):
                return 1
            outcome = run_named_behavior(name, link, store, vehicle_id=vehicle_record(store, link), campaign_id=None,
                                         abort=abort, preset=args.preset, simulator=args.simulator_hooks,
                                         config={"roll": roll, "min_speed": min_speed, "steady_state": steady}.get(name))
    except ConnectFailed as exc:
        print(exc, file=sys.stderr)
        return 1
    summary = outcome.summary
    if args.json:
        print_json(summary)
    else:
        for key, value in summary.items():
            print(f"{key:28s} {value if not isinstance(value, float) else format(value, '.4g')}")
    return 0 if summary.get("status") == "completed" else 1
