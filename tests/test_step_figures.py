"""A step's figures of merit are records (``companion.numerics.step_figures``): refused where they are
made when they break their invariant, read by attribute, and their ``to_dict`` is the JSON the store
and the commands have always written, key for key and in order (docs/store.md, "Step figures")."""
from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from companion.numerics.skid_step import SkidDrive, SkidMixer
from companion.numerics.step_figures import STEP_ENDINGS, FlownStepFigures, PredictedStep, StepFigures
from companion.numerics.step_response import RudderPlant, predict_step, step_metrics
from companion.procedures.verified_design import PredictedAtSpeed
from companion.records.serialise import json_ready

FIGURE_KEYS = ["overshoot_pct", "rise_time_s", "settling_time_s", "iae_s", "oscillations"]
FIGURES = StepFigures(overshoot_pct=4.0, rise_time_s=2.5, settling_time_s=math.nan, iae_s=1.5, oscillations=1)
PLANT = RudderPlant(a22=-0.95, b2=0.49, delta0=0.0, rudder_max=0.35)
CASCADE = {"heading_angle_p": 1.5, "heading_rate_p": 0.8, "heading_rate_i": 0.2, "heading_rate_ff": 1.5}


def _strict(out: dict) -> dict:
    """``out`` is strict JSON, unchanged by the store's serialiser."""
    json.dumps(out, allow_nan=False)
    assert json_ready(out) == out
    return out


@pytest.mark.parametrize("field, value, words", [
    ("overshoot_pct", -1.0, "overshoot_pct must be a number ≥ 0 or NaN"),
    ("rise_time_s", -0.1, "rise_time_s must be a number ≥ 0 or NaN"),
    ("settling_time_s", None, "settling_time_s must be a number ≥ 0 or NaN"),
    ("iae_s", -2.0, "iae_s must be a number ≥ 0 or NaN"),
    ("iae_s", True, "iae_s must be a number ≥ 0 or NaN"),
    ("oscillations", -1, "oscillations"),
    ("oscillations", 1.0, "oscillations"),
])
def test_step_figures_refuse_what_no_step_measures(field, value, words):
    with pytest.raises(ValueError, match=words):
        dataclasses.replace(FIGURES, **{field: value})


def test_step_figures_hold_nan_where_nothing_was_measured_and_write_it_as_null():
    out = _strict(StepFigures.unmeasured().to_dict())
    assert list(out) == FIGURE_KEYS
    assert out == {"overshoot_pct": None, "rise_time_s": None, "settling_time_s": None, "iae_s": None,
                   "oscillations": 0}
    assert _strict(FIGURES.to_dict())["settling_time_s"] is None  # never settled
    assert StepFigures(0.0, math.inf, 0.0, 0.0, 0).to_dict()["rise_time_s"] is None


def test_a_step_too_small_to_score_is_unmeasured():
    assert step_metrics([0.0, 1.0], [0.0, 0.0], 0.0, 0.0) == StepFigures.unmeasured()
    figures = step_metrics(np.arange(0.0, 20.0, 0.01), np.minimum(np.arange(0.0, 20.0, 0.01) * 0.1, 1.0), 0.0, 1.0,
                           smooth=False)
    assert isinstance(figures.oscillations, int) and figures.overshoot_pct == 0.0 and figures.rise_time_s > 0.0


def test_a_predicted_step_refuses_a_negative_saturation_time_and_a_saturation_that_is_not_a_bool():
    step = PredictedStep(FIGURES, rudder_peak=0.3, saturated=False, saturated_s=0.0)
    with pytest.raises(ValueError, match="saturated_s must be a finite time ≥ 0"):
        dataclasses.replace(step, saturated_s=-0.5)
    with pytest.raises(ValueError, match="saturated must be a bool"):
        dataclasses.replace(step, saturated=np.bool_(True))
    with pytest.raises(ValueError, match="rudder_peak must be a number ≥ 0 or NaN"):
        dataclasses.replace(step, rudder_peak=-0.1)
    with pytest.raises(ValueError, match="figures must be StepFigures"):
        dataclasses.replace(step, figures=FIGURES.to_dict())


def test_a_predicted_steps_json_is_its_figures_then_the_rudder_with_a_skid_boats_speed_dip_before_it():
    rudder = predict_step(PLANT, "cascade", CASCADE, math.radians(40.0), 10.0, full_scale=0.35)
    assert rudder.speed_dip_pct is None and isinstance(rudder.saturated, bool)
    assert list(_strict(rudder.to_dict())) == FIGURE_KEYS + ["rudder_peak", "saturated", "saturated_s"]
    skid = predict_step(PLANT, "cascade", CASCADE, math.radians(40.0), 10.0, full_scale=0.35,
                        skid=SkidDrive(SkidMixer(), speed=2.0, throttle=0.81))
    out = _strict(skid.to_dict())
    assert list(out) == FIGURE_KEYS + ["speed_dip_pct", "rudder_peak", "saturated", "saturated_s"]
    assert out["speed_dip_pct"] == skid.speed_dip_pct and out["iae_s"] == skid.figures.iae_s


def test_a_flown_heading_steps_json_adds_its_size_and_speed_and_a_verification_steps_its_ending():
    heading = FlownStepFigures(FIGURES, step_deg=-20.0, speed=math.nan)
    assert list(_strict(heading.to_dict())) == FIGURE_KEYS + ["step_deg", "speed"]
    assert heading.to_dict()["speed"] is None and heading.to_dict()["step_deg"] == -20.0
    verified = FlownStepFigures(FIGURES, step_deg=20.0, speed=1.6, ended="settled", duration_s=8.5)
    assert list(_strict(verified.to_dict())) == FIGURE_KEYS + ["step_deg", "speed", "ended", "duration_s"]


@pytest.mark.parametrize("changes, words", [
    ({"ended": "settled"}, "ending and its duration come together"),
    ({"duration_s": 3.0}, "ending and its duration come together"),
    ({"ended": "finished", "duration_s": 3.0}, "ended must be one of " + ", ".join(STEP_ENDINGS)),
    ({"ended": "timeout", "duration_s": -1.0}, "duration_s must be a finite time ≥ 0"),
    ({"step_deg": math.nan}, "step_deg must be a finite angle"),
])
def test_a_flown_heading_step_refuses_an_ending_without_its_duration_and_an_unknown_ending(changes, words):
    with pytest.raises(ValueError, match=words):
        dataclasses.replace(FlownStepFigures(FIGURES, step_deg=20.0, speed=1.6), **changes)


def test_a_step_predicted_at_a_speed_names_its_thrust_speed_and_gains_first():
    step = predict_step(PLANT, "cascade", CASCADE, math.radians(20.0), 10.0, full_scale=0.35)
    at = PredictedAtSpeed(0.8, 1.9, "scheduled", step)
    assert _strict(at.to_dict()) == {"thrust": 0.8, "speed": 1.9, "label": "scheduled", **step.to_dict()}
    with pytest.raises(ValueError, match="label must be one of scheduled, original"):
        PredictedAtSpeed(0.8, 1.9, "own", step)
