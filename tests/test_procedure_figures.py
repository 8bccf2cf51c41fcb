"""A procedure's figures are a typed record: the campaign's, roll stabilisation's, minimum-speed
seeking's and the steady-state manoeuvres'. Each refuses what breaks its invariant where it is made,
is read by attribute, and gives its JSON (strict: NaN and infinities null) only through ``to_dict``,
which the stored row and the printed JSON begin with (docs/store.md, "Procedure figures")."""
from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from behaviors.base import Status
from behaviors.min_speed_result import MinSpeedResult
from behaviors.observe import ObserveResult
from behaviors.roll_kick import RollKickResult
from behaviors.roll_stabilisation import RollStabilisationResult
from behaviors.steady_state import SquareConfig, SquaresResult, TurnConfig, TurnsResult
from companion.numerics.roll import RollPIGains
from companion.procedures.campaign import CampaignConfig, IdentificationCampaign
from companion.procedures.campaign_figures import CampaignFigures, LoopOutcome, ThrustLevels
from companion.procedures.min_speed import AnalyticMinimum, MinSpeedFigures
from companion.procedures.results import NO_FIGURES, ProcedureResult
from companion.procedures.roll import RollFigures
from companion.procedures.runner import RestorePoint, run_procedure
from companion.procedures.steady_state import DecimatedPath, SteadyStateFigures
from harness.inprocess import InProcessLink


def strict_json(figures) -> dict:
    """The figures' JSON, refused if it holds NaN or an infinity."""
    return json.loads(json.dumps(figures.to_dict(), allow_nan=False))


def observed(roll: list[float]) -> ObserveResult:
    times = [0.1 * i for i in range(len(roll))]
    return ObserveResult("open loop", 1.0, False, {"time": times, "roll": roll, "mass_angle": [0.0] * len(roll),
                                                   "speed_water": [1.4] * (len(roll) - 1) + [math.nan]})


def stabilised(std: float) -> RollStabilisationResult:
    series = {"time": [0.0, 0.1], "roll": [0.01, math.nan], "mass_command": [0.0, 0.0], "mass_angle": [0.0, 0.0]}
    return RollStabilisationResult(False, "", 2, 0.1, std, 0.0, 0.0, 0.0, RollPIGains(kp=-1.0), series)


def roll_figures(**overrides) -> RollFigures:
    kicks = (RollKickResult("roll kick open loop", Status.SUCCESS, 3.0, None),
             RollKickResult("roll kick closed loop", Status.SUCCESS, 3.0, 4.0))
    return RollFigures(**({"thrust": 0.7, "simulator": True, "disturbance_nm": 0.05,
                           "open_loop": observed([0.02, -0.01, math.nan, 0.03]), "closed_loop": stabilised(math.nan),
                           "kick_deg": 25.0, "kicks": kicks} | overrides))


def seeker(**overrides) -> MinSpeedResult:
    fields = {"aborted": False, "abort_reason": "", "thrust_ratio_final": 0.44, "speed_final": 0.9,
              "settle_time_s": None, "max_depth_error_m": math.nan, "max_depth_error_settled_m": None,
              "depth_setpoint_m": 2.0, "reversals_last_30s": 1, "decisions": 12, "theta_e_crossover": 0.01,
              "start_reached_s": math.inf, "governed_stalled": False, "depth_offset_max_m": 0.1,
              "depth_offset_faded_s": None, "duration_s": 200.0,
              "series": {"time": [0.0, 1.0], "thrust_ratio": [0.45, math.nan]}}
    return MinSpeedResult(**(fields | overrides))


def flown_campaign() -> IdentificationCampaign:
    """A short campaign flown in process: two thrusts, yaw, its design verified by two steps."""
    link = InProcessLink(seed=4)
    campaign = IdentificationCampaign(CampaignConfig(thrusts=(0.7, 1.0), axes=("yaw",)).quick())
    campaign.original_gains = dict(RestorePoint.capture(link, campaign.footprint).parameters)
    outcome = run_procedure(link, campaign)
    assert outcome.status == "completed", outcome.reason
    return campaign


