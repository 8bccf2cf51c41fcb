"""Roll stabilisation and minimum-speed seeking as procedures of the application (SPEC C6, C7).

Each procedure is a short sequence of runs of pure behaviours over the link (each run restores the
vehicle on abort), followed by one store record. On the simulator (``simulator=True``) the
procedures also use its test hooks — a random roll moment (``SIM_ROLL_DIST``) and a roll "impulse"
(``SIM_ROLL_KICK``) — to reproduce the seeds' experiments; on a vehicle they only observe and act.

Figures (issue 4): roll standard deviation open vs closed loop at cruise (seed: 1.02° → 0.39° at
1.4 m/s), the settling time of a 25° roll impulse, and for the seeker the final thrust ratio and
speed against the analytic TR* and Vmin (eq. 5.28–5.54).
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace

import numpy as np

from behaviors.min_speed import MinSpeedConfig, MinSpeedSeeking
from behaviors.observe import Observe
from behaviors.roll_stabilisation import RollStabilisation, RollStabilisationConfig
from behaviors.sequence import Instant, SequenceBehavior
from companion.procedures.app import AbortFlag, finite_or_none
from companion.interface import SetMode, SetRollingMass, SetThrust
from companion.numerics.roll import settle_time
from companion.procedures.runner import RestorePoint, RunOutcome, SafetyLimits, run_behavior
from companion.records.store import Store

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RollProcedureConfig:
    thrust: float = 0.70  # ≈ 1.4 m/s on STARFISH, the seed's condition
    settle_s: float = 20.0
    open_s: float = 60.0
    closed_s: float = 60.0
    disturbance_nm: float = 0.05  # SIM_ROLL_DIST on the simulator
    kick_deg: float = 25.0  # SIM_ROLL_KICK on the simulator; 0 skips the impulse tests
    kick_record_s: float = 15.0
    settle_band_deg: float = 2.5


@dataclass(frozen=True)
class MinSpeedProcedureConfig:
    nominal_thrust: float = 0.70
    # steady running at the nominal thrust before seeking, as in the thesis (Fig. 5.22: seeking
    # starts at 100 s): the depth and pitch integrators must hold the trim before the first decision
    settle_s: float = 100.0
    duration_s: float = 200.0
    period_s: float | None = None  # None: the seeker's default Ts


class ProcedureAborted(Exception):
    def __init__(self, outcome: RunOutcome) -> None:
        super().__init__(outcome.reason)
        self.outcome = outcome


def _run(link, behavior, abort: AbortFlag, limits: SafetyLimits, *, skip_backlog: bool = True):
    """One stage of a procedure; the procedure's own restore point (taken before its first stage)
    puts the vehicle back afterwards, so a stage only releases what it holds on abort."""
    outcome = run_behavior(link, behavior, limits=limits, abort_requested=abort, skip_backlog=skip_backlog)
    if outcome.status != "completed":
        raise ProcedureAborted(outcome)
    return behavior


def _finish(link, result: dict, restore: RestorePoint, cleanup, *, pilot_has_it: bool = False) -> None:
    """Clean-up of the procedure's own changes, then the restore point: mode, gains, overrides
    (not the mode when the pilot took the vehicle: the companion never switches away from them)."""
    for action in cleanup:
        _quietly(*action)
    result["restore_problems"] = restore.restore(link, mode=not pilot_has_it)


def _kick(link, degrees: float) -> None:
    link.set_param("SIM_ROLL_KICK", degrees)


def roll_procedure(link, abort: AbortFlag, config: RollProcedureConfig = RollProcedureConfig(), *,
                   simulator: bool = False, limits: SafetyLimits = SafetyLimits()) -> dict:
    """Open loop, closed loop (and on the simulator: 25° impulses both ways). Returns the result;
    the vehicle is left as found (mode, gains, mass centred) whatever happens."""
    result: dict = {"behavior": "roll", "thrust": config.thrust, "simulator": simulator}
    restore = RestorePoint.capture(link)
    try:
        if simulator:
            link.set_param("SIM_ROLL_DIST", config.disturbance_nm)
            result["disturbance_nm"] = config.disturbance_nm
        prepare = SequenceBehavior([Instant(SetMode("hold"), SetThrust(config.thrust), SetRollingMass(0.0)),
                                    Observe(config.settle_s, label="settle")])
        _run(link, prepare, abort, limits)
        open_loop = _run(link, Observe(config.open_s, ("roll", "mass_angle", "speed_water"), label="open loop"), abort, limits)
        closed = _run(link, RollStabilisation(RollStabilisationConfig(duration_s=config.closed_s)), abort, limits)
        closed_result = closed.result()
        speeds = [v for v in open_loop.series["speed_water"] if math.isfinite(v)]
        result.update(std_open_deg=open_loop.std_deg("roll"), std_closed_deg=closed_result["roll_std_deg"],
                      speed=float(np.mean(speeds)) if speeds else None,
                      open_series={k: open_loop.series[k] for k in ("time", "roll", "mass_angle")},
                      closed_series={"time": closed_result["series"]["time"], "roll": closed_result["series"]["roll"],
                                     "mass_angle": closed_result["series"]["mass_angle"]},
                      gains=closed_result["gains"])
        if simulator and config.kick_deg:
            link.set_param("SIM_ROLL_DIST", 0.0)
            result["kick_deg"] = config.kick_deg
            result["kick_settle_open_s"] = _kick_settle(link, abort, limits, config, closed_loop=False)
            result["kick_settle_closed_s"] = _kick_settle(link, abort, limits, config, closed_loop=True)
        result["status"] = "completed"
    except ProcedureAborted as exc:
        result.update(status="aborted", abort_reason=exc.outcome.reason, pilot_has_it=exc.outcome.pilot_has_it)
    except Exception as exc:  # noqa: BLE001 - a refused hook or lost link: keep what was measured
        log.exception("roll procedure failed")
        result.update(status="failed", abort_reason=f"{type(exc).__name__}: {exc}")
    finally:
        cleanup = [(link.execute, [SetRollingMass(0.0)])]
        if simulator:
            cleanup.insert(0, (link.set_param, "SIM_ROLL_DIST", 0.0))
        _finish(link, result, restore, cleanup, pilot_has_it=result.get("pilot_has_it", False))
    return result


def _kick_settle(link, abort, limits, config: RollProcedureConfig, *, closed_loop: bool) -> float | None:
    """Settling time (s) of the roll after a SIM_ROLL_KICK, within ±band of the level before it,
    timed from the kick: the vehicle time at which its parameter echo arrived (the simulator applies
    it on receipt), keeping the samples queued while the link waited for that echo."""
    before = _run(link, Observe(5.0, ("roll",), commands=[SetRollingMass(0.0)], label="before kick"), abort, limits)
    level = float(np.nanmean(before.series["roll"]))
    _kick(link, config.kick_deg)
    kicked_at = link.vehicle_time_s
    behavior = (RollStabilisation(RollStabilisationConfig(duration_s=config.kick_record_s)) if closed_loop
                else Observe(config.kick_record_s, ("roll",), label="kick open loop"))
    _run(link, behavior, abort, limits, skip_backlog=False)
    series = behavior.series
    times = np.asarray(series["time"], dtype=float)
    if closed_loop:  # the controller's series is timed from its own start
        times = times + (behavior.start_time_s or 0.0)
    roll = np.asarray(series["roll"], dtype=float) - level
    after = times >= kicked_at
    if after.sum() < 2:
        return None
    value = settle_time(times[after] - kicked_at, roll[after], band=math.radians(config.settle_band_deg))
    return finite_or_none(value)


def min_speed_procedure(link, abort: AbortFlag, config: MinSpeedProcedureConfig = MinSpeedProcedureConfig(), *,
                        analytic: dict | None = None, limits: SafetyLimits = SafetyLimits()) -> dict:
    """Settle at the nominal thrust in the holding mode, then seek for ``duration_s``; the vehicle
    is left as found (mode, gains; thrust back to nominal on abort) whatever happens."""
    seeker_config = MinSpeedConfig(nominal_thrust=config.nominal_thrust, duration_s=config.duration_s)
    gains_source = "autopilot"
    try:  # the seeker re-computes the autopilot's desired pitch with its depth-loop gains
        gains = link.get_params(["depth_p", "depth_i", "pitch_max"])
        seeker_config = replace(seeker_config, depth_p=gains["depth_p"], depth_i=gains["depth_i"],
                                pitch_max=gains["pitch_max"])
    except Exception as exc:  # noqa: BLE001 - e.g. a profile without these names: Table 5.1's gains
        gains_source = "Table 5.1 (autopilot's not readable)"
        log.warning("depth-loop gains not readable (%s): the seeker assumes Table 5.1's", exc)
    if config.period_s is not None:
        seeker_config = replace(seeker_config, seeker=replace(seeker_config.seeker, period_s=config.period_s))
    restore = RestorePoint.capture(link)
    try:
        _run(link, SequenceBehavior([Instant(SetMode("hold"), SetThrust(config.nominal_thrust)),
                                     Observe(config.settle_s, label="settle")]), abort, limits)
        seeker = _run(link, MinSpeedSeeking(seeker_config), abort, limits)
        result = seeker.result()
        result["status"] = "completed"
    except ProcedureAborted as exc:
        result = {**exc.outcome.result, "status": "aborted", "abort_reason": exc.outcome.reason,
                  "pilot_has_it": exc.outcome.pilot_has_it}
    except Exception as exc:  # noqa: BLE001 - keep the procedure's outcome, restore below
        log.exception("minimum-speed procedure failed")
        result = {"status": "failed", "abort_reason": f"{type(exc).__name__}: {exc}"}
    _finish(link, result, restore, [], pilot_has_it=result.get("pilot_has_it", False))
    result["depth_gains_source"] = gains_source
    if analytic:
        result.update(thrust_ratio_star=analytic.get("thrust_ratio_star"), v_min=analytic.get("v_min"),
                      theta_star_deg=analytic.get("theta_star_deg"))
    return result


def analytic_minimum_speed(preset: str | None) -> dict | None:
    """Eq. 5.28–5.54 for a simulator preset's vehicle data (read as data, never imported)."""
    if not preset:
        return None
    from companion.cli.commands.minspeed import load_vehicle
    from companion.numerics.minspeed import minimum_speed

    try:
        vehicle, _ = load_vehicle(preset, None)
    except (OSError, ValueError, KeyError) as exc:
        log.warning("no analytic minimum speed for %r: %s", preset, exc)
        return None
    return minimum_speed(vehicle).as_json()


