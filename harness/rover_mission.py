"""An ordinary survey on a real autopilot: a lawnmower of waypoints uploaded with the MAVLink mission
protocol and flown in AUTO, by a ground station of its own (pymavlink, its own serial port), the
way an operator's planner does it. For the benches and SITL tests of ``companion run --learn``, on
ArduRover (a boat at the surface) and ArduSub (an AUV at a depth): :class:`MissionVehicle`.

* :func:`lawnmower` — ``lanes`` lanes of ``lane_m`` metres, ``spacing_m`` apart, north and back,
  starting ``start_m`` north of home: (north, east) offsets in metres.
* :func:`upload_mission` — MISSION_COUNT, then a MISSION_ITEM_INT per MISSION_REQUEST(_INT), until
  MISSION_ACK (item 0 is home, as ArduPilot numbers a mission).
* :class:`MissionGroundStation` — connects, sets parameters, uploads, arms, switches to AUTO and
  records what the vehicle says (mode, position, the current waypoint) until stopped, in a thread.
"""
from __future__ import annotations

import logging
import math
import subprocess
import time
from dataclasses import dataclass, field
from typing import IO, Sequence

from companion.link.autopilots.ardurover import PROFILE as ARDUROVER
from companion.link.autopilots.ardusub import PROFILE as ARDUSUB
from companion.link.profile import PidTuningReport
from harness.mavlink_clients import connect_client
from harness.station_thread import StationThread

log = logging.getLogger(__name__)

EARTH_RADIUS_M = 6378137.0
MAV_CMD_NAV_WAYPOINT = 16
MAV_CMD_COMPONENT_ARM_DISARM = 400
MAV_CMD_DO_SET_MODE = 176
MAV_FRAME_GLOBAL_RELATIVE_ALT_INT = 6
MAV_MISSION_ACCEPTED = 0
ROVER_AUTO = 10
SUB_AUTO = 3
RAD_TO_DEG = 180.0 / math.pi
#: ArduRover's speed loop on PID_TUNING (its profile's ``speed_loop_report``)
SPEED_AXIS = ARDUROVER.speed_loop_report.axis if ARDUROVER.speed_loop_report is not None else 4
SPEED_MASK_BIT = ARDUROVER.speed_loop_report.mask_bit if ARDUROVER.speed_loop_report is not None else 2


@dataclass(frozen=True)
class MissionVehicle:
    """What differs between the vehicles a survey is flown on: AUTO's mode number, the waypoints'
    altitude (m above home: ArduSub's home is the surface, so a depth is negative) and the
    PID_TUNING report of its heading rate loop (axis and units, from the autopilot's profile)."""

    auto_mode: int
    altitude_m: float
    pid_tuning: PidTuningReport

    def __post_init__(self) -> None:
        if not (isinstance(self.auto_mode, int) and self.auto_mode >= 0):
            raise ValueError(f"MissionVehicle.auto_mode must be a mode number, not {self.auto_mode!r}")
        if not math.isfinite(self.altitude_m):
            raise ValueError(f"MissionVehicle.altitude_m must be finite, not {self.altitude_m!r}")
        if not isinstance(self.pid_tuning, PidTuningReport):
            raise ValueError(f"MissionVehicle.pid_tuning must be a PidTuningReport, not {self.pid_tuning!r}")

    @property
    def pid_mask(self) -> int:
        """The GCS_PID_MASK value that asks for the heading rate loop's PID_TUNING."""
        return self.pid_tuning.mask_bit


def _report(profile) -> PidTuningReport:
    if profile.pid_tuning is None:
        raise ValueError(f"{profile.name} sends no PID_TUNING of its heading rate loop")
    return profile.pid_tuning


ROVER = MissionVehicle(ROVER_AUTO, 0.0, _report(ARDUROVER))
#: the AUV 5 m deep (where the simulator starts it)
SUB = MissionVehicle(SUB_AUTO, -5.0, _report(ARDUSUB))


def lawnmower(lanes: int = 8, lane_m: float = 120.0, spacing_m: float = 20.0, start_m: float = 10.0
              ) -> list[tuple[float, float]]:
    """The survey's waypoints as (north, east) metres from home (module docstring)."""
    if lanes < 1 or lane_m <= 0 or spacing_m <= 0:
        raise ValueError("a lawnmower needs at least one lane of positive length and spacing")
    points = []
    for lane in range(lanes):
        east = lane * spacing_m
        ends = (start_m, start_m + lane_m) if lane % 2 == 0 else (start_m + lane_m, start_m)
        points += [(ends[0], east), (ends[1], east)]
    return points


