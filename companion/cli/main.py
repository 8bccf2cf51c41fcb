"""The ``companion`` command line (SPEC C10).

Each subcommand lives in its own module under :mod:`companion.cli.commands` and exposes
``add_parser(subparsers)`` (which registers the subcommand and sets ``func``) and a ``run(args)``
returning the process exit code. This file only assembles them.
"""
from __future__ import annotations

import argparse
import importlib
import logging
import os
import sqlite3
import sys

from companion.errors import UserError
from companion.service.logs import configure_logging

#: subcommand modules, in the order ``companion --help`` lists them
SUBCOMMANDS = (
    "rehearse",
    "sweep",
    "identify",
    "run",
    "run_behavior",
    "sim",
    "status",
    "design",
    "minspeed",
    "analyze",
    "results",
    "recover",
)


def package_version() -> str:
    """The installed distribution's version (``companion --version``)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("marine-companion")
    except PackageNotFoundError:  # run from a source tree that was never installed
        return "unknown (not installed)"


def _selected(argv: list[str]) -> tuple[str, ...]:
    """Only the invoked subcommand's module is imported (some pull in scipy/matplotlib, ~1 s each);
    the top-level help imports them all."""
    for arg in argv:
        if arg.startswith("-"):
            continue
        name = arg.replace("-", "_")
        return (name,) if name in SUBCOMMANDS else SUBCOMMANDS
    return SUBCOMMANDS


def build_parser(names: tuple[str, ...] = SUBCOMMANDS) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="companion",
        description=(
            "Companion process for marine vehicles: self-identification, speed-scheduled heading "
            "gains, roll stabilisation and minimum-speed seeking over MAVLink."
        ),
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {package_version()}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    parser.add_argument("--log-format", choices=("auto", "text", "journal"), default=None,
                        help="log lines with timestamps (text) or for journald (journal: syslog priority prefix, "
                             "no timestamp); auto (default): journal when standard error is the journal")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in names:
        try:
            module = importlib.import_module(f"companion.cli.commands.{name}")
        except ModuleNotFoundError as exc:  # a subcommand still being built must not break the others
            if exc.name != f"companion.cli.commands.{name}":
                raise
            continue
        module.add_parser(subparsers)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = build_parser(_selected(argv))
    args = parser.parse_args(argv)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    configure_logging(args.log_format or "auto", level)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except UserError as exc:  # bad input or an unusable file: its one sentence, no traceback
        print(f"companion {args.command}: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except sqlite3.DatabaseError as exc:  # a damaged or unreadable store: a sentence and what to do
        store = getattr(args, "store", None) or "the store"
        damaged = "malformed" in str(exc) or "not a database" in str(exc)
        hint = (f"; it is damaged: move it aside (a new one is made at the next start), and "
                f"`sqlite3 {store} .recover` may save what it holds" if damaged else "")
        print(f"companion {args.command}: error: {store} could not be read: {exc}{hint}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # `companion results | head`: the reader left, stop quietly
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141


if __name__ == "__main__":
    sys.exit(main())
