"""Our preset physics behind PX4 SITL as its MAVLink HIL simulator (``simulator_mavlink``).

The real PX4 firmware (built for SITL by the user; never shipped with this project) runs the
autopilot; this module is its vehicle, the role jMAVSim or Gazebo classic plays. The protocol is
PX4's ``src/modules/simulation/simulator_mavlink/SimulatorMavlink.cpp``:

* PX4 is the TCP **client**: ``simulator_mavlink start -c 4560+i`` (``px4-rc.mavlinksim``)
  connects to port ``4560 + instance`` on the local host; we listen there (:class:`HilEndpoint`).
* We send ``HIL_SENSOR`` (``id`` 0; ``fields_updated`` bits: accel 0-2, gyro 3-5, mag 6-8,
  baro = absolute pressure 9 + pressure altitude 11 + temperature 12), ``HIL_GPS`` and
  ``HIL_STATE_QUATERNION`` (ground truth: PX4 asks for it with ``SET_MESSAGE_INTERVAL``; it feeds
  only the ``*_groundtruth`` topics). ``HIL_SENSOR.time_usec`` of IMU 0 **sets PX4's clock**
  (``px4_clock_settime``): PX4 runs in lockstep with our vehicle time, whatever the wall clock.
* PX4 answers with ``HIL_ACTUATOR_CONTROLS`` whenever its output driver (``pwm_out_sim``)
  publishes: ``controls[i]`` is output channel ``i+1`` (function ``PWM_MAIN_FUNCi``): a motor
  in [0, 1] (or [−1, 1] if reversible, ``CA_R_REV``), a servo in [−1, 1]; all zero while
  disarmed (``mode`` bit 128 = armed, ``flags`` bit 0 = lockstep). ``time_usec`` is PX4's clock
  when the outputs were computed, i.e. the ``HIL_SENSOR`` time they answer.

Lockstep (:class:`HilEndpoint`): one physics step of ``dt`` (10 ms, the rover and UUV
controllers' rate) per ``HIL_SENSOR``; while PX4's outputs are flowing, the next step waits for
the ``HIL_ACTUATOR_CONTROLS`` stamped with the time just sent (as Gazebo classic waits for one
actuator message per sensor message). PX4 publishes outputs only when a controller runs (a
rover's module only while armed), so when none come for a few steps the endpoint runs free,
paced by the wall clock at ``speedup``, until they flow again.

Output channels become our actuators through a decoder per PX4 airframe:

* :class:`AckermannDecoder` — PX4 Ackermann rover (``rover_ackermann``): a steering servo
  (function 201) is the rudder, a motor (101) the thruster: a rudder boat.
* :class:`DifferentialDecoder` — PX4 differential rover (``rover_differential``): right (101)
  and left (102) motors of a twin-screw boat: thrust the mean, an equivalent rudder the difference.
* :class:`UuvQuadDecoder` — PX4 HippoCampus UUV (airframe 1021, ``uuv_att_control`` + control
  allocator): four forward thrusters at (y, z) = (∓0.3, ∓0.3) m, un-mixed by least squares into
  forward (thrust ratio), yaw (equivalent rudder) and pitch (equivalent elevator).

Neither this module nor the simulator imports the companion.
"""
from __future__ import annotations

import logging
import math
import select
import socket
import time
from dataclasses import dataclass, field
from typing import Protocol, Sequence, TextIO

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from sim.vehicle import ActuatorDemand, Vehicle, VehicleState

log = logging.getLogger(__name__)

GRAVITY = 9.80665
EARTH_RADIUS_M = 6371000.0
#: HIL_SENSOR.fields_updated (SimulatorMavlink.hpp ``SensorSource``)
FIELDS_ACCEL = 0b111
FIELDS_GYRO = 0b111000
FIELDS_MAG = 0b111000000
FIELDS_BARO = 0b1101000000000  # abs_pressure, pressure_alt, temperature
FIELDS_ALL = FIELDS_ACCEL | FIELDS_GYRO | FIELDS_MAG | FIELDS_BARO
#: HIL_ACTUATOR_CONTROLS.mode bit set while armed (SimulatorMavlink.cpp ``mode_flag_armed``)
MODE_FLAG_ARMED = 128
WATER_DENSITY = 1025.0  # kg/m³ (sea water) for the pressure at depth


