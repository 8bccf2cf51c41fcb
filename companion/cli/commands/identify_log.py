"""``companion identify --log FILE``: identification from a recorded mission.

Reads the log (:mod:`companion.records.flight_logs`), finds the usable segments, identifies and
cross-validates each one and designs the gain schedules
(:mod:`companion.procedures.log_identification`), stores them as a campaign of kind ``"log"`` and
prints one line per segment (used or why not) and the models, or one JSON object (``--json``:
``campaign_id``, ``status``, ``reason``, ``log`` with the checks made, ``segments``, ``accepted``,
``design``, ``gains_written`` (always null: a log cannot verify gains), ``export`` (the command
that writes the designed gains as a parameter file, null without a design), ``store``, ``report``;
strict JSON, an undetermined number is null with its reason under ``null_reasons``).
Exit 0 when a model was accepted and the schedules designed, 1 otherwise or for an unreadable log.
"""
from __future__ import annotations

import argparse
import math
import sys
from dataclasses import replace

from companion.cli.commands._common import print_json

NULL_REASON = "not determined: no validation segment at a similar speed, or the estimate is undefined"


def log_config(args: argparse.Namespace):
    """The campaign configuration of ``identify`` options that apply to a log (schedules, estimator, R²)."""
    from companion.procedures.campaign import CampaignConfig
    from companion.procedures.log_identification import LogIdentificationConfig

    campaign = CampaignConfig(axes=("yaw",), schedules=tuple(getattr(args, "schedules", ("heading",))))
    if getattr(args, "thesis_estimator", False):
        campaign = campaign.with_thesis_estimator()
    if getattr(args, "r2_threshold", None) is not None:
        campaign = replace(campaign, yaw=replace(campaign.yaw, r2_threshold=args.r2_threshold))
    return LogIdentificationConfig(campaign=campaign)


def run_log(args: argparse.Namespace) -> int:
    from companion.link.profiles import get_profile
    from companion.procedures.log_identification import identify_log, log_summary, store_log_identification
    from companion.records.flight_logs import LogError, read_steering_log
    from companion.procedures.registry import report_sections
    from companion.records.report import write_report
    from companion.records.serialise import null_reasons, to_json
    from companion.records.store import Store

    profile = get_profile(args.profile or "sim")
    config = log_config(args)
    try:
        record = read_steering_log(args.log, profile, rudder_full_scale=getattr(args, "rudder_full_scale", None))
        result = identify_log(record, config, profile)
    except (LogError, ValueError) as exc:
        print(f"companion identify: error: {exc}", file=sys.stderr)
        return 1
    with Store(args.store) as store:
        campaign_id = store_log_identification(store, result, config, profile.name)
        report = str(write_report(store, campaign_id, args.report, sections=report_sections())) if args.report else None
    out = {"campaign_id": campaign_id, "status": result.status, "reason": result.reason, "profile": profile.name,
           "log": log_summary(record), "segments": [s.summary() for s in result.segments],
           "accepted": [a.summary() for a in result.accepted],
           "design": {name: to_json(d) for name, d in result.designs.items()} or None,
           "design_errors": result.design_errors, "gains_written": None, "store": args.store, "report": report}
    from companion.cli.commands.results import export_command

    out["export"] = export_command(args.store, campaign_id) if result.designs and result.status == "completed" else None
    reasons = null_reasons(out["segments"], NULL_REASON, "segments")
    if reasons:
        out["null_reasons"] = reasons
    if args.json:
        print_json(out)
    else:
        _print_table(out, result)
    return 0 if result.status == "completed" else 1


def _number(value, fmt: str) -> str:
    if isinstance(value, (int, float)) and math.isfinite(value):
        return format(value, fmt)
    width = fmt.split(".")[0]
    return format("–", f">{width}") if width.isdigit() else "–"


def _print_table(out: dict, result) -> None:
    info = out["log"]
    print(f"log {info['source']} ({info['format']}, {info['samples']} samples over {info['duration_s']:.0f} s; "
          f"rudder: {info['rudder_source']}; speed: {info['speed_source']})")
    print(f"{'#':>3} {'from s':>8} {'to s':>8} {'speed':>6} {'thrust':>6}  {'a22':>8} {'b2':>7} {'δ0':>7} "
          f"{'R²':>6} {'on':>3}  verdict")
    for item in out["segments"]:
        model = item.get("model") or {}
        number = item["number"] if item["number"] is not None else "-"
        verdict = ("accepted" if item.get("accepted") else "rejected by validation") if item.get("model") else ""
        reason = item["reason"] if not item.get("model") else f"{verdict}; {item['reason']}"
        print(f"{number:>3} {item['t_start']:8.1f} {item['t_end']:8.1f} {_number(item['speed'], '6.3f')} "
              f"{_number(item['thrust'], '6.2f')}  {_number(model.get('a22'), '8.4f')} {_number(model.get('b2'), '7.4f')} "
              f"{_number(model.get('delta0'), '7.4f')} {_number(item.get('r2'), '6.3f')} "
              f"{item['validated_on'] if item['validated_on'] is not None else '-':>3}  {reason}")
    print(f"campaign {out['campaign_id']} (log): {out['status']}" + (f" ({out['reason']})" if out["reason"] else "")
          + f"; {len(out['accepted'])} models accepted")
    for name, design in result.designs.items():
        print(f"  {name} schedule: {design.schedule.describe()}")
        for point in design.points[:1] + design.points[-1:] if len(design.points) > 1 else design.points:
            gains = ", ".join(f"{k} {v:.3f}" for k, v in point.scheduled.items())
            print(f"    at {point.speed:.2f} m/s: {gains}")
    print("  gains designed, not written: a log cannot check them with heading steps on the vehicle")
    if result.designs and out["status"] == "completed":
        from companion.cli.commands.results import export_command

        print(f"  as a parameter file for a ground station: {export_command(out['store'], out['campaign_id'])}"
              " [--speed M_S] [--format qgc]")
    if out["report"]:
        print(f"  report: {out['report']}")
