"""What yaw identification needs from the logs users already have: heading, rudder and
speed on one vehicle-time base, in SI units, with the checks that were made on the way.

Formats (chosen by content, not by the name alone: a DataFlash log starts with its FMT header
``A3 95 80``, a ULog with ``ULog\\x01\\x12\\x35``, a CSV is text):

* **MAVLink tlog** (ground station, our simulator or ArduPilot; pymavlink): heading from ATTITUDE
  (rad, ``time_boot_ms``), the rudder from SERVO_OUTPUT_RAW decoded with the boat's actuation when
  the log carries its SERVOn_FUNCTION (PARAM_VALUE, as a ground station records them: a steering
  servo 26/21 with a throttle 70, or a skid-steered pair 73/74 un-mixed, ``companion.link.actuation``,
  eq. S.1), else with the autopilot profile (our simulator: output 1 is the rudder deflection;
  ArduRover: output 1 the steering servo; ArduSub: the vectored thrusters un-mixed into the yaw
  demand), speed from VFR_HUD (its airspeed is the water speed on our simulator; a boat's ground
  speed otherwise) or LOCAL_POSITION_NED.
* **ArduPilot DataFlash .bin** (pymavlink DFReader): ATT.Yaw (degrees by its FMTU unit; a yaw
  beyond 360 is taken as centidegrees and said so), RCOU (servo PWM, decoded with the actuation
  the PARM messages describe: SERVOn_FUNCTION, SERVOn_MIN/TRIM/MAX/REVERSED, the skid mixer's MOT_*;
  the profile's steering output when the log has no PARM), speed from GPS.Spd or XKF1.VN/VE;
  ``TimeUS``. A log whose functions name no steering is refused with what to set.
* **PX4 ULog .ulg** (pyulog): vehicle_attitude.q (yaw from the quaternion), the steering from
  actuator_controls_0.control[2] (normalised yaw), actuator_servos.control[0] (a rover's steering),
  vehicle_torque_setpoint.xyz[2] (a UUV's yaw torque demand: its thrusters make it an equivalent
  rudder, ``companion.link.autopilots.px4_uuv``) or actuator_outputs.output[0] (PWM, or normalised
  on newer firmware: told apart by range), speed from vehicle_local_position.vx/vy; ``timestamp``
  in µs.
* **CSV** with a header: ``t`` (s), ``yaw`` (rad), ``rudder`` (rad) and a speed column (``speed``,
  ``u`` or ``speed_water``), optionally ``thrust``.

Units and time stamps are checked, never assumed (:class:`LogError` with one sentence otherwise):
time stamps increase (repeats dropped and counted), the sample interval is plausible, heading
within ±2π rad and turning at most 60°/s, speed below 25 m/s, rudder within ±π/2 rad, and the
actuator's time base matches the attitude's. Each check made is listed in ``SteeringRecord.checks``.
"""
from __future__ import annotations

import contextlib
import io
import logging
import math
import os
from dataclasses import dataclass, field

import numpy as np

from companion.link.actuation import Actuation, actuation_from_params
from companion.link.errors import ProfileError
from companion.link.profile import AutopilotProfile
from companion.link.profiles import SIM, get_profile
from companion.numerics.angles import wrap_pi
from companion.records.logs import MAX_HEADING_RATE, MAX_SPEED, LogError, read_table_csv

log = logging.getLogger(__name__)

__all__ = ["SteeringRecord", "read_steering_log", "log_format", "LogError"]

DATAFLASH_MAGIC = b"\xa3\x95\x80"
ULOG_MAGIC = b"ULog\x01\x12\x35"
#: the widest rudder deflection a log may report, rad (a fin beyond ±90° is another unit)
MAX_RUDDER = math.pi / 2
#: plausible attitude sample intervals, s (400 Hz … 0.5 Hz)
DT_RANGE = (0.0025, 2.0)
#: servo functions of ArduPilot's steering output: 26 GroundSteering (Rover), 21 Rudder
STEERING_FUNCTIONS = (26, 21)