# ---------------------------------------------------------------------------------------- frames
def body_from_ned(roll: float, pitch: float, yaw: float, vector: Sequence[float]) -> list[float]:
    """R_nbᵀ·v: a NED vector in body (FRD) axes, ZYX Euler angles."""
    cr, sr, cp, sp, cy, sy = (math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch),
                              math.cos(yaw), math.sin(yaw))
    n, e, d = vector
    return [cp * cy * n + cp * sy * e - sp * d,
            (sr * sp * cy - cr * sy) * n + (sr * sp * sy + cr * cy) * e + sr * cp * d,
            (cr * sp * cy + sr * sy) * n + (cr * sp * sy - sr * cy) * e + cr * cp * d]


def body_rates(roll: float, pitch: float, roll_rate: float, pitch_rate: float, yaw_rate: float) -> list[float]:
    """Body rates (p, q, r) of Euler-angle rates (φ̇, θ̇, ψ̇): what a gyro reads. Our physics integrate
    the Euler angles from these rates, so the gyro must carry their body-axis equivalent for an
    estimator's attitude to follow ours once the vehicle pitches or rolls."""
    sr, cr, sp, cp = math.sin(roll), math.cos(roll), math.sin(pitch), math.cos(pitch)
    return [roll_rate - yaw_rate * sp,
            pitch_rate * cr + yaw_rate * sr * cp,
            -pitch_rate * sr + yaw_rate * cr * cp]


def quaternion_from_euler(roll: float, pitch: float, yaw: float) -> list[float]:
    """(w, x, y, z) of body-to-NED, ZYX Euler angles (MAVLink's and PX4's convention)."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return [cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy]


# ---------------------------------------------------------------------------------- environment
@dataclass(frozen=True)
class Home:
    """Where the local NED origin is (WGS-84 degrees, metres above mean sea level)."""

    lat_deg: float = 47.397742  # PX4's default SITL home (Zurich); any place works
    lon_deg: float = 8.545594
    alt_m: float = 0.0  # the water surface

    def global_position(self, north: float, east: float, down: float) -> tuple[float, float, float]:
        """Flat-earth (lat, lon, alt) of a NED offset from home: exact enough for kilometres."""
        lat = self.lat_deg + math.degrees(north / EARTH_RADIUS_M)
        lon = self.lon_deg + math.degrees(east / (EARTH_RADIUS_M * math.cos(math.radians(self.lat_deg))))
        return lat, lon, self.alt_m - down


@dataclass(frozen=True)
class MagneticField:
    """Earth field (gauss) from declination, inclination (degrees, + down) and strength.

    PX4 is told the same declination (``EKF2_DECL_TYPE 0``, ``EKF2_MAG_DECL``) by the parameter files
    the launcher loads, so the heading PX4 estimates is the true heading whatever its own world
    magnetic model says about the place (its strength/inclination checks are relaxed there too)."""

    declination_deg: float = 0.0
    inclination_deg: float = 63.0
    strength_gauss: float = 0.48

    def ned(self) -> tuple[float, float, float]:
        d, i = math.radians(self.declination_deg), math.radians(self.inclination_deg)
        h = self.strength_gauss * math.cos(i)
        return h * math.cos(d), h * math.sin(d), self.strength_gauss * math.sin(i)


def air_pressure_hpa(altitude_m: float) -> float:
    """ISA pressure (hPa) at an altitude (m): what PX4 turns back into altitude."""
    return 1013.25 * (1.0 - 2.25577e-5 * altitude_m) ** 5.25588


def absolute_pressure_hpa(depth_m: float, surface_altitude_m: float = 0.0) -> float:
    """Pressure (hPa) at a depth below a water surface at an altitude: air + ρ·g·depth."""
    return air_pressure_hpa(surface_altitude_m) + WATER_DENSITY * GRAVITY * max(0.0, depth_m) / 100.0


@dataclass(frozen=True)
class SensorNoise:
    """White noise σ of the simulated sensors (0 = exact); seeded by the vehicle's seed."""

    accel: float = 0.02  # m/s²
    gyro: float = 0.0005  # rad/s
    mag: float = 0.0005  # gauss
    pressure: float = 0.005  # hPa (5 cm of water)


NO_NOISE = SensorNoise(0.0, 0.0, 0.0, 0.0)


