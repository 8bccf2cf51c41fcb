"""Minimum-speed seeking (SPEC C7; thesis 002, §5.3, Fig. 5.16–5.17, 5.22–5.26).

Runs in the heading-and-depth holding mode: the autopilot holds heading and depth (depth PI →
desired pitch θd → pitch PI → elevator) and this behaviour moves the thrust set-point (the levelled
start below also offsets the depth set-point for a while, and always puts it back). It starts
from the nominal thrust (SetThrust 0.70) and every Ts seconds of vehicle time applies the fuzzy
decision (:mod:`companion.numerics.fuzzy_seeker`) T_R(k) = T_R(k−1) + {−ΔT, 0, +ΔT} (eq. 5.62),
clamped to [thrust floor, 1]. It never stops seeking by itself (it keeps following disturbances)
unless a ``duration_s`` is configured.

Inputs. δs is the actual elevator (telemetry.elevator). The autopilot does not report θd, so the
behaviour recomputes it with a *shadow depth loop*: the same depth PI the autopilot runs (gains
DPT_P/DPT_I and the PIT_MAX limit, passed in as parameters, read from the autopilot by the caller),
θd = clamp(Kpz·(z_sp − z) + I, ±θmax), İ = Kiz·(z_sp − z) (conditional integration while saturated). The unknown initial integrator state is
taken from the assumption the thesis makes anyway (§5.3.1: the depth subsystem is at steady state
when the seeker starts, so the pitch loop tracks θd): I(0) = θ(0) − Kpz·(z_sp − z(0)), with θ(0)
the pitch averaged over the first ``init_average_s``. From then on the shadow integrator sees the same
depth error as the autopilot's, so the two stay together up to sensor noise and the autopilot's
own anti-windup; θe = θ − θd then grows exactly when the pitch loop can no longer follow (§5.2.2).
The depth set-point is the hold mode's (the depth when the mode was entered); pass it in when
known, otherwise the depth averaged over ``init_average_s`` is used.

The design record — why the hold after every change, the governed and levelled starts, the pitch-error
crossover, what was tried and not taken, with every measurement — is in
``docs/min_speed_notebook.md``.

Settling rule: the seeker has settled when its thrust set-point has not changed for
``settle_window_s`` (15 s, i.e. 15 decisions at Ts = 1 s); ``settle_time_s`` is the time from the
start to the last change before the first such quiet window. ``max_depth_error_m`` is the largest
|z − z_sp| after the first ``transient_s`` seconds (the start-up transient of stepping to the nominal
thrust). A run with a ``duration_s`` succeeds only if it has settled by then; otherwise it fails,
saying when the set-point last moved (its final T_R is not the minimum speed).
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np

from companion.checks import require_finite, require_non_negative, require_positive, require_range

from companion.interface import Command, NamedValue, SetDepth, SetThrust, StatusText, Telemetry
from behaviors.base import Behaviour, Footprint, Status
from behaviors.min_speed_result import MinSpeedResult
from companion.numerics.fuzzy_seeker import (LowPass, SeekerConfig, decide, hold_decision, next_thrust,
                                             pitch_error_crossover)
from companion.numerics.minspeed import THRUST_DEAD_ZONE
from companion.numerics.trim_feedforward import DepthSetpointFeedForward, FeedForwardConfig

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class MinSpeedConfig:
    """Parameters of the behaviour; the depth-loop gains must be the autopilot's (DPT_P, DPT_I, PIT_MAX)."""

    seeker: SeekerConfig = field(default_factory=SeekerConfig)
    nominal_thrust: float = 0.70
    thrust_floor: float = THRUST_DEAD_ZONE  # below this the thruster gives nothing (Fig. 5.3)
    thrust_ceiling: float = 1.0
    depth_p: float = -0.15  # DPT_P, rad pitch per m
    depth_i: float = -0.01  # DPT_I, rad pitch per m·s
    pitch_max: float = 0.35  # PIT_MAX, rad
    # PIT_P, elevator rad per rad of pitch error: sets the θe crossover the seeker decides with
    # (fuzzy_seeker.pitch_error_crossover, eq. M.1); None: the seeker's configured θe_TS as it is
    pitch_p: float | None = -20.0
    depth_setpoint: float | None = None  # m; None: the depth at the start
    init_average_s: float = 1.0  # s, averaging of pitch/depth for the shadow loop's initial state
    settle_window_s: float = 15.0
    transient_s: float = 5.0
    duration_s: float | None = None  # None: seek until aborted
    # the set-point the seeking starts from (None: the nominal thrust, the thesis); the
    # procedure passes the model's predicted TR* plus a margin, so the seeker only fine-tunes
    start_thrust: float | None = None
    # how fast the set-point moves from the nominal thrust to ``start_thrust`` (1/s of thrust ratio);
    # a step there at once lost 0.7 m of depth in the speed transient, 0.01/s 0.44 m, 0.005/s 0.30 m
    # (bench/bench_min_speed.py --predicted); no decision meanwhile
    start_ramp_rate: float = 0.005
    # the governed move (None: the ramp at ``start_ramp_rate``): the set-point falls
    # as fast as the autopilot's depth integrator can carry the pitch change while the depth error
    # stays near this budget (m); needs ``start_pitch_curve``, see :meth:`MinSpeedSeeking._governed`
    start_depth_budget_m: float | None = None
    # the model's level-flight pitch against thrust ratio, ((T_R, θ rad), ...) with T_R ascending
    # and θ rising with T_R (minspeed.trim_pitch_curve, eq. 5.25–5.29, 5.54–5.55)
    start_pitch_curve: tuple[tuple[float, float], ...] = ()
    # a governed move that has not lowered the set-point for this long (e.g. the vehicle is not in
    # the level flight the curve describes, such as at the surface) continues as the ramp above
    start_stall_s: float = 10.0
    # the levelled move (needs ``start_thrust`` and ``start_pitch_curve``; instead of the governed move):
    # the set-point falls at ``start_feedforward_rate`` while the curve's level-flight pitch change is
    # fed forward through a depth set-point offset that fades as the autopilot's integrator takes it
    # over (companion.numerics.trim_feedforward, :meth:`MinSpeedSeeking._feed_forward`)
    start_feedforward: bool = False
    start_feedforward_rate: float = 0.02  # 1/s of thrust ratio: 13 s from 0.70 to 0.44
    # s, the speed's lag behind the thrust set-point (surge time constant m_x/(ρA_b|C_D0|V): 1.3-2.7 s
    # from 1.4 to 0.69 m/s, plus the deceleration itself); the pitch is fed forward through this lag
    start_feedforward_lag_s: float = 2.5
    feedforward_quantum_m: float = 0.01  # the offset is sent again when it moved this much
    feedforward_max_offset_m: float = 1.5

    def __post_init__(self) -> None:
        require_range(self, "nominal_thrust", 0.0, 1.0)
        require_range(self, "thrust_floor", 0.0, 1.0)
        require_range(self, "thrust_ceiling", 0.0, 1.0)
        if self.thrust_floor > self.thrust_ceiling:
            raise ValueError(f"MinSpeedConfig: thrust_floor {self.thrust_floor} above thrust_ceiling {self.thrust_ceiling}")
        require_finite(self, "depth_p", "depth_i")
        require_positive(self, "pitch_max", "init_average_s", "settle_window_s", "start_ramp_rate", "start_stall_s",
                         "start_feedforward_rate", "feedforward_quantum_m", "feedforward_max_offset_m")
        require_non_negative(self, "start_feedforward_lag_s")
        require_non_negative(self, "transient_s")
        require_range(self, "duration_s", 1e-3, 1e6, optional=True)
        require_range(self, "start_thrust", 0.0, 1.0, optional=True)
        require_range(self, "start_depth_budget_m", 1e-3, 10.0, optional=True)
        require_range(self, "depth_setpoint", -10.0, 11000.0, optional=True)


