"""Argument helpers shared by the subcommands."""
from __future__ import annotations

import argparse
from dataclasses import replace
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
                        help=f"SQLite store (default: $COMPANION_STORE or ./{DEFAULT_STORE})")


def add_connect_arguments(parser: argparse.ArgumentParser, required: bool = True) -> None:
    from companion.link.profiles import PROFILES  # the registered autopilot modules: one line each

    parser.add_argument("--connect", required=required, metavar="ENDPOINT", type=endpoint_argument,
                        help="pymavlink connection string, e.g. udpin:0.0.0.0:14551, udpout:127.0.0.1:14550, "
                             "tcp:127.0.0.1:5760, /dev/ttyUSB0,57600")
    parser.add_argument("--profile", choices=sorted(PROFILES), default=None,
                        help="autopilot profile (default: detected from the parameter names)")
    parser.add_argument("--signing-key", metavar="HEX", default=None, type=signing_key_argument,
                        help="MAVLink 2 signing key as 64 hex characters (32 bytes)")
    parser.add_argument("--lockstep", action="store_true",
                        help="acknowledge vehicle time to our simulator started with --lockstep (its clock then "
                             "advances only as the companion reads it: same seed, same numbers)")
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
    parser.add_argument("--full-comparison", action="store_true",
                        help="fly the thesis' comparison: ±20° heading steps with the original, the constant "
                             "(QuickTune on ArduPilot) and the scheduled gains at every thrust (the quick procedure "
                             "flies the designed gains' step at the lowest and highest speed and predicts the rest)")


def apply_procedure(config, args: argparse.Namespace):
    """The campaign configuration for ``--procedure`` and ``--full-comparison``."""
    config = config.for_procedure(args.procedure)
    if getattr(args, "full_comparison", False) and config.step_labels:
        config = replace(config, checks="compare")
    return config


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
                                       vehicle=vehicle_properties(args), lockstep=getattr(args, "lockstep", False))
        except LinkError as exc:  # no heartbeat, endpoint that cannot be opened, ...
            raise ConnectFailed(f"error: {exc}") from exc
        try:
            yield link, abort
        finally:
            link.close()
    finally:
        undo()


def link_unfit_for_identification(link) -> str | None:
    """Measure what the link delivers (two vehicle seconds of telemetry); the sentence saying what to
    change (also printed) when it is too slow to identify from, else None; a slower link than asked
    for is said and accepted."""
    from companion.link.errors import LinkError
    from companion.procedures.readiness import measure_link_rate

    try:
        rate = measure_link_rate(link)
    except LinkError as exc:
        reason = f"the link rate could not be measured: {exc}"
        print(f"error: {reason}", file=sys.stderr)
        return reason
    verdict, warning = rate.verdict(), rate.warning()
    if verdict is not None:
        print(f"error: {verdict}", file=sys.stderr)
        return verdict
    if warning is not None:
        print(f"warning: {warning}", file=sys.stderr)
    return None


def refused(args, reason: str, code: int = 1, **details) -> int:
    """A command that did not start its work: with ``--json`` the refusal is JSON too (status
    ``refused``, the reason, and any ``details``: the link quality of a link refused as unfit),
    never an empty output; the exit code."""
    if getattr(args, "json", False):
        print_json({"campaign_id": None, "status": "refused", "reason": reason.removeprefix("error: "), **details})
    return code


#: the fraction of samples lost or late beyond which the link's quality is warned about
LINK_LOSS_WARNING = 0.05


def link_quality_record(link, campaign=None) -> dict:
    """What the link delivered (samples late, lost, duplicated; the vehicle's frames received, lost on
    the link and discarded as corrupt), the fraction of samples that came without their own output or
    too late to use (``lost_fraction``) and of frames lost (``frame_loss_fraction``), a ``warning``
    when either is above :data:`LINK_LOSS_WARNING` (None below), and how many identification records
    were not used because the link lost too much of them."""
    quality = dict(link.telemetry.quality()) if hasattr(link, "telemetry") else {}
    samples = quality.get("samples", 0)
    lost = quality.get("outputs_lost", 0) + quality.get("late_dropped", 0) + quality.get("dropped_unread", 0)
    frames_sent = quality.get("frames", 0) + quality.get("frames_lost", 0)
    parts = []
    if samples:
        quality["lost_fraction"] = lost / samples
        if lost / samples > LINK_LOSS_WARNING:
            parts.append(f"lost or delayed {100 * lost / samples:.1f} % of the samples")
    if frames_sent:
        fraction = quality["frames_lost"] / frames_sent
        quality["frame_loss_fraction"] = fraction
        if fraction > LINK_LOSS_WARNING:
            parts.append(f"lost {100 * fraction:.1f} % of the vehicle's frames ({quality['frames_lost']} of "
                         f"{frames_sent}; {quality.get('frames_corrupt', 0)} discarded as corrupt)")
    if samples or frames_sent:
        quality["warning"] = (f"the link {' and '.join(parts)} (above {100 * LINK_LOSS_WARNING:.0f} %): a faster or "
                              "cleaner link gives better models" if parts else None)
    if campaign is not None:
        quality["records_rejected"] = campaign.records_rejected_for_link
    return quality


