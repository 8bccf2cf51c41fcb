"""Gain design (SPEC C5, eq. 3.55–3.57, Table 3.4), turning performance (Table 3.3), schedule (Fig. 3.8)."""
from __future__ import annotations

import json
import math

import control
import numpy as np
import pytest

from companion.cli.main import main as cli_main
from companion.numerics.gains import DESIGN_DAMPING, GainBounds, design_heading_gains
from companion.numerics.identification import YawEstimate, YawModel
from companion.numerics.schedule import fit_yaw_schedule
from companion.numerics.turning import turning_performance

#: Table 3.4: (a22, b2) → Kp
TABLE_3_4 = [((-1.28, 0.65), 1.26), ((-1.51, 1.04), 1.09), ((-1.70, 1.41), 1.02),
             ((-1.54, 1.30), 0.91), ((-1.69, 1.85), 0.77), ((-1.48, 2.02), 0.54)]
TABLE_3_1_SPEEDS = [1.07, 1.36, 1.63, 1.92, 2.19]
TABLE_3_1 = [(-0.95, 0.60, 0.012), (-1.12, 0.87, 0.012), (-1.07, 1.08, 0.011), (-1.14, 1.37, 0.004), (-1.21, 1.77, 0.003)]


@pytest.mark.parametrize("pair, kp", TABLE_3_4)
def test_table_3_4_proportional_gains(pair, kp):
    gains = design_heading_gains(YawModel(pair[0], pair[1], 0.02), speed=1.5)
    assert gains.kp == pytest.approx(kp, abs=0.01)
    assert gains.trim == 0.02 and gains.speed == 1.5 and gains.clamped == ()


@pytest.mark.parametrize("pair, kp", TABLE_3_4)
def test_pi_keeps_the_damping_and_overshoot_below_6_percent(pair, kp):
    """python-control: heading loop b2/(s² − a22 s) with PI on the error; dominant pair ζ within
    0.005 of 0.7071, step overshoot ≤ 6 %, zero steady-state error, third pole real and slow."""
    a22, b2 = pair
    gains = design_heading_gains(YawModel(a22, b2, 0.0))
    assert gains.ki > 0.0
    plant = control.tf([b2], [1.0, -a22, 0.0])
    controller = control.tf([gains.kp, gains.ki], [1.0, 0.0])
    closed = control.feedback(controller * plant, 1)
    wn, zeta, poles = control.damp(closed, doprint=False)
    complex_idx = np.flatnonzero(np.abs(poles.imag) > 1e-9)
    assert complex_idx.size == 2
    assert np.all(np.abs(zeta[complex_idx] - DESIGN_DAMPING) < 0.005)
    real_pole = poles[np.abs(poles.imag) <= 1e-9]
    assert real_pole.size == 1 and -abs(a22) / 20 < real_pole[0].real < 0.0
    info = control.step_info(closed, T=np.linspace(0, 3000, 60001))
    assert info["Overshoot"] <= 6.0
    assert control.dcgain(closed) == pytest.approx(1.0)


def test_p_only_loop_overshoot_is_the_second_order_value():
    """Eq. 3.55 with eq. 3.57: ζ = 0.7071 ⇒ 4.3 % overshoot (the thesis' "approximately 5 %")."""
    a22, b2 = -1.51, 1.04
    kp = design_heading_gains(YawModel(a22, b2, 0.0)).kp
    closed = control.tf([kp * b2], [1.0, -a22, kp * b2])
    assert control.step_info(closed)["Overshoot"] == pytest.approx(4.32, abs=0.05)


def test_bounds_clamp_and_invalid_models_raise():
    tiny_authority = design_heading_gains(YawModel(-1.5, 0.01, 0.4))
    assert tiny_authority.kp == GainBounds().kp_max
    assert tiny_authority.trim == GainBounds().trim_limit
    assert set(tiny_authority.clamped) >= {"kp", "trim"}
    tight = design_heading_gains(YawModel(-1.28, 0.65, -0.3), GainBounds(kp_max=1.0, trim_limit=0.05))
    assert tight.kp == 1.0 and tight.trim == -0.05
    for bad in (YawEstimate(0.5, 1.0, 0.0), YawEstimate(-1.0, -1.0, 0.0), YawEstimate(math.nan, 1.0, 0.0)):
        with pytest.raises(ValueError):
            design_heading_gains(bad)  # an estimate that is no model is refused
        with pytest.raises(ValueError):
            YawModel(bad.a22, bad.b2, bad.delta0)  # and no model holds its numbers


def test_table_3_3_turning_performance():
    perf = turning_performance(YawModel(-1.62, 1.25, 0.036), speed=1.4, delta_max=0.26)
    assert perf.yaw_rate_max_deg_s == pytest.approx(9.90, rel=0.03)
    assert perf.u_turn_time_s == pytest.approx(20.65, rel=0.03)
    assert perf.turning_radius_m == pytest.approx(9.20, rel=0.03)
    assert perf.settle_time_s == pytest.approx(4 / 1.62)
    assert perf.u_turn_time_s == pytest.approx(perf.settle_time_s + math.pi / perf.yaw_rate_max)