@dataclass
class SteeringRecord:
    """Heading, rudder and speed of one log on the attitude's time base (SI; see module docstring)."""

    t: np.ndarray  # s, vehicle time, strictly increasing
    heading: np.ndarray  # rad, wrapped to (−π, π]
    rudder: np.ndarray  # rad, deflection (or equivalent rudder: normalised output × full scale)
    speed: np.ndarray  # m/s, water speed where the log has one, else over ground
    thrust: np.ndarray | None = None  # ratio, where the log has it
    rudder_limit: float | None = None  # rad: |rudder| at it is a saturated actuator (None: unknown)
    source: str = ""
    kind: str = ""  # "tlog", "bin", "ulg", "csv"
    rudder_source: str = ""
    speed_source: str = ""
    checks: list[str] = field(default_factory=list)
    actuation: Actuation | None = None  # read from the log's SERVOn_FUNCTION, where it has them

    def __len__(self) -> int:
        return int(self.t.size)

    @property
    def duration_s(self) -> float:
        return float(self.t[-1] - self.t[0]) if len(self) else 0.0


def log_format(path: str) -> str:
    """"bin", "ulg", "csv" or "tlog", from the file's first bytes (the name only for text)."""
    _check_file(path)
    with open(path, "rb") as handle:
        head = handle.read(16)
    if head.startswith(ULOG_MAGIC):
        return "ulg"
    if head.startswith(DATAFLASH_MAGIC):
        return "bin"
    if path.lower().endswith((".csv", ".txt")):
        return "csv"
    return "tlog"


def read_steering_log(path: str, profile: AutopilotProfile | str = SIM, *,
                      rudder_full_scale: float | None = None) -> SteeringRecord:
    """Read ``path`` (any format of the module docstring) and check it; ``profile`` decodes the
    actuators of MAVLink and DataFlash logs; ``rudder_full_scale`` (rad per unit of normalised
    output) overrides the profile's for logs that carry a normalised output (ArduPilot, PX4)."""
    profile = get_profile(profile) if isinstance(profile, str) else profile
    kind = log_format(path)
    full_scale = rudder_full_scale or profile.angle_full_scale_rad
    reader = {"tlog": _read_tlog, "bin": _read_dataflash, "ulg": _read_ulog, "csv": _read_csv}[kind]
    record = reader(path, profile, full_scale)
    record.kind, record.source = kind, path
    return _checked(record)


# --------------------------------------------------------------------------- helpers
def _check_file(path: str) -> None:
    if not os.path.exists(path):
        raise LogError(f"{path}: no such file")
    if not os.path.isfile(path):
        raise LogError(f"{path}: not a regular file")
    if os.path.getsize(path) == 0:
        raise LogError(f"{path}: the file is empty")


def _series(rows: list, what: str, path: str, minimum: int = 2) -> np.ndarray:
    if len(rows) < minimum:
        raise LogError(f"{path}: {what}")
    array = np.array(rows, dtype=float)
    order = np.argsort(array[:, 0], kind="stable")
    return array[order]


def _on(t: np.ndarray, times: np.ndarray, values: np.ndarray) -> np.ndarray:
    """``values`` (sampled at ``times``) at ``t``: linear between samples, held beyond the ends."""
    ok = np.isfinite(values)
    if ok.sum() < 2:
        return np.full(t.shape, np.nan)
    return np.interp(t, times[ok], values[ok])


def _time_base_check(path: str, what: str, attitude_t: np.ndarray, other_t: np.ndarray, checks: list[str]) -> None:
    """The other stream's clock must be the attitude's: overlapping spans (µs vs ms slips show here)."""
    lo, hi = max(attitude_t[0], other_t[0]), min(attitude_t[-1], other_t[-1])
    span = attitude_t[-1] - attitude_t[0]
    if hi - lo < 0.5 * span:
        raise LogError(f"{path}: the {what} time stamps ({other_t[0]:.6g}…{other_t[-1]:.6g} s) do not overlap the "
                       f"attitude's ({attitude_t[0]:.6g}…{attitude_t[-1]:.6g} s): another clock or another unit")
    checks.append(f"{what} time base overlaps the attitude's ({100 * (hi - lo) / max(span, 1e-9):.0f} %)")