def link_quality_line(quality: dict) -> str | None:
    """The text summary's line on the link (None when nothing was measured)."""
    if not quality.get("samples"):
        return None
    line = (f"link: {quality['samples']} samples, {quality.get('late', 0)} late, {quality.get('outputs_lost', 0)} "
            f"without their outputs, {100 * quality.get('lost_fraction', 0.0):.1f} % lost or late")
    if "frames" in quality:
        line += (f"; frames: {quality['frames']} received, {quality.get('frames_lost', 0)} lost on the link "
                 f"({100 * quality.get('frame_loss_fraction', 0.0):.1f} %), {quality.get('frames_corrupt', 0)} "
                 "discarded as corrupt")
    if quality.get("records_rejected"):
        line += f"; {quality['records_rejected']} identification records not used for it"
    return line + (f" — WARNING: {quality['warning']}" if quality.get("warning") else "")


def add_recovery_argument(parser: argparse.ArgumentParser) -> None:
    """``--yes``: put the vehicle back after an interrupted procedure without asking."""
    parser.add_argument("--yes", action="store_true",
                        help="if an earlier procedure was interrupted (its process died), put the vehicle back as "
                             "it found it without asking (for scripts and services)")


def follow_interrupted_trails(link, store, args: argparse.Namespace, guard=None) -> bool:
    """Before anything else on a vehicle: a procedure whose process died left a trail; say what it
    left changed and put the vehicle back (asked on a terminal, ``--yes`` for scripts). False when
    one is left unrecovered, or recovered only in part (the caller must not start another procedure;
    the trail stays open and the next start tries again)."""
    from companion.link.errors import LinkError
    from companion.procedures.trail import close_without_vehicle, interrupted, recover

    for trail in interrupted(store):
        print(f"campaign {trail.campaign_id} ({trail.kind}, started {trail.started_utc}) was interrupted: "
              f"the companion ({trail.owner.describe()}) stopped during it", file=sys.stderr)
        if trail.restore is None and not trail.changes:
            close_without_vehicle(store, trail)
            print("  it had changed nothing yet (or its restore had run): closed as interrupted", file=sys.stderr)
            continue

        def decide(found: list[str], trail=trail) -> bool | None:
            for line in found or ["nothing differs from how it was found"]:
                print(f"  {line}", file=sys.stderr)
            if getattr(args, "yes", False):
                return True
            if not sys.stdin.isatty():
                return None  # nobody to ask
            answer = input(f"Put the vehicle back as campaign {trail.campaign_id} found it? [y/N] ")
            return answer.strip().lower() in ("y", "yes")

        try:
            done = recover(link, store, trail, decide, guard=guard)
        except LinkError as exc:  # the trail stays open: the next start tries again
            print(f"  not put back: {type(exc).__name__}: {exc}; the trail stays open", file=sys.stderr)
            return False
        for note in done.notes:
            print(f"  {note}", file=sys.stderr)
        if not done.applied and not done.other_vehicle:
            print(f"  not put back: run `companion recover --connect {args.connect} --yes` (or answer y), "
                  "then start again", file=sys.stderr)
            return False
        for problem in done.problems:
            print(f"  could not put back: {problem}", file=sys.stderr)
        if done.applied and not done.complete:
            print(f"  put back except the items above; campaign {trail.campaign_id} stays open: fix them (or set "
                  f"them by hand) and run `companion recover --connect {args.connect} --yes` again",
                  file=sys.stderr)
            return False
        if done.applied:
            print(f"  put back; campaign {trail.campaign_id} closed as interrupted", file=sys.stderr)
    return True
