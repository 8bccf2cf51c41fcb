"""Argument helpers shared by the subcommands."""
from __future__ import annotations

import argparse
import json
import math
import os
from contextlib import contextmanager
import sys
from pathlib import Path

from companion.cli.endpoints import endpoint_argument

DEFAULT_STORE = "companion.sqlite"


def add_store_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--store", default=os.environ.get("COMPANION_STORE", DEFAULT_STORE),
                        help="SQLite store (default: $COMPANION_STORE or ./%(default)s)")


def add_connect_arguments(parser: argparse.ArgumentParser, required: bool = True) -> None:
    parser.add_argument("--connect", required=required, metavar="ENDPOINT", type=endpoint_argument,
                        help="pymavlink connection string, e.g. udpin:0.0.0.0:14551, udpout:127.0.0.1:14550, "
                             "tcp:127.0.0.1:5760, /dev/ttyUSB0,57600")
    parser.add_argument("--profile", choices=("sim", "ardusub", "ardurover", "px4-rover", "px4-uuv"), default=None,
                        help="autopilot profile (default: detected from the parameter names)")
    parser.add_argument("--signing-key", metavar="HEX", default=None, type=signing_key_argument,
                        help="MAVLink 2 signing key as 64 hex characters (32 bytes)")
    vehicle = parser.add_argument_group("vehicle properties (over the profile's defaults)")
    vehicle.add_argument("--rudder-full-scale", type=_positive, default=None, metavar="RAD",
                         help="rudder deflection at full steering output (ArduPilot profiles: 0.5236 rover, 0.35 sub)")
    vehicle.add_argument("--rudder-rate", type=_positive, default=None, metavar="RAD_S",
                         help="rudder servo slew rate: where the autopilot reports its commanded output (ArduPilot), "
                              "the identifier uses the deflection such a servo makes of it")


def finite_float(text: str) -> float:
    """A finite number (argparse type): nan and inf are refused."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, not {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, not {text!r}")
    return value


def positive_float(text: str) -> float:
    """A finite number > 0 (argparse type)."""
    value = finite_float(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"expected a positive finite number, not {text!r}")
    return value


_positive = positive_float  # the name the vehicle options were written with


def vehicle_properties(args: argparse.Namespace) -> dict:
    """The ``--rudder-*`` options as AutopilotProfile fields."""
    out = {}
    if getattr(args, "rudder_full_scale", None) is not None:
        out["angle_full_scale_rad"] = args.rudder_full_scale
    if getattr(args, "rudder_rate", None) is not None:
        out["actuator_rate_rad_s"] = args.rudder_rate
    return out


def parse_signing_key(text: str) -> bytes:
    """The 32-byte MAVLink 2 signing key written as 64 hex characters; ValueError otherwise (an
    empty key too: it must never mean "run unsigned")."""
    if not text.strip():
        raise ValueError("the key is empty: give its 64 hex characters, or leave the option out to run unsigned")
    try:
        key = bytes.fromhex(text.strip())
    except ValueError:
        raise ValueError("the key must be hexadecimal") from None
    if len(key) != 32:
        raise ValueError(f"the key must be 32 bytes (64 hex characters), not {len(key)}")
    return key


def signing_key_argument(text: str) -> str:
    """:func:`parse_signing_key` as an argparse type (checked at parse time; the text is kept)."""
    try:
        parse_signing_key(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def signing_key(args: argparse.Namespace) -> bytes | None:
    """The key of ``--signing-key``, or None when the option was not given."""
    text = getattr(args, "signing_key", None)
    if text is None:
        return None
    try:
        return parse_signing_key(text)
    except ValueError as exc:
        raise SystemExit(f"--signing-key: {exc}") from None


def thrust_list(text: str) -> tuple[float, ...]:
    """'0.6,0.7' or '60,70' (percent, the whole list) -> (0.6, 0.7) (argparse type; the rules are
    ``companion.checks.parse_thrust_levels``)."""
    from companion.checks import parse_thrust_levels

    try:
        return parse_thrust_levels(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def schedule_list(text: str) -> tuple[str, ...]:
    """``heading,pitch`` -> the registered gain schedules named (argparse type)."""
    from behaviors.schedules import GAIN_SCHEDULES

    names = tuple(n.strip() for n in text.split(",") if n.strip())
    unknown = [n for n in names if n not in GAIN_SCHEDULES]
    if not names or unknown:
        raise argparse.ArgumentTypeError(f"gain schedules are {', '.join(GAIN_SCHEDULES)} (got {text!r})")
    return names


def add_schedules_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--schedules", type=schedule_list, default=("heading",), metavar="NAMES",
                        help="gain schedules to design and write: heading and/or pitch (default: heading; "
                             "pitch needs the pitch axis identified)")


def add_procedure_argument(parser: argparse.ArgumentParser) -> None:
    """``--procedure quick|thesis`` (default quick) and ``--quick``, its older spelling."""
    parser.add_argument("--procedure", choices=("quick", "thesis"), default="quick",
                        help="quick (default): settle only until steady, yaw and pitch identified together, "
                             "short validation records, the noise-aware stopping rule, heading gains for ζ = 0.75; "
                             "thesis: the seeds' fixed timings (40 s settles, 16.5 s records), eq. 3.39 and eq. 3.57")
    parser.add_argument("--quick", dest="procedure", action="store_const", const="quick", help=argparse.SUPPRESS)


def print_json(value) -> None:
    from companion.records.store import json_safe

    json.dump(json_safe(value), sys.stdout, indent=1, allow_nan=False)
    sys.stdout.write("\n")


def ensure_parent(path: str) -> Path:
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    return p


class ConnectFailed(Exception):
    """The vehicle did not answer (the message is printed; exit code 1)."""


@contextmanager
def connected_vehicle(args: argparse.Namespace):
    """Signals → abort flag, connect (``--connect``, ``--profile``, ``--signing-key``), and always
    close and restore the signal handlers. Yields ``(link, abort)``; raises ConnectFailed."""
    from companion.procedures.app import AbortFlag, install_signal_handlers
    from companion.link.errors import LinkError
    from companion.link.vehicle import VehicleLink

    abort = AbortFlag()
    undo = install_signal_handlers(abort)
    try:
        try:
            link = VehicleLink.connect(args.connect, profile=args.profile, signing_key=signing_key(args),
                                       vehicle=vehicle_properties(args))
        except LinkError as exc:  # no heartbeat, endpoint that cannot be opened, ...
            raise ConnectFailed(f"error: {exc}") from exc
        try:
            yield link, abort
        finally:
            link.close()
    finally:
        undo()