# ------------------------------------------------------------------------------------ messages
def hil_sensor_fields(state: VehicleState, accel_ned: Sequence[float], home: Home = Home(),
                      magnetic: MagneticField = MagneticField(), temperature_c: float = 15.0,
                      noise: np.ndarray | None = None) -> dict:
    """HIL_SENSOR fields of a state (``noise``: 10 additive values in field order, or None).

    Accelerometer: specific force (acceleration − gravity) in body FRD, so level at rest reads
    (0, 0, −g). Gyro: body rates (:func:`body_rates`). Magnetometer: the field in body axes. Absolute pressure: the air
    at the surface plus the water column above the vehicle (a boat reads the surface pressure)."""
    s = state
    specific_force = body_from_ned(s.roll, s.pitch, s.yaw, [accel_ned[0], accel_ned[1], accel_ned[2] - GRAVITY])
    mag = body_from_ned(s.roll, s.pitch, s.yaw, magnetic.ned())
    pressure = absolute_pressure_hpa(s.depth, home.alt_m)
    gyro = body_rates(s.roll, s.pitch, s.roll_rate, s.pitch_rate, s.yaw_rate)
    values = [*specific_force, *gyro, *mag, pressure]
    if noise is not None:
        values = [v + n for v, n in zip(values, noise)]
    return dict(
        time_usec=time_usec(s.time_s),
        xacc=values[0], yacc=values[1], zacc=values[2],
        xgyro=values[3], ygyro=values[4], zgyro=values[5],
        xmag=values[6], ymag=values[7], zmag=values[8],
        abs_pressure=values[9], diff_pressure=0.0,
        pressure_alt=home.alt_m - s.depth, temperature=temperature_c,
        fields_updated=FIELDS_ALL, id=0,
    )


def hil_gps_fields(state: VehicleState, home: Home = Home(), eph_m: float = 0.3, epv_m: float = 0.4,
                   satellites: int = 12) -> dict:
    """HIL_GPS fields (3-D fix) of a state: position from home + NED offset, velocity over ground.
    Under water this stands in for the AUV's navigation (DVL/USBL-aided), as PX4 has no other input."""
    s = state
    lat, lon, alt = home.global_position(s.north, s.east, s.depth)
    speed = math.hypot(s.vel_north, s.vel_east)
    cog = 65535 if speed < 0.05 else int(round(math.degrees(math.atan2(s.vel_east, s.vel_north)) * 100.0)) % 36000
    return dict(
        time_usec=time_usec(s.time_s), fix_type=3,
        lat=int(round(lat * 1e7)), lon=int(round(lon * 1e7)), alt=int(round(alt * 1000.0)),
        eph=int(round(eph_m * 100.0)), epv=int(round(epv_m * 100.0)),
        vel=int(round(speed * 100.0)), vn=int(round(s.vel_north * 100.0)), ve=int(round(s.vel_east * 100.0)),
        vd=int(round(s.vel_down * 100.0)), cog=cog, satellites_visible=satellites, id=0, yaw=0,
    )


def hil_state_quaternion_fields(state: VehicleState, accel_ned: Sequence[float], home: Home = Home()) -> dict:
    """HIL_STATE_QUATERNION (PX4's ground-truth topics) of a state."""
    s = state
    lat, lon, alt = home.global_position(s.north, s.east, s.depth)
    accel_body = body_from_ned(s.roll, s.pitch, s.yaw, [accel_ned[0], accel_ned[1], accel_ned[2] - GRAVITY])
    p, q, r = body_rates(s.roll, s.pitch, s.roll_rate, s.pitch_rate, s.yaw_rate)
    return dict(
        time_usec=time_usec(s.time_s), attitude_quaternion=quaternion_from_euler(s.roll, s.pitch, s.yaw),
        rollspeed=p, pitchspeed=q, yawspeed=r,
        lat=int(round(lat * 1e7)), lon=int(round(lon * 1e7)), alt=int(round(alt * 1000.0)),
        vx=int(round(s.vel_north * 100.0)), vy=int(round(s.vel_east * 100.0)), vz=int(round(s.vel_down * 100.0)),
        ind_airspeed=0, true_airspeed=0,
        xacc=int(round(accel_body[0] / GRAVITY * 1000.0)), yacc=int(round(accel_body[1] / GRAVITY * 1000.0)),
        zacc=int(round(accel_body[2] / GRAVITY * 1000.0)),
    )


