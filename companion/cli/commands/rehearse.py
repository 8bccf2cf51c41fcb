"""``companion rehearse``: the self-contained rehearsal on the built-in simulator (the main job)."""
from __future__ import annotations

import argparse
import sys
from dataclasses import replace

from companion.cli.commands._campaign_text import loop_lines, phase_line, verification_lines
from companion.cli.commands._common import add_procedure_argument, apply_procedure, add_schedules_argument, print_json, thrust_list
from companion.procedures.registry import PROCEDURES, rehearsal_behaviors


def add_parser(subparsers) -> None:
    parser = subparsers.add_parser(
        "rehearse", help="start the simulator, identify, design and write gains, run the behaviours, report",
        description="The self-contained rehearsal: starts the simulator as a child process, runs the "
                    "identification campaign over MAVLink, designs and writes speed-scheduled heading "
                    "gains, checks them with heading steps, runs roll stabilisation and minimum-speed "
                    "seeking, and writes the store and an HTML report.")
    parser.add_argument("--preset", default="starfish", help="simulator vehicle preset (default: %(default)s)")
    parser.add_argument("--speedup", type=float, default=50.0, help="simulation speed-up over real time (default: %(default)s)")
    parser.add_argument("--seed", type=int, default=1, help="simulator noise seed (default: %(default)s)")
    parser.add_argument("--out", default="rehearsal", help="output directory for the store and the report (default: %(default)s)")
    parser.add_argument("--thrusts", type=thrust_list, default=None, help="thrust settings, e.g. 0.6,0.7,0.8 (default: 60..100%%)")
    parser.add_argument("--axes", default=None,
                        help="axes to identify: yaw and/or pitch (default: yaw,pitch; yaw on ArduPilot)")
    parser.add_argument("--no-steps", action="store_true", help="skip the heading-step checks")
    add_schedules_argument(parser)
    add_procedure_argument(parser)
    parser.add_argument("--thesis-estimator", action="store_true",
                        help="the seeds' exact estimator (P0 = 100·I, zero-order holds) instead of the defaults")
    names = [PROCEDURES[name].cli_name for name in rehearsal_behaviors()]
    parser.add_argument("--behaviors", default=None,
                        help=f"behaviours to run after the campaign: {','.join(names)} or 'none' "
                             "(default: the preset's own, its JSON's rehearsal section: both on STARFISH presets, "
                             "none on hugin and the boats)")
    parser.add_argument("--steady-state", action=argparse.BooleanOptionalAction, default=None,
                        help="run the steady-state squares and turns (default: on for hugin)")
    parser.add_argument("--current", default=None, metavar="VN,VE",
                        help="water current north,east in m/s (default: still water; hugin: 0.007,-0.012)")
    parser.add_argument("--autopilot", choices=("builtin", "ardurover", "ardusub", "px4-rover", "px4-uuv"),
                        default="builtin",
                        help="builtin: our own autopilot (default); ardurover/ardusub: the real ArduPilot firmware "
                             "(SITL, JSON backend) flying our physics (boat preset for ardurover); px4-rover/px4-uuv: "
                             "the real PX4 firmware (SITL, MAVLink HIL) flying our boat / our AUV trimmed neutral")
    parser.add_argument("--ardupilot-bin", metavar="DIR", default=None,
                        help="ArduPilot SITL binaries (build/sitl/bin); default $ARDUPILOT_SITL_BIN")
    parser.add_argument("--px4-bin", metavar="DIR", default=None,
                        help="PX4 SITL build folder (with bin/px4 and etc/); default $PX4_SITL_BIN")
    parser.add_argument("--perturb", type=perturbation_list, action="append", default=[], metavar="NAME=FACTOR",
                        help="fly a variant of the preset: multiply a parameter group by a factor, e.g. mass=1.1,b2=0.8 "
                             "(mass, b2, a22, trim, elevator, drag, thrust or SECTION.FIELD; repeatable)")
    parser.add_argument("--noise", type=noise_factor, default=1.0, metavar="FACTOR",
                        help="sensor-noise level: factor on every sensor σ of the preset (default: %(default)s)")
    parser.add_argument("--no-report", action="store_true", help="do not write report.html (the summary and store only)")
    parser.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    parser.set_defaults(func=run)


def perturbation_list(text: str) -> tuple[tuple[str, float], ...]:
    """``mass=1.1,b2=0.8`` -> (("mass", 1.1), ("b2", 0.8)) (argparse type; names and factors checked)."""
    from companion.records.variants import VariantError, check_perturbation

    out = []
    for item in (part.strip() for part in text.split(",") if part.strip()):
        name, sep, value = item.partition("=")
        try:
            factor = float(value)
            if not sep:
                raise ValueError
            check_perturbation(name.strip(), factor)
        except ValueError as exc:
            detail = str(exc) if isinstance(exc, VariantError) else f"expected NAME=FACTOR, not {item!r}"
            raise argparse.ArgumentTypeError(detail) from None
        out.append((name.strip(), factor))
    if not out:
        raise argparse.ArgumentTypeError("expected NAME=FACTOR[,NAME=FACTOR...]")
    return tuple(out)