def roll_summary(result: dict) -> dict:
    return {key: finite_or_none(result.get(key)) for key in
            ("std_open_deg", "std_closed_deg", "speed", "kick_settle_open_s", "kick_settle_closed_s")} | \
        {"status": result.get("status")}


def min_speed_summary(result: dict) -> dict:
    return {key: finite_or_none(result.get(key)) for key in
            ("thrust_ratio_final", "thrust_ratio_star", "speed_final", "v_min", "settle_time_s",
             "max_depth_error_m", "max_depth_error_settled_m")} | {"status": result.get("status")}


def run_named_behavior(name: str, link, store: Store, *, vehicle_id: int, campaign_id: int | None,
                       abort: AbortFlag, preset: str | None = None, simulator: bool = True,
                       roll_config: RollProcedureConfig = RollProcedureConfig(),
                       min_speed_config: MinSpeedProcedureConfig = MinSpeedProcedureConfig()) -> dict | None:
    """Run ``roll`` or ``min_speed``, store the result, return {"result", "summary"}."""
    if name not in ("roll", "min_speed"):
        raise ValueError(f"unknown behaviour {name!r} (roll, min_speed)")
    own = campaign_id is None
    if own:
        campaign_id = store.start_campaign(vehicle_id, name, {"preset": preset})
    result: dict = {"status": "failed", "abort_reason": "not started"}
    try:
        if name == "roll":
            result = roll_procedure(link, abort, roll_config, simulator=simulator)
        else:
            result = min_speed_procedure(link, abort, min_speed_config, analytic=analytic_minimum_speed(preset))
        store.add_behavior_result(campaign_id, name, result["status"], result)
    finally:
        if own:
            store.finish_campaign(campaign_id, result["status"], result.get("abort_reason"))
    summary = roll_summary(result) if name == "roll" else min_speed_summary(result)
    return {"result": result, "summary": summary}


def _quietly(fn, *args) -> None:
    try:
        fn(*args)
    except Exception as exc:  # noqa: BLE001 - clean-up after a procedure must not mask its outcome
        log.warning("clean-up %s failed: %s", getattr(fn, "__name__", fn), exc)