def _checked(record: SteeringRecord) -> SteeringRecord:
    """Unit and time-stamp checks shared by every format (module docstring)."""
    where, checks = record.source, record.checks
    t = record.t
    if t.size < 10:
        raise LogError(f"{where}: fewer than 10 attitude samples")
    keep = np.concatenate([[True], np.diff(t) > 0])
    if not keep.all():
        checks.append(f"{int((~keep).sum())} repeated or out-of-order time stamps dropped")
        record = _select(record, keep)
        t = record.t
    dt = float(np.median(np.diff(t)))
    if not DT_RANGE[0] <= dt <= DT_RANGE[1]:
        raise LogError(f"{where}: median interval between attitude samples {dt:.3g} s: not a time in seconds "
                       f"(expected {DT_RANGE[0]}–{DT_RANGE[1]} s; check the time stamps' unit)")
    checks.append(f"time: {t.size} samples over {t[-1] - t[0]:.1f} s, median interval {1000 * dt:.1f} ms")
    heading = record.heading
    if np.nanmax(np.abs(heading)) > 2 * math.pi + 1e-3:
        raise LogError(f"{where}: heading reaches {np.nanmax(np.abs(heading)):.4g}, beyond ±2π rad: degrees?")
    unwrapped = np.unwrap(np.where(np.isfinite(heading), heading, 0.0))
    window = max(1, int(round(1.0 / dt)))
    if t.size > 2 * window:
        rate = np.abs(unwrapped[window:] - unwrapped[:-window]) / (t[window:] - t[:-window])
        worst = float(np.max(rate))
        if worst > MAX_HEADING_RATE:
            raise LogError(f"{where}: the heading turns at up to {math.degrees(worst):.0f}°/s (1 s average), beyond "
                           f"{math.degrees(MAX_HEADING_RATE):.0f}°/s: is it in degrees?")
        checks.append(f"heading: radians, at most {math.degrees(worst):.1f}°/s")
    record.heading = wrap_pi(heading)
    rudder = record.rudder
    if np.isfinite(rudder).sum() < 2:
        raise LogError(f"{where}: no actuator value could be read ({record.rudder_source or 'none found'})")
    worst = float(np.nanmax(np.abs(rudder)))
    if worst > MAX_RUDDER:
        raise LogError(f"{where}: the rudder reaches {worst:.4g} rad, beyond ±π/2: degrees or an unscaled output?")
    checks.append(f"rudder ({record.rudder_source}): within ±{worst:.3f} rad")
    speed = record.speed
    if np.isfinite(speed).sum() < 2:
        raise LogError(f"{where}: no speed could be read ({record.speed_source or 'none found'})")
    worst = float(np.nanmax(np.abs(speed)))
    if worst > MAX_SPEED:
        raise LogError(f"{where}: the speed reaches {worst:.4g}, beyond {MAX_SPEED:g} m/s: another unit (cm/s, knots…)?")
    checks.append(f"speed ({record.speed_source}): up to {worst:.2f} m/s")
    return record


def _select(record: SteeringRecord, mask: np.ndarray) -> SteeringRecord:
    return SteeringRecord(t=record.t[mask], heading=record.heading[mask], rudder=record.rudder[mask],
                          speed=record.speed[mask], thrust=None if record.thrust is None else record.thrust[mask],
                          rudder_limit=record.rudder_limit, source=record.source, kind=record.kind,
                          rudder_source=record.rudder_source, speed_source=record.speed_source, checks=record.checks,
                          actuation=record.actuation)


