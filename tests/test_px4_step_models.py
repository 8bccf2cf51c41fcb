"""PX4's heading controllers as step models (eq. A.4, A.5), their rule families in the designer by
prediction (eq. D.1), the campaign's wiring and ``companion design --autopilot px4-rover|px4-uuv``."""
from __future__ import annotations

import json
import math
from dataclasses import dataclass

import control
import numpy as np
import pytest

from behaviors.schedules import schedule_kind
from companion.cli.main import main as cli_main
from companion.link.autopilots import px4_rover, px4_uuv
from companion.numerics.cascade_gains import CascadeRules
from companion.numerics.identification import YawModel
from companion.numerics.px4_gains import design_ackermann_gains, design_uuv_gains
from companion.numerics.px4_step import AckermannYawControl, UuvAllocation, UuvYawControl, fly
from companion.numerics.step_design import (DesignObjective, design_by_prediction, px4_rover_case, px4_rover_family,
                                            px4_uuv_case, px4_uuv_family)
from companion.numerics.step_response import RudderPlant, simulate_step, step_metrics
from companion.procedures.campaign import CampaignConfig
from companion.procedures.heading_design import choose_heading_design, optimisable, with_design
from companion.procedures.verified_design import CONTROLLERS, LIMIT_PARAMETERS, HeadingLimits, predicted_step

BOAT = YawModel(a22=-0.9, b2=1.1, delta0=0.0)  # a rudder boat at 1.5 m/s
AUV = YawModel(a22=-0.948, b2=0.489, delta0=0.0)  # our STARFISH at 0.86 m/s (sim.linearize)
ROVER_RULES = CascadeRules(**px4_rover.GAIN_RANGES)
UUV_RULES = CascadeRules(full_scale=0.35, **px4_uuv.GAIN_RANGES)
#: PX4's shipped gains (generic Ackermann rover airframe 51000; uuv_att_control's defaults)
ROVER_SHIPPED = {"heading_angle_p": 3.0, "heading_rate_p": 0.25, "heading_rate_i": 0.01, "heading_ff_length": 0.5,
                 "heading_ff_correction": 1.0}
UUV_SHIPPED = {"heading_angle_p": 4.0, "heading_rate_d": 2.0}
OBJECTIVE = DesignObjective(max_evaluations=50)


def _linear_rover_loop(model: YawModel, gains: dict[str, float], speed: float) -> control.TransferFunction:
    """ψ/ψ_a of eq. A.4 without its limits, atan linearised: r_d = RO_YAW_P·(ψ_a − ψ),
    δ = (CORR·L/û)·r_d + (P + I/s)·(r_d − r), ṙ = a22·r + b2·δ."""
    plant = control.tf([model.b2], [1.0, -model.a22])  # δ → r
    pi = control.tf([gains["heading_rate_p"], gains["heading_rate_i"]], [1.0, 0.0])
    feed_forward = gains["heading_ff_correction"] * gains["heading_ff_length"] / speed
    rate_loop = control.feedback(plant, pi) * (feed_forward + pi)  # r / r_d
    heading = gains["heading_angle_p"] * rate_loop * control.tf([1.0], [1.0, 0.0])
    return control.feedback(heading, 1)


# ---------------------------------------------------------------------- eq. A.4: the Ackermann rover
def test_a_small_rover_step_is_the_linear_loop_of_its_transfer_function():
    speed, step, dt = 1.5, math.radians(0.5), 0.002
    gains = design_ackermann_gains(BOAT, speed, ROVER_RULES).params()
    controller = AckermannYawControl.from_gains(gains, speed_estimate=speed, steering_max=0.5236)
    trace = fly(RudderPlant(BOAT.a22, BOAT.b2, 0.0, 0.5236), controller, step, 12.0, dt)
    assert trace.rudder_peak < 0.5 * 0.5236  # far from every limit
    # the yaw set-point is slewed at the feasible rate û·tan(δmax)/L: the same ramp enters the linear loop
    ramp = np.minimum(step, controller.feasible_rate * trace.times)
    linear = control.forced_response(_linear_rover_loop(BOAT, gains, speed), trace.times, ramp).outputs
    assert np.max(np.abs(trace.heading - linear)) < 0.01 * step


