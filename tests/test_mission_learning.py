"""Tuning during ordinary missions (``companion run --learn``): the parameter tracker, the turns and
their verdict, and the resident loop on the simulator's autopilot in-process (lockstep by
construction) flying a survey of heading set-points with poor gains: written on a straight,
verified by the next course changes, reverted when the vehicle does not answer as predicted, held
back in a hand-flown mode, decided from the ground station, and recoverable after a crash."""
from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest

from behaviors.mission_learning import Phase
from companion.interface import SetHeading, SetThrust, Telemetry
from companion.numerics.drift import DriftConfig, PassiveYawEstimator
from companion.numerics.mission_turns import RateSegmentRecorder, TurnFigures, TurnRecorder, VerdictConfig, judge_turns
from companion.numerics.step_response import RudderPlant, simulate_rate_tracking
from companion.numerics.parameter_tracking import MissionModels, TrackingConfig
from companion.procedures.app import AbortFlag
from companion.procedures.learning import LearningSession
from companion.procedures.registry import ABORT_COMMAND
from companion.procedures.resident import Companion, ServeConfig
from companion.procedures.trail import interrupted, recover
from companion.records.owner import ProcessOwner
from companion.records.store import Store
from harness.inprocess import InProcessLink
from harness.missions import SurveyPlan
from sim.faults import Fault
from sim.linearize import linearized_yaw, steady_speed
from sim.preset import load_preset

POOR = {"HDG_P": 0.4, "HDG_I": 0.02}  # sluggish: 13 % overshoot and twice the step error of the design
PLAN = SurveyPlan(thrusts=(0.7,), seconds_per_thrust=1e9, course_changes_deg=(30.0, -45.0, 20.0, -30.0, 40.0, -15.0))


def _survey_link(seed: int = 3, faults: tuple = (), plan: SurveyPlan = PLAN, manual: tuple[float, float] | None = None,
                 gains: dict[str, float] = POOR) -> InProcessLink:
    """The simulator in-process flying ``plan`` in its holding mode (its own mission: course
    changes, never a doublet), optionally in MANUAL for ``manual`` = (from, to) vehicle seconds."""
    link = InProcessLink(seed=seed, faults=faults)
    for name, value in gains.items():
        link.simulated.set_param(name, value)
    read = link.next_telemetry
    last: list = []

    def mission(timeout_s: float = 5.0) -> Telemetry:
        telemetry = read(timeout_s)
        if manual is not None:
            wanted = "manual" if manual[0] <= telemetry.time_s < manual[1] else "hold"
            if link.mode != wanted:
                link.set_mode(wanted)
                last.clear()
        setpoint = plan.setpoints(telemetry.time_s)
        if link.mode != "manual" and setpoint not in last:
            link.execute([SetThrust(setpoint[0]), SetHeading(setpoint[1])])
            last[:] = [setpoint]
        return telemetry

    link.next_telemetry = mission
    return link


def _serve(link, tmp_path, seconds: float, **extra) -> tuple[Companion, Store]:
    store = Store(tmp_path / "store.sqlite")
    config = ServeConfig(max_vehicle_s=seconds, health=False, learn=True, **extra)
    companion = Companion(link, store, store.add_vehicle("v"), config, AbortFlag())
    companion.run()
    return companion, store


def _learning_result(store: Store) -> tuple[dict, dict]:
    (campaign,) = [c for c in store.campaigns() if c["kind"] == "learning"]
    (result,) = store.behavior_results(campaign["id"], "learning")
    return campaign, result["result"]


def _dead_process() -> ProcessOwner:
    child = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    me = ProcessOwner.current()
    return ProcessOwner(int(child.stdout), me.host, me.boot_id, "1")


# ---------------------------------------------------------------------------- numerics
def _flown_windows(seed: int = 3, seconds: float = 300.0):
    link = _survey_link(seed)
    estimator = PassiveYawEstimator(DriftConfig(), keep_records=True)
    windows = []
    while True:
        telemetry = link.next_telemetry()
        if telemetry.time_s > seconds:
            return windows
        window = estimator.add(telemetry.time_s, telemetry.yaw, telemetry.rudder, telemetry.speed_water)
        if window is not None:
            windows.append(window)


def test_the_tracker_learns_the_hull_from_course_changes_and_validates_on_windows_it_has_not_seen():
    windows = _flown_windows()
    models = MissionModels(TrackingConfig())
    outcomes = [models.add(w) for w in windows]
    skipped = [o for o in outcomes if not o.used]
    assert skipped and all(o.reason for o in skipped)  # the straights between course changes teach nothing
    assert all("course change" in o.reason or "steady" in o.reason for o in skipped)
    ((speed, model),) = models.validated()
    truth = linearized_yaw(load_preset("starfish"), steady_speed(load_preset("starfish"), 0.7))
    assert speed == pytest.approx(truth["speed"], rel=0.03)
    assert model.a22 == pytest.approx(truth["a22"], rel=0.1)
    assert model.b2 == pytest.approx(truth["b2"], rel=0.1)
    validations = [o.r2 for o in outcomes if math.isfinite(o.r2)]
    assert len(validations) >= 3 and min(validations) >= 0.9


def test_without_process_noise_the_filter_is_the_least_squares_over_its_windows():
    """eq. L.1 with q = 0: the Kalman filter over the parameters is recursive least squares over every
    row it absorbed, each window weighted by its own noise; on windows of similar noise that is the
    plain least squares."""
    windows = [w for w in _flown_windows(seconds=200.0) if w.heading_span_deg > 10.0]
    models = MissionModels(TrackingConfig(process_noise=0.0, min_windows=99))
    for window in windows:
        models.add(window)
    (band,) = models.bands
    phi = np.vstack([w.record.phi for w in windows])
    y = np.concatenate([w.record.y for w in windows])
    least_squares = np.linalg.lstsq(phi, y, rcond=None)[0]
    assert band.tracker.theta == pytest.approx(least_squares, rel=0.02)