def time_usec(time_s: float) -> int:
    """PX4's clock for a vehicle time: the vehicle time itself, in microseconds."""
    return int(round(time_s * 1e6))


# ------------------------------------------------------------------------------------ decoders
class OutputDecoder(Protocol):
    """HIL_ACTUATOR_CONTROLS.controls -> our actuator demand, plus a heave force (N, down positive)."""

    name: str

    def demand(self, controls: Sequence[float], armed: bool,
               previous: ActuatorDemand) -> tuple[ActuatorDemand, float]: ...


def _clamp(value: float, limit: float = 1.0) -> float:
    return max(-limit, min(limit, value))


@dataclass
class AckermannDecoder:
    """PX4 Ackermann rover as a rudder boat: the steering servo (±1, + = turn right) is the rudder
    (±``rudder_full_scale`` rad, + = clockwise yaw in our physics), the motor the thrust ratio
    (reverse is not simulated and reads as zero thrust). Channels are 1-based output channels."""

    rudder_full_scale: float = 0.5236  # rad at ±1: RA_MAX_STR_ANG in sim/px4/px4-rover.params
    steering_channel: int = 2  # PWM_MAIN_FUNC2 201 (Servo 1)
    throttle_channel: int = 1  # PWM_MAIN_FUNC1 101 (Motor 1)
    name: str = "px4-ackermann"

    def demand(self, controls: Sequence[float], armed: bool,
               previous: ActuatorDemand) -> tuple[ActuatorDemand, float]:
        steering = _clamp(controls[self.steering_channel - 1])
        throttle = _clamp(controls[self.throttle_channel - 1])
        return ActuatorDemand(rudder=steering * self.rudder_full_scale, elevator=0.0,
                              thrust_ratio=max(0.0, throttle), mass_angle=previous.mass_angle), 0.0


@dataclass
class DifferentialDecoder:
    """PX4 differential rover as a twin-screw boat: thrust ratio = mean of the right (Motor 1) and
    left (Motor 2) outputs, equivalent rudder = (left − right)/2 · ``rudder_full_scale`` (left faster
    = turn right, as PX4's ``DifferentialActControl`` mixes a positive steering setpoint)."""

    rudder_full_scale: float = 0.5236
    right_channel: int = 1  # PWM_MAIN_FUNC1 101
    left_channel: int = 2  # PWM_MAIN_FUNC2 102
    name: str = "px4-differential"

    def demand(self, controls: Sequence[float], armed: bool,
               previous: ActuatorDemand) -> tuple[ActuatorDemand, float]:
        right = _clamp(controls[self.right_channel - 1])
        left = _clamp(controls[self.left_channel - 1])
        return ActuatorDemand(rudder=(left - right) / 2.0 * self.rudder_full_scale, elevator=0.0,
                              thrust_ratio=max(0.0, (left + right) / 2.0), mass_angle=previous.mass_angle), 0.0


#: HippoCampus (PX4 airframe 1021): thruster positions (y, z) in metres, all thrusting along +x
HIPPOCAMPUS_ROTORS = ((-0.3, -0.3), (0.3, -0.3), (0.3, 0.3), (-0.3, 0.3))


def unmix_quad(outputs: Sequence[float], rotors: Sequence[tuple[float, float]] = HIPPOCAMPUS_ROTORS) -> dict[str, float]:
    """Least-squares un-mix of forward thrusters at (y, z) into forward, yaw and pitch (each ±1).

    A thruster at (y, z) pushing T along +x gives a yaw moment −y·T and a pitch moment z·T (FRD):
    the factors are (1, −sign y, sign z); each axis is Σ fᵢ·oᵢ / Σ fᵢ² (exact while none saturates)."""
    axes = {}
    for name, factor in (("forward", lambda y, z: 1.0), ("yaw", lambda y, z: -math.copysign(1.0, y)),
                         ("pitch", lambda y, z: math.copysign(1.0, z))):
        factors = [factor(y, z) for y, z in rotors]
        axes[name] = sum(f * o for f, o in zip(factors, outputs)) / sum(f * f for f in factors)
    return axes


