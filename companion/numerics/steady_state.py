"""Steady-state manoeuvring characteristics under an unknown current (SPEC C8; Hegrenæs et al.).

Two least-squares formulations from the HUGIN 4500 paper (seed ``000_*``):

* **Straight legs** (square patterns), eq. 5, 7, 8: the body velocity over ground is
  ``z = v_b = R_mbᵀ·[vc_n, vc_e, 0] + v_wb = [c1 c2]·[vc_n, vc_e] + v_wb`` with c1, c2 the first two
  columns of ``R_m^b = R_mbᵀ``; stacking all samples gives the linear problem ``Z = H·θ`` with
  ``θ = (v_wb (3), vc_n, vc_e)``, solved with :func:`numpy.linalg.lstsq` (on the triangle of a
  block-wise QR of ``H``: the same solution, in memory bounded by one block).
* **Steady turns**, eq. 9, 10: ``p(t) = r0 + vc·t + R·[cos(ωt − φ0), sin(ωt − φ0)]`` fitted to the
  horizontal positions by Levenberg–Marquardt, each step from a block-wise QR of the Jacobian
  (memory of one block, however long the log).

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


def fit_straight_legs(roll, pitch, yaw, vel_body, mask: np.ndarray | None = None) -> StraightLegFit:
    """Stacked linear least squares of eq. 7–8 for θ = (v_wb, vc_n, vc_e) (SPEC C8).

    ``vel_body`` (N, 3) is the body velocity over ground z = v_mb^b; roll/pitch/yaw give R_mb. The
    samples should come from several headings (a square), otherwise the current is unobservable
    (a large ``condition_number`` tells). ``mask`` (boolean, one per sample) fits only the samples
    it selects, without copying the others out first. Raises ValueError on too few samples.
    """
    z = np.asarray(vel_body, float)
    if z.ndim != 2 or z.shape[1] != 3:
        raise ValueError("vel_body must have shape (N, 3)")
    chosen = np.ones(z.shape[0], bool) if mask is None else np.asarray(mask, bool)
    n = int(chosen.sum())
    if n < 3:
        raise ValueError(f"need at least 3 samples for the straight-leg fit, got {n}")
    roll, pitch, yaw = (np.asarray(a, float) for a in (roll, pitch, yaw))

    def rows(block: slice) -> np.ndarray:
        pick = chosen[block]
        return _straight_leg_rows(roll[block][pick], pitch[block][pick], yaw[block][pick], z[block][pick])

    # H is 3N×5: reduce it block by block to the 6×6 triangle of [H z] (a tall-skinny QR), so a
    # long log needs memory for one block, not for H; the solution is lstsq's on the full H.
    triangle = np.zeros((0, 6))
    for block in _blocks(z.shape[0]):
        stacked = np.vstack([triangle, rows(block)])
        triangle = np.linalg.qr(stacked, mode="r")  # type: ignore[assignment]  # numpy stub wrong: mode="r" returns R only
    r, qtz = triangle[:5, :5], triangle[:5, 5]
    theta, *_ = np.linalg.lstsq(r, qtz, rcond=None)
    residuals = np.empty((n, 3))
    filled = 0
    for block in _blocks(z.shape[0]):
        block_rows = rows(block)
        count = block_rows.shape[0] // 3
        residuals[filled:filled + count] = (block_rows[:, 5] - block_rows[:, :5] @ theta).reshape(-1, 3)
        filled += count
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


def _reduce(rows_of, n: int, width: int) -> np.ndarray:
    """The ``width``×``width`` triangle R of a QR of the tall matrix whose rows ``rows_of(block)``
    gives for consecutive blocks of the ``n`` samples (tall-skinny QR: memory of one block)."""
    triangle = np.zeros((0, width))
    for block in _blocks(n):
        stacked = np.vstack([triangle, rows_of(block)])
        triangle = np.linalg.qr(stacked, mode="r")  # type: ignore[assignment]  # numpy stub wrong: mode="r" returns R only
    if triangle.shape[0] < width:  # fewer rows than columns: pad (R's missing rows are zero)
        triangle = np.vstack([triangle, np.zeros((width - triangle.shape[0], width))])
    return triangle


def _solve_triangle(triangle: np.ndarray) -> tuple[np.ndarray, float]:
    """(x, SSR) of min ‖A·x − b‖² from the triangle of a QR of [A b] (the last column is b)."""
    r, qtb = triangle[:-1, :-1], triangle[:-1, -1]
    x, *_ = np.linalg.lstsq(r, qtb, rcond=None)
    return x, float(np.sum((r @ x - qtb) ** 2) + triangle[-1, -1] ** 2)


def _linear_rows(tau: np.ndarray, pos: np.ndarray, rate: float) -> np.ndarray:
    """Rows [H y] of eq. 9 at a fixed ω, linear in (r0, vc, R·cosφ0, R·sinφ0), shape (2m, 7)."""
    c, s = np.cos(rate * tau), np.sin(rate * tau)
    ones, zeros = np.ones_like(tau), np.zeros_like(tau)
    # x = r0x + vcx·t + a·cos + b·sin ;  y = r0y + vcy·t + a·sin − b·cos   (a = R cosφ0, b = R sinφ0)
    hx = np.column_stack([ones, zeros, tau, zeros, c, s, pos[:, 0]])
    hy = np.column_stack([zeros, ones, zeros, tau, s, -c, pos[:, 1]])
    return np.vstack([hx, hy])


def _linear_given_rate(tau: np.ndarray, pos: np.ndarray, rate: float) -> tuple[np.ndarray, float]:
    """For a fixed ω eq. 9 is linear in (r0, vc, R·cosφ0, R·sinφ0): solve it, return (coefs, SSR)."""
    return _solve_triangle(_reduce(lambda b: _linear_rows(tau[b], pos[b], rate), tau.size, 7))


def _turn_model(phi: np.ndarray, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(x, y, cos, sin) of eq. 9 at Φ for times τ."""
    angle = phi[4] * tau - phi[5]
    c, s = np.cos(angle), np.sin(angle)
    return phi[0] + phi[2] * tau + phi[6] * c, phi[1] + phi[3] * tau + phi[6] * s, c, s


