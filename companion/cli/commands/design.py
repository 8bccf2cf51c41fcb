"""``companion design``: heading gains and turning performance from a yaw model (SPEC C5).

    companion design --a22 -1.62 --b2 1.25 --delta0 0.036 --speed 1.4 [--delta-max 0.26] [--json]
    companion design --autopilot ardurover --a22 -0.9 --b2 1.1 --speed 2.0 [--original ATC_STR_RAT_FF=0.2,...]
    companion design --autopilot px4-rover --a22 -0.9 --b2 1.1 --speed 1.5 [--original RA_WHEEL_BASE=2,...]

Without ``--autopilot``: the thesis' PI (kp, ki, trim; gains.py) and, for the speed given, ψ̇max,
the U-turn time and the turning radius (turning.py, eq. 3.47–3.50). Without ``--speed`` the radius
is not printed (it needs V).

With ``--autopilot``: the campaign's designer (eq. D.1, ``companion.numerics.step_design``) for that
autopilot's own heading controller — our simulator's PI (eq. A.1), ArduPilot's cascade (eq. A.2), PX4's
Ackermann rover (eq. A.4) or UUV (eq. A.5) — the rule's parameters optimised on the predicted ±20° and
±40° steps under the controller's limits (the autopilot's shipped defaults unless given), with the
original gains (the autopilot's defaults, or ``--original``) as a candidate — printing the chosen gains
under the autopilot's parameter names and every candidate's predicted steps. A user with a model from
elsewhere gets the design a campaign would make at that one speed.
"""
from __future__ import annotations

import argparse
import math
import sys

from companion.cli.commands._common import print_json

from companion.numerics.gains import GainBounds, design_heading_gains
from companion.numerics.identification import YawEstimate, YawModel
from companion.numerics.turning import DEFAULT_DELTA_MAX, turning_performance
from companion.cli.commands.design_autopilot import autopilot_profiles, run_for_autopilot

