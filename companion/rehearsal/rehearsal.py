"""The self-contained rehearsal: simulator + companion + report (the README's first command).

The simulator runs as a child process (``python -m sim run``) and is reached only over MAVLink on
loopback; its linearised "truth" comes from another child process (``python -m sim linearize``).
The companion never imports the simulator (SPEC §5).
"""
from __future__ import annotations

import json
import logging
import math
import subprocess
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path

from companion.rehearsal.launcher import SimulatorError, SimulatorProcess  # noqa: F401 - re-exported
from companion.rehearsal.reproducibility import reproducibility_record
from companion.checks import is_number, require_non_negative, require_positive
from companion.link.autopilots.ardusub import CAMPAIGN_DEFAULTS as ARDUSUB_CAMPAIGN
from companion.procedures.app import AbortFlag, ConsoleProgress, run_campaign, vehicle_record
from companion.procedures.campaign import CampaignConfig
from companion.procedures.campaign_figures import loops_to_dict
from companion.procedures.registry import rehearsal_behaviors, report_sections
from companion.procedures.results import finite_or_none
from companion.records.store import Store, json_safe

log = logging.getLogger(__name__)


def simulator_truth(preset: str, speed: float, doublet: tuple[float, float, float, float] | None = None) -> dict | None:
    """The preset's linearised yaw parameters at ``speed`` (SPEC C2), from ``python -m sim linearize``.

    With ``doublet`` (amplitude, pre, period, window) a 3-DOF vessel's truth is the doublet-equivalent
    first-order model of its linearisation (eq. S.6): "a22"/"b2" become that, Nomoto's classic
    K/T moves to "a22_nomoto"/"b2_nomoto", and the nonlinear hull's fit at the doublet's amplitude is
    "a22_amplitude"/"b2_amplitude" (how far the hull is from linear at that amplitude)."""
    if not math.isfinite(speed):
        return None
    command = [sys.executable, "-m", "sim", "linearize", "--preset", preset, "--speed", f"{speed:.6f}", "--json"]
    if doublet is not None:
        command += ["--doublet", ",".join(f"{value:.6f}" for value in doublet)]
    try:
        out = subprocess.run(command, capture_output=True, text=True, timeout=60, check=True).stdout
        truth = json.loads(out)
    except (subprocess.SubprocessError, json.JSONDecodeError) as exc:
        log.warning("no simulator truth at %.3f m/s: %s", speed, exc)
        return None
    equivalent, nonlinear = truth.pop("doublet_equivalent", None), truth.pop("doublet_nonlinear", None)
    if equivalent is not None:
        truth.update(a22_nomoto=truth["a22"], b2_nomoto=truth["b2"], a22=equivalent["a22"], b2=equivalent["b2"],
                     truth="doublet-equivalent first order of the linearised hull (eq. S.6)",
                     doublet=equivalent["doublet"])
    if nonlinear is not None:
        truth.update(a22_amplitude=nonlinear["a22"], b2_amplitude=nonlinear["b2"])
    return truth


def training_doublet(attempt, yaw) -> tuple[float, float, float, float] | None:
    """(amplitude, pre, period, window) of an attempt's training doublet as flown: the amplitude from
    its recorded actuator (half its swing while the doublet ran: a skid boat's may have been scaled
    into the mixer's room), the timing from the manoeuvre's configuration ``yaw`` and the record's
    length."""
    series = attempt.training or {}
    times, actuator = series.get("time") or [], series.get("actuator") or []
    if len(times) < 3:
        return None
    start, end = times[0] + yaw.pre_excitation_s, times[0] + yaw.pre_excitation_s + yaw.doublet_period_s
    during = [a for t, a in zip(times, actuator) if start <= t < end and math.isfinite(a)]
    if not during:
        return None
    window = max(times[-1] - times[0], yaw.pre_excitation_s + yaw.doublet_period_s)
    return (max(during) - min(during)) / 2.0, yaw.pre_excitation_s, yaw.doublet_period_s, window