def test_eq_3_52_radius_curve():
    """Eq. 3.52 (a22 −1.1, b2 = 0.31V² + 0.26, δ0 0): R(0.25 m/s) ≈ 4 m ("at speed 0.25 m/s, the
    turning radius is 4 m"); the local minimum of the high-speed region is ≈ 7.6 m near 3 m/s
    (SPEC §3: not the printed 5.9 m at 4.2 m/s)."""
    def radius(v):
        return turning_performance(YawModel(-1.1, 0.31 * v * v + 0.26, 0.0), v).turning_radius_m
    assert radius(0.25) == pytest.approx(4.0, abs=0.2)
    speeds = np.linspace(2.0, 5.0, 301)
    radii = [radius(v) for v in speeds]
    assert min(radii) == pytest.approx(7.6, abs=0.1)
    assert speeds[int(np.argmin(radii))] == pytest.approx(3.0, abs=0.15)
    with pytest.raises(ValueError):
        turning_performance(YawModel(-1.1, 1.0, 0.3), 1.0, delta_max=0.26)


def test_schedule_fit_of_table_3_1():
    models = [YawModel(*row) for row in TABLE_3_1]
    schedule = fit_yaw_schedule(TABLE_3_1_SPEEDS, models)
    assert schedule.a22 == pytest.approx(-1.1, abs=0.01)
    assert schedule.b2_slope == pytest.approx(0.31, abs=0.01)  # Fig. 3.8: 0.31 u² + 0.26
    assert schedule.b2_intercept == pytest.approx(0.26, abs=0.01)
    assert schedule.b2_residual_rms < 0.05
    assert schedule.speed_range == (1.07, 2.19)
    # inside the range: the law; gains follow it
    model = schedule.model_at(1.5)
    assert model.b2 == pytest.approx(0.3109 * 2.25 + 0.2592, abs=1e-3)
    gains = schedule.gains_at(1.5)
    assert gains.kp == pytest.approx(model.a22**2 / (2 * model.b2)) and gains.speed == 1.5
    # clamped extrapolation: beyond 1.2 × u_max (and below 0.8 × u_min) the laws are held
    assert schedule.model_at(10.0).b2 == pytest.approx(schedule.model_at(2.19 * 1.2).b2)
    assert schedule.model_at(0.0).b2 == pytest.approx(schedule.model_at(1.07 * 0.8).b2)
    assert schedule.gains_at(3.0).kp < schedule.gains_at(1.0).kp  # more authority, less gain


def test_schedule_a22_trend_kept_only_when_significant():
    speeds = [1.1, 1.4, 1.65, 1.9, 2.2]
    # a22 growing with speed (the simulator's STARFISH law): the trend is kept and recovered
    trend = [YawModel(-0.78 - 0.19 * u + noise, 0.31 * u * u + 0.26, 0.01)
             for u, noise in zip(speeds, (0.004, -0.003, 0.002, -0.004, 0.003))]
    schedule = fit_yaw_schedule(speeds, trend)
    assert schedule.a22_per_speed == pytest.approx(-0.19, abs=0.02)
    assert schedule.model_at(1.1).a22 == pytest.approx(-0.78 - 0.19 * 1.1, abs=0.01)
    assert schedule.model_at(2.2).a22 == pytest.approx(-0.78 - 0.19 * 2.2, abs=0.01)
    # scatter without a trend: a22 stays the constant mean (the thesis' law)
    flat = [YawModel(-1.1 + noise, 0.31 * u * u + 0.26, 0.01)
            for u, noise in zip(speeds, (0.05, -0.06, 0.04, 0.05, -0.05))]
    schedule = fit_yaw_schedule(speeds, flat)
    assert schedule.a22_per_speed == 0.0
    assert schedule.model_at(1.1).a22 == schedule.model_at(2.2).a22 == pytest.approx(schedule.a22)
    # two speeds cannot show a significant trend
    assert fit_yaw_schedule(speeds[:2], trend[:2]).a22_per_speed == 0.0


def test_schedule_weights_and_errors():
    models = [YawModel(-1.0, 1.0, 0.0), YawModel(-2.0, 2.0, 0.01)]
    weighted = fit_yaw_schedule([1.0, 2.0], models, weights=[3.0, 1.0])
    assert weighted.a22 == pytest.approx(-1.25)
    # a negative fitted intercept cannot make b2 ≤ 0 at low speed
    steep = fit_yaw_schedule([1.0, 2.0], [YawModel(-1.0, 0.2, 0.0), YawModel(-1.0, 2.0, 0.0)])
    assert steep.b2_intercept < 0 and steep.model_at(0.1).b2 >= 0.1
    with pytest.raises(ValueError):
        fit_yaw_schedule([1.0, 1.0], models)
    with pytest.raises(ValueError):
        fit_yaw_schedule([1.0, 2.0], [YawEstimate(0.1, 1.0, 0.0), YawModel(-1.0, 1.0, 0.0)])