def offset(lat: float, lon: float, north: float, east: float) -> tuple[float, float]:
    """The position ``north``/``east`` metres from (lat, lon), degrees (flat earth: a survey's size)."""
    dlat = math.degrees(north / EARTH_RADIUS_M)
    dlon = math.degrees(east / (EARTH_RADIUS_M * math.cos(math.radians(lat))))
    return lat + dlat, lon + dlon


def upload_mission(conn, home: tuple[float, float], points: list[tuple[float, float]], timeout_s: float = 30.0,
                   altitude_m: float = 0.0) -> None:
    """The waypoints (module docstring), at ``altitude_m`` above home; RuntimeError when the vehicle
    does not accept them."""
    items = [home] + [offset(home[0], home[1], n, e) for n, e in points]
    conn.mav.mission_count_send(1, 1, len(items), 0)
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        msg = conn.recv_match(type=["MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK"], blocking=True, timeout=1.0)
        if msg is None:
            continue
        if msg.get_type() == "MISSION_ACK":
            if msg.type != MAV_MISSION_ACCEPTED:
                raise RuntimeError(f"the vehicle refused the mission (MISSION_ACK type {msg.type})")
            return
        seq = msg.seq
        lat, lon = items[seq]
        conn.mav.mission_item_int_send(1, 1, seq, MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, MAV_CMD_NAV_WAYPOINT,
                                       0, 1, 0.0, 0.0, 0.0, 0.0, int(round(lat * 1e7)), int(round(lon * 1e7)),
                                       altitude_m if seq else 0.0, 0)
    raise RuntimeError("the mission upload did not finish (no MISSION_ACK)")


def set_parameter(conn, name: str, value: float, timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        conn.mav.param_set_send(1, 1, name.encode(), float(value), 9)
        msg = conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=1.0)
        if msg is not None and msg.param_id == name and abs(msg.param_value - value) <= 1e-4 * max(1.0, abs(value)):
            return
    raise RuntimeError(f"{name} was never echoed as {value:g}")


@dataclass
class MissionTrack:
    """What the ground station saw: (vehicle s, mode number) changes, (vehicle s, north m, east m)
    positions, (vehicle s, waypoint) changes."""

    modes: list[tuple[float, int]] = field(default_factory=list)
    positions: list[tuple[float, float, float]] = field(default_factory=list)
    waypoints: list[tuple[float, int]] = field(default_factory=list)
    cross_track: list[tuple[float, float]] = field(default_factory=list)  # (vehicle s, m) NAV_CONTROLLER_OUTPUT
    turn_rates: list[tuple[float, float, float]] = field(default_factory=list)  # (vehicle s, asked, got) deg/s
    #: (vehicle s, asked, got) m/s: ArduRover's speed loop (PID_TUNING axis 4, GCS_PID_MASK bit value 2)
    speeds: list[tuple[float, float, float]] = field(default_factory=list)

    def legs(self, trim: float = 0.25, points: list[tuple[float, float]] | None = None) -> list[dict]:
        """Each lane (a leg to an even waypoint: north or south), its middle (``trim`` cut from each
        end, the turns out): start and end vehicle time, cross-track RMS (m) and turn-rate error RMS
        (deg/s, where PID_TUNING was sent), and the speed loop's tracking error RMS (m/s) over the whole
        leg from the waypoint's start (its corner, re-acceleration and slow-down included; where its
        PID_TUNING was sent). The cross-track is NAV_CONTROLLER_OUTPUT's (ArduRover),
        or with the mission's ``points`` each position's distance from the lane's line (ArduSub
        sends no cross-track error: its NAV_CONTROLLER_OUTPUT.xtrack_error is 0)."""
        out = []
        for (t0, seq), (t1, _next) in zip(self.waypoints, self.waypoints[1:]):
            if seq < 2 or seq % 2:
                continue
            a, b = t0 + trim * (t1 - t0), t1 - trim * (t1 - t0)
            if points is None:
                xt = [x for t, x in self.cross_track if a <= t <= b]
            else:  # waypoint seq is points[seq - 1] (item 0 is home); the lane starts at the one before
                xt = [_off_line(points[seq - 2], points[seq - 1], (n, e)) for t, n, e in self.positions if a <= t <= b]
            rates = [(d - g) for t, d, g in self.turn_rates if a <= t <= b]
            speeds = [(d - g) for t, d, g in self.speeds if t0 <= t <= t1]
            out.append({"waypoint": seq, "start_s": t0, "end_s": t1,
                        "cross_track_rms_m": math.sqrt(sum(x * x for x in xt) / len(xt)) if xt else math.nan,
                        "turn_rate_error_rms_deg_s": math.sqrt(sum(e * e for e in rates) / len(rates)) if rates else math.nan,
                        "speed_error_rms_m_s": math.sqrt(sum(e * e for e in speeds) / len(speeds)) if speeds else math.nan})
        return out

    def corners(self, trim: float = 0.25) -> list[dict]:
        """Each lane-end corner: from the end of a lane's middle to the start of the next lane's
        middle (``legs``' trim), named by the lane it leads into; its turn-rate error RMS (deg/s) over
        every sample, the turns the rudder flies at its stop included."""
        lanes = self.legs(trim)
        out = []
        for before, after in zip(lanes, lanes[1:]):
            a = before["end_s"] - trim * (before["end_s"] - before["start_s"])
            b = after["start_s"] + trim * (after["end_s"] - after["start_s"])
            rates = [(d - g) for t, d, g in self.turn_rates if a <= t <= b]
            out.append({"waypoint": after["waypoint"], "start_s": a, "end_s": b,
                        "turn_rate_error_rms_deg_s": math.sqrt(sum(e * e for e in rates) / len(rates)) if rates else math.nan})
        return out