# --------------------------------------------------------------------------- MAVLink tlog
def _read_tlog(path: str, profile: AutopilotProfile, full_scale: float) -> SteeringRecord:
    from pymavlink import mavutil

    from companion.link.autopilots.vectored_mix import unmix_vectored

    try:
        conn = mavutil.mavlink_connection(path, notimestamps=False)
    except Exception as exc:  # noqa: BLE001 - pymavlink raises assorted errors for unreadable files
        raise LogError(f"{path}: cannot open as a MAVLink log ({exc})") from None
    attitude, servo, hud, position, params = [], [], [], [], {}
    last_ms = math.nan  # VFR_HUD carries no time: it takes the latest vehicle time seen before it
    rudder_output = profile.servo_outputs.get("rudder")
    thrust_output = profile.servo_outputs.get("thrust")
    mixed = profile.name == "ardusub"
    try:
        while True:
            msg = conn.recv_match(type=["ATTITUDE", "SERVO_OUTPUT_RAW", "VFR_HUD", "LOCAL_POSITION_NED",
                                        "PARAM_VALUE"], blocking=False)
            if msg is None:
                break
            kind = msg.get_type()
            if kind == "ATTITUDE":
                last_ms = msg.time_boot_ms
                attitude.append((msg.time_boot_ms / 1000.0, msg.yaw))
            elif kind == "SERVO_OUTPUT_RAW":
                pwm = [getattr(msg, f"servo{i}_raw", 0) or 0 for i in range(1, 17)]
                servo.append((_unwrap_usec(msg.time_usec, last_ms), pwm))
            elif kind == "VFR_HUD":
                if math.isfinite(last_ms):
                    hud.append((last_ms / 1000.0, msg.airspeed, msg.groundspeed))
            elif kind == "LOCAL_POSITION_NED":
                last_ms = msg.time_boot_ms
                position.append((msg.time_boot_ms / 1000.0, math.hypot(msg.vx, msg.vy)))
            elif kind == "PARAM_VALUE":
                params[str(msg.param_id).rstrip("\x00")] = float(msg.param_value)
    except Exception as exc:  # noqa: BLE001
        raise LogError(f"{path}: malformed MAVLink log ({exc})") from None
    finally:
        try:
            conn.close()
        except Exception:  # noqa: BLE001 - closing a file-backed connection must not mask the result
            pass
    att = _series(attitude, "fewer than 2 ATTITUDE messages (not a vehicle tlog?)", path)
    actuation = _log_actuation(params, profile, path) if not mixed else None
    decoded = []
    for time_s, pwm in servo:
        if mixed:
            axes = unmix_vectored(pwm)
            rudder_at = axes.yaw * full_scale if axes is not None else math.nan
            thrust_at = axes.forward if axes is not None else math.nan
        elif actuation is not None:
            steering, thrust_at = actuation.demands(pwm)
            rudder_at = steering * full_scale
        else:
            rudder_at = _scaled_angle(profile, pwm[rudder_output - 1], full_scale) if rudder_output else math.nan
            thrust_at = profile.pwm_to_thrust(pwm[thrust_output - 1]) if thrust_output else math.nan
        decoded.append((time_s, rudder_at, thrust_at))
    srv = _series(decoded, "no SERVO_OUTPUT_RAW messages: the log carries no actuator output", path)
    checks: list[str] = []
    t = att[:, 0]
    _time_base_check(path, "SERVO_OUTPUT_RAW", t, srv[:, 0], checks)
    rudder, thrust = _on(t, srv[:, 0], srv[:, 1]), _on(t, srv[:, 0], srv[:, 2])
    if hud:
        h = _series(hud, "", path, 1)
        water = profile.water_speed_sensor
        speed, speed_source = _on(t, h[:, 0], h[:, 1 if water else 2]), \
            "VFR_HUD.airspeed (water speed)" if water else "VFR_HUD.groundspeed"
    elif position:
        p = _series(position, "", path, 1)
        speed, speed_source = _on(t, p[:, 0], p[:, 1]), "LOCAL_POSITION_NED vx, vy (over ground)"
    else:
        raise LogError(f"{path}: no VFR_HUD or LOCAL_POSITION_NED messages: no speed")
    limit = params.get("RUD_MAX") if profile.name == "sim" else None
    if limit is not None:
        checks.append(f"rudder limit RUD_MAX {limit:.3f} rad from the log's parameters")
    if mixed:
        rudder_source = "SERVO_OUTPUT_RAW outputs 1-4 un-mixed (vectored frame yaw)"
    elif actuation is not None:
        rudder_source = f"SERVO_OUTPUT_RAW, {actuation.describe()} (PARAM_VALUE in the log)"
        checks.append(f"actuation from the log's SERVOn_FUNCTION: {actuation.kind}")
    else:
        rudder_source = f"SERVO_OUTPUT_RAW output {rudder_output} ({profile.name} profile)"
    return SteeringRecord(t=t, heading=att[:, 1], rudder=rudder, speed=speed,
                          thrust=thrust if np.isfinite(thrust).any() else None, rudder_limit=limit,
                          rudder_source=rudder_source, speed_source=speed_source, checks=checks,
                          actuation=actuation)


#: SERVO_OUTPUT_RAW.time_usec is a uint32: it wraps every 2³² µs (71.6 min of uptime)
USEC_WRAP_S = 2 ** 32 / 1e6


def _unwrap_usec(time_usec: int, attitude_ms: float) -> float:
    """``time_usec`` in s on the lap nearest the latest attitude time seen before it (ms; NaN: none)."""
    t = time_usec / 1e6
    if not math.isfinite(attitude_ms):
        return t
    return t + round((attitude_ms / 1000.0 - t) / USEC_WRAP_S) * USEC_WRAP_S


