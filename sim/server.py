"""The simulator's MAVLink 2 endpoint (docs/PROTOCOL.md; SPEC C2).

One process, one loop: physics at ``dt`` = 0.01 s of vehicle time, telemetry streams scheduled on
the vehicle clock (integer 10 ms ticks, so rates are exact), incoming MAVLink polled between
batches of physics steps. ``speedup`` paces vehicle time against ``time.monotonic()`` — the only
place in the simulator that reads a wall clock. If the machine cannot keep up it runs as fast as
it can, drops the backlog instead of bursting, and logs the achieved ratio.

Transports are pymavlink's (``udpin:``, ``udpout:``, ``tcpin:``). ``udpin:`` serves every client
that has sent at least one datagram (pymavlink's multi-client UDP server) and routes messages
between them like an autopilot; ``tcpin:`` serves several clients at once the same way
(sim/tcp_clients.py) and is lossless: vehicle time waits for a client that falls behind. A new
client hears a HEARTBEAT at once (even while vehicle time waits for a lockstep companion). All
messages of a tick go out in one datagram/write (the hot loop's largest saving). docs/PROTOCOL.md,
"Transport". With ``--lockstep`` input is read only when the physics has reached the last tick the
companion allows (sim/lockstep.py), so every message acts at a vehicle time fixed by the
companion's own stream, never by scheduling.
"""
from __future__ import annotations

import logging
import math
import os
import collections
import select
import time
from dataclasses import dataclass
from typing import Callable

# MAVLink 2 framing must be chosen before pymavlink's dialect module is first imported (this is
# pymavlink's own switch, also used by MAVProxy).
os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402

from sim.autopilot import (  # noqa: E402
    Autopilot,
    Result,
    pwm_from_fin,
    pwm_from_thrust,
    wrap_pi,
)
from sim.build import build_vehicle  # noqa: E402
from sim.frame_parser import ResyncParser  # noqa: E402
from sim.lockstep import Lockstep  # noqa: E402
from sim.params import ParamTable  # noqa: E402
from sim.preset import load_preset  # noqa: E402
from sim.skid_mixer import pwm_from_motor  # noqa: E402
from sim.tcp_clients import TcpClient, TcpClients  # noqa: E402

log = logging.getLogger(__name__)
mavlink = mavutil.mavlink

DEFAULT_LISTEN = "udpin:127.0.0.1:14550"
DEFAULT_PRESET = "starfish"
GRAVITY = 9.80665
PRESSURE_RHO = 1000.0  # kg/m³, fixed so a client can invert SCALED_PRESSURE (PROTOCOL.md)
SEA_LEVEL_HPA = 1013.25
ORIGIN_LAT_DEG, ORIGIN_LON_DEG = 63.4400, 10.3900  # fixed local origin (Trondheimsfjord)
EARTH_RADIUS_M = 6378137.0
UDP_CLIENT_TIMEOUT_S = 30.0  # wall seconds: a silent UDP client is dropped if others remain
MAX_TICKS_PER_POLL = 10  # physics steps between two polls of the socket
TCP_LISTEN_BACKLOG = 8  # connections the kernel queues before the simulator accepts them
MAX_BACKLOG_S = 0.25  # wall seconds behind schedule before the pacing drops the backlog
REPORT_EVERY_S = 10.0  # wall seconds between achieved-ratio log lines
REBOOT_S = 2.0  # vehicle seconds a rebooting autopilot is silent

ATT_STREAMS = (mavlink.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW, mavlink.MAVLINK_MSG_ID_ATTITUDE)
POS_STREAMS = (
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
    mavlink.MAVLINK_MSG_ID_VFR_HUD,
    mavlink.MAVLINK_MSG_ID_SCALED_PRESSURE,
    mavlink.MAVLINK_MSG_ID_NAV_CONTROLLER_OUTPUT,
)
ONE_HZ_STREAMS = (
    mavlink.MAVLINK_MSG_ID_HEARTBEAT,
    mavlink.MAVLINK_MSG_ID_SYS_STATUS,
    mavlink.MAVLINK_MSG_ID_SYSTEM_TIME,
)
# Emission order inside one tick: SERVO_OUTPUT_RAW immediately before ATTITUDE (one sample).
STREAM_ORDER = ONE_HZ_STREAMS + ATT_STREAMS + POS_STREAMS

CAPABILITIES = (
    mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
    | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST
    | mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
)


@dataclass
class SimConfig:
    """Everything ``python -m sim run`` takes."""

    preset: str = DEFAULT_PRESET
    listen: str = DEFAULT_LISTEN
    speedup: float = 1.0  # vehicle time / wall time; 0 = as fast as possible
    seed: int = 0
    current_north: float = 0.0
    current_east: float = 0.0
    duration: float | None = None  # seconds of vehicle time, None = until stopped
    dt: float = 0.01
    depth: float = 5.0
    heading: float = 0.0
    lockstep: bool = False  # see SimServer._lockstep_limit
    signing_key: bytes | None = None  # MAVLink 2 signing: sign everything, drop unsigned input
    faults: tuple = ()  # sim.faults.Fault: a property scaled from a vehicle time on (with the preset's)


