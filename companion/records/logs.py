"""Readers for recorded data (SPEC C10, "analysing a recorded log (tlog/CSV)").

Both readers return a :class:`NavLog` of numpy arrays on one time base (vehicle time, s):

* **CSV** with a header row: required ``t`` (s), ``north``, ``east``, ``down`` (m), ``roll``,
  ``pitch``, ``yaw`` (rad), ``u``, ``v``, ``w`` (body velocity over ground, m/s); optional
  ``rudder`` (rad), ``thrust`` (ratio), ``force`` (N or N·m), and any other numeric column (kept in
  ``extra``). :func:`read_table_csv` reads a CSV with arbitrary required columns (for the η and
  inertia analyses).
* **MAVLink tlog** (pymavlink ``mavutil.mavlink_connection``): samples at each LOCAL_POSITION_NED
  (time_boot_ms), attitude interpolated from ATTITUDE (yaw unwrapped, interpolated, re-wrapped),
  NED velocity rotated to body axes with that attitude, rudder/thrust from the latest
  SERVO_OUTPUT_RAW decoded with the vehicle's autopilot profile
  (:mod:`companion.link.profiles`: which servo output reports each actuator and its PWM → SI
  mapping; default ``sim``, docs/PROTOCOL.md). A profile that reads no servo output back for an
  actuator (``ardusub``: mixed thrusters) leaves that channel ``None``; a PWM meaning "no data"
  (0, 65535, out of range) decodes to NaN.

Errors (missing file or column, empty or malformed file) raise :class:`LogError` with a message
that names the file and the problem.
"""
from __future__ import annotations

import csv
import logging
import math
import os
from dataclasses import dataclass, field

import numpy as np

from companion.link.profiles import SIM, AutopilotProfile, get_profile
from companion.numerics.angles import wrap_pi
from companion.numerics.steady_state import ned_to_body

log = logging.getLogger(__name__)

__all__ = ["LogError", "NavLog", "read_csv", "read_table_csv", "read_tlog", "read_log", "REQUIRED_COLUMNS"]

REQUIRED_COLUMNS = ("t", "north", "east", "down", "roll", "pitch", "yaw", "u", "v", "w")
OPTIONAL_COLUMNS = ("rudder", "thrust", "force")


class LogError(ValueError):
    """A recorded log cannot be read (missing/empty/malformed file or a missing column)."""


@dataclass
class NavLog:
    """Navigation samples on one vehicle-time base; optional channels are None when absent."""

    t: np.ndarray
    north: np.ndarray
    east: np.ndarray
    down: np.ndarray
    roll: np.ndarray
    pitch: np.ndarray
    yaw: np.ndarray
    u: np.ndarray
    v: np.ndarray
    w: np.ndarray
    rudder: np.ndarray | None = None
    thrust: np.ndarray | None = None
    force: np.ndarray | None = None
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    source: str = ""

    def __len__(self) -> int:
        return int(self.t.size)

    @property
    def vel_body(self) -> np.ndarray:
        return np.column_stack([self.u, self.v, self.w])

    def select(self, mask: np.ndarray) -> "NavLog":
        """A copy with only the samples where ``mask`` is true."""
        pick = lambda a: None if a is None else a[mask]  # noqa: E731
        return NavLog(
            t=self.t[mask], north=self.north[mask], east=self.east[mask], down=self.down[mask],
            roll=self.roll[mask], pitch=self.pitch[mask], yaw=self.yaw[mask],
            u=self.u[mask], v=self.v[mask], w=self.w[mask],
            rudder=pick(self.rudder), thrust=pick(self.thrust), force=pick(self.force),
            extra={k: v[mask] for k, v in self.extra.items()}, source=self.source,
        )


def _check_file(path: str) -> None:
    if not os.path.exists(path):
        raise LogError(f"{path}: no such file")
    if os.path.getsize(path) == 0:
        raise LogError(f"{path}: the file is empty")


def read_table_csv(path: str, required: tuple[str, ...] = ()) -> dict[str, np.ndarray]:
    """Read a CSV with a header row into ``{column: float array}``; every ``required`` column must
    be present and every value numeric and finite."""
    _check_file(path)
    try:
        with open(path, newline="") as handle:
            reader = csv.reader(handle)
            header = next(reader, None)
            if not header:
                raise LogError(f"{path}: the file is empty (no header row)")
            header = [name.strip() for name in header]
            rows = [row for row in reader if row and any(cell.strip() for cell in row)]
    except UnicodeDecodeError as exc:
        raise LogError(f"{path}: not a text CSV file ({exc})") from exc
    missing = [name for name in required if name not in header]
    if missing:
        raise LogError(f"{path}: missing column(s) {', '.join(missing)} (header: {', '.join(header)})")
    if not rows:
        raise LogError(f"{path}: no data rows after the header")
    data = np.empty((len(rows), len(header)))
    for line, row in enumerate(rows, start=2):
        if len(row) != len(header):
            raise LogError(f"{path}: line {line} has {len(row)} fields, the header has {len(header)}")
        for col, cell in enumerate(row):
            try:
                data[line - 2, col] = float(cell)
            except ValueError:
                raise LogError(f"{path}: line {line}, column {header[col]!r}: {cell!r} is not a number") from None
    if not np.all(np.isfinite(data)):
        raise LogError(f"{path}: non-finite value (nan/inf) in the data")
    return {name: data[:, i].copy() for i, name in enumerate(header)}


