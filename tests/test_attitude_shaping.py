"""ArduSub's shaped yaw angle loop (eq. A.2s), against ArduPilot's arithmetic worked by hand."""
from __future__ import annotations

import math

import numpy as np
import pytest

from companion.numerics.attitude_shaping import (YAW_MAX_ERROR, ShapedYawTarget, inv_sqrt_controller,
                                                 sqrt_controller)
from companion.numerics.step_response import RudderPlant, simulate_step, step_metrics


def test_the_sqrt_controller_is_linear_near_zero_and_a_constant_deceleration_beyond():
    p, accel = 2.0, 1.0
    linear = accel / p ** 2  # 0.25 rad
    assert sqrt_controller(0.1, p, accel, 0.0) == pytest.approx(0.2)
    assert sqrt_controller(1.0, p, accel, 0.0) == pytest.approx(math.sqrt(2.0 * accel * (1.0 - linear / 2.0)))
    assert sqrt_controller(-1.0, p, accel, 0.0) == pytest.approx(-math.sqrt(2.0 * accel * (1.0 - linear / 2.0)))
    assert sqrt_controller(0.01, p, accel, 0.1) == pytest.approx(0.02)  # within one dt: p·e < e/dt
    assert sqrt_controller(0.01, 50.0, 0.0, 0.1) == pytest.approx(0.1)  # never past the error in one dt
    for output in (0.1, 0.4, 0.9, 3.0):  # the inverse gives back the error
        error = inv_sqrt_controller(output, p, accel)
        assert sqrt_controller(error, p, accel, 0.0) == pytest.approx(output, rel=1e-9)


def test_without_limits_the_target_follows_the_set_point_with_the_input_time_constant():
    shaper = ShapedYawTarget(input_tc=0.5, angle_p=4.0, rate_p=1.0)
    dt, step = 0.0025, math.radians(20.0)
    for _ in range(int(round(0.5 / dt))):
        shaper.rate_demand(step, shaper.target, dt)  # the vehicle on its target: only the feed-forward acts
    assert shaper.target / step == pytest.approx(1.0 - math.exp(-1.0), abs=0.01)


def test_the_vehicle_on_its_target_is_asked_for_the_target_rate_alone():
    shaper = ShapedYawTarget(input_tc=0.15, angle_p=4.5, rate_p=0.18, accel_max=math.radians(30.0))
    demands = [(shaper.rate_demand(math.radians(40.0), shaper.target, 0.01), shaper.target_rate) for _ in range(50)]
    # the target moves one dt ahead of the heading it was given: the angle P adds only that
    assert all(demand == pytest.approx(rate * (1.0 + 4.5 * 0.01), rel=1e-9) for demand, rate in demands)
    rates = np.array([rate for _, rate in demands])
    assert np.all(np.diff(rates) <= math.radians(30.0) * 0.01 + 1e-12)  # the acceleration limit


def test_a_heading_error_beyond_what_saturates_the_rate_loop_pulls_the_target_back():
    shaper = ShapedYawTarget(input_tc=0.15, angle_p=1.0, rate_p=2.0, accel_max=math.radians(200.0))
    error_max = abs(inv_sqrt_controller(1.0 / 2.0, 1.0, min(max(math.radians(100.0), math.radians(10.0)),
                                                                 math.radians(120.0))))
    assert error_max < YAW_MAX_ERROR
    shaper.target = math.radians(90.0)  # far ahead of the vehicle at 0
    shaper.rate_demand(math.radians(90.0), 0.0, 0.01)
    assert shaper.target == pytest.approx(error_max)


def test_the_target_rate_is_fed_forward_so_a_quick_shaping_turns_sooner_and_a_slow_one_later():
    """The rate loop is asked for the target's own rate plus the angle P on what is left: with
    1/ATC_INPUT_TC above ANG_P the turn starts sooner than the angle P alone would ask, below it later."""
    plant = RudderPlant(-0.95, 0.49, 0.0, 0.35, math.inf)
    gains = {"heading_angle_p": 1.0, "heading_rate_p": 0.5, "heading_rate_i": 0.05}  # the rudder not saturated
    step, early = math.radians(40.0), int(round(0.3 / 0.01))

    def heading(input_tc: float) -> np.ndarray:
        return simulate_step(plant, "cascade", gains, step, 25.0, full_scale=0.35, dt=0.01, input_tc=input_tc)[1]

    plain = heading(0.0)
    assert heading(0.5)[early] > plain[early]  # 1/tc = 2 > ANG_P 1
    assert heading(2.0)[early] < plain[early]  # 1/tc = 0.5 < ANG_P 1
    assert step_metrics(np.arange(plain.size) * 0.01, heading(0.5), 0.0, step, smooth=False).iae_s < \
        step_metrics(np.arange(plain.size) * 0.01, plain, 0.0, step, smooth=False).iae_s
    with pytest.raises(ValueError, match="rate_max"):
        ShapedYawTarget(input_tc=0.15, angle_p=1.0, rate_p=1.0, rate_max=0.0)
