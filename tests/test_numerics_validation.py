"""Validation R² (eq. 3.35–3.37) and the offline Nelder–Mead baseline (eq. 3.38, Table 3.2)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.signal import cont2discrete

from companion.numerics.identification import PitchModel, YawModel
from companion.numerics.offline import fit_yaw_offline, simulate_yaw_rk4
from companion.numerics.validation import r_squared, simulate_yaw, validate_pitch, validate_yaw, interval_factors
from tests.test_numerics_identification import HEADING_NOISE, PITCH_TRUE, pitch_record, yaw_record

TRUE = YawModel(-1.12, 0.87, 0.012)


def test_r_squared_definition():
    measured = np.array([0.0, 1.0, 2.0, 3.0])
    assert r_squared(measured, measured) == 1.0
    assert r_squared(np.full(4, measured.mean()), measured) == pytest.approx(0.0)
    # 1 − mean(err²)/population variance
    assert r_squared(measured + 0.5, measured) == pytest.approx(1 - 0.25 / 1.25)
    assert math.isnan(r_squared(np.ones(3), np.ones(3)))


def test_simulation_matches_the_analytic_step_response():
    """ψ for a rudder step from rest: b2·Δδ/a22²·(e^{a22 t} − 1 − a22 t) (exact ZOH, varying dt)."""
    times = np.round(np.cumsum(np.r_[0.0, np.random.default_rng(0).uniform(0.04, 0.06, 300)]), 3)
    rudder = np.full(times.size, 0.1 + TRUE.delta0)
    heading = simulate_yaw(TRUE, times, rudder, 0.0)
    a, b = TRUE.a22, TRUE.b2 * 0.1
    expected = b / a**2 * (np.exp(a * times) - 1 - a * times)
    assert heading == pytest.approx(expected, abs=1e-12)
    rk4 = simulate_yaw_rk4(TRUE.a22, TRUE.b2, TRUE.c0, times, rudder, 0.0)
    assert rk4 == pytest.approx(expected, abs=1e-7)


def test_validation_r2_true_model_near_one_wrong_model_low():
    times, heading, rudder = yaw_record(TRUE, seed=21, amplitude=0.15)
    assert validate_yaw(TRUE, times, heading, rudder) == pytest.approx(1.0, abs=1e-12)
    times, noisy, rudder = yaw_record(TRUE, seed=21, amplitude=0.15, noise=HEADING_NOISE)
    assert validate_yaw(TRUE, times, noisy, rudder) > 0.95
    wrong = YawModel(a22=-0.5, b2=1.7, delta0=0.0)
    assert validate_yaw(wrong, times, noisy, rudder) < 0.0
    slightly_wrong = YawModel(a22=-1.12 * 1.3, b2=0.87 * 0.8, delta0=0.012)
    assert 0.0 < validate_yaw(slightly_wrong, times, noisy, rudder) < 0.95


def test_validation_handles_wrap_and_nan():
    times, heading, rudder = yaw_record(TRUE, seed=22, amplitude=0.15, heading0=math.pi - 0.02)
    wrapped = (heading + math.pi) % (2 * math.pi) - math.pi
    wrapped[40] = math.nan
    assert validate_yaw(TRUE, times, wrapped, rudder) == pytest.approx(1.0, abs=1e-9)


def test_pitch_validation():
    times, pitch, elevator = pitch_record(PITCH_TRUE, seed=23)
    assert validate_pitch(PITCH_TRUE, times, pitch, elevator) == pytest.approx(1.0, abs=1e-12)
    wrong = PitchModel(c22=1.0, c23=0.5, d2=-3.0, cb=0.0)
    assert validate_pitch(wrong, times, pitch, elevator) < 0.5


def test_offline_nelder_mead_recovers_the_model():
    times, heading, rudder = yaw_record(TRUE, seed=24)
    fit = fit_yaw_offline(times, heading, rudder)
    assert fit.success
    # stopping tolerance on the parameters is the thesis' 0.01
    assert fit.model.a22 == pytest.approx(TRUE.a22, abs=0.03)
    assert fit.model.b2 == pytest.approx(TRUE.b2, abs=0.03)
    assert fit.model.delta0 == pytest.approx(TRUE.delta0, abs=2e-3)
    assert fit.r2 > 0.999 and fit.cost < 2e-3
    assert 20 <= fit.iterations <= 400  # reported; Table 3.2: 67–137 on field data
    assert fit.function_evaluations >= fit.iterations


def test_offline_with_noise_validates_on_fresh_data():
    times, heading, rudder = yaw_record(TRUE, seed=25, noise=HEADING_NOISE)
    fit = fit_yaw_offline(times, heading, rudder)
    v_times, v_heading, v_rudder = yaw_record(TRUE, seed=26, noise=HEADING_NOISE, amplitude=0.15)
    assert validate_yaw(fit.model, v_times, v_heading, v_rudder) > 0.95
    assert fit.model.a22 == pytest.approx(TRUE.a22, rel=0.1)


@pytest.mark.parametrize("alpha", [-2.5, -0.4, -1e-9, 0.0, 3e-8, 0.3])
@pytest.mark.parametrize("dt", [0.02, 0.1, 1.3])
def test_a_yaw_interval_written_out_equals_the_matrix_exponential(alpha, dt):
    """The closed form of one held interval (eq. L.3) against scipy's zero-order-hold discretisation."""
    x0, beta = np.array([0.7, -0.2]), 0.35
    a = np.array([[0.0, 1.0], [0.0, alpha]])
    ad, bd, *_ = cont2discrete((a, np.array([[0.0], [beta]]), np.eye(2), np.zeros((2, 1))), dt, method="zoh")
    expected = ad @ x0 + bd[:, 0]
    phi1, phi2 = interval_factors(alpha, dt)
    written_out = [x0[0] + x0[1] * phi1 + beta * phi2, (1.0 + alpha * phi1) * x0[1] + beta * phi1]
    np.testing.assert_allclose(written_out, expected, rtol=1e-11, atol=1e-12)
