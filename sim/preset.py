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
from dataclasses import MISSING, dataclass, fields
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
    # first-order lag (s) of the propeller shaft behind the demand; 0 = none. Used by the 3-DOF
    # vessels only (sim/vessel3dof.py); optional in a preset file
    time_constant: float = 0.0


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
class Hull:
    """A surface vessel's surge–sway–yaw hull (``sim/physics/hull3dof.py``; Fossen's symbols).

    Added masses are Fossen's derivatives (negative: M_A = −[[X_u̇,0,0],[0,Y_v̇,Y_ṙ],[0,N_v̇,N_ṙ]]).
    Each linear sway/yaw derivative has a constant part and a part per unit of water speed U
    (``*_speed``: the linear maneuvering model's ∝ U form), e.g. N_r(U) = ``n_r`` + ``n_r_speed``·U.
    """

    length: float  # L (m), for reference
    mass: float  # m (kg)
    inertia_yaw: float  # I_z about the CG (kg·m²)
    x_g: float  # CG ahead of the body origin (m)
    x_udot: float  # X_u̇ (kg)
    y_vdot: float  # Y_v̇ (kg)
    y_rdot: float  # Y_ṙ (kg·m)
    n_vdot: float  # N_v̇ (kg·m)
    n_rdot: float  # N_ṙ (kg·m²)
    x_u: float  # X_u (N·s/m)
    x_uu: float  # X_|u|u (N·s²/m²)
    y_v: float  # Y_v (N·s/m)
    y_v_speed: float  # Y_v per m/s of U (N·s²/m²)
    y_r: float  # Y_r (N·s)
    y_r_speed: float  # (N·s²/m)
    y_vv: float  # Y_|v|v (N·s²/m²)
    n_v: float  # N_v (N·s)
    n_v_speed: float  # (N·s²/m)
    n_r: float  # N_r (N·m·s)
    n_r_speed: float  # (N·s²)
    n_rr: float  # N_|r|r (N·m·s²)


@dataclass(frozen=True)
class Rudder:
    """A stern rudder of a 3-DOF vessel (``sim/physics/propulsion3dof.py``): Y = −lift·u|u|·(δ − offset)
    at x = ``x_r`` (< 0), drag −``drag``·u²·(δ − offset)²."""

    x_r: float  # m, negative: behind the CG
    lift: float  # ½ρ·A_R·C_Lα, N/(rad·(m/s)²)
    drag: float  # N/(rad²·(m/s)²)
    offset: float  # misalignment (rad): the straight-course rudder δ0


@dataclass(frozen=True)
class TwinThrusters:
    """Two thrusters at y = ∓``y_arm`` (skid steering, no rudder; ``sim/physics/propulsion3dof.py``).
    Each motor has the preset's ``thruster`` map ahead and ``reverse_efficiency`` × it astern."""

    y_arm: float  # m
    reverse_efficiency: float  # astern / ahead thrust at the same demand
    right_efficiency: float  # right motor / left motor (≤ 1: a mismatch, hence a steering trim)


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
    dive_plane: DivePlane | None  # None for a 3-DOF vessel (``hull``)
    yaw: Yaw | None  # None for a 3-DOF vessel
    sway: Sway | None  # None for a 3-DOF vessel
    roll: Roll
    actuators: ActuatorDefaults
    autopilot: AutopilotDefaults
    sensors: SensorNoise
    surface: bool = False  # a surface vessel: depth, pitch and heave held at 0 (no dive plane)
    # faults injected at their vehicle time (sim/faults.py; optional "faults" list of a preset file)
    faults: tuple = ()
    # a 3-DOF surface vessel (sim/vessel3dof.py) instead of the first-order yaw laws: its hull and
    # either a stern rudder or twin thrusters (skid steering)
    hull: Hull | None = None
    rudder: Rudder | None = None
    twin_thrusters: TwinThrusters | None = None

    @property
    def is_3dof(self) -> bool:
        """A surge–sway–yaw hull (``hull``) rather than the first-order yaw laws (``yaw``, ``sway``)."""
        return self.hull is not None

    @property
    def is_skid(self) -> bool:
        """Twin thrusters, no rudder: steering by differential thrust (ArduRover skid steering)."""
        return self.twin_thrusters is not None

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
#: the first-order model's sections, which a 3-DOF vessel (``hull``) has no use for
_FIRST_ORDER_SECTIONS = ("dive_plane", "yaw", "sway")
#: the 3-DOF vessel's sections: a hull and exactly one of the two propulsions
_HULL_SECTIONS = {"hull": Hull, "rudder": Rudder, "twin_thrusters": TwinThrusters}


def preset_names() -> list[str]:
    """Names of the presets shipped in ``sim/presets`` (sorted)."""
    folder = resources.files("sim") / "presets"
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".json"))


def _section(cls: type, data: dict[str, Any], where: str) -> Any:
    names = {f.name for f in fields(cls)}
    optional = {f.name for f in fields(cls) if f.default is not MISSING}
    missing = names - optional - data.keys()
    unknown = data.keys() - names
    if missing or unknown:
        raise ValueError(f"preset section {where!r}: missing {sorted(missing)}, unknown {sorted(unknown)}")
    return cls(**{k: float(v) for k, v in data.items()})


def preset_from_dict(data: dict[str, Any]) -> Preset:
    """Build a :class:`Preset` from its JSON dictionary, checking every field is present.

    A 3-DOF surface vessel has a ``hull`` section and one of ``rudder`` / ``twin_thrusters``, and then
    no ``dive_plane``, ``yaw`` or ``sway`` (those are the first-order model's)."""
    hull_model = "hull" in data
    sections = {key: (None if hull_model and key in _FIRST_ORDER_SECTIONS else _section(cls, data[key], key))
                for key, cls in _SECTIONS.items()}
    if hull_model:
        extra = [key for key in _FIRST_ORDER_SECTIONS if key in data]
        if extra:
            raise ValueError(f"a preset with a 'hull' (3-DOF vessel) has no use for {extra}")
        propulsions = [key for key in ("rudder", "twin_thrusters") if key in data]
        if len(propulsions) != 1:
            raise ValueError("a preset with a 'hull' needs exactly one of 'rudder' and 'twin_thrusters'")
        sections.update({key: _section(cls, data[key], key) for key, cls in _HULL_SECTIONS.items() if key in data})
    elif any(key in data for key in ("rudder", "twin_thrusters")):
        raise ValueError("'rudder' and 'twin_thrusters' belong to a 3-DOF vessel, which needs a 'hull'")
    surface = data.get("surface", False)
    if not isinstance(surface, bool):
        raise ValueError(f"preset field 'surface' must be true or false, not {surface!r}")
    if hull_model and not surface:
        raise ValueError("a preset with a 'hull' (3-DOF vessel) must be a surface vessel (\"surface\": true)")
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
