"""A ground station that flies an ordinary survey on our simulator over MAVLink: arm, the holding
mode, then the :class:`harness.missions.SurveyPlan`'s thrust and course set-points as the vehicle's
clock (ATTITUDE ``time_boot_ms``) reaches them — the vehicle's mission, beside a companion that only
watches (``companion run --learn``). It runs in a thread of its own, like a separate program.

Its set-points follow the vehicle's clock, but it is not the lockstep client: a set-point reaches
the simulator some wall milliseconds after the sample that called for it, so a course change can
start a little later in vehicle time on a busy machine. A course change's response is the same
whenever it starts, so what learning concludes does not depend on it; its timing does, a little.
"""
from __future__ import annotations

import logging
import math
from collections.abc import Mapping

from harness.mavlink_clients import connect_client, set_param_echoed
from harness.missions import SurveyPlan
from harness.station_thread import StationThread

log = logging.getLogger(__name__)

MAV_CMD_COMPONENT_ARM_DISARM = 400
MAV_CMD_DO_SET_MODE = 176
MAV_CMD_CONDITION_YAW = 115
MAV_CMD_DO_CHANGE_SPEED = 178
MODE_HOLD = 2  # the simulator's ALT_HOLD: heading and depth held, set-points obeyed
CUSTOM_MODE_ENABLED = 1


class SurveyGroundStation(StationThread):
    """``start()`` flies ``plan`` until ``stop()`` (module docstring); ``sent`` lists
    (vehicle time, thrust, course rad) of every set-point change sent."""

    what = "survey ground station"

    def __init__(self, endpoint: str, plan: SurveyPlan, *, source_system: int = 255,
                 parameters: Mapping[str, float] | None = None) -> None:
        super().__init__()
        self.endpoint, self.plan, self.source_system = endpoint, plan, source_system
        self.parameters = dict(parameters or {})
        self.sent: list[tuple[float, float, float]] = []

    def start(self) -> "SurveyGroundStation":
        """Connect, set ``parameters`` (each until echoed), then fly in the thread. The parameters are
        set before the thread reads the connection: its reader would otherwise take the echoes."""
        self.conn = connect_client(self.endpoint, source_system=self.source_system)
        for name, value in self.parameters.items():
            set_param_echoed(self.conn, name, value)
        self._start_thread()
        return self

    def _run(self) -> None:
        last: tuple[float, float] | None = None
        armed_sent = False
        while not self._stop.is_set():
            msg = self.conn.recv_match(type=["ATTITUDE", "HEARTBEAT"], blocking=True, timeout=0.5)
            if msg is None:
                continue
            if msg.get_type() == "HEARTBEAT":
                if msg.get_srcComponent() != 1:
                    continue
                if not msg.base_mode & 128 or msg.custom_mode != MODE_HOLD:
                    if not armed_sent or not msg.base_mode & 128:
                        self.command(MAV_CMD_COMPONENT_ARM_DISARM, 1.0)
                        armed_sent = True
                    self.command(MAV_CMD_DO_SET_MODE, CUSTOM_MODE_ENABLED, MODE_HOLD)
                    last = None  # a mode change captures the heading: say the set-points again
                continue
            t = msg.time_boot_ms / 1000.0
            setpoint = self.plan.setpoints(t)
            if setpoint != last:
                thrust, course = setpoint
                self.command(MAV_CMD_DO_CHANGE_SPEED, 0.0, -1.0, 100.0 * thrust)
                self.command(MAV_CMD_CONDITION_YAW, math.degrees(course) % 360.0)
                self.sent.append((t, thrust, course))
                last = setpoint