def _scaled_angle(profile: AutopilotProfile, pwm: float, full_scale: float) -> float:
    """Fin angle of a PWM with the profile's centre and half range and the given full scale."""
    angle = profile.pwm_to_angle(pwm)
    return angle / profile.angle_full_scale_rad * full_scale if math.isfinite(angle) else math.nan


# --------------------------------------------------------------------------- ArduPilot DataFlash
def _read_dataflash(path: str, profile: AutopilotProfile, full_scale: float) -> SteeringRecord:
    from pymavlink import DFReader

    said = io.StringIO()  # DFReader prints what it cannot parse ("bad msg at offset …") on stdout
    try:
        with contextlib.redirect_stdout(said):
            reader = DFReader.DFReader_binary(path, zero_time_base=True)
    except Exception as exc:  # noqa: BLE001
        raise LogError(f"{path}: cannot open as an ArduPilot DataFlash log ({exc})") from None
    att: list[tuple[float, float]] = []  # (time, yaw)
    rcou: list[tuple[float, ...]] = []  # (time, C1..C14)
    gps: list[tuple[float, float]] = []  # (time, speed)
    xkf: list[tuple[float, float]] = []  # (time, horizontal speed)
    params: dict[str, float] = {}
    units: dict[str, str] = {}
    try:
        with contextlib.redirect_stdout(said):
            _collect_dataflash(reader, att, rcou, gps, xkf, params, units)
    except Exception as exc:  # noqa: BLE001
        raise LogError(f"{path}: malformed DataFlash log ({exc})") from None
    bad = sum(1 for line in said.getvalue().splitlines() if line.startswith("bad msg"))
    return _dataflash_record(path, profile, full_scale, att, rcou, gps, xkf, params, units, bad)


def _collect_dataflash(reader, att: list, rcou: list, gps: list, xkf: list, params: dict, units: dict) -> None:
    """The ATT, RCOU, GPS, XKF1 rows and the PARM values of a DataFlash log, with the units its FMTU states."""
    while True:
        msg = reader.recv_match(type=["ATT", "RCOU", "GPS", "XKF1", "PARM"])
        if msg is None:
            break
        kind = msg.get_type()
        if kind == "PARM":
            params[str(msg.Name)] = float(msg.Value)
            continue
        if kind not in units:
            units[kind] = _unit(msg, "TimeUS")
        t = msg.TimeUS / 1e6
        if kind == "ATT":
            units.setdefault("ATT.Yaw", _unit(msg, "Yaw"))
            att.append((t, float(msg.Yaw)))
        elif kind == "RCOU":
            rcou.append((t, *[float(getattr(msg, f"C{i}", 0) or 0) for i in range(1, 15)]))
        elif kind == "GPS" and getattr(msg, "I", 0) == 0:
            gps.append((t, float(msg.Spd)))
        elif kind == "XKF1" and getattr(msg, "C", 0) == 0:
            xkf.append((t, math.hypot(msg.VN, msg.VE)))