def noise_factor(text: str) -> float:
    """A finite factor >= 0 on the sensor noise (argparse type)."""
    from companion.cli.commands._common import finite_float

    value = finite_float(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"the noise factor must be >= 0, not {text!r}")
    return value


def run(args: argparse.Namespace) -> int:
    from companion.procedures.app import AbortFlag, install_signal_handlers
    from companion.procedures.campaign import CampaignConfig
    from companion.rehearsal.rehearsal import RehearsalConfig, SimulatorError, preset_defaults, rehearse

    args.axes_given = args.axes is not None
    axes = tuple(a.strip() for a in (args.axes or "yaw,pitch").split(",") if a.strip())
    if not axes or any(a not in ("yaw", "pitch") for a in axes):
        print("--axes takes yaw and/or pitch", file=sys.stderr)
        return 2
    import os

    if args.autopilot in ("ardurover", "px4-rover") and args.preset == "starfish":
        args.preset = "boat"  # the rover firmwares fly the boat preset unless told otherwise
    ardupilot_bin = args.ardupilot_bin or os.environ.get("ARDUPILOT_SITL_BIN")
    px4_bin = args.px4_bin or os.environ.get("PX4_SITL_BIN")
    if args.autopilot.startswith("px4-") and not px4_bin:
        print(f"--autopilot {args.autopilot} needs --px4-bin DIR (or PX4_SITL_BIN): a PX4 SITL build folder built "
              "from PX4's sources", file=sys.stderr)
        return 2
    if args.autopilot in ("ardurover", "ardusub") and not ardupilot_bin:
        print(f"--autopilot {args.autopilot} needs --ardupilot-bin DIR (or ARDUPILOT_SITL_BIN): the folder of "
              "ArduPilot SITL binaries built from ArduPilot's sources", file=sys.stderr)
        return 2
    try:
        defaults = preset_defaults(args.preset)
    except ValueError as exc:  # a vehicle file whose rehearsal section cannot be used
        print(exc, file=sys.stderr)
        return 2
    try:
        if args.current is None:
            current: tuple[float, float] = defaults["current"]
        else:
            north, east = (float(v) for v in args.current.split(","))  # ValueError unless two numbers
            current = (north, east)
    except ValueError:
        print("--current takes VN,VE in m/s", file=sys.stderr)
        return 2
    # the autopilot's thrusts, axes and doublets (ArduRover: fractions of WP_SPEED) where the user set none:
    # applied once, by the campaign (CampaignConfig.resolved_for)
    explicit = tuple(name for name, given in (("axes", args.axes_given), ("thrusts", bool(args.thrusts))) if given)
    campaign = CampaignConfig(axes=axes, schedules=args.schedules, user_set=explicit)
    if args.thrusts:
        campaign = replace(campaign, thrusts=args.thrusts)
    if args.no_steps:
        campaign = replace(campaign, step_labels=())
    campaign = apply_procedure(campaign, args)
    if args.thesis_estimator:
        campaign = campaign.with_thesis_estimator()
    if args.behaviors is None:
        # ArduSub: no rolling mass, and the minimum-speed seeker drives a depth loop ALT_HOLD keeps
        behaviors = () if args.autopilot != "builtin" else defaults["behaviors"]
    elif args.behaviors == "none":
        behaviors = ()
    else:
        behaviors = tuple(b.strip().replace("-", "_") for b in args.behaviors.split(",") if b.strip())
    known = rehearsal_behaviors()
    unknown = set(behaviors) - set(known)
    if unknown:
        print(f"unknown behaviour(s) {', '.join(sorted(unknown))}: use "
              f"{', '.join(PROCEDURES[name].cli_name for name in known)} or none", file=sys.stderr)
        return 2
    steady = defaults["steady_state"] if args.steady_state is None else args.steady_state
    perturb = dict(pair for group in args.perturb for pair in group)  # a name given twice: the last wins
    config = RehearsalConfig(preset=args.preset, speedup=args.speedup, seed=args.seed, out_dir=args.out,
                             campaign=campaign, behaviors=behaviors, current=current, steady_state=steady,
                             progress=not args.json, autopilot=args.autopilot, ardupilot_bin=ardupilot_bin,
                             px4_bin=px4_bin,
                             perturb=tuple(sorted(perturb.items())), noise=args.noise, report=not args.no_report)
    abort = AbortFlag()
    undo = install_signal_handlers(abort)
    try:
        summary = rehearse(config, abort)
    except SimulatorError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    finally:
        undo()
    if args.json:
        print_json(summary)
    else:
        print_summary(summary)
    return 0 if summary.get("status") == "completed" else 1


