"""A yaw model validates at construction (a22 < 0, b2 > 0, finite: eq. 3.5–3.9); what estimators give
is a YawEstimate, which becomes a model only where designs, schedules and predictions take it. An
unstable or inverted estimate is never an accepted model, old stores holding one still load, and
the design command refuses one with a clear error."""
from __future__ import annotations

import json
import math
import sqlite3

import numpy as np
import pytest

import behaviors.identification as identification
from behaviors.identification import IdentificationAttempt, IdentificationManoeuvre, ManoeuvreConfig, Rejection
from companion.cli.main import main as cli_main
from companion.numerics.bounded_pole import ONLINE, YawModelChoice
from companion.numerics.identification import YawEstimate, YawIdentifier, YawModel
from companion.numerics.offline import fit_yaw_offline
from companion.numerics.parameter_tracking import MissionModels, SpeedBand, TrackingConfig
from companion.procedures.health import reference_from_store
from companion.procedures.runner import run_behavior
from companion.records.serialise import from_json, to_json
from companion.records.store import Store
from harness.inprocess import InProcessLink

UNSTABLE = "a22 = 0.6 ≥ 0: not a stable model"
INVERTED = "b2 = -5 ≤ 0: the rudder turns the vehicle the wrong way"


def _attempt(model, accepted: bool, **changes) -> IdentificationAttempt:
    fields = dict(attempt=1, axis="yaw", thrust=0.7, speed=1.4, model=model, r2=0.95, accepted=accepted,
                  converged=True, converged_s=9.0, criterion_met_from_s=8.0, training_s=10.0, samples=200)
    return IdentificationAttempt(**{**fields, **changes})


def test_a_yaw_model_is_stable_turns_the_right_way_and_is_finite():
    model = YawModel(-1.05, 0.86, 0.01)
    assert model.c0 == pytest.approx(0.86 * 0.01) and model.model() is model
    with pytest.raises(ValueError, match=UNSTABLE):
        YawModel(0.6, 1.0, 0.0)
    with pytest.raises(ValueError, match=INVERTED):
        YawModel(-1.0, -5.0, 0.0)
    with pytest.raises(ValueError, match="a22 = 0 ≥ 0"):
        YawModel(0.0, 1.0, 0.0)  # a pure integrator is no stable model
    with pytest.raises(ValueError, match="a22 = nan: not a finite number"):
        YawModel(math.nan, 1.0, 0.0)
    with pytest.raises(ValueError, match="delta0 = inf: not a finite number"):
        YawModel(-1.0, 1.0, math.inf)
    with pytest.raises(ValueError) as both:  # every number at fault is named
        YawModel(0.6, -5.0, 0.0)
    assert str(both.value) == f"{UNSTABLE}; {INVERTED}"


def test_an_estimate_holds_any_numbers_and_says_why_it_is_no_model():
    unstable = YawEstimate(0.6, 1.0, 0.0)
    assert not unstable.is_model and unstable.why_not_model == UNSTABLE
    with pytest.raises(ValueError, match=UNSTABLE):
        unstable.model()
    assert YawEstimate(-1.0, -5.0, 0.0).why_not_model == INVERTED
    assert not YawEstimate(math.nan, math.nan, math.nan).is_model  # NaN is an estimate too
    covariance = np.eye(3) * 1e-4
    estimate = YawEstimate(-1.05, 0.86, 0.01, covariance=covariance)
    assert estimate.is_model and estimate.why_not_model is None
    model = estimate.model()
    assert type(model) is YawModel and (model.a22, model.b2, model.delta0) == (-1.05, 0.86, 0.01)
    assert model.covariance is covariance


def test_estimators_give_estimates():
    identifier = YawIdentifier()
    assert type(identifier.model()) is YawEstimate and not identifier.model().is_model  # Θ = 0 before any data
    times = np.arange(0.0, 12.0, 0.05)
    rudder = np.where((times > 2.0) & (times < 4.0), 0.2, 0.0)
    heading = np.cumsum(0.05 * np.cumsum(0.05 * rudder))  # an integrator's response: no lag resolved
    assert type(fit_yaw_offline(times, heading, rudder).model) is YawEstimate