def test_the_yaw_rate_limit_bounds_the_turn_and_the_yaw_set_point_ramps_at_it():
    speed, limit = 1.5, math.radians(10.0)
    gains = design_ackermann_gains(BOAT, speed, ROVER_RULES).params()
    controller = AckermannYawControl.from_gains(gains, speed_estimate=speed, steering_max=0.5236, rate_max=limit)
    trace = fly(RudderPlant(BOAT.a22, BOAT.b2, 0.0, 0.5236), controller, math.radians(40.0), 15.0, 0.01)
    # the rate loop follows the limited set-point (its integral overshoots it by a few per cent)
    assert 0.95 * limit < np.max(np.abs(trace.yaw_rate)) <= 1.05 * limit
    # 40° at 10°/s: not before 4 s within 5 % of the step
    reached = trace.times[np.argmax(trace.heading >= 0.95 * math.radians(40.0))]
    assert 3.6 < reached < 5.0


def _unanswered(rate_p: float, loops: int = 2000) -> tuple[AckermannYawControl, float]:
    """A rover asked for 60° whose turn never comes (the rudder saturated, the yaw rate 0)."""
    controller = AckermannYawControl(yaw_p=1.0, rate_p=rate_p, rate_i=0.5, wheel_base=1.0, speed_estimate=1.5,
                                     steering_max=0.5236, rate_max=math.radians(30.0))
    controller.start(0.0)
    for _ in range(loops):
        rudder = controller.update(math.radians(60.0), 0.0, 0.0, 0.01)
    return controller, rudder


def test_the_rate_integral_is_held_at_its_own_clamp_not_at_the_rudders():
    # the rudder sits at RA_MAX_STR_ANG from the start, while the integral keeps growing up to the PI's
    # ±1 rad (PX4's PID: setIntegralLimit(1)) and no further
    controller, rudder = _unanswered(rate_p=0.0)
    assert rudder == pytest.approx(0.5236) and controller.integral == 1.0
    # it stops where the PI's own output reaches its ±1 rad limit (conditional integration): with
    # P·(r_d − r) = 0.1·30°/s it stops at 1 − 0.052 rad
    controller, _ = _unanswered(rate_p=0.1)
    assert controller.integral == pytest.approx(1.0 - 0.1 * math.radians(30.0), abs=0.5 * 0.01 * 0.5)
    # and is frozen while P alone is beyond it (after the few loops in which the demand grew to 1/P)
    controller, _ = _unanswered(rate_p=5.0, loops=500)
    frozen = controller.integral
    for _ in range(500):
        controller.update(math.radians(60.0), 0.0, 0.0, 0.01)
    assert frozen < 0.05 and controller.integral == frozen


def test_measured_yaw_rates_below_the_threshold_read_zero_and_the_trim_is_held():
    controller = AckermannYawControl(yaw_p=1.0, rate_p=1.0, rate_i=0.2, wheel_base=1.0, speed_estimate=1.5,
                                     steering_max=0.5236, rate_threshold=math.radians(3.0))
    assert controller.start(0.03) == 0.0 and controller.integral == pytest.approx(0.03)
    # on course, turning at 2°/s (below RO_YAW_RATE_TH): no rate error is seen, the trim stays
    assert controller.update(0.0, 0.0, math.radians(2.0), 0.01) == pytest.approx(0.03)
    # at 4°/s it is seen: the rate loop steers against it
    assert controller.update(0.0, 0.0, math.radians(4.0), 0.01) < 0.03 - 0.05


def test_the_rover_refuses_what_px4_refuses_to_fly():
    with pytest.raises(ValueError):
        AckermannYawControl(yaw_p=1.0, rate_p=1.0, rate_i=0.1, wheel_base=0.0, speed_estimate=1.5, steering_max=0.5)
    with pytest.raises(ValueError):
        AckermannYawControl(yaw_p=1.0, rate_p=1.0, rate_i=0.1, wheel_base=1.0, speed_estimate=0.0, steering_max=0.5)


