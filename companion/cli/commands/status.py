"""``companion status``: one live snapshot of a vehicle (SPEC C1, C10).

Connects, waits (up to ``--timeout`` seconds of wall clock) until the snapshot has every field this
autopilot reports — attitude, mode, depth, position, speeds and the actuators its profile reads back
— and prints it: a JSON object with ``--json`` (mode, armed, attitude in degrees, depth, speeds,
actuators, vehicle time, profile, and ``missing``: the fields that never arrived), a table
otherwise. Exit code 1 with a clear message on stderr when nothing answers.
"""
from __future__ import annotations

import argparse
import math
import sys

from companion.cli.commands._common import add_connect_arguments, print_json, signing_key


def add_parser(subparsers) -> None:
    parser = subparsers.add_parser("status", help="print a live snapshot of a vehicle",
                                   description=__doc__.splitlines()[0])
    add_connect_arguments(parser)
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--timeout", type=float, default=10.0,
                        help="seconds (wall clock) to wait for the vehicle (default: %(default)s)")
    parser.set_defaults(func=run)


def snapshot_record(link, telemetry) -> dict:
    """The status as a JSON-ready dict (angles in degrees, None for unknown values)."""
    def deg(value: float) -> float:
        return math.degrees(value) if math.isfinite(value) else math.nan

    return {
        "profile": link.profile.name,
        # what drives the boat, as read from the vehicle at connect (None: the profile's fixed outputs)
        "actuation": link.profile.actuation.describe() if link.profile.actuation is not None else None,
        "system_id": link.transport.system_id,
        "vehicle_time_s": telemetry.time_s,
        "mode": telemetry.mode,
        "armed": telemetry.armed,
        "attitude_deg": {"roll": deg(telemetry.roll), "pitch": deg(telemetry.pitch),
                         "yaw": deg(telemetry.yaw) % 360.0 if math.isfinite(telemetry.yaw) else math.nan},
        "rates_deg_s": {"roll": deg(telemetry.roll_rate), "pitch": deg(telemetry.pitch_rate),
                        "yaw": deg(telemetry.yaw_rate)},
        "depth_m": telemetry.depth,
        "position_ned_m": {"north": telemetry.north, "east": telemetry.east, "down": telemetry.down},
        "speed_water_m_s": telemetry.speed_water,
        "speed_ground_m_s": telemetry.speed_ground,
        "actuators": {"rudder_deg": deg(telemetry.rudder), "elevator_deg": deg(telemetry.elevator),
                      "thrust_ratio": telemetry.thrust_ratio, "mass_angle_deg": deg(telemetry.mass_angle)},
        "gcs_sysid": link.ground.gcs_sysid,
        "int_encoding": link.parameters.int_encoding,
    }


def missing_fields(link, telemetry) -> list[str]:
    """The snapshot fields this autopilot should report that are still unknown (NaN or empty)."""
    profile = link.profile
    wanted = ["roll", "pitch", "yaw", "depth", "north", "east", "speed_ground"]
    if profile.water_speed_sensor:
        wanted.append("speed_water")
    wanted += [{"rudder": "rudder", "elevator": "elevator", "thrust": "thrust_ratio"}[actuator]
               for actuator in profile.servo_outputs]
    missing = [name for name in wanted if not telemetry.finite(name)]
    if not telemetry.mode:
        missing.append("mode")
    return missing


def _table(record: dict) -> str:
    def fmt(value) -> str:
        if isinstance(value, float):
            return "-" if not math.isfinite(value) else f"{value:.3f}"
        return str(value)

    rows = []
    for key, value in record.items():
        if isinstance(value, dict):
            rows.append((key, "  ".join(f"{k}={fmt(v)}" for k, v in value.items())))
        else:
            rows.append((key, fmt(value)))
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"{k:<{width}}  {v}" for k, v in rows)


def run(args: argparse.Namespace) -> int:
    from companion.link.errors import LinkError
    from companion.link.vehicle import VehicleLink

    try:
        link = VehicleLink.connect(args.connect, profile=args.profile, signing_key=signing_key(args),
                                   heartbeat_timeout_s=args.timeout)
    except LinkError as exc:
        print(f"companion status: cannot reach a vehicle on {args.connect}: {exc}", file=sys.stderr)
        return 1
    try:
        import time

        deadline = time.monotonic() + args.timeout  # a process-level wait for the fields, not vehicle logic
        telemetry = link.next_telemetry(timeout_s=args.timeout)
        while missing_fields(link, telemetry) and time.monotonic() < deadline:
            telemetry = link.next_telemetry(timeout_s=max(0.1, deadline - time.monotonic()))
        record = snapshot_record(link, telemetry)
        record["missing"] = missing_fields(link, telemetry)
        if record["missing"]:
            print(f"companion status: no {', '.join(record['missing'])} within {args.timeout:g} s", file=sys.stderr)
    except LinkError as exc:
        print(f"companion status: {exc}", file=sys.stderr)
        return 1
    finally:
        link.close()
    if args.json:
        print_json(record)
    else:
        print(_table(record))
    return 0