def test_a_turn_is_a_set_point_jump_and_an_interrupted_one_is_dropped():
    recorder = TurnRecorder(min_step_deg=10.0, turn_s=10.0)
    out = []
    heading, target = 0.0, 0.0
    for k in range(400):
        t = 0.1 * k
        if k in (50, 200, 250):  # a course change at 5 s, then two 5 s apart (the first is cut short)
            target += math.radians(30.0)
        heading += 0.1 * (target - heading)
        found = recorder.add(t, heading, target, 1.5)
        if found is not None:
            out.append(found)
    assert [round(turn.t_start, 1) for turn in out] == [5.0, 25.0]
    assert recorder.interrupted == 1
    assert math.degrees(out[0].step) == pytest.approx(30.0)
    assert out[0].figures().overshoot_pct < 1.0


def _turns(label: str, iae: float, overshoot: float = 2.0, predicted: float = math.nan) -> list[TurnFigures]:
    return [TurnFigures(t_start=float(i), speed=1.4, size=30.0, gains=label, error=iae, overshoot_pct=overshoot,
                        predicted_error=predicted, predicted_overshoot_pct=3.0, original_error=5.0) for i in range(3)]


def test_the_verdict_keeps_better_gains_as_predicted_and_names_what_failed_otherwise():
    config = VerdictConfig(overshoot_margin_pct=2.0, error_tolerance=0.3)
    kept = judge_turns(_turns("original", 4.8), _turns("learned", 2.8, predicted=2.6), config)
    assert kept.keep and kept.turns_before == 3
    worse = judge_turns(_turns("original", 2.5), _turns("learned", 2.8, predicted=2.6), config)
    assert not worse.keep and worse.reason.startswith("worse than the original gains")
    off = judge_turns(_turns("original", 4.8), _turns("learned", 4.0, predicted=2.6), config)
    assert not off.keep and "not as predicted: step error" in off.reason
    overshoot = judge_turns(_turns("original", 4.8), _turns("learned", 2.6, overshoot=9.0, predicted=2.6), config)
    assert not overshoot.keep and "overshoot" in overshoot.reason
    alone = judge_turns([], _turns("learned", 2.8, predicted=2.6), config)
    assert alone.keep and "prediction (none flown before)" in alone.reason
    unpredicted = judge_turns(_turns("original", 4.8), _turns("learned", 2.8), config)  # no prediction: fail safe
    assert not unpredicted.keep and "no prediction" in unpredicted.reason


# ---------------------------------------------------------------------------- the resident loop
def test_run_learn_writes_verified_gains_within_five_minutes_of_an_ordinary_survey(tmp_path):
    link = _survey_link()
    companion, store = _serve(link, tmp_path, 420.0)
    campaign, result = _learning_result(store)
    assert campaign["status"] == "completed" and result["phase"] == "kept", campaign["reason"]
    (write,) = [w for w in result["writes"] if w["why"] == "design"]
    assert write["time_s"] < 300.0
    assert (write["time_s"] - 30.0) % 30.0 >= 8.0  # at least steady_s after the course change before it
    verdict = result["verdict"]
    assert verdict["turns_after"] >= 2 and verdict["after_error"] < 0.8 * verdict["before_error"]
    # written on a straight: no turn recorded around the write, and the vehicle holds the written gains
    assert link.param("heading_p") == pytest.approx(write["gains"]["heading_p"])
    later = [t for t in result["turns"] if t["gains"] == "learned"]
    assert later and all(t["error"] < min(b["error"] for b in result["turns"] if b["gains"] == "original")
                         for t in later)
    assert any(text.startswith("LEARN: wrote") for text in link.status_texts)
    assert any(text.startswith("LEARN: kept") for text in link.status_texts)
    events = [e["status"] for e in store.behavior_results(campaign["id"], "learning_event")]
    assert events[:3] == ["design", "write", "verdict"]
    assert interrupted(store) == [] and not store.open_trails()  # kept gains stay; the trail is closed
    assert link.mode_changes == []  # nothing asked of the vehicle but the gains
    assert companion.learning.result.mode_left_s == 0.0


def test_gains_the_vehicle_does_not_answer_as_predicted_are_reverted_on_a_straight(tmp_path):
    """The fin loses 60 % of its effectiveness just after the gains are written (near 108 s on this
    survey): the turns that follow are far slower than predicted, and the original gains go back."""
    link = _survey_link(faults=(Fault("b2", 0.4, 112.0),))
    _companion, store = _serve(link, tmp_path, 420.0)
    campaign, result = _learning_result(store)
    assert result["phase"] == "reverted" and campaign["status"] == "failed"
    assert "not as predicted" in campaign["reason"] or "worse" in campaign["reason"]
    assert [w["why"] for w in result["writes"]] == ["design", "revert"]
    assert link.param("heading_p") == pytest.approx(POOR["HDG_P"]) and link.param("heading_i") == pytest.approx(POOR["HDG_I"])
    assert any(text.startswith("LEARN: reverted") for text in link.status_texts)


class _ReadyDesign:
    """A design ready at once (the tracker and designer are tested above): gains and predictions."""

    summary = "ready"

    def gains_at(self, speed):
        return {"heading_p": 0.63, "heading_i": 0.001}

    def predict(self, gains, speed, step):
        return 2.6, 4.0

    def replay(self, gains, speed, segment):
        return segment.desired

    def rate_limit(self, speed):
        return 1.0


