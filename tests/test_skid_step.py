"""A skid-steered boat's predicted heading step through its mixer, thrust and speed (eq. A.2k,
companion.numerics.skid_step): the mixer worked by hand, the yaw moment that falls with the throttle
the mixer leaves, the step slower where the mixer binds and where the speed falls, and a rudder
boat's prediction unchanged."""
from __future__ import annotations

import dataclasses
import math

import pytest

from companion.link.actuation import Actuation, OutputScale
from companion.link.profiles import get_profile
from companion.numerics.identification import YawModel
from companion.numerics.skid_step import SkidDrive, SkidMixer, SkidPlant, SkidState, SpeedHold
from companion.numerics.step_response import RudderPlant, predict_step, simulate_step
from companion.procedures.campaign_config import CampaignConfig
from companion.procedures.verified_design import HeadingLimits, limits_case, predicted_step, skid_plant

FULL_SCALE = 0.5236
#: the designed gains the skid boat flew at thrust 0.80 on ArduRover SITL (they ask for full steering)
QUICK = {"heading_rate_ff": 1.49, "heading_rate_p": 2.0, "heading_rate_i": 0.35, "heading_angle_p": 1.34}
MODEL = YawModel(-1.13, 1.47, 0.0)  # its model at 2.0 m/s
STEP = math.radians(40.0)
#: the boat's ATC_STR_RAT_MAX and ATC_STR_ACC_MAX (120°/s, 120°/s²)
LIMITS = {"rate_max": math.radians(120.0), "rate_accel_max": math.radians(120.0)}


def _cascade(model: YawModel = MODEL) -> RudderPlant:
    return RudderPlant(model.a22, model.b2, model.delta0, FULL_SCALE)


# ---------------------------------------------------------------------------- the mixer by hand
def test_the_mixer_scales_steering_and_throttle_together_by_default():
    # σ = t + |s| = 1.8: s' = 1/1.8, t' = 1 − s' (MOT_STR_THR_MIX 0.5)
    out = SkidMixer().mix(1.0, 0.8)
    assert out.steering == pytest.approx(1.0 / 1.8) and out.throttle == pytest.approx(1.0 - 1.0 / 1.8)
    assert out.steering_limited and out.throttle_limited
    inside = SkidMixer().mix(-0.15, 0.8)  # within the room 1 − t
    assert (inside.steering, inside.throttle) == (-0.15, 0.8)
    assert not inside.steering_limited and not inside.throttle_limited


def test_the_mixers_priority_and_asymmetry():
    steering_first = SkidMixer(steering_throttle_mix=1.0).mix(0.6, 0.8)
    assert steering_first.steering == pytest.approx(0.6) and steering_first.throttle == pytest.approx(0.4)
    assert not steering_first.steering_limited and steering_first.throttle_limited
    throttle_first = SkidMixer(steering_throttle_mix=0.0).mix(0.6, 0.8)
    assert throttle_first.throttle == pytest.approx(0.8) and throttle_first.steering == pytest.approx(0.2)
    assert throttle_first.steering_limited and not throttle_first.throttle_limited
    # MOT_THST_ASYM 2: reverse limit −0.5, best throttle 0.25; at t 0.1 the room is 0.1 + 0.5
    slow = SkidMixer(thrust_asymmetry=2.0).mix(1.0, 0.1)
    assert slow.steering == pytest.approx(0.6) and slow.throttle == pytest.approx(0.1) and slow.steering_limited


def test_a_mixer_outside_arduPilots_ranges_is_refused():
    with pytest.raises(ValueError, match="steering_throttle_mix"):
        SkidMixer(steering_throttle_mix=1.5)
    with pytest.raises(ValueError, match="thrust_asymmetry"):
        SkidMixer(thrust_asymmetry=0.5)
    with pytest.raises(ValueError, match="throttle"):
        SkidDrive(SkidMixer(), speed=2.0, throttle=0.0)
    with pytest.raises(ValueError, match="speed_loop"):
        SkidDrive(SkidMixer(), speed=2.0, throttle=0.8, speed_loop=0.1)  # type: ignore[arg-type]


