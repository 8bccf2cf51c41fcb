"""Steady-state manoeuvring characteristics under an unknown current (SPEC C8; Hegrenæs et al.).

Two least-squares formulations from the HUGIN 4500 paper (seed ``000_*``):

* **Straight legs** (square patterns), eq. 5, 7, 8: the body velocity over ground is
  ``z = v_b = R_mbᵀ·[vc_n, vc_e, 0] + v_wb = [c1 c2]·[vc_n, vc_e] + v_wb`` with c1, c2 the first two
  columns of ``R_m^b = R_mbᵀ``; stacking all samples gives the linear problem ``Z = H·θ`` with
  ``θ = (v_wb (3), vc_n, vc_e)``, solved with :func:`numpy.linalg.lstsq` (on the triangle of a
  block-wise QR of ``H``: the same solution, in memory bounded by one block).
* **Steady turns**, eq. 9, 10: ``p(t) = r0 + vc·t + R·[cos(ωt − φ0), sin(ωt − φ0)]`` fitted to the
  horizontal positions with :func:`scipy.optimize.least_squares`.

Conventions (NED, the paper's {m} frame): x north, y east, z down; angles in radians.
**Current direction**: ``current_dir_deg`` is the direction the current flows **towards**, in
degrees 0–360 measured from north, clockwise (the paper's eq. 11, β_w = atan2(vc_e, vc_n); the
oceanographic convention: 90° = water moving towards the east). A turn with ω > 0 is clockwise seen
from above (a starboard turn); the radius R is always positive.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares
from scipy.signal import savgol_filter
from scipy.spatial.transform import Rotation

log = logging.getLogger(__name__)

__all__ = [
    "StraightLegFit",
    "TurnFit",
    "body_to_ned_matrices",
    "ned_to_body",
    "current_direction_deg",
    "fit_straight_legs",
    "fit_steady_turn",
    "heading_rate",
    "steady_straight_mask",
    "steady_turn_mask",
    "water_relative_velocity",
]


# --------------------------------------------------------------------------- geometry helpers
def body_to_ned_matrices(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Rotation matrices R_mb (body → NED), shape (N, 3, 3), from ZYX Euler angles (yaw, pitch, roll)."""
    angles = np.column_stack([np.asarray(yaw, float), np.asarray(pitch, float), np.asarray(roll, float)])
    return Rotation.from_euler("ZYX", angles).as_matrix()


def ned_to_body(roll, pitch, yaw, vel_ned: np.ndarray) -> np.ndarray:
    """Velocity over ground in body axes, ``v_b = R_mbᵀ·v_ned`` (paper eq. 3), shape (N, 3)."""
    r_mb = body_to_ned_matrices(np.atleast_1d(roll), np.atleast_1d(pitch), np.atleast_1d(yaw))
    return np.einsum("nji,nj->ni", r_mb, np.atleast_2d(np.asarray(vel_ned, float)))


def current_direction_deg(current_north: float, current_east: float) -> float:
    """Direction the current flows TOWARDS, 0–360° from north clockwise (paper eq. 11)."""
    return float(math.degrees(math.atan2(current_east, current_north)) % 360.0)


def heading_rate(t: np.ndarray, yaw: np.ndarray, window_s: float = 5.0) -> np.ndarray:
    """Smoothed heading rate (rad/s) of the unwrapped yaw: Savitzky–Golay first derivative.

    The samples must be roughly uniform in time; the window is converted to samples with the median
    sample interval (at least 5 samples, odd).
    """
    t = np.asarray(t, float)
    psi = np.unwrap(np.asarray(yaw, float))
    if t.size < 5:
        return np.gradient(psi, t) if t.size > 1 else np.zeros_like(psi)
    dt = float(np.median(np.diff(t)))
    window = max(5, int(round(window_s / dt)) | 1)
    window = min(window, t.size if t.size % 2 else t.size - 1)
    if window < 5:
        return np.gradient(psi, t)
    return savgol_filter(psi, window, polyorder=2, deriv=1, delta=dt)


