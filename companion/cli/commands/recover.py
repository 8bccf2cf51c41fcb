"""``companion recover``: follow the trail of a procedure whose process died (``kill -9``, a power
cut on the companion computer) and put the vehicle back as that procedure found it."""
from __future__ import annotations

import argparse
import sys

from companion.cli.commands._common import (ConnectFailed, add_connect_arguments, add_recovery_argument,
                                            add_store_argument, connected_vehicle, follow_interrupted_trails,
                                            print_json)


def add_parser(subparsers) -> None:
    parser = subparsers.add_parser(
        "recover", help="put the vehicle back after a procedure whose process died",
        description="A procedure stores how it found the vehicle before its first change and records every "
                    "change. If the companion died during one, this finds it in the store, says what is still "
                    "changed on the vehicle (parameters, mode, thrust, RC overrides held) and puts it back "
                    "(asked on a terminal; --yes for scripts). After a reboot of the vehicle only the "
                    "parameters are put back: a fresh boot keeps its own mode and set-points. `identify` and "
                    "`run` do the same before they start.")
    add_connect_arguments(parser)
    add_store_argument(parser)
    add_recovery_argument(parser)
    parser.add_argument("--json", action="store_true", help="print what was found and done as JSON")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from companion.procedures.trail import interrupted
    from companion.records.store import Store

    with Store(args.store) as store:
        open_before = [t.campaign_id for t in interrupted(store)]
        if not open_before:
            print("nothing to recover: no interrupted procedure in the store", file=sys.stderr)
            if args.json:
                print_json({"interrupted": [], "recovered": []})
            return 0
        try:
            with connected_vehicle(args) as (link, abort):
                ok = follow_interrupted_trails(link, store, args, guard=getattr(abort, "guard", None))
        except ConnectFailed as exc:
            print(exc, file=sys.stderr)
            return 1
        left = [t.campaign_id for t in interrupted(store)]
    if args.json:
        print_json({"interrupted": open_before, "recovered": [c for c in open_before if c not in left],
                    "left": left})
    return 0 if ok and not left else 1