def read_csv(path: str) -> NavLog:
    """Read a navigation CSV (columns: see the module docstring), sorted by time."""
    table = read_table_csv(path, REQUIRED_COLUMNS)
    order = np.argsort(table["t"], kind="stable")
    table = {k: v[order] for k, v in table.items()}
    if np.any(np.diff(table["t"]) <= 0):
        raise LogError(f"{path}: repeated time stamps in column 't'")
    known = set(REQUIRED_COLUMNS) | set(OPTIONAL_COLUMNS)
    return NavLog(
        **{name: table[name] for name in REQUIRED_COLUMNS},
        **{name: table.get(name) for name in OPTIONAL_COLUMNS},
        extra={k: v for k, v in table.items() if k not in known},
        source=path,
    )


def _resolve_profile(profile: AutopilotProfile | str) -> AutopilotProfile:
    return get_profile(profile) if isinstance(profile, str) else profile


def read_tlog(path: str, profile: AutopilotProfile | str = SIM) -> NavLog:
    """Read a MAVLink telemetry log (see the module docstring) with pymavlink; actuator PWM is
    decoded with ``profile`` (an :class:`AutopilotProfile` or its name; default the simulator's)."""
    from pymavlink import mavutil

    profile = _resolve_profile(profile)
    rudder_output = profile.servo_outputs.get("rudder")
    thrust_output = profile.servo_outputs.get("thrust")
    _check_file(path)
    try:
        conn = mavutil.mavlink_connection(path, notimestamps=False)
    except Exception as exc:  # pymavlink raises assorted errors for unreadable files
        raise LogError(f"{path}: cannot open as a MAVLink log ({exc})") from exc
    attitude: list[tuple[float, float, float, float]] = []
    position: list[tuple[float, ...]] = []
    servo: list[tuple[float, float, float]] = []
    nan = math.nan
    try:
        while True:
            msg = conn.recv_match(type=["ATTITUDE", "LOCAL_POSITION_NED", "SERVO_OUTPUT_RAW"], blocking=False)
            if msg is None:
                break
            kind = msg.get_type()
            if kind == "ATTITUDE":
                attitude.append((msg.time_boot_ms / 1000.0, msg.roll, msg.pitch, msg.yaw))
            elif kind == "LOCAL_POSITION_NED":
                position.append((msg.time_boot_ms / 1000.0, msg.x, msg.y, msg.z, msg.vx, msg.vy, msg.vz))
            else:
                servo.append((
                    msg.time_usec / 1e6,
                    profile.pwm_to_angle(_servo_raw(msg, rudder_output)) if rudder_output else nan,
                    profile.pwm_to_thrust(_servo_raw(msg, thrust_output)) if thrust_output else nan,
                ))
    except Exception as exc:
        raise LogError(f"{path}: malformed MAVLink log ({exc})") from exc
    finally:
        try:
            conn.close()
        except Exception:  # noqa: BLE001 - closing a file-backed connection must not mask the result
            pass
    if not position:
        raise LogError(f"{path}: no LOCAL_POSITION_NED messages (not a vehicle tlog, or empty)")
    if len(attitude) < 2:
        raise LogError(f"{path}: fewer than 2 ATTITUDE messages: cannot rotate velocity to body axes")
    att = np.array(sorted(attitude))
    pos = np.array(sorted(position))
    _, unique = np.unique(pos[:, 0], return_index=True)
    pos = pos[unique]
    t = pos[:, 0]
    roll = np.interp(t, att[:, 0], att[:, 1])
    pitch = np.interp(t, att[:, 0], att[:, 2])
    yaw_unwrapped = np.interp(t, att[:, 0], np.unwrap(att[:, 3]))
    yaw = wrap_pi(yaw_unwrapped)
    vel_body = ned_to_body(roll, pitch, yaw, pos[:, 4:7])
    rudder = thrust = None
    if servo:
        srv = np.array(sorted(servo))
        idx = np.clip(np.searchsorted(srv[:, 0], t, side="right") - 1, 0, len(srv) - 1)  # latest sample (hold)
        rudder = srv[idx, 1] if rudder_output else None
        thrust = srv[idx, 2] if thrust_output else None
    return NavLog(
        t=t, north=pos[:, 1], east=pos[:, 2], down=pos[:, 3], roll=roll, pitch=pitch, yaw=yaw,
        u=vel_body[:, 0], v=vel_body[:, 1], w=vel_body[:, 2], rudder=rudder, thrust=thrust,
        source=path,
    )


def _servo_raw(msg, output: int) -> float:
    """PWM of servo output ``output`` (1-based) in a SERVO_OUTPUT_RAW; 0 ("no data") when absent
    (outputs 9-16 are MAVLink 2 extension fields)."""
    return getattr(msg, f"servo{output}_raw", 0) or 0


def read_log(path: str, profile: AutopilotProfile | str = SIM) -> NavLog:
    """Read a CSV (``.csv``, already in SI units: ``profile`` unused) or a MAVLink log (anything
    else: ``.tlog``, ``.bin``…, actuators decoded with ``profile``)."""
    if path.lower().endswith(".csv"):
        return read_csv(path)
    return read_tlog(path, profile)
