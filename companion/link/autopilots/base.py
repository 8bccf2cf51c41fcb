"""What every autopilot strategy does, and the defaults (SPEC C1, §4).

A strategy turns the product's neutral commands into what one autopilot accepts: heading, depth
and thrust set-points, open-loop actuator excitation and its release, the telemetry streams to
ask for, and per-snapshot upkeep (targets that must be refreshed, a ground-station heartbeat the
failsafe needs). The link (``VehicleLink``) holds no autopilot-specific branch; it calls these.
A strategy is given the link's parts as :class:`LinkPorts` and uses nothing else.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace

from companion.interface import Telemetry
from companion.link.clock import VehicleClock
from companion.link.commands import CommandChannel
from companion.link.errors import ProfileError
from companion.link.ground_station import GroundStation
from companion.link.modes import ModeControl
from companion.link.overrides import OverrideChannels
from companion.link.parameters import ParameterChannel
from companion.link.profile import AutopilotProfile
from companion.link.telemetry import TelemetryFeed
from companion.link.transport import Transport
from companion.link.vehicle_state import VehicleAnnouncements

log = logging.getLogger(__name__)

#: message id -> rate (Hz of vehicle time) asked for with MAV_CMD_SET_MESSAGE_INTERVAL
BASE_STREAMS: dict[int, float] = {
    30: 20.0,  # ATTITUDE
    36: 20.0,  # SERVO_OUTPUT_RAW
    32: 10.0,  # LOCAL_POSITION_NED
    74: 10.0,  # VFR_HUD
}


@dataclass
class LinkPorts:
    """The parts of the link a strategy may use, each owning its state (``companion.link``).

    A strategy reaches the vehicle only through these: it never holds the connection object nor
    calls a private method of another part."""

    transport: Transport
    clock: VehicleClock
    announcements: VehicleAnnouncements
    commands: CommandChannel
    modes: ModeControl
    parameters: ParameterChannel
    overrides: OverrideChannels
    telemetry: TelemetryFeed
    ground: GroundStation
    profile: AutopilotProfile | None = None


class AutopilotStrategy:
    """Base strategy: every method says clearly what it cannot do (ProfileError), never guesses."""

    #: telemetry streams to request at connect
    streams: dict[int, float] = BASE_STREAMS
    #: set-points the autopilot keeps as its own state after the companion is done, read back from
    #: telemetry by a restore point and put back after a procedure (none by default)
    persistent_setpoints: tuple[str, ...] = ()

    def __init__(self, ports: LinkPorts) -> None:
        self.ports = ports

    @property
    def profile(self) -> AutopilotProfile:
        if self.ports.profile is None:
            raise ProfileError("no profile yet (still connecting)")
        return self.ports.profile

    @property
    def now(self) -> float:
        """Vehicle time (s)."""
        return self.ports.clock.vehicle_time_s

    def latest(self) -> Telemetry | None:
        """The newest telemetry snapshot."""
        return self.ports.telemetry.latest

    def configure(self) -> AutopilotProfile:
        """The profile completed with what this vehicle says about itself, read at connect (the
        handshake installs the result); the profile unchanged by default."""
        return self.profile

    def in_mode(self, neutral: str) -> bool:
        """The latest HEARTBEAT shows the profile's mode ``neutral``."""
        return self.ports.announcements.custom_mode == self.profile.modes[neutral]

    # ------------------------------------------------------------------ set-points
    def set_heading(self, heading: float) -> None:
        raise self._cannot("a heading set-point")

    def set_depth(self, depth: float) -> None:
        raise self._cannot("a depth set-point")

    def set_thrust(self, thrust_level: float) -> None:
        raise self._cannot("a thrust set-point")

    def set_rolling_mass(self, angle: float) -> None:
        raise self._cannot("rolling-mass servo")

    # ------------------------------------------------------------------ open-loop excitation
    def send_overrides(self, values: list[int]) -> None:
        """Put RC channel values (``companion.link.overrides``) on the vehicle."""
        raise self._cannot("RC override")

    def override(self, actuator: str, value: float) -> None:
        """Drive ``actuator`` open loop (kept alive until released)."""
        self.ports.overrides.override(actuator, value)

    def release(self, actuator: str | None) -> None:
        """Give ``actuator`` (None: all) back to the autopilot."""
        self.ports.overrides.release(actuator)

    def before_mode_change(self, neutral: str) -> None:
        """Called before the link asks for a mode (what must already stream for the autopilot to
        accept it starts here)."""

    def mode_changed(self, neutral: str) -> None:
        """Called after the link switched mode (targets a new mode needs are sent here)."""

    def mode_accepted(self, neutral: str) -> None:
        """Called when the autopilot acknowledged a mode change, before a HEARTBEAT verifies it."""
    # ------------------------------------------------------------------ endings
    def forget_targets(self) -> None:
        """A procedure's restore is done: targets the strategy refreshes on its own (a GUIDED
        heading and speed...) are no longer the companion's to send; none by default."""

    def forget_excitation(self) -> None:
        """End an open-loop excitation without the mode switch that normally ends it (someone else
        has the vehicle, or it rebooted: the companion must not change its mode); none by default."""

    def release_after_crash(self, actuators: list[str]) -> None:
        """Give back overrides a companion that died may have left held (its trail names them; this
        process holds nothing): a release of each channel, repeated like any release."""
        for actuator in actuators:
            self.ports.overrides.release(actuator)

    def on_reboot(self) -> None:
        """The vehicle rebooted: what the strategy kept of the old boot (targets, an excitation, a
        stick being centred) means nothing on the new one."""
        self.forget_excitation()
        self.forget_targets()

    def not_ready(self, telemetry: Telemetry) -> str | None:
        """Why a procedure cannot start on this vehicle yet (an estimator still initialising ...),
        None when it can."""
        return None

    # ------------------------------------------------------------------ upkeep
    def on_snapshot(self, telemetry: Telemetry) -> Telemetry:
        """Per-snapshot upkeep (refresh targets); may complete the snapshot (e.g. a commanded
        actuator where nothing reports it back)."""
        return telemetry

    def servo_model(self, telemetry: Telemetry) -> Telemetry:
        """The rudder a servo of ``profile.actuator_rate_rad_s`` makes of the commanded output,
        rate-limited in vehicle time between snapshots; the snapshot unchanged without a rate.

        A loop's output is applied *after* the attitude it is paired with, so a new command seen
        at snapshot k has moved the servo only since it took effect: ``profile.output_lead_s``
        before snapshot k on average (it may have landed at an unsampled loop); before that the
        servo was still moving towards the previous command. Measured on ArduRover SITL with the
        boat preset's 5 rad/s servo: moving towards the newest command over the whole interval led
        the real rudder by one 40 ms sample and made |a22| 3–6 % too small at 1.4 m/s; starting it
        at the snapshot itself lagged by 0 or 20 ms (the loop the override landed in) and made
        |a22| up to 4 % too large."""
        rate = self.profile.actuator_rate_rad_s
        if rate is None or not math.isfinite(telemetry.rudder):
            return telemetry
        previous = getattr(self, "_servo_state", None)  # (time, modelled deflection, command)
        if previous is None or not math.isfinite(previous[1]):
            modelled = telemetry.rudder
        else:
            time_s, deflection, command = previous
            interval = max(0.0, telemetry.time_s - time_s)
            lead = min(interval, max(0.0, self.profile.output_lead_s))
            modelled = _slew(deflection, command, rate * (interval - lead))
            modelled = _slew(modelled, telemetry.rudder, rate * lead)
        self._servo_state = (telemetry.time_s, modelled, telemetry.rudder)
        return replace(telemetry, rudder=modelled)

    def _cannot(self, what: str) -> ProfileError:
        return ProfileError(f"the {self.profile.name} profile has no {what}")


def _slew(position: float, target: float, max_step: float) -> float:
    """``position`` moved towards ``target`` by at most ``max_step``."""
    if not math.isfinite(target):
        return position
    return position + max(-max_step, min(max_step, target - position))
