"""Health monitoring: passive estimates, their HAC covariance, the CUSUM, the
monitor on synthetic data, and ``companion run``'s resident loop flagging a 30 % loss of fin
effectiveness injected into the simulator (in-process), with its STATUSTEXT, NAMED_VALUE_FLOATs,
store records and drift plot."""
from __future__ import annotations

import math

import numpy as np
import pytest

from behaviors.identification import IdentificationAttempt
from behaviors.health_monitor import HealthMonitor
from companion.interface import SetHeading, SetThrust, Telemetry
from companion.numerics.drift import Cusum, DriftConfig, PassiveYawEstimator, hac_least_squares
from companion.numerics.identification import YawModel
from companion.procedures.app import AbortFlag
from companion.procedures.resident import Companion, ServeConfig
from companion.records.report import write_report
from companion.records.store import Store
from harness.inprocess import InProcessLink
from harness.missions import SurveyPlan
from harness.steering_data import SteeringTruth, synth_steering
from sim.faults import Fault
from sim.linearize import linearized_yaw, steady_speed
from sim.preset import load_preset

TRUTH = SteeringTruth(a22=-1.1, b2=1.0, delta0=0.01)


def test_hac_covariance_is_wider_than_white_noise_for_coloured_errors():
    """With an equation error correlated over ~1 s the white-noise σ understates the scatter; the
    Newey–West σ does not (checked against the scatter over 200 seeded repeats)."""
    rng = np.random.default_rng(1)
    n, lags = 400, 20
    estimates, hac, white = [], [], []
    kernel = np.ones(20) / 20
    for _ in range(200):
        x = np.column_stack([np.convolve(rng.standard_normal(n + 19), kernel, "valid"), np.ones(n)])
        e = np.convolve(rng.standard_normal(n + 19), kernel, "valid")
        theta, cov = hac_least_squares(x, x @ [2.0, 0.5] + e, lags)
        resid = x @ [2.0, 0.5] + e - x @ theta
        estimates.append(theta[0])
        hac.append(math.sqrt(cov[0, 0]))
        white.append(math.sqrt(resid @ resid / (n - 2) * np.linalg.inv(x.T @ x)[0, 0]))
    scatter = float(np.std(estimates))
    assert np.median(white) < 0.5 * scatter
    assert 0.6 * scatter < np.median(hac) < 1.5 * scatter


def test_cusum_two_sided():
    cusum = Cusum(allowance=1.0, threshold=4.0)
    assert not any(cusum.add(z) for z in (0.5, -0.8, 0.9, -0.2) * 25)
    assert cusum.statistic == 0.0
    assert not cusum.add(-3.0) and cusum.add(-3.5) and cusum.direction == -1


def _monitor_run(data, config=DriftConfig()):
    monitor = HealthMonitor(lambda u: (TRUTH.a22, TRUTH.b2), (1.0, 2.0), config)
    texts = []
    for t, yaw, rudder, speed in zip(data["t"], data["heading"], data["rudder"], data["speed"]):
        for command in monitor.step(Telemetry(time_s=float(t), yaw=float(yaw), rudder=float(rudder),
                                              speed_water=float(speed))):
            if hasattr(command, "text"):
                texts.append(command.text)
    return monitor, texts


def test_passive_estimates_and_alarm_on_synthetic_data():
    healthy, texts = _monitor_run(synth_steering(1200.0, truth=TRUTH, seed=5))
    used = [v for v in healthy.verdicts if v.used]
    assert len(used) >= 30 and healthy.alarm is None and not texts
    assert np.median([v.ratio["b2"] for v in used]) == pytest.approx(1.0, abs=0.02)
    assert max(max(v.cusum.values()) for v in used) < 2.0  # far from the threshold (4)
    faulty, texts = _monitor_run(synth_steering(900.0, truth=TRUTH, seed=5, b2_change=(600.0, 0.7)))
    assert faulty.alarm is not None and faulty.alarm.alarm == "b2"
    assert 600.0 < faulty.alarm.window.t_end <= 660.0
    assert faulty.alarm.ratio["b2"] == pytest.approx(0.7, abs=0.05)
    assert texts and texts[0].startswith("HEALTH: fin effectiveness b2 -")


def test_estimator_restarts_after_a_gap():
    data = synth_steering(120.0, truth=TRUTH, seed=1)
    estimator = PassiveYawEstimator()
    for t, yaw, rudder in zip(data["t"], data["heading"], data["rudder"]):
        if 50.0 < t < 52.0:
            continue
        estimator.add(float(t), float(yaw), float(rudder), 1.5)
    assert estimator.restarts == 2


def _reference_campaign(store: Store, preset) -> None:
    """The vehicle's healthy models at three thrusts, stored as a completed campaign stores them."""
    vehicle = store.add_vehicle("starfish")
    campaign = store.start_campaign(vehicle, "identification")
    for thrust in (0.6, 0.7, 0.8):
        truth = linearized_yaw(preset, steady_speed(preset, thrust))
        store.add_run(campaign, IdentificationAttempt(
            attempt=1, axis="yaw", thrust=thrust, speed=truth["speed"], model=YawModel(truth["a22"], truth["b2"], truth["delta0"]),
            r2=0.99, accepted=True, converged=True, converged_s=10.0, criterion_met_from_s=9.0, training_s=12.0,
            samples=240))
    store.finish_campaign(campaign, "completed")


def test_companion_run_flags_a_fin_fault(tmp_path):
    """The resident loop, on the simulator's autopilot in-process, flying a survey at cruise: the
    fin loses 30 % of its effectiveness at 300 s; flagged within 60 s, recorded, plotted."""
    link = InProcessLink(seed=7, faults=(Fault("b2", 0.7, 300.0),))
    plan = SurveyPlan(thrusts=(0.7,), seconds_per_thrust=1e9, course_changes_deg=(30.0, -20.0, 25.0, -35.0))
    read = link.next_telemetry
    last = []

    def mission(timeout_s: float = 5.0) -> Telemetry:  # the vehicle's own mission: course changes
        telemetry = read(timeout_s)
        setpoint = plan.setpoints(telemetry.time_s)
        if setpoint not in last:
            link.execute([SetThrust(setpoint[0]), SetHeading(setpoint[1])])
            last[:] = [setpoint]
        return telemetry

    link.next_telemetry = mission
    with Store(tmp_path / "store.sqlite") as store:
        _reference_campaign(store, load_preset("starfish"))
        config = ServeConfig(max_vehicle_s=390.0, schedule_gains=False)
        Companion(link, store, store.add_vehicle("v"), config, AbortFlag()).run()
        health = [c for c in store.campaigns() if c["kind"] == "health"]
        assert len(health) == 1 and health[0]["status"] == "completed" and health[0]["reason"].startswith("b2 -")
        alarm = store.behavior_results(health[0]["id"], "health_alarm")[0]["result"]
        assert alarm["parameter"] == "b2" and 300.0 < alarm["time_s"] <= 360.0
        assert alarm["windows"] and alarm["windows"][-1]["alarm"] == "b2"
        session = store.behavior_results(health[0]["id"], "health")[0]["result"]
        before = [w for w in session["windows"] if w["used"] and w["t_end"] < 300.0]
        assert before and all(max(w["cusum"].values()) < 1.0 for w in before)  # no drift while healthy
        write_report(store, health[0]["id"], tmp_path / "report")
    assert (tmp_path / "report" / "health.png").exists()
    assert any(text.startswith("HEALTH: fin effectiveness b2") for text in link.status_texts)
    assert {"hm_a22r", "hm_b2r", "hm_cusum"} <= {name for name, _ in link.named_values}