def _ready_learner(**config):
    from behaviors.mission_learning import DesignOutcome, LearningConfig, MissionLearner

    learner = MissionLearner(lambda validated: DesignOutcome(_ReadyDesign(), "ready"),
                             {"heading_p": 0.4, "heading_i": 0.02}, LearningConfig(**config))
    learner.models.validated = lambda: [(1.4, None)]
    return learner


def _writes(learner, samples) -> list[float]:
    """Vehicle times at which the learner wrote gains, over (time, mode, yaw, yaw target) samples."""
    out = []
    for t, mode, yaw, target in samples:
        telemetry = Telemetry(time_s=t, yaw=yaw, yaw_rate=0.0, speed_water=1.4, rudder=0.0, heading_target=target,
                              mode=mode, armed=True)
        if any(type(c).__name__ == "SetParameters" for c in learner.tick(telemetry)):
            out.append(t)
    return out


def test_nothing_is_written_while_the_pilot_flies_by_hand():
    """A design is ready at once, but the vehicle is in MANUAL for the first 60 s on a steady
    course: nothing is written then; in the holding mode it is written once the course has been
    steady for ``steady_s`` (8 s) there."""
    learner = _ready_learner()
    samples = [(0.05 * k, "manual" if k < 1200 else "hold", 0.3, 0.3) for k in range(1600)]
    assert _writes(learner, samples) == [pytest.approx(60.0 + 0.9 * 8.0, abs=0.1)]


def test_nothing_is_written_in_a_turn_or_off_the_set_point():
    """In the holding mode, ready at once: a steady turn (a net change of course) and a heading 10°
    off its set-point both hold the write back until a straight on its set-point."""
    learner = _ready_learner()
    turning = [(0.05 * k, "hold", 0.05 * 0.05 * k, 0.05 * 0.05 * k) for k in range(400)]  # 2.9°/s turn, on target
    off = [(20.0 + 0.05 * k, "hold", 1.0 + math.radians(10.0), 1.0) for k in range(400)]  # 10° off, 20 s
    on = [(40.0 + 0.05 * k, "hold", 1.0, 1.0) for k in range(400)]
    assert _writes(learner, turning + off + on) == [pytest.approx(40.0 + 0.9 * 8.0, abs=0.1)]
    lax = _ready_learner(max_turn_rate_deg_s=100.0)  # the same turn counts as a straight without the rule
    assert _writes(lax, turning)[:1] == [pytest.approx(0.9 * 8.0, abs=0.1)]


def test_time_outside_the_learning_modes_is_counted(tmp_path):
    link = _survey_link(manual=(90.0, 200.0))
    companion, _store = _serve(link, tmp_path, 200.0)
    assert companion.learning.result.mode_left_s == pytest.approx(110.0, abs=0.5)


def test_the_ground_station_reverts_learned_gains_at_once(tmp_path):
    link = _survey_link()
    link.inject_user_command(ABORT_COMMAND, 150.0, (0.0,) * 7)  # verifying by then: param1 0 reverts
    _companion, store = _serve(link, tmp_path, 170.0)
    _campaign, result = _learning_result(store)
    assert [w["why"] for w in result["writes"]] == ["design", "revert"]
    assert 150.0 <= result["writes"][1]["time_s"] < 150.2  # at once, not at the next straight
    assert result["phase"] == "reverted" and result["reason"] == "reverted by the ground station"
    assert (ABORT_COMMAND, 0) in [(c, r) for c, r, _ in link.acks]
    assert link.param("heading_p") == pytest.approx(POOR["HDG_P"])


def test_the_ground_station_accepts_learned_gains_before_the_turns_verified_them(tmp_path):
    link = _survey_link()
    link.inject_user_command(ABORT_COMMAND, 130.0, (1.0,) + (0.0,) * 6)
    _companion, store = _serve(link, tmp_path, 140.0)
    _campaign, result = _learning_result(store)
    assert result["phase"] == "kept" and result["reason"] == "accepted by the ground station"
    assert link.param("heading_p") != pytest.approx(POOR["HDG_P"])


def test_a_session_ended_during_the_verification_writes_the_original_gains_back(tmp_path):
    link = _survey_link()
    _companion, store = _serve(link, tmp_path, 140.0)  # written near 108 s, three turns not yet flown
    campaign, result = _learning_result(store)
    assert result["phase"] == "reverted" and campaign["status"] == "failed"
    assert "written back" in campaign["reason"]
    assert link.param("heading_p") == pytest.approx(POOR["HDG_P"])
    assert not store.open_trails()


def test_a_crash_mid_learning_leaves_a_trail_that_puts_the_original_gains_back(tmp_path):
    """A ``kill -9`` after the write: the session never finishes; the trail (restore point stored
    before the first write, the write recorded before it was sent) is followed by the next start."""
    link = _survey_link()
    store = Store(tmp_path / "store.sqlite")
    session = LearningSession(link, store, store.add_vehicle("v"))
    link.next_telemetry()
    assert session.start() is None
    while not session.learner.writes:
        session.step(link.next_telemetry())
    assert link.param("heading_p") != pytest.approx(POOR["HDG_P"])
    (trail,) = [t for t in store.open_trails()]
    assert any(change["kind"] in ("SetParameters", "ParamWrite") for change in trail["changes"])
    dead = _dead_process()
    store._db.execute("UPDATE trails SET owner_pid=?, owner_started=?", (dead.pid, dead.started))
    store._db.commit()
    (found,) = interrupted(store)
    recovery = recover(link, store, found, decide=lambda differences: True)
    assert recovery.complete
    assert link.param("heading_p") == pytest.approx(POOR["HDG_P"]) and link.param("heading_i") == pytest.approx(POOR["HDG_I"])