def test_the_rover_model_predicts_the_flown_overshoot_of_px4_sitls_own_gains():
    # docs/figures.md: PX4 SITL with sim/px4/px4-rover.params flew ±20° steps at 18.2–20.8 % on our boat
    # at 1.25–2.25 m/s (its b2 = 0.735·(u/1.5)², a22 = −0.975 − 0.25·(u − 1.5), sim.linearize)
    gains = {"heading_angle_p": 1.5, "heading_rate_p": 0.3, "heading_rate_i": 0.1, "heading_ff_length": 2.0,
             "heading_ff_correction": 1.0}
    for speed in (1.25, 1.75, 2.25):
        model = YawModel(-0.975 - 0.25 * (speed - 1.5), 0.735 * (speed / 1.5) ** 2, 0.02)
        limits = HeadingLimits(rudder_max=0.5236, rudder_rate=5.0, rate_max=math.radians(30.0),
                               steering_rate=math.radians(286.0), rate_threshold=math.radians(0.5))
        step = predicted_step("px4_rover", model, gains, limits, math.radians(20.0), 30.0, speed)
        assert 15.0 < step.figures.overshoot_pct < 24.0


# ---------------------------------------------------------------------- eq. A.5: the UUV
def test_a_small_uuv_step_is_its_pd_loops_transfer_function():
    step, dt, full_scale = math.radians(0.5), 0.002, 0.35
    gains = design_uuv_gains(AUV, UUV_RULES).params()
    times, heading, peak = simulate_step(RudderPlant(AUV.a22, AUV.b2, 0.0, full_scale), "px4_uuv", gains, step, 12.0,
                                         full_scale=full_scale, dt=dt)
    b = AUV.b2 * full_scale
    p, d = gains["heading_angle_p"], gains["heading_rate_d"]
    loop = control.tf([b * p], [1.0, -AUV.a22 + b * d, b * p])
    linear = control.step_response(loop, times).outputs * step
    assert peak < full_scale and np.max(np.abs(heading - linear)) < 0.01 * step


def test_the_torque_limit_bounds_the_equivalent_rudder():
    controller = UuvYawControl(yaw_p=4.0, yaw_d=2.0, full_scale=0.35, torque_max=0.3)
    trace = fly(RudderPlant(AUV.a22, AUV.b2, 0.0, 0.35), controller, math.radians(40.0), 20.0, 0.01)
    assert trace.rudder_peak == pytest.approx(0.3 * 0.35)


def test_without_an_integrator_the_uuv_holds_a_rudder_offset_at_a_heading_error():
    controller = UuvYawControl(yaw_p=4.0, yaw_d=2.0, full_scale=0.35)
    offset = controller.start(0.01)
    assert offset == pytest.approx(-math.asin(0.01 / 0.35 / 4.0))
    assert controller.update(0.0, offset, 0.0, 0.01) == pytest.approx(0.01)
    with pytest.raises(ValueError):
        UuvYawControl(yaw_p=4.0, yaw_d=2.0, full_scale=0.35, torque_max=1.5)


# ---------------------------------------------------------------------- eq. D.1 for PX4
def test_the_rule_families_default_points_are_px4_gains_formulas():
    rover, uuv = px4_rover_family(ROVER_RULES), px4_uuv_family(UUV_RULES)
    rule = design_ackermann_gains(BOAT, 1.5, ROVER_RULES)
    assert rover.gains(rover.make(rover.x0), BOAT, 1.5) == pytest.approx(rule.params())
    assert uuv.gains(uuv.make(uuv.x0), AUV, 0.86) == pytest.approx(design_uuv_gains(AUV, UUV_RULES).params())
    # the cascade's FF scale is PX4's RO_YAW_RATE_CORR; the angle ratio moves RO_YAW_P and UUV_YAW_P
    x = rover.x0.copy()
    x[1], x[3] = 0.3, 0.8
    moved = rover.gains(rover.make(x), BOAT, 1.5)
    assert moved["heading_ff_correction"] == pytest.approx(0.8)
    assert moved["heading_ff_length"] == pytest.approx(0.9 / 1.1 * 1.5)
    assert moved["heading_angle_p"] == pytest.approx(0.6 * rule.angle_p)


def test_the_rover_design_is_no_worse_than_px4s_shipped_gains():
    case = px4_rover_case(BOAT, 1.5, steering_max=0.5236, steering_rate=math.radians(360.0),
                          rate_max=math.radians(130.0), rate_accel_max=math.radians(800.0),
                          rate_threshold=math.radians(3.0))
    choice = design_by_prediction(px4_rover_family(ROVER_RULES), [case], [BOAT], OBJECTIVE, original=ROVER_SHIPPED)
    original = next(c for c in choice.candidates if c.name == "original")
    assert not original.score.feasible  # PX4's shipped gains overshoot ~20 % on this boat
    assert choice.chosen.name != "original" and choice.chosen.score.feasible
    assert choice.chosen.score.iae_s < original.score.iae_s
    assert set(choice.chosen.gains[0]) == set(ROVER_SHIPPED)


