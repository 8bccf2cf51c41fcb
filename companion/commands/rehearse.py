"""``companion rehearse``: the self-contained rehearsal on the built-in simulator (the main job)."""
from __future__ import annotations

import argparse
import sys
from dataclasses import replace

from companion.commands._common import print_json, thrust_list


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
    parser.add_argument("--axes", default="yaw,pitch", help="axes to identify (default: %(default)s)")
    parser.add_argument("--no-steps", action="store_true", help="skip the heading-step checks")
    parser.add_argument("--thesis-estimator", action="store_true",
                        help="the seeds' exact estimator (P0 = 100·I, zero-order holds) instead of the defaults")
    parser.add_argument("--behaviors", default=None,
                        help="behaviours to run after the campaign: roll,min-speed or 'none' "
                             "(default: both on STARFISH presets, none on hugin)")
    parser.add_argument("--steady-state", action=argparse.BooleanOptionalAction, default=None,
                        help="run the steady-state squares and turns (default: on for hugin)")
    parser.add_argument("--current", default=None, metavar="VN,VE",
                        help="water current north,east in m/s (default: still water; hugin: 0.007,-0.012)")
    parser.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from companion.app import AbortFlag, install_signal_handlers
    from companion.campaign import CampaignConfig
    from companion.rehearsal import RehearsalConfig, SimulatorError, preset_defaults, rehearse

    axes = tuple(a.strip() for a in args.axes.split(",") if a.strip())
    if not axes or any(a not in ("yaw", "pitch") for a in axes):
        print("--axes takes yaw and/or pitch", file=sys.stderr)
        return 2
    defaults = preset_defaults(args.preset)
    try:
        current = defaults["current"] if args.current is None else tuple(float(v) for v in args.current.split(","))
        assert len(current) == 2
    except (ValueError, AssertionError):
        print("--current takes VN,VE in m/s", file=sys.stderr)
        return 2
    campaign = CampaignConfig(axes=axes)
    if args.thrusts:
        campaign = replace(campaign, thrusts=args.thrusts)
    if args.no_steps:
        campaign = replace(campaign, step_labels=())
    if args.thesis_estimator:
        campaign = campaign.with_thesis_estimator()
    if args.behaviors is None:
        behaviors = defaults["behaviors"]
    elif args.behaviors == "none":
        behaviors = ()
    else:
        behaviors = tuple(b.strip().replace("-", "_") for b in args.behaviors.split(",") if b.strip())
    unknown = set(behaviors) - {"roll", "min_speed"}
    if unknown:
        print(f"unknown behaviour(s) {', '.join(sorted(unknown))}: use roll, min-speed or none", file=sys.stderr)
        return 2
    steady = defaults["steady_state"] if args.steady_state is None else args.steady_state
    config = RehearsalConfig(preset=args.preset, speedup=args.speedup, seed=args.seed, out_dir=args.out,
                             campaign=campaign, behaviors=behaviors, current=current, steady_state=steady,
                             progress=not args.json)
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


def print_summary(summary: dict) -> None:
    print(f"rehearsal on preset {summary['preset']} at {summary['speedup']:g}x: {summary.get('status')}"
          + (f" ({summary['reason']})" if summary.get("reason") else ""))
    rows = summary.get("runs") or []
    if rows:
        print(f"{'thrust':>6} {'speed':>6} {'a22':>8} {'true':>8} {'b2':>7} {'true':>7} {'delta0':>7} {'R2':>6} {'conv s':>6} {'Kp':>6} {'Ki':>6}")
        for r in rows:
            f = lambda v, fmt: format(v, fmt) if isinstance(v, (int, float)) else "-"  # noqa: E731
            print(f"{f(r['thrust'], '6.2f')} {f(r['speed'], '6.2f')} {f(r['a22'], '8.3f')} {f(r['true_a22'], '8.3f')} "
                  f"{f(r['b2'], '7.3f')} {f(r['true_b2'], '7.3f')} {f(r['delta0'], '7.4f')} {f(r['r2'], '6.3f')} "
                  f"{f(r['converged_s'], '6.1f')} {f(r['kp'], '6.3f')} {f(r['ki'], '6.3f')}")
    for step in summary.get("heading_steps") or []:
        if step["label"] == "scheduled":
            print(f"heading step at thrust {step['thrust']:.2f} with scheduled gains: overshoot {step['max_overshoot_pct']}")
    for key in ("roll", "min_speed", "steady_state"):
        if summary.get(key):
            print(f"{key}: {summary[key]}")
    print(f"report: {summary.get('report')}\nstore:  {summary.get('store')}  (companion results --store {summary.get('store')})")
    print(f"wall time: {summary.get('wall_time_s')} s")