@dataclass
class UuvQuadDecoder:
    """PX4 HippoCampus UUV flying our AUV: the four thruster outputs are un-mixed
    (:func:`unmix_quad`); yaw (±1) is an equivalent rudder of ±``rudder_full_scale`` rad, pitch (±1,
    + = nose up) an equivalent elevator of ∓``elevator_full_scale`` rad (our elevator + = nose down),
    forward (≥ 0) the thrust ratio.

    **Launch cradle** (as :class:`sim.ardupilot_json.SubVectoredDecoder`): until PX4 first drives the
    thrusters while armed, the buoyant AUV is held where it boots by a heave force of
    ``cradle_force`` N (down), so it neither floats up nor pitches while PX4's estimator starts."""

    rudder_full_scale: float = 0.35
    elevator_full_scale: float = 0.26
    cradle_force: float = 0.0
    channels: tuple[int, ...] = (1, 2, 3, 4)  # PWM_MAIN_FUNC1..4 101..104
    name: str = "px4-uuv-quad"
    launched: bool = False

    @classmethod
    def for_preset(cls, preset) -> UuvQuadDecoder:
        return cls(cradle_force=preset.dive_plane.buoyancy - preset.dive_plane.weight,
                   rudder_full_scale=preset.actuators.rudder_max, elevator_full_scale=preset.actuators.elevator_max)

    def demand(self, controls: Sequence[float], armed: bool,
               previous: ActuatorDemand) -> tuple[ActuatorDemand, float]:
        outputs = [_clamp(controls[c - 1]) for c in self.channels]
        if not self.launched:
            if not (armed and any(abs(o) > 1e-6 for o in outputs)):
                return previous, self.cradle_force
            self.launched = True
        axes = unmix_quad(outputs)
        return ActuatorDemand(rudder=axes["yaw"] * self.rudder_full_scale,
                              elevator=-axes["pitch"] * self.elevator_full_scale,
                              thrust_ratio=max(0.0, axes["forward"]), mass_angle=previous.mass_angle), 0.0


DECODERS: dict[str, type] = {"ackermann": AckermannDecoder, "differential": DifferentialDecoder,
                             "uuv-quad": UuvQuadDecoder}


# ------------------------------------------------------------------------------------- physics
@dataclass
class HilStats:
    """What the lockstep did: steps, actuator messages, steps that waited in vain (late)."""

    steps: int = 0
    actuator_messages: int = 0
    lockstep_steps: int = 0  # steps released by the actuator message answering them
    late_steps: int = 0  # steps that gave up waiting (PX4 slower than ``actuator_timeout_s``)
    free_steps: int = 0  # steps run without waiting (outputs not flowing)


