"""What every autopilot strategy does, and the defaults (SPEC C1, §4).

A strategy turns the product's neutral commands into what one autopilot accepts: heading, depth
and thrust set-points, open-loop actuator excitation and its release, the telemetry streams to
ask for, and per-snapshot upkeep (targets that must be refreshed, a ground-station heartbeat the
failsafe needs). The link (``VehicleLink``) holds no autopilot-specific branch; it calls these.
"""
from __future__ import annotations

import logging
import math
from dataclasses import replace

from companion.interface import Telemetry

log = logging.getLogger(__name__)

#: message id -> rate (Hz of vehicle time) asked for with MAV_CMD_SET_MESSAGE_INTERVAL
BASE_STREAMS: dict[int, float] = {
    30: 20.0,  # ATTITUDE
    36: 20.0,  # SERVO_OUTPUT_RAW
    32: 10.0,  # LOCAL_POSITION_NED
    74: 10.0,  # VFR_HUD
}


class AutopilotStrategy:
    """Base strategy: every method says clearly what it cannot do (ProfileError), never guesses."""

    #: telemetry streams to request at connect
    streams: dict[int, float] = BASE_STREAMS

    def __init__(self, link) -> None:
        self.link = link

    @property
    def profile(self):
        return self.link.profile

    # ------------------------------------------------------------------ set-points
    def set_heading(self, heading: float) -> None:
        raise self._cannot("a heading set-point")

    def set_depth(self, depth: float) -> None:
        raise self._cannot("a depth set-point")

    def set_thrust(self, thrust_ratio: float) -> None:
        raise self._cannot("a thrust set-point")

    # ------------------------------------------------------------------ open-loop excitation
    def override(self, actuator: str, value: float) -> None:
        """Drive ``actuator`` open loop (RC override from the GCS system id, kept alive)."""
        self.link.override(actuator, value)

    def release(self, actuator: str | None) -> None:
        """Give ``actuator`` (None: all) back to the autopilot."""
        self.link.release(actuator)

    def mode_changed(self, neutral: str) -> None:
        """Called after the link switched mode (targets a new mode needs are sent here)."""

    # ------------------------------------------------------------------ upkeep
    def on_snapshot(self, telemetry: Telemetry) -> Telemetry:
        """Per-snapshot upkeep (refresh targets); may complete the snapshot (e.g. a commanded
        actuator where nothing reports it back)."""
        return telemetry

    def servo_model(self, telemetry: Telemetry) -> Telemetry:
        """The rudder a servo of ``profile.actuator_rate_rad_s`` makes of the commanded output
        (rate-limited in vehicle time between snapshots); the snapshot unchanged without a rate."""
        rate = self.profile.actuator_rate_rad_s
        if rate is None or not math.isfinite(telemetry.rudder):
            return telemetry
        previous = getattr(self, "_servo_state", None)
        if previous is None or not math.isfinite(previous[1]):
            modelled = telemetry.rudder
        else:
            step = rate * max(0.0, telemetry.time_s - previous[0])
            modelled = previous[1] + max(-step, min(step, telemetry.rudder - previous[1]))
        self._servo_state = (telemetry.time_s, modelled)
        return replace(telemetry, rudder=modelled)

    def _cannot(self, what: str):
        from companion.link.errors import ProfileError

        return ProfileError(f"the {self.profile.name} profile has no {what}")


def yaw_quaternion(heading: float) -> list[float]:
    """(w, x, y, z) of a level attitude at ``heading`` (rad, clockwise from north)."""
    return [math.cos(heading / 2.0), 0.0, 0.0, math.sin(heading / 2.0)]