# ---------------------------------------------------------------------------------------------- the campaign
def test_the_campaigns_figures_are_its_typed_records_and_their_json_is_strict():
    campaign = flown_campaign()
    result = campaign.result()
    figures = result.figures
    assert isinstance(figures, CampaignFigures)
    assert figures.accepted == tuple(campaign.accepted) and all(a.accepted for a in figures.accepted)
    assert figures.speed_loop is None and figures.verified is not None and figures.verified.flown
    assert figures.loops["heading"].outcome == "written" and figures.final_gains == campaign.final_gains
    assert figures.thrust_levels == ThrustLevels((0.7, 1.0), ())
    stored = strict_json(figures)
    assert list(stored) == ["config", "manoeuvres", "accepted", "design", "design_errors", "verification", "steps",
                            "checks", "verified", "vehicle_time_by_phase", "final_gains", "speed_loop",
                            "heading_design", "loops", "thrust_levels"]
    assert stored["design"] == campaign.design_summary() and stored["loops"]["heading"]["outcome"] == "written"
    assert stored["thrust_levels"] == {"flown": [0.7, 1.0], "respacing": []}
    assert all("attempts" not in m for m in stored["manoeuvres"]) and all("series" not in s for s in stored["steps"])
    # the procedure's own JSON: the figures, then what the runner saw
    assert list(result.to_json())[:len(stored)] == list(stored)
    assert list(result.to_json())[len(stored):] == ["status", "pilot_has_it", "restore_problems"]


def test_a_campaigns_figures_refuse_a_rejected_attempt_an_unknown_check_or_loop():
    figures = flown_campaign().result().figures
    with pytest.raises(ValueError, match="accepted attempts only"):
        replace(figures, accepted=(replace(figures.accepted[0], accepted=False),))
    with pytest.raises(ValueError, match="checks"):
        replace(figures, checks="sometimes")
    with pytest.raises(ValueError, match="by loop"):
        replace(figures, loops={"pitch": LoopOutcome("written", "")})
    with pytest.raises(ValueError, match="seconds"):
        replace(figures, vehicle_time_by_phase={"settle": -1.0})
    with pytest.raises(ValueError, match="outcome"):
        LoopOutcome("kept somehow", "")
    with pytest.raises(ValueError, match="thrust levels"):
        ThrustLevels((0.7, 1.5))


# ---------------------------------------------------------------------------------------------- roll
def test_the_roll_figures_json_is_strict_and_in_the_stored_order():
    figures = roll_figures()
    stored = strict_json(figures)
    assert list(stored) == ["behavior", "thrust", "simulator", "disturbance_nm", "std_open_deg", "std_closed_deg",
                            "speed", "open_series", "closed_series", "gains", "kick_deg", "kick_settle_open_s",
                            "kick_settle_closed_s"]
    assert stored["std_closed_deg"] is None and stored["open_series"]["roll"][2] is None
    assert stored["std_open_deg"] == pytest.approx(figures.std_open_deg) and figures.speed == pytest.approx(1.4)
    assert (figures.kick_settle_open_s, figures.kick_settle_closed_s) == (None, 4.0)
    bare = RollFigures(0.7, False)  # on a vehicle, the closed loop not completed, no impulse tests
    assert strict_json(bare) == {"behavior": "roll", "thrust": 0.7, "simulator": False}
    assert bare.std_open_deg is None and bare.speed is None


def test_roll_figures_refuse_half_a_comparison_a_moment_off_the_simulator_and_one_kick():
    with pytest.raises(ValueError, match="open loop and the closed loop"):
        roll_figures(closed_loop=None)
    with pytest.raises(ValueError, match="simulator"):
        roll_figures(simulator=False)
    with pytest.raises(ValueError, match="impulse tests"):
        roll_figures(kicks=roll_figures().kicks[:1])
    with pytest.raises(ValueError, match="impulse tests"):
        roll_figures(kick_deg=None)
    with pytest.raises(ValueError, match="thrust"):
        roll_figures(thrust=1.5)
    with pytest.raises(ValueError, match="speed_water"):
        roll_figures(open_loop=ObserveResult("open loop", 1.0, False, {"time": [0.0], "roll": [0.0]}))


