"""The simulated vehicle: actuators, 6-DOF-ish nonlinear physics, water current and sensors (SPEC C2).

Degrees of freedom: the thesis dive plane (surge u, heave w, pitch rate q, pitch θ, depth; eq.
5.1–5.13), yaw (ψ, r) with sway v (SPEC C3 model made nonlinear), roll (φ, p) with the rolling mass
(eq. 4.11), and horizontal position over ground with a 2-D water current. Integration is Heun's
method (RK2) at the caller's dt with actuators held over the step; plain floats for speed (the
server steps this at 100 Hz × 50 real time). No MAVLink, no wall clock.

Sign conventions: NED, depth positive down; yaw clockwise from north, wrapped to (−π, π]; pitch
nose-up positive; positive rudder → positive (clockwise) yaw rate; positive elevator → nose-down
moment (thesis ch. 5); positive rolling-mass angle → negative roll (thesis ch. 4, k < 0).
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from sim.physics.disturbance import RollDisturbance
from sim.physics.dive_plane import DivePlaneConstants, dive_plane_accelerations
from sim.physics.equilibrium import level_trim_at_speed, level_trim_at_thrust
from sim.physics.roll import RollConstants, propeller_torque, roll_acceleration
from sim.physics.thruster import thrust_force
from sim.faults import Fault, in_time_order, scale_yaw
from sim.physics.yaw import YawConstants, sway_acceleration, yaw_acceleration
from sim.preset import Preset

log = logging.getLogger(__name__)

TWO_PI = 2.0 * math.pi


def wrap_angle(angle: float) -> float:
    """Wrap to (−π, π]: the simulator's one angle wrap (it cannot use the companion's, SPEC §5)."""
    wrapped = math.remainder(angle, TWO_PI)
    return math.pi if wrapped == -math.pi else wrapped


@dataclass
class ActuatorDemand:
    """What the autopilot asks of the actuators (rad, ratio).

    ``motor_left``/``motor_right`` (±1) drive a twin-thruster (skid-steered) vessel instead of
    ``rudder`` and ``thrust_ratio`` (sim/vessel3dof.py); other vehicles ignore them."""

    rudder: float = 0.0
    elevator: float = 0.0
    thrust_ratio: float = 0.0
    mass_angle: float = 0.0
    motor_left: float = 0.0
    motor_right: float = 0.0


@dataclass
class ActuatorLimits:
    """Actuator limits (rad) and rate limits (rad/s); mutable, set by the autopilot's parameters."""

    rudder_max: float = 0.35
    rudder_rate: float = 0.5
    elevator_max: float = 0.26
    elevator_rate: float = 0.5
    mass_max: float = 0.349


@dataclass(frozen=True)
class VehicleState:
    """Truth. Body velocities (surge, sway, heave) are water-relative; vel_* are over ground (NED)."""

    time_s: float
    north: float
    east: float
    depth: float
    roll: float
    pitch: float
    yaw: float
    roll_rate: float
    pitch_rate: float
    yaw_rate: float
    surge: float
    sway: float
    heave: float
    vel_north: float
    vel_east: float
    vel_down: float
    speed_water: float
    speed_ground: float
    rudder: float
    elevator: float
    thrust_ratio: float
    mass_angle: float
    motor_left: float = 0.0  # commanded motor demands (±1) of a twin-thruster vessel, else 0
    motor_right: float = 0.0


@dataclass(frozen=True)
class Measurements(VehicleState):
    """The same fields as :class:`VehicleState` with seeded sensor noise (actuators and time exact)."""


def _toward(actual: float, demand: float, limit: float, max_step: float) -> float:
    """Move ``actual`` toward ``demand`` clamped to ±limit, by at most ``max_step``."""
    target = limit if demand > limit else (-limit if demand < -limit else demand)
    delta = target - actual
    if delta > max_step:
        return actual + max_step
    if delta < -max_step:
        return actual - max_step
    return target


