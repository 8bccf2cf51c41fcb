"""Our preset physics behind ArduPilot SITL's JSON backend (``--model JSON:127.0.0.1``).

The real ArduPilot firmware (built for SITL) runs the autopilot; this module is its vehicle. The
protocol is ArduPilot's ``libraries/SITL/examples/JSON/readme.md``:

* SITL sends one binary servo frame per physics step to our UDP port
  (``uint16 magic 18458 | uint16 frame_rate | uint32 frame_count | uint16 pwm[16]``; magic 29569
  carries 32 channels);
* we answer each frame with one JSON line of the state after a step of ``1/frame_rate`` seconds:
  ``timestamp`` (s), ``imu.gyro`` (body rad/s), ``imu.accel_body`` (specific force, body FRD,
  m/s²), ``position`` and ``velocity`` (NED, m, m/s), ``attitude`` (roll, pitch, yaw).

SITL waits for each answer before it advances (lockstep), so results do not depend on the
speed-up. The state sent is the true state: ArduPilot's own SITL sensor models add their noise.

Servo outputs become our actuators through a :class:`FrameDecoder` per autopilot frame:

* :class:`RoverBoatDecoder` — ArduRover boat (``FRAME_CLASS 2``): SERVO1 ground steering, SERVO3
  throttle (1500 µs = stop for boats; reverse is not simulated and reads as zero thrust).
* :class:`RoverSkidDecoder` — ArduRover skid-steered boat: SERVO1 ThrottleLeft (function 73), SERVO3
  ThrottleRight (74), each 1000–2000 µs with 1500 = stop and below it astern: the two motor demands
  of a twin-thruster vessel (``AP_MotorsUGV::output_skid_steering`` mixed them; ``sim.skid_mixer``).
* :class:`SubVectoredDecoder` — ArduSub vectored frame: the six thruster outputs are un-mixed into
  yaw, forward and vertical demands (``AP_Motors6DOF`` factors); yaw acts as an equivalent rudder
  and the vertical demand as a heave force.

Neither this module nor the simulator imports the companion.
"""
from __future__ import annotations

import json
import logging
import math
import socket
import struct
from dataclasses import dataclass
from typing import Protocol, Sequence, TextIO

from sim.vehicle import ActuatorDemand, Vehicle

log = logging.getLogger(__name__)

MAGIC_16 = 18458
MAGIC_32 = 29569
_HEADER = struct.Struct("<HHI")
GRAVITY = 9.80665


@dataclass(frozen=True)
class ServoFrame:
    frame_rate: int  # Hz: the step SITL asks for
    frame_count: int
    pwm: tuple[int, ...]  # µs, channel 1 first


def parse_servo_frame(data: bytes) -> ServoFrame | None:
    """A servo frame, or None for anything else (wrong magic or length: ignored, never raised)."""
    if len(data) < _HEADER.size:
        return None
    magic, frame_rate, frame_count = _HEADER.unpack_from(data)
    channels = {MAGIC_16: 16, MAGIC_32: 32}.get(magic)
    if channels is None or len(data) < _HEADER.size + 2 * channels:
        return None
    pwm = struct.unpack_from(f"<{channels}H", data, _HEADER.size)
    return ServoFrame(frame_rate=frame_rate, frame_count=frame_count, pwm=tuple(pwm))


class FrameDecoder(Protocol):
    """Servo outputs (µs) -> our actuator demand, plus an optional heave force (N, down positive)."""

    name: str

    def demand(self, pwm: Sequence[int], previous: ActuatorDemand) -> tuple[ActuatorDemand, float]: ...


def _normalised(pwm: int, centre: float = 1500.0, half_range: float = 500.0) -> float | None:
    """(pwm − centre)/half_range clamped to ±1; None for 0 (output disabled)."""
    if pwm <= 0:
        return None
    return max(-1.0, min(1.0, (pwm - centre) / half_range))


@dataclass(frozen=True)
class RoverBoatDecoder:
    """ArduRover boat: SERVO1 steering (±1 -> ±``rudder_full_scale`` rad), SERVO3 throttle."""

    rudder_full_scale: float = 0.5236  # rad at 1000/2000 µs (the ardurover profile's default)
    steering_channel: int = 1
    throttle_channel: int = 3
    name: str = "ardurover-boat"

    def demand(self, pwm: Sequence[int], previous: ActuatorDemand) -> tuple[ActuatorDemand, float]:
        steering = _normalised(pwm[self.steering_channel - 1])
        throttle = _normalised(pwm[self.throttle_channel - 1])
        rudder = previous.rudder if steering is None else steering * self.rudder_full_scale
        thrust = 0.0 if throttle is None else max(0.0, throttle)  # reverse: not simulated
        return ActuatorDemand(rudder=rudder, elevator=0.0, thrust_ratio=thrust,
                              mass_angle=previous.mass_angle), 0.0