# ---------------------------------------------------------------------------- turn-rate segments
def test_a_turn_rate_segment_opens_with_the_turn_asked_for_and_lasts_at_most_a_window():
    recorder = RateSegmentRecorder(window_s=10.0, min_rate_deg_s=2.0, lead_s=2.0)
    found = []
    for k in range(620):  # 31 s at 20 Hz: 10 s straight, then a ±10°/s sine asked for
        t = 0.05 * k
        desired = 0.0 if t < 10.0 else math.radians(10.0) * math.sin(0.5 * t)
        segment = recorder.add(t, desired, 0.8 * desired, 2.0, rudder=0.01 if t < 9.0 else 0.02)
        if segment is not None:
            found.append(segment)
    # the first opens 2 s before the turn asked for (its lead), the next at once when the window is full
    assert len(found) == 2 and found[0].t_start == pytest.approx(8.0)
    assert found[0].times[-1] == pytest.approx(18.0) and found[1].t_start == pytest.approx(18.05)
    assert found[0].rudder0 == pytest.approx(0.01) and found[1].rudder0 == pytest.approx(0.02)
    assert found[0].error_deg_s() == pytest.approx(0.2 * found[0].size_deg_s, rel=1e-6)
    assert [start for start, _ in recorder.straights] == [0.0]  # the straight before the turn: a leg


def test_each_turn_of_a_lane_end_corner_is_a_segment_of_its_own():
    """Two 90° turns 10 s apart (a lane-end corner): two segments, each from 2 s before its turn to
    3 s after it, wherever the corner falls on the clock; the lanes either side are legs."""
    for offset in (0.0, 7.3, 13.1):
        recorder = RateSegmentRecorder(window_s=20.0, min_rate_deg_s=2.0, lead_s=2.0, quiet_s=3.0)
        found = []
        for k in range(int(100.0 / 0.04)):
            t = 0.04 * k
            first, second = 40.0 + offset, 58.0 + offset  # each turn asks 11.25°/s for 8 s
            turning = first <= t < first + 8.0 or second <= t < second + 8.0
            desired = math.radians(11.25) if turning else 0.0
            segment = recorder.add(t, desired, 0.9 * desired, 2.0)
            if segment is not None:
                found.append(segment)
        assert [s.t_start for s in found] == pytest.approx([first - 2.0, second - 2.0], abs=0.1), offset  # to a sample or two
        assert all(12.9 <= s.times[-1] - s.times[0] <= 13.1 for s in found)
        # the legs are the stream's own 20 s windows: none that holds a turn's worth of asking
        assert len(recorder.straights) >= 2
        for start, _ in recorder.straights:
            overlap = sum(max(0.0, min(start + 20.0, t0 + 8.0) - max(start, t0)) for t0 in (first, second))
            assert overlap < 0.7, (start, offset)


def test_a_brief_ask_on_a_leg_opens_no_segment_and_stays_in_the_leg():
    """A 0.2 s ask of 2.5°/s on a leg (the heading loop answering a wobble): no segment (its RMS is
    below 2°/s), and the leg's window keeps it, so a leg flown on gains that make the heading loop
    ask more is judged by eq. L.2h rather than dropped."""
    recorder = RateSegmentRecorder(window_s=20.0, min_rate_deg_s=2.0)
    found = [recorder.add(0.05 * k, math.radians(2.5) if 200 <= k < 204 else 0.0, 0.0, 2.0) for k in range(500)]
    assert not any(found)
    assert [start for start, _ in recorder.straights] == [0.0]
    # the ask, not followed, is the leg's whole error: 2.5 deg/s over 4 of the window's 401 samples
    assert recorder.straights[0][1] == pytest.approx(2.5 * math.sqrt(4 / 401), rel=1e-6)


def test_the_rate_loop_prediction_tracks_with_the_right_feed_forward_and_not_without():
    """eq. A.2's inner loop alone: the feed-forward that is the model's inverse gain tracks a slow
    turn-rate request closely; no gain at all leaves the whole request as error."""
    plant = RudderPlant(a22=-1.0, b2=0.5, delta0=0.0, rudder_max=0.5236)
    times = np.arange(0.0, 30.0, 0.05)
    desired = math.radians(8.0) * np.sin(0.3 * times)
    feed_forward = 1.0 / (plant.b2 / -plant.a22 * 0.5236)  # output per rad/s of steady turn rate
    tracked = simulate_rate_tracking(plant, {"heading_rate_ff": feed_forward}, times, desired, 0.0)
    idle = simulate_rate_tracking(plant, {}, times, desired, 0.0)
    rms = lambda error: float(np.sqrt(np.mean(error ** 2)))  # noqa: E731
    assert rms(desired - tracked) < 0.35 * rms(desired)  # the first-order lag of a 1 s time constant
    assert rms(desired - idle) == pytest.approx(rms(desired), rel=1e-9)
    with_p = simulate_rate_tracking(plant, {"heading_rate_ff": feed_forward, "heading_rate_p": 1.0}, times, desired, 0.0)
    assert rms(desired - with_p) < rms(desired - tracked)