def test_the_uuv_design_is_no_worse_than_px4s_shipped_gains():
    case = px4_uuv_case(AUV, 0.86, full_scale=0.35, torque_max=1.0)
    choice = design_by_prediction(px4_uuv_family(UUV_RULES), [case], [AUV], OBJECTIVE, original=UUV_SHIPPED)
    original = next(c for c in choice.candidates if c.name == "original")
    assert choice.chosen.score.feasible and choice.chosen.score.iae_s <= original.score.iae_s
    for gains in choice.chosen.gains:
        assert 0.0 <= gains["heading_angle_p"] <= 40.0 and 0.0 <= gains["heading_rate_d"] <= 20.0


@dataclass(frozen=True)
class _Accepted:
    speed: float
    model: YawModel
    axis: str = "yaw"
    accepted: bool = True


def test_the_campaign_designs_px4_gains_by_prediction_and_its_schedule_writes_the_chosen_ones():
    assert CONTROLLERS["px4_rover"] == "px4_rover" and CONTROLLERS["px4_uuv"] == "px4_uuv"
    kind = schedule_kind("px4_rover", ROVER_RULES)
    assert optimisable(kind)
    attempts = [_Accepted(u, YawModel(-0.9, 0.49 * u * u, 0.0)) for u in (1.25, 1.75)]
    limits = HeadingLimits.from_vehicle({"turn_rate_max": 130.0, "turn_accel_max": 800.0, "steering_rate_max": 360.0,
                                         "yaw_rate_threshold": 3.0, "steering_max": 0.5236}, full_scale=0.5236,
                                        rudder_rate=None)
    design = choose_heading_design(kind, ROVER_RULES, None, attempts, limits, DesignObjective(max_evaluations=30),
                                   ROVER_SHIPPED)
    assert not design.keeps_original
    rebuilt = schedule_kind("px4_rover", design.cascade)
    for attempt, chosen in zip(attempts, design.choice.chosen.gains):
        assert rebuilt.model_gains(attempt.model, attempt.speed) == pytest.approx(chosen)
    config = with_design(CampaignConfig().resolved_for(px4_rover.PROFILE), design)
    assert config.kinds()[0].name == "px4_rover" and config.cascade == design.cascade


def test_px4s_limits_are_read_from_the_vehicle_by_logical_names_its_profiles_declare():
    for name in ("turn_rate_max", "turn_accel_max", "steering_rate_max", "yaw_rate_threshold", "steering_max"):
        assert name in LIMIT_PARAMETERS and name in px4_rover.PROFILE.params
    assert "torque_max" in LIMIT_PARAMETERS and px4_uuv.PROFILE.params["torque_max"] == "UUV_TORQUE_SAT"
    limits = HeadingLimits.from_vehicle({"turn_rate_max": 30.0, "turn_accel_max": -1.0, "steering_rate_max": 286.0,
                                         "yaw_rate_threshold": 0.5, "steering_max": 0.5}, full_scale=0.5236,
                                        rudder_rate=None)
    assert limits.rate_max == pytest.approx(math.radians(30.0)) and limits.rate_accel_max == math.inf
    assert limits.steering_rate == pytest.approx(math.radians(286.0))
    assert limits.rate_threshold == pytest.approx(math.radians(0.5)) and limits.rudder_max == 0.5
    assert HeadingLimits.from_vehicle({"torque_max": 0.3}, full_scale=0.35, rudder_rate=None).torque_max == 0.3


