"""Vehicle presets: the simulator's physical parameters as JSON data files (SPEC C2, §3).

A preset is read from ``sim/presets/<name>.json`` through :mod:`importlib.resources`, so it works
from an installed package too, or from any JSON file of the same form (``--preset PATH.json``, e.g.
a vehicle variant a sweep derived). Every field is SI (m, kg, N, s, rad) unless its name says
otherwise (``*_deg``). The field meanings are documented on the dataclasses below and in
``sim/presets/README.md``.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, fields
from importlib import resources
from pathlib import Path
from typing import Any


@dataclass(frozen=True)
class ThrusterMap:
    """Thrust ratio TR (0..1) → thrust force Ft (N), SPEC §3.5.

    ``Ft = quadratic·TR² + linear·TR + constant`` for TR > ``deadzone``, 0 below it (and never
    negative). Starfish: 120, −31, −0.53, dead zone 0.28 (SPEC §3.5, not the "+0.53" of eq. 5.16).
    """

    deadzone: float
    quadratic: float
    linear: float
    constant: float


@dataclass(frozen=True)
class DivePlane:
    """The nonlinear dive-plane model of thesis eq. 5.3–5.13 (Table 5.1 symbols in brackets).

    Sign conventions are the thesis's: pitch θ positive nose up, depth positive down,
    angle of attack α = atan2(w, u); a positive elevator δs gives a *nose-down* moment
    (C_Lδ < 0 with a positive fin arm). ``pitch_damping_linear`` (N·m·s, ≤ 0) is an addition to
    the thesis model: a small speed-independent pitch damping so a vehicle at rest does not swing
    undamped; it is zero at any equilibrium (q = 0) and so leaves the minimum speed unchanged.
    """

    rho: float  # water density ρ (kg/m³)
    mass: float  # dry mass m (kg)
    mass_surge: float  # m_x, mass + surge added mass (kg)
    mass_heave: float  # m_z, mass + heave added mass (kg)
    weight: float  # F_W (N)
    buoyancy: float  # F_B (N)
    inertia_pitch: float  # J_y incl. added inertia (kg·m²)
    x_cg: float  # x_cg (m)
    z_cg: float  # z_cg, metacentric height (m)
    area_body: float  # A_b (m²)
    area_fin: float  # A_f (m²)
    length: float  # L (m)
    fin_arm: float  # x_f (m)
    drag_coefficient: float  # C_D0 (< 0)
    lift_alpha: float  # C_Lα
    lift_elevator: float  # C_Lδ
    moment_alpha: float  # C_mα
    moment_pitch_rate: float  # C_mq (thesis form: multiplies q directly, eq. 5.13)
    pitch_damping_linear: float  # N·m·s, see class docstring


@dataclass(frozen=True)
class Yaw:
    """Yaw-rate dynamics whose linearisation at r = 0 is ṙ = a22(V)·r + b2(V)·(δr − δ0) (SPEC C3).

    a22(V) = a22_constant + a22_per_speed·V;  b2(V) = (b2_constant + b2_per_speed_squared·V²)·f(V)
    with f(V) = min(1, V / authority_fade_speed) (no rudder authority at rest; f = 1 above the fade
    speed); plus the nonlinear damping ``yaw_damping_quadratic``·r·|r| (1/rad), which vanishes in
    the linearisation. V is the dive-plane water speed √(u² + w²).
    """

    a22_constant: float
    a22_per_speed: float
    b2_constant: float
    b2_per_speed_squared: float
    rudder_offset: float  # δ0 (rad)
    yaw_damping_quadratic: float
    authority_fade_speed: float


@dataclass(frozen=True)
class Sway:
    """First-order sway: v̇ = (v_ss − v)/time_constant, v_ss = bias·g(V) + per_turn·V·r.

    g(V) = min(1, V / 0.3) fades the straight-leg asymmetry out at rest. Sway does not feed back
    into yaw (SPEC §3.7 on HUGIN: ≈ −0.012 m/s on straight legs).
    """

    time_constant: float
    bias: float  # m/s
    per_turn: float  # s (v per V·r)


@dataclass(frozen=True)
class Roll:
    """Nonlinear roll with an internal rolling mass, thesis eq. 4.11 / SPEC C6 (Table 4.1 symbols).

    ``damping_linear`` (N·m·s) is the thesis's linearised drag K_p = −a·(I_xx − K_ṗ) (a = 0.24),
    kept beside the quadratic K_pp because the quadratic term alone leaves small oscillations
    undamped. Propeller torque τ_prop = propeller_torque_coefficient·TR² (τ ∝ ω², ω ∝ TR).
    A positive mass angle gives a *negative* roll (thesis k < 0).
    """

    inertia: float  # I_xx (kg·m²)
    added_inertia: float  # K_ṗ (kg·m², < 0)
    y_g: float  # m
    z_g: float  # m
    moving_mass: float  # m (kg)
    total_mass: float  # M (kg)
    weight: float  # W (N)
    mass_arm: float  # l (m)
    damping_quadratic: float  # K_pp (N·m·s²)
    damping_linear: float  # N·m·s
    servo_time_constant: float  # s
    propeller_torque_coefficient: float  # N·m at TR = 1
    disturbance_correlation_time: float  # s, of the band-limited random roll moment


@dataclass(frozen=True)
class ActuatorDefaults:
    """Default actuator limits (rad, rad/s); the autopilot overwrites them from its parameters."""

    rudder_max: float
    rudder_rate: float
    elevator_max: float
    elevator_rate: float
    mass_max: float


@dataclass(frozen=True)
class AutopilotDefaults:
    """Default gains of the simulated autopilot (SPEC C2; Table 5.1 for the depth/pitch cascade)."""

    heading_p: float
    heading_i: float
    heading_imax: float
    heading_trim: float
    depth_p: float
    depth_i: float
    pitch_p: float
    pitch_i: float
    pitch_max: float
    cruise_thrust: float


@dataclass(frozen=True)
class SensorNoise:
    """Standard deviations of the simulated sensors (white, seeded)."""

    attitude_deg: float  # compass / roll / pitch
    rate_deg_s: float  # gyro
    depth_m: float  # pressure depth
    velocity_m_s: float  # DVL over ground and body velocities
    speed_m_s: float  # water speed log
    position_m: float  # navigation position


@dataclass(frozen=True)
class Preset:
    """A complete simulated vehicle."""

    name: str
    description: str
    thruster: ThrusterMap
    dive_plane: DivePlane
    yaw: Yaw
    sway: Sway
    roll: Roll
    actuators: ActuatorDefaults
    autopilot: AutopilotDefaults
    sensors: SensorNoise
    surface: bool = False  # a surface vessel: depth, pitch and heave held at 0 (no dive plane)
    # faults injected at their vehicle time (sim/faults.py; optional "faults" list of a preset file)
    faults: tuple = ()

    @property
    def attitude_noise(self) -> float:
        """σ of attitude/heading noise in rad."""
        return math.radians(self.sensors.attitude_deg)


_SECTIONS = {
    "thruster": ThrusterMap,
    "dive_plane": DivePlane,
    "yaw": Yaw,
    "sway": Sway,
    "roll": Roll,
    "actuators": ActuatorDefaults,
    "autopilot": AutopilotDefaults,
    "sensors": SensorNoise,
}


def preset_names() -> list[str]:
    """Names of the presets shipped in ``sim/presets`` (sorted)."""
    folder = resources.files("sim") / "presets"
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".json"))


def _section(cls: type, data: dict[str, Any], where: str) -> Any:
    names = {f.name for f in fields(cls)}
    missing = names - data.keys()
    unknown = data.keys() - names
    if missing or unknown:
        raise ValueError(f"preset section {where!r}: missing {sorted(missing)}, unknown {sorted(unknown)}")
    return cls(**{k: float(v) for k, v in data.items()})


def preset_from_dict(data: dict[str, Any]) -> Preset:
    """Build a :class:`Preset` from its JSON dictionary, checking every field is present."""
    sections = {key: _section(cls, data[key], key) for key, cls in _SECTIONS.items()}
    surface = data.get("surface", False)
    if not isinstance(surface, bool):
        raise ValueError(f"preset field 'surface' must be true or false, not {surface!r}")
    from sim.faults import faults_from_json

    return Preset(name=str(data["name"]), description=str(data.get("description", "")), surface=surface,
                  faults=faults_from_json(data.get("faults")), **sections)


def is_preset_file(name: str) -> bool:
    """Whether ``--preset`` names a JSON file (a path ending in ``.json``) rather than a shipped preset."""
    return name.endswith(".json")


def load_preset(name: str) -> Preset:
    """Read ``sim/presets/<name>.json``, or the preset file ``name`` when it is a path ending in
    ``.json`` (a vehicle variant, e.g. one a parameter sweep derived from a shipped preset); a clear
    error lists the available names."""
    if is_preset_file(name):
        try:
            data = json.loads(Path(name).read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise ValueError(f"cannot read the preset file {name}: {exc}") from None
        if not isinstance(data, dict):
            raise ValueError(f"the preset file {name} does not hold a JSON object")
        try:
            return preset_from_dict(data)
        except (KeyError, TypeError) as exc:
            raise ValueError(f"the preset file {name} lacks {exc}") from None
    names = preset_names()
    if name not in names:
        raise ValueError(f"unknown vehicle preset {name!r}; available: {', '.join(names)}")
    text = (resources.files("sim") / "presets" / f"{name}.json").read_text(encoding="utf-8")
    return preset_from_dict(json.loads(text))