# --------------------------------------------------------------------------- transient cutting
def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Contiguous runs [start, stop) where ``mask`` is true."""
    padded = np.concatenate([[False], mask, [False]]).astype(np.int8)
    edges = np.flatnonzero(np.diff(padded))
    return list(zip(edges[::2], edges[1::2]))


def _settled_from(t: np.ndarray, deviation: np.ndarray, tolerance: float) -> int:
    """Index after the last sample whose deviation exceeds the tolerance (the settling point)."""
    bad = np.flatnonzero(deviation > tolerance)
    return int(bad[-1] + 1) if bad.size else 0


def steady_straight_mask(
    t: np.ndarray,
    yaw: np.ndarray,
    vel_body: np.ndarray,
    rate_tol: float = math.radians(0.5),
    speed_tol: float = 0.02,
    min_leg_s: float = 20.0,
    window_s: float = 5.0,
) -> np.ndarray:
    """Samples on steady straight legs: transients after heading changes cut automatically.

    A leg is a contiguous run where the smoothed heading rate stays below ``rate_tol``; within it,
    samples before the horizontal body velocity over ground (smoothed) settles within ``speed_tol``
    of the leg's final value (median of its second half) are discarded; legs shorter than
    ``min_leg_s`` after cutting are dropped.
    """
    t = np.asarray(t, float)
    vel_body = np.asarray(vel_body, float)
    rate = heading_rate(t, yaw, window_s)
    mask = np.zeros(t.size, bool)
    dt = float(np.median(np.diff(t))) if t.size > 1 else 1.0
    smooth_n = max(1, int(round(window_s / dt)))
    kernel = np.ones(smooth_n) / smooth_n
    for start, stop in _runs(np.abs(rate) < rate_tol):
        if t[stop - 1] - t[start] < min_leg_s:
            continue
        uv = vel_body[start:stop, :2]
        smooth = np.column_stack([np.convolve(uv[:, k], kernel, mode="same") for k in range(2)])
        final = np.median(uv[uv.shape[0] // 2 :], axis=0)
        deviation = np.hypot(*(smooth - final).T)
        # the convolution's edges are biased; ignore the last half window when locating the settle point
        edge = min(smooth_n // 2, deviation.size // 4)
        if edge:
            deviation[-edge:] = 0.0
        first = start + _settled_from(t[start:stop], deviation, speed_tol)
        if t[stop - 1] - t[first] >= min_leg_s:
            mask[first:stop] = True
    return mask


def steady_turn_mask(
    t: np.ndarray,
    yaw: np.ndarray,
    rate_tol: float = math.radians(0.3),
    window_s: float = 5.0,
) -> np.ndarray:
    """Samples of the steady part of a turn: from the moment the smoothed heading rate settles
    within ``rate_tol`` of its final value (median over the second half) to the end."""
    t = np.asarray(t, float)
    rate = heading_rate(t, yaw, window_s)
    final = float(np.median(rate[rate.size // 2 :]))
    deviation = np.abs(rate - final)
    dt = float(np.median(np.diff(t))) if t.size > 1 else 1.0
    edge = min(int(round(window_s / dt)) // 2, deviation.size // 4)
    if edge:
        deviation[-edge:] = 0.0
    mask = np.zeros(t.size, bool)
    mask[_settled_from(t, deviation, rate_tol) :] = True
    return mask


# --------------------------------------------------------------------------- straight legs
@dataclass(frozen=True)
class StraightLegFit:
    """Result of the stacked linear LS of eq. 7–8.

    ``velocity_water`` = v_wb (surge, sway, heave relative to the water, body axes, m/s);
    ``current`` = (north, east) m/s; ``covariance`` of θ = (u, v, w, vc_n, vc_e) is
    ``σ̂²·(HᵀH)⁻¹`` with ``σ̂² = J/(3N − 5)``; ``condition_number`` is cond(H) (≈ 1 for a square).
    """

    velocity_water: np.ndarray
    current: np.ndarray
    covariance: np.ndarray
    condition_number: float
    residual_std: float
    residuals: np.ndarray  # (N, 3), z − Hθ per sample
    samples: int

    @property
    def sigma(self) -> np.ndarray:
        return np.sqrt(np.diag(self.covariance))

    @property
    def surge(self) -> float:
        return float(self.velocity_water[0])

    @property
    def sway(self) -> float:
        return float(self.velocity_water[1])

    @property
    def heave(self) -> float:
        return float(self.velocity_water[2])

    @property
    def sideslip(self) -> float:
        """β = atan2(v, u) of the water-relative velocity (rad)."""
        return float(math.atan2(self.velocity_water[1], self.velocity_water[0]))

    @property
    def current_speed(self) -> float:
        return float(np.hypot(*self.current))

    @property
    def current_dir_deg(self) -> float:
        """Direction the current flows towards, 0–360° from north clockwise."""
        return current_direction_deg(*self.current)

    def as_dict(self) -> dict:
        sig = self.sigma
        return {
            "surge_water": self.surge,
            "sway_water": self.sway,
            "heave_water": self.heave,
            "sideslip_deg": math.degrees(self.sideslip),
            "current_north": float(self.current[0]),
            "current_east": float(self.current[1]),
            "current_speed": self.current_speed,
            "current_dir_deg": self.current_dir_deg,
            "sigma": {name: float(value) for name, value in zip(("surge", "sway", "heave", "current_north", "current_east"), sig)},
            "condition_number": self.condition_number,
            "residual_std": self.residual_std,
            "samples": self.samples,
        }


def fit_straight_legs(roll, pitch, yaw, vel_body) -> StraightLegFit:
    """Stacked linear least squares of eq. 7–8 for θ = (v_wb, vc_n, vc_e) (SPEC C8).

    ``vel_body`` (N, 3) is the body velocity over ground z = v_mb^b; roll/pitch/yaw give R_mb. The
    samples should come from several headings (a square), otherwise the current is unobservable
    (a large ``condition_number`` tells). Raises ValueError on too few samples.
    """
    z = np.asarray(vel_body, float)
    if z.ndim != 2 or z.shape[1] != 3:
        raise ValueError("vel_body must have shape (N, 3)")
    n = z.shape[0]
    if n < 3:
        raise ValueError(f"need at least 3 samples for the straight-leg fit, got {n}")
    roll, pitch, yaw = (np.asarray(a, float) for a in (roll, pitch, yaw))
    # H is 3N×5: reduce it block by block to the 6×6 triangle of [H z] (a tall-skinny QR), so a
    # long log needs memory for one block, not for H; the solution is lstsq's on the full H.
    triangle = np.zeros((0, 6))
    for block in _blocks(n):
        triangle = np.linalg.qr(np.vstack([triangle, _straight_leg_rows(roll[block], pitch[block], yaw[block],
                                                                           z[block])]), mode="r")
    r, qtz = triangle[:5, :5], triangle[:5, 5]
    theta, *_ = np.linalg.lstsq(r, qtz, rcond=None)
    residuals = np.empty_like(z)
    for block in _blocks(n):
        rows = _straight_leg_rows(roll[block], pitch[block], yaw[block], z[block])
        residuals[block] = (rows[:, 5] - rows[:, :5] @ theta).reshape(-1, 3)
    dof = 3 * n - 5
    variance = float(np.sum(residuals * residuals)) / dof
    covariance = variance * np.linalg.inv(r.T @ r)  # (HᵀH)⁻¹ = (RᵀR)⁻¹
    return StraightLegFit(
        velocity_water=theta[:3].copy(),
        current=theta[3:].copy(),
        covariance=covariance,
        condition_number=float(np.linalg.cond(r)),  # H = QR: the same singular values
        residual_std=math.sqrt(variance),
        residuals=residuals,
        samples=n,
    )


#: samples per block of the straight-leg fit (its memory: ~1 kB per sample of a block)
_BLOCK = 65536


def _blocks(n: int) -> list[slice]:
    return [slice(start, min(start + _BLOCK, n)) for start in range(0, n, _BLOCK)]


def _straight_leg_rows(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Rows ``[H | z]`` of eq. 8 for some samples, shape (3·N, 6): identity for v_wb, c1, c2 for the current."""
    m = z.shape[0]
    r_bm = np.transpose(body_to_ned_matrices(roll, pitch, yaw), (0, 2, 1))  # R_m^b = R_mbᵀ
    rows = np.zeros((m, 3, 6))
    rows[:, :, :3] = np.eye(3)
    rows[:, :, 3] = r_bm[:, :, 0]  # c1
    rows[:, :, 4] = r_bm[:, :, 1]  # c2
    rows[:, :, 5] = z
    return rows.reshape(3 * m, 6)