def true_speed(truth_log: Path, attempt) -> float | None:
    """The physics' own mean speed over an attempt's training record, from the simulator's truth
    log (``python -m sim run --truth-log``, written where a real autopilot flies our physics): the
    truth is scored at the speed the vehicle really had, not at the autopilot's estimate of it
    (measured: ArduRover's EKF reads 0.02 m/s low, ArduSub's ~3.5 % low). None without a log."""
    times = (attempt.training or {}).get("time") or []
    if not times or not truth_log.is_file():
        return None
    start, end = times[0], times[-1]
    speeds = []
    with truth_log.open(encoding="utf-8") as rows:
        next(rows, None)
        for row in rows:
            fields = row.split(",")
            try:
                time_s, speed = float(fields[0]), float(fields[1])
            except (ValueError, IndexError):
                continue
            if start <= time_s <= end and math.isfinite(speed):
                speeds.append(speed)
    return sum(speeds) / len(speeds) if speeds else None


@dataclass(frozen=True)
class RehearsalConfig:
    preset: str = "starfish"
    speedup: float = 50.0
    seed: int = 1
    out_dir: str = "rehearsal"
    campaign: CampaignConfig = CampaignConfig()
    behaviors: tuple[str, ...] = ("roll", "min_speed")
    current: tuple[float, float] = (0.0, 0.0)
    steady_state: bool = False
    progress: bool = True
    autopilot: str = "builtin"  # or "ardurover"/"ardusub": real ArduPilot SITL (needs ardupilot_bin)
    ardupilot_bin: str | None = None  # "px4-rover"/"px4-uuv": real PX4 SITL (needs px4_bin)
    px4_bin: str | None = None
    #: a vehicle variant: (perturbation, factor) pairs on the preset (companion.records.variants)
    perturb: tuple[tuple[str, float], ...] = ()
    noise: float = 1.0  # factor on every sensor σ of the preset
    report: bool = True  # write report.html (a sweep's cases skip it)

    def __post_init__(self) -> None:
        require_non_negative(self, "speedup")
        require_positive(self, "noise")
        if not (isinstance(self.current, tuple) and len(self.current) == 2 and all(is_number(v) for v in self.current)):
            raise ValueError(f"RehearsalConfig.current must be (north, east) in m/s, not {self.current!r}")
        known = rehearsal_behaviors()
        unknown = set(self.behaviors) - set(known)
        if unknown:
            raise ValueError(f"RehearsalConfig.behaviors: unknown {', '.join(sorted(unknown))} ({', '.join(known)})")

    @property
    def variant(self) -> bool:
        """Whether the simulator flies a variant of the preset rather than the preset itself."""
        return bool(self.perturb) or self.noise != 1.0


def preset_defaults(preset: str) -> dict:
    """What a rehearsal does on a preset unless told otherwise: its JSON's ``rehearsal`` section
    (``behaviors`` flown after the campaign, ``steady_state``, the ``current`` north/east in m/s), read
    as data. The STARFISH presets (the seeds' small AUV) fly roll stabilisation and minimum-speed
    seeking in still water; the HUGIN-like AUV the steady-state squares and turns in a known current
    of 14 mm/s towards 300°; the boats neither (no rolling mass, no depth). A vehicle file without
    the section flies the campaign alone, in still water."""
    from companion.records.vehicle_files import preset_path

    defaults = {"behaviors": (), "steady_state": False, "current": (0.0, 0.0)}
    try:
        section = json.loads(preset_path(preset).read_text(encoding="utf-8")).get("rehearsal") or {}
    except (OSError, ValueError) as exc:
        log.warning("no rehearsal defaults for preset %r: %s", preset, exc)
        return defaults
    behaviors = tuple(section.get("behaviors", ()))
    unknown = set(behaviors) - set(rehearsal_behaviors())
    if unknown:
        raise ValueError(f"preset {preset!r}: its rehearsal names unknown behaviours {sorted(unknown)}")
    current = tuple(float(v) for v in section.get("current", (0.0, 0.0)))
    if len(current) != 2:
        raise ValueError(f"preset {preset!r}: its rehearsal current must be [north, east] in m/s")
    return {"behaviors": behaviors, "steady_state": bool(section.get("steady_state", False)), "current": current}


#: ArduSub's campaign defaults (thrusts and doublets that keep its motors out of saturation) live in
#: its profile: ``companion.link.autopilots.ardusub.CAMPAIGN_DEFAULTS``
ARDUSUB_THRUSTS = ARDUSUB_CAMPAIGN.thrusts
#: what the companion is told about the AUV under ArduSub: nothing beyond the profile; its equivalent
#: rudder is the thrusters' yaw differential, no fin servo (sim.ardupilot_sitl.FRAME_LIMITS)
ARDUSUB_VEHICLE: dict = {}