class MinSpeedSeeking(Behaviour):
    """The minimum-speed seeker."""

    footprint = Footprint.of(setpoints=("thrust",))

    def __init__(self, config: MinSpeedConfig = MinSpeedConfig()) -> None:
        super().__init__("minimum-speed seeking")
        self.config = config
        self._levelled = (config.start_feedforward and config.start_thrust is not None
                          and bool(config.start_pitch_curve))
        if self._levelled:  # the levelled move offsets the depth set-point for a while
            self.footprint = Footprint.of(setpoints=("thrust", "depth"))
        # the seeker's rules as decided here: θe_TS raised to what the pitch loop needs (eq. M.1)
        self.seeker_config = replace(config.seeker,
                                     theta_e_threshold=pitch_error_crossover(config.seeker, config.pitch_p))
        self._theta_filter = LowPass(config.seeker)
        self._delta_filter = LowPass(config.seeker)
        self._start: float | None = None
        self._init_pitch: list[float] = []
        self._init_depth: list[float] = []
        self._initialised = False
        self._depth_setpoint = math.nan
        self._integrator = 0.0
        self._last_time = math.nan
        self._next_decision = math.nan
        self._last_change = -math.inf  # vehicle time of the last set-point change by a decision
        self._ramp_to: float | None = None  # the predicted start the set-point is moving to
        self._ramp_clock = math.nan  # vehicle time of the last ramp step
        self._governed_since = math.nan  # vehicle time the governed move last lowered the set-point
        self.governed_stalled = False  # the governed move stalled and continued as the ramp
        self.ramp_done_s: float | None = None  # when the set-point reached the predicted start
        self._feedforward: DepthSetpointFeedForward | None = None  # the levelled move's, while it lasts
        self._offset_sent = 0.0  # m, the depth set-point offset in effect (0: the depth to hold)
        self._lagged_thrust = math.nan  # the thrust set-point through the speed's lag
        self._feedforward_clock = math.nan
        self.feedforward_faded_s: float | None = None  # when the depth set-point was back, exactly
        self.max_depth_offset_m = 0.0
        self.thrust_ratio = config.nominal_thrust
        self.series: dict[str, list[float]] = {
            name: []
            for name in ("time", "thrust_ratio", "thrust_setpoint", "speed", "pitch", "pitch_desired",
                         "pitch_error_filtered", "elevator", "elevator_filtered", "depth", "decision")
        }
        self.decisions: list[tuple[float, int, float]] = []  # (time since start, decision, new set-point)

    # ------------------------------------------------------------------ Behavior protocol
    @property
    def aborted(self) -> bool:
        return self.status is Status.ABORTED

    def terminate(self, status: Status) -> Sequence[Command]:
        """An abort gives the vehicle back its nominal thrust; any end its depth set-point (the levelled
        move's offset is never left behind)."""
        commands: list[Command] = []
        if self._offset_sent != 0.0:
            self._offset_sent = 0.0
            self._feedforward = None
            commands.append(SetDepth(self._depth_setpoint))
        if status is not Status.ABORTED:
            return commands
        log.info("minimum-speed seeking aborted: %s", self.reason)
        return commands + [SetThrust(self.config.nominal_thrust),
                           StatusText(f"minspeed aborted: {self.reason}"[:50], 4)]

    def update(self, telemetry: Telemetry) -> Sequence[Command]:
        if not telemetry.finite("pitch", "depth"):
            return []
        cfg = self.config
        now = telemetry.time_s
        commands: list[Command] = []
        if self._start is None:
            self._start = now
            self._next_decision = now + cfg.seeker.period_s
            self.thrust_ratio = cfg.nominal_thrust
            commands += [SetThrust(self.thrust_ratio), StatusText("minspeed: seeking started")]
            if cfg.start_thrust is not None:
                self._ramp_to = min(max(cfg.start_thrust, cfg.thrust_floor), cfg.thrust_ceiling)
                commands.append(StatusText(f"minspeed: to the predicted TR {self._ramp_to:.2f}"))
        elapsed = now - self._start
        theta_d = self._shadow_depth_loop(now, elapsed, telemetry)
        if self._ramp_to is not None:  # moving to the predicted start: no seeking decision yet
            target = self._ramp_to
            governed = (not self._levelled and cfg.start_depth_budget_m is not None and bool(cfg.start_pitch_curve)
                        and not self.governed_stalled)
            if self._levelled:  # at its own rate, from the first sample the shadow loop knows
                moved = self._ramp(target, cfg.start_feedforward_rate, now) if self._initialised else self.thrust_ratio
            elif governed:
                moved = self._governed(target)
                if moved != self.thrust_ratio or not math.isfinite(self._governed_since):
                    self._governed_since = now
                elif now - self._governed_since >= cfg.start_stall_s:
                    self.governed_stalled = True  # from the next sample on, the ramp
                    self._ramp_clock = now
                    commands.append(StatusText("minspeed: governed move stalled, ramping", 4))
                    log.warning("governed move stalled for %.0f s at TR %.3f: continuing as the %.3f/s ramp",
                                cfg.start_stall_s, self.thrust_ratio, cfg.start_ramp_rate)
            else:
                moved = self._ramp(target, cfg.start_ramp_rate, now)
            if moved != self.thrust_ratio or not (governed or self._levelled):
                self.thrust_ratio = moved
                commands.append(SetThrust(round(self.thrust_ratio, 6)))
            if self.thrust_ratio == target:
                self._ramp_to = None
                self.ramp_done_s = elapsed
                self._last_change = now
                self._next_decision = now + cfg.seeker.period_s
        if self._levelled and self._initialised and self.feedforward_faded_s is None:
            commands += self._feed_forward(now, elapsed)
        theta_e = telemetry.pitch - theta_d if math.isfinite(theta_d) else math.nan
        theta_e_f = self._theta_filter.update(now, theta_e)
        delta_f = self._delta_filter.update(now, telemetry.elevator)
        decision = 0
        decided = False
        if (self._ramp_to is None and now >= self._next_decision - 1e-9 and math.isfinite(theta_e_f)
                and math.isfinite(delta_f)):
            self._next_decision += cfg.seeker.period_s * max(1, math.floor((now - self._next_decision) / cfg.seeker.period_s) + 1)
            decision = hold_decision(decide(theta_e_f, delta_f, self.seeker_config), now, self._last_change,
                                     self.seeker_config)
            decided = True
            new_thrust = next_thrust(self.thrust_ratio, decision, cfg.seeker, cfg.thrust_floor, cfg.thrust_ceiling)
            if new_thrust != self.thrust_ratio:
                self.thrust_ratio = new_thrust
                self._last_change = now
                commands.append(SetThrust(round(new_thrust, 6)))
            self.decisions.append((elapsed, decision, self.thrust_ratio))
            commands.append(NamedValue("MS_TR", self.thrust_ratio))
        self._record(telemetry, elapsed, theta_d, theta_e_f, delta_f, decision if decided else math.nan)
        if cfg.duration_s is not None and elapsed >= cfg.duration_s:
            commands += self._finish_at_duration(elapsed)
        return commands

    def _finish_at_duration(self, elapsed: float) -> list[Command]:
        """At the end of ``duration_s``: success only if the seeker has settled (settling rule, module
        doc): a set-point still moving is not the minimum speed, whatever it is at that moment."""
        if not self.decisions:
            self.finish(Status.FAILURE, "no seeking decision was made")
            return [StatusText("minspeed: no decision made", 4)]
        if self.settle_time() is None:
            last_change = max([self.ramp_done_s or 0.0] + [t for t, d, _ in self.decisions if d != 0])
            self.finish(Status.FAILURE,
                        f"not settled in {elapsed:.0f} s of seeking: the thrust set-point last changed at "
                        f"{last_change:.0f} s (TR {self.thrust_ratio:.2f}), {self.config.settle_window_s:.0f} s "
                        "without a change are needed")
            return [StatusText(f"minspeed: not settled, TR {self.thrust_ratio:.2f}", 4)]
        self.finish(Status.SUCCESS)
        return [StatusText(f"minspeed: settled, TR {self.thrust_ratio:.2f}")]

    # ------------------------------------------------------------------ internals
    def _ramp(self, target: float, rate: float, now: float) -> float:
        """The set-point ``rate`` (1/s) closer to ``target`` than at the last call (vehicle time)."""
        step = rate * max(0.0, now - self._ramp_clock) if math.isfinite(self._ramp_clock) else 0.0
        self._ramp_clock = now
        if abs(target - self.thrust_ratio) <= step:
            return target
        return self.thrust_ratio + math.copysign(step, target - self.thrust_ratio)

    def _feed_forward(self, now: float, elapsed: float) -> list[Command]:
        """The levelled move's depth set-point (companion.numerics.trim_feedforward).

        The fed-forward pitch is the model's level-flight pitch (``start_pitch_curve``, eq. 5.25–5.29)
        at the thrust set-point seen through the speed's first-order lag (``start_feedforward_lag_s``),
        relative to the curve at the nominal thrust: only the model's slope counts, not its offset.
        It follows the set-point (the seeker's steps too) until, after the move, the offset has
        faded below one quantum; the depth set-point is then sent back exactly and the feed-forward
        ends. The shadow depth loop integrates the offset in effect, as the autopilot does.
        """
        cfg = self.config
        ratios = [point[0] for point in cfg.start_pitch_curve]
        pitches = [point[1] for point in cfg.start_pitch_curve]
        if self._feedforward is None:
            self._lagged_thrust = cfg.nominal_thrust
            self._feedforward_clock = now
            self._feedforward = DepthSetpointFeedForward(
                FeedForwardConfig(depth_p=cfg.depth_p, depth_i=cfg.depth_i, quantum_m=cfg.feedforward_quantum_m,
                                  max_offset_m=cfg.feedforward_max_offset_m),
                float(np.interp(cfg.nominal_thrust, ratios, pitches)))
        dt = now - self._feedforward_clock
        self._feedforward_clock = now
        lag = cfg.start_feedforward_lag_s
        follow = 1.0 - math.exp(-dt / lag) if lag > 0.0 else 1.0
        self._lagged_thrust += follow * (self.thrust_ratio - self._lagged_thrust)
        wanted = self._feedforward.offset(float(np.interp(self._lagged_thrust, ratios, pitches)))
        wanted = max(wanted, -self._depth_setpoint)  # never a set-point above the surface
        if self._ramp_to is None and abs(wanted) < cfg.feedforward_quantum_m:
            wanted = 0.0  # faded: the autopilot's integrator carries the whole pitch change now
            self._feedforward = None
            self.feedforward_faded_s = elapsed
            log.info("levelled move: the depth set-point offset faded after %.1f s", elapsed)
        elif not self._feedforward.to_send(wanted, self._offset_sent):
            return []
        if wanted == self._offset_sent:
            return []
        self._offset_sent = wanted
        self.max_depth_offset_m = max(self.max_depth_offset_m, abs(wanted))
        return [SetDepth(self._depth_setpoint + wanted)]

    def _governed(self, target: float) -> float:
        """The set-point of the governed move to ``target``, never rising.

        In level flight the pitch θ(T_R) is fixed by the thrust (eq. 5.25–5.29: the slower, the more
        nose-down), and the autopilot's depth PI, θd = Kpz·e + I, holds it at zero depth error only
        once its integrator I has moved there; what I has not yet carried, the depth error e must
        (e = (θ − I)/Kpz). So the thrust may fall only to where the model's trim pitch is within
        |Kpz|·``start_depth_budget_m`` of the shadow integrator (module doc): the depth error then
        rises to about the budget at once and stays there while I integrates at Kiz·e, the fastest
        move the depth loop allows with that error. Before the shadow loop is initialised the
        set-point stays where it is (without a curve the caller ramps at ``start_ramp_rate``).
        """
        cfg = self.config
        curve = cfg.start_pitch_curve
        budget = cfg.start_depth_budget_m
        if not self._initialised or budget is None:  # the caller governs only with a budget
            return self.thrust_ratio
        ratios = np.array([point[0] for point in curve])
        pitches = np.array([point[1] for point in curve])
        allowed_pitch = self._integrator - abs(cfg.depth_p) * budget
        allowed = float(np.interp(allowed_pitch, pitches, ratios))  # θ rises with T_R (config doc)
        return max(target, min(self.thrust_ratio, allowed))

    def _shadow_depth_loop(self, now: float, elapsed: float, t: Telemetry) -> float:
        """θd recomputed from the autopilot's depth PI (see module docstring); NaN while initialising."""
        cfg = self.config
        if not self._initialised:
            self._init_pitch.append(t.pitch)
            self._init_depth.append(t.depth)
            if elapsed + 1e-9 < cfg.init_average_s:
                return math.nan
            depth0 = float(np.mean(self._init_depth))
            pitch0 = float(np.mean(self._init_pitch))
            # never above the surface: a hold entered there reads the depth's noise about zero
            self._depth_setpoint = max(0.0, depth0) if cfg.depth_setpoint is None else cfg.depth_setpoint
            self._integrator = pitch0 - cfg.depth_p * (self._depth_setpoint - depth0)
            self._initialised = True
            self._last_time = now
        error = self._depth_setpoint + self._offset_sent - t.depth  # the set-point the autopilot holds
        dt = now - self._last_time
        if self._feedforward is not None:
            self._feedforward.advance(dt, self._offset_sent)
        self._last_time = now
        raw = cfg.depth_p * error + self._integrator
        # conditional integration, the usual anti-windup (and the simulator's): hold the integrator
        # while the output is saturated and the error would push it further into the limit
        if dt > 0.0 and (abs(raw) < cfg.pitch_max or (cfg.depth_i * error) * raw <= 0.0):
            self._integrator += cfg.depth_i * error * dt
        return min(cfg.pitch_max, max(-cfg.pitch_max, cfg.depth_p * error + self._integrator))

    def _record(self, t: Telemetry, elapsed: float, theta_d: float, theta_e_f: float, delta_f: float,
                decision: float) -> None:
        s = self.series
        s["time"].append(elapsed)
        s["thrust_ratio"].append(t.thrust_ratio)
        s["thrust_setpoint"].append(self.thrust_ratio)
        s["speed"].append(t.speed_water)
        s["pitch"].append(t.pitch)
        s["pitch_desired"].append(theta_d)
        s["pitch_error_filtered"].append(theta_e_f)
        s["elevator"].append(t.elevator)
        s["elevator_filtered"].append(delta_f)
        s["depth"].append(t.depth)
        s["decision"].append(decision)

    # ------------------------------------------------------------------ results
    def settle_time(self) -> float | None:
        """Time from the start to the last set-point change before the first quiet window (see module doc)."""
        window = self.config.settle_window_s
        if not self.series["time"]:
            return None
        end = self.series["time"][-1]
        # the move to a predicted start is a change too: settled means quiet after it
        changes = [0.0] if self.ramp_done_s is None else [self.ramp_done_s]
        previous = self.config.nominal_thrust if self.config.start_thrust is None else self.config.start_thrust
        for time_s, _decision, thrust in self.decisions:
            if thrust != previous:
                changes.append(time_s)
                previous = thrust
        for i, change in enumerate(changes):
            following = changes[i + 1] if i + 1 < len(changes) else end
            if following - change >= window - 1e-9:
                return change
        return None

    def reversals(self, since_s: float) -> int:
        """Direction reversals of the thrust set-point after ``since_s`` (a limit-cycle indicator)."""
        moves = [d for time_s, d, _ in self.decisions if time_s >= since_s and d != 0]
        return sum(1 for a, b in zip(moves, moves[1:]) if a != b)

    def max_depth_error(self, since_s: float | None = None) -> float:
        """Largest |z − z_sp| after ``since_s`` (default: after the start-up transient)."""
        if not math.isfinite(self._depth_setpoint):
            return math.nan
        times = np.asarray(self.series["time"])
        depth = np.asarray(self.series["depth"])
        mask = times >= (self.config.transient_s if since_s is None else since_s)
        return float(np.max(np.abs(depth[mask] - self._depth_setpoint))) if mask.any() else math.nan

    def result(self) -> MinSpeedResult:
        """The figures and the time series for plots (Fig. 5.22–5.24)."""
        speed = np.asarray(self.series["speed"], dtype=float)
        times = np.asarray(self.series["time"], dtype=float)
        tail = times >= (times[-1] - 10.0) if len(times) else np.zeros(0, dtype=bool)
        tail_speed = speed[tail & np.isfinite(speed)] if len(speed) else speed
        end = float(times[-1]) if len(times) else 0.0
        settle = self.settle_time()
        return MinSpeedResult(
            aborted=self.aborted, abort_reason=self.reason or "", thrust_ratio_final=self.thrust_ratio,
            speed_final=float(np.mean(tail_speed)) if len(tail_speed) else None, settle_time_s=settle,
            max_depth_error_m=self.max_depth_error(),
            max_depth_error_settled_m=self.max_depth_error(settle) if settle is not None else None,
            depth_setpoint_m=self._depth_setpoint if math.isfinite(self._depth_setpoint) else None,
            reversals_last_30s=self.reversals(end - 30.0), decisions=len(self.decisions),
            theta_e_crossover=self.seeker_config.theta_e_threshold, start_reached_s=self.ramp_done_s,
            governed_stalled=self.governed_stalled, depth_offset_max_m=self.max_depth_offset_m,
            depth_offset_faded_s=self.feedforward_faded_s, duration_s=end,
            series={name: list(values) for name, values in self.series.items()})
