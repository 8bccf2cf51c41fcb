"""End to end: ``companion rehearse`` runs the simulator as a child process and the whole product over
MAVLink on loopback, sped up (the goal: "companion rehearse on a fresh clone produces the report and
the JSON summary"). A reduced campaign (two thrusts, yaw, no step checks) keeps it short."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

from companion.numerics.gains import CAMPAIGN_DAMPING
from companion.records.store import Store

# one worker runs the module: its rehearsal (about 14 s) is made once, not once per worker that a test
# of it lands on; session-scoped, because the worker may run other modules' tests between this one's,
# and a module fixture would be made again after each (three times, measured)
pytestmark = [pytest.mark.e2e, pytest.mark.xdist_group("e2e-rehearse")]


@pytest.fixture(scope="session")
def rehearsal(tmp_path_factory):
    out = tmp_path_factory.mktemp("rehearsal")
    command = [sys.executable, "-m", "companion", "rehearse", "--out", str(out), "--thrusts", "0.7,1.0",
               "--axes", "yaw", "--no-steps", "--behaviors", "roll,min-speed", "--speedup", "100", "--seed", "4", "--json"]
    done = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    return out, json.loads(done.stdout)


def test_summary_has_one_run_per_accepted_thrust_close_to_the_truth(rehearsal):
    _, summary = rehearsal
    assert summary["status"] == "completed"
    runs = summary["runs"]
    assert [r["thrust"] for r in runs] == [0.7, 1.0]
    for run in runs:
        assert set(run) >= {"thrust", "speed", "a22", "b2", "delta0", "r2", "converged_s", "true_a22", "true_b2",
                            "true_delta0", "kp", "ki"}
        assert run["a22"] == pytest.approx(run["true_a22"], rel=0.08)
        assert run["b2"] == pytest.approx(run["true_b2"], rel=0.08)
        assert run["r2"] >= 0.9
        # the default (quick) procedure designs the pair at ζ = 0.75: eq. 3.57 with the damping margin
        zeta = CAMPAIGN_DAMPING
        assert run["kp"] == pytest.approx(run["a22"] ** 2 / (4 * zeta * zeta * run["b2"]), rel=1e-6)
    assert summary["wall_time_s"] > 0


def test_behaviours_ran_over_mavlink(rehearsal):
    _, summary = rehearsal
    roll, seek = summary["roll"], summary["min_speed"]
    assert roll["status"] == "completed" and roll["std_closed_deg"] < roll["std_open_deg"]
    assert seek["status"] == "completed" and summary["status"] == summary["campaign_status"] == "completed"
    # settled (the status says so) within a minute of seeking, within 2 % of TR* ≈ 0.432, depth held
    assert seek["settle_time_s"] is not None and seek["settle_time_s"] <= 60.0
    assert seek["thrust_ratio_star"] == pytest.approx(0.432, abs=0.002)
    assert seek["thrust_ratio_star"] <= seek["thrust_ratio_final"] <= 1.02 * seek["thrust_ratio_star"]
    assert seek["max_depth_error_m"] <= 0.3


def test_a_behaviour_that_missed_its_goal_fails_the_rehearsal():
    """A seeker that did not settle has not found the minimum speed: the rehearsal says failed, with its
    reason, and keeps the campaign's own outcome."""
    from companion.rehearsal.rehearsal import _behaviours_decide

    summary = {"status": "completed", "roll": {"status": "completed"},
               "min_speed": {"status": "failed", "reason": "not settled in 200 s of seeking"}}
    _behaviours_decide(summary, ("roll", "min_speed"))
    assert summary["status"] == "failed" and summary["campaign_status"] == "completed"
    assert summary["reason"] == "min-speed: not settled in 200 s of seeking"
    fine = {"status": "completed", "roll": {"status": "completed"}, "min_speed": {"status": "completed"}}
    _behaviours_decide(fine, ("roll", "min_speed"))
    assert fine["status"] == "completed" and "reason" not in fine


def test_report_and_store_are_written(rehearsal):
    out, summary = rehearsal
    report = (out / "report.html").read_text()
    for image in ("convergence.png", "validation.png", "b2_law.png", "turning.png", "roll.png", "min_speed.png"):
        assert image in report and (out / image).stat().st_size > 5000, image
    with Store(summary["store"]) as store:
        campaigns = store.campaigns()
        assert campaigns[0]["status"] == "completed"
        assert len(store.models(campaigns[0]["id"], axis="yaw")) == 2
        # --no-steps: the gains were designed but never checked, so none was written
        assert not store.gains(campaigns[0]["id"]) and summary["final_gains"] is None
        kinds = {b["kind"] for b in store.behavior_results()}
        assert {"roll", "min_speed", "gain_design"} <= kinds