class _RateDesign:
    """A synthetic design for the turn-rate learner: its gains (FF 2) are predicted as flown, the
    original gains' replay falls 30 % short of the asked-for rates."""

    summary = "synthetic"

    def gains_at(self, speed):
        return {"heading_rate_ff": 2.0}

    def predict(self, gains, speed, step):
        return 1.0, 0.0

    def replay(self, gains, speed, segment):
        return (0.93 if gains.get("heading_rate_ff") == 2.0 else 0.7) * segment.desired

    def rate_limit(self, speed):
        return math.radians(20.0)


def test_the_learner_verifies_turn_rate_tracking_where_the_navigation_asks_for_rates():
    """A learner in "turn_rate" mode judges segments: kept when the flown tracking error after the
    write is below the original gains' replay on the same asked-for rates and near its own
    prediction (a synthetic design and vehicle)."""
    from behaviors.mission_learning import DesignOutcome, LearningConfig, MissionLearner

    learner = MissionLearner(lambda validated: DesignOutcome(_RateDesign(), "synthetic"), {"heading_rate_ff": 0.5},
                             LearningConfig(verification="turn_rate", verify_segments=2))
    now = [0.0]
    learner.models.validated = lambda: [(2.0, None)] if now[0] > 60.0 else []  # (the tracker is tested above)
    written = []
    for k in range(20 * 250):
        t = now[0] = 0.05 * k
        quality = 0.7 if not written else 0.93  # the rate loop tracks better once the design is written
        desired = math.radians(6.0) * math.sin(0.4 * t)
        telemetry = Telemetry(time_s=t, yaw=0.01 * math.sin(0.4 * t), yaw_rate=0.0, speed_water=2.0, rudder=0.0,
                              turn_rate_target=desired, turn_rate_achieved=quality * desired, mode="auto", armed=True)
        for command in learner.tick(telemetry):
            if type(command).__name__ == "SetParameters":
                written.append((t, command.values))
    assert written and learner.phase is Phase.KEPT, learner.note
    assert learner.verdict.after_error < learner.verdict.before_error and "replayed" in learner.verdict.reason
    assert learner.verdict.metric == "turn-rate error deg/s"


def test_the_status_page_shows_what_learning_wrote(tmp_path):
    """The learning section of the status page, fed by the resident loop: phase, bands, writes."""
    import json

    from companion.service.feed import StatusFeed
    from companion.service.status import StatusBoard

    link = _survey_link()
    companion, store = _serve(link, tmp_path, 260.0)
    board = StatusBoard()
    feed = StatusFeed(board, link, store, endpoint="in-process")
    feed.companion = companion
    feed.refresh()
    section = json.loads(board.to_json())["learning"]
    assert section["on"] is False and section["phase"] == "kept"  # the session ended with verified gains
    assert section["writes"][0]["why"] == "design" and "heading_p" in section["writes"][0]["gains"]


def test_a_ground_stations_change_to_a_learned_gain_stands_and_stops_learning(tmp_path):
    """HDG_P set to 0.9 by a ground station while the learned gains are being verified: learning
    stops, their HDG_P stays (also at the end of the session), the learned HDG_I goes back."""
    link = _survey_link()
    link.next_telemetry = _with_change(link, at_s=130.0, native="HDG_P", value=0.9)
    _companion, store = _serve(link, tmp_path, 200.0)
    campaign, result = _learning_result(store)
    assert result["phase"] == "overridden" and "HDG_P 0.9" in result["reason"]
    assert link.param("heading_p") == pytest.approx(0.9)  # theirs, kept on exit too
    assert link.param("heading_i") == pytest.approx(POOR["HDG_I"])  # the unverified learned one, back
    assert any(text.startswith("LEARN: stopped") for text in link.status_texts)


def _with_change(link, *, at_s: float, native: str, value: float):
    read = link.next_telemetry
    done = []

    def next_telemetry(timeout_s: float = 5.0):
        telemetry = read(timeout_s)
        if not done and telemetry.time_s >= at_s:
            link.set_by_someone_else(native, value)
            done.append(True)
        return telemetry

    return next_telemetry


def test_a_campaign_during_learning_ends_the_session_first_and_its_gains_stand(tmp_path):
    """USER_1 while learning: the session ends first (its unverified gains back), the campaign
    writes its verified gains, and a new session learns from them; nothing of learning undoes them."""
    from pymavlink.dialects.v20.common import MAV_CMD_USER_1

    from companion.procedures.campaign import CampaignConfig

    link = _survey_link()
    link.inject_user_command(MAV_CMD_USER_1, 120.0)  # gains learned and written near 108 s, unverified
    companion, store = _serve(link, tmp_path, 600.0, campaign=CampaignConfig(thrusts=(0.7,), axes=("yaw",)).quick())
    first, second = [c for c in store.campaigns() if c["kind"] == "learning"]
    (identification,) = [c for c in store.campaigns() if c["kind"] == "identification"]
    assert identification["status"] == "completed", identification["reason"]
    assert first["id"] < identification["id"] < second["id"]
    assert first["status"] == "failed" and "written back" in first["reason"]
    (written,) = store.gains(identification["id"])
    assert written["before"]["heading_p"] == pytest.approx(POOR["HDG_P"])  # learning's unverified gains were gone
    assert link.param("heading_p") == pytest.approx(written["after"]["heading_p"])  # and learning left the campaign's
    assert link.param("heading_i") == pytest.approx(written["after"]["heading_i"])
    result = store.behavior_results(second["id"], "learning")[0]["result"]
    assert result["original_best"] and second["status"] == "completed"  # nothing better than the campaign's


