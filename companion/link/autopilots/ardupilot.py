"""What every ArduPilot vehicle shares, as the companion meets it (SPEC §4).

* **Dialect**: ``ardupilotmega`` (a superset of ``common``; the link opens every connection with
  it, see :data:`companion.link.autopilots.CONNECT_DIALECT`).
* **RC overrides** are accepted only from the ground station's system id (``MAV_GCS_SYSID``,
  formerly ``SYSID_MYGCS``) and expire after ``RC_OVERRIDE_TIME``: :meth:`ArduPilotStrategy.send_overrides`
  sends them as the ground station, and the link refreshes them with every snapshot.
* **SET_ATTITUDE_TARGET** carries heading (quaternion) and, on Rover, the speed demand (thrust ×
  ``WP_SPEED``); targets expire (Rover 3 s, Sub 5 s) and are refreshed by the strategies.
* **A ground-station heartbeat** is what ArduSub's GCS failsafe watches (a companion's own heartbeat
  on component 191 does not count).
* **Servo functions** (``SERVOn_FUNCTION``) say what each output drives: a boat's actuation is read
  from them at connect (:meth:`ArduPilotStrategy.read_actuation`, ``companion.link.actuation``).
* **Spare outputs** take DO_SET_SERVO (refused on an output that has a function).

Our simulator follows the same override and servo rules (docs/PROTOCOL.md), so its strategy builds
on :class:`ArduPilotStrategy` too.
"""
from __future__ import annotations

import math
from typing import Sequence

from companion.link.actuation import (
    FUNCTION_GROUND_STEERING,
    FUNCTION_RUDDER,
    FUNCTION_THROTTLE,
    FUNCTION_THROTTLE_LEFT,
    FUNCTION_THROTTLE_RIGHT,
    MIXER_DEFAULTS,
    Actuation,
    actuation_from_functions,
    function_names,
)
from companion.link.autopilots.base import AutopilotStrategy
from companion.link.errors import ParamTimeout, ProfileError
from companion.link.transport import MAV_AUTOPILOT_INVALID, MAV_STATE_ACTIVE, MAV_TYPE_GCS

DIALECT = "ardupilotmega"
#: the component a ground-station heartbeat is sent from (any component of the GCS system id counts)
GCS_HEARTBEAT_COMPONENT = 190

#: SERVOn_FUNCTION values the companion understands (ArduPilot's SRV_Channel::Aux_servo_function_t)
SERVO_FUNCTION_RUDDER = FUNCTION_RUDDER
SERVO_FUNCTION_GROUND_STEERING = FUNCTION_GROUND_STEERING
SERVO_FUNCTION_THROTTLE = FUNCTION_THROTTLE
SERVO_FUNCTION_THROTTLE_LEFT = FUNCTION_THROTTLE_LEFT
SERVO_FUNCTION_THROTTLE_RIGHT = FUNCTION_THROTTLE_RIGHT


def yaw_quaternion(heading: float) -> list[float]:
    """(w, x, y, z) of a level attitude at ``heading`` (rad, clockwise from north)."""
    return [math.cos(heading / 2.0), 0.0, 0.0, math.sin(heading / 2.0)]


class ArduPilotStrategy(AutopilotStrategy):
    """The ArduPilot habits every vehicle of the family shares (module docstring)."""

    def send_overrides(self, values: list[int]) -> None:
        """RC_CHANNELS_OVERRIDE from the vehicle's ground-station system id (ArduPilot accepts it
        only from there), then back to our own identity."""
        transport = self.ports.transport
        transport.send_as(self.ports.ground.gcs_sysid, transport.component,
                          lambda mav: mav.rc_channels_override_send(transport.system_id,
                                                                    transport.autopilot_component, *values))

    def send_attitude_target(self, quaternion: Sequence[float], thrust: float, *, ignore_thrust: bool = False) -> None:
        """SET_ATTITUDE_TARGET: attitude from the quaternion, body rates ignored (type_mask 7, +64
        to ignore the thrust field)."""
        type_mask = 7 | (64 if ignore_thrust else 0)
        now = self.now
        time_ms = int(now * 1000) if math.isfinite(now) else 0
        transport = self.ports.transport
        transport.mav.set_attitude_target_send(time_ms & 0xFFFFFFFF, transport.system_id,
                                               transport.autopilot_component, type_mask,
                                               [float(q) for q in quaternion], 0.0, 0.0, 0.0, float(thrust))

    def send_gcs_heartbeat(self) -> None:
        """A HEARTBEAT as the ground station (its system id, type GCS): what a GCS failsafe watches."""
        self.ports.transport.send_as(self.ports.ground.gcs_sysid, GCS_HEARTBEAT_COMPONENT,
                                     lambda mav: mav.heartbeat_send(MAV_TYPE_GCS, MAV_AUTOPILOT_INVALID, 0, 0,
                                                                    MAV_STATE_ACTIVE))

    def set_rolling_mass(self, angle: float) -> None:
        """The rolling mass on its spare output (DO_SET_SERVO, not awaited)."""
        if self.profile.mass_servo is None:
            raise self._cannot("rolling-mass servo")
        self.ports.commands.set_servo(self.profile.mass_servo, self.profile.angle_to_pwm(angle))

    # ------------------------------------------------------------------ what the vehicle says it is
    def read_present(self, names: tuple[str, ...], fence: str) -> dict[str, float]:
        """The parameters among ``names`` the vehicle has: all requested at once, then ``fence`` (a
        parameter it certainly has) read and awaited; ArduPilot and our simulator answer requests in
        order (ArduPilot through a FIFO), so what has not answered by then is not there (or was lost:
        a caller that needs a name reads it again)."""
        parameters = self.ports.parameters
        since = {name: parameters.events.get(name, 0) for name in names}
        for name in names:
            parameters.request(name)
        parameters.get_param(fence)
        return {name: parameters.cache[name] for name in names if parameters.events.get(name, 0) > since[name]}

    def read_actuation(self, outputs: tuple[int, ...], *, required: bool) -> Actuation | None:
        """The boat's actuation from ``SERVOn_FUNCTION`` of ``outputs`` and, for the outputs in use,
        SERVOn_MIN/TRIM/MAX/REVERSED and the skid mixer's MOT_* parameters. With ``required`` a
        missing answer is asked again and a vehicle that reports no function is refused
        (ProfileError); otherwise None when it reports none (not a boat)."""
        fence = self.profile.marker_param
        names = function_names(outputs)
        params = self.read_present(names, fence)
        if required:
            for name in names:
                if name not in params:
                    try:
                        params[name] = self.ports.parameters.get_param(name, retries=2)
                    except ParamTimeout:
                        continue
        functions = {n: params[name] for n, name in zip(outputs, names) if name in params}
        where = f"this {self.profile.name} vehicle"
        if not functions:
            if required:
                raise ProfileError(f"{where} did not report SERVOn_FUNCTION: the companion cannot tell which "
                                   "output steers (a link that drops parameter requests?)")
            return None
        layout = actuation_from_functions(functions, {}, where)
        scales = self.read_present(layout.scale_params() + tuple(MIXER_DEFAULTS), fence)
        return actuation_from_functions(functions, scales, where)
