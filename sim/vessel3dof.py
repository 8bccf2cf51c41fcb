"""A 3-DOF surface vessel (surge, sway, yaw) with a stern rudder or twin thrusters (skid steering).

The hull is Fossen's manoeuvring model (``sim/physics/hull3dof.py``), the control forces a rudder or
two thrusters (``sim/physics/propulsion3dof.py``). Beside them the vessel keeps the simulator's roll
with the internal rolling mass (thesis eq. 4.11, the preset's ``roll`` section), its sensors and
its current, so the autopilot, the MAVLink server and the ArduPilot JSON bridge drive it exactly as
they drive :class:`sim.vehicle.Vehicle`: it *is* a ``Vehicle`` to them (same ``step``, ``state``,
``measure``, limits and settings; the inherited ``measure``, ``set_current``, ``kick_roll`` and
``roll_disturbance_amplitude`` read the attributes this class sets).

Actuators:

* rudder vessels: the rudder demand is position- and rate-limited as on the first-order boat; the
  thrust ratio (0…1) drives one propeller;
* twin-thruster vessels: ``ActuatorDemand.motor_left/right`` (±1, already mixed by the autopilot:
  ``sim.skid_mixer``) drive the two motors; reverse thrust is allowed.

Each propeller shaft follows its demand with a first-order lag (``thruster.time_constant``, exact
exponential discretisation, as Fossen's Otter's ``n_dot = (n_c − n)/T_n``). The state reports the
*commanded* outputs (what an autopilot's SERVO_OUTPUT_RAW shows); for a skid vessel ``rudder`` and
``thrust_ratio`` are the steering and throttle un-mixed from the commanded motors, steering scaled
to an equivalent rudder angle of ±``FULL_SCALE_RAD`` (the simulator's channel-1 scale).

Integration: Heun (RK2) over (u, v, r, ψ, north, east, φ, p) with actuators held over the step.
Depth, pitch and heave stay 0 (a surface vessel).
"""
from __future__ import annotations

import logging
import math
from dataclasses import replace
from typing import Sequence

import numpy as np

from sim.faults import Fault, in_time_order
from sim.params import FULL_SCALE_RAD
from sim.physics.disturbance import RollDisturbance
from sim.physics.hull3dof import HullConstants, accelerations, hull_forces
from sim.physics.propulsion3dof import RudderConstants, rudder_forces, twin_thruster_forces
from sim.physics.roll import RollConstants, propeller_torque, roll_acceleration
from sim.physics.straight_run import straight_run_at_speed, straight_run_at_thrust
from sim.physics.thruster import thrust_force
from sim.preset import Preset
from sim.skid_mixer import skid_unmix
from sim.vehicle import ActuatorDemand, ActuatorLimits, Measurements, Vehicle, VehicleState, _toward, wrap_angle

log = logging.getLogger(__name__)


def _lag_factor(dt: float, time_constant: float) -> float:
    """Fraction of the gap a first-order lag closes in ``dt`` (1 without a lag)."""
    return 1.0 if time_constant <= 0.0 else 1.0 - math.exp(-dt / time_constant)