class HilPhysics:
    """Our vehicle stepped at ``dt`` per HIL_SENSOR, with its messages and the truth log."""

    #: vehicle seconds between two rows of the truth log
    TRUTH_PERIOD_S = 0.1

    def __init__(self, vehicle: Vehicle, decoder: OutputDecoder, dt: float = 0.01, home: Home = Home(),
                 magnetic: MagneticField = MagneticField(), noise: SensorNoise = SensorNoise(),
                 gps_period_s: float = 0.1, seed: int = 0, truth_log: TextIO | None = None) -> None:
        self.vehicle = vehicle
        self.decoder = decoder
        self.dt = dt
        self.home = home
        self.magnetic = magnetic
        self.noise = noise
        self.gps_period_s = gps_period_s
        self._rng = np.random.default_rng(np.random.SeedSequence([seed, 4560]))
        self._sigma = np.array([noise.accel] * 3 + [noise.gyro] * 3 + [noise.mag] * 3 + [noise.pressure])
        self.demand = ActuatorDemand(thrust_ratio=0.0)
        self.heave_force = 0.0
        self.armed = False
        self._gps_due_s = 0.0
        self._last_velocity = self._velocity_ned()
        self.accel_ned = [0.0, 0.0, 0.0]
        self.truth_log = truth_log
        self._truth_due_s = 0.0
        if truth_log is not None:
            truth_log.write("time_s,model_speed_m_s,speed_ground_m_s,yaw_rate_rad_s,rudder_rad\n")

    def _velocity_ned(self) -> tuple[float, float, float]:
        s = self.vehicle.state
        return s.vel_north, s.vel_east, s.vel_down

    def apply_controls(self, controls: Sequence[float], mode: int) -> None:
        """A HIL_ACTUATOR_CONTROLS: the demand held over the next steps."""
        self.armed = bool(mode & MODE_FLAG_ARMED)
        self.demand, self.heave_force = self.decoder.demand(controls, self.armed, self.demand)

    def step(self) -> None:
        """One physics step of ``dt`` with the demand held (the cradle holds the AUV until launch)."""
        if not getattr(self.decoder, "launched", True):
            self.demand, self.heave_force = self.decoder.demand([0.0] * 16, self.armed, self.demand)
        self.vehicle.step(self.dt, self.demand, heave_force=self.heave_force)
        velocity = self._velocity_ned()
        self.accel_ned = [(v - v0) / self.dt for v, v0 in zip(velocity, self._last_velocity)]
        self._last_velocity = velocity
        self._log_truth()

    def messages(self, encoder: mavlink.MAVLink) -> list:
        """The messages of the current state: HIL_SENSOR, HIL_STATE_QUATERNION, and HIL_GPS when due."""
        state = self.vehicle.state
        noise = self._rng.standard_normal(10) * self._sigma if self._sigma.any() else None
        out = [encoder.hil_sensor_encode(**hil_sensor_fields(state, self.accel_ned, self.home, self.magnetic,
                                                             noise=noise))]
        if state.time_s >= self._gps_due_s - 1e-9:
            self._gps_due_s = state.time_s + self.gps_period_s
            out.append(encoder.hil_gps_encode(**hil_gps_fields(state, self.home)))
        out.append(encoder.hil_state_quaternion_encode(**hil_state_quaternion_fields(state, self.accel_ned, self.home)))
        return out

    def _log_truth(self) -> None:
        """One row every ``TRUTH_PERIOD_S`` of vehicle time (= PX4's ``time_boot_ms``/1000): the speed
        the yaw model is evaluated at, as :class:`sim.ardupilot_json.JsonPhysics` writes it."""
        state = self.vehicle.state
        if self.truth_log is None or state.time_s < self._truth_due_s - 1e-9:
            return
        self._truth_due_s = state.time_s + self.TRUTH_PERIOD_S
        self.truth_log.write(f"{state.time_s:.3f},{math.hypot(state.surge, state.heave):.5f},"
                             f"{state.speed_ground:.5f},{state.yaw_rate:.6f},{state.rudder:.5f}\n")
        self.truth_log.flush()


# ------------------------------------------------------------------------------------ endpoint
class _Writer:
    """pymavlink's encoder needs a file; we only use it to build messages."""

    def write(self, data: bytes) -> None:  # pragma: no cover - never called (we pack ourselves)
        pass