# --------------------------------------------------------------------------- steady turns
@dataclass(frozen=True)
class TurnFit:
    """Result of the nonlinear LS of eq. 9–10 (t measured from ``t0``).

    ``center`` = r0 (north, east) at t0; ``current`` (north, east) m/s; ``rate`` ω (rad/s, > 0
    clockwise from above); ``radius`` R > 0 (m) of the water-relative circle; ``phase`` φ0 (rad);
    ``covariance`` of Φ = (r0n, r0e, vcn, vce, ω, φ0, R) scaled by the residual variance.
    """

    center: np.ndarray
    current: np.ndarray
    rate: float
    phase: float
    radius: float
    t0: float
    covariance: np.ndarray
    residual_std: float
    residuals: np.ndarray  # (M, 2)
    samples: int
    iterations: int = 0
    initial_guess: dict = field(default_factory=dict)

    @property
    def sigma(self) -> np.ndarray:
        return np.sqrt(np.diag(self.covariance))

    @property
    def current_speed(self) -> float:
        return float(np.hypot(*self.current))

    @property
    def current_dir_deg(self) -> float:
        """Direction the current flows towards, 0–360° from north clockwise."""
        return current_direction_deg(*self.current)

    @property
    def water_speed(self) -> float:
        """Speed along the water-relative circle, |ω|·R (m/s)."""
        return abs(self.rate) * self.radius

    def position(self, t: np.ndarray, with_current: bool = True) -> np.ndarray:
        """Model positions h(Φ, t) (eq. 9), shape (M, 2); ``with_current=False`` gives the circle."""
        tau = np.asarray(t, float) - self.t0
        angle = self.rate * tau - self.phase
        circle = self.radius * np.column_stack([np.cos(angle), np.sin(angle)])
        drift = np.outer(tau, self.current) if with_current else 0.0
        return self.center + drift + circle

    def as_dict(self) -> dict:
        sig = self.sigma
        return {
            "radius_m": self.radius,
            "turn_rate_deg_s": math.degrees(self.rate),
            "water_speed": self.water_speed,
            "current_north": float(self.current[0]),
            "current_east": float(self.current[1]),
            "current_speed": self.current_speed,
            "current_dir_deg": self.current_dir_deg,
            "residual_std_m": self.residual_std,
            "center_north": float(self.center[0]),  # r0 at t0: with rate, phase and t0 these
            "center_east": float(self.center[1]),  # give the fitted path back (eq. 9), for plots
            "phase_rad": float(self.phase),
            "t0": float(self.t0),
            "sigma": {
                "radius_m": float(sig[6]),
                "turn_rate_deg_s": math.degrees(sig[4]),
                "current_north": float(sig[2]),
                "current_east": float(sig[3]),
            },
            "samples": self.samples,
        }