# ---------------------------------------------------------------------- the command line
@pytest.mark.parametrize("autopilot, speed, names", [
    ("px4-rover", "1.5", {"RO_YAW_P", "RO_YAW_RATE_P", "RO_YAW_RATE_I", "RA_WHEEL_BASE", "RO_YAW_RATE_CORR"}),
    ("px4-uuv", "0.86", {"UUV_YAW_P", "UUV_YAW_D"}),
])
def test_design_for_px4_prints_its_parameters_and_every_candidates_predicted_steps(capsys, monkeypatch, autopilot,
                                                                                   speed, names):
    from companion.cli.commands import design_autopilot

    # a shorter search than the command's (160 evaluations): what is printed, not the optimum, is tested
    monkeypatch.setattr(design_autopilot, "DesignObjective", lambda: DesignObjective(max_evaluations=30))
    argv = ["design", "--autopilot", autopilot, "--a22", "-0.9", "--b2", "1.1", "--speed", speed]
    assert cli_main([*argv, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out["parameters"]) == names and out["controller"] == autopilot.replace("-", "_")
    assert set(out["predicted_steps"]) == set(out["design"]["candidates"]) >= {"rule", "optimised", "original"}
    assert [row["step_deg"] for row in out["predicted_steps"]["original"]] == pytest.approx([20.0, 40.0])
    assert cli_main(argv) == 0
    text = capsys.readouterr().out
    assert all(name in text for name in names) and "time to 5 %" in text and "no step model" not in text


# ---------------------------------------------------------------------------- the UUV's allocation (eq. A.5a)
@pytest.mark.parametrize("forward, demand, made", [
    (0.45, 0.3, 0.3),  # room on both sides: the torque as asked
    (0.65, 0.5, 0.425),  # within the yaw margin: not desaturated, the top thrusters clipped at 1
    (0.65, 1.0, 0.5),  # reduced to 1.3 − 0.65, then clipped: (1 − 0)/2
    (0.45, 1.0, 0.7),  # (1 − (−0.4))/2
    (0.45, -1.0, -0.7),  # the other way alike
    (0.0, 1.0, 1.0),  # at rest: the whole range
])
def test_the_uuv_allocation_leaves_the_yaw_the_thrusters_room_beside_the_surge_thrust(forward, demand, made):
    assert UuvAllocation(forward).torque(demand) == pytest.approx(made, abs=1e-9)


def test_a_uuv_step_at_high_surge_thrust_is_predicted_slower_through_the_allocation():
    """PX4 SITL flew the UUV's verification steps 13–77 % slower than eq. A.5 predicted, most at the
    highest thrust: with the allocation, a saturating step at thrust 0.65 is 40 % or more slower, a
    small one not at all."""
    plant = RudderPlant(-1.04, 0.745, 0.0, 0.35)
    gains = {"heading_angle_p": 40.0, "heading_rate_d": 20.0}
    def iae(step_deg: float, forward: float) -> float:
        times, heading, _ = simulate_step(plant, "px4_uuv", gains, math.radians(step_deg), 25.0, full_scale=0.35,
                                          forward_thrust=forward, dt=0.02)
        return step_metrics(times, heading, 0.0, math.radians(step_deg), smooth=False).iae_s
    assert iae(20.0, 0.65) > 1.4 * iae(20.0, math.nan)
    assert iae(20.0, 0.45) < iae(20.0, 0.65)
    assert iae(0.5, 0.45) == pytest.approx(iae(0.5, math.nan), rel=1e-9)  # small: inside the room


def test_the_campaigns_uuv_limits_carry_the_surge_thrust_of_each_speed():
    limits = HeadingLimits(rudder_max=0.35, full_scale=0.35, forward_thrust=((1.25, 0.65), (0.72, 0.45)))
    assert limits.thrust_at(1.0) == pytest.approx(0.45 + 0.2 * (1.0 - 0.72) / (1.25 - 0.72))
    assert limits.thrust_at(2.0) == 0.65 and math.isnan(HeadingLimits(rudder_max=0.35).thrust_at(1.0))
    with pytest.raises(ValueError, match="forward_thrust"):
        HeadingLimits(rudder_max=0.35, forward_thrust=((1.0, 1.5),))


def test_design_for_the_uuv_takes_its_surge_thrust_from_the_command_line(capsys):
    argv = ["design", "--autopilot", "px4-uuv", "--a22", "-1.04", "--b2", "0.745", "--speed", "1.25",
            "--original", "UUV_TORQUE_SAT=1", "--json"]
    outputs = []
    for extra in ([], ["--forward-thrust", "0.65"]):
        assert cli_main(argv + extra) == 0
        outputs.append(json.loads(capsys.readouterr().out))
    free, allocated = (out["design"]["candidates"]["original"]["iae_s"] for out in outputs)
    assert allocated > 1.3 * free  # the thrusters' room beside the surge thrust (eq. A.5a)
    assert outputs[1]["forward_thrust"] == 0.65
    assert cli_main(["design", "--autopilot", "ardurover", "--a22", "-1", "--b2", "1", "--speed", "1",
                     "--forward-thrust", "0.5"]) == 2
    assert "for PX4's UUV" in capsys.readouterr().err