def test_design_command_json_and_errors(capsys):
    code = cli_main(["design", "--a22", "-1.62", "--b2", "1.25", "--delta0", "0.036", "--speed", "1.4", "--json"])
    assert code == 0
    result = json.loads(capsys.readouterr().out)
    assert result["kp"] == pytest.approx(1.62**2 / 2.5)
    assert result["trim"] == pytest.approx(0.036)
    assert result["yaw_rate_max_deg_s"] == pytest.approx(9.90, abs=0.01)
    assert result["u_turn_time_s"] == pytest.approx(20.65, abs=0.01)
    assert result["turning_radius_m"] == pytest.approx(9.20, abs=0.01)
    assert cli_main(["design", "--a22", "-1.62", "--b2", "1.25"]) == 0
    assert "turning_radius_m" in capsys.readouterr().out
    for bad in (["--a22", "0.5", "--b2", "1"], ["--a22", "-1", "--b2", "-1"], ["--a22", "nan", "--b2", "1"],
                ["--a22", "-1", "--b2", "1", "--delta0", "0.3"]):
        assert cli_main(["design", *bad]) == 2
        assert "error" in capsys.readouterr().err


def _cascade_heading_step_overshoot(a22: float, b: float, gains) -> float:
    """Overshoot (%) of a heading step through the cascade without feed-forward: ψ̈ = a22·ψ̇ + b·s,
    s = P·(r_d − r) + I·∫(r_d − r), r_d = ANG_P·(ψd − ψ) (python-control, linear)."""
    plant = control.tf([b], [1.0, -a22])  # rate per output
    rate_pi = control.tf([gains.rate_p, gains.rate_i], [1.0, 0.0])
    rate_loop = control.feedback(rate_pi * plant, 1)
    heading = control.feedback(gains.angle_p * rate_loop * control.tf([1.0], [1.0, 0.0]), 1)
    t = np.linspace(0.0, 60.0, 6001)
    _, y = control.step_response(heading, t)
    return 100.0 * (float(np.max(y)) - 1.0)


def test_without_feed_forward_a_fast_plant_still_gets_a_proportional_rate_gain():
    """ArduSub (FF range (0, 0)) on its own SITL sub: a22 ≈ −15, b2 ≈ 200 per rad of equivalent rudder.
    The FF rule's P = (ωr + a22)/b is 0 there; without FF the rate loop then had only I and the heading
    steps overshot 78–124 % on the firmware. P now carries two thirds of the steady turn."""
    from companion.numerics.cascade_gains import CascadeRules, design_cascade_gains

    ardusub = CascadeRules(full_scale=0.5236, angle_p_range=(0.0, 6.0), rate_p_range=(0.0, 2.0),
                           rate_i_range=(0.0, 0.05), rate_ff_range=(0.0, 0.0))
    model = YawModel(a22=-15.0, b2=200.0, delta0=0.0)
    gains = design_cascade_gains(model, ardusub)
    b = 200.0 * 0.5236
    assert gains.rate_ff == 0.0 and gains.rate_p == pytest.approx(2.0 * 15.0 / b)
    assert b * gains.rate_p / (b * gains.rate_p + 15.0) == pytest.approx(2.0 / 3.0)
    assert _cascade_heading_step_overshoot(-15.0, b, gains) < 10.0
    # with a feed-forward the FF carries the turn and the plant is fast enough: P stays 0
    assert design_cascade_gains(model, CascadeRules()).rate_p == 0.0


@pytest.mark.parametrize("zeta", [0.75, 0.8])
def test_a_design_damping_places_the_pair_at_that_damping_and_lowers_the_overshoot(zeta):
    """GainBounds.damping generalises eq. 3.57: Kp = a22²/(4ζ²b2) puts the dominant pair at ζ
    (within 0.005 with the N = 100 integrator) and the step overshoots less than at 0.7071."""
    a22, b2 = TABLE_3_4[1][0]
    plant = control.tf([b2], [1.0, -a22, 0.0])

    def loop(bounds: GainBounds):
        gains = design_heading_gains(YawModel(a22, b2, 0.0), bounds)
        return gains, control.feedback(control.tf([gains.kp, gains.ki], [1.0, 0.0]) * plant, 1)

    gains, closed = loop(GainBounds(damping=zeta))
    assert gains.kp == pytest.approx(a22 * a22 / (4 * zeta * zeta * b2))
    wn, damping, poles = control.damp(closed, doprint=False)
    pair = np.flatnonzero(np.abs(poles.imag) > 1e-9)
    assert np.all(np.abs(damping[pair] - zeta) < 0.005)
    overshoot = control.step_info(closed, T=np.linspace(0, 3000, 60001))["Overshoot"]
    _, reference = loop(GainBounds())
    assert overshoot < control.step_info(reference, T=np.linspace(0, 3000, 60001))["Overshoot"] - 1.0
    with pytest.raises(ValueError):
        design_heading_gains(YawModel(a22, b2, 0.0), GainBounds(damping=0.0))