class Vehicle:
    """The simulated vehicle. Starts in level trimmed flight at ``speed`` (or the cruise-thrust speed)."""

    def __init__(
        self,
        preset: Preset,
        seed: int = 0,
        current_north: float = 0.0,
        current_east: float = 0.0,
        depth: float = 5.0,
        heading: float = 0.0,
        speed: float | None = None,
        faults: Sequence[Fault] = (),
    ) -> None:
        self.preset = preset
        a = preset.actuators
        self.limits = ActuatorLimits(a.rudder_max, a.rudder_rate, a.elevator_max, a.elevator_rate, a.mass_max)
        self._dive = DivePlaneConstants.from_preset(preset.dive_plane)
        self._yaw = YawConstants.from_preset(preset.yaw, preset.sway)
        self._thrust_efficiency = 1.0
        # the preset's faults and the caller's, applied in order of onset (sim/faults.py)
        self._pending_faults = in_time_order((*getattr(preset, "faults", ()), *faults))
        self.active_faults: list[Fault] = []
        self._roll = RollConstants.from_preset(preset.roll)
        self._mass_time_constant = preset.roll.servo_time_constant
        seeds = np.random.SeedSequence(seed).spawn(2)
        self._sensor_rng = np.random.default_rng(seeds[0])
        self._disturbance = RollDisturbance(
            np.random.default_rng(seeds[1]), preset.roll.disturbance_correlation_time
        )
        s = preset.sensors
        deg = math.pi / 180.0
        self._noise_sigma = np.array(
            [s.attitude_deg * deg] * 3 + [s.rate_deg_s * deg] * 3 + [s.depth_m] + [s.position_m] * 2
            + [s.velocity_m_s] * 6 + [s.speed_m_s]
        )
        self.current_north = current_north
        self.current_east = current_east

        if speed is None:
            trim = level_trim_at_thrust(preset, preset.autopilot.cruise_thrust)
        elif speed > 0.0:
            trim = level_trim_at_speed(preset, speed)
        else:
            trim = None
        self.time_s = 0.0
        self.north = 0.0
        self.east = 0.0
        self.depth = depth
        self.yaw = heading  # unwrapped internally
        self.yaw_rate = 0.0
        self.sway = 0.0
        self.roll = 0.0
        self.roll_rate = 0.0
        self.pitch_rate = 0.0
        if trim is None:
            self.surge = self.heave = self.pitch = 0.0
            self.elevator = 0.0
            self.thrust_ratio = 0.0
        else:
            self.pitch = trim.pitch
            self.surge = trim.speed * math.cos(trim.pitch)
            self.heave = trim.speed * math.sin(trim.pitch)
            self.elevator = max(-a.elevator_max, min(a.elevator_max, trim.elevator))
            self.thrust_ratio = trim.thrust_ratio
        self.rudder = 0.0
        self.mass_angle = 0.0
        self._heave_force = 0.0
        if preset.surface:
            self.depth = self.heave = self.pitch = 0.0
            self.elevator = 0.0

    # ------------------------------------------------------------------ configuration
    @property
    def roll_disturbance_amplitude(self) -> float:
        """σ (N·m) of the seeded band-limited random roll moment; 0 switches it off."""
        return self._disturbance.amplitude

    @roll_disturbance_amplitude.setter
    def roll_disturbance_amplitude(self, value: float) -> None:
        self._disturbance.amplitude = max(0.0, float(value))

    def set_current(self, north: float, east: float) -> None:
        """Set the 2-D water current (m/s, over ground); may change at run time."""
        self.current_north = north
        self.current_east = east

    def kick_roll(self, roll: float) -> None:
        """Set the roll angle (rad) instantly with zero roll rate (a tank "impulse", SPEC C6)."""
        self.roll = roll
        self.roll_rate = 0.0

    def _apply_due_faults(self) -> None:
        """Apply every fault whose onset has come (sim/faults.py): from then on the physics differs."""
        while self._pending_faults and self.time_s >= self._pending_faults[0].at_s - 1e-9:
            fault = self._pending_faults.pop(0)
            if fault.kind == "thrust":
                self._thrust_efficiency *= fault.factor
            else:
                self._yaw = scale_yaw(self._yaw, fault)
            self.active_faults.append(fault)
            log.info("fault injected at t=%.2f s: %s", self.time_s, fault.describe())

    # ------------------------------------------------------------------ dynamics
    def _derivatives(
        self, u: float, w: float, q: float, theta: float, r: float, psi: float, v: float,
        phi: float, p: float, thrust: float, roll_moment: float,
    ) -> tuple[float, ...]:
        du, dw, dq = dive_plane_accelerations(self._dive, u, w, q, theta, self.elevator, thrust)
        dw += self._heave_force / self.preset.dive_plane.mass_heave
        speed = math.sqrt(u * u + w * w)
        dr = yaw_acceleration(self._yaw, speed, r, self.rudder)
        dv = sway_acceleration(self._yaw, speed, r, v)
        dp = roll_acceleration(self._roll, phi, p, self.mass_angle, roll_moment)
        sin_t, cos_t = math.sin(theta), math.cos(theta)
        horizontal = u * cos_t + w * sin_t
        sin_y, cos_y = math.sin(psi), math.cos(psi)
        dn = horizontal * cos_y - v * sin_y + self.current_north
        de = horizontal * sin_y + v * cos_y + self.current_east
        dz = -u * sin_t + w * cos_t
        return du, dw, dq, q, dz, dr, r, dv, p, dp, dn, de

    def step(self, dt: float, demand: ActuatorDemand, heave_force: float = 0.0) -> None:
        """Advance ``dt`` seconds: actuator limits, rate limits and mass servo lag, then physics (RK2).

        ``heave_force`` (N, positive down) is an external vertical thrust (a vectored vehicle's
        vertical thrusters). A surface vessel (``preset.surface``) stays at the surface, level in pitch."""
        self._heave_force = heave_force
        if self._pending_faults:
            self._apply_due_faults()
        lim = self.limits
        self.rudder = _toward(self.rudder, demand.rudder, lim.rudder_max, lim.rudder_rate * dt)
        self.elevator = _toward(self.elevator, demand.elevator, lim.elevator_max, lim.elevator_rate * dt)
        self.thrust_ratio = min(1.0, max(0.0, demand.thrust_ratio))
        mass_target = max(-lim.mass_max, min(lim.mass_max, demand.mass_angle))
        self.mass_angle += (mass_target - self.mass_angle) * (1.0 - math.exp(-dt / self._mass_time_constant))

        thrust = thrust_force(self.preset.thruster, self.thrust_ratio) * self._thrust_efficiency
        roll_moment = propeller_torque(self._roll, self.thrust_ratio) + self._disturbance.step(dt)
        x0 = (self.surge, self.heave, self.pitch_rate, self.pitch, self.depth, self.yaw_rate, self.yaw,
              self.sway, self.roll, self.roll_rate, self.north, self.east)
        k1 = self._derivatives(x0[0], x0[1], x0[2], x0[3], x0[5], x0[6], x0[7], x0[8], x0[9], thrust, roll_moment)
        x1 = [x + dt * k for x, k in zip(x0, k1)]
        k2 = self._derivatives(x1[0], x1[1], x1[2], x1[3], x1[5], x1[6], x1[7], x1[8], x1[9], thrust, roll_moment)
        half = 0.5 * dt
        (self.surge, self.heave, self.pitch_rate, self.pitch, self.depth, self.yaw_rate, self.yaw,
         self.sway, self.roll, self.roll_rate, self.north, self.east) = (
            x + half * (a + b) for x, a, b in zip(x0, k1, k2))
        if self.depth < 0.0:  # a buoyant vehicle that loses depth control ends at the surface
            self.depth = 0.0
        if self.preset.surface:  # a boat: no dive plane
            self.depth = self.heave = self.pitch = self.pitch_rate = 0.0
        self.time_s += dt

    # ------------------------------------------------------------------ outputs
    def _velocities_over_ground(self) -> tuple[float, float, float]:
        sin_t, cos_t = math.sin(self.pitch), math.cos(self.pitch)
        horizontal = self.surge * cos_t + self.heave * sin_t
        sin_y, cos_y = math.sin(self.yaw), math.cos(self.yaw)
        vn = horizontal * cos_y - self.sway * sin_y + self.current_north
        ve = horizontal * sin_y + self.sway * cos_y + self.current_east
        vd = -self.surge * sin_t + self.heave * cos_t
        return vn, ve, vd

    @property
    def state(self) -> VehicleState:
        """The true state now."""
        vn, ve, vd = self._velocities_over_ground()
        return VehicleState(
            time_s=self.time_s, north=self.north, east=self.east, depth=self.depth,
            roll=self.roll, pitch=self.pitch, yaw=wrap_angle(self.yaw),
            roll_rate=self.roll_rate, pitch_rate=self.pitch_rate, yaw_rate=self.yaw_rate,
            surge=self.surge, sway=self.sway, heave=self.heave,
            vel_north=vn, vel_east=ve, vel_down=vd,
            speed_water=math.sqrt(self.surge ** 2 + self.sway ** 2 + self.heave ** 2),
            speed_ground=math.hypot(vn, ve),
            rudder=self.rudder, elevator=self.elevator, thrust_ratio=self.thrust_ratio,
            mass_angle=self.mass_angle,
        )

    def measure(self) -> Measurements:
        """The state as the sensors see it: seeded white noise on attitude, rates, depth, position,
        velocities and water speed (deterministic for a seed and a sequence of calls)."""
        s = self.state
        n = (self._sensor_rng.standard_normal(16) * self._noise_sigma).tolist()
        vn, ve, vd = s.vel_north + n[9], s.vel_east + n[10], s.vel_down + n[11]
        return Measurements(
            time_s=s.time_s, north=s.north + n[7], east=s.east + n[8], depth=s.depth + n[6],
            roll=s.roll + n[0], pitch=s.pitch + n[1], yaw=wrap_angle(s.yaw + n[2]),
            roll_rate=s.roll_rate + n[3], pitch_rate=s.pitch_rate + n[4], yaw_rate=s.yaw_rate + n[5],
            surge=s.surge + n[12], sway=s.sway + n[13], heave=s.heave + n[14],
            vel_north=vn, vel_east=ve, vel_down=vd,
            speed_water=max(0.0, s.speed_water + n[15]), speed_ground=math.hypot(vn, ve),
            rudder=s.rudder, elevator=s.elevator, thrust_ratio=s.thrust_ratio, mass_angle=s.mass_angle,
        )