# ---------------------------------------------------------------------------------------------- minimum speed
def test_the_minimum_speed_figures_json_is_the_seekers_without_its_reason_then_the_analytic_point():
    figures = MinSpeedFigures(seeker(), "autopilot", AnalyticMinimum(0.432, 0.86, 2.5))
    stored = strict_json(figures)
    assert list(stored) == [k for k in seeker().to_dict() if k != "abort_reason"] + [
        "depth_gains_source", "thrust_ratio_star", "v_min", "theta_star_deg"]
    assert stored["max_depth_error_m"] is None and stored["start_reached_s"] is None
    assert stored["thrust_ratio_star"] == 0.432 and figures.seeker is not None
    unknown = MinSpeedFigures(None, "Table 5.1 (autopilot's not readable)")
    assert strict_json(unknown) == {"depth_gains_source": "Table 5.1 (autopilot's not readable)"}
    assert AnalyticMinimum.of({"thrust_ratio_star": None, "v_min": 0.9}) == AnalyticMinimum(None, 0.9, None)


def test_minimum_speed_figures_refuse_an_unknown_gain_source_and_an_impossible_operating_point():
    with pytest.raises(ValueError, match="depth_gains_source"):
        MinSpeedFigures(seeker(), "guessed")
    with pytest.raises(ValueError, match="thrust_ratio_star"):
        AnalyticMinimum(1.4, 0.9, 2.0)
    with pytest.raises(ValueError, match="v_min"):
        AnalyticMinimum(0.4, -0.9, 2.0)
    with pytest.raises(ValueError, match="theta_star_deg"):
        AnalyticMinimum(0.4, 0.9, math.nan)


# ---------------------------------------------------------------------------------------------- steady state
def test_the_steady_state_figures_json_holds_each_part_with_its_paths_once_started():
    path = DecimatedPath.of({"t": np.array([0.0, 0.4, 1.1, 2.0]), "north": np.array([0.0, 1.0, math.nan, 3.0]),
                             "east": np.zeros(4)}, 1.0)
    assert path.t == (0.0, 1.1, 2.0) and math.isnan(path.north[1])
    squares = SquaresResult("failed", SquareConfig(), 12, None, None, "no steady leg")
    turns = TurnsResult("running", TurnConfig())
    figures = SteadyStateFigures(squares, path, turns, (path,))
    stored = strict_json(figures)
    assert list(stored) == ["behavior", "squares", "turns"]
    assert list(stored["squares"]) == list(squares.to_dict()) + ["path"]
    assert list(stored["turns"]) == list(turns.to_dict()) + ["paths"]
    assert stored["squares"]["path"] == {"t": [0.0, 1.1, 2.0], "north": [0.0, None, 3.0], "east": [0.0, 0.0, 0.0]}
    assert strict_json(SteadyStateFigures()) == {"behavior": "steady_state"}
    empty = DecimatedPath.of({"t": np.array([]), "north": np.array([]), "east": np.array([])}, 1.0)
    assert empty.to_dict() == {"t": [], "north": [], "east": []}


def test_steady_state_figures_refuse_a_part_without_its_path_and_a_path_of_unequal_lengths():
    squares = SquaresResult("failed", SquareConfig(), 12, None, None, "no steady leg")
    path = DecimatedPath((0.0,), (1.0,), (2.0,))
    with pytest.raises(ValueError, match="squares with their path"):
        SteadyStateFigures(squares, None)
    with pytest.raises(ValueError, match="without the turns"):
        SteadyStateFigures(turn_paths=(path,))
    with pytest.raises(ValueError, match="one north and one east"):
        DecimatedPath((0.0, 1.0), (1.0,), (2.0, 3.0))


# ---------------------------------------------------------------------------------------------- the result
def test_a_procedure_result_holds_typed_figures_never_a_dict():
    assert ProcedureResult("roll", "refused", "no rolling mass").to_json() == {
        "status": "refused", "abort_reason": "no rolling mass", "pilot_has_it": False, "restore_problems": []}
    assert ProcedureResult("roll", "not started").figures is NO_FIGURES
    with pytest.raises(ValueError, match="ProcedureFigures"):
        ProcedureResult("roll", "completed", None, {"std_open_deg": 1.5})
    result = ProcedureResult.of("roll", Status.SUCCESS, "ignored", roll_figures())
    assert result.to_json()["kick_settle_closed_s"] == 4.0 and result.figures.kick_deg == 25.0
    json.dumps(result.to_dict(), allow_nan=False)