def _linear_given_rate(tau: np.ndarray, pos: np.ndarray, rate: float) -> tuple[np.ndarray, float]:
    """For a fixed ω eq. 9 is linear in (r0, vc, R·cosφ0, R·sinφ0): solve it, return (coefs, SSR)."""
    c, s = np.cos(rate * tau), np.sin(rate * tau)
    ones, zeros = np.ones_like(tau), np.zeros_like(tau)
    # x = r0x + vcx·t + a·cos + b·sin ;  y = r0y + vcy·t + a·sin − b·cos   (a = R cosφ0, b = R sinφ0)
    hx = np.column_stack([ones, zeros, tau, zeros, c, s])
    hy = np.column_stack([zeros, ones, zeros, tau, s, -c])
    h = np.vstack([hx, hy])
    y = np.concatenate([pos[:, 0], pos[:, 1]])
    coef, *_ = np.linalg.lstsq(h, y, rcond=None)
    r = y - h @ coef
    return coef, float(r @ r)


def _rate_from_positions(tau: np.ndarray, pos: np.ndarray) -> float:
    """Initial ω from positions alone: the peak of the periodogram of the detrended complex path
    x + i·y (positive frequency = clockwise), scanned on a grid with the linear sub-problem."""
    span = tau[-1] - tau[0]
    dt = float(np.median(np.diff(tau)))
    z = pos[:, 0] + 1j * pos[:, 1]
    trend = np.polyfit(tau, z, 1)
    zd = z - np.polyval(trend, tau)
    omegas = np.linspace(0.5 * math.pi / span, 0.25 * math.pi / dt, 4000)
    omegas = np.concatenate([-omegas[::-1], omegas])
    power = np.abs(np.exp(-1j * np.outer(omegas, tau)) @ zd)
    return float(omegas[int(np.argmax(power))])