def _fmt(value, spec: str) -> str:
    return format(value, spec) if isinstance(value, (int, float)) else "-"


def print_summary(summary: dict) -> None:
    print(f"rehearsal on preset {summary['preset']} at {summary['speedup']:g}x: {summary.get('status')}"
          + (f" ({summary['reason']})" if summary.get("reason") else ""))
    line = phase_line(summary.get("vehicle_time_s"), summary.get("vehicle_time_by_phase") or {})
    if line:
        print(line)
    rows = summary.get("runs") or []
    if rows:
        print("\nyaw models (identified vs the simulator's linearised truth) and designed gains")
        print(f"{'thrust':>6} {'speed':>6} {'a22':>8} {'true':>8} {'b2':>7} {'true':>7} {'delta0':>7} {'R2':>6} "
              f"{'conv s':>6} {'Kp':>6} {'Ki':>7}")
        for r in rows:
            print(f"{_fmt(r['thrust'], '6.2f')} {_fmt(r['speed'], '6.2f')} {_fmt(r['a22'], '8.3f')} "
                  f"{_fmt(r['true_a22'], '8.3f')} {_fmt(r['b2'], '7.3f')} {_fmt(r['true_b2'], '7.3f')} "
                  f"{_fmt(r['delta0'], '7.4f')} {_fmt(r['r2'], '6.3f')} {_fmt(r['converged_s'], '6.1f')} "
                  f"{_fmt(r['kp'], '6.3f')} {_fmt(r['ki'], '7.4f')}")
    steps = summary.get("heading_steps") or []
    if steps and not summary.get("verified"):  # the verification's table below says more
        labels = sorted({s["label"] for s in steps})
        print("\n±20° heading steps, max overshoot %")
        print(f"{'thrust':>6} " + " ".join(f"{label:>10}" for label in labels))
        for thrust in sorted({s["thrust"] for s in steps}):
            cells = {s["label"]: s["max_overshoot_pct"] for s in steps if s["thrust"] == thrust}
            print(f"{thrust:6.2f} " + " ".join(f"{_fmt(cells.get(label), '10.1f')}" for label in labels))
    lines = verification_lines(summary.get("verified")) + loop_lines(summary.get("loops"), summary.get("heading_design"))
    if lines:
        print()
        print("\n".join(lines))
    roll = summary.get("roll")
    if roll:
        print(f"\nroll stabilisation: std {_fmt(roll.get('std_open_deg'), '.2f')} deg open loop -> "
              f"{_fmt(roll.get('std_closed_deg'), '.2f')} deg closed loop; 25 deg impulse settles in "
              f"{_fmt(roll.get('kick_settle_closed_s'), '.1f')} s (open loop {_fmt(roll.get('kick_settle_open_s'), '.1f')} s)")
    seek = summary.get("min_speed")
    if seek:
        print(f"minimum-speed seeking: thrust ratio {_fmt(seek.get('thrust_ratio_final'), '.3f')} "
              f"(analytic TR* {_fmt(seek.get('thrust_ratio_star'), '.3f')}), speed {_fmt(seek.get('speed_final'), '.3f')} m/s "
              f"(Vmin {_fmt(seek.get('v_min'), '.3f')}), "
              + (f"settled after {_fmt(seek.get('settle_time_s'), '.0f')} s, " if seek.get("settle_time_s") is not None
                 else "NOT settled, ")
              + f"max depth error {_fmt(seek.get('max_depth_error_m'), '.2f')} m")
    steady = summary.get("steady_state")
    if steady and steady.get("squares"):
        sq = steady["squares"]
        print(f"\nsquares: surge {_fmt(sq.get('surge_water'), '.3f')} m/s, sway {_fmt(sq.get('sway_water'), '.4f')} m/s, "
              f"current {_fmt(1000 * sq['current_speed'] if sq.get('current_speed') is not None else None, '.1f')} mm/s "
              f"towards {_fmt(sq.get('current_dir_deg'), '.0f')} deg, cond(H) {_fmt(sq.get('condition_number'), '.2f')}")
    for turn in (steady or {}).get("turns", []):
        print(f"turn at rudder {_fmt(turn.get('rudder_deg'), '+.1f')} deg: R {_fmt(turn.get('radius_m'), '.2f')} m, "
              f"{_fmt(turn.get('turn_rate_deg_s'), '.2f')} deg/s, residual {_fmt(turn.get('residual_std_m'), '.3f')} m")
    print(f"\nreport: {summary.get('report')}\nstore:  {summary.get('store')}  "
          f"(companion results --store {summary.get('store')})\nwall time: {summary.get('wall_time_s')} s")