def _off_line(start: tuple[float, float], end: tuple[float, float], at: tuple[float, float]) -> float:
    """The signed distance (m) of ``at`` from the line through ``start`` and ``end`` ((north, east))."""
    dn, de = end[0] - start[0], end[1] - start[1]
    length = math.hypot(dn, de)
    return ((at[0] - start[0]) * de - (at[1] - start[1]) * dn) / length if length > 0 else math.nan


class MissionGroundStation(StationThread):
    """Upload ``points`` and fly them in AUTO (module docstring); ``track`` holds what it saw."""

    what = "mission ground station"

    def __init__(self, endpoint: str, points: list[tuple[float, float]], params: dict[str, float] | None = None,
                 *, source_system: int = 255, vehicle: MissionVehicle = ROVER) -> None:
        super().__init__()
        self.endpoint, self.points, self.params = endpoint, points, dict(params or {})
        self.vehicle = vehicle
        self.source_system = source_system
        self.track = MissionTrack()
        self.home: tuple[float, float] | None = None
        self.done_at_s = math.nan  # vehicle time the last waypoint was reached
        self.now_s = math.nan  # the vehicle's clock, from the latest message that carries it

    def start(self, timeout_s: float = 120.0) -> "MissionGroundStation":
        self.conn = connect_client(self.endpoint, source_system=self.source_system, timeout=timeout_s)
        self.conn.mav.request_data_stream_send(1, 1, 0, 5, 1)  # every stream at 5 Hz for this port
        for name, value in self.params.items():
            set_parameter(self.conn, name, value)
        deadline = time.monotonic() + timeout_s
        while self.home is None and time.monotonic() < deadline:
            msg = self.conn.recv_match(type="GLOBAL_POSITION_INT", blocking=True, timeout=1.0)
            if msg is not None:
                self.now_s = msg.time_boot_ms / 1000.0
                if msg.lat != 0:
                    self.home = (msg.lat / 1e7, msg.lon / 1e7)
        if self.home is None:
            raise RuntimeError("no position from the vehicle")
        upload_mission(self.conn, self.home, self.points, altitude_m=self.vehicle.altitude_m)
        armed = False
        while not armed and time.monotonic() < deadline:
            self.command(MAV_CMD_COMPONENT_ARM_DISARM, 1.0)
            msg = self.conn.recv_match(type="HEARTBEAT", blocking=True, timeout=2.0)
            armed = msg is not None and msg.get_srcComponent() == 1 and bool(msg.base_mode & 128)
        if not armed:
            raise RuntimeError("the vehicle would not arm")
        in_auto = False
        while not in_auto and time.monotonic() < deadline:  # refused until the EKF has a position
            self.command(MAV_CMD_DO_SET_MODE, 1.0, self.vehicle.auto_mode)
            msg = self.conn.recv_match(type="HEARTBEAT", blocking=True, timeout=2.0)
            in_auto = msg is not None and msg.get_srcComponent() == 1 and msg.custom_mode == self.vehicle.auto_mode
        if not in_auto:
            raise RuntimeError("the vehicle would not enter AUTO")
        self.track.modes.append((self.now_s, self.vehicle.auto_mode))  # the clock of the last position: within 0.2 s
        self._start_thread()
        return self

    def start_when_open(self, patience_s: float = 60.0) -> "MissionGroundStation":
        """:meth:`start` once the port listens: SITL opens serial1 only after it booted, which it does
        once serial0's client (the companion) connected."""
        deadline = time.monotonic() + patience_s
        while True:
            try:
                return self.start()
            except ConnectionRefusedError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(1.0)

    def wait_done(self, process, wall_s: float) -> bool:
        """Wait (wall clock: a process's life, not vehicle logic) until the last waypoint is reached,
        ``process`` ended or ``wall_s`` passed; whether the survey finished."""
        deadline = time.monotonic() + wall_s
        while time.monotonic() < deadline and not math.isfinite(self.done_at_s) and process.poll() is None:
            time.sleep(1.0)
        return math.isfinite(self.done_at_s)

    def _run(self) -> None:
        lat0, lon0 = self.home
        while not self._stop.is_set():
            msg = self.conn.recv_match(type=["HEARTBEAT", "GLOBAL_POSITION_INT", "MISSION_CURRENT",
                                             "MISSION_ITEM_REACHED", "NAV_CONTROLLER_OUTPUT", "PID_TUNING"],
                                       blocking=True, timeout=0.5)
            if msg is None:
                continue
            kind = msg.get_type()
            if kind == "GLOBAL_POSITION_INT":
                t = self.now_s = msg.time_boot_ms / 1000.0
                north = math.radians(msg.lat / 1e7 - lat0) * EARTH_RADIUS_M
                east = math.radians(msg.lon / 1e7 - lon0) * EARTH_RADIUS_M * math.cos(math.radians(lat0))
                self.track.positions.append((t, north, east))
            elif kind == "HEARTBEAT" and msg.get_srcComponent() == 1:
                t = self.now_s
                if not self.track.modes or self.track.modes[-1][1] != msg.custom_mode:
                    self.track.modes.append((t, msg.custom_mode))
            elif kind == "MISSION_CURRENT":
                t = self.now_s
                if not self.track.waypoints or self.track.waypoints[-1][1] != msg.seq:
                    self.track.waypoints.append((t, msg.seq))
            elif kind == "NAV_CONTROLLER_OUTPUT":
                self.track.cross_track.append((self.now_s, msg.xtrack_error))
            elif kind == "PID_TUNING" and msg.axis == SPEED_AXIS and self.vehicle is ROVER:  # the speed loop, m/s
                self.track.speeds.append((self.now_s, msg.desired, msg.achieved))
            elif kind == "PID_TUNING" and msg.axis == self.vehicle.pid_tuning.axis:  # the heading rate loop
                report = self.vehicle.pid_tuning
                self.track.turn_rates.append((self.now_s, msg.desired * report.desired_to_rad_s * RAD_TO_DEG,
                                              msg.achieved * report.achieved_to_rad_s * RAD_TO_DEG))
            elif kind == "MISSION_ITEM_REACHED" and msg.seq == len(self.points):
                self.done_at_s = self.now_s


@dataclass(frozen=True)
class SurveyRun:
    """How a companion beside a flown survey ended: whether the survey finished, its exit code and
    its output (empty when it wrote to a file)."""

    finished: bool
    returncode: int
    output: str


def fly_survey_beside(command: Sequence[str], station: MissionGroundStation, wall_s: float,
                      output: IO[str] | None = None) -> SurveyRun:
    """Start the companion ``command``, let ``station`` upload and fly its survey (at most ``wall_s``
    of wall clock: a process's life, not vehicle logic), then stop the companion and the station.
    The companion's output goes to ``output`` (a file) or is returned."""
    companion = subprocess.Popen(list(command), stdout=output if output is not None else subprocess.PIPE,
                                 stderr=subprocess.STDOUT, text=True)
    try:
        station.start_when_open()
        finished = station.wait_done(companion, wall_s)
    finally:
        companion.terminate()
        text = companion.communicate(timeout=60)[0] or ""
        station.stop()
    return SurveyRun(finished, companion.returncode, text)