def test_learning_is_refused_where_its_gains_could_not_be_verified():
    from companion.link.autopilots.px4_uuv import PROFILE as PX4_UUV
    from companion.link.profiles import ARDUROVER, ARDUSUB, SIM
    from companion.procedures.learning import unverifiable

    assert unverifiable(SIM) is None  # reports the heading set-point it holds
    assert unverifiable(ARDUROVER) is None  # reports its steering loop's turn rates (PID_TUNING)
    assert unverifiable(ARDUSUB) is None  # reports its yaw rate loop's turn rates (PID_TUNING axis YAW)
    refused = unverifiable(PX4_UUV)
    assert "could not be verified" in refused and "companion identify" in refused


def test_ardusubs_rate_loop_applies_no_feed_forward_and_never_freezes_its_integrator():
    """eq. A.2r: ArduSub sends P + I (+ D) to the motors, never FF, and its vectored mixer never
    reports a yaw limit, so the integrator runs on while the output is saturated (only IMAX holds it)."""
    from companion.numerics.rate_loop import ARDUROVER_RATE_LOOP, ARDUSUB_RATE_LOOP

    plant = RudderPlant(a22=-1.0, b2=1.0, delta0=0.0, rudder_max=0.35)
    times = np.arange(0.0, 20.0, 0.1)
    desired = np.where(times < 10.0, 0.6, 0.0)  # beyond what full rudder holds (0.35 rad/s): saturated
    gains = {"heading_rate_p": 1.0, "heading_rate_i": 0.5, "heading_rate_imax": 1.0}
    with_ff = simulate_rate_tracking(plant, {**gains, "heading_rate_ff": 2.0}, times, desired, 0.0,
                                     full_scale=0.35, rate_loop=ARDUSUB_RATE_LOOP)
    without_ff = simulate_rate_tracking(plant, gains, times, desired, 0.0, full_scale=0.35, rate_loop=ARDUSUB_RATE_LOOP)
    assert np.array_equal(with_ff, without_ff)  # FF changes nothing on ArduSub
    rover = simulate_rate_tracking(plant, gains, times, desired, 0.0, full_scale=0.35, rate_loop=ARDUROVER_RATE_LOOP)
    assert np.allclose(rover[times < 10.0], without_ff[times < 10.0], atol=1e-9)  # the same while saturated
    after = (times > 10.5) & (times < 14.0)
    # asked for 0 again: ArduSub's integrator wound up to IMAX while saturated and holds the turn
    # longer, by more than 1 deg/s for 3.5 s (ArduRover's, frozen at the limit, lets it go sooner)
    assert np.min(without_ff[after] - rover[after]) > math.radians(1.0)


def test_a_replay_that_starts_in_a_steady_turn_stays_in_it():
    """A segment may begin in the middle of a turn the vehicle was already holding: the replay starts
    in that steady turn, whatever the gains, instead of from the trim (which made weak feed-forward
    gains look 2.6 deg/s worse than they were)."""
    plant = RudderPlant(a22=-1.0, b2=0.5, delta0=0.01, rudder_max=0.5236)
    times = np.arange(0.0, 10.0, 0.05)
    held = np.full(times.size, 0.1)  # asked for the turn it is in
    for gains in ({"heading_rate_ff": 1.0, "heading_rate_p": 0.2, "heading_rate_i": 0.2},
                  {"heading_rate_ff": 3.8, "heading_rate_p": 0.5, "heading_rate_i": 0.5}):
        achieved = simulate_rate_tracking(plant, gains, times, held, 0.1)
        assert np.max(np.abs(achieved - 0.1)) < math.radians(0.2)


def test_verified_gains_stay_when_someone_else_later_sets_another_one(tmp_path):
    """Kept near 205 s; a ground station sets HDG_I at 240 s: their HDG_I stays, and so does the
    verified learned HDG_P, at the end of the session too."""
    link = _survey_link()
    link.next_telemetry = _with_change(link, at_s=240.0, native="HDG_I", value=0.05)
    _companion, store = _serve(link, tmp_path, 280.0)
    campaign, result = _learning_result(store)
    learned = next(w["gains"] for w in result["writes"] if w["why"] == "design")
    assert result["phase"] == "overridden" and campaign["status"] == "completed", campaign["reason"]
    assert link.param("heading_i") == pytest.approx(0.05)
    assert link.param("heading_p") == pytest.approx(learned["heading_p"])


def test_a_write_the_vehicle_refuses_ends_learning_and_the_loop_goes_on(tmp_path):
    link = _survey_link()
    link.refuse.add("HDG_I")  # the learned gains' write fails half-way (HDG_P went through)
    companion, store = _serve(link, tmp_path, 200.0)
    campaign, result = _learning_result(store)
    assert campaign["status"] == "failed" and "stopped" in campaign["reason"]
    assert link.param("heading_p") == pytest.approx(POOR["HDG_P"])  # put back by the restore point
    assert any(text.startswith("LEARN: stopped") for text in link.status_texts)
    assert companion.learning is None or companion.learning.learner is None  # the session ended, the loop did not


def test_a_session_that_learned_nothing_says_why_and_what_would_teach_it(tmp_path):
    """A vehicle holding one course (no course change to learn from): the session ends failed, with
    the windows skipped by reason and what to fly."""
    link = _survey_link(plan=SurveyPlan(thrusts=(0.7,), seconds_per_thrust=1e9, course_changes_deg=(0.0,)))
    _companion, store = _serve(link, tmp_path, 120.0)
    campaign, result = _learning_result(store)
    assert campaign["status"] == "failed" and result["writes"] == []
    assert campaign["reason"].startswith("no model validated from 5 windows (")
    assert "no course change" in campaign["reason"] and "companion identify" in campaign["reason"]


