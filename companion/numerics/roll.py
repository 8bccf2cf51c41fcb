"""Roll with an internal rolling mass: linearised model and PI stabiliser (SPEC C6, §3.6).

Thesis 002, ch. 4. The nonlinear model (eq. 4.11)

    (Ixx − Kṗ)·φ̈ = −(yg + (m/M)·l·sin α)·W·cos φ + (zg − (m/M)·l·cos α)·W·sin φ + Kpp·p|p| + τprop

linearised at φ = 0, α small, yg = 0, τprop treated as a disturbance (eq. 4.12–4.13), and with the
servo lag (eq. 4.15):

    Φ(s)/α_cmd(s) = 1/(τ·s + 1) · k / (s² + a·s + b),
    k = −(m/M)·l·W / (Ixx − Kṗ),   b = ((m/M)·l − zg)·W / (Ixx − Kṗ),   a = −Kp_lin / (Ixx − Kṗ).

With Table 4.1 this gives k = −1.54 s⁻², b = 5.23 s⁻² (printed: 5.21, agrees) and a static gain
k/b = −0.293 rad/rad, i.e. 5.9° of roll per 20° of mass angle, as the ±5° design requirement says.
The printed k = −0.61 (static gain −0.117: 2.3° per 20°) does not follow from the listed values;
SPEC §3.6 says to trust the nonlinear model, so k is computed. The quadratic drag has no linear
part; ``a`` comes from a linear drag K_p,lin (−0.133 N·m·s = the printed a = 0.24 × 0.554, as the
simulator preset also keeps it) plus, optionally, the describing-function equivalent of K_pp at a
roll amplitude Φ and frequency ω = √b: K_pp·(8/(3π))·ω·Φ (alone it would give a = 0.24 at Φ ≈ 3.3°).

Controller (Table 4.2): the seed's closed loop is s(s+2)(s² + 0.24s + 5.21) − 6.10·(s − 0.01),
i.e. with the seed's k the law α = −Kp·(φ − z·∫φ dt), Kp = 5, z = 0.01. Its proportional part
is *positive* feedback through the servo lag (it trades roll stiffness for damping: the loop is
stable for Kp·|k| < b, the seed's "0 < Kp < 8.50"), its integral part is the slow negative
feedback that removes the mean roll (propeller torque). Applied to the physical k, Kp = 5 would be
unstable (limit 3.4); :func:`seed_equivalent_gain` rescales Kp so that Kp·|k| equals the seed's
loop gain 5 × 0.61, which reproduces the seed's closed-loop poles on the physical plant.
The default law of the product is therefore :func:`rate_feedback_gains` (restoring angle feedback
plus roll-rate damping, same integral zero); :func:`seed_gains` keeps the seed's law for comparison.
Pure numerics: no I/O, no clock.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any, Mapping

import numpy as np

from .vehicle_data import actuator_limit, section_numbers

if TYPE_CHECKING:
    import control

# ``control`` is imported where a transfer function is made, not with the module: it brings in
# scipy.signal and matplotlib, about 1 s of every command's start-up that never needs it

#: the seed's printed linear gain and controller (Table 4.1, 4.2)
SEED_K = -0.61
SEED_KP = 5.0
SEED_INTEGRAL_ZERO = 0.01

_ALIASES = {
    "inertia": "inertia_xx",
    "added_inertia": "k_pdot",
    "moving_mass": "mass_rolling",
    "damping_quadratic": "k_pp",
    "servo_time_constant": "servo_lag",
    "ixx": "inertia_xx",
    "i_xx": "inertia_xx",
    "yg": "y_g",
    "zg": "z_g",
    "m": "mass_rolling",
    "mass_mass": "mass_rolling",
    "rolling_mass": "mass_rolling",
    "m_mass": "mass_rolling",
    "total_mass": "mass_total",
    "big_m": "mass_total",
    "m_total": "mass_total",
    "w": "weight",
    "kpdot": "k_pdot",
    "k_p_dot": "k_pdot",
    "kpp": "k_pp",
    "k_p_p": "k_pp",
    "l": "arm",
    "l_mass": "arm",
    "mass_arm": "arm",
    "servo_tau": "servo_lag",
    "tau_servo": "servo_lag",
    "mass_tau": "servo_lag",
    "mass_max": "mass_limit",
    "alpha_max": "mass_limit",
}
_SECTIONS = ("roll",)


@dataclass(frozen=True)
class RollVehicle:
    """Table 4.1 roll parameters (SI units)."""

    inertia_xx: float = 0.474  # kg·m², Ixx
    y_g: float = 0.0  # m
    z_g: float = -0.0034  # m (CG below CB: negative, body frame at the CB)
    mass_rolling: float = 2.00  # kg, m (the rolling tail tray)
    mass_total: float = 61.41  # kg, M
    weight: float = 602.5  # N, W
    k_pdot: float = -0.08  # kg·m², Kṗ (added inertia)
    k_pp: float = -1.21  # N·m·s², quadratic roll drag
    damping_linear: float = -0.133  # N·m·s, linear drag: the seed's a = 0.24 × (Ixx − Kṗ)
    arm: float = 0.04336  # m, l
    servo_lag: float = 0.5  # s, τ of the mass servo
    mass_limit: float = math.radians(20.0)  # rad, ±α limit

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "RollVehicle":
        """From a preset dict: field names of this class, the simulator preset's names
        (``sim/presets/*.json`` ``roll`` section; ``actuators.mass_max`` gives the limit) or Table
        4.1 symbols, at top level or nested in ``roll``."""
        values = section_numbers(data, cls, _SECTIONS, _ALIASES)
        limit = actuator_limit(data, "mass_max")
        if "mass_limit" not in values and limit is not None:
            values["mass_limit"] = limit
        return cls(**values)

    def to_dict(self) -> dict[str, float]:
        return asdict(self)


@dataclass(frozen=True)
class RollLinearModel:
    """Φ/α_cmd = 1/(τs+1) · k/(s² + a s + b) (eq. 4.15)."""

    k: float
    a: float
    b: float
    servo_lag: float

    @property
    def static_gain(self) -> float:
        """Steady roll per unit mass angle, rad/rad."""
        return self.k / self.b

    @property
    def natural_frequency(self) -> float:
        return math.sqrt(self.b)

    @property
    def damping_ratio(self) -> float:
        return self.a / (2.0 * math.sqrt(self.b))

    def transfer_function(self) -> "control.TransferFunction":
        import control

        s = control.tf("s")
        return self.k / ((self.servo_lag * s + 1) * (s**2 + self.a * s + self.b))


def linearise(vehicle: RollVehicle, roll_amplitude: float = 0.0) -> RollLinearModel:
    """Linearise eq. 4.11 (eq. 4.12): k and b from the physical values.

    ``a`` = −(K_p,lin + K_pp·(8/3π)·ω·Φ)/(Ixx − Kṗ): the linear drag plus the describing-function
    equivalent of the quadratic drag at ``roll_amplitude`` Φ (rad); Φ = 0 gives the seed's a = 0.24
    with the default linear drag.
    """
    v = vehicle
    inertia = v.inertia_xx - v.k_pdot
    shift = v.mass_rolling / v.mass_total * v.arm
    k = -shift * v.weight / inertia
    b = (shift - v.z_g) * v.weight / inertia
    omega = math.sqrt(b)
    equivalent_drag = v.damping_linear + v.k_pp * 8.0 / (3.0 * math.pi) * omega * abs(roll_amplitude)
    a = -equivalent_drag / inertia
    return RollLinearModel(k=k, a=a, b=b, servo_lag=v.servo_lag)


@dataclass(frozen=True)
class RollPIGains:
    """Roll law in the *restoring* convention (positive gains oppose roll):

        α_cmd = −sign(k)·(kp·φ + kd·p + ki·∫φ dt),  |α_cmd| ≤ limit, |ki·∫φ| ≤ limit (anti-windup)

    The seed's law (Table 4.2) is kp = −Kp (negative: it softens the roll through the servo lag to
    gain damping), ki = Kp·z, kd = 0; see :func:`seed_gains`. ``kd`` uses the measured roll rate p.
    """

    kp: float  # rad mass per rad roll
    ki: float = 0.0  # rad mass per rad·s of roll
    kd: float = 0.0  # rad mass per rad/s of roll rate
    limit: float = math.radians(20.0)  # rad, mass-angle limit (anti-windup clamp)
    plant_sign: float = -1.0  # sign of k: −1 when a positive mass angle rolls the vehicle negative


def seed_equivalent_gain(model: RollLinearModel, seed_kp: float = SEED_KP, seed_k: float = SEED_K) -> float:
    """Kp that gives the seed's loop gain Kp·|k| = 5 × 0.61 on ``model`` (see module docstring)."""
    return seed_kp * abs(seed_k) / abs(model.k)


def seed_gains(model: RollLinearModel, limit: float = math.radians(20.0),
               integral_zero: float = SEED_INTEGRAL_ZERO) -> RollPIGains:
    """The seed's design transferred to ``model``: loop gain of Table 4.2, zero at ``integral_zero``."""
    kp = seed_equivalent_gain(model)
    return RollPIGains(kp=-kp, ki=kp * integral_zero, kd=0.0, limit=limit, plant_sign=math.copysign(1.0, model.k))


#: loop gains |k|·kp (s⁻²) and |k|·kd (s⁻¹) of the default rate-feedback design (kp ≈ 6.5, kd ≈ 13
#: on the Table 4.1 plant). Chosen on the nonlinear simulator by the *measured* roll std
#: (0.3° attitude noise included, as the thesis measured it) at 1.4 m/s with the random roll moment
#: through the roll procedure: loop gains (4.6, 9.2) gave 2.2–3.3× lower std than open loop over
#: seeds 1/2/3/7, (10, 20) 3.4–5.0× over seeds 1–5; beyond that the 0.5 s servo lag and the sensor
#: noise set the floor. The integral zero stays the seed's 0.01: a zero at 0.1 removes the
#: propeller-torque mean in ~15 s instead of minutes but winds up during a 25° kick (13 s to settle
#: at cruise instead of 1.6 s) and did not lower the std.
RATE_DESIGN_LOOP_KP = 10.0
RATE_DESIGN_LOOP_KD = 20.0
RATE_DESIGN_INTEGRAL_ZERO = SEED_INTEGRAL_ZERO


def rate_feedback_gains(model: RollLinearModel, limit: float = math.radians(20.0),
                        integral_zero: float = RATE_DESIGN_INTEGRAL_ZERO) -> RollPIGains:
    """The default design: restoring angle feedback plus roll-rate damping, integral zero at z.

    The seed's law only trades stiffness for damping, so against a broadband disturbance it does
    not lower the roll standard deviation (measured: bench/bench_roll.py); feeding back the roll rate
    adds damping directly. Gains are scaled by 1/|k| so the loop gains carry over to another plant.
    """
    kp = RATE_DESIGN_LOOP_KP / abs(model.k)
    kd = RATE_DESIGN_LOOP_KD / abs(model.k)
    return RollPIGains(kp=kp, ki=kp * integral_zero, kd=kd, limit=limit, plant_sign=math.copysign(1.0, model.k))


def closed_loop_poles(model: RollLinearModel, gains: RollPIGains) -> np.ndarray:
    """Poles of the linear closed loop (for design checks and the report)."""
    import control

    s = control.tf("s")
    plant = model.transfer_function()
    # α = −sign(k)·(kp + kd·s + ki/s)·φ = −C·φ  ⇒  negative feedback with C = sign(k)·(kp + kd·s + ki/s)
    controller = gains.plant_sign * (gains.kp + gains.kd * s + gains.ki / s)
    loop = control.feedback(plant * controller, 1)
    return np.sort_complex(np.asarray(control.poles(loop)))


def stability_limit(model: RollLinearModel) -> float:
    """Largest proportional gain for which the stiffness stays positive: Kp < b/|k|."""
    return model.b / abs(model.k)


class RollPI:
    """The discrete roll law on vehicle time (forward-Euler integral, the seed's anti-windup clamp)."""

    def __init__(self, gains: RollPIGains) -> None:
        self.gains = gains
        self.integral_term = 0.0  # rad, the integral part of the mass command (clamped)
        self._last_time = math.nan

    def reset(self) -> None:
        self.integral_term = 0.0
        self._last_time = math.nan

    def update(self, time_s: float, roll: float, roll_rate: float = 0.0) -> float:
        """Mass-angle command for roll (and roll rate) measured at vehicle time ``time_s``."""
        g = self.gains
        direction = -g.plant_sign  # +1 for the usual negative k
        dt = time_s - self._last_time if math.isfinite(self._last_time) else 0.0
        self._last_time = time_s
        if dt > 0.0:
            self.integral_term += direction * g.ki * roll * dt
            self.integral_term = min(g.limit, max(-g.limit, self.integral_term))
        rate = roll_rate if math.isfinite(roll_rate) else 0.0
        command = direction * (g.kp * roll + g.kd * rate) + self.integral_term
        return min(g.limit, max(-g.limit, command))


def settle_time(times, values, band: float, start: float = 0.0) -> float:
    """Time after ``start`` from which |value| stays within ``band`` to the end of the record
    (0 if it never leaves the band, NaN if it is still outside at the end). Used for the roll
    impulse response (thesis §4.5: 25° settles in 4 s closed loop)."""
    last_outside = math.nan
    for t, v in zip(times, values):
        if t >= start and abs(v) > band:
            last_outside = t
    if math.isnan(last_outside):
        return 0.0
    if last_outside >= times[-1]:
        return math.nan
    return last_outside - start
