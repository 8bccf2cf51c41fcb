"""The minimum-speed seeker's decision: a three-rule Mamdani system with largest-of-maximum
defuzzification (SPEC C7; thesis 002, §5.3.2, eq. 5.62–5.64, Fig. 5.19–5.21).

Written by hand because it is three rules on two inputs and scikit-fuzzy is not an allowed
dependency.

Rules (thesis §5.3.2.1):
  1. δs NotSaturated                → decreased (−1)
  2. θe Small and δs Saturated      → kept (0)
  3. θe Big   and δs Saturated      → increased (+1)

Inputs: the pitch error θe = θ − θd (negative values count as Small) and the elevator δs, both
low-pass filtered (eq. 5.64). Membership functions are complementary ramps (trapezoids) that cross
at 0.5 at θe_TS and at δmax − δFB; the ramp widths are not given in the text (Fig. 5.19 is missing
from the seed) and are parameters here. Because the sets are complementary and "and" is min, the
crisp surface depends only on the crossovers (as the three-colour surface of Fig. 5.21 shows).

Inference: min for "and"/implication (clipping), max aggregation, output sets are triangles centred
on −1, 0, +1 (half-width 0.5) on the universe [−1, 1]; the crisp output is the largest x at which
the aggregate reaches its maximum (LOM), rounded to the nearest output level (eq. 5.63). Ties
between rules therefore go to the larger (more cautious) output.

Departure from SPEC C7 (default on; ``hold_after_change_s = 0`` gives the thesis law): after every
change of the set-point, further moves are held ("kept") for ``hold_after_change_s`` = 4 s of
vehicle time, so the previous step has reached the filtered elevator before the next decision (on
STARFISH the filtered elevator lags the thrust by ≈ 4 s: surge time constant ≈ 2.7 s at Vmin plus
the 1 s input filter). The three rules and LOM are untouched; only the move is gated
(:func:`hold_decision`). Measured with sensor noise, seeds 1-6, Ts = 1 s, on the closed-loop harness
and on the product procedure (bench/bench_min_speed.py --hold): final TR 0.44 on 10/12 runs, 0.45 on
two (thesis law 0.42-0.49, within 2 % of TR* on 8/12), max depth error 0.24-0.26 m (thesis 0.53-0.65
m), ≤ 1 reversal in the last 30 s on 11/12 (thesis 7/12), after a kick to TR 0.60 quiet again within
61-100 s and at 0.44 by 300 s on 11/12 (thesis: never quiet again within 150 s); the same at
Ts = 0.5 s (where the thesis law limit-cycles). Cost: the descent from 0.70 takes one step per 4 s,
so settling takes 100-175 s (goal ≤ 60 s, met by neither law). A 3 s hold leaves 0.30-0.35 m of
depth error, a 6 s hold 0.20-0.22 m but settles in 150-185 s. Tried and worse: holding only after a reversal (3/4/6 s: slow large limit cycles, depth
errors 0.6-1.8 m — the hold keeps the thrust below TR* while the depth error grows), a decision that
must repeat on two periods, Schmitt bands on the crossovers, fast until the first reversal then slow.
Second departure: the θe crossover is raised to what the autopilot's pitch loop needs
(:func:`pitch_error_crossover`, eq. M.1: 0.0155 rad for Table 5.1's Kpθ = −20). At the optimum the
elevator sits near the crossover while the pitch integrator catches up over minutes, so the
proportional error alone, (δmax − δFB)/|Kpθ| = 0.0105 rad, sits on the thesis' 0.01 and the keep
and increase rules trade places on sensor noise. Measured (bench/bench_min_speed.py --predicted,
levelled start, seeds 1-6): settled after 38-42 s (0.01: 52-123 s), T_R 0.440 on every seed, after a
kick to 0.60 back at 0.44 on every seed; 0.02 settles in 28-46 s but stays at 0.45 after the kick
on three seeds of six.

Pure numerics: no I/O, no clock.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from companion.checks import require_non_negative, require_positive, require_range

DECREASE = -1
KEEP = 0
INCREASE = 1

_OUTPUT_LEVELS = (DECREASE, KEEP, INCREASE)
_OUTPUT_HALF_WIDTH = 0.5
_UNIVERSE = np.linspace(-1.0, 1.0, 2001)


@dataclass(frozen=True)
class SeekerConfig:
    """Design parameters of the seeker (thesis Table 5.1; SPEC C7)."""

    # rad, θe_TS: Small/Big crossover (0.01 in the thesis' simulation, 0.02 at sea); the seeker raises
    # it to what the autopilot's pitch loop needs (pitch_error_crossover, eq. M.1)
    theta_e_threshold: float = 0.01
    fin_budget: float = 0.05  # rad, δFB: Saturated when δs > δmax − δFB
    delta_max: float = 0.26  # rad, elevator limit of the pitch loop
    theta_e_ramp: float = 0.01  # rad, width of the Small→Big ramp (centred on θe_TS)
    delta_ramp: float = 0.02  # rad, width of the NotSaturated→Saturated ramp
    saturation_sign: float = 1.0  # +1: the elevator saturates at +δmax when holding the vehicle down
    step: float = 0.01  # ΔT, thrust-ratio change per decision
    period_s: float = 1.0  # Ts, seeking period (vehicle time)
    filter_r: float = 0.95  # r of eq. 5.64 at the reference sample interval
    filter_reference_dt: float = 0.05  # s, the sample interval r was chosen for (20 Hz)
    hold_after_change_s: float = 4.0  # s, keep for this long after every change (0: thesis law; see module doc)

    def __post_init__(self) -> None:
        require_positive(self, "theta_e_threshold", "delta_max", "step", "period_s", "filter_reference_dt")
        require_non_negative(self, "fin_budget", "theta_e_ramp", "delta_ramp", "hold_after_change_s")
        require_range(self, "filter_r", 0.0, 0.9999)
        if self.saturation_sign not in (1.0, -1.0):
            raise ValueError(f"SeekerConfig.saturation_sign must be +1 or -1, not {self.saturation_sign!r}")

    @property
    def delta_crossover(self) -> float:
        return self.delta_max - self.fin_budget


def pitch_error_crossover(config: SeekerConfig, pitch_p: float | None) -> float:
    """θe_TS for an autopilot whose pitch loop has the proportional gain ``pitch_p`` (eq. M.1).

    The pitch PI holds an elevator δ with the error θe = (δ − Iθ)/|Kpθ|; before its integrator Iθ has
    caught up with a new trim (Kpθ/Kiθ = 200 s for Table 5.1) the proportional term alone holds it.
    A loop that holds the crossover elevator δmax − δFB on its proportional term is following the
    pitch, not failing to: that error must count as fully Small, so the crossover sits half a ramp
    above it: θe_TS = max(θe_TS configured, (δmax − δFB)/|Kpθ| + ramp/2). For Table 5.1 (Kpθ = −20):
    0.0105 + 0.005 = 0.0155 rad, between the thesis' 0.01 (simulation) and 0.02 (at sea). Without a
    known gain (None, 0 or not finite) the configured value stands.
    """
    if pitch_p is None or not math.isfinite(pitch_p) or pitch_p == 0.0:
        return config.theta_e_threshold
    held_on_proportional = config.delta_crossover / abs(pitch_p)
    return max(config.theta_e_threshold, held_on_proportional + config.theta_e_ramp / 2.0)


def ramp_up(x: float, centre: float, width: float) -> float:
    """0 below centre − width/2, 1 above centre + width/2, linear between (0.5 at ``centre``)."""
    if width <= 0.0:
        return 1.0 if x > centre else (0.5 if x == centre else 0.0)
    return min(1.0, max(0.0, (x - centre) / width + 0.5))


@dataclass(frozen=True)
class Memberships:
    theta_small: float
    theta_big: float
    delta_not_saturated: float
    delta_saturated: float


def memberships(theta_e: float, delta_s: float, config: SeekerConfig) -> Memberships:
    """Degrees of membership of the two inputs (Fig. 5.19); complementary pairs."""
    big = ramp_up(theta_e, config.theta_e_threshold, config.theta_e_ramp)
    sat = ramp_up(config.saturation_sign * delta_s, config.delta_crossover, config.delta_ramp)
    return Memberships(1.0 - big, big, 1.0 - sat, sat)


def rule_strengths(theta_e: float, delta_s: float, config: SeekerConfig) -> tuple[float, float, float]:
    """Firing strengths (decrease, keep, increase) of rules 1, 2, 3 (min for "and")."""
    mu = memberships(theta_e, delta_s, config)
    return (
        mu.delta_not_saturated,
        min(mu.theta_small, mu.delta_saturated),
        min(mu.theta_big, mu.delta_saturated),
    )


def _output_set(level: int) -> np.ndarray:
    return np.clip(1.0 - np.abs(_UNIVERSE - level) / _OUTPUT_HALF_WIDTH, 0.0, 1.0)


_OUTPUT_SETS = tuple(_output_set(level) for level in _OUTPUT_LEVELS)


def defuzzify_lom(strengths: tuple[float, float, float]) -> float:
    """Mamdani max–min aggregation of the clipped output sets and largest-of-maximum defuzzification."""
    aggregate = np.zeros_like(_UNIVERSE)
    for strength, output_set in zip(strengths, _OUTPUT_SETS):
        aggregate = np.maximum(aggregate, np.minimum(output_set, strength))
    peak = aggregate.max()
    return float(_UNIVERSE[np.nonzero(aggregate >= peak - 1e-12)[0][-1]])


def decide(theta_e: float, delta_s: float, config: SeekerConfig) -> int:
    """The FIS decision −1 / 0 / +1 for filtered inputs (eq. 5.63)."""
    crisp = defuzzify_lom(rule_strengths(theta_e, delta_s, config))
    return int(min(_OUTPUT_LEVELS, key=lambda level: abs(level - crisp)))


def hold_decision(decision: int, time_s: float, last_change_s: float, config: SeekerConfig) -> int:
    """The FIS decision, turned into KEEP while less than ``hold_after_change_s`` has passed since
    the set-point last changed at ``last_change_s`` (vehicle time; −inf: never). Not in the thesis
    (see module doc); with ``hold_after_change_s = 0`` the decision passes unchanged."""
    if decision != KEEP and time_s - last_change_s < config.hold_after_change_s - 1e-9:
        return KEEP
    return decision


def filter_coefficient(dt: float, config: SeekerConfig) -> float:
    """r for a sample interval dt, so the filter's time constant does not depend on the rate.

    Eq. 5.64 gives r = exp(−1/d) with d in samples; r = 0.95 at 20 Hz is a time constant of
    −Δt_ref / ln r ≈ 0.975 s, kept for any dt: r(dt) = r_ref^(dt / Δt_ref).
    """
    if dt <= 0.0:
        return 1.0
    return config.filter_r ** (dt / config.filter_reference_dt)


class LowPass:
    """y(n) = (1 − r)·x(n) + r·y(n − 1) (eq. 5.64) with r following the actual sample interval."""

    def __init__(self, config: SeekerConfig) -> None:
        self._config = config
        self.value = math.nan
        self._last_time = math.nan

    def update(self, time_s: float, x: float) -> float:
        if not math.isfinite(x):
            return self.value
        if not math.isfinite(self.value):
            self.value = x
        else:
            r = filter_coefficient(time_s - self._last_time, self._config)
            self.value = (1.0 - r) * x + r * self.value
        self._last_time = time_s
        return self.value


def next_thrust(thrust_ratio: float, decision: int, config: SeekerConfig, floor: float, ceiling: float = 1.0) -> float:
    """T_R(k) = T_R(k−1) + ΔT_R (eq. 5.62), clamped to [floor, ceiling]."""
    return min(ceiling, max(floor, thrust_ratio + decision * config.step))