def _turn_rows(phi: np.ndarray, tau: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """Rows [J r] of the turn fit at Φ: the model's Jacobian (∂h/∂Φ, eq. 9) and the residual
    r = p − h(Φ), x rows then y rows, shape (2m, 8)."""
    x, y, c, s = _turn_model(phi, tau)
    ones, zeros = np.ones_like(tau), np.zeros_like(tau)
    radius = phi[6]
    jx = np.column_stack([ones, zeros, tau, zeros, -radius * s * tau, radius * s, c, pos[:, 0] - x])
    jy = np.column_stack([zeros, ones, zeros, tau, radius * c * tau, -radius * c, s, pos[:, 1] - y])
    return np.vstack([jx, jy])


def _turn_ssr(phi: np.ndarray, tau: np.ndarray, pos: np.ndarray) -> float:
    total = 0.0
    for block in _blocks(tau.size):
        x, y, _, _ = _turn_model(phi, tau[block])
        total += float(np.sum((pos[block, 0] - x) ** 2) + np.sum((pos[block, 1] - y) ** 2))
    return total


def _levenberg_marquardt(phi: np.ndarray, tau: np.ndarray, pos: np.ndarray,
                         max_evaluations: int = 200) -> tuple[np.ndarray, np.ndarray, int]:
    """Levenberg–Marquardt on eq. 9 from Φ (scaled by the Jacobian's column norms, as MINPACK's
    ``lm``), each step from the 8×8 triangle of a block-wise QR of [J r]: memory of one block
    whatever the log's length. Returns (Φ, triangle R of J at Φ, evaluations)."""
    ssr = _turn_ssr(phi, tau, pos)
    damping, evaluations = 1e-3, 1
    while evaluations < max_evaluations:
        triangle = _reduce(lambda b: _turn_rows(phi, tau[b], pos[b]), tau.size, 8)
        r, qtr = triangle[:7, :7], triangle[:7, 7]
        scale = np.maximum(np.linalg.norm(r, axis=0), 1e-300)
        while evaluations < max_evaluations:
            augmented = np.vstack([r, math.sqrt(damping) * np.diag(scale)])
            step, *_ = np.linalg.lstsq(augmented, np.concatenate([qtr, np.zeros(7)]), rcond=None)
            trial = phi + step
            trial_ssr = _turn_ssr(trial, tau, pos)
            evaluations += 1
            if trial_ssr <= ssr:
                break
            damping *= 10.0
            if damping > 1e12:
                return phi, r, evaluations
        converged = ssr - trial_ssr <= 1e-12 * ssr or np.all(np.abs(step * scale) <= 1e-10 * (np.abs(phi * scale) + 1e-10))
        phi, ssr, damping = trial, trial_ssr, max(damping / 10.0, 1e-12)
        if converged:
            break
    triangle = _reduce(lambda b: _turn_rows(phi, tau[b], pos[b]), tau.size, 8)
    return phi, triangle[:7, :7], evaluations


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
    a Levenberg–Marquardt refinement of all seven (:func:`_levenberg_marquardt`, the scaling of
    MINPACK's ``lm``; each step from the triangle of a block-wise QR of [J r], so memory stays that
    of one block). Raises ValueError on too few samples.
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
    scan_ssr = [_linear_given_rate(tau, pos, w)[1] for w in scan]
    rate_init = float(scan[int(np.argmin(scan_ssr))])
    coef, _ = _linear_given_rate(tau, pos, rate_init)
    a, b = coef[4], coef[5]
    radius0, phase0 = math.hypot(a, b), math.atan2(b, a)
    x0 = np.array([coef[0], coef[1], coef[2], coef[3], rate_init, phase0, radius0])

    phi, r, evaluations = _levenberg_marquardt(x0, tau, pos)
    if phi[6] < 0:  # (R, φ0) and (−R, φ0 + π) describe the same path: keep R > 0
        phi[6], phi[5] = -phi[6], phi[5] + math.pi
    phi[5] = math.atan2(math.sin(phi[5]), math.cos(phi[5]))
    r = _reduce(lambda b: _turn_rows(phi, tau[b], pos[b]), tau.size, 8)[:7, :7]  # J at the Φ reported
    x, y, _, _ = _turn_model(phi, tau)
    residuals = np.column_stack([pos[:, 0] - x, pos[:, 1] - y])
    m = t.size
    ssr = float(np.sum(residuals * residuals))
    variance = ssr / (2 * m - 7)
    try:
        covariance = variance * np.linalg.inv(r.T @ r)  # JᵀJ = RᵀR
    except np.linalg.LinAlgError:
        covariance = np.full((7, 7), np.nan)
    return TurnFit(
        center=phi[:2],
        current=phi[2:4],
        rate=float(phi[4]),
        phase=float(phi[5]),
        radius=float(phi[6]),
        t0=t0,
        covariance=covariance,
        residual_std=math.sqrt(ssr / max(1, 2 * m - 7)),
        residuals=residuals,
        samples=m,
        iterations=evaluations,
        initial_guess={"rate_source": source, "rate0": rate0, "rate_scan": rate_init, "radius0": radius0},
    )


def water_relative_velocity(roll, pitch, yaw, vel_body, current) -> np.ndarray:
    """Water-relative body velocity per sample once the current is known, eq. 5 solved for v_wb:
    ``v_wb = v_b − [c1 c2]·[vc_n, vc_e]`` (e.g. surge/sway in a steady turn), shape (N, 3)."""
    r_bm = np.transpose(body_to_ned_matrices(roll, pitch, yaw), (0, 2, 1))
    current = np.asarray(current, float)
    return np.asarray(vel_body, float) - (r_bm[:, :, 0] * current[0] + r_bm[:, :, 1] * current[1])
