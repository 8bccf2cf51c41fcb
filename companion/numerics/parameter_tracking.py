"""The yaw model learned from a mission's own course changes, per speed band (eq. L.1). Pure numerics.

**Rows.** The passive estimator of health monitoring (:mod:`companion.numerics.drift`) runs the
heading and the rudder through the state-variable filters and closes a window every
``window_s`` seconds with its rows ψ̈f = [ψ̇f, δf, −1]·θ, θ = [a22, b2, C0] (eq. 3.14–3.15), kept
here (``keep_records``).

**Which windows.** A window is *informative* when the speed was steady, the rudder moved and the
heading turned by at least ``min_heading_span_deg`` (a course change of the mission), its own
least-squares estimate is physical (a22 < 0, b2 > 0) and known to ``max_relative_sigma`` by its
Newey–West covariance. Other windows are skipped with the reason.

**Closed-loop data.** On a mission the rudder is the autopilot's answer to the heading error, so
a disturbance that turns the boat is answered by the rudder and the equation error is correlated
with the regressor δf: equation-error least squares is biased, most where the rudder only answers
disturbances (a straight leg in waves). Three things keep the bias small and visible: (1) only
windows with a course change are used, where the set-point, an external signal uncorrelated with
the disturbance, drives most of the rudder's motion; (2) a constant yaw moment (current, wind,
an asymmetric hull) is the regressor −1's C0 and is estimated, not left in the error; (3) the
model is *validated* by output error (eq. 3.35) on a window it has not absorbed: the heading is
simulated from the recorded rudder, which a biased model does not reproduce.

**eq. L.1: tracking.** Per speed band a Kalman filter over θ (filterpy's ``KalmanFilter``) with a
random walk θ_k = θ_{k−1} + w, Q = diag((q·θ̂)²)·Δt, and each row a measurement
ψ̈f,k = φ_kᵀθ + e_k. With q = 0 it is the recursive weighted least squares over every row absorbed
(each window's rows weighted by 1/R of that window; the first window's estimate and covariance are
its start). The rows' error may be coloured (the SVF correlates neighbours over ~1/λ), so R is the
window's residual variance times the ratio of its Newey–West variance to the white-noise one when
that ratio exceeds 1 (never deflated below the white-noise variance); the first window's covariance
follows the same rule, so no window weighs more than its noise says.

**Bands.** A window joins the band whose centre speed is within ``band_width`` (relative) of its
speed, else it opens a band. A band's model is *validated* once ``min_windows`` windows were
absorbed and its model, before absorbing the next informative window, reproduced that window's
heading with R² ≥ ``min_r2``; a later failed validation withdraws it until one passes again.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from filterpy.kalman import KalmanFilter

from companion.checks import require_non_negative, require_positive, require_range
from .drift import WindowEstimate
from .identification import YawModel
from .validation import simulate_yaw, r_squared


@dataclass(frozen=True)
class TrackingConfig:
    """Which windows teach, how fast θ may wander, when a band's model is validated (module docstring)."""

    band_width: float = 0.12  # relative half-width of a speed band
    process_noise: float = 0.003  # q: relative σ of θ's random walk per √s
    min_windows: int = 2
    min_r2: float = 0.9
    speed_tolerance: float = 0.08  # (max − min)/mean speed of a steady window
    min_rudder_std: float = 0.005  # rad
    min_heading_span_deg: float = 10.0
    max_relative_sigma: float = 0.15

    def __post_init__(self) -> None:
        require_positive(self, "band_width", "min_windows", "speed_tolerance", "min_rudder_std",
                         "min_heading_span_deg", "max_relative_sigma")
        require_range(self, "min_r2", 0.0, 1.0)
        require_non_negative(self, "process_noise")


def skip_reason(window: WindowEstimate, config: TrackingConfig) -> str | None:
    """Why a window cannot teach the model (module docstring), None when it can."""
    if window.record is None:
        return "no samples kept"
    if not window.speed_spread <= config.speed_tolerance:
        return f"speed not steady ({100 * window.speed_spread:.0f} %)"
    if window.rudder_std < config.min_rudder_std or window.heading_span_deg < config.min_heading_span_deg:
        return f"no course change (rudder σ {window.rudder_std:.4f} rad, heading span {window.heading_span_deg:.1f}°)"
    if not (window.a22 < 0.0 and window.b2 > 0.0):
        return f"not a physical model (a22 {window.a22:.3g}, b2 {window.b2:.3g})"
    relative = max(window.sigma(0) / abs(window.a22), window.sigma(1) / abs(window.b2))
    if not relative <= config.max_relative_sigma:
        return f"too little information (σ {100 * relative:.0f} % of the estimate)"
    return None


def _white_and_hac(window: WindowEstimate) -> tuple[float, float]:
    """The window's residual variance, and the ratio of its Newey–West to white-noise variance of θ."""
    record = window.record
    theta = np.asarray(window.theta)
    residual = record.y - record.phi @ theta
    sigma2 = float(np.mean(residual ** 2))
    white = sigma2 * np.linalg.inv(record.phi.T @ record.phi)
    hac = np.asarray(window.covariance)
    ratio = float(np.trace(hac) / np.trace(white)) if np.trace(white) > 0 else 1.0
    return max(sigma2, 1e-12), max(ratio, 1.0)


