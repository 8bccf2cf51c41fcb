"""A skid-steered boat's open-loop doublet, kept inside the room its mixer leaves (SPEC C4, §4).

A pilot's (or an override's) steering s and throttle t on an ArduRover skid boat are shrunk together
when |s| + |t| > 1 (``Rover/mode.cpp``, ``get_pilot_desired_steering_and_throttle``; our simulator
does the same), and the mixer itself cannot steer beyond t + |s| ≤ 1, t − |s| ≥ −1/MOT_THST_ASYM
(``companion.link.actuation``). Either way the throttle would drop while the doublet steers and the
speed would sag within the record, which biases a22 and b2. Nor does the slower motor go near
stop: there a propeller crosses its dead band (an ESC's, or the thruster map's: ours gives no thrust
below 5 %) and astern gives less thrust than ahead (ArduPilot's MOT_THST_ASYM exists for it), so the
yaw moment stops being linear in s, while a quadratic thrust map alone keeps it exactly linear
(F(t + s) − F(t − s) = 4a·t·s). Measured on the simulated skid boat at t = 0.4: b2 14 % low with the
doublet reversing a motor, 7–8 % low with it at 0.03, inside the dead band. So the steering stays
within min(1 − |t|, |t| − :data:`SLOW_MOTOR_MIN`, the mixer's own range) − a margin: a doublet that
would leave it is scaled down around its trim, by one factor for the whole excitation (it stays a
doublet), and the strategy says so. Its campaign flies below full throttle (:data:`SKID_THRUSTS`), where there
is room to steer at all.
"""
from __future__ import annotations

from dataclasses import replace

from companion.link.actuation import Actuation
from companion.link.profile import AutopilotProfile

#: a skid boat's campaign thrusts unless the user sets them: its steering room is 1 − |t|, none at
#: full throttle, so the campaign stays below it (with thrust ∝ U², t ∝ U: 40–80 % of the top speed)
SKID_THRUSTS = (0.4, 0.6, 0.8)
#: |s| + |t| stays this far below 1 (a read-back PWM step and the held throttle's trims stay inside)
SKID_MARGIN = 0.03
#: the slower motor's least demand during a doublet: clear of typical ESC and propeller dead bands
SLOW_MOTOR_MIN = 0.10


def doublet_scale(actuation: Actuation | None, full_scale: float, throttle: float, trim: float,
                  value: float, margin: float = SKID_MARGIN) -> tuple[float, str | None]:
    """(factor, message): 1 and None when the doublet around ``trim`` (rad of equivalent rudder)
    whose first value is ``value`` fits at ``throttle``, else the factor that makes it fit and a
    message (≤ 50 characters, a STATUSTEXT) saying so."""
    if actuation is None or not actuation.skid:
        return 1.0, None
    room = min(1.0 - abs(throttle), abs(throttle) - SLOW_MOTOR_MIN, actuation.steering_room(throttle)) - margin
    centre, swing = abs(trim) / full_scale, abs(value - trim) / full_scale
    if swing <= 0.0 or centre + swing <= room:
        return 1.0, None
    scale = max(0.0, (room - centre) / swing)
    if scale > 0.0:
        return scale, f"skid: doublet x{scale:.2f} (steering room {room:.2f})"
    return 0.0, f"skid: no steering room at throttle {throttle:.2f}"


#: a doublet scaled below this fraction of the one asked for is refused (too small to identify from)
MIN_SCALE = 0.05


def refusal(throttle: float, scale: float) -> str | None:
    """Why a doublet cannot be flown at ``throttle`` (None when it can): what a user can change."""
    if scale >= MIN_SCALE:
        return None
    if throttle >= 0.5:
        return (f"skid steering: at throttle {throttle:.2f} the mixer leaves no room to steer without cutting the "
                "throttle: fly slower (lower --thrusts, fractions of WP_SPEED), or check that the speed loop holds "
                "the speed (CRUISE_THROTTLE/CRUISE_SPEED near the boat's own)")
    return (f"skid steering: at throttle {throttle:.2f} the mixer leaves no room to steer without a motor near stop "
            f"or astern: fly faster (the campaign's thrusts are fractions of WP_SPEED; at those speeds this boat "
            f"needs throttle {throttle:.2f}: raise WP_SPEED for the campaign)")


def scaled(value: float, trim: float, scale: float) -> float:
    """An override of a scaled excitation: ``trim + scale·(value − trim)``."""
    return value if scale == 1.0 else trim + scale * (value - trim)


def with_actuation(profile: AutopilotProfile, actuation: Actuation) -> AutopilotProfile:
    """``profile`` with the actuation read from the vehicle; a skid boat's campaign defaults to
    :data:`SKID_THRUSTS` (the user's ``--thrusts`` still win)."""
    if actuation.skid:
        return replace(profile, actuation=actuation,
                       campaign_defaults=replace(profile.campaign_defaults, thrusts=SKID_THRUSTS))
    return replace(profile, actuation=actuation)