def test_the_verdict_comes_early_only_when_every_segment_alone_agrees_with_it():
    """From min_verify segments on, a unanimous record decides; one segment that alone would say
    otherwise makes the learner wait for the full count."""
    from behaviors.mission_learning import LearningConfig, MissionLearner
    from companion.numerics.mission_turns import RATE_ERROR

    def learner() -> MissionLearner:
        made = MissionLearner(lambda validated: None, {"heading_rate_ff": 0.5},
                              LearningConfig(verification="turn_rate", verify_segments=4, min_verify=2))
        made.phase, made.written = Phase.VERIFYING, {"heading_rate_ff": 2.0}
        return made

    def segment(t: float, error: float) -> TurnFigures:
        return TurnFigures(t_start=t, speed=2.0, size=10.0, gains="learned", error=error, predicted_error=3.0,
                           original_error=7.0, metric=RATE_ERROR)

    agreed = learner()
    agreed.turns = [segment(100.0, 3.1), segment(120.0, 2.9)]
    agreed._maybe_judge(140.0)
    assert agreed.phase is Phase.KEPT and agreed.verdict.turns_after == 2 and agreed.verdict_at_s == 140.0
    split = learner()
    split.turns = [segment(100.0, 3.1), segment(120.0, 8.0)]  # the second alone: worse than the original
    split._maybe_judge(140.0)
    assert split.phase is Phase.VERIFYING and split.verdict is None
    split.turns += [segment(140.0, 3.0)]
    split._maybe_judge(160.0)
    assert split.verdict is None  # still split, and short of the full count
    split.turns += [segment(160.0, 3.2)]
    split._maybe_judge(180.0)
    assert split.verdict is not None and split.verdict.turns_after == 4 and split.verdict_at_s == 180.0
    with pytest.raises(ValueError):
        LearningConfig(verify_segments=2, min_verify=3)


# ---------------------------------------------------------------------------- eq. L.3
def _slowing_turns(seconds: float = 60.0, dt: float = 0.05, u0: float = 2.0, a0: float = -0.8, b0: float = 0.6):
    """A hull whose a22 ∝ u and b2 ∝ u² (a rudder), slowing by 30 % in each of its turns (a rudder
    doublet each 20 s while the speed dips), integrated finely: (time, heading, rudder, speed, yaw rate)."""
    times = np.arange(0.0, seconds, dt)
    heading, rate = 0.0, 0.0
    out = []
    for t in times:
        phase = t % 20.0
        rudder = 0.25 if 4.0 <= phase < 8.0 else (-0.25 if 8.0 <= phase < 11.0 else 0.0)
        speed = u0 * (1.0 - 0.3 * math.sin(math.pi * min(max(phase - 3.0, 0.0), 10.0) / 10.0))
        out.append((t, heading, rudder, speed, rate))
        for _ in range(10):
            s = speed / u0
            rate += dt / 10 * (a0 * s * rate + b0 * s * s * rudder)
            heading += dt / 10 * rate
    return out


def test_rows_written_at_one_speed_recover_the_hull_of_a_boat_that_slows_in_its_turns():
    """eq. L.3: a window whose speed dips 30 % teaches the hull at the reference speed when its rows
    are normalised by the speed law, and the normalised model reproduces the window's heading; taken
    as they come (one model for the whole window) it is biased and fits worse."""
    from companion.numerics.parameter_tracking import normalised, validate_on

    estimator = PassiveYawEstimator(DriftConfig(), keep_records=True, speed_exponents=(1.0, 2.0))
    windows = [w for t, h, r, u, rate in _slowing_turns(120.0) if (w := estimator.add(t, h, r, u, rate)) is not None]
    window = windows[-1]
    assert window.speed_spread > 0.25
    config = TrackingConfig()
    rows = normalised(window, 2.0, config)
    assert rows.a22 == pytest.approx(-0.8, rel=0.05) and rows.b2 == pytest.approx(0.6, rel=0.05)
    raw_error = max(abs(window.a22 / -0.8 - 1.0), abs(window.b2 / 0.6 - 1.0))
    assert raw_error > 0.1  # one model for the whole window: biased by the dip
    from companion.numerics.identification import YawModel

    law = validate_on(YawModel(a22=rows.a22, b2=rows.b2, delta0=0.0), rows)
    constant = validate_on(YawModel(a22=window.a22, b2=window.b2, delta0=0.0), window)
    assert law > 0.99 and law > constant
    unchanged = normalised(window, 2.0, TrackingConfig(a22_speed_exponent=0.0, b2_speed_exponent=0.0))
    assert unchanged is window


def test_a_band_reports_its_model_at_the_speeds_its_windows_were_flown_by_the_speed_law():
    from companion.numerics.parameter_tracking import normalised

    windows = []
    for cruise in (2.0, 2.2):  # a faster leg after a slower one: the band spans both
        estimator = PassiveYawEstimator(DriftConfig(), keep_records=True, speed_exponents=(1.0, 2.0))
        windows += [w for t, h, r, u, rate in _slowing_turns(120.0, u0=cruise, a0=-0.8 * cruise / 2.0,
                                                             b0=0.6 * (cruise / 2.0) ** 2)
                    if (w := estimator.add(t, h, r, u, rate)) is not None]
    models = MissionModels(TrackingConfig())
    outcomes = [models.add(w) for w in windows]
    assert all(o.used for o in outcomes[1:]), [o.reason for o in outcomes]
    (band,) = models.bands
    validated = models.validated()
    assert len(validated) == 2 and validated[0][0] < validated[1][0]  # slowest and fastest window
    for speed, model in validated:
        ratio = speed / band.speed
        assert model.a22 == pytest.approx(-0.8 * speed / 2.0, rel=0.05)  # the hull's own law
        assert model.b2 == pytest.approx(0.6 * (speed / 2.0) ** 2, rel=0.05)
        assert model.a22 == pytest.approx(band.model().a22 * ratio, rel=1e-9)
        assert model.b2 == pytest.approx(band.model().b2 * ratio ** 2, rel=1e-9)
        assert model.c0 == pytest.approx(band.model().c0, abs=1e-12)
    assert normalised(windows[-1], band.speed, TrackingConfig()).record.a22_scale is not None