#: ``python -m sim run`` options for ArduSub: the AUV boots 2 m down (the thesis' depth). ArduSub's
#: EKF starts its height at 0 and converges onto the depth sensor: from 2 m within 3 s, while from
#: 5 m (the simulator's default) the innovations fail their gate, the height runs away at 5 m/s
#: and the EKF resets itself 10 s later (measured).
ARDUSUB_SIM_ARGS = ("--depth", "2")


def ardusub_campaign(campaign: CampaignConfig) -> CampaignConfig:
    """The campaign a rehearsal flies on ArduSub unless told otherwise: the ArduSub profile's defaults
    (yaw only, thrusts and doublets that keep the motors out of saturation), as ``identify --connect``
    on a real sub gets them."""
    from companion.link.autopilots.ardusub import PROFILE

    return campaign.with_profile_defaults(PROFILE)


def preset_vehicle(preset: str) -> dict:
    """What the companion is told about a simulated vehicle flown by a real autopilot, as it would be
    told about a real one: the rudder servo's slew rate (the preset's data, read as a file); nothing
    for a twin-thruster boat (no servo: its steering is the motors' difference)."""
    from companion.records.vehicle_files import preset_path

    try:
        data = json.loads(preset_path(preset).read_text(encoding="utf-8"))
        if data.get("twin_thrusters"):  # steered by two motors: no rudder servo to model
            return {}
        return {"actuator_rate_rad_s": float(data["actuators"]["rudder_rate"])}
    except (OSError, KeyError, ValueError) as exc:
        log.warning("no servo rate for preset %r: %s", preset, exc)
        return {}


def neutral_buoyancy(preset: str) -> tuple[tuple[str, float], ...]:
    """The perturbation that trims a preset's AUV neutrally buoyant (buoyancy = weight), as PX4's
    HippoCampus airframe flies it: its four forward thrusters pitch our STARFISH at most −1.9° at
    0.86 m/s (one thrust differential is all its pitch authority), while the thesis' 1.9 N of
    buoyancy needs about −3.5°: it rose 5 m in 100 s with the depth hold at its limit (measured).
    Yaw is not affected. () when the preset has no dive plane."""
    from companion.records.vehicle_files import preset_path

    try:
        plane = json.loads(preset_path(preset).read_text(encoding="utf-8"))["dive_plane"]
        return (("dive_plane.buoyancy", float(plane["weight"]) / float(plane["buoyancy"])),)
    except (OSError, KeyError, ValueError, ZeroDivisionError) as exc:
        log.warning("no dive plane in preset %r: %s", preset, exc)
        return ()


def arm_px4_when_ready(link, patience_s: float) -> None:
    """Arm PX4 in the mode it is in (Hold after boot, where no stick gates arming), retrying while it
    still initialises ("no heading reference" for the first seconds)."""
    start = link.next_telemetry(timeout_s=30.0).time_s
    _retrier(link, start, patience_s)(lambda: link.arm(True))


def _retrier(link, start: float, patience_s: float):
    """``retry(action)``: call ``action`` until the vehicle accepts it, trying about every 2 s of
    vehicle time until ``patience_s`` after ``start``; then raise with the vehicle's last words."""
    from companion.link.errors import CommandFailed, ModeChangeFailed

    def retry(action) -> None:
        while True:
            try:
                action()
                return
            except (CommandFailed, ModeChangeFailed) as exc:
                if not link.vehicle_time_s - start < patience_s:
                    texts = [t for _, _, t in list(link.announcements.statustexts)[-3:]]
                    raise type(exc)(f"{exc}; the vehicle said: {texts}") from exc
                for _ in range(40):
                    link.next_telemetry()

    return retry


def arm_when_ready(link, patience_s: float) -> None:
    """Arm. A real autopilot refuses while it is still initialising (EKF, GPS), and ArduRover takes
    GUIDED while disarmed but not once armed until its EKF uses GPS: so retry arming, then entering
    the holding mode (and back to the mode found), for ``patience_s`` seconds of vehicle time;
    raise with the vehicle's last words when it never becomes ready."""

    start = link.next_telemetry(timeout_s=30.0).time_s  # the vehicle clock runs before anything is timed

    retry = _retrier(link, start, patience_s)

    retry(lambda: link.arm(True))
    if patience_s > 0:
        found = link.mode
        retry(lambda: link.set_mode("hold"))
        link.set_mode(found)