def fit_steady_turn(t, north, east, yaw=None) -> TurnFit:
    """Nonlinear LS of eq. 9–10 for Φ = (r0n, r0e, vcn, vce, ω, φ0, R) (SPEC C8).

    Robust automatic initial guess (variable projection): ω0 from the slope of the unwrapped heading
    when ``yaw`` is given (in a steady turn the heading rate equals ω), otherwise from the
    periodogram of the detrended path; then a 1-D scan of ω over ±30 % around ω0 where, for each ω,
    eq. 9 is linear in the other six parameters and is solved exactly; the best scan point seeds
    :func:`scipy.optimize.least_squares` on all seven. Raises ValueError on too few samples.
    """
    t = np.asarray(t, float)
    pos = np.column_stack([np.asarray(north, float), np.asarray(east, float)])
    if t.size < 8:
        raise ValueError(f"need at least 8 samples for the turn fit, got {t.size}")
    t0 = float(t[0])
    tau = t - t0
    if yaw is not None:
        psi = np.unwrap(np.asarray(yaw, float))
        rate0 = float(np.polyfit(tau, psi, 1)[0])
        source = "heading"
    else:
        rate0 = _rate_from_positions(tau, pos)
        source = "periodogram"
    if abs(rate0) < 1e-6:
        raise ValueError("no turning detected (heading rate ≈ 0): not a steady turn")
    scan = np.linspace(0.7 * rate0, 1.3 * rate0, 121)
    ssr = [_linear_given_rate(tau, pos, w)[1] for w in scan]
    rate_init = float(scan[int(np.argmin(ssr))])
    coef, _ = _linear_given_rate(tau, pos, rate_init)
    a, b = coef[4], coef[5]
    radius0, phase0 = math.hypot(a, b), math.atan2(b, a)
    x0 = np.array([coef[0], coef[1], coef[2], coef[3], rate_init, phase0, radius0])

    def residual(phi: np.ndarray) -> np.ndarray:
        angle = phi[4] * tau - phi[5]
        model_x = phi[0] + phi[2] * tau + phi[6] * np.cos(angle)
        model_y = phi[1] + phi[3] * tau + phi[6] * np.sin(angle)
        return np.concatenate([pos[:, 0] - model_x, pos[:, 1] - model_y])

    sol = least_squares(residual, x0, method="lm", x_scale="jac")
    phi = sol.x.copy()
    if phi[6] < 0:  # (R, φ0) and (−R, φ0 + π) describe the same path: keep R > 0
        phi[6], phi[5] = -phi[6], phi[5] + math.pi
    phi[5] = math.atan2(math.sin(phi[5]), math.cos(phi[5]))
    res = residual(phi)
    dof = res.size - 7
    variance = float(res @ res) / dof
    jac = sol.jac
    try:
        covariance = variance * np.linalg.inv(jac.T @ jac)
    except np.linalg.LinAlgError:
        covariance = np.full((7, 7), np.nan)
    m = t.size
    return TurnFit(
        center=phi[:2],
        current=phi[2:4],
        rate=float(phi[4]),
        phase=float(phi[5]),
        radius=float(phi[6]),
        t0=t0,
        covariance=covariance,
        residual_std=math.sqrt(float(res @ res) / max(1, 2 * m - 7)),
        residuals=np.column_stack([res[:m], res[m:]]),
        samples=m,
        iterations=int(sol.nfev),
        initial_guess={"rate_source": source, "rate0": rate0, "rate_scan": rate_init, "radius0": radius0},
    )


def water_relative_velocity(roll, pitch, yaw, vel_body, current) -> np.ndarray:
    """Water-relative body velocity per sample once the current is known, eq. 5 solved for v_wb:
    ``v_wb = v_b − [c1 c2]·[vc_n, vc_e]`` (e.g. surge/sway in a steady turn), shape (N, 3)."""
    r_bm = np.transpose(body_to_ned_matrices(roll, pitch, yaw), (0, 2, 1))
    current = np.asarray(current, float)
    return np.asarray(vel_body, float) - (r_bm[:, :, 0] * current[0] + r_bm[:, :, 1] * current[1])