#: what the runner adds to a procedure's stored row after its figures (``ProcedureResult.to_json``)
RUNNER_KEYS = ["status", "pilot_has_it", "restore_problems"]


def test_the_stored_procedure_rows_keep_their_keys_in_order(rehearsal):
    """The roll and minimum-speed rows hold each procedure's figures (its typed record's JSON), then
    what the runner saw: key for key the rows stored before the figures had a type."""
    out, summary = rehearsal
    with Store(summary["store"]) as store:
        rows = {b["kind"]: b["result"] for b in store.behavior_results()}
    assert list(rows["roll"]) == ["behavior", "thrust", "simulator", "disturbance_nm", "std_open_deg", "std_closed_deg",
                                  "speed", "open_series", "closed_series", "gains", "kick_deg", "kick_settle_open_s",
                                  "kick_settle_closed_s"] + RUNNER_KEYS
    assert list(rows["roll"]["open_series"]) == list(rows["roll"]["closed_series"]) == ["time", "roll", "mass_angle"]
    assert list(rows["min_speed"]) == ["behavior", "aborted", "thrust_ratio_final", "speed_final", "settle_time_s",
                                       "max_depth_error_m", "max_depth_error_settled_m", "depth_setpoint_m",
                                       "reversals_last_30s", "decisions", "theta_e_crossover", "start_reached_s",
                                       "governed_stalled", "depth_offset_max_m", "depth_offset_faded_s", "duration_s",
                                       "series", "depth_gains_source", "thrust_ratio_star", "v_min",
                                       "theta_star_deg"] + RUNNER_KEYS
    assert list(summary["thrust_levels"]) == ["flown", "respacing"] and summary["thrust_levels"]["flown"] == [0.7, 1.0]


@pytest.mark.slow
def test_hugin_rehearsal_recovers_the_current_from_squares_and_turns(tmp_path):
    """The steady-state manoeuvres inside the rehearsal on the HUGIN-like preset, scored
    against the known current the simulator was started with (14 mm/s towards 300°)."""
    command = [sys.executable, "-m", "companion", "rehearse", "--preset", "hugin", "--out", str(tmp_path),
               "--thrusts", "0.8", "--axes", "yaw", "--no-steps", "--seed", "2", "--speedup", "100", "--json"]
    done = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    steady = json.loads(done.stdout)["steady_state"]
    assert steady["status"] == "completed"
    squares = steady["squares"]
    assert squares["current_error_mm_s"] < 3.0
    assert squares["condition_number"] < 1.5
    assert abs(squares["sway_water"]) < 0.03 and 1.3 < squares["surge_water"] < 2.0
    assert len(steady["turns"]) == 2
    for turn in steady["turns"]:
        assert turn["current_error_mm_s"] < 3.0
        assert 14.0 < turn["radius_m"] < 18.0 and 4.0 < abs(turn["turn_rate_deg_s"]) < 6.0
        assert turn["residual_std_m"] < 0.15
    assert "steady_state.png" in (tmp_path / "report.html").read_text()
    # the stored row: the figures (squares and turns, each with its decimated paths), then the runner's keys
    with Store(str(tmp_path / "store.sqlite")) as store:
        row = next(b["result"] for b in store.behavior_results() if b["kind"] == "steady_state")
    assert list(row) == ["behavior", "squares", "turns"] + RUNNER_KEYS
    assert list(row["squares"]) == ["behavior", "status", "config", "samples", "surge_water", "sway_water",
                                    "heave_water", "sideslip_deg", "current_north", "current_east", "current_speed",
                                    "current_dir_deg", "sigma", "condition_number", "residual_std", "samples_used",
                                    "path"]
    assert list(row["squares"]["path"]) == ["t", "north", "east"]
    assert list(row["turns"]) == ["behavior", "status", "config", "turns", "current_north", "current_east", "paths"]
    assert len(row["turns"]["paths"]) == 2 and all(list(p) == ["t", "north", "east"] for p in row["turns"]["paths"])
