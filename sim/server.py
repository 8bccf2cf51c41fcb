"""The simulator's MAVLink 2 endpoint (docs/PROTOCOL.md; SPEC C2): the simulated autopilot behind it.

One process, one loop: physics at ``dt`` = 0.01 s of vehicle time, telemetry streams scheduled on
the vehicle clock, incoming MAVLink applied between batches of physics steps. :class:`SimServer`
composes the parts, each in a module of its own:

* :mod:`sim.pacing` — the loop: vehicle time against the wall clock (``speedup``), waiting for a
  TCP client that falls behind and, with ``--lockstep``, for the companion (sim/lockstep.py);
* :mod:`sim.routing` — the clients: transport, what arrives from whom, forwarding between clients,
  one datagram/write per tick;
* :mod:`sim.streams` — which telemetry streams are due at a tick; :mod:`sim.telemetry` — the
  messages, built from the vehicle's state;
* :mod:`sim.param_protocol` and :mod:`sim.command_protocol` — the parameter and command handlers.

What stays here is the autopilot's life: its parameters, vehicle and autopilot, its boot clock and
reboots, and the order in which input is applied (free-running: all that has arrived between two
batches; lockstep: at the limit, until an acknowledgement moves it).
"""
from __future__ import annotations

import logging
import os
import time
from dataclasses import dataclass
from typing import Any, Callable

# MAVLink 2 framing must be chosen before pymavlink's dialect module is first imported (this is
# pymavlink's own switch, also used by MAVProxy).
os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402

from sim.autopilot import Autopilot, Result  # noqa: E402
from sim.build import build_vehicle  # noqa: E402
from sim.command_protocol import CommandProtocol  # noqa: E402
from sim.lockstep import COMPONENT as LOCKSTEP_COMPONENT  # noqa: E402
from sim.lockstep import Lockstep  # noqa: E402
from sim.pacing import Pace, log_ratio, run_paced  # noqa: E402
from sim.param_protocol import ParamProtocol  # noqa: E402
from sim.params import ParamTable  # noqa: E402
from sim.preset import load_preset  # noqa: E402
from sim.routing import Clients  # noqa: E402
from sim.streams import RATE_PARAMETERS, StreamScheduler  # noqa: E402
from sim.tcp_clients import TcpClient  # noqa: E402
from sim.telemetry import TelemetryEncoder, heartbeat  # noqa: E402

log = logging.getLogger(__name__)

