"""``companion identify``: the identification campaign against any vehicle (SPEC C4, C5)."""
from __future__ import annotations

import argparse
import sys
from dataclasses import replace

from companion.cli.commands._campaign_text import loop_lines, phase_line, verification_lines
from companion.cli.commands._common import (ConnectFailed, add_connect_arguments, add_procedure_argument, apply_procedure,
                                            add_recovery_argument, add_schedules_argument, add_store_argument,
                                            connected_vehicle, follow_interrupted_trails, link_unfit_for_identification, link_quality_record,
                                            link_quality_line, print_json, refused,
                                            thrust_list)

#: the campaign's figures (``CampaignFigures``) ``identify --json`` prints, in the figures' order
PRINTED_FIGURES = ("accepted", "design", "steps", "checks", "verified", "vehicle_time_by_phase", "final_gains",
                   "speed_loop", "heading_design", "loops", "thrust_levels")


def add_parser(subparsers) -> None:
    parser = subparsers.add_parser(
        "identify", help="run the self-identification campaign on a vehicle and write scheduled heading gains",
        description="Settles, excites with rudder (and elevator) doublets, identifies online, validates on "
                    "fresh doublets at each thrust, designs speed-scheduled heading PI gains and writes them. "
                    "Ctrl-C (or MAV_CMD_USER_4 from the ground station) aborts and restores the autopilot.")
    add_connect_arguments(parser, required=False)
    parser.add_argument("--log", metavar="FILE", default=None,
                        help="identify offline from a recorded mission instead of a connected vehicle: a tlog, an "
                             "ArduPilot DataFlash .bin, a PX4 .ulg or a CSV (t, yaw, rudder, speed); ordinary course "
                             "changes at steady speed are enough (--profile decodes the actuators; default sim)")
    add_store_argument(parser)
    add_recovery_argument(parser)
    parser.add_argument("--thrusts", type=thrust_list, default=None,
                        help="thrust settings (default: the autopilot's: 60..100%% on our simulator and ArduRover, "
                             "45..65%% on ArduSub)")
    parser.add_argument("--depth", type=float, default=None, help="campaign depth in m (default: 2)")
    parser.add_argument("--axes", default=None,
                        help="axes to identify: yaw and/or pitch (default: yaw,pitch; yaw on ArduPilot)")
    parser.add_argument("--no-steps", action="store_true", help="skip the heading-step checks")
    parser.add_argument("--step-deg", type=float, default=None,
                        help="size of the heading-step checks in degrees (default: 20)")
    add_schedules_argument(parser)
    add_procedure_argument(parser)
    parser.add_argument("--thesis-estimator", action="store_true",
                        help="the seeds' exact estimator (P0 = 100·I, zero-order holds) instead of the defaults")
    parser.add_argument("--no-write", action="store_true", help="design the gains but do not write them")
    parser.add_argument("--r2-threshold", type=float, default=None, help="validation acceptance threshold (default: 0.61)")
    parser.add_argument("--max-distance", type=float, default=None, metavar="M",
                        help="abort and restore if the vehicle goes more than M metres over ground from where the "
                             "campaign started (default: not checked; the default campaign's straight runs add up "
                             "to about 2.6 km)")
    parser.add_argument("--report", metavar="DIR", default=None, help="also write the HTML report into DIR")
    parser.add_argument("--json", action="store_true", help="print the campaign result as JSON")
    parser.set_defaults(func=run)


def campaign_config(args: argparse.Namespace):
    from companion.procedures.campaign import CampaignConfig

    # the autopilot's defaults (thrusts, axes, doublets it can fly) apply where the user set none
    explicit = tuple(name for name, given in (("thrusts", args.thrusts), ("axes", args.axes)) if given)
    config = CampaignConfig(schedules=args.schedules, user_set=explicit)
    if args.axes is not None:
        axes = tuple(a.strip() for a in args.axes.split(",") if a.strip())
        if not axes or any(a not in ("yaw", "pitch") for a in axes):
            raise ValueError("--axes takes yaw and/or pitch")
        config = replace(config, axes=axes)
    if args.thrusts:
        config = replace(config, thrusts=args.thrusts)
    if args.depth is not None:
        config = replace(config, depth=args.depth)
    if args.no_steps:
        config = replace(config, step_labels=())
    if getattr(args, "step_deg", None) is not None:
        import math

        step = math.radians(args.step_deg)
        config = replace(config, step_test=replace(config.step_test, step=step),
                         verification=replace(config.verification, step=step))
    config = apply_procedure(config, args)
    if args.thesis_estimator:
        config = config.with_thesis_estimator()
    if args.no_write:
        config = replace(config, write_gains=False)
    if args.r2_threshold is not None:
        config = replace(config, yaw=replace(config.yaw, r2_threshold=args.r2_threshold),
                         pitch=replace(config.pitch, r2_threshold=args.r2_threshold))
    return config


