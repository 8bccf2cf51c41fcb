"""Analytic minimum speed of a positively buoyant, tail-controlled vehicle (SPEC C7, §3.4–3.5).

Implements Eng's dive-plane equilibrium analysis (thesis 002, ch. 5, eq. 5.28–5.55): the maximum
required pitch curve θ_max_req(V) (5.28), the achievable pitch curve θ_ach(V) (5.30), the β1..β6
shorthand (5.33–5.38), the quadratic in V² (5.40) whose root is V_min² (5.49), the pitch θ* (5.53),
the thrust F_t* (5.54), the thrust ratio T_R* by inverting the thruster map (5.55, SPEC §3.5 sign
fix: F_t = 120·T_R² − 31·T_R − 0.53, no thrust below T_R = 0.28) and the existence condition (5.48).

Sign conventions are the thesis's: pitch θ positive nose up, z_cg > 0 when the centre of gravity
is below the centre of buoyancy, C_Lα, C_D0, C_Lδ, C_mα negative, δ_max positive (the elevator
deflection that pitches the nose down). Pure numerics: no I/O, no clock.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, Mapping

import numpy as np

from .vehicle_data import actuator_limit, section_numbers

#: thruster map of the Tecnadyne 520 (Fig. 5.3, eq. 5.16 with the SPEC §3.5 sign fix)
THRUST_MAP_A = 120.0
THRUST_MAP_B = -31.0
THRUST_MAP_C = -0.53
THRUST_DEAD_ZONE = 0.28

# Alternative spellings accepted by DivePlaneVehicle.from_dict (preset files may use the thesis's
# symbols); keys are compared case-insensitively.
_ALIASES: dict[str, str] = {
    "m": "mass",
    "dry_mass": "mass",
    "mx": "mass_x",
    "m_x": "mass_x",
    "mz": "mass_z",
    "m_z": "mass_z",
    "fw": "weight",
    "f_w": "weight",
    "w": "weight",
    "fb": "buoyancy",
    "f_b": "buoyancy",
    "b": "buoyancy",
    "jy": "inertia_y",
    "j_y": "inertia_y",
    "zcg": "z_cg",
    "xcg": "x_cg",
    "ab": "area_body",
    "a_b": "area_body",
    "af": "area_fin",
    "a_f": "area_fin",
    "l": "length",
    "xf": "x_fin",
    "x_f": "x_fin",
    "cd0": "c_d0",
    "c_d_0": "c_d0",
    "cla": "c_l_alpha",
    "cl_alpha": "c_l_alpha",
    "c_lalpha": "c_l_alpha",
    "cld": "c_l_delta",
    "cl_delta": "c_l_delta",
    "c_ldelta": "c_l_delta",
    "cma": "c_m_alpha",
    "cm_alpha": "c_m_alpha",
    "c_malpha": "c_m_alpha",
    "cmq": "c_m_q",
    "cm_q": "c_m_q",
    "mass_surge": "mass_x",
    "mass_heave": "mass_z",
    "inertia_pitch": "inertia_y",
    "fin_arm": "x_fin",
    "drag_coefficient": "c_d0",
    "lift_alpha": "c_l_alpha",
    "lift_elevator": "c_l_delta",
    "moment_alpha": "c_m_alpha",
    "moment_pitch_rate": "c_m_q",
    "dmax": "delta_max",
    "elev_max": "delta_max",
    "elevator_max": "delta_max",
}

#: sections of a preset file in which the dive-plane parameters may be nested
_SECTIONS = ("dive_plane", "diveplane", "dive", "minspeed", "min_speed")
#: the same, public (the vehicle-file schema of companion.records.vehicle_files reads them)
DIVE_PLANE_SECTIONS = _SECTIONS


def dive_plane_field(key: str) -> str | None:
    """The :class:`DivePlaneVehicle` field a file key names (field name, preset name or thesis
    symbol, case-insensitive), or None for a key that names none."""
    name = str(key).lower()
    known = {f for f in DivePlaneVehicle.__dataclass_fields__}
    return name if name in known else _ALIASES.get(name)


@dataclass(frozen=True)
class DivePlaneVehicle:
    """Dive-plane parameters of the Table 5.1 vehicle (thesis 002, eq. 5.3–5.13); SI units."""

    rho: float = 1000.0  # kg/m³, water density
    mass: float = 66.0  # kg, dry mass m
    mass_x: float = 70.2  # kg, m_x (dry + added mass in surge)
    mass_z: float = 128.8  # kg, m_z (dry + added mass in heave)
    weight: float = 647.5  # N, F_w
    buoyancy: float = 649.4  # N, F_B
    inertia_y: float = 40.0  # kg·m², J_y (incl. added inertia)
    z_cg: float = 0.01  # m, CG below CB when positive
    x_cg: float = 0.0  # m
    area_body: float = 0.0314  # m², A_b
    area_fin: float = 0.0431  # m², A_f
    length: float = 2.0  # m, L
    x_fin: float = 1.0  # m, x_f (fins behind the CB)
    c_d0: float = -1.2
    c_l_alpha: float = -1.5
    c_l_delta: float = -0.3
    c_m_alpha: float = -1.8
    c_m_q: float = -0.8
    delta_max: float = 0.26  # rad, elevator limit δ_max

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "DivePlaneVehicle":
        """Build from a preset/JSON dict.

        Accepts the field names of this class, the simulator preset's names (``sim/presets/*.json``:
        ``mass_surge``, ``fin_arm``, ``lift_elevator`` …) or the thesis symbols listed in
        ``_ALIASES`` (case-insensitive), either at top level or nested in a section named
        ``dive_plane`` (or ``minspeed``); a preset's ``actuators.elevator_max`` gives δ_max unless
        the section has its own. Missing fields keep the Table 5.1 defaults; unknown keys are ignored.
        """
        values = section_numbers(data, cls, _SECTIONS, _ALIASES)
        limit = actuator_limit(data, "elevator_max")
        if "delta_max" not in values and limit is not None:
            values["delta_max"] = limit
        return cls(**values)

    def to_dict(self) -> dict[str, float]:
        return asdict(self)

    def with_delta_max(self, delta_max: float) -> "DivePlaneVehicle":
        return DivePlaneVehicle(**{**asdict(self), "delta_max": float(delta_max)})


@dataclass(frozen=True)
class Betas:
    """β1..β6 of eq. 5.33–5.38."""

    b1: float
    b2: float
    b3: float
    b4: float
    b5: float
    b6: float


@dataclass(frozen=True)
class MinimumSpeed:
    """The analytic minimum-speed operating point (eq. 5.49, 5.53–5.55) and its existence (5.48)."""

    exists: bool
    condition_548: bool  # the closed-form existence condition (5.48)
    v_min: float  # m/s (NaN when it does not exist)
    theta_star: float  # rad
    thrust_star: float  # N
    thrust_ratio_star: float  # 0..1 (NaN when above full thrust is needed)
    betas: Betas

    @property
    def theta_star_deg(self) -> float:
        return math.degrees(self.theta_star)

    def as_json(self) -> dict[str, Any]:
        def num(x: float) -> float | None:
            return float(x) if math.isfinite(x) else None

        return {
            "v_min": num(self.v_min),
            "theta_star_deg": num(self.theta_star_deg),
            "thrust_star_n": num(self.thrust_star),
            "thrust_ratio_star": num(self.thrust_ratio_star),
            "exists": bool(self.exists),
            "condition_5_48": bool(self.condition_548),
        }


def betas(vehicle: DivePlaneVehicle, delta_max: float | None = None) -> Betas:
    """β1..β6 (eq. 5.33–5.38) at the elevator limit ``delta_max`` (default: the vehicle's)."""
    v = vehicle
    d = v.delta_max if delta_max is None else delta_max
    half_rho = 0.5 * v.rho
    lift_slope = v.c_l_alpha + v.c_d0
    return Betas(
        b1=half_rho * v.area_fin * v.x_fin * v.c_l_delta * d,
        b2=v.z_cg * v.weight,
        b3=half_rho * v.area_body * v.length * v.c_m_alpha + (v.mass_z - v.mass_x),
        b4=v.buoyancy - v.weight,
        b5=half_rho * v.area_body * lift_slope,
        b6=v.area_fin * v.c_l_delta * d / (v.area_body * lift_slope),
    )


def theta_max_required(vehicle: DivePlaneVehicle, speed: float | np.ndarray, delta_max: float | None = None):
    """Maximum required pitch for level flight at water speed V (eq. 5.28), rad."""
    b = betas(vehicle, delta_max)
    v2 = np.asarray(speed, dtype=float) ** 2
    return b.b4 / (b.b5 * v2) - b.b6


def theta_achievable(vehicle: DivePlaneVehicle, speed: float | np.ndarray, delta_max: float | None = None):
    """Achievable pitch with the elevator at δ_max (eq. 5.30, x_cg = 0), rad."""
    b = betas(vehicle, delta_max)
    v2 = np.asarray(speed, dtype=float) ** 2
    return b.b1 * v2 / (b.b2 - b.b3 * v2)


def existence_condition(vehicle: DivePlaneVehicle) -> bool:
    """Eq. 5.48: x_f/L·(C_Lα + C_D0) − (m_z − m_x)/(½ρA_bL) < C_mα < 0."""
    v = vehicle
    lower = v.x_fin / v.length * (v.c_l_alpha + v.c_d0) - (v.mass_z - v.mass_x) / (0.5 * v.rho * v.area_body * v.length)
    return lower < v.c_m_alpha < 0.0


def thrust_from_ratio(thrust_ratio: float) -> float:
    """Thruster map (eq. 5.16 with the SPEC §3.5 sign): F_t = 120·T_R² − 31·T_R − 0.53, 0 below 0.28."""
    if thrust_ratio < THRUST_DEAD_ZONE:
        return 0.0
    return THRUST_MAP_A * thrust_ratio**2 + THRUST_MAP_B * thrust_ratio + THRUST_MAP_C


def ratio_from_thrust(thrust: float) -> float:
    """Invert the thruster map (eq. 5.55): the smallest T_R that gives at least ``thrust`` newtons.

    Returns 0 for no thrust, ``THRUST_DEAD_ZONE`` for thrusts below the map's value there, and the
    larger root of the quadratic otherwise (it may exceed 1 when the thruster cannot deliver).
    """
    if thrust <= 0.0:
        return 0.0
    if thrust <= thrust_from_ratio(THRUST_DEAD_ZONE):
        return THRUST_DEAD_ZONE
    a, b, c = THRUST_MAP_A, THRUST_MAP_B, THRUST_MAP_C - thrust
    return (-b + math.sqrt(b * b - 4.0 * a * c)) / (2.0 * a)


def steady_thrust(vehicle: DivePlaneVehicle, speed: float, theta: float) -> float:
    """Thrust that balances drag in level flight (eq. 5.25/5.54): F_t = −½ρV²A_bC_D0·cosθ."""
    return -0.5 * vehicle.rho * speed**2 * vehicle.area_body * vehicle.c_d0 * math.cos(theta)


def minimum_speed(vehicle: DivePlaneVehicle, delta_max: float | None = None) -> MinimumSpeed:
    """Solve the quadratic in V² (eq. 5.40/5.49) for V_min, then θ* (5.53), F_t* (5.54), T_R* (5.55).

    Both roots of the quadratic are examined; a root counts when V² is real and positive and the
    two pitch curves really meet there (eq. 5.39 holds with a finite θ_ach). When several do, the
    smallest speed is the minimum. ``exists`` is that numerical answer; ``condition_548`` is the
    thesis's closed-form condition, which presumes F_B > F_w and z_cg > 0.
    """
    d = vehicle.delta_max if delta_max is None else float(delta_max)
    b = betas(vehicle, d)
    denom = b.b1 * b.b5 - b.b3 * b.b5 * b.b6
    cond = existence_condition(vehicle)
    nan = float("nan")
    roots: list[float] = []
    if denom != 0.0:
        p = (b.b3 * b.b4 + b.b2 * b.b5 * b.b6) / denom
        q = -b.b2 * b.b4 / denom
        for r in np.roots([1.0, p, q]):
            if abs(r.imag) < 1e-12 and r.real > 0.0:
                v2 = float(r.real)
                if abs(b.b2 - b.b3 * v2) > 1e-12:
                    lhs = b.b1 * v2 / (b.b2 - b.b3 * v2)
                    rhs = b.b4 / (b.b5 * v2) - b.b6
                    if math.isclose(lhs, rhs, rel_tol=1e-6, abs_tol=1e-9):
                        roots.append(v2)
    if not roots:
        return MinimumSpeed(False, cond, nan, nan, nan, nan, b)
    v_min = math.sqrt(min(roots))
    theta = float(theta_max_required(vehicle, v_min, d))
    thrust = steady_thrust(vehicle, v_min, theta)
    return MinimumSpeed(True, cond, v_min, theta, thrust, ratio_from_thrust(thrust), b)


def elevator_for_level_flight(vehicle: DivePlaneVehicle, speed: float) -> tuple[float, float]:
    """Steady (θ, δ) that hold depth at water speed V, from the same small-angle balance.

    Solves the heave balance (5.27) and the moment balance (5.29) with α = θ, q = 0, x_cg = 0
    (linear in θ and δ): used to relate a fin budget δ_FB to the speed the seeker can reach
    (Fig. 5.25: the seeker stops where δ = δ_max − δ_FB).
    """
    v = vehicle
    hq = 0.5 * v.rho * speed**2
    # heave: hq·(A_b(C_Lα + C_D0))·θ + hq·A_f·C_Lδ·δ = F_B − F_w      (from 5.25 + 5.27, small θ)
    # moment: (hq·A_b·L·C_mα + (m_z − m_x)V² − z_cg·F_w)·θ + hq·A_f·x_f·C_Lδ·δ = 0
    a = np.array(
        [
            [hq * v.area_body * (v.c_l_alpha + v.c_d0), hq * v.area_fin * v.c_l_delta],
            [hq * v.area_body * v.length * v.c_m_alpha + (v.mass_z - v.mass_x) * speed**2 - v.z_cg * v.weight,
             hq * v.area_fin * v.x_fin * v.c_l_delta],
        ]
    )
    rhs = np.array([v.buoyancy - v.weight, 0.0])
    theta, delta = np.linalg.solve(a, rhs)
    return float(theta), float(delta)


def trim_pitch_curve(vehicle: DivePlaneVehicle, thrust_ratio_low: float, thrust_ratio_high: float = 1.0,
                     points: int = 121) -> tuple[tuple[float, float], ...]:
    """The level-flight pitch the vehicle needs at each steady thrust ratio: ((T_R, θ), ...), T_R ascending.

    For a grid of water speeds V, θ and δ from the heave and moment balances (eq. 5.27, 5.29, see
    :func:`elevator_for_level_flight`), the thrust that balances drag F_t = −½ρV²A_bC_D0·cosθ
    (eq. 5.25/5.54) and T_R from the thruster map (eq. 5.16/5.55). The speeds span the thrust ratios
    [``thrust_ratio_low``, ``thrust_ratio_high``]. This is the curve the minimum-speed seeker's
    governed start (behaviors.min_speed) moves along: the autopilot's depth integrator must carry
    the pitch change from θ(T_R nominal) to θ(T_R*), so the thrust may fall only as fast as the
    integrator follows. Points where the drag balance needs no thrust are left out.
    """
    def speed_for(ratio: float) -> float:  # F_t(T_R) = ½ρV²A_b|C_D0| at small θ, refined below
        force = thrust_from_ratio(ratio)
        return math.sqrt(max(force, 1e-9) / (0.5 * vehicle.rho * vehicle.area_body * abs(vehicle.c_d0)))

    speeds = np.linspace(speed_for(thrust_ratio_low) * 0.97, speed_for(thrust_ratio_high) * 1.03, points)
    pairs: list[tuple[float, float]] = []
    for speed in speeds:
        theta, _delta = elevator_for_level_flight(vehicle, float(speed))
        ratio = ratio_from_thrust(steady_thrust(vehicle, float(speed), theta))
        if ratio > THRUST_DEAD_ZONE and thrust_ratio_low - 0.02 <= ratio <= thrust_ratio_high + 0.02:
            pairs.append((float(ratio), float(theta)))
    pairs.sort()
    return tuple(pairs)