# ---------------------------------------------------------------------------- the yaw moment
def test_the_yaw_moment_follows_the_throttle_the_mixer_leaves():
    drive = SkidDrive(SkidMixer(), speed=2.0, throttle=0.8)  # q = 2: F(d) = d·|d|
    # at the trim throttle the moment is the steering itself: ((0.9)² − (0.7)²)/(2·2·0.8) = 0.1
    assert drive.moment(0.8, 0.1, 2.0) == pytest.approx(0.1)
    # full steering through the mixer: s' 0.556 at t' 0.444, the right motor 0.111 astern:
    # (1 + 0.111²)/3.2 = 0.3164, 31 % of the unit steering eq. A.2 assumes
    out = SkidMixer().mix(1.0, 0.8)
    assert drive.moment(out.throttle, out.steering, 2.0) == pytest.approx((1.0 + (1.0 / 9.0) ** 2) / 3.2)
    # with a thrust linear in the demand (q = 1) only the steering room acts
    linear = SkidDrive(SkidMixer(), speed=2.0, throttle=0.8, thrust_exponent=1.0)
    assert linear.moment(out.throttle, out.steering, 2.0) == pytest.approx(out.steering)


def test_the_integration_is_the_equation():
    # the step's hot loop inlines eq. A.2k; away from the step's speed, with q ≠ 2 and a trim, it is
    # still a22(u)·r + b2(u)·δfs·(M(t', s'; u) − M(t', s0; u))
    drive = SkidDrive(SkidMixer(), speed=2.0, throttle=0.8, thrust_exponent=2.2, a22_slope=-0.15,
                      b2_exponent=1.0, b2_intercept_ratio=0.8)
    state = SkidState(drive, trim_steering=-0.01)
    state.speed, state.throttle = 1.7, 0.55
    expected = (-1.1 - 0.15 * (1.7 - 2.0)) * 0.3 + 1.4 * drive.b2_ratio(1.7) * FULL_SCALE * (
        drive.moment(0.55, 0.45, 1.7) - drive.moment(0.55, -0.01, 1.7))
    assert state.accelerate(-1.1, 1.4, FULL_SCALE, 0.3, 0.45, 0.01) == pytest.approx(expected, rel=1e-12)


def test_the_speed_law_and_the_steady_throttle():
    drive = SkidDrive(SkidMixer(), speed=2.0, throttle=0.8, b2_exponent=1.0, b2_intercept_ratio=0.5)
    assert drive.b2_ratio(1.5) == pytest.approx(2.0 / 2.5)  # (1.5 + 0.5)/(2 + 0.5)
    assert drive.steady_throttle(1.0) == pytest.approx(0.4)  # p = q/2 = 1: t ∝ u
    plant = SkidPlant(SkidMixer(), throttle_gain=2.5, throttle_exponent=1.0, gamma=0.28)
    assert plant.at(2.0).throttle == pytest.approx(0.8) and plant.at(2.0).thrust_exponent == 2.0
    assert SkidPlant.from_dict(dataclasses.asdict(plant)) == plant


# ---------------------------------------------------------------------------- the step
def test_the_step_is_unchanged_where_the_mixer_never_binds_and_the_speed_is_held():
    gentle = {"heading_rate_ff": 0.3, "heading_rate_p": 0.2, "heading_rate_i": 0.1, "heading_angle_p": 1.0}
    drive = SkidDrive(SkidMixer(), speed=1.0, throttle=0.3)  # room 0.7; the steering stays below 0.3
    plain = simulate_step(_cascade(), "cascade", gentle, math.radians(10.0), 20.0)
    skid = simulate_step(_cascade(), "cascade", gentle, math.radians(10.0), 20.0, skid=drive)
    assert skid[2] < 0.3 * FULL_SCALE
    assert skid[1] == pytest.approx(plain[1], abs=1e-9)