#: the largest rudder limit accepted, rad: a deflection beyond 90° is not a rudder angle (degrees?)
MAX_RUDDER = math.pi / 2


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "design",
        help="heading PI gains and turning performance from an identified yaw model",
        description=(
            "Design heading PI gains (Kp = a22^2/(2 b2), zeta 0.7071; integral zero 100x below wn; "
            "trim = delta0) and predict turning performance (eq. 3.47-3.50) for the yaw model "
            "r' = a22 r + b2 (rudder - delta0)."
        ),
    )
    parser.add_argument("--a22", type=float, required=True, help="yaw damping a22, 1/s (negative)")
    parser.add_argument("--b2", type=float, required=True, help="rudder authority b2, 1/s^2 (positive)")
    parser.add_argument("--delta0", type=float, default=0.0, help="steady-state rudder offset, rad (default 0)")
    parser.add_argument("--speed", type=float, default=None, help="speed through water, m/s (for the radius)")
    parser.add_argument(
        "--delta-max", type=float, default=DEFAULT_DELTA_MAX, help=f"rudder limit, rad (default {DEFAULT_DELTA_MAX})"
    )
    parser.add_argument("--autopilot", choices=tuple(autopilot_profiles()), default=None,
                        help="design for this autopilot's own heading controller by its predicted steps (eq. D.1: "
                             "builtin PI, ArduPilot cascade, PX4 rover or UUV); default: the thesis PI rule")
    parser.add_argument("--original", default=None, metavar="NAME=VALUE,...",
                        help="the vehicle's heading gains and limits as found, by the autopilot's parameter names "
                             "(default: its shipped defaults); scored as a candidate")
    parser.add_argument("--scale-base", type=float, default=None,
                        help="ArduRover: the speed above which the steering output is scaled down "
                             "(MOT_SPD_SCA_BASE, m/s; default 1 for a rudder); 0: not scaled (a skid boat)")
    parser.add_argument("--skid-throttle", type=float, default=None, metavar="T",
                        help="--autopilot ardurover with twin thrusters: the throttle (0..1) that holds --speed; "
                             "the steps are then predicted through ArduRover's skid mixer at its defaults "
                             "(MOT_THST_ASYM 1, MOT_STR_THR_MIX 0.5), the thrust the steering leaves and the "
                             "speed it costs (eq. A.2k), with no output speed scaling")
    parser.add_argument("--forward-thrust", type=float, default=None, metavar="F",
                        help="--autopilot px4-uuv: the surge thrust (0..1) flown at --speed; the yaw torque is "
                             "then allocated beside it as PX4's thrusters allow (eq. A.5a)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.set_defaults(func=run)
    return parser


def _model(args) -> YawModel:
    """The model the flags give (a22 < 0, b2 > 0, all finite: eq. 3.5–3.9); ValueError naming what is
    wrong otherwise."""
    try:
        return YawEstimate(a22=args.a22, b2=args.b2, delta0=args.delta0).model()
    except ValueError as exc:
        raise ValueError(f"--a22, --b2 and --delta0 give no yaw model: {exc}") from None


def _validate(args) -> str | None:
    if not math.isfinite(args.delta_max):
        return "--delta-max must be a finite number"
    if args.speed is not None and not (math.isfinite(args.speed) and args.speed >= 0.0):
        return "--speed must be a finite number >= 0"
    if not 0.0 < args.delta_max <= MAX_RUDDER:
        return f"--delta-max must be a rudder limit in (0, π/2] rad, got {args.delta_max}"
    if args.delta_max <= args.delta0:
        return f"--delta-max ({args.delta_max}) must exceed --delta0 ({args.delta0})"
    return None


def _non_finite(result: dict) -> str | None:
    """The first output the inputs drove beyond floating point (overflow), or None."""
    for name, value in result.items():
        if isinstance(value, float) and not math.isfinite(value):
            return name
    return None


def _refuse(error: str) -> int:
    """An input error as argparse gives one: one line on stderr, exit status 2."""
    print(f"companion design: error: {error}", file=sys.stderr)
    return 2


def run(args) -> int:
    try:
        model = _model(args)
    except ValueError as exc:
        return _refuse(str(exc))
    error = _validate(args)
    if error:
        return _refuse(error)
    if getattr(args, "autopilot", None) is not None:
        return run_for_autopilot(args, model)
    gains = design_heading_gains(model, GainBounds(), speed=args.speed)
    turning = turning_performance(model, args.speed if args.speed is not None else 0.0, args.delta_max)
    result = {
        "kp": gains.kp,
        "ki": gains.ki,
        "trim": gains.trim,
        "clamped": list(gains.clamped),
        "yaw_rate_max_deg_s": turning.yaw_rate_max_deg_s,
        "settle_time_s": turning.settle_time_s,
        "u_turn_time_s": turning.u_turn_time_s,
        "turning_radius_m": turning.turning_radius_m if args.speed is not None else None,
        "speed": args.speed,
    }
    overflow = _non_finite(result)
    if overflow:
        print(f"companion design: error: the model gives a non-finite {overflow} (a22 {args.a22:g}, b2 {args.b2:g}, "
              f"speed {args.speed}): the inputs are outside any vehicle's range", file=sys.stderr)
        return 2
    if args.json:
        print_json(result)
        return 0
    rows = [
        ("kp", f"{gains.kp:.4f}", "rad rudder / rad heading error"),
        ("ki", f"{gains.ki:.5f}", "rad rudder / (rad s)"),
        ("trim", f"{gains.trim:.4f}", "rad (delta0 feed-forward)"),
        ("yaw_rate_max_deg_s", f"{turning.yaw_rate_max_deg_s:.2f}", "deg/s"),
        ("u_turn_time_s", f"{turning.u_turn_time_s:.2f}", "s"),
        (
            "turning_radius_m",
            f"{turning.turning_radius_m:.2f}" if args.speed is not None else "n/a",
            "m" if args.speed is not None else "(give --speed)",
        ),
    ]
    for name, value, unit in rows:
        print(f"{name:<20} {value:>10}  {unit}")
    if gains.clamped:
        print(f"clamped to bounds: {', '.join(gains.clamped)}")
    return 0