def arm_ardusub_when_ready(link, patience_s: float) -> None:
    """ArduSub: wait, disarmed, until the EKF navigates (ArduSub accepts POSHOLD, disarmed, only with
    a predicted absolute position; before that its height is still converging onto the depth sensor
    and the ground speed, our water speed, reads 0), then hold the depth in ALT_HOLD and arm. Ends in
    ALT_HOLD at zero thrust, so a campaign's restore leaves the vehicle stopped at its depth.

    Disarmed, because armed before its EKF uses GPS ArduSub dead-reckons a vehicle at rest into
    2 m/s of ground speed and a heading 15° off (measured). The simulated AUV waits in its launch
    cradle until the thrusters run (sim.ardupilot_json.SubVectoredDecoder)."""

    start = link.next_telemetry(timeout_s=30.0).time_s

    retry = _retrier(link, start, patience_s)

    retry(lambda: link.set_mode("poshold"))
    link.set_mode("hold")
    retry(lambda: link.arm(True))


def _run_rows(campaign, truth: dict, speeds: dict | None = None) -> list[dict]:
    design = campaign.heading_design
    own_gains = {point.thrust: point.own for point in (design.points if design else [])}
    rows = []
    for attempt in campaign.accepted:
        if attempt.axis != "yaw":
            continue
        model = attempt.model
        true = truth.get(f"{attempt.thrust:.2f}") or {}
        own = own_gains.get(attempt.thrust, {})
        rows.append({
            "thrust": attempt.thrust,
            "speed": finite_or_none(attempt.speed),
            "true_speed": (speeds or {}).get(f"{attempt.thrust:.2f}"),
            "a22": model.a22, "b2": model.b2, "delta0": model.delta0,
            "r2": finite_or_none(attempt.r2),
            "converged_s": finite_or_none(attempt.converged_s) if attempt.converged_s is not None else None,
            "true_a22": true.get("a22"), "true_b2": true.get("b2"), "true_delta0": true.get("delta0"),
            **{f"true_{key}": true[key] for key in ("a22_nomoto", "b2_nomoto", "a22_amplitude", "b2_amplitude")
               if key in true},
            "kp": own.get("heading_p"), "ki": own.get("heading_i"),
        })
    return rows