def test_the_quick_step_is_slower_and_overshoots_less_where_the_mixer_binds():
    # the SITL flight of these gains at thrust 0.80: IAE 2.36 s, 0.0-0.3 % overshoot; eq. A.2 said 1.27 s, 2.5 %
    plain = predict_step(_cascade(), "cascade", QUICK, STEP, 6.2, **LIMITS)
    drive = SkidDrive(SkidMixer(), speed=2.0, throttle=0.81)
    held = predict_step(_cascade(), "cascade", QUICK, STEP, 6.2, skid=drive, **LIMITS)
    assert plain.figures.iae_s == pytest.approx(1.27, abs=0.03)
    assert plain.figures.overshoot_pct == pytest.approx(2.5, abs=0.3)
    assert held.figures.iae_s == pytest.approx(2.36, rel=0.1) and held.figures.overshoot_pct < 1.5
    assert held.saturated and held.speed_dip_pct == 0.0  # full steering asked for; the speed held


def test_the_speed_dip_is_predicted():
    # the mixer cuts the throttle from 0.81 to 0.45 and the thrust falls: the SITL boat went from
    # 2.00 to 1.72 m/s (14 %); its surge model (γ 0.28, lag 0.4 s) says about the same
    drive = SkidDrive(SkidMixer(), speed=2.0, throttle=0.81, gamma=0.28, lag=0.4, b2_exponent=1.0)
    step = predict_step(_cascade(), "cascade", QUICK, STEP, 6.2, skid=drive, **LIMITS)
    assert step.speed_dip_pct == pytest.approx(13.0, abs=2.0)
    gentle = predict_step(_cascade(), "cascade", QUICK, math.radians(2.0), 6.2, skid=drive, **LIMITS)
    assert gentle.speed_dip_pct < 0.5


def test_the_step_is_slower_when_the_authority_follows_the_falling_speed():
    # a thrust linear in the demand (p = ½, ArduPilot's own motorboat): the yaw moment does not
    # follow the throttle, but b2 ∝ u follows the speed the boat loses in the turn
    held = SkidDrive(SkidMixer(), speed=2.0, throttle=0.81, thrust_exponent=1.0, b2_exponent=1.0)
    slowing = dataclasses.replace(held, gamma=0.28, lag=0.4)
    fixed = predict_step(_cascade(), "cascade", QUICK, STEP, 6.2, skid=held, **LIMITS)
    falling = predict_step(_cascade(), "cascade", QUICK, STEP, 6.2, skid=slowing, **LIMITS)
    assert falling.speed_dip_pct > 10.0 and falling.figures.iae_s > fixed.figures.iae_s + 0.05
    # with thrust ∝ demand² and b2 ∝ u, b2(u)/t_ss(u) is constant: the speed alone changes nothing
    quadratic = dataclasses.replace(slowing, thrust_exponent=2.0)
    assert predict_step(_cascade(), "cascade", QUICK, STEP, 6.2, skid=quadratic, **LIMITS).figures.iae_s == pytest.approx(
        predict_step(_cascade(), "cascade", QUICK, STEP, 6.2, skid=dataclasses.replace(held, thrust_exponent=2.0),
                     **LIMITS).figures.iae_s, rel=1e-6)


def test_the_speed_loop_pushes_the_throttle_back():
    # the original gains at 0.40: the differential thrust speeds the boat up, ArduRover's speed loop
    # cuts the throttle, and the authority goes with it: the step's tail is slower
    original = {"heading_angle_p": 2.0, "heading_rate_ff": 0.2, "heading_rate_i": 0.2, "heading_rate_p": 0.2}
    model = YawModel(-0.99, 0.97, 0.0)
    drive = SkidDrive(SkidMixer(), speed=1.03, throttle=0.42, gamma=0.28, lag=0.4, b2_exponent=1.0)
    free = predict_step(_cascade(model), "cascade", original, STEP, 20.0, skid=drive)
    looped = predict_step(_cascade(model), "cascade", original, STEP, 20.0,
                          skid=dataclasses.replace(drive, speed_loop=SpeedHold(0.1, 0.2)))
    assert looped.figures.iae_s > free.figures.iae_s