def test_an_attempt_is_accepted_only_with_a_model():
    with pytest.raises(ValueError, match=f"yaw attempt 1 cannot be accepted: the estimate is not a yaw model: {UNSTABLE}"):
        _attempt(YawEstimate(0.6, 1.0, 0.0), accepted=True)
    rejected = _attempt(YawEstimate(0.6, 1.0, 0.0), accepted=False, r2=0.2)
    assert type(rejected.model) is YawEstimate and not rejected.spoiled_by_link
    # an estimate that is a model is held as one, so it is stored under the tag it always had
    kept = _attempt(YawEstimate(-1.05, 0.86, 0.01), accepted=True)
    assert type(kept.model) is YawModel and to_json(kept.model)["type"] == "YawModel"
    assert _attempt(YawModel(-1.05, 0.86, 0.01), accepted=False, rejected_for="training record: 30 % lost",
                    rejection=Rejection.LINK).spoiled_by_link
    no_model = _attempt(YawEstimate(0.6, 1.0, 0.0), accepted=False, rejected_for="not a model",
                        rejection=Rejection.NOT_A_MODEL)
    assert not no_model.spoiled_by_link
    with pytest.raises(ValueError, match="a rejection needs both its reason and its kind"):
        _attempt(YawModel(-1.05, 0.86, 0.01), accepted=False, rejected_for="training record: 30 % lost")


def test_an_unstable_estimate_that_passes_validation_is_rejected_with_its_reason(monkeypatch):
    """A fit can reproduce a short fresh record and still be unstable: the attempt is rejected, says
    why, and the manoeuvre never ends with it as its model."""
    monkeypatch.setattr(identification, "validate_yaw", lambda *args, **kwargs: 0.99)
    monkeypatch.setattr(identification, "choose_yaw_model",
                        lambda online, fit: YawModelChoice(YawEstimate(0.6, online.b2, online.delta0), ONLINE))
    link = InProcessLink(seed=4)
    manoeuvre = IdentificationManoeuvre(ManoeuvreConfig(settle_s=10.0, resettle_s=8.0, max_attempts=2), thrust=0.7)
    outcome = run_behavior(link, manoeuvre)
    assert outcome.status == "failed" and manoeuvre.outcome == "rejected"
    assert [a.accepted for a in manoeuvre.attempts] == [False, False]
    assert all(a.r2 == 0.99 and type(a.model) is YawEstimate for a in manoeuvre.attempts)
    assert all(a.rejected_for == f"the estimate is not a yaw model: {UNSTABLE}" for a in manoeuvre.attempts)
    assert "2 of them passing with an estimate that is not a model" in outcome.reason
    assert "spoiled by the link" not in outcome.reason
    assert any("rejected, not a model: a22 0.600" in text for text in link.status_texts)
    summary = manoeuvre.result().to_dict()["best"]
    assert summary["accepted"] is False and summary["model"]["a22"] == 0.6


class _Tracker:
    """A band's tracker holding one estimate (what ParameterTracker.model gives)."""

    def __init__(self, estimate: YawEstimate) -> None:
        self.estimate, self.windows = estimate, 3

    def model(self) -> YawEstimate:
        return self.estimate


def test_a_learned_band_becomes_a_model_only_when_its_estimate_is_one():
    config = TrackingConfig()
    stable = SpeedBand(speed=1.5, tracker=_Tracker(YawEstimate(-1.0, 0.8, 0.0)), speeds=[1.5],
                       validations=[(10.0, 0.95)])
    inverted = SpeedBand(speed=2.5, tracker=_Tracker(YawEstimate(-1.0, -0.8, 0.0)), speeds=[2.5],
                         validations=[(10.0, 0.95)])
    assert stable.validated(config) and not inverted.validated(config)
    models = MissionModels(config)
    models.bands = [stable, inverted]
    [(speed, model)] = models.validated()
    assert speed == 1.5 and type(model) is YawModel


def test_estimates_and_models_are_stored_under_their_own_tags():
    model = YawModel(-1.05, 0.86, 0.01)
    assert to_json(model) == {"type": "YawModel", "a22": -1.05, "b2": 0.86, "delta0": 0.01, "covariance": None}
    estimate = YawEstimate(13.9, -93.6, math.nan)
    data = json.loads(json.dumps(to_json(estimate), allow_nan=False))
    assert data["type"] == "YawEstimate" and data["delta0"] is None
    back = from_json(data)
    assert type(back) is YawEstimate and (back.a22, back.b2) == (13.9, -93.6) and math.isnan(back.delta0)
    assert from_json(to_json(model)) == model