def rehearse(config: RehearsalConfig, abort: AbortFlag | None = None) -> dict:
    """Run the whole rehearsal; returns the JSON summary (also written to ``<out>/summary.json``)."""
    from companion.link.vehicle import VehicleLink  # the link pulls in pymavlink; keep CLI start-up light

    abort = abort or AbortFlag()
    px4 = config.autopilot.startswith("px4-")
    if config.autopilot == "px4-uuv" and not config.perturb:  # see neutral_buoyancy
        config = replace(config, perturb=neutral_buoyancy(config.preset))
    started = time.monotonic()  # wall time of the whole rehearsal: a reported figure, not logic
    out = Path(config.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    store_path = out / "store.sqlite"
    summary: dict = {"preset": config.preset, "speedup": config.speedup, "seed": config.seed}
    sim_preset = config.preset  # what the simulator and its truth read: the preset or its variant's file
    if config.variant:
        from companion.records.variants import write_variant

        sim_preset = str(write_variant(config.preset, dict(config.perturb), config.noise, out / "preset.json"))
        summary["variant"] = {"perturb": dict(sorted(config.perturb)), "noise": config.noise}
    simulator = SimulatorProcess(sim_preset, config.speedup, config.seed, config.current,
                                 log_path=out / "simulator.log", autopilot=config.autopilot,
                                 ardupilot_bin=config.ardupilot_bin, lockstep=config.autopilot == "builtin",
                                 px4_bin=config.px4_bin, transport="udp" if px4 else "tcp",
                                 ready_timeout_s=120.0,
                                 extra_args=([*ARDUSUB_SIM_ARGS] if config.autopilot == "ardusub" else [])
                                 + (["--truth-log", str(out / "truth.csv")] if config.autopilot != "builtin" else []))
    summary["autopilot"] = config.autopilot
    with Store(store_path) as store, simulator as sim:
        link = VehicleLink.connect(sim.endpoint, lockstep=sim.lockstep,
                                   heartbeat_timeout_s=60.0 if sim.real_autopilot else 10.0,
                                   vehicle=(ARDUSUB_VEHICLE if config.autopilot == "ardusub" else {} if px4 else
                                            preset_vehicle(sim_preset)) if sim.real_autopilot else None)
        try:
            if px4:  # PX4 slews its outputs itself: the read-back is the rudder (no servo model)
                arm_px4_when_ready(link, patience_s=120.0)
            elif config.autopilot == "ardusub":
                arm_ardusub_when_ready(link, patience_s=120.0)
            else:
                arm_when_ready(link, patience_s=120.0 if sim.real_autopilot else 0.0)
            vehicle_id = vehicle_record(store, link, f"sim:{config.preset}",
                                        {"preset": config.preset, "seed": config.seed, **summary.get("variant", {})})
            console = ConsoleProgress("identification", enabled=config.progress)
            campaign, outcome, campaign_id = run_campaign(link, store, config.campaign, vehicle_id=vehicle_id,
                                                          abort=abort, console=console)
            summary.update(status=outcome.status, reason=outcome.reason, campaign_id=campaign_id,
                           restore_problems=outcome.restore_problems, restore_notes=outcome.restore_notes,
                           records_rejected_for_link=campaign.records_rejected_for_link,
                           vehicle_time_s=outcome.vehicle_time_s,
                           vehicle_time_by_phase={k: round(v, 2) for k, v in campaign.phases_in_order().items()},
                           identification_stage_s={k: round(v, 2) for k, v in campaign.phase_times.items()})
            extra: dict = {}
            if outcome.status == "completed":
                extra = _run_behaviors(link, store, config, vehicle_id, campaign_id, abort, summary, sim_preset)
                _behaviours_decide(summary, config.behaviors)
            if outcome.status == "completed" and config.steady_state:
                extra["steady_state"] = _run_steady_state(link, store, config, campaign_id, abort, summary)
        finally:
            snapshots_dropped, wall_timeouts = link.telemetry.snapshots_dropped, link.clock.wall_timeouts
            summary["link_quality"] = link.telemetry.quality()
            link.close()
        truth, speeds = {}, {}
        for attempt in campaign.accepted:
            if attempt.axis == "yaw":
                # our autopilot's speed sensor is the physics' (noise only); a real one's is an estimate
                speed = true_speed(out / "truth.csv", attempt) if sim.real_autopilot else None
                speeds[f"{attempt.thrust:.2f}"] = speed
                truth[f"{attempt.thrust:.2f}"] = simulator_truth(sim_preset, speed if speed else attempt.speed,
                                                                 training_doublet(attempt, campaign.config.yaw))
        summary["runs"] = _run_rows(campaign, truth, speeds if sim.real_autopilot else None)
        summary["design"] = campaign.design_summary()
        summary["heading_steps"] = [{"thrust": s.thrust, "label": s.label,
                                     "max_overshoot_pct": finite_or_none(s.max_overshoot_pct),
                                     "iae_s": finite_or_none(s.iae_s), "oscillations": s.oscillations,
                                     "step_deg": s.steps[0].step_deg if s.steps else None,
                                     # time to stay within 5 % of the step, the slower of the step and its return
                                     "settling_time_s": finite_or_none(_slowest(x.figures.settling_time_s
                                                                                for x in s.steps))}
                                    for s in campaign.step_results]
        summary["speed_loop"] = speed_loop_summary(campaign.speed)
        summary["verification"] = campaign.verification or ("passed" if campaign.final_gains else None)
        summary["checks"] = campaign.checks
        summary["verified"] = campaign.verifier.summary() if campaign.verifier is not None else None
        summary["heading_design"] = campaign.heading_choice.choice.to_dict() if campaign.heading_choice else None
        summary["loops"] = loops_to_dict(campaign.loop_outcomes())
        summary["thrust_levels"] = campaign.result().figures.thrust_levels.to_dict()
        summary["final_gains"] = campaign.final_gains
        summary["store"] = str(store_path)
        summary["report"] = str(out / "report.html") if config.report else None
        summary["wall_time_s"] = round(time.monotonic() - started, 2)
        if config.report:
            from companion.records.report import write_report  # matplotlib: only when a report is written

            write_report(store, campaign_id, out, truth={k: v for k, v in truth.items() if v}, extra_results=extra,
                         summary={k: v for k, v in summary.items() if k != "design"},
                         delta_max=campaign.config.yaw.training_amplitude, sections=report_sections())
        summary["wall_time_s"] = round(time.monotonic() - started, 2)
    # after the simulator stopped: its exit report says whether lockstep held
    summary["reproducibility"] = reproducibility_record(config.autopilot, simulator.lockstep, simulator.stats,
                                                        snapshots_dropped, wall_timeouts)
    if not summary["reproducibility"]["exact"]:
        log.warning("this rehearsal may not be reproducible: %s", "; ".join(summary["reproducibility"]["varied"]))
    (out / "summary.json").write_text(json.dumps(json_safe(summary), indent=1, allow_nan=False))
    return summary


def _slowest(times) -> float:
    """The largest of some settling times; NaN when there is none or one never settled."""
    values = list(times)
    return max(values) if values and all(math.isfinite(v) for v in values) else math.nan


def speed_loop_summary(tuning) -> dict | None:
    """The speed loop's figures for the summary: the surge model (eq. S.4), the designed gains and
    their predicted steps, the flown speed steps per gain set, and the verdict (None: not tuned)."""
    if tuning is None:
        return None
    surge, design = tuning.surge, tuning.design
    steps = {label: {"max_overshoot_pct": finite_or_none(r.max_overshoot_pct),
                     "settling_time_s": finite_or_none(r.settling_time_s), "speeds": list(r.speeds),
                     "steps": [{k: finite_or_none(v) for k, v in step.to_dict().items()} for step in r.steps]}
             for label, r in tuning.step_results.items()}
    return {"status": tuning.status.value, "reason": tuning.reason, "verdict": tuning.verdict, "kept": tuning.kept,
            "surge": None if surge is None else {"gain": surge.gain, "exponent": surge.exponent, "gamma": surge.gamma,
                                                 "lag": surge.lag,
                                                 "r2": finite_or_none(surge.r2), "levels": surge.levels,
                                                 "describe": surge.describe()},
            "design": None if design is None else {"gains": design.gains.params(), "speed": design.design_speed,
                                                   "time_constant_s": design.time_constant_s,
                                                   "step": list(design.step), "predicted": design.predicted,
                                                   "clamped": list(design.clamped),
                                                   # eq. S.5r: the worst settling over the drift, and the choice
                                                   "worst_settling_s": {k: finite_or_none(v) for k, v in
                                                                        design.worst_settling_s.items()},
                                                   "feed_forward_error": design.feed_forward_error,
                                                   "keeps_original": design.keeps_original},
            "original": tuning.original, "steps": steps,
            # what the design was compared with: the original gains' steps flown, or predicted
            "original_compared": "flown" if "original" in tuning.step_results else
            "predicted" if tuning.original_figures is not None else None,
            "original_flown_because": tuning.original_flown_because}


def _run_steady_state(link, store, config: RehearsalConfig, campaign_id: int, abort: AbortFlag, summary: dict) -> dict:
    """Squares and turns, scored against the current the simulator was started with."""
    from companion.procedures.app import run_named_procedure
    from companion.procedures.steady_state import steady_summary

    ran = run_named_procedure("steady_state", link, store, vehicle_id=0, campaign_id=campaign_id, abort=abort)
    stored = ran.result.to_json()
    summary["steady_state"] = steady_summary(stored, config.current)
    return stored


def _behaviours_decide(summary: dict, behaviors: tuple[str, ...]) -> None:
    """The rehearsal completes only if every behaviour it ran reached its goal (a seeker that did not
    settle has not found the minimum speed); otherwise it fails with the first behaviour's reason.
    The campaign's own outcome stays under ``campaign_status``."""
    summary["campaign_status"] = summary.get("status")
    for name in behaviors:
        ran = summary.get(name) or {}
        if ran.get("status") != "completed":
            reason = ran.get("reason") or ran.get("abort_reason") or ran.get("status") or "did not run"
            summary.update(status="failed", reason=f"{name.replace('_', '-')}: {reason}")
            return


def _run_behaviors(link, store, config: RehearsalConfig, vehicle_id: int, campaign_id: int, abort: AbortFlag,
                   summary: dict, sim_preset: str | None = None) -> dict:
    """Roll stabilisation and minimum-speed seeking after the campaign; ``sim_preset`` is
    the vehicle data the analytic figures come from (a variant's file, or the preset)."""
    extra: dict = {}
    if not config.behaviors:
        return extra
    from companion.procedures.app import run_named_behavior

    for name in config.behaviors:
        ran = run_named_behavior(name, link, store, vehicle_id=vehicle_id, campaign_id=campaign_id, abort=abort,
                                 preset=sim_preset or config.preset)
        extra[name] = ran.result.to_json()
        summary[name] = ran.summary
    return extra