class ParameterTracker:
    """eq. L.1 over one speed band: started from its first window's estimate and covariance."""

    def __init__(self, first: WindowEstimate, process_noise: float) -> None:
        self.process_noise = process_noise
        self.filter = KalmanFilter(dim_x=3, dim_z=1)
        self.filter.x = np.asarray(first.theta, dtype=float).reshape(3, 1)
        sigma2, ratio = _white_and_hac(first)  # the same noise rule as every later window's rows
        record = first.record
        self.filter.P = ratio * sigma2 * np.linalg.inv(record.phi.T @ record.phi) \
            + np.diag(np.square(1e-6 * np.abs(first.theta)))
        self.filter.F = np.eye(3)
        self.last_t = first.t_end
        self.windows = 1

    def absorb(self, window: WindowEstimate) -> None:
        """Every row of ``window`` as one measurement, after the random walk since the last row."""
        record = window.record
        sigma2, ratio = _white_and_hac(window)
        noise = sigma2 * ratio
        kf = self.filter
        scale = np.square(self.process_noise * np.abs(kf.x[:, 0]))
        previous = self.last_t
        for t, phi, y in zip(record.times, record.phi, record.y):
            dt = max(float(t - previous), 0.0)
            previous = t
            if dt > 0.0 and self.process_noise > 0.0:
                kf.predict(Q=np.diag(scale * dt))
            kf.update(np.array([[y]]), R=np.array([[noise]]), H=phi.reshape(1, 3))
        self.last_t = float(previous)
        self.windows += 1

    @property
    def theta(self) -> np.ndarray:
        return self.filter.x[:, 0].copy()

    def model(self) -> YawModel:
        """ṙ = a22·r + b2·(δ − δ0), δ0 = C0/b2 (eq. 3.6–3.7), with θ's covariance."""
        a22, b2, c0 = (float(v) for v in self.theta)
        return YawModel(a22=a22, b2=b2, delta0=c0 / b2 if b2 != 0.0 else 0.0, covariance=self.filter.P.copy())


def validate_on(model: YawModel, window: WindowEstimate) -> float:
    """R² (eq. 3.35) of ``model``'s heading simulated on the window's recorded rudder."""
    record = window.record
    simulated = simulate_yaw(model, record.times, record.rudder, float(record.heading[0]), record.yaw_rate0)
    return float(r_squared(simulated, record.heading))


@dataclass
class SpeedBand:
    """One band's tracker, its centre speed and its validations (time, R²)."""

    speed: float
    tracker: ParameterTracker
    speeds: list[float] = field(default_factory=list)
    validations: list[tuple[float, float]] = field(default_factory=list)

    def validated(self, config: TrackingConfig) -> bool:
        return (self.tracker.windows >= config.min_windows and bool(self.validations)
                and self.validations[-1][1] >= config.min_r2)

    def model(self) -> YawModel:
        return self.tracker.model()


@dataclass(frozen=True)
class WindowOutcome:
    """What one closed window did: skipped (with the reason), or absorbed by a band, validated first
    (R², NaN when the band had too few windows to validate)."""

    t_end: float
    speed: float
    reason: str | None = None
    band: int | None = None
    r2: float = math.nan

    @property
    def used(self) -> bool:
        return self.reason is None

    def to_dict(self) -> dict:
        return {"t_end": self.t_end, "speed": self.speed, "reason": self.reason, "band": self.band,
                "r2": self.r2 if math.isfinite(self.r2) else None}


class MissionModels:
    """The bands of one mission (module docstring): ``add`` each closed window."""

    def __init__(self, config: TrackingConfig = TrackingConfig()) -> None:
        self.config = config
        self.bands: list[SpeedBand] = []

    def _band_for(self, speed: float) -> int | None:
        near = [(abs(b.speed - speed) / b.speed, i) for i, b in enumerate(self.bands)
                if abs(b.speed - speed) <= self.config.band_width * b.speed]
        return min(near)[1] if near else None

    def add(self, window: WindowEstimate) -> WindowOutcome:
        reason = skip_reason(window, self.config)
        if reason is not None:
            return WindowOutcome(window.t_end, window.speed, reason=reason)
        index = self._band_for(window.speed)
        if index is None:
            self.bands.append(SpeedBand(speed=window.speed, tracker=ParameterTracker(window, self.config.process_noise),
                                        speeds=[window.speed]))
            return WindowOutcome(window.t_end, window.speed, band=len(self.bands) - 1)
        band = self.bands[index]
        r2 = math.nan
        if band.tracker.windows >= self.config.min_windows:
            r2 = validate_on(band.model(), window)  # held out: judged before it is absorbed
            band.validations.append((window.t_end, r2))
        band.tracker.absorb(window)
        band.speeds.append(window.speed)
        band.speed = float(np.mean(band.speeds))
        return WindowOutcome(window.t_end, window.speed, band=index, r2=r2)

    def validated(self) -> list[tuple[float, YawModel]]:
        """(centre speed, model) of every validated band, slowest first."""
        return sorted(((b.speed, b.model()) for b in self.bands if b.validated(self.config)), key=lambda p: p[0])