def test_the_scaled_simulation_is_the_plain_one_at_constant_speed():
    from companion.numerics.identification import YawModel
    from companion.numerics.validation import simulate_yaw, simulate_yaw_scaled

    times = np.arange(0.0, 10.0, 0.05)
    rudder = np.where((times > 2.0) & (times < 5.0), 0.2, -0.05)
    model = YawModel(a22=-0.7, b2=0.5, delta0=0.02)
    ones = np.ones_like(times)
    plain = simulate_yaw(model, times, rudder, 0.3, 0.01)
    assert simulate_yaw_scaled(model, times, rudder, 0.3, 0.01, ones, ones) == pytest.approx(plain, abs=1e-9)
    with pytest.raises(ValueError):
        simulate_yaw_scaled(model, times, rudder, 0.3, 0.01, ones[:-1], ones)


def test_a_thrusters_yaw_takes_windows_at_any_speed_and_only_it_does():
    """eq. L.3 with p = n = 0 (ArduSub's yaw is differential thrust, its authority independent of
    the speed): a window whose speed changed in a corner still teaches; a speed law that scales the
    rows keeps its bound on the spread."""
    assert TrackingConfig(a22_speed_exponent=0.0, b2_speed_exponent=0.0, speed_tolerance=math.inf).speed_tolerance == math.inf
    with pytest.raises(ValueError, match="speed_tolerance"):
        TrackingConfig(speed_tolerance=math.inf)  # Nomoto's a22 ∝ u and a rudder's b2 ∝ u²
    with pytest.raises(ValueError, match="speed_tolerance"):
        TrackingConfig(a22_speed_exponent=0.0, b2_speed_exponent=0.0, speed_tolerance=1.5)


def test_turn_rate_learned_gains_that_hold_the_legs_worse_are_not_kept():
    """eq. L.2h: a verdict the turns would give is held back until a leg is flown on the learned
    gains, and refused when the legs' tracking grew beyond 1.5× and 0.2 deg/s of the original's."""
    config = VerdictConfig()
    assert config.holding_worse([0.28, 0.30], [0.68, 0.67]) is not None  # SITL's ArduSub ROV, measured
    assert "worse on the legs" in config.holding_worse([0.28], [0.68])
    assert config.holding_worse([0.28, 0.30], [0.40]) is None  # within 0.2 deg/s
    assert config.holding_worse([2.0], [2.9]) is None  # within 1.5×
    assert config.holding_worse([], [5.0]) is None and config.holding_worse([0.3], []) is None
    recorder = RateSegmentRecorder(window_s=20.0, min_rate_deg_s=2.0)
    times = np.arange(0.0, 41.0, 0.04)
    for t in times:  # a leg: asks for no turn, the rate loop wanders by 0.5 deg/s
        recorder.add(float(t), 0.0, math.radians(0.5) * math.sin(t), 2.0)
    assert len(recorder.straights) == 2 and recorder.straights[0][1] == pytest.approx(0.5 / math.sqrt(2), rel=0.05)


@pytest.mark.parametrize("wobble_deg_s, kept", [(0.1, True), (1.0, False)])
def test_a_turn_rate_verdict_waits_for_a_leg_and_refuses_gains_that_hold_it_worse(wobble_deg_s, kept):
    """eq. L.2h in the learner: a mission of 40 s turning and 40 s legs; the learned gains track the
    turns better (as predicted) and wobble on the legs by ``wobble_deg_s`` where the original gains
    wobbled by 0.1 deg/s: kept when they hold the legs as well, reverted when they do not."""
    from behaviors.mission_learning import DesignOutcome, LearningConfig, MissionLearner

    learner = MissionLearner(lambda validated: DesignOutcome(_RateDesign(), "synthetic"), {"heading_rate_ff": 0.5},
                             LearningConfig(verification="turn_rate", verify_segments=2))
    now = [0.0]
    learner.models.validated = lambda: [(2.0, None)] if now[0] > 60.0 else []
    written = []
    for k in range(20 * 900):
        t = now[0] = 0.05 * k
        leg = (t // 40.0) % 2 == 1
        desired = 0.0 if leg else math.radians(6.0) * math.sin(0.4 * t)
        quality = 0.93 if written else 0.7
        wobble = math.radians(wobble_deg_s if written else 0.1) * math.sin(3.0 * t)
        achieved = wobble if leg else quality * desired
        telemetry = Telemetry(time_s=t, yaw=0.0, yaw_rate=0.0, speed_water=2.0, rudder=0.0,
                              turn_rate_target=desired, turn_rate_achieved=achieved, mode="auto", armed=True)
        for command in learner.tick(telemetry):
            if type(command).__name__ == "SetParameters":
                written.append((t, command.values))
    assert written
    if kept:
        assert learner.phase is Phase.KEPT, learner.note
    else:
        assert learner.phase in (Phase.WAITING_TO_REVERT, Phase.REVERTED), learner.note
        assert "worse on the legs" in learner.verdict.reason
        assert learner.verdict.after_error < learner.verdict.before_error  # the turns alone would have kept them