@dataclass
class HilEndpoint:
    """The TCP server PX4's ``simulator_mavlink`` connects to, running the lockstep loop."""

    physics: HilPhysics
    host: str = "127.0.0.1"
    port: int = 4560
    speedup: float = 1.0  # vehicle s per wall s; 0 = as fast as PX4 goes
    actuator_timeout_s: float = 0.25  # wall s a step waits for its outputs before running free
    free_after_missed: int = 3  # consecutive steps without outputs before running free
    #: running free nothing holds us back to PX4's pace: at most this speed-up then (PX4 booted and
    #: aligned its estimator at 24x on 2 busy cores, measured; lockstep steps are limited only by PX4)
    free_speedup_max: float = 20.0
    stats: HilStats = field(default_factory=HilStats)

    def __post_init__(self) -> None:
        self.listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.listener.bind((self.host, self.port))
        self.listener.listen(1)
        self.port = self.listener.getsockname()[1]
        self.conn: socket.socket | None = None
        self.mav = mavlink.MAVLink(_Writer(), srcSystem=1, srcComponent=51)
        self.mav.robust_parsing = True
        self._flowing = False
        self._missed = 0
        self._latest_output_usec = -1
        self._pace_speedup = -1.0
        self._free_seen = 0  # actuator messages counted when the outputs last stopped
        self._stop = False
        self.closed = False

    def accept(self, timeout_s: float, alive=lambda: True) -> None:
        """Wait for PX4 to connect (``alive()`` False aborts: the process died)."""
        deadline = time.monotonic() + timeout_s
        self.listener.settimeout(0.2)
        while time.monotonic() < deadline:
            if not alive():
                raise RuntimeError("PX4 exited before it connected to the simulator port")
            try:
                self.conn, _ = self.listener.accept()
            except socket.timeout:
                continue
            self.conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self.conn.setblocking(False)
            log.info("PX4 connected to the HIL port %d", self.port)
            return
        raise RuntimeError(f"PX4 did not connect to the HIL port {self.port} within {timeout_s:.0f} s")

    def stop(self) -> None:
        self._stop = True

    def _send(self, messages) -> bool:
        """Send whole messages; False when the connection is gone."""
        data = b"".join(m.pack(self.mav) for m in messages)
        view = memoryview(data)
        while view:
            try:
                sent = self.conn.send(view)
            except BlockingIOError:
                select.select([], [self.conn], [], 1.0)
                continue
            except OSError:
                return False
            view = view[sent:]
        return True

    def _receive(self, timeout_s: float) -> bool:
        """Read what PX4 sent within ``timeout_s``; False when the connection closed."""
        readable, _, _ = select.select([self.conn], [], [], max(0.0, timeout_s))
        if not readable:
            return True
        try:
            data = self.conn.recv(65536)
        except (BlockingIOError, InterruptedError):
            return True
        except OSError:
            return False
        if not data:
            return False
        for message in self.mav.parse_buffer(data) or []:
            if message.get_type() == "HIL_ACTUATOR_CONTROLS":
                self.stats.actuator_messages += 1
                self.physics.apply_controls(message.controls, message.mode)
                self._latest_output_usec = max(self._latest_output_usec, message.time_usec)
        return True

    def step_once(self) -> bool:
        """One lockstep step: physics, sensors out, then PX4's outputs for them (or run free).
        False when PX4 closed the connection."""
        self.physics.step()
        sent_usec = time_usec(self.physics.vehicle.time_s)
        if not self._send(self.physics.messages(self.mav)):
            return False
        self.stats.steps += 1
        if self._flowing:
            deadline = time.monotonic() + self.actuator_timeout_s
            while self._latest_output_usec < sent_usec:
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                if not self._receive(left):
                    return False
            if self._latest_output_usec >= sent_usec:
                self.stats.lockstep_steps += 1
                self._missed = 0
            else:
                self.stats.late_steps += 1
                self._missed += 1
                if self._missed >= self.free_after_missed:
                    log.debug("PX4 outputs stopped at %.2f s: running free", self.physics.vehicle.time_s)
                    self._flowing = False
                    self._free_seen = self.stats.actuator_messages
        else:
            if not self._receive(0.0):
                return False
            self.stats.free_steps += 1
            if self.stats.actuator_messages > self._free_seen:  # outputs came (here or while pacing)
                self._flowing = True
                self._missed = 0
        return True

    def run(self, alive=lambda: True, duration_s: float | None = None, until=None, every: int = 20) -> None:
        """Step until stopped, PX4 disconnects or ``alive()`` turns False; paced at ``speedup`` (0: as
        fast as PX4 answers), at most ``free_speedup_max`` while running free. ``until()``, asked every
        ``every`` steps, ends the run when it returns True."""
        start_s = self.physics.vehicle.time_s
        wall0, sim0 = time.monotonic(), start_s
        while not self._stop and alive():
            if duration_s is not None and self.physics.vehicle.time_s - start_s >= duration_s - 1e-6:
                break
            if not self.step_once():
                log.info("PX4 closed the HIL connection")
                self.closed = True
                break
            if until is not None and self.stats.steps % every == 0 and until():
                break
            speedup = self.speedup if self._flowing else min(self.speedup or math.inf, self.free_speedup_max)
            if speedup != self._pace_speedup:  # restart the pacing clock when the pace changes
                self._pace_speedup, wall0, sim0 = speedup, time.monotonic(), self.physics.vehicle.time_s
            while speedup > 0:  # pace: meanwhile read what PX4 sends
                ahead = (self.physics.vehicle.time_s - sim0) / speedup - (time.monotonic() - wall0)
                if ahead <= 0:
                    break
                if not self._receive(ahead):
                    return

    def close(self) -> None:
        for sock in (self.conn, self.listener):
            if sock is not None:
                try:
                    sock.close()
                except OSError:
                    pass