@dataclass(frozen=True)
class RoverSkidDecoder:
    """ArduRover skid steering: SERVO1 ThrottleLeft, SERVO3 ThrottleRight → motor demands ±1
    ((pwm − 1500)/500; a disabled output, PWM 0, stops its motor)."""

    left_channel: int = 1
    right_channel: int = 3
    name: str = "ardurover-skid"

    def demand(self, pwm: Sequence[int], previous: ActuatorDemand) -> tuple[ActuatorDemand, float]:
        left = _normalised(pwm[self.left_channel - 1])
        right = _normalised(pwm[self.right_channel - 1])
        return ActuatorDemand(rudder=0.0, elevator=0.0, thrust_ratio=0.0, mass_angle=previous.mass_angle,
                              motor_left=0.0 if left is None else left,
                              motor_right=0.0 if right is None else right), 0.0


# AP_Motors6DOF SUB_FRAME_VECTORED factors: (roll, pitch, yaw, throttle, forward, lateral) per motor
_VECTORED = (
    (0.0, 0.0, 1.0, 0.0, -1.0, 1.0),
    (0.0, 0.0, -1.0, 0.0, -1.0, -1.0),
    (0.0, 0.0, -1.0, 0.0, 1.0, 1.0),
    (0.0, 0.0, 1.0, 0.0, 1.0, -1.0),
    (1.0, 0.0, 0.0, -1.0, 0.0, 0.0),
    (-1.0, 0.0, 0.0, -1.0, 0.0, 0.0),
)


def unmix_vectored(outputs: Sequence[float]) -> dict[str, float]:
    """Least-squares un-mix of the vectored frame's six motor outputs (±1) into its axes.

    Each axis is Σ fᵢ·oᵢ / Σ fᵢ² over the frame factors (exact while no motor saturates; once one
    does, the axes the motors actually produce). ``throttle`` is ArduSub's bidirectional throttle:
    positive = climb (motors 5/6 have throttle factor −1, so a climb drives them below 1500 µs)."""
    axes = {}
    for index, name in ((0, "roll"), (2, "yaw"), (3, "throttle"), (4, "forward"), (5, "lateral")):
        factors = [row[index] for row in _VECTORED]
        axes[name] = sum(f * o for f, o in zip(factors, outputs)) / sum(f * f for f in factors)
    return axes


@dataclass
class SubVectoredDecoder:
    """ArduSub vectored frame: thruster outputs un-mixed by least squares over the frame factors.

    Yaw (±1) acts as an equivalent rudder of ±``rudder_full_scale`` rad (the ardusub profile's
    default), forward (≥ 0) as the thrust ratio, and the throttle (vertical thrusters, positive =
    climb) as a heave force of up to ``heave_force_max`` N upwards. Roll and lateral are not
    simulated. Motor directions (``MOT_n_DIRECTION``) are those of the parameter file the launcher
    writes: all normal.

    **Launch cradle**: until the thrusters first run (any of motors 1..6 off 1500 µs), the AUV is
    held where it boots by a heave force of ``cradle_force`` N (down; its buoyancy minus its
    weight), as if hanging from a launch crane. ArduSub's EKF needs tens of seconds after boot
    before it navigates, and the buoyant AUV would meanwhile float up and pitch (measured: from
    2 m to the surface in 17 s, 20° of pitch; our physics cannot rest at the surface)."""

    rudder_full_scale: float = 0.35
    heave_force_max: float = 60.0
    pwm_half_range: float = 400.0
    cradle_force: float = 0.0
    name: str = "ardusub-vectored"
    launched: bool = False

    @classmethod
    def for_preset(cls, preset) -> SubVectoredDecoder:
        """The decoder of this vehicle: its cradle cancels the preset's net buoyancy."""
        return cls(cradle_force=preset.dive_plane.buoyancy - preset.dive_plane.weight)

    def demand(self, pwm: Sequence[int], previous: ActuatorDemand) -> tuple[ActuatorDemand, float]:
        outputs = [_normalised(p, 1500.0, self.pwm_half_range) for p in pwm[:6]]
        if len(outputs) < 6 or any(o is None for o in outputs):
            return previous, (0.0 if self.launched else self.cradle_force)
        if not self.launched and all(o == 0.0 for o in outputs):
            return previous, self.cradle_force
        self.launched = True
        axes = unmix_vectored(outputs)
        heave_force = -axes["throttle"] * self.heave_force_max  # climb demand -> force up (negative down)
        return ActuatorDemand(rudder=axes["yaw"] * self.rudder_full_scale, elevator=0.0,
                              thrust_ratio=max(0.0, axes["forward"]), mass_angle=previous.mass_angle), heave_force


DECODERS: dict[str, type] = {"ardurover": RoverBoatDecoder, "ardusub": SubVectoredDecoder}
#: the decoder of an autopilot flying a twin-thruster (skid-steered) preset instead
SKID_DECODERS: dict[str, type] = {"ardurover": RoverSkidDecoder}