def run(args: argparse.Namespace) -> int:
    if args.log is not None:
        from companion.cli.commands.identify_log import run_log

        return run_log(args)
    if args.connect is None:
        print("companion identify: error: one of --connect ENDPOINT (a vehicle) or --log FILE (a recorded "
              "mission) is required", file=sys.stderr)
        return 2
    from companion.procedures.app import ConsoleProgress, run_campaign, vehicle_record
    from companion.procedures.campaign_figures import loops_to_dict
    from companion.procedures.limits import SafetyLimits
    from companion.procedures.registry import report_sections
    from companion.records.report import write_report
    from companion.records.store import Store

    try:
        config = campaign_config(args)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return refused(args, str(exc), 2)
    try:
        with connected_vehicle(args) as (link, abort), Store(args.store) as store:
            try:
                limits = SafetyLimits.for_profile(link.profile, max_distance_m=args.max_distance)
            except ValueError as exc:
                print(f"error: {exc}", file=sys.stderr)
                return refused(args, str(exc), 2)
            if not follow_interrupted_trails(link, store, args, guard=getattr(abort, "guard", None)):
                return refused(args, "an interrupted procedure left the vehicle changed: run `companion recover "
                                     f"--connect {args.connect} --yes`, then start again")
            unfit = link_unfit_for_identification(link)
            if unfit is not None:  # what the link delivered while it was measured, frames lost included
                quality = link_quality_record(link)
                line = link_quality_line(quality)
                if line and not args.json:
                    print(line, file=sys.stderr)
                return refused(args, unfit, link_quality=quality)
            campaign, outcome, campaign_id = run_campaign(
                link, store, config, vehicle_id=vehicle_record(store, link), abort=abort, limits=limits,
                console=ConsoleProgress("identification", enabled=not args.json))
            link_quality = link_quality_record(link, campaign)
            if link_quality.get("warning"):
                print(f"warning: {link_quality['warning']}", file=sys.stderr)
            report = str(write_report(store, campaign_id, args.report, sections=report_sections())) if args.report and not outcome.store_problems \
                else None
    except ConnectFailed as exc:
        print(exc, file=sys.stderr)
        return refused(args, str(exc))
    figures = campaign.result().figures
    result = {"campaign_id": campaign_id, "status": outcome.status, "reason": outcome.reason,
              "restore_problems": outcome.restore_problems, "restore_notes": outcome.restore_notes,
              "store_problems": outcome.store_problems, "link_quality": link_quality,
              "store": args.store, "report": report,
              **{k: v for k, v in figures.to_dict().items() if k in PRINTED_FIGURES}}
    if args.json:
        print_json(result)
    else:
        print(f"campaign {campaign_id}: {outcome.status}" + (f" ({outcome.reason})" if outcome.reason else ""))
        for line in outcome.restore_problems:
            print(f"  NOT restored: {line}")
        for line in outcome.restore_notes + outcome.store_problems:
            print(f"  {line}")
        for a in figures.accepted:
            model = ", ".join(f"{k} {v:.4f}" for k, v in vars(a.model).items() if isinstance(v, float))
            print(f"  {a.axis:5s} thrust {a.thrust:.2f} speed {a.speed:.2f} m/s R2 {a.r2:.3f}: {model}")
        for line in figures.thrust_levels.respacing:
            print(f"  thrust levels: {line}")
        heading_design = figures.heading_design.to_dict() if figures.heading_design is not None else None
        for line in loop_lines(loops_to_dict(figures.loops), heading_design):
            print(f"  {line}")
        speed = figures.speed_loop
        if speed is not None:
            print(f"  speed loop: {speed.reason or speed.verdict}" + (f"; {speed.surge.describe()}"
                                                                    if speed.surge is not None else ""))
        verified = figures.verified.summary() if figures.verified is not None else None
        for line in filter(None, [phase_line(None, figures.vehicle_time_by_phase), *verification_lines(verified)]):
            print(f"  {line}")
        if figures.final_gains:
            print(f"  gains written: {figures.final_gains}")
        line = link_quality_line(result["link_quality"] or {})
        if line:
            print(f"  {line}")
        if report:
            print(f"  report: {report}")
    return 0 if outcome.status == "completed" else 1