def _old_store(path) -> int:
    """A store written before models validated: a campaign whose rejected attempt holds an inverted
    estimate tagged "YawModel", and whose accepted one (R² passed) is unstable, stored as a model."""
    with Store(path) as store:
        vehicle = store.add_vehicle("boat", "ardurover")
        campaign = store.start_campaign(vehicle, "identification", {"thrusts": [0.5]})
        store.finish_campaign(campaign, "completed")
    rows = ((1, 0, {"type": "YawModel", "a22": 13.9, "b2": -93.6, "delta0": 0.0, "covariance": None}, 0.2),
            (2, 1, {"type": "YawModel", "a22": 0.6, "b2": 40.0, "delta0": None, "covariance": None}, 0.93))
    with sqlite3.connect(path) as db:
        for attempt, accepted, model, r2 in rows:
            run = db.execute("INSERT INTO runs(campaign_id, axis, thrust, attempt, speed, r2, accepted, converged_s,"
                             " training_s, samples, model_json, series_json) VALUES (?,?,?,?,?,?,?,?,?,?,?,?)",
                             (campaign, "yaw", 0.5, attempt, 3.1, r2, accepted, 8.0, 10.0, 250, json.dumps(model),
                              json.dumps({"training": {}, "validation": {}}))).lastrowid
            if accepted:
                params = {k: v for k, v in model.items() if k not in ("type", "covariance")}
                db.execute("INSERT INTO models(run_id, campaign_id, axis, thrust, speed, params_json, covariance_json,"
                           " r2) VALUES (?,?,?,?,?,?,?,?)", (run, campaign, "yaw", 0.5, 3.1, json.dumps(params),
                                                             "null", r2))
    return campaign


def test_old_store_rows_holding_an_inverted_yaw_model_still_load(tmp_path, capsys):
    path = tmp_path / "old.sqlite"
    campaign = _old_store(path)
    with Store(path, read_only=True) as store:
        runs = store.runs(campaign)
        estimates = [from_json(run["model"]) for run in runs]  # read back as the estimates they are
        assert [type(e) for e in estimates] == [YawEstimate, YawEstimate]
        assert estimates[0].why_not_model == "a22 = 13.9 ≥ 0: not a stable model; " \
                                             "b2 = -93.6 ≤ 0: the rudder turns the vehicle the wrong way"
        assert math.isnan(estimates[1].delta0)
        assert reference_from_store(store) is None  # an unstable accepted model is no health reference
    assert cli_main(["results", "--store", str(path), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["campaigns"][0]["models"] == 1
    assert cli_main(["results", "--store", str(path), "--campaign", str(campaign), "--json"]) == 0
    shown = json.loads(capsys.readouterr().out)
    assert [run["model"]["a22"] for run in shown["runs"]] == [13.9, 0.6]
    assert cli_main(["results", "--store", str(path), "--campaign", str(campaign)]) == 0  # the text listing
    assert cli_main(["results", "--store", str(path), "--campaign", str(campaign), "--report",
                     str(tmp_path / "report")]) == 0
    err = capsys.readouterr().err
    assert "Traceback" not in err and (tmp_path / "report").exists()


@pytest.mark.parametrize("argv, problem", [
    (["--a22", "0.6", "--b2", "1"], UNSTABLE),
    (["--a22", "-1", "--b2", "-5"], INVERTED),
    (["--a22", "nan", "--b2", "1"], "a22 = nan: not a finite number"),
    (["--autopilot", "ardurover", "--speed", "2", "--a22", "0.6", "--b2", "1"], UNSTABLE),
])
def test_the_design_command_refuses_numbers_that_are_no_model(capsys, argv, problem):
    assert cli_main(["design", *argv]) == 2
    out, err = capsys.readouterr()
    assert out == "" and "Traceback" not in err
    assert err.strip() == f"companion design: error: --a22, --b2 and --delta0 give no yaw model: {problem}"
