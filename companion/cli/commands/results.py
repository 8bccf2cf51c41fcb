"""``companion results``: what the store holds (campaigns, models, gains, behaviour results); the
designed gains of a campaign as parameter files ground stations load (``--export``)."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from companion.cli.commands._common import add_store_argument, positive_float, print_json


def add_parser(subparsers) -> None:
    parser = subparsers.add_parser("results", help="show what the store holds",
                                   description="Lists the campaigns in the store, or one campaign in detail.")
    add_store_argument(parser)
    parser.add_argument("--campaign", type=int, default=None, help="show this campaign in detail (default: list all)")
    parser.add_argument("--report", metavar="DIR", default=None, help="(re)write the HTML report of --campaign (or the latest) into DIR")
    parser.add_argument("--json", action="store_true", help="print JSON")
    parser.add_argument("--export", metavar="FILE", default=None,
                        help="write the designed gains of --campaign N as a parameter file a ground station loads: one "
                             "file per identified speed (FILE-<speed>ms.parm), or one at --speed")
    parser.add_argument("--speed", type=positive_float, default=None, metavar="M_S",
                        help="with --export: the gains the schedule gives at this speed, in one file")
    parser.add_argument("--format", choices=("parm", "qgc"), default=None,
                        help="with --export: parm (ArduPilot: MAVProxy param load, Mission Planner) or qgc "
                             "(QGroundControl .params, PX4); default: from the suffix, .params is qgc, else parm")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from companion.records.store import Store

    if not Path(args.store).exists():
        print(f"error: no store at {args.store} (run `companion rehearse` or `companion identify`, or pass --store)",
              file=sys.stderr)
        return 1
    if args.export is not None or args.speed is not None or args.format is not None:
        return export(args)
    with Store(args.store, read_only=True) as store:  # a reading command never writes to the file
        campaign_id = args.campaign
        if args.report:
            from companion.procedures.registry import report_sections
            from companion.records.report import write_report

            campaign_id = campaign_id or store.latest_campaign_id("identification")
            if campaign_id is None:
                print("error: no identification campaign in the store", file=sys.stderr)
                return 1
            print(f"report: {write_report(store, campaign_id, args.report, sections=report_sections())}", file=sys.stderr)
        if campaign_id is None:
            data = {"store": args.store, "schema_version": store.schema_version,
                    "campaigns": [_as_seen(c, gone) for gone in (_process_gone(store),) for c in store.campaigns()]}
            if args.json:
                print_json(data)
            else:
                print(f"{'id':>4} {'kind':16} {'status':10} {'vehicle':20} {'runs':>4} {'models':>6} started")
                for c in data["campaigns"]:
                    print(f"{c['id']:>4} {c['kind']:16} {c['status']:10} {c['vehicle'][:20]:20} {c['runs']:>4} "
                          f"{c['models']:>6} {c['started_utc']}" + (f"  ({c['reason']})" if c.get("reason") else ""))
            return 0
        try:
            campaign = _as_seen(store.campaign(campaign_id), _process_gone(store))
        except KeyError as exc:
            print(f"error: {exc.args[0]}", file=sys.stderr)
            return 1
        data = {
            "campaign": campaign,
            "runs": store.runs(campaign_id),
            "models": [vars(m) for m in store.models(campaign_id)],
            "gains": store.gains(campaign_id),
            "behaviors": [{k: v for k, v in b.items() if k != "result"} | {"summary": _short(b["result"])}
                          for b in store.behavior_results(campaign_id)],
        }
    if args.json:
        print_json(data)
        return 0
    print(f"campaign {campaign_id} ({campaign['kind']}) on {campaign['vehicle']}: {campaign['status']}")
    for r in data["runs"]:
        model = " ".join(f"{k} {v:.4f}" for k, v in r["model"].items() if isinstance(v, float))
        print(f"  run {r['id']:>3} {r['axis']:5} thrust {r['thrust'] or 0:.2f} try {r['attempt']} "
              f"speed {r['speed'] or float('nan'):.2f} R2 {r['r2'] if r['r2'] is not None else float('nan'):.3f} "
              f"{'accepted' if r['accepted'] else 'rejected'}: {model}")
    for g in data["gains"]:
        print(f"  gains at {g['speed']:.2f} m/s: {g['before']} -> {g['after']}")
    for b in data["behaviors"]:
        print(f"  {b['kind']}: {b['status']} {b['summary']}")
    return 0


def _short(result: dict) -> dict:
    """The scalar part of a behaviour result (time series left out)."""
    return {k: v for k, v in result.items() if isinstance(v, (int, float, str, bool)) or v is None}


def export(args: argparse.Namespace) -> int:
    """``--export FILE [--speed U] [--format parm|qgc]`` of ``--campaign N``."""
    from companion.cli.main import package_version
    from companion.records.gain_export import export_gains
    from companion.records.store import Store

    if args.export is None:
        print("companion results: error: --speed and --format go with --export FILE", file=sys.stderr)
        return 2
    if args.campaign is None:
        print("companion results: error: --export needs --campaign N (`companion results` lists the campaigns)",
              file=sys.stderr)
        return 2
    with Store(args.store, read_only=True) as store:
        paths = export_gains(store, args.campaign, args.export, speed=args.speed, fmt=args.format,
                             generator=f"marine-companion {package_version()}")
    for path in paths:
        print(path)
    return 0


def export_command(store: str, campaign_id: int) -> str:
    """The command that exports a campaign's designed gains (printed by ``identify --log``)."""
    import shlex

    return f"companion results --store {shlex.quote(store)} --campaign {campaign_id} --export gains.parm"


#: what a campaign still marked running is shown as once the process that ran it is gone
INTERRUPTED = "interrupted"


def _process_gone(store) -> set[int]:
    """Campaigns still marked ``running`` whose process is gone (a crash, a power cut): the store is
    only closed by the next start, a reading command says what happened meanwhile."""
    from companion.procedures.trail import interrupted

    return {trail.campaign_id for trail in interrupted(store)}


def _as_seen(campaign: dict, gone: set[int]) -> dict:
    if campaign["status"] != "running" or campaign["id"] not in gone:
        return campaign
    return {**campaign, "status": INTERRUPTED,
            "reason": "its process is gone; the next start (or `companion recover`) puts the vehicle back"}