def _dataflash_record(path: str, profile: AutopilotProfile, full_scale: float, att, rcou, gps, xkf, params, units,
                      bad: int) -> SteeringRecord:
    from companion.link.autopilots.vectored_mix import unmix_vectored

    a = _series(att, "fewer than 2 ATT messages", path)
    out = _series(rcou, "no RCOU messages: the log carries no servo output", path)
    checks = [f"TimeUS unit {units.get('ATT') or 'not stated'}: read as microseconds"]
    if bad:
        checks.append(f"{bad} DataFlash message(s) could not be parsed and were skipped")
    yaw_deg = a[:, 1]
    unit = units.get("ATT.Yaw") or ""
    if "cdeg" in unit or np.nanmax(np.abs(yaw_deg)) > 360.0 + 1e-6:
        yaw_deg = yaw_deg / 100.0
        checks.append(f"ATT.Yaw in centidegrees (unit {unit or 'not stated'}, values beyond 360): divided by 100")
    else:
        checks.append(f"ATT.Yaw in degrees (unit {unit or 'not stated'}, values within 0–360)")
    t = a[:, 0]
    _time_base_check(path, "RCOU", t, out[:, 0], checks)
    actuation = _log_actuation(params, profile, path) if profile.name != "ardusub" else None
    thrust = None
    if profile.name == "ardusub":
        axes = [unmix_vectored(list(row[1:7])) for row in out]
        values = np.array([x.yaw * full_scale if x is not None else math.nan for x in axes])
        rudder_source = "RCOU C1-C4 un-mixed (vectored frame yaw)"
    elif actuation is not None:
        demands = np.array([actuation.demands(list(row[1:])) for row in out])
        values, thrust = demands[:, 0] * full_scale, _on(a[:, 0], out[:, 0], demands[:, 1])
        rudder_source = f"RCOU, {actuation.describe()} (PARM in the log)"
        checks.append(f"actuation from the log's SERVOn_FUNCTION: {actuation.kind}")
    else:
        channel = _steering_channel(params, profile)
        trim = params.get(f"SERVO{channel}_TRIM", profile.pwm_center)
        low = params.get(f"SERVO{channel}_MIN", profile.pwm_center - profile.pwm_half_range)
        high = params.get(f"SERVO{channel}_MAX", profile.pwm_center + profile.pwm_half_range)
        pwm = out[:, channel]
        valid = (pwm >= 800) & (pwm <= 2200)
        normalised = np.where(pwm >= trim, (pwm - trim) / max(high - trim, 1.0), (pwm - trim) / max(trim - low, 1.0))
        values = np.where(valid, normalised * full_scale, np.nan)
        stated = "from PARM" if f"SERVO{channel}_TRIM" in params else "the profile's (no PARM in the log)"
        rudder_source = f"RCOU C{channel}, SERVO{channel} min/trim/max {low:.0f}/{trim:.0f}/{high:.0f} {stated}"
    rudder = _on(t, out[:, 0], values)
    if xkf:
        s = _series(xkf, "", path, 1)
        speed, speed_source = _on(t, s[:, 0], s[:, 1]), "XKF1 VN, VE (EKF velocity over ground)"
    elif gps:
        s = _series(gps, "", path, 1)
        speed, speed_source = _on(t, s[:, 0], s[:, 1]), "GPS.Spd (over ground)"
    else:
        raise LogError(f"{path}: no GPS or XKF1 messages: no speed")
    return SteeringRecord(t=t, heading=np.radians(yaw_deg), rudder=rudder, speed=speed,
                          thrust=thrust if thrust is not None and np.isfinite(thrust).any() else None,
                          rudder_limit=full_scale, rudder_source=rudder_source, speed_source=speed_source,
                          checks=checks, actuation=actuation)


def _unit(msg, column: str) -> str:
    try:
        return str(msg.fmt.get_unit(column) or "")
    except Exception:  # noqa: BLE001 - logs without FMTU have no units
        return ""


def _log_actuation(params: dict[str, float], profile: AutopilotProfile, path: str) -> Actuation | None:
    """The boat's actuation from the log's own parameters (None when it has no SERVOn_FUNCTION: the
    profile's outputs then); LogError with what to set when they name no steering."""
    if not any(name.startswith("SERVO") and name.endswith("_FUNCTION") for name in params):
        return None
    try:
        actuation = actuation_from_params(params, where=os.path.basename(path))
    except ProfileError as exc:
        raise LogError(str(exc)) from None
    if profile.name == "sim" and not actuation.skid:
        return None  # our simulator's rudder boats report the deflection and a 1000-2000 µs thrust: the profile's
    return actuation


def _steering_channel(params: dict[str, float], profile: AutopilotProfile) -> int:
    """The RCOU channel of the steering servo: SERVOn_FUNCTION 26/21 in the log, else the profile's."""
    for function in STEERING_FUNCTIONS:
        for n in range(1, 15):
            if params.get(f"SERVO{n}_FUNCTION") == function:
                return n
    return profile.servo_outputs.get("rudder", 1)


