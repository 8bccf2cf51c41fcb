"""The steering authority's speed law chosen with the models (eq. S.3): u² + c for a rudder, u + c
for differential thrust; the actuation's law stands unless ≥ 4 speeds overrule it by a 2× residual;
the schedule, its gains and its record carry the choice and the evidence."""
from __future__ import annotations

import math

import numpy as np
import pytest

from behaviors.schedules import schedule_kind
from companion.numerics.identification import YawModel
from companion.numerics.schedule import schedule_from_models
from companion.numerics.speed_law import choose_speed_law
from companion.records.serialise import from_json, to_json

SPEEDS = (1.2, 1.45, 1.7, 1.95, 2.2)


def _noisy(law, seed: int, sigma: float = 0.015, speeds=SPEEDS):
    rng = np.random.default_rng(seed)
    return [law(u) * (1.0 + sigma * rng.standard_normal()) for u in speeds]


def rudder_law(u):
    return 0.31 * u * u + 0.26  # the thesis' Fig. 3.8


def skid_law(u):
    return 0.62 * u + 0.05


def test_precise_models_overrule_a_wrong_actuation_law():
    for seed in range(10):
        assert choose_speed_law(SPEEDS, _noisy(rudder_law, seed, 0.003), prior="u").law == "u2"
        assert choose_speed_law(SPEEDS, _noisy(skid_law, seed, 0.003), prior="u2").law == "u"


def test_noisy_models_rarely_overrule_the_actuation_and_three_speeds_never_do():
    flips = 0
    for seed in range(40):
        flips += choose_speed_law(SPEEDS, _noisy(rudder_law, seed), prior="u2").law != "u2"
        flips += choose_speed_law(SPEEDS, _noisy(skid_law, seed), prior="u").law != "u"
        three = choose_speed_law(SPEEDS[::2], _noisy(skid_law, seed, 0.003, SPEEDS[::2]), prior="u2")
        assert three.law == "u2"  # 3 speeds cannot overrule, however clear
    assert flips <= 2  # of 80 (simulated: 0.1 % and 1.6 %)


def test_the_reason_says_whether_the_models_agree():
    agree = choose_speed_law(SPEEDS, _noisy(skid_law, 1, 0.003), prior="u")
    assert agree.law == "u" and "the models agree" in agree.reason
    lean = choose_speed_law(SPEEDS[::2], _noisy(skid_law, 1, 0.003, SPEEDS[::2]), prior="u2")
    assert "lean to u" in lean.reason
    assert "cannot tell" in choose_speed_law([1.2, 2.0], [0.9, 1.5], prior="u").reason
    assert "span only" in choose_speed_law([1.50, 1.55, 1.60], [1.00, 1.05, 1.09], prior="u").reason


def test_the_thesis_table_is_a_rudders_law_though_its_power_law_exponent_is_nearer_one():
    speeds, b2 = [1.07, 1.36, 1.63, 1.92, 2.19], [0.60, 0.87, 1.08, 1.37, 1.77]
    choice = choose_speed_law(speeds, b2, prior="u2")
    assert choice.law == "u2" and "the models agree" in choice.reason
    assert choice.exponent == pytest.approx(1.47, abs=0.02)  # the intercept bends the power law
    assert choice.residual_rms["u"] > 1.9 * choice.residual_rms["u2"]
    wrong = choose_speed_law(speeds, b2, prior="u")  # 1.96x: just short of overruling a skid prior
    assert wrong.law == "u" and "lean to u2" in wrong.reason


def test_the_schedule_gains_and_stored_record_follow_the_chosen_law():
    models = [YawModel(a22=-1.0, b2=0.62 * u + 0.05, delta0=0.0) for u in SPEEDS]
    schedule = schedule_from_models(SPEEDS, models, prior_law="u2")
    assert schedule.b2_law == "u" and "·u +" in schedule.describe()
    for speed in (1.3, 2.0, 2.6):  # interpolation and (clamped) extrapolation follow u, not u²
        clamped = schedule.clamp_speed(speed)
        assert schedule.b2_at(speed) == pytest.approx(0.62 * clamped + 0.05, rel=1e-6)
    back = from_json(to_json(schedule))
    assert back.b2_law == "u" and back.b2_law_reason == schedule.b2_law_reason
    assert back.b2_at(1.8) == pytest.approx(schedule.b2_at(1.8))
    old = to_json(schedule)
    for key in ("b2_law", "b2_law_reason", "b2_law_rms", "b2_exponent", "b2_exponent_sigma"):
        old.pop(key)
    assert from_json(old).b2_law == "u2" and math.isfinite(from_json(old).b2_at(1.5))  # stored before: u²


def test_a_skid_vehicles_schedule_kinds_carry_its_law():
    kind = schedule_kind("cascade", None, "u")
    models = [YawModel(a22=-1.0, b2=0.62 * u + 0.05, delta0=0.0) for u in SPEEDS[:2]]
    assert kind.fit(SPEEDS[:2], models).b2_law == "u"  # two speeds: the actuation's law
    assert schedule_kind("heading").fit(SPEEDS[:2], models).b2_law == "u2"
    assert schedule_kind("pitch", None, "u").name == "pitch"  # not a yaw kind: the law is not its business


def test_a_schedule_states_its_invariants_where_it_is_made():
    """A schedule is fitted on stable models over the speeds flown: an unstable mean, an empty or
    inverted speed range or an unknown law is refused at construction, not at the first gain."""
    from companion.numerics.schedule import YawSchedule

    good = dict(a22=-0.9, b2_slope=0.3, b2_intercept=0.05, delta0=0.01, speed_range=(1.0, 2.0))
    assert YawSchedule(**good).speed_range == (1.0, 2.0)
    for bad, match in ((dict(a22=0.1), "negative"), (dict(a22=float("nan")), "negative"),
                       (dict(speed_range=(2.0, 1.0)), "speed_range"), (dict(speed_range=(0.0, 1.0)), "speed_range"),
                       (dict(b2_law="u3"), "b2_law"), (dict(b2_slope=float("inf")), "finite")):
        with pytest.raises(ValueError, match=match):
            YawSchedule(**{**good, **bad})