# ---------------------------------------------------------------------------- the campaign's wiring
def test_a_rudder_boat_is_predicted_as_before():
    limits = HeadingLimits(rudder_max=FULL_SCALE, rate_max=math.radians(120.0), rate_accel_max=math.radians(120.0))
    case = limits_case("cascade", MODEL, 2.0, limits)
    assert case.skid is None
    plain = predict_step(case.plant, "cascade", QUICK, STEP, 6.2, **case.limits)
    assert predicted_step("cascade", MODEL, QUICK, limits, STEP, 6.2, 2.0) == plain
    assert plain.figures.iae_s == pytest.approx(1.27, abs=0.03) and plain.speed_dip_pct is None
    rover = CampaignConfig(thrusts=(0.6, 1.0), axes=("yaw",)).resolved_for(get_profile("ardurover"))
    assert rover.skid_mixer is None


def test_a_skid_boats_limits_carry_its_drive_at_each_speed():
    plant = SkidPlant(SkidMixer(), throttle_gain=2.48, throttle_exponent=1.0, gamma=0.28, lag=0.4)
    limits = HeadingLimits(rudder_max=FULL_SCALE, skid=plant)
    case = limits_case("cascade", MODEL, 2.0, limits)
    assert case.skid is not None and case.skid.throttle == pytest.approx(2.0 / 2.48)
    assert limits_case("cascade", MODEL, None, limits).skid is None  # no speed: no throttle to mix
    skid_step = predicted_step("cascade", MODEL, QUICK, limits, STEP, 6.2, 2.0)
    assert skid_step.figures.iae_s > 1.7 * predicted_step("cascade", MODEL, QUICK, HeadingLimits(rudder_max=FULL_SCALE),
                                                     STEP, 6.2, 2.0).figures.iae_s
    with pytest.raises(ValueError, match="skid"):
        HeadingLimits(rudder_max=FULL_SCALE, skid=math.inf)  # type: ignore[arg-type]


def test_the_skid_plant_from_what_the_campaign_measured():
    speeds, a22, b2 = [1.03, 1.54, 2.00], [-0.99, -1.10, -1.13], [0.97, 1.23, 1.47]
    levels = [(0.408, 1.003), (0.609, 1.502), (0.809, 2.000)]
    plant = skid_plant(SkidMixer(), levels, None, speeds, a22, b2, "u",
                       {"speed_p": 0.1, "speed_i": 0.2, "heading_rate_ff": 0.2})
    assert plant is not None
    assert plant.throttle_exponent == pytest.approx(1.0, abs=0.03) and plant.gamma == 0.0  # no surge model: held
    assert plant.throttle_at(2.0) == pytest.approx(0.809, abs=0.005)
    assert plant.a22_slope == pytest.approx(-0.145, abs=0.01)
    assert plant.b2_exponent == 1.0 and plant.b2_intercept_ratio == pytest.approx(0.83, abs=0.05)
    assert plant.speed_loop == SpeedHold(0.1, 0.2)
    assert skid_plant(SkidMixer(), [], None, speeds, a22, b2, "u", {}) is None  # no throttle known


def test_a_skid_boat_campaign_predicts_through_its_mixer():
    actuation = Actuation("skid", left=OutputScale(1), right=OutputScale(3), thrust_asymmetry=1.5,
                          steering_throttle_mix=0.7)
    profile = dataclasses.replace(get_profile("ardurover"), actuation=actuation)
    config = CampaignConfig(thrusts=(0.4, 0.8), axes=("yaw",)).resolved_for(profile)
    assert config.skid_mixer == SkidMixer(1.5, 0.7)