DEFAULT_LISTEN = "udpin:127.0.0.1:14550"
DEFAULT_PRESET = "starfish"
REBOOT_S = 2.0  # vehicle seconds a rebooting autopilot is silent
MAX_INPUT_READS = 64  # reads of the socket per poll: input never starves the physics


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
    lockstep: bool = False  # see sim/lockstep.py and SimServer.poll_at_limit
    signing_key: bytes | None = None  # MAVLink 2 signing: sign everything, drop unsigned input
    faults: tuple = ()  # sim.faults.Fault: a property scaled from a vehicle time on (with the preset's)


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
        self.reboots = 0  # reboots since the simulator started
        self.dt = config.dt
        self._tick_ms = config.dt * 1000.0
        self._stop = False
        self._wall_s = 0.0  # wall seconds the loop ran
        self.lockstep = Lockstep(config.lockstep, config.dt)
        self.streams = StreamScheduler(self.params, config.dt)
        self.telemetry = TelemetryEncoder(self.vehicle, self.params)
        self.clients = Clients(config.listen, config.signing_key, greeting=lambda: heartbeat(self.autopilot),
                               on_tcp_drop=self.lockstep.client_left)
        self._origin: object = None  # where the message being handled came from
        self._handlers: dict[str, Callable[[Any], None]] = {
            **ParamProtocol(self).handlers,
            **CommandProtocol(self).handlers,
            "SYSTEM_TIME": self._handle_system_time,
        }

    # ------------------------------------------------------------------ public control
    def stop(self) -> None:
        """Ask the loop to finish (safe from a signal handler)."""
        self._stop = True

    @property
    def stopping(self) -> bool:
        return self._stop

    @property
    def time_boot_ms(self) -> int:
        return int(round((self.tick - self._boot_tick) * self._tick_ms))

    def open(self) -> None:
        self.clients.open(int(self.params["SYSID_THISMAV"]))

    def bound_endpoint(self) -> str:
        """The listen endpoint with the port actually bound (``…:0`` asks the OS for a free one)."""
        return self.clients.bound_endpoint()

    def close(self) -> None:
        self.clients.close()

    def run(self) -> int:
        """Serve until stopped or ``duration`` of vehicle time has passed; returns an exit code."""
        if self.clients.conn is None:
            self.open()
        if self._on_ready is not None:
            self._on_ready(self.bound_endpoint())
        try:
            pace = Pace(dt=self.dt, speedup=self.config.speedup, duration=self.config.duration)
            self._wall_s = run_paced(self, self.clients, pace)
        finally:
            log_ratio("final", self._wall_s, self.tick * self.dt, self.config.speedup)
            self.close()
        return 0

    def summary(self) -> dict:
        """What the run did, for the ``STATS`` line on exit: counters and the lockstep record (an
        exact run has ``interruptions`` 0)."""
        traffic = self.clients.traffic
        return {"vehicle_s": round(self.tick * self.dt, 6), "sent": traffic.sent,
                "received": traffic.received, "bad": traffic.bad, "dropped": self.clients.dropped,
                "lockstep": dict(self.lockstep.stats) if self.lockstep.enabled else None}

    # ------------------------------------------------------------------ reboot
    def schedule_reboot(self) -> int:
        """MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN (param1 = 1): the autopilot reboots as ArduPilot does —
        silent for ``REBOOT_S`` of vehicle time (the physics go on), then a fresh boot: its clock from
        0, disarmed in MANUAL with its default set-points, no override, the streams at their SR_*
        rates; its parameters are kept (flash). In lockstep the silence and the new boot's first
        sample run without acknowledgements (there is nothing to acknowledge meanwhile; sim/lockstep.py),
        so the reboot lands at the same vehicle time whatever the pace."""
        self._reboot_at_tick = self.tick + max(1, int(round(REBOOT_S / self.dt)))
        if self.lockstep.enabled:
            self.lockstep.hold_until = self._reboot_at_tick + self.lead_ticks()
        return Result.ACCEPTED

    @property
    def rebooting(self) -> bool:
        return self._reboot_at_tick is not None

    def _boot(self) -> None:
        self._reboot_at_tick = None
        self._boot_tick = self.tick
        self.autopilot = Autopilot(self.vehicle, self.params)
        self.streams.reset(self.tick)
        self.reboots += 1
        log.info("rebooted at vehicle time %.2f s", self.tick * self.dt)

    # ------------------------------------------------------------------ one tick
    def step(self) -> None:
        """One physics step, then the streams due at the new tick (none while rebooting)."""
        self.autopilot.step(self.dt)
        self.tick += 1
        if self._reboot_at_tick is not None:
            if self.tick < self._reboot_at_tick:
                return  # booting: the physics go on, the autopilot says nothing
            self._boot()
        if self.tick >= self.streams.next_emit:
            self._emit_due()

    def _emit_due(self) -> None:
        """Send every stream due at this tick, packed into ONE datagram / TCP write."""
        tick, ms, autopilot, build = self.tick, self.time_boot_ms, self.autopilot, self.telemetry.build
        self.clients.send_together([build(msg_id, tick, ms, autopilot) for msg_id in self.streams.take_due(tick)])

    def build(self, msg_id: int) -> Any | None:
        """One message of the streamed set (or AUTOPILOT_VERSION) from the current state."""
        return self.telemetry.build(msg_id, self.tick, self.time_boot_ms, self.autopilot)

    _build = build  # tests/test_fault_injection.py builds a message by this name

    def send(self, msg: Any) -> None:
        self.clients.send(msg)

    def status_text(self, text: str, severity: int = mavlink.MAV_SEVERITY_WARNING) -> None:
        log.info("STATUSTEXT: %s", text)
        self.send(mavlink.MAVLink_statustext_message(severity, text.encode("ascii", "replace")[:50]))

    def param_changed(self, name: str) -> None:
        """A parameter was set: the stream rates follow SR_*, what is sent carries SYSID_THISMAV."""
        if name in RATE_PARAMETERS:
            self.streams.apply_rate_parameter(name, self.tick)
        elif name == "SYSID_THISMAV":
            self.clients.set_system_id(int(self.params[name]))

    # ------------------------------------------------------------------ input (sim/pacing.py calls)
    def poll(self) -> None:
        """Free-running: apply everything that has arrived (bounded: never starve the physics)."""
        inbox = self.clients.inbox
        for _ in range(MAX_INPUT_READS):
            while inbox:
                self._dispatch(inbox.popleft())
            if not self.clients.receive():
                break
        while inbox:
            self._dispatch(inbox.popleft())

    def poll_at_limit(self) -> bool:
        """Lockstep: apply input in arrival order until an acknowledgement lets the physics move on;
        the rest waits in the inbox for the next limit. True when the physics may move on."""
        inbox = self.clients.inbox
        for _ in range(MAX_INPUT_READS):  # bounded: the loop comes back here at once if it may not move
            while inbox:
                self._dispatch(inbox.popleft())
                if self._may_advance():
                    return True
            if not self.clients.receive():
                return self._may_advance()
        return self._may_advance()

    def lead_ticks(self) -> int:
        """How far past the acknowledged sample the physics may run: one ATTITUDE period (the
        stream's own, which the companion may have set), else 1/SR_ATT_HZ."""
        period = self.streams.period(mavlink.MAVLINK_MSG_ID_ATTITUDE)
        if period > 0:
            return period
        return self.streams.period_ticks(max(self.params["SR_ATT_HZ"], 1.0))

    def _may_advance(self) -> bool:
        limit = self.lockstep.limit(self.tick, self.lead_ticks(), time.monotonic())
        return limit is None or limit > self.tick

    def _dispatch(self, item: tuple[Any, object]) -> None:
        msg, origin = item
        traffic = self.clients.traffic
        traffic.received += 1
        if self._reboot_at_tick is not None:
            return  # a booting autopilot reads nothing
        self._origin = origin
        try:
            self.handle(msg)
            self.clients.route(msg, origin, int(self.params["SYSID_THISMAV"]))
        except Exception:  # a handler bug on odd input is logged, never fatal
            traffic.bad += 1
            log.exception("error handling %s", msg.get_type())
        finally:
            self._origin = None

    def handle(self, msg: Any) -> None:
        """Dispatch one incoming message (unknown types are ignored)."""
        kind = msg.get_type()
        if kind == "BAD_DATA":
            self.clients.traffic.bad += 1
            log.debug("bad data: %s", getattr(msg, "reason", ""))
            return
        handler = self._handlers.get(kind)
        if handler is not None:
            handler(msg)

    def _handle_system_time(self, msg: Any) -> None:
        """SYSTEM_TIME from the companion: its acknowledgement of a processed sample (lockstep)."""
        if msg.get_srcComponent() != LOCKSTEP_COMPONENT:
            return
        self.lockstep.acknowledge(msg.time_boot_ms, self.tick, time.monotonic(),
                                  client=self._origin if isinstance(self._origin, TcpClient) else None,
                                  boot_tick=self._boot_tick, max_ahead=2 * self.lead_ticks())