class Vessel3Dof(Vehicle):
    """The 3-DOF surface vessel; starts on a straight run at ``speed`` (or the cruise-thrust speed)."""

    def __init__(  # noqa: PLR0913 - the same signature as Vehicle
        self,
        preset: Preset,
        seed: int = 0,
        current_north: float = 0.0,
        current_east: float = 0.0,
        depth: float = 0.0,
        heading: float = 0.0,
        speed: float | None = None,
        faults: Sequence[Fault] = (),
    ) -> None:
        if not preset.is_3dof:
            raise ValueError(f"preset {preset.name!r} has no 'hull': use sim.vehicle.Vehicle")
        self.preset = preset
        a = preset.actuators
        self.limits = ActuatorLimits(a.rudder_max, a.rudder_rate, a.elevator_max, a.elevator_rate, a.mass_max)
        self.skid = preset.is_skid
        self._hull = HullConstants.from_preset(preset.hull)
        self._rudder = None if self.skid else RudderConstants.from_preset(preset.rudder)
        self._shaft_time_constant = preset.thruster.time_constant
        self._thrust_efficiency = 1.0
        self._steering_authority = 1.0  # a skid vessel's "b2" fault: its yaw moment arm scaled
        self._pending_faults = in_time_order((*getattr(preset, "faults", ()), *faults))
        self.active_faults: list[Fault] = []
        self._roll = RollConstants.from_preset(preset.roll)
        self._mass_time_constant = preset.roll.servo_time_constant
        seeds = np.random.SeedSequence(seed).spawn(2)
        self._sensor_rng = np.random.default_rng(seeds[0])
        self._disturbance = RollDisturbance(np.random.default_rng(seeds[1]), preset.roll.disturbance_correlation_time)
        s = preset.sensors
        deg = math.pi / 180.0
        self._noise_sigma = np.array(
            [s.attitude_deg * deg] * 3 + [s.rate_deg_s * deg] * 3 + [s.depth_m] + [s.position_m] * 2
            + [s.velocity_m_s] * 6 + [s.speed_m_s]
        )
        self.current_north = current_north
        self.current_east = current_east

        if speed is None:
            run = straight_run_at_thrust(preset, preset.autopilot.cruise_thrust)
        else:
            run = straight_run_at_speed(preset, max(0.0, speed))
        self.time_s = 0.0
        self.north = 0.0
        self.east = 0.0
        self.yaw = heading  # unwrapped internally
        self.yaw_rate = 0.0
        self.surge = run.speed
        self.sway = 0.0
        self.roll = 0.0
        self.roll_rate = 0.0
        self.depth = self.heave = self.pitch = self.pitch_rate = 0.0
        self.elevator = 0.0
        self.mass_angle = 0.0
        self._heave_force = 0.0
        if self.skid:
            self.rudder = 0.0
            self.motor_left, self.motor_right = (run.left, run.right) if run.speed > 0.0 else (0.0, 0.0)
            self._shaft_left, self._shaft_right = self.motor_left, self.motor_right
            self.thrust_ratio = 0.5 * (self.motor_left + self.motor_right)
        else:
            self.rudder = 0.0
            self.motor_left = self.motor_right = 0.0
            self.thrust_ratio = run.thrust_ratio if run.speed > 0.0 else 0.0
            self._shaft = self.thrust_ratio

    # ------------------------------------------------------------------ faults
    def _apply_due_faults(self) -> None:
        """Faults (sim/faults.py) on this vessel: ``thrust`` scales every propeller's thrust, ``b2`` the
        rudder's lift (or, skid, the yaw moment of the differential thrust), ``damping`` the hull's
        yaw damping N_r, N_rU and N_|r|r."""
        while self._pending_faults and self.time_s >= self._pending_faults[0].at_s - 1e-9:
            fault = self._pending_faults.pop(0)
            if fault.kind == "thrust":
                self._thrust_efficiency *= fault.factor
            elif fault.kind == "b2":
                if self.skid:
                    self._steering_authority *= fault.factor
                else:
                    self._rudder = replace(self._rudder, lift=self._rudder.lift * fault.factor)
            else:
                self._hull = self._hull.scaled_yaw_damping(fault.factor)
            self.active_faults.append(fault)
            log.info("fault injected at t=%.2f s: %s", self.time_s, fault.describe())

    # ------------------------------------------------------------------ dynamics
    def _propulsion(self) -> tuple[float, float]:
        """(surge force, yaw moment) of the propellers over this step (the rudder depends on u)."""
        if self.skid:
            x, _, n = twin_thruster_forces(self.preset.twin_thrusters, self.preset.thruster, self._shaft_left,
                                           self._shaft_right, self._thrust_efficiency, self._steering_authority)
            return x, n
        return thrust_force(self.preset.thruster, self._shaft) * self._thrust_efficiency, 0.0

    def _derivatives(self, u: float, v: float, r: float, psi: float, phi: float, p: float,
                     thrust_x: float, thrust_n: float, roll_moment: float) -> tuple[float, ...]:
        x, y, n = hull_forces(self._hull, u, v, r)
        x += thrust_x
        n += thrust_n
        if self._rudder is not None:
            rx, ry, rn = rudder_forces(self._rudder, u, self.rudder)
            x += rx
            y += ry
            n += rn
        du, dv, dr = accelerations(self._hull, x, y, n)
        dp = roll_acceleration(self._roll, phi, p, self.mass_angle, roll_moment)
        sin_y, cos_y = math.sin(psi), math.cos(psi)
        dn = u * cos_y - v * sin_y + self.current_north
        de = u * sin_y + v * cos_y + self.current_east
        return du, dv, dr, r, p, dp, dn, de

    def step(self, dt: float, demand: ActuatorDemand, heave_force: float = 0.0) -> None:
        """Advance ``dt`` seconds: actuators (limits, rate limit, shaft lag, mass servo), then RK2.
        ``heave_force`` is accepted for the interface and ignored (a surface vessel)."""
        if self._pending_faults:
            self._apply_due_faults()
        lim = self.limits
        lag = _lag_factor(dt, self._shaft_time_constant)
        if self.skid:
            self.motor_left = max(-1.0, min(1.0, demand.motor_left))
            self.motor_right = max(-1.0, min(1.0, demand.motor_right))
            self._shaft_left += (self.motor_left - self._shaft_left) * lag
            self._shaft_right += (self.motor_right - self._shaft_right) * lag
            steering, throttle = skid_unmix(self.motor_left, self.motor_right)
            self.rudder = steering * FULL_SCALE_RAD
            self.thrust_ratio = throttle
        else:
            self.rudder = _toward(self.rudder, demand.rudder, lim.rudder_max, lim.rudder_rate * dt)
            self.thrust_ratio = min(1.0, max(0.0, demand.thrust_ratio))
            self._shaft += (self.thrust_ratio - self._shaft) * lag
        mass_target = max(-lim.mass_max, min(lim.mass_max, demand.mass_angle))
        self.mass_angle += (mass_target - self.mass_angle) * (1.0 - math.exp(-dt / self._mass_time_constant))

        thrust_x, thrust_n = self._propulsion()
        roll_moment = propeller_torque(self._roll, max(0.0, self.thrust_ratio)) + self._disturbance.step(dt)
        x0 = (self.surge, self.sway, self.yaw_rate, self.yaw, self.roll, self.roll_rate, self.north, self.east)
        k1 = self._derivatives(*x0[:6], thrust_x, thrust_n, roll_moment)
        x1 = [x + dt * k for x, k in zip(x0, k1)]
        k2 = self._derivatives(*x1[:6], thrust_x, thrust_n, roll_moment)
        half = 0.5 * dt
        (self.surge, self.sway, self.yaw_rate, self.yaw, self.roll, self.roll_rate, self.north, self.east) = (
            x + half * (a + b) for x, a, b in zip(x0, k1, k2))
        self.time_s += dt

    # ------------------------------------------------------------------ outputs
    @property
    def shafts(self) -> tuple[float, float]:
        """The propeller shafts' lagged demands (left, right; a rudder vessel's one shaft twice)."""
        return (self._shaft_left, self._shaft_right) if self.skid else (self._shaft, self._shaft)

    @property
    def state(self) -> VehicleState:
        vn, ve, vd = self._velocities_over_ground()
        return VehicleState(
            time_s=self.time_s, north=self.north, east=self.east, depth=0.0,
            roll=self.roll, pitch=0.0, yaw=wrap_angle(self.yaw),
            roll_rate=self.roll_rate, pitch_rate=0.0, yaw_rate=self.yaw_rate,
            surge=self.surge, sway=self.sway, heave=0.0,
            vel_north=vn, vel_east=ve, vel_down=vd,
            speed_water=math.sqrt(self.surge ** 2 + self.sway ** 2),
            speed_ground=math.hypot(vn, ve),
            rudder=self.rudder, elevator=0.0, thrust_ratio=self.thrust_ratio, mass_angle=self.mass_angle,
            motor_left=self.motor_left, motor_right=self.motor_right,
        )

    def measure(self) -> Measurements:
        """Sensor readings as :meth:`Vehicle.measure` (same noise draws), with the motor demands."""
        return replace(super().measure(), motor_left=self.motor_left, motor_right=self.motor_right)
