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
import warnings
from dataclasses import dataclass, field

import numpy as np

from companion.link.profiles import SIM, AutopilotProfile, get_profile
from companion.numerics.angles import wrap_pi
from companion.numerics.steady_state import heading_rate, ned_to_body

log = logging.getLogger(__name__)

__all__ = ["LogError", "NavLog", "read_csv", "read_table_csv", "read_tlog", "read_log", "REQUIRED_COLUMNS",
           "check_navigation_units"]

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
    if os.path.isdir(path):
        raise LogError(f"{path}: is a directory, not a log file")
    if not os.path.isfile(path):
        raise LogError(f"{path}: not a regular file")
    if os.path.getsize(path) == 0:
        raise LogError(f"{path}: the file is empty")


#: text encoding of CSV files: UTF-8, with the byte-order mark Excel writes skipped when present
CSV_ENCODING = "utf-8-sig"


def read_table_csv(path: str, required: tuple[str, ...] = ()) -> dict[str, np.ndarray]:
    """Read a CSV with a header row into ``{column: float array}``; every ``required`` column must
    be present and every value numeric and finite.

    UTF-8 with or without a byte-order mark (an Excel export). Memory: the values are parsed
    straight into one float64 array (numpy's C reader, no per-row Python objects), so the peak
    is about 8 bytes per value plus the reader's growth margin, below twice the file's size for
    usual number widths (``bench/bench_csv_memory.py``). The columns returned are views of that
    one array. A file the fast reader refuses is read again line by line for the exact message.
    """
    _check_file(path)
    header = _csv_header(path)
    missing = [name for name in required if name not in header]
    if missing:
        raise LogError(f"{path}: missing column(s) {', '.join(missing)} (header: {', '.join(header)})")
    try:
        with open(path, encoding=CSV_ENCODING, newline="") as handle, warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # "input contained no data": said below, in our words
            data = np.loadtxt(handle, delimiter=",", skiprows=1, ndmin=2, comments=None, quotechar='"',
                              dtype=np.float64)
    except ValueError:  # a malformed line, a blank-but-not-empty line: the slow reader says which or copes
        data = _read_rows_slowly(path, len(header))
    except UnicodeDecodeError as exc:
        raise LogError(f"{path}: not a UTF-8 text CSV file ({exc.reason} at byte {exc.start})") from None
    if data.shape[0] == 0:
        raise LogError(f"{path}: no data rows after the header")
    if data.shape[1] != len(header):
        raise LogError(f"{path}: line 2 has {data.shape[1]} fields, the header has {len(header)}")
    bad = ~np.isfinite(data)
    if bad.any():
        row, col = (int(i) for i in np.argwhere(bad)[0])
        raise LogError(f"{path}: non-finite value (nan/inf) in column {header[col]!r} of data row {row + 1}")
    return {name: data[:, i] for i, name in enumerate(header)}


def _csv_header(path: str) -> list[str]:
    """The header row's column names (stripped); LogError when the file has none or is not text."""
    try:
        with open(path, encoding=CSV_ENCODING, newline="") as handle:
            header = next(csv.reader(handle), None)
    except UnicodeDecodeError as exc:
        raise LogError(f"{path}: not a UTF-8 text CSV file ({exc.reason} at byte {exc.start})") from None
    if not header or not any(name.strip() for name in header):
        raise LogError(f"{path}: the file is empty (no header row)")
    names = [name.strip() for name in header]
    repeated = sorted({name for name in names if names.count(name) > 1})
    if repeated:
        raise LogError(f"{path}: column(s) {', '.join(map(repr, repeated))} appear more than once in the header")
    return names


def _read_rows_slowly(path: str, width: int, chunk_rows: int = 65536) -> np.ndarray:
    """The data rows parsed line by line (blank lines skipped), in chunks of ``chunk_rows`` rows so the
    memory stays bounded; LogError naming the line and column of the first bad field."""
    chunks: list[np.ndarray] = []
    buffer = np.empty((chunk_rows, width))
    filled = 0
    with open(path, encoding=CSV_ENCODING, newline="") as handle:
        reader = csv.reader(handle)
        header = [name.strip() for name in next(reader)]
        for row in reader:
            if not row or not any(cell.strip() for cell in row):
                continue
            line = reader.line_num
            if len(row) != width:
                raise LogError(f"{path}: line {line} has {len(row)} fields, the header has {width}")
            for col, cell in enumerate(row):
                try:
                    buffer[filled, col] = float(cell)
                except ValueError:
                    raise LogError(f"{path}: line {line}, column {header[col]!r}: {cell!r} is not a number") from None
            filled += 1
            if filled == chunk_rows:
                chunks.append(buffer)
                buffer, filled = np.empty((chunk_rows, width)), 0
    chunks.append(buffer[:filled])
    return chunks[0] if len(chunks) == 1 else np.concatenate(chunks)