class _Stream:
    __slots__ = ("msg_id", "period", "next_tick", "custom")

    def __init__(self, msg_id: int) -> None:
        self.msg_id = msg_id
        self.period = 0  # ticks; 0 = disabled
        self.next_tick = 0
        self.custom = False  # set by SET_MESSAGE_INTERVAL, no longer follows SR_* parameters


class SimServer:
    """The simulated autopilot behind a MAVLink endpoint. ``run()`` blocks until ``stop()``."""

    def __init__(self, config: SimConfig, on_ready: Callable[[str], None] | None = None) -> None:
        self.config = config
        self._on_ready = on_ready
        preset = load_preset(config.preset)
        self.params = ParamTable.for_preset(preset)
        for name, value in (("SIM_CUR_VN", config.current_north), ("SIM_CUR_VE", config.current_east)):
            result = self.params.set(name, value)
            if not result.accepted:
                raise ValueError(f"--current: {result.message}")
        self.vehicle = build_vehicle(
            preset,
            seed=config.seed,
            current_north=config.current_north,
            current_east=config.current_east,
            depth=config.depth,
            heading=config.heading,
            faults=config.faults,
        )
        self.autopilot = Autopilot(self.vehicle, self.params)
        self.tick = 0
        self._boot_tick = 0  # the tick of the last boot: time_boot_ms counts from it
        self._reboot_at_tick: int | None = None  # while rebooting: the tick the new boot starts
        self.dt = config.dt
        self._tick_ms = config.dt * 1000.0
        self._stop = False
        self._streams = {msg_id: _Stream(msg_id) for msg_id in STREAM_ORDER}
        self._ordered_streams = [self._streams[m] for m in STREAM_ORDER]
        self._next_emit = 0
        self._measure = None
        self._measure_tick = -1
        self._after_ack: list = []  # replies a command asked for, sent after its COMMAND_ACK
        self._batch: bytearray | None = None  # frames collected during one tick's emission
        self.conn: mavutil.mavfile | None = None
        self._tcp_mode = config.listen.startswith("tcpin:")
        self._tcp: TcpClients | None = None  # the accepted TCP clients (tcpin: only)
        self.stats = {"ticks": 0, "sent": 0, "received": 0, "bad": 0, "dropped": 0, "wall_s": 0.0}
        self.lockstep = Lockstep(config.lockstep, config.dt)
        # parsed input not yet applied, with where it came from (UDP address or TcpClient): under
        # lockstep what follows the acknowledgement that moves the limit waits for the next limit
        self._inbox: collections.deque[tuple[object, object]] = collections.deque()
        self._origin: object = None  # where the message being handled came from
        for name in ("SR_ATT_HZ", "SR_POS_HZ"):
            self._apply_stream_param(name)
        for msg_id in ONE_HZ_STREAMS:
            self._streams[msg_id].period = self._period_ticks(1.0)
        self._refresh_next_emit()

    # ------------------------------------------------------------------ public control
    def stop(self) -> None:
        """Ask the loop to finish (safe from a signal handler)."""
        self._stop = True

    @property
    def time_boot_ms(self) -> int:
        return int(round((self.tick - self._boot_tick) * self._tick_ms))

    # ------------------------------------------------------------------ reboot
    def _schedule_reboot(self) -> int:
        """MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN (param1 = 1): the autopilot reboots as ArduPilot does —
        silent for ``REBOOT_S`` of vehicle time (the physics go on), then a fresh boot: its clock from
        0, disarmed in MANUAL with its default set-points, no override, the streams at their SR_*
        rates; its parameters are kept (flash). In lockstep the silence and the new boot's first
        sample run without acknowledgements (there is nothing to acknowledge meanwhile; sim/lockstep.py),
        so the reboot lands at the same vehicle time whatever the pace."""
        self._reboot_at_tick = self.tick + max(1, int(round(REBOOT_S / self.dt)))
        if self.lockstep.enabled:
            self.lockstep.hold_until = self._reboot_at_tick + self._lead_ticks()
        return Result.ACCEPTED

    @property
    def rebooting(self) -> bool:
        return self._reboot_at_tick is not None

    def _boot(self) -> None:
        self._reboot_at_tick = None
        self._boot_tick = self.tick
        self.autopilot = Autopilot(self.vehicle, self.params)
        for stream in self._ordered_streams:
            stream.custom = False
            stream.next_tick = self.tick
        for name in ("SR_ATT_HZ", "SR_POS_HZ"):
            self._apply_stream_param(name)
        for msg_id in ONE_HZ_STREAMS:
            self._streams[msg_id].period = self._period_ticks(1.0)
        self._refresh_next_emit()
        self.stats["reboots"] = self.stats.get("reboots", 0) + 1
        log.info("rebooted at vehicle time %.2f s", self.tick * self.dt)

    def open(self) -> None:
        self.conn = mavutil.mavlink_connection(
            self.config.listen,
            source_system=int(self.params["SYSID_THISMAV"]),
            source_component=mavlink.MAV_COMP_ID_AUTOPILOT1,
            udp_timeout=UDP_CLIENT_TIMEOUT_S,
        )
        self.conn.mav.robust_parsing = True
        if self.config.signing_key is not None:
            # as an autopilot with signing enabled: outgoing frames signed, unsigned input dropped
            self.conn.setup_signing(self.config.signing_key, sign_outgoing=True)
        if self._tcp_mode:
            self.conn.listen.listen(TCP_LISTEN_BACKLOG)  # pymavlink listens with a backlog of 1
            self._tcp = TcpClients(self.conn.listen, self._client_parser, on_drop=self.lockstep.client_left)

    def _client_parser(self):
        """A MAVLink parser of one TCP client's bytes, sharing the endpoint's signing state, that
        resynchronises after a damaged frame (sim/frame_parser.py: a serial link bridged to the port
        loses bytes, and in lockstep nothing would come to complete a false frame)."""
        mav = self.conn.mav
        parser = type(mav)(None, srcSystem=mav.srcSystem, srcComponent=mav.srcComponent)
        parser.robust_parsing = True
        parser.signing = mav.signing
        return ResyncParser(parser)

    def bound_endpoint(self) -> str:
        """The listen endpoint with the port actually bound (``…:0`` asks the OS for a free one)."""
        listen = self.config.listen
        sock = None
        if self.conn is not None:
            sock = self.conn.listen if self._tcp_mode else getattr(self.conn, "port", None)
        if sock is None or not listen.startswith(("udpin:", "tcpin:")):
            return listen
        try:
            host, port = sock.getsockname()[:2]
        except OSError:
            return listen
        return f"{listen.split(':', 1)[0]}:{host}:{port}"

    def close(self) -> None:
        if self._tcp is not None:
            self._tcp.close()
        if self.conn is not None:
            try:
                self.conn.close()
            except OSError:
                pass
            self.conn = None

    def run(self) -> int:
        """Serve until stopped or ``duration`` of vehicle time has passed; returns an exit code."""
        if self.conn is None:
            self.open()
        if self._on_ready is not None:
            self._on_ready(self.bound_endpoint())
        try:
            self._loop()
        finally:
            self._log_ratio("final", self.stats["wall_s"], self.tick * self.dt)
            self.close()
        return 0

    # ------------------------------------------------------------------ main loop
    def _loop(self) -> None:
        speedup = self.config.speedup
        paced = speedup > 0
        duration = self.config.duration
        end_tick = None if duration is None else int(round(duration / self.dt))
        wall_start = time.monotonic()
        base_wall, base_tick = wall_start, 0
        report_wall, report_tick = wall_start, 0
        step = self._step_once
        lockstep = self.lockstep
        while not self._stop:
            now = time.monotonic()
            if paced:
                due = base_tick + int((now - base_wall) * speedup / self.dt)
                if due - self.tick > MAX_BACKLOG_S * speedup / self.dt:
                    # Cannot keep up: drop the backlog rather than burst to catch up later.
                    base_wall, base_tick = now, self.tick
                    due = self.tick + 1
            else:
                due = self.tick + MAX_TICKS_PER_POLL
            batch_end = min(due, self.tick + MAX_TICKS_PER_POLL)
            if end_tick is not None:
                batch_end = min(batch_end, end_tick)
            limit = lockstep.limit(self.tick, self._lead_ticks(), now)
            if limit is not None:
                batch_end = min(batch_end, max(self.tick, limit))
            if self._tcp_backlogged():
                # A TCP client is behind: vehicle time waits for it (lossless, flow-controlled).
                self._wait_writable(0.005)
                batch_end = self.tick
            first = self.tick
            while self.tick < batch_end:
                step()
            if limit is None:
                lockstep.count_free(self.tick - first)
                self._poll()
            elif self.tick >= limit:
                # Lockstep: input is applied only here, at the last tick the companion allows.
                if not self._poll_at_limit():
                    if end_tick is not None and self.tick >= end_tick:
                        break
                    self._wait_readable(0.05)  # the companion has not acknowledged yet: wait for it
                    continue
            if end_tick is not None and self.tick >= end_tick:
                break
            if now - report_wall >= REPORT_EVERY_S:
                self._log_ratio("running", now - report_wall, (self.tick - report_tick) * self.dt)
                report_wall, report_tick = now, self.tick
            if paced and self.tick >= due:
                wait = base_wall + (self.tick + 1 - base_tick) * self.dt / speedup - time.monotonic()
                if wait > 0:
                    if limit is None:
                        self._wait_readable(min(wait, 0.05))
                    else:
                        time.sleep(min(wait, 0.05))  # input waits for the limit anyway
        self.stats["ticks"] = self.tick
        self.stats["wall_s"] = time.monotonic() - wall_start

    # ------------------------------------------------------------------ lockstep (sim/lockstep.py)
    def _lead_ticks(self) -> int:
        """How far past the acknowledged sample the physics may run: one ATTITUDE period (the
        stream's own, which the companion may have set), else 1/SR_ATT_HZ."""
        period = self._streams[mavlink.MAVLINK_MSG_ID_ATTITUDE].period
        if period > 0:
            return period
        return self._period_ticks(max(self.params["SR_ATT_HZ"], 1.0))

    def _poll_at_limit(self) -> bool:
        """Apply input in arrival order until an acknowledgement lets the physics move on; the rest
        waits in the inbox for the next limit. True when the physics may move on."""
        for _ in range(64):  # bounded: the loop comes back here at once if it may not move
            while self._inbox:
                self._dispatch(self._inbox.popleft())
                if self._may_advance():
                    return True
            if not self._receive():
                return self._may_advance()
        return self._may_advance()

    def _may_advance(self) -> bool:
        limit = self.lockstep.limit(self.tick, self._lead_ticks(), time.monotonic())
        return limit is None or limit > self.tick

    def _handle_system_time(self, msg) -> None:
        """SYSTEM_TIME from the companion: its acknowledgement of a processed sample (lockstep)."""
        if msg.get_srcComponent() != self.LOCKSTEP_COMPONENT:
            return
        self.lockstep.acknowledge(msg.time_boot_ms, self.tick, time.monotonic(),
                                  client=self._origin if isinstance(self._origin, TcpClient) else None,
                                  boot_tick=self._boot_tick, max_ahead=2 * self._lead_ticks())

    LOCKSTEP_COMPONENT = 191  # MAV_COMP_ID_ONBOARD_COMPUTER: the companion

    def summary(self) -> dict:
        """What the run did, for the ``STATS`` line on exit: counters and the lockstep record (an
        exact run has ``interruptions`` 0)."""
        return {"vehicle_s": round(self.tick * self.dt, 6), "sent": self.stats["sent"],
                "received": self.stats["received"], "bad": self.stats["bad"],
                "dropped": self.stats["dropped"] + (self._tcp.dropped if self._tcp is not None else 0),
                "lockstep": dict(self.lockstep.stats) if self.lockstep.enabled else None}

    def _log_ratio(self, label: str, wall_s: float, sim_s: float) -> None:
        if wall_s <= 0:
            return
        ratio = sim_s / wall_s
        target = self.config.speedup
        level = logging.WARNING if target > 0 and ratio < 0.9 * target else logging.INFO
        log.log(level, "%s: %.1f s vehicle in %.1f s wall = %.1fx (target %s)", label, sim_s,
                wall_s, ratio, f"{target:g}x" if target > 0 else "as fast as possible")

    def _wait_readable(self, timeout: float) -> None:
        """Wait for input, or (TCP) for a client's socket to take frames still queued for it."""
        pending: list[int] = []
        if self._tcp is not None:
            fds = self._tcp.fds()
            pending = self._tcp.pending_fds()
        else:
            fds = [self.conn.fd] if self.conn is not None and self.conn.fd is not None else []
        try:
            if fds:
                select.select(fds, pending, [], timeout)
            else:
                time.sleep(timeout)
        except (OSError, ValueError):
            time.sleep(timeout)

    def _wait_writable(self, timeout: float) -> None:
        fds = self._tcp.writable_fds() if self._tcp is not None else []
        try:
            if fds:
                select.select([], fds, [], timeout)
        except (OSError, ValueError):
            pass

    def _step_once(self) -> None:
        self.autopilot.step(self.dt)
        self.tick += 1
        if self._reboot_at_tick is not None:
            if self.tick < self._reboot_at_tick:
                return  # booting: the physics go on, the autopilot says nothing
            self._boot()
        if self.tick >= self._next_emit:
            self._emit_due()

    # ------------------------------------------------------------------ telemetry
    @staticmethod
    def _period_ticks_for(hz: float, dt: float) -> int:
        if hz <= 0 or not math.isfinite(hz):
            return 0
        return max(1, int(round(1.0 / (hz * dt))))

    def _period_ticks(self, hz: float) -> int:
        return self._period_ticks_for(hz, self.dt)

    def _apply_stream_param(self, name: str) -> None:
        ids = ATT_STREAMS if name == "SR_ATT_HZ" else POS_STREAMS
        period = self._period_ticks(self.params[name])
        for msg_id in ids:
            stream = self._streams[msg_id]
            if not stream.custom:
                stream.period = period
                stream.next_tick = self.tick
        self._refresh_next_emit()

    def _refresh_next_emit(self) -> None:
        ticks = [s.next_tick for s in self._ordered_streams if s.period > 0]
        self._next_emit = min(ticks) if ticks else 1 << 62

    def _emit_due(self) -> None:
        """Send every stream due at this tick, packed into ONE datagram / TCP write.

        MAVLink allows several frames per UDP datagram (ArduPilot does the same); one system call
        per tick instead of one per message is the largest saving of the hot loop, for the
        simulator and for every client.
        """
        tick = self.tick
        self._batch = bytearray()
        try:
            for stream in self._ordered_streams:
                if stream.period and stream.next_tick <= tick:
                    self._send_stream(stream.msg_id)
                    stream.next_tick = tick + stream.period
        finally:
            batch, self._batch = self._batch, None
            self._write(bytes(batch))
        self._refresh_next_emit()

    def _write(self, data: bytes) -> None:
        if not data or self.conn is None:
            return
        if self._tcp is not None:
            self._tcp.send(data)  # every client; lossless, flow-controlled (sim/tcp_clients.py)
            return
        try:
            self.conn.write(data)  # pymavlink: sendto every known UDP client
        except (OSError, ValueError) as exc:
            log.debug("write failed: %s", exc)

    def _tcp_backlogged(self) -> bool:
        if self._tcp is None:
            return False
        self._tcp.flush()  # whatever a full socket left queued, even when no new frame follows
        return self._tcp.backlogged()

    def _greet(self, client: object) -> None:
        """A HEARTBEAT for a client just heard from, at once: it learns the vehicle is there even
        while vehicle time waits for a lockstep companion (no tick, no stream, would send one)."""
        frame = self._frame(self._heartbeat())
        if frame is None:
            return
        if isinstance(client, TcpClient):
            self._tcp.send(frame, only=client)
            return
        try:
            self.conn.port.sendto(frame, client)
        except OSError as exc:
            log.debug("heartbeat to %s failed: %s", client, exc)

    def _measurements(self):
        if self._measure_tick != self.tick:
            self._measure = self.vehicle.measure()
            self._measure_tick = self.tick
        return self._measure

    def _frame(self, msg) -> bytes | None:
        """One packed frame (what MAVLink.send does, minus the write: pack and sequence number)."""
        if self.conn is None:
            return None
        encoder = self.conn.mav
        try:
            frame = msg.pack(encoder)
        except Exception as exc:  # a value out of a field's range must not stop the simulator
            log.warning("cannot pack %s: %s", msg.get_type(), exc)
            return None
        encoder.seq = (encoder.seq + 1) % 256
        self.stats["sent"] += 1
        return frame

    def _send(self, msg) -> None:
        frame = self._frame(msg)
        if frame is None:
            return
        if self._batch is not None:
            self._batch += frame
        else:
            self._write(frame)

    def _send_stream(self, msg_id: int) -> None:
        msg = self._build(msg_id)
        if msg is not None:
            self._send(msg)

    def _build(self, msg_id: int):
        """Build one message of the streamed set from the current state (PROTOCOL.md Telemetry)."""
        ms = self.time_boot_ms
        if msg_id == mavlink.MAVLINK_MSG_ID_ATTITUDE:
            m = self._measurements()
            return mavlink.MAVLink_attitude_message(
                ms, m.roll, m.pitch, wrap_pi(m.yaw), m.roll_rate, m.pitch_rate, m.yaw_rate
            )
        if msg_id == mavlink.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW:
            m = self._measurements()
            servos = [0] * 16
            if self.autopilot.skid:  # ArduRover skid steering: ThrottleLeft on 1, ThrottleRight on 3
                servos[0] = pwm_from_motor(m.motor_left)
                servos[2] = pwm_from_motor(m.motor_right)
            else:
                servos[0] = pwm_from_fin(m.rudder)
                servos[2] = pwm_from_thrust(m.thrust_ratio)
            servos[1] = pwm_from_fin(m.elevator)
            mass_output = int(self.params["MASS_SERVO"])
            servos[mass_output - 1] = pwm_from_fin(m.mass_angle)
            # time_usec is a uint32 (micros() on ArduPilot): it wraps every 71.6 minutes; unwrapped it
            # could not be packed after 4295 s and the outputs vanished from telemetry (the fault bench)
            return mavlink.MAVLink_servo_output_raw_message((ms * 1000) & 0xFFFFFFFF, 0, *servos)
        if msg_id == mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED:
            m = self._measurements()
            return mavlink.MAVLink_local_position_ned_message(
                ms, m.north, m.east, m.depth, m.vel_north, m.vel_east, m.vel_down
            )
        if msg_id == mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT:
            m = self._measurements()
            lat = ORIGIN_LAT_DEG + math.degrees(m.north / EARTH_RADIUS_M)
            lon = ORIGIN_LON_DEG + math.degrees(
                m.east / (EARTH_RADIUS_M * math.cos(math.radians(ORIGIN_LAT_DEG))))
            heading = int(round(math.degrees(m.yaw) * 100.0)) % 36000
            return mavlink.MAVLink_global_position_int_message(
                ms, int(round(lat * 1e7)), int(round(lon * 1e7)), int(round(-m.depth * 1000)),
                int(round(-m.depth * 1000)), _cm(m.vel_north), _cm(m.vel_east), _cm(m.vel_down),
                heading,
            )
        if msg_id == mavlink.MAVLINK_MSG_ID_VFR_HUD:
            m = self._measurements()
            heading = int(round(math.degrees(m.yaw))) % 360
            throttle = int(round(m.thrust_ratio * 100.0))
            return mavlink.MAVLink_vfr_hud_message(
                m.speed_water, m.speed_ground, heading, throttle, -m.depth, -m.vel_down
            )
        if msg_id == mavlink.MAVLINK_MSG_ID_SCALED_PRESSURE:
            m = self._measurements()
            press = SEA_LEVEL_HPA + PRESSURE_RHO * GRAVITY * m.depth / 100.0
            return mavlink.MAVLink_scaled_pressure_message(ms, press, 0.0, 1500)
        if msg_id == mavlink.MAVLINK_MSG_ID_NAV_CONTROLLER_OUTPUT:
            # the holding mode's targets, as an autopilot reports them: the heading set-point (whole
            # degrees, as the message carries it) and the depth error
            m = self._measurements()
            ap = self.autopilot
            bearing = int(round(math.degrees(ap.heading_setpoint))) % 360
            return mavlink.MAVLink_nav_controller_output_message(
                0.0, 0.0, bearing, bearing, 0, float(m.depth - ap.depth_setpoint), 0.0, 0.0)
        if msg_id == mavlink.MAVLINK_MSG_ID_HEARTBEAT:
            return self._heartbeat()
        if msg_id == mavlink.MAVLINK_MSG_ID_SYS_STATUS:
            return mavlink.MAVLink_sys_status_message(0, 0, 0, 0, 16000, -1, 100, 0, 0, 0, 0, 0, 0)
        if msg_id == mavlink.MAVLINK_MSG_ID_SYSTEM_TIME:
            return mavlink.MAVLink_system_time_message(0, ms)
        if msg_id == mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            return self._autopilot_version()
        return None

    def _heartbeat(self):
        ap = self.autopilot
        base_mode = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if ap.armed:
            base_mode |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        state = mavlink.MAV_STATE_ACTIVE if ap.armed else mavlink.MAV_STATE_STANDBY
        return mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_SUBMARINE, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, base_mode, ap.mode,
            state, 3,
        )

    def _autopilot_version(self):
        version = (0 << 24) | (1 << 16) | (0 << 8) | 255  # 0.1.0 official
        return mavlink.MAVLink_autopilot_version_message(
            CAPABILITIES, version, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0,
            0x51AB_0000 + int(self.params["SYSID_THISMAV"]),
        )

    def status_text(self, text: str, severity: int = mavlink.MAV_SEVERITY_WARNING) -> None:
        log.info("STATUSTEXT: %s", text)
        self._send(mavlink.MAVLink_statustext_message(severity, text.encode("ascii", "replace")[:50]))

    # ------------------------------------------------------------------ incoming
    def _receive(self) -> bool:
        """Read what has arrived, parse it and queue the messages in the inbox with their origin
        (UDP address or TcpClient); False when nothing arrived. New clients are greeted."""
        conn = self.conn
        if conn is None:
            return False
        if self._tcp is not None:
            for client in self._tcp.accept():
                self._greet(client)
            received = self._tcp.receive()
            for client, data in received:
                self._parse(client.parser, data, client)
            return bool(received)
        try:
            data, sender = conn.port.recvfrom(65535)
        except (BlockingIOError, InterruptedError):
            return False
        except OSError as exc:  # e.g. ECONNREFUSED reported for an earlier datagram
            log.debug("recv failed: %s", exc)
            return False
        if getattr(conn, "udp_server", False):  # pymavlink's client list, used by conn.write
            new = sender not in conn.clients
            conn.clients.add(sender)
            conn.clients_last_alive[sender] = time.time()
            if new:
                self._greet(sender)
        self._parse(conn.mav, data, sender)
        # A frame never spans UDP datagrams: drop a partial tail so that garbage from one client
        # cannot swallow the next datagram (of any client).
        conn.mav.buf = bytearray()
        conn.mav.buf_index = 0
        return True

    def _parse(self, parser, data: bytes, origin: object) -> None:
        try:
            messages = parser.parse_buffer(data) or []
        except Exception as exc:  # malformed input must never stop the simulator
            self.stats["bad"] += 1
            log.debug("unparseable input (%s)", exc)
            messages = []
        self._inbox.extend((msg, origin) for msg in messages)

    def _poll(self) -> None:
        """Free-running: apply everything that has arrived (bounded: never starve the physics)."""
        for _ in range(64):
            while self._inbox:
                self._dispatch(self._inbox.popleft())
            if not self._receive():
                break
        while self._inbox:
            self._dispatch(self._inbox.popleft())

    def _dispatch(self, item: tuple[object, object]) -> None:
        msg, origin = item
        self.stats["received"] += 1
        if self._reboot_at_tick is not None:
            return  # a booting autopilot reads nothing
        self._origin = origin
        try:
            self.handle(msg)
            self._route(msg, origin)
        except Exception:  # a handler bug on odd input is logged, never fatal
            self.stats["bad"] += 1
            log.exception("error handling %s", msg.get_type())
        finally:
            self._origin = None

    def _route(self, msg, origin: object) -> None:
        """Forward a client's message to the other clients unless it was for the autopilot only.

        This is what an autopilot's MAVLink routing does for a GCS and a companion computer on
        different links: the companion's STATUSTEXT/NAMED_VALUE_FLOAT reach the GCS, and a GCS's
        COMMAND_LONG to component 191 reaches the companion.
        """
        if msg.get_type() == "BAD_DATA":
            return
        if self._tcp is not None:
            if len(self._tcp.clients) < 2:
                return
        else:
            clients = getattr(self.conn, "clients", None)
            if not clients or len(clients) < 2 or origin is None:
                return
        target_system = getattr(msg, "target_system", 0)
        target_component = getattr(msg, "target_component", 0)
        if target_system == int(self.params["SYSID_THISMAV"]) and \
                target_component == mavlink.MAV_COMP_ID_AUTOPILOT1:
            return
        frame = msg.get_msgbuf()
        if self._tcp is not None:
            self._tcp.send(bytes(frame), exclude=origin)
            return
        for client in list(clients):
            if client != origin:
                try:
                    self.conn.port.sendto(frame, client)
                except OSError as exc:
                    log.debug("forward to %s failed: %s", client, exc)

    def _for_us(self, msg, component_field: bool = True) -> bool:
        sysid = int(self.params["SYSID_THISMAV"])
        target_system = getattr(msg, "target_system", 0)
        if target_system not in (0, sysid):
            return False
        if component_field:
            target_component = getattr(msg, "target_component", 0)
            if target_component not in (0, mavlink.MAV_COMP_ID_AUTOPILOT1):
                return False
        return True

    def handle(self, msg) -> None:
        """Dispatch one incoming message (unknown types are ignored)."""
        kind = msg.get_type()
        if kind == "BAD_DATA":
            self.stats["bad"] += 1
            log.debug("bad data: %s", getattr(msg, "reason", ""))
            return
        handler = self._handlers.get(kind)
        if handler is not None:
            handler(self, msg)

    def _handle_param_request_list(self, msg) -> None:
        if self._for_us(msg):
            for index in range(len(self.params)):
                self._send_param(self.params.name_at(index))

    def _handle_param_request_read(self, msg) -> None:
        if not self._for_us(msg):
            return
        if msg.param_index >= 0:
            name = self.params.name_at(msg.param_index)
        else:
            name = _param_name(msg.param_id)
        if name is not None and name in self.params:
            self._send_param(name)
        else:
            log.info("PARAM_REQUEST_READ of unknown %r / %d", msg.param_id, msg.param_index)

    def _handle_param_set(self, msg) -> None:
        if not self._for_us(msg):
            return
        name = _param_name(msg.param_id)
        result = self.autopilot.set_param(name, msg.param_value)
        if not result.accepted:
            self.status_text(f"Param {result.message}")
            if result.value is None:
                return
            self._send_param(name, result.value)
            return
        self._send_param(name, result.value)
        if name in ("SR_ATT_HZ", "SR_POS_HZ"):
            self._apply_stream_param(name)
        elif name == "SYSID_THISMAV" and self.conn is not None:
            self.conn.mav.srcSystem = int(self.params[name])

    def _send_param(self, name: str, value: float | None = None) -> None:
        params = self.params
        param_type = (
            mavlink.MAV_PARAM_TYPE_INT32 if params.is_integer(name) else mavlink.MAV_PARAM_TYPE_REAL32
        )
        self._send(
            mavlink.MAVLink_param_value_message(
                name.encode("ascii"),
                params[name] if value is None else value,
                param_type,
                len(params),
                params.index(name),
            )
        )

    def _handle_set_mode(self, msg) -> None:
        if msg.target_system not in (0, int(self.params["SYSID_THISMAV"])):
            return
        result = Result.FAILED
        if msg.base_mode & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            result = self.autopilot.set_mode(int(msg.custom_mode))
        self._ack(msg, mavlink.MAVLINK_MSG_ID_SET_MODE, result)

    def _handle_rc_override(self, msg) -> None:
        if not self._for_us(msg):
            return
        channels = [msg.chan1_raw, msg.chan2_raw, msg.chan3_raw]
        if not self.autopilot.rc_override(msg.get_srcSystem(), channels):
            log.debug("RC override from system %d ignored (SYSID_MYGCS %d)",
                      msg.get_srcSystem(), int(self.params["SYSID_MYGCS"]))

    def _handle_command_long(self, msg) -> None:
        if not self._for_us(msg):
            return
        params = (msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7)
        self._answer(msg, params)

    def _handle_command_int(self, msg) -> None:
        if not self._for_us(msg):
            return
        params = (msg.param1, msg.param2, msg.param3, msg.param4, float(msg.x), float(msg.y), msg.z)
        self._answer(msg, params)

    def _answer(self, msg, params: tuple) -> None:
        """Execute, ACK, then send what the command asked for (ArduPilot's order)."""
        self._after_ack = []
        result = self._command(msg.command, params, msg)
        self._ack(msg, msg.command, result)
        for reply in self._after_ack:
            self._send(reply)
        self._after_ack = []

    def _ack(self, msg, command: int, result: int) -> None:
        self._send(
            mavlink.MAVLink_command_ack_message(
                command, int(result), 0, 0, msg.get_srcSystem(), msg.get_srcComponent()
            )
        )

    def _command(self, command: int, p: tuple, msg) -> int:
        """Execute one COMMAND_LONG/COMMAND_INT; returns a MAV_RESULT (PROTOCOL.md Commands)."""
        ap = self.autopilot
        if not all(math.isfinite(v) for v in p[:4]):
            return Result.DENIED
        if command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            return ap.arm(p[0] >= 0.5)
        if command == mavlink.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN and int(p[0]) == 1:
            return self._schedule_reboot()
        if command == mavlink.MAV_CMD_DO_SET_MODE:
            if not int(p[0]) & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
                return Result.FAILED
            return ap.set_mode(int(p[1]))
        if command == mavlink.MAV_CMD_DO_SET_SERVO:
            return ap.set_servo(int(p[0]), p[1])
        if command == mavlink.MAV_CMD_CONDITION_YAW:
            relative = p[3] != 0
            heading = math.radians(p[0])
            if relative and p[2] < 0:
                heading = -heading
            return ap.set_heading(heading, relative=relative)
        if command == mavlink.MAV_CMD_DO_CHANGE_ALTITUDE:
            return ap.set_depth(-p[0])
        if command == mavlink.MAV_CMD_DO_CHANGE_SPEED:
            if p[2] < 0:  # −1 = no change
                return Result.ACCEPTED
            return ap.set_thrust(p[2] / 100.0)
        if command == mavlink.MAV_CMD_REQUEST_MESSAGE:
            built = self._build(int(p[0])) if int(p[0]) in self._requestable else None
            if built is None:
                return Result.DENIED
            self._after_ack.append(built)
            return Result.ACCEPTED
        if command == mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            self._after_ack.append(self._autopilot_version())
            return Result.ACCEPTED
        if command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            return self._set_interval(int(p[0]), p[1])
        if command == mavlink.MAV_CMD_GET_MESSAGE_INTERVAL:
            stream = self._streams.get(int(p[0]))
            if stream is None:
                return Result.DENIED
            interval = int(round(stream.period * self.dt * 1e6)) if stream.period else -1
            self._after_ack.append(mavlink.MAVLink_message_interval_message(stream.msg_id, interval))
            return Result.ACCEPTED
        log.info("unsupported command %d from %d/%d", command, msg.get_srcSystem(),
                 msg.get_srcComponent())
        return Result.UNSUPPORTED

    def _set_interval(self, msg_id: int, interval_us: float) -> int:
        """SET_MESSAGE_INTERVAL: −1 stops a stream, 0 restores its SR_* default (vehicle time)."""
        stream = self._streams.get(msg_id)
        if stream is None:
            return Result.DENIED
        if interval_us == 0:
            stream.custom = False
            if msg_id in ATT_STREAMS:
                self._apply_stream_param("SR_ATT_HZ")
            elif msg_id in POS_STREAMS:
                self._apply_stream_param("SR_POS_HZ")
            else:
                stream.period = self._period_ticks(1.0)
        elif interval_us < 0:
            stream.custom = True
            stream.period = 0
        else:
            stream.custom = True
            stream.period = max(1, int(round(interval_us * 1e-6 / self.dt)))
            stream.next_tick = self.tick
        self._refresh_next_emit()
        return Result.ACCEPTED

    _requestable = frozenset(STREAM_ORDER + (mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION,))
    _handlers: dict[str, Callable[["SimServer", object], None]] = {
        "PARAM_REQUEST_LIST": _handle_param_request_list,
        "PARAM_REQUEST_READ": _handle_param_request_read,
        "PARAM_SET": _handle_param_set,
        "SET_MODE": _handle_set_mode,
        "RC_CHANNELS_OVERRIDE": _handle_rc_override,
        "COMMAND_LONG": _handle_command_long,
        "COMMAND_INT": _handle_command_int,
        "SYSTEM_TIME": _handle_system_time,
    }


def _param_name(raw) -> str:
    """A PARAM_* ``param_id`` as text (pymavlink gives str; tolerate bytes and NUL padding)."""
    if isinstance(raw, (bytes, bytearray)):
        raw = raw.decode("ascii", "replace")
    return str(raw).split("\x00", 1)[0].strip()


def _cm(speed: float) -> int:
    """m/s → cm/s clamped to int16 (GLOBAL_POSITION_INT velocity fields)."""
    return max(-32768, min(32767, int(round(speed * 100.0))))
