"""The telemetry stream scheduler of the simulated autopilot (docs/PROTOCOL.md, "Telemetry").

Streams are scheduled on the vehicle clock in whole ticks of ``dt``, so a rate is exact whatever the
pace: each stream has a period in ticks (0 = stopped) and the tick it is next due. The attitude
pair follows ``SR_ATT_HZ``, the position set ``SR_POS_HZ``, HEARTBEAT, SYS_STATUS and SYSTEM_TIME
run at 1 Hz; SET_MESSAGE_INTERVAL gives a stream a rate of its own (it then no longer follows its
SR_* parameter) until an interval of 0 restores the default. Which messages the streams carry and
how they are encoded is :mod:`sim.telemetry`'s.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sim.params import ParamTable

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
#: the SR_* parameter that sets each group's rate
RATE_PARAMETERS = {"SR_ATT_HZ": ATT_STREAMS, "SR_POS_HZ": POS_STREAMS}
NEVER = 1 << 62  # the next emission tick while every stream is stopped


@dataclass(slots=True)
class Stream:
    """One message's schedule."""

    msg_id: int
    period: int = 0  # ticks; 0 = disabled
    next_tick: int = 0
    custom: bool = False  # set by SET_MESSAGE_INTERVAL, no longer follows SR_* parameters


def period_ticks(hz: float, dt: float) -> int:
    """A rate as a whole number of ticks (at least one); 0 (stopped) for a rate ≤ 0 or not finite."""
    if hz <= 0 or not math.isfinite(hz):
        return 0
    return max(1, int(round(1.0 / (hz * dt))))


class StreamScheduler:
    """Which streams are due at a tick, at the rates the SR_* parameters and SET_MESSAGE_INTERVAL set."""

    def __init__(self, params: ParamTable, dt: float) -> None:
        self._params = params
        self.dt = dt
        self.streams = {msg_id: Stream(msg_id) for msg_id in STREAM_ORDER}
        self._ordered = [self.streams[m] for m in STREAM_ORDER]
        self.next_emit = 0  # the first tick at which a stream is due
        self.reset(0)

    def period_ticks(self, hz: float) -> int:
        return period_ticks(hz, self.dt)

    def reset(self, tick: int) -> None:
        """Every stream at its default rate, due at ``tick`` (a boot)."""
        for stream in self._ordered:
            stream.custom = False
            stream.next_tick = tick
        for name in RATE_PARAMETERS:
            self.apply_rate_parameter(name, tick)
        for msg_id in ONE_HZ_STREAMS:
            self.streams[msg_id].period = self.period_ticks(1.0)
        self._refresh()

    def apply_rate_parameter(self, name: str, tick: int) -> None:
        """``SR_ATT_HZ`` or ``SR_POS_HZ`` changed: its streams without a rate of their own follow it
        from ``tick`` on."""
        period = self.period_ticks(self._params[name])
        for msg_id in RATE_PARAMETERS[name]:
            stream = self.streams[msg_id]
            if not stream.custom:
                stream.period = period
                stream.next_tick = tick
        self._refresh()

    def set_interval(self, msg_id: int, interval_us: float, tick: int) -> bool:
        """SET_MESSAGE_INTERVAL: −1 stops a stream, 0 restores its SR_* default (vehicle time);
        False for a message that is not streamed."""
        stream = self.streams.get(msg_id)
        if stream is None:
            return False
        if interval_us == 0:
            stream.custom = False
            name = next((n for n, ids in RATE_PARAMETERS.items() if msg_id in ids), None)
            if name is not None:
                self.apply_rate_parameter(name, tick)
            else:
                stream.period = self.period_ticks(1.0)
        elif interval_us < 0:
            stream.custom = True
            stream.period = 0
        else:
            stream.custom = True
            stream.period = max(1, int(round(interval_us * 1e-6 / self.dt)))
            stream.next_tick = tick
        self._refresh()
        return True

    def interval_us(self, msg_id: int) -> int | None:
        """GET_MESSAGE_INTERVAL: the stream's interval in µs, −1 while stopped; None when not streamed."""
        stream = self.streams.get(msg_id)
        if stream is None:
            return None
        return int(round(stream.period * self.dt * 1e6)) if stream.period else -1

    def period(self, msg_id: int) -> int:
        """A stream's period in ticks (0: stopped)."""
        return self.streams[msg_id].period

    def take_due(self, tick: int) -> list[int]:
        """The messages due at ``tick``, in emission order, each scheduled again one period on."""
        due = []
        for stream in self._ordered:
            if stream.period and stream.next_tick <= tick:
                due.append(stream.msg_id)
                stream.next_tick = tick + stream.period
        self._refresh()
        return due

    def _refresh(self) -> None:
        ticks = [s.next_tick for s in self._ordered if s.period > 0]
        self.next_emit = min(ticks) if ticks else NEVER