def read_csv(path: str) -> NavLog:
    """Read a navigation CSV (columns: see the module docstring), sorted by time."""
    table = read_table_csv(path, REQUIRED_COLUMNS)
    if not np.all(table["t"][1:] > table["t"][:-1]):  # a log out of order is sorted (a copy); in order, not
        order = np.argsort(table["t"], kind="stable")
        table = {k: v[order] for k, v in table.items()}
        if np.any(np.diff(table["t"]) <= 0):
            raise LogError(f"{path}: repeated time stamps in column 't'")
    known = set(REQUIRED_COLUMNS) | set(OPTIONAL_COLUMNS)
    return NavLog(
        t=table["t"], north=table["north"], east=table["east"], down=table["down"], roll=table["roll"],
        pitch=table["pitch"], yaw=table["yaw"], u=table["u"], v=table["v"], w=table["w"],  # REQUIRED_COLUMNS
        rudder=table.get("rudder"), thrust=table.get("thrust"), force=table.get("force"),  # OPTIONAL_COLUMNS
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


# --------------------------------------------------------------------------- plausibility of units
#: the largest heading rate (5 s smoothed) accepted from a marine vehicle's log, rad/s; a yaw column
#: in degrees read as radians turns 57× too fast and lands far above it
MAX_HEADING_RATE = math.radians(60.0)
#: the largest body velocity component accepted, m/s (≈ 50 kn); cm/s or mm/s land far above it
MAX_SPEED = 25.0
#: positions and body velocities must agree on the distance travelled within this factor
DISTANCE_RATIO_LIMIT = 2.0


def check_navigation_units(nav: NavLog) -> None:
    """Refuse (LogError, one sentence) a log whose numbers cannot be in the documented units: roll
    beyond ±π or pitch beyond ±π/2 rad, a yaw that starts beyond ±2π or jumps there (degrees), a
    heading rate above 60°/s, a velocity above 25 m/s, positions and velocities that disagree on the
    distance travelled by more than a factor 2 (one of them in other units)."""
    where = nav.source or "the log"
    for name, limit, text in (("roll", math.pi, "±π"), ("pitch", math.pi / 2, "±π/2")):
        worst = float(np.max(np.abs(getattr(nav, name))))
        if worst > limit + 1e-3:
            raise LogError(f"{where}: {name} reaches {worst:.4g}, beyond {text} rad: the column looks like degrees "
                           "(convert to radians)")
    _check_yaw(nav, where)
    for name in ("u", "v", "w"):
        worst = float(np.max(np.abs(getattr(nav, name))))
        if worst > MAX_SPEED:
            raise LogError(f"{where}: {name} reaches {worst:.4g}, beyond {MAX_SPEED:g} m/s: the velocities look like "
                           "another unit (cm/s, mm/s…); convert to m/s")
    _check_distance(nav, where)


def _check_yaw(nav: NavLog, where: str) -> None:
    """Yaw in radians: wrapped within ±2π, or unwrapped (continuous) from a start within ±2π; the heading
    rate within :data:`MAX_HEADING_RATE`."""
    yaw = nav.yaw
    worst = float(np.max(np.abs(yaw)))
    continuous = bool(np.all(np.abs(np.diff(yaw)) < math.pi)) if len(nav) > 1 else True
    if abs(float(yaw[0])) > 2 * math.pi + 1e-3 or (worst > 2 * math.pi + 1e-3 and not continuous):
        raise LogError(f"{where}: yaw reaches {worst:.4g}, beyond ±2π rad: the column looks like degrees "
                       "(convert to radians)")
    if len(nav) >= 3:
        rate = float(np.max(np.abs(heading_rate(nav.t, yaw))))
        if rate > MAX_HEADING_RATE:
            raise LogError(f"{where}: the heading turns at up to {math.degrees(rate):.0f}°/s, beyond "
                           f"{math.degrees(MAX_HEADING_RATE):.0f}°/s: is yaw in degrees (convert to radians)?")


def _check_distance(nav: NavLog, where: str, baseline_s: float = 10.0) -> None:
    """Distance along the track from the positions (chords ≥ ``baseline_s`` apart, so position noise
    does not add up) against the integral of the horizontal body speed; skipped below 10 m."""
    if len(nav) < 3:
        return
    by_speed = float(np.sum(np.hypot(nav.u, nav.v)[1:] * np.diff(nav.t)))
    picks = np.searchsorted(nav.t, np.arange(nav.t[0], nav.t[-1], baseline_s))
    picks = np.unique(np.append(picks, len(nav) - 1))
    by_position = float(np.sum(np.hypot(np.diff(nav.north[picks]), np.diff(nav.east[picks]))))
    if max(by_speed, by_position) < 10.0:
        return
    ratio = by_position / by_speed if by_speed > 0 else math.inf
    if not 1 / DISTANCE_RATIO_LIMIT <= ratio <= DISTANCE_RATIO_LIMIT:
        raise LogError(f"{where}: the positions travel {by_position:.4g} m and the velocities {by_speed:.4g} m "
                       f"(ratio {ratio:.3g}): north/east and u/v must be in m and m/s")
