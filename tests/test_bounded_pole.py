"""The output-error fit with the pole bounded by the sampling (eq. 3.38p): it recovers a lag the
record resolves, and says so when the yaw rate follows the rudder within one sample (where the
online regression's a22 is undetermined), keeping the static gain."""
from __future__ import annotations

import math

import numpy as np
import pytest

from companion.numerics.bounded_pole import (LAG_UNRESOLVED, ONLINE, ONLINE_UNSTABLE, BoundedPoleFit, YawModelChoice,
                                              choose_yaw_model, fit_yaw_bounded_pole)
from companion.numerics.identification import YawEstimate, YawIdentifier, YawModel
from tests.test_numerics_identification import HEADING_NOISE, doublet, identify, sample_times, yaw_record


def test_a_lag_the_record_resolves_is_recovered_inside_the_bound():
    true = YawModel(-1.12, 0.87, 0.012)
    times, heading, rudder = yaw_record(true, seed=3, noise=HEADING_NOISE)
    fit = fit_yaw_bounded_pole(times, heading, rudder)
    assert not fit.at_bound
    assert fit.model.a22 == pytest.approx(true.a22, rel=0.05)
    assert fit.model.b2 == pytest.approx(true.b2, rel=0.05)
    assert fit.r2 > 0.99


def _instant_turner(gain: float, delta0: float, seed: int):
    """A record of a vehicle whose yaw rate is K·(δ − δ0) at once (no lag: ArduPilot SITL's motorboat),
    sampled at about 20 Hz, the heading integrated exactly and measured with noise."""
    times = sample_times(16.5, seed)
    rudder = doublet(times, 0.1) + delta0
    rate = gain * (rudder - delta0)
    heading = 0.3 + np.concatenate([[0.0], np.cumsum(rate[:-1] * np.diff(times))])
    return times, heading + np.random.default_rng(seed).normal(0.0, HEADING_NOISE, times.size), rudder


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_rate_that_follows_the_rudder_at_once_sits_on_the_bound_with_its_static_gain(seed):
    gain, delta0 = 8.9, 0.004
    times, heading, rudder = _instant_turner(gain, delta0, seed)
    online = identify(YawIdentifier(), times, heading, rudder)
    fit = fit_yaw_bounded_pole(times, heading, rudder)
    assert fit.at_bound and fit.model.a22 == pytest.approx(-fit.fast_bound, rel=0.02)
    assert fit.fast_bound == pytest.approx(1.0 / np.median(np.diff(times)))
    assert fit.static_gain == pytest.approx(gain, rel=0.02)
    assert fit.model.delta0 == pytest.approx(delta0, abs=0.002)
    assert fit.r2 > 0.99
    # the online regression's a22 is not the record's (only b2/a22 is determined by it)
    assert abs(online.a22 - fit.model.a22) > 0.1 * fit.fast_bound or online.a22 >= 0.0


def test_too_short_or_disordered_records_are_refused_with_the_reason():
    with pytest.raises(ValueError, match="at least 8"):
        fit_yaw_bounded_pole([0.0, 0.1, 0.2], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    times = np.linspace(0.0, 1.0, 20)
    with pytest.raises(ValueError, match="increasing"):
        fit_yaw_bounded_pole(times[::-1], np.zeros(20), np.zeros(20))
    nan_heavy = np.full(20, math.nan)
    with pytest.raises(ValueError, match="at least 8"):
        fit_yaw_bounded_pole(times, nan_heavy, np.zeros(20))


def _fit(a22: float, b2: float, at_bound: bool) -> BoundedPoleFit:
    return BoundedPoleFit(model=YawEstimate(a22, b2, 0.0), r2=0.99, fast_bound=25.0, at_bound=at_bound, initial_rate=0.0)


def test_the_online_estimate_stays_unless_the_fit_says_the_lag_is_unresolved_or_it_is_unstable():
    online = YawEstimate(-1.1, 0.9, 0.01)
    assert choose_yaw_model(online, None).model is online
    assert choose_yaw_model(online, _fit(-1.0, 0.8, False)).source == ONLINE
    unresolved = choose_yaw_model(YawEstimate(-6.0, 50.0, 0.0), _fit(-24.9, 220.0, True))
    assert unresolved.source == LAG_UNRESOLVED and unresolved.model.a22 == -24.9 and "40 ms" in unresolved.note
    inverted = choose_yaw_model(YawEstimate(13.9, -93.6, 0.0), _fit(-3.0, 20.0, False))
    assert inverted.source == ONLINE_UNSTABLE and inverted.model.a22 == -3.0
    assert isinstance(unresolved.model, YawModel) and isinstance(inverted.model, YawModel)  # the fit kept as a model
    # a fit that is itself no stable model never replaces anything
    assert choose_yaw_model(YawEstimate(13.9, -93.6, 0.0), _fit(-3.0, -20.0, True)).source == ONLINE
    with pytest.raises(ValueError, match="source"):
        YawModelChoice(online, "guessed")
