"""Passive yaw identification and drift detection for health monitoring (the
thesis' future work §6.2.1: faults seen as drift of the identified parameters). Pure numerics.

**Passive estimates.** The heading and the rudder pass, sample by sample, through the same
state-variable filters λ²/(s+λ)² as the online identifier (SPEC C3, eq. 3.26–3.31), giving the
regression ψ̈f = [ψ̇f, δf, −1]·[a22, b2, C0]ᵀ (eq. 3.14–3.15). The filters run continuously
(restarted after a gap and warmed up for ``warm_up_s`` before their output is used); the rows are
collected over consecutive windows of ``window_s`` seconds, and each window gives the least-squares
estimate Θ̂ (the RLS of the identifier with P0 → ∞ gives the same numbers) with its covariance.

**Covariance.** The filtered equation error is coloured (the SVF itself correlates neighbouring
samples over ~1/λ), so σ̂²(ΦᵀΦ)⁻¹, the RLS's white-noise covariance, is far too optimistic. The
window's covariance is the Newey–West (HAC) sandwich (ΦᵀΦ)⁻¹ S (ΦᵀΦ)⁻¹ with
S = Σ_{|l|≤L} (1 − |l|/(L+1)) Σ_k φ_k e_k e_{k−l} φ_{k−l}ᵀ over ``hac_lag_s`` seconds of lags.

**Test.** Against the reference model at the window's speed (the stored schedule), each parameter's
standardised deviation z = (θ̂ − θ_ref)/√(σ̂²_θ + (ε·θ_ref)²) — the tolerance ε (``tolerance``)
covers what separates a passive estimate from the campaign's on a healthy vehicle (nonlinear
damping at other turn rates, closed-loop data, the fit of the speed laws) — feeds a two-sided CUSUM
(Page): S⁺ ← max(0, S⁺ + z − k), S⁻ ← max(0, S⁻ − z − k); an alarm when either reaches h. Windows
without the information to say anything (no steady speed, no manoeuvre — too little rudder activity
or heading change —, a relative σ above ``max_relative_sigma``, a speed outside the reference's
range) are skipped and leave the sums unchanged.

**Speed-scaled channels** (``speed_exponents`` = (p, n), for eq. L.3 of
:mod:`companion.numerics.parameter_tracking`): the products u^p·r and uⁿ·δ (r the measured yaw rate when given,
else the heading's difference quotient, which mission learning uses) pass through filters of their own, so a window's rows can be
written at any speed: F[(u/u_b)^p·r] = u_b^(−p)·F[u^p·r] exactly, where scaling the filtered rate by
the speed at each sample is not (the filter lags the speed's own change: on a boat slowing 30 % in
its turns that left a22 and b2 11 % low, the filtered products 3 %).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from companion.checks import require_choice, require_non_negative, require_positive
from .angles import wrap_pi
from .svf import DEFAULT_BANDWIDTH, StateVariableFilter

PARAMETERS = ("a22", "b2")


@dataclass(frozen=True)
class DriftConfig:
    """Window, filters, covariance and CUSUM settings (module docstring; defaults measured with
    bench/bench_health.py)."""

    window_s: float = 20.0
    bandwidth: float = DEFAULT_BANDWIDTH
    output_hold: str = "foh"
    input_hold: str = "foh"
    warm_up_s: float = 8.0
    max_gap_s: float = 0.5
    hac_lag_s: float = 3.0
    speed_tolerance: float = 0.08  # (max − min)/mean of the window's speed for a steady window
    min_rudder_std: float = 0.005  # rad
    # a window must hold a manoeuvre: with a small heading change the noise in the filtered heading
    # rate (a regressor) is no longer small against its signal, and a22 is biased towards 0
    # (errors in variables), which no covariance shows
    min_heading_span_deg: float = 10.0
    max_relative_sigma: float = 0.1  # σ/|θ_ref| of a22 or b2 above it: the window says too little
    reference_margin: float = 0.1  # a speed within [0.9·u_min, 1.1·u_max] of the reference's range
    tolerance: float = 0.06  # ε, relative
    allowance: float = 1.0  # k (in units of z)
    threshold: float = 3.5  # h: one window with z ≥ 4.5 (a 27 % shift at ε = 6 %) alarms at once

    def __post_init__(self) -> None:
        require_positive(self, "window_s", "bandwidth", "warm_up_s", "max_gap_s", "hac_lag_s", "speed_tolerance",
                         "min_rudder_std", "min_heading_span_deg", "max_relative_sigma", "tolerance", "threshold")
        require_non_negative(self, "reference_margin", "allowance")
        require_choice(self, "output_hold", ("foh", "zoh"))
        require_choice(self, "input_hold", ("foh", "zoh"))


@dataclass(frozen=True)
class WindowRecord:
    """A window's samples, kept when asked (``PassiveYawEstimator(keep_records=True)``): the
    regression rows Φ = [ψ̇f, δf, −1] and targets ψ̈f (eq. 3.14–3.15), and the raw series a model is
    validated on (eq. 3.35): times, unwrapped heading, rudder, and the yaw rate at the start."""

    phi: np.ndarray
    y: np.ndarray
    times: np.ndarray
    heading: np.ndarray
    rudder: np.ndarray
    yaw_rate0: float
    speed: np.ndarray | None = None  # per sample (m/s; NaN where unknown)
    hac_lags: int = 1  # the Newey–West lags the window's covariance was computed with
    # per-sample factors of a22 and b2 when the rows were normalised to one speed (eq. L.3), else None
    a22_scale: np.ndarray | None = None
    b2_scale: np.ndarray | None = None
    # the filtered products F[u^p·r] and F[uⁿ·δ] per row, and (p, n) (speed-scaled channels), else None
    scaled: np.ndarray | None = None
    scaled_exponents: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        n = len(self.y)
        if self.phi.shape != (n, 3) or not len(self.times) == len(self.heading) == len(self.rudder) == n:
            raise ValueError("a window record's rows and series must have one length")
        for name in ("speed", "a22_scale", "b2_scale", "scaled"):
            series = getattr(self, name)
            if series is not None and len(series) != n:
                raise ValueError(f"a window record's {name} must have one value per row")
        if (self.scaled is None) != (self.scaled_exponents is None):
            raise ValueError("a window record's scaled channels come with their exponents")
        if self.hac_lags < 1:
            raise ValueError(f"a window record's Newey–West lags are at least 1, not {self.hac_lags}")


@dataclass
class WindowEstimate:
    """One window's passive estimate: Θ̂ = [a22, b2, C0] and its HAC covariance (and, when kept,
    its samples)."""

    t_start: float
    t_end: float
    samples: int
    speed: float
    speed_spread: float
    rudder_std: float
    heading_span_deg: float
    theta: list[float]
    covariance: list[list[float]]
    record: WindowRecord | None = field(default=None, repr=False)

    @property
    def a22(self) -> float:
        return self.theta[0]

    @property
    def b2(self) -> float:
        return self.theta[1]

    def sigma(self, index: int) -> float:
        return math.sqrt(max(self.covariance[index][index], 0.0))


def hac_least_squares(phi: np.ndarray, y: np.ndarray, lags: int) -> tuple[np.ndarray, np.ndarray]:
    """Θ̂ = argmin ‖y − ΦΘ‖ and its Newey–West covariance with Bartlett weights over ``lags`` lags."""
    gram = phi.T @ phi
    theta = np.linalg.solve(gram, phi.T @ y)
    scores = phi * (y - phi @ theta)[:, None]
    meat = scores.T @ scores
    for lag in range(1, min(lags, len(y) - 1) + 1):
        weight = 1.0 - lag / (lags + 1.0)
        cross = scores[lag:].T @ scores[:-lag]
        meat += weight * (cross + cross.T)
    bread = np.linalg.inv(gram)
    return theta, bread @ meat @ bread


class PassiveYawEstimator:
    """Streams (time, heading, rudder, speed) samples; :meth:`add` returns a :class:`WindowEstimate`
    when a window closes (else None). See the module docstring."""

    def __init__(self, config: DriftConfig = DriftConfig(), *, keep_records: bool = False,
                 speed_exponents: tuple[float, float] | None = None) -> None:
        self.config = config
        self.keep_records = keep_records
        self.speed_exponents = speed_exponents
        self._heading_filter = StateVariableFilter(config.bandwidth, hold=config.output_hold)
        self._rudder_filter = StateVariableFilter(config.bandwidth, hold=config.input_hold)
        # the speed-scaled channels (module docstring): u^p·r and uⁿ·δ
        self._scaled_filters = (StateVariableFilter(config.bandwidth, hold=config.output_hold),
                                StateVariableFilter(config.bandwidth, hold=config.input_hold))
        self._scaled: list[tuple[float, float]] = []
        self._last_speed = math.nan
        self._last_t: float | None = None
        self._last_raw = 0.0
        self._unwrapped = 0.0
        self._ready_at = math.inf
        self._rows: list[tuple[float, float, float]] = []
        self._targets: list[float] = []
        self._speeds: list[float] = []
        self._rudders: list[float] = []
        self._headings: list[float] = []
        self._times: list[float] = []
        self._yaw_rate0 = 0.0
        self._window_start: float | None = None
        self.restarts = 0

    def _scaled_inputs(self, rate: float, rudder: float, speed: float) -> tuple[float, float]:
        """u^p·r and uⁿ·δ at this sample (the last finite speed held; NaN before any)."""
        if math.isfinite(speed):
            self._last_speed = speed
        p, n = self.speed_exponents or (0.0, 0.0)
        u = max(self._last_speed, 0.0)
        return u ** p * rate, u ** n * rudder

    def _restart(self, t: float, heading: float, rudder: float) -> None:
        self._heading_filter.reset(heading)
        self._rudder_filter.reset(rudder)
        for channel, value in zip(self._scaled_filters, self._scaled_inputs(0.0, rudder, self._last_speed)):
            channel.reset(value if math.isfinite(value) else 0.0)
        self._unwrapped = heading
        self._ready_at = t + self.config.warm_up_s
        self._clear()
        self.restarts += 1

    def _clear(self) -> None:
        self._rows, self._targets, self._speeds, self._rudders, self._headings = [], [], [], [], []
        self._times, self._scaled = [], []
        self._window_start = None

    def add(self, t: float, heading: float, rudder: float, speed: float,
            yaw_rate: float = math.nan) -> WindowEstimate | None:
        """One sample (``yaw_rate`` measured, rad/s: for the speed-scaled channels, else the heading's
        difference quotient is used); a :class:`WindowEstimate` when a window closes."""
        if not all(math.isfinite(v) for v in (t, heading, rudder)):
            self._last_t = None  # a missing value: restart at the next complete sample
            return None
        if self._last_t is not None and not (t > self._last_t):
            return None
        if self._last_t is None or t - self._last_t > self.config.max_gap_s:
            self._last_t, self._last_raw = t, heading
            self._restart(t, heading, rudder)
            return None
        dt = t - self._last_t
        turned = wrap_pi(heading - self._last_raw)
        self._unwrapped += turned
        self._last_t, self._last_raw = t, heading
        _, rate_f, acc_f = self._heading_filter.update(self._unwrapped, dt)
        rudder_f = self._rudder_filter.update(rudder, dt)[0]
        if self.speed_exponents is not None:
            rate = yaw_rate if math.isfinite(yaw_rate) else turned / dt
            inputs = self._scaled_inputs(rate, rudder, speed)
            rate_scaled, rudder_scaled = (f.update(v if math.isfinite(v) else 0.0, dt)[0]
                                          for f, v in zip(self._scaled_filters, inputs))
            scaled = (rate_scaled, rudder_scaled)
        if t < self._ready_at:
            return None
        if self._window_start is None:
            self._window_start = t
            self._yaw_rate0 = rate_f  # the filtered rate: the record's initial condition (eq. 3.35)
        self._rows.append((rate_f, rudder_f, -1.0))
        if self.speed_exponents is not None:
            self._scaled.append(scaled)
        self._targets.append(acc_f)
        self._speeds.append(speed)
        self._rudders.append(rudder)
        self._headings.append(self._unwrapped)
        self._times.append(t)
        if t - self._window_start < self.config.window_s:
            return None
        estimate = self._estimate(t)
        self._clear()
        return estimate

    def _estimate(self, t_end: float) -> WindowEstimate | None:
        window_start = self._window_start
        if window_start is None:
            raise RuntimeError("no window under way to estimate from")
        phi, y = np.asarray(self._rows), np.asarray(self._targets)
        speeds = np.asarray(self._speeds, dtype=float)
        speeds = speeds[np.isfinite(speeds)]
        speed = float(np.mean(speeds)) if speeds.size else math.nan
        spread = float((speeds.max() - speeds.min()) / speed) if speeds.size and speed > 0 else math.nan
        duration = t_end - window_start
        lags = max(1, int(round(self.config.hac_lag_s * (len(y) - 1) / max(duration, 1e-9))))
        try:
            theta, covariance = hac_least_squares(phi, y, lags)
        except np.linalg.LinAlgError:
            return None
        record = WindowRecord(phi=phi, y=y, times=np.asarray(self._times), heading=np.asarray(self._headings),
                              rudder=np.asarray(self._rudders, dtype=float), yaw_rate0=float(self._yaw_rate0),
                              speed=np.asarray(self._speeds, dtype=float), hac_lags=lags,
                              scaled=np.asarray(self._scaled) if self.speed_exponents is not None else None,
                              scaled_exponents=self.speed_exponents) if self.keep_records else None
        return WindowEstimate(t_start=float(window_start), t_end=float(t_end), samples=len(y), speed=speed,
                              speed_spread=spread, rudder_std=float(np.std(self._rudders)),
                              heading_span_deg=math.degrees(max(self._headings) - min(self._headings)),
                              theta=[float(v) for v in theta], covariance=covariance.tolist(), record=record)


@dataclass
class Cusum:
    """Two-sided CUSUM (Page) on standardised deviations z: S⁺, S⁻ ≥ 0."""

    allowance: float
    threshold: float
    high: float = 0.0
    low: float = 0.0

    def add(self, z: float) -> bool:
        """Add one z; True when either sum reaches the threshold."""
        self.high = max(0.0, self.high + z - self.allowance)
        self.low = max(0.0, self.low - z - self.allowance)
        return self.statistic >= self.threshold

    @property
    def statistic(self) -> float:
        return max(self.high, self.low)

    @property
    def direction(self) -> int:
        """+1 when the upward sum leads, −1 the downward one."""
        return 1 if self.high >= self.low else -1


@dataclass
class DriftVerdict:
    """One window against the reference: per-parameter ratio θ̂/θ_ref, z and the CUSUM after it."""

    window: WindowEstimate
    used: bool
    reason: str = ""
    reference: dict[str, float] = field(default_factory=dict)
    ratio: dict[str, float] = field(default_factory=dict)
    z: dict[str, float] = field(default_factory=dict)
    cusum: dict[str, float] = field(default_factory=dict)
    alarm: str | None = None  # the parameter that reached the threshold


class DriftDetector:
    """CUSUMs of a22 and b2 against a reference ``reference(speed) -> (a22, b2)`` defined on
    ``speed_range`` (module docstring)."""

    def __init__(self, reference, speed_range: tuple[float, float], config: DriftConfig = DriftConfig()) -> None:
        self.reference = reference
        self.speed_range = speed_range
        self.config = config
        self.sums = {name: Cusum(config.allowance, config.threshold) for name in PARAMETERS}

    def _skip(self, window: WindowEstimate) -> str | None:
        c = self.config
        low, high = self.speed_range
        if not (window.speed_spread <= c.speed_tolerance):
            return f"speed not steady ({100 * window.speed_spread:.0f} %)"
        if not low * (1 - c.reference_margin) <= window.speed <= high * (1 + c.reference_margin):
            return f"no reference at {window.speed:.2f} m/s (models {low:.2f}–{high:.2f} m/s)"
        if window.rudder_std < c.min_rudder_std or window.heading_span_deg < c.min_heading_span_deg:
            return (f"too little excitation (rudder σ {window.rudder_std:.4f} rad, heading span "
                    f"{window.heading_span_deg:.1f}°)")
        return None

    def add(self, window: WindowEstimate) -> DriftVerdict:
        reason = self._skip(window)
        if reason is not None:
            return DriftVerdict(window, False, reason, cusum={n: s.statistic for n, s in self.sums.items()})
        a22_ref, b2_ref = self.reference(window.speed)
        relative = max(window.sigma(0) / abs(a22_ref), window.sigma(1) / abs(b2_ref))
        if not relative <= self.config.max_relative_sigma:
            return DriftVerdict(window, False, f"too little information (σ {100 * relative:.0f} % of the reference)",
                                cusum={n: s.statistic for n, s in self.sums.items()})
        verdict = DriftVerdict(window, True, reference={"a22": a22_ref, "b2": b2_ref})
        for index, name in enumerate(PARAMETERS):
            ref = verdict.reference[name]
            estimate = window.theta[index]
            spread = math.sqrt(window.sigma(index) ** 2 + (self.config.tolerance * ref) ** 2)
            z = (estimate - ref) / spread
            verdict.ratio[name] = estimate / ref
            verdict.z[name] = z
            if self.sums[name].add(z) and verdict.alarm is None:
                verdict.alarm = name
            verdict.cusum[name] = self.sums[name].statistic
        return verdict