class JsonPhysics:
    """One step of our physics per servo frame; builds the JSON answer (see the module docstring)."""

    #: vehicle seconds between two rows of the truth log
    TRUTH_PERIOD_S = 0.1

    def __init__(self, vehicle: Vehicle, decoder: FrameDecoder, max_step_s: float = 0.01,
                 truth_log: TextIO | None = None) -> None:
        self.vehicle = vehicle
        self.decoder = decoder
        self.max_step_s = max_step_s
        # the physics' own speed, for scoring: ArduPilot's estimate of it is not the truth (measured
        # on SITL: the EKF's ground speed reads 0.02 m/s low on the boat, ~3.5 % low on the sub)
        self.truth_log = truth_log
        self._truth_due_s = 0.0
        if truth_log is not None:
            truth_log.write("time_s,model_speed_m_s,speed_ground_m_s,yaw_rate_rad_s,rudder_rad\n")
        self.demand = ActuatorDemand(thrust_ratio=0.0)
        self.frames = 0
        self._last_velocity = self._velocity_ned()

    def _velocity_ned(self) -> tuple[float, float, float]:
        s = self.vehicle.state
        return s.vel_north, s.vel_east, s.vel_down

    def step(self, frame: ServoFrame) -> bytes:
        """Advance by the frame's time step (sub-stepped at ``max_step_s``); return the JSON line."""
        self.demand, heave_force = self.decoder.demand(frame.pwm, self.demand)
        dt = 1.0 / frame.frame_rate if frame.frame_rate > 0 else self.max_step_s
        dt = min(dt, 0.1)
        steps = max(1, int(math.ceil(dt / self.max_step_s - 1e-9)))
        for _ in range(steps):
            self.vehicle.step(dt / steps, self.demand, heave_force=heave_force)
        self.frames += 1
        self._log_truth()
        velocity = self._velocity_ned()
        accel_ned = [(v - v0) / dt for v, v0 in zip(velocity, self._last_velocity)]
        self._last_velocity = velocity
        return state_line(self.vehicle, accel_ned)


    def _log_truth(self) -> None:
        """One row of the truth log every ``TRUTH_PERIOD_S`` of physics time: the speed the yaw model
        is evaluated at (surge and heave through the water), on the clock SITL reports as
        ``time_boot_ms`` (both start at the first frame; measured offset 1.5 ms)."""
        state = self.vehicle.state
        if self.truth_log is None or state.time_s < self._truth_due_s:
            return
        self._truth_due_s = state.time_s + self.TRUTH_PERIOD_S
        self.truth_log.write(f"{state.time_s:.3f},{math.hypot(state.surge, state.heave):.5f},"
                             f"{state.speed_ground:.5f},{state.yaw_rate:.6f},{state.rudder:.5f}\n")
        self.truth_log.flush()


def _body_from_ned(roll: float, pitch: float, yaw: float, vector: Sequence[float]) -> list[float]:
    """R_nbᵀ·v: a NED vector in body axes (ZYX Euler angles)."""
    cr, sr, cp, sp, cy, sy = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch), math.cos(yaw), math.sin(yaw)
    n, e, d = vector
    x = cp * cy * n + cp * sy * e - sp * d
    y = (sr * sp * cy - cr * sy) * n + (sr * sp * sy + cr * cy) * e + sr * cp * d
    z = (cr * sp * cy + sr * sy) * n + (cr * sp * sy - sr * cy) * e + cr * cp * d
    return [x, y, z]


def state_line(vehicle: Vehicle, accel_ned: Sequence[float]) -> bytes:
    """The JSON state SITL reads: specific force = acceleration − gravity, in body axes."""
    s = vehicle.state
    specific_force = _body_from_ned(s.roll, s.pitch, s.yaw, [accel_ned[0], accel_ned[1], accel_ned[2] - GRAVITY])
    state = {
        "timestamp": s.time_s,
        "imu": {"gyro": [s.roll_rate, s.pitch_rate, s.yaw_rate], "accel_body": specific_force},
        "position": [s.north, s.east, s.depth],
        "velocity": [s.vel_north, s.vel_east, s.vel_down],
        "attitude": [s.roll, s.pitch, s.yaw],
    }
    return ("\n" + json.dumps(state, separators=(",", ":")) + "\n").encode("ascii")


class JsonBridge:
    """UDP endpoint for SITL's servo frames (bind to port 0 for a free port, then tell SITL with
    ``--sim-port-out``); answers each frame to the address it came from."""

    def __init__(self, physics: JsonPhysics, host: str = "127.0.0.1", port: int = 0) -> None:
        self.physics = physics
        self.socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.socket.bind((host, port))
        self.port = self.socket.getsockname()[1]
        self.last_frame_count = -1

    def serve_once(self, timeout_s: float) -> bool:
        """Handle one frame if one arrives within ``timeout_s`` (wall clock: a process-level wait)."""
        self.socket.settimeout(timeout_s)
        try:
            data, address = self.socket.recvfrom(2048)
        except socket.timeout:
            return False
        frame = parse_servo_frame(data)
        if frame is None:
            log.debug("ignored a %d-byte datagram that is not a servo frame", len(data))
            return True
        if frame.frame_count == self.last_frame_count:
            # SITL re-sends a frame it got no answer to: answer again without stepping twice
            self.socket.sendto(state_line(self.physics.vehicle, [0.0, 0.0, 0.0]), address)
            return True
        self.last_frame_count = frame.frame_count
        self.socket.sendto(self.physics.step(frame), address)
        return True

    def close(self) -> None:
        self.socket.close()
