"""The form of an autopilot's heading rate loop (eq. A.2r in docs/method.md): which terms of its rate
PID reach the actuator and when its integrator stops. Light (no numerics imported): autopilot
profiles name their form here, ``companion.numerics.step_response.simulate_rate_tracking`` flies it."""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class RateLoopForm:
    """How an autopilot's rate loop makes its output of the rate PID (eq. A.2r).

    ``feed_forward``: FF·r_d is part of the output (ArduRover's AR_AttitudeControl); ArduSub 4.7
    computes it but sends only AC_PID's ``update_all`` (P + I + D) to the motors
    (AC_AttitudeControl_Sub::rate_controller_run). ``freeze_at_limit``: the integrator stops growing
    while the output is at its limit (ArduRover); ArduSub passes the mixer's ``limit.yaw``, which
    AP_Motors6DOF's vectored mix never sets, so only IMAX bounds it."""

    feed_forward: bool = True
    freeze_at_limit: bool = True

    def __post_init__(self) -> None:
        for name, value in (("feed_forward", self.feed_forward), ("freeze_at_limit", self.freeze_at_limit)):
            if not isinstance(value, bool):
                raise ValueError(f"RateLoopForm.{name} must be a bool, not {value!r}")


#: ArduRover's steering rate loop (eq. A.2), the default
ARDUROVER_RATE_LOOP = RateLoopForm()
#: ArduSub's yaw rate loop on the vectored frame (eq. A.2r)
ARDUSUB_RATE_LOOP = RateLoopForm(feed_forward=False, freeze_at_limit=False)