# --------------------------------------------------------------------------- PX4 ULog
def _read_ulog(path: str, profile: AutopilotProfile, full_scale: float) -> SteeringRecord:
    try:
        from pyulog import ULog
    except ImportError:  # pragma: no cover - a declared dependency
        raise LogError("reading .ulg logs needs pyulog (pip install pyulog)") from None
    wanted = ["vehicle_attitude", "actuator_controls_0", "actuator_servos", "vehicle_torque_setpoint", "actuator_outputs",
              "vehicle_local_position"]
    try:
        ulog = ULog(path, message_name_filter_list=wanted)
    except Exception as exc:  # noqa: BLE001
        raise LogError(f"{path}: cannot read as a PX4 ULog ({exc})") from None
    topics = {d.name: d.data for d in ulog.data_list if d.multi_id == 0}
    checks = [f"ULog topics: {', '.join(sorted(topics)) or 'none of ' + ', '.join(wanted)}"]
    if "vehicle_attitude" not in topics:
        raise LogError(f"{path}: no vehicle_attitude topic")
    att = topics["vehicle_attitude"]
    t = att["timestamp"] / 1e6
    q0, q1, q2, q3 = (np.asarray(att[f"q[{i}]"], dtype=float) for i in range(4))
    norm = np.sqrt(q0 ** 2 + q1 ** 2 + q2 ** 2 + q3 ** 2)
    if not np.all(np.abs(norm - 1.0) < 0.05):
        raise LogError(f"{path}: vehicle_attitude.q is not a unit quaternion (|q| {norm.min():.3g}…{norm.max():.3g})")
    checks.append("vehicle_attitude.q: unit quaternion (Hamilton, w first), yaw = atan2(2(wz+xy), 1−2(y²+z²))")
    heading = np.arctan2(2.0 * (q0 * q3 + q1 * q2), 1.0 - 2.0 * (q2 ** 2 + q3 ** 2))
    rudder = None
    for topic, column in (("actuator_controls_0", "control[2]"), ("actuator_servos", "control[0]"),
                          ("vehicle_torque_setpoint", "xyz[2]"), ("actuator_outputs", "output[0]")):
        data = topics.get(topic)
        if data is None or column not in data:
            continue
        times = data["timestamp"] / 1e6
        values = np.asarray(data[column], dtype=float)
        finite = values[np.isfinite(values)]
        if topic == "actuator_outputs" and finite.size and np.median(np.abs(finite)) > 2.0:
            values = np.where((values >= 800) & (values <= 2200), (values - 1500.0) / 500.0, np.nan)
            checks.append("actuator_outputs.output[0] in PWM µs (1500 ± 500 → ±1)")
        elif finite.size and np.max(np.abs(finite)) > 1.0 + 1e-6:
            raise LogError(f"{path}: {topic}.{column} reaches {np.max(np.abs(finite)):.4g}, beyond the normalised ±1")
        _time_base_check(path, topic, t, times, checks)
        rudder = _on(t, times, values * full_scale)
        rudder_source = f"{topic}.{column} × {full_scale:.4f} rad"
        break
    if rudder is None:
        raise LogError(f"{path}: no actuator_controls_0, actuator_servos, vehicle_torque_setpoint or actuator_outputs: "
                       "no steering output")
    position = topics.get("vehicle_local_position")
    if position is None:
        raise LogError(f"{path}: no vehicle_local_position topic: no speed")
    pt = position["timestamp"] / 1e6
    speed = _on(t, pt, np.hypot(position["vx"], position["vy"]))
    return SteeringRecord(t=t, heading=heading, rudder=rudder, speed=speed, rudder_limit=full_scale,
                          rudder_source=rudder_source, speed_source="vehicle_local_position vx, vy (over ground)",
                          checks=checks)


# --------------------------------------------------------------------------- CSV
SPEED_COLUMNS = ("speed", "speed_water", "u")


def _read_csv(path: str, profile: AutopilotProfile, full_scale: float) -> SteeringRecord:
    table = read_table_csv(path, ("t", "yaw", "rudder"))
    speed_column = next((c for c in SPEED_COLUMNS if c in table), None)
    if speed_column is None:
        raise LogError(f"{path}: no speed column (one of {', '.join(SPEED_COLUMNS)}, m/s)")
    order = np.argsort(table["t"], kind="stable")
    pick = lambda name: np.asarray(table[name], dtype=float)[order]  # noqa: E731
    return SteeringRecord(t=pick("t"), heading=pick("yaw"), rudder=pick("rudder"), speed=np.abs(pick(speed_column)),
                          thrust=pick("thrust") if "thrust" in table else None,
                          rudder_source="column rudder (rad)", speed_source=f"column {speed_column} (m/s)",
                          checks=["CSV: SI units as documented (t s, yaw rad, rudder rad, speed m/s)"])
