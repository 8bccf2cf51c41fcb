"""Our physics behind PX4 SITL, without PX4: the HIL messages, the output decoders, the lockstep
endpoint against a fake ``simulator_mavlink``, and the launcher's pieces (sim/px4_hil.py,
sim/px4_sitl.py)."""
from __future__ import annotations

import math
import socket
import threading
import time
from dataclasses import replace
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as mavlink

from sim.preset import load_preset
from sim.px4_hil import (
    FIELDS_ALL,
    GRAVITY,
    MODE_FLAG_ARMED,
    AckermannDecoder,
    DifferentialDecoder,
    HilEndpoint,
    HilPhysics,
    Home,
    MagneticField,
    UuvQuadDecoder,
    absolute_pressure_hpa,
    body_from_ned,
    body_rates,
    hil_gps_fields,
    hil_sensor_fields,
    hil_state_quaternion_fields,
    quaternion_from_euler,
    unmix_quad,
)
from sim.px4_sitl import AUTOPILOTS, Px4Config, find_build, free_instance, parameter_text, parse_parameters
from sim.vehicle import ActuatorDemand, Vehicle


def _state(**overrides):
    vehicle = Vehicle(load_preset("starfish"), depth=0.0, speed=0.0)
    return replace(vehicle.state, **overrides)


# ----------------------------------------------------------------------------------- HIL_SENSOR
def test_level_at_rest_reads_minus_g_and_the_field_at_north():
    field = MagneticField(declination_deg=0.0, inclination_deg=60.0, strength_gauss=0.5)
    sensor = hil_sensor_fields(_state(), [0.0, 0.0, 0.0], magnetic=field)
    assert (sensor["xacc"], sensor["yacc"]) == pytest.approx((0.0, 0.0), abs=1e-12)
    assert sensor["zacc"] == pytest.approx(-GRAVITY)  # specific force, body FRD
    assert (sensor["xgyro"], sensor["ygyro"], sensor["zgyro"]) == pytest.approx((0.0, 0.0, 0.0))
    assert sensor["xmag"] == pytest.approx(0.25)  # 0.5·cos 60°, all of it ahead
    assert sensor["ymag"] == pytest.approx(0.0, abs=1e-12)
    assert sensor["zmag"] == pytest.approx(0.5 * math.sin(math.radians(60.0)))
    assert sensor["fields_updated"] == FIELDS_ALL == 0b1101111111111
    assert sensor["id"] == 0


def test_heading_east_sees_north_on_the_left_and_a_forward_push_on_x():
    field = MagneticField(0.0, 60.0, 0.5)
    sensor = hil_sensor_fields(_state(yaw=math.pi / 2), [0.0, 2.0, 0.0], magnetic=field)
    assert sensor["xmag"] == pytest.approx(0.0, abs=1e-12)
    assert sensor["ymag"] == pytest.approx(-0.25)  # north is to port when heading east
    assert sensor["xacc"] == pytest.approx(2.0)  # accelerating east = forward


def test_gyro_carries_body_rates_of_the_euler_rates():
    assert body_rates(0.0, 0.0, 0.1, 0.2, 0.3) == pytest.approx([0.1, 0.2, 0.3])
    p, q, r = body_rates(0.0, math.radians(30.0), 0.0, 0.0, 1.0)  # turning while pitched 30°
    assert (p, q, r) == pytest.approx((-0.5, 0.0, math.cos(math.radians(30.0))))
    sensor = hil_sensor_fields(_state(pitch=math.radians(30.0), yaw_rate=1.0), [0.0, 0.0, 0.0])
    assert (sensor["xgyro"], sensor["zgyro"]) == pytest.approx((-0.5, math.cos(math.radians(30.0))))


def test_pitched_up_at_rest_feels_gravity_forward_backwards():
    sensor = hil_sensor_fields(_state(pitch=math.radians(10.0)), [0.0, 0.0, 0.0])
    assert sensor["xacc"] == pytest.approx(GRAVITY * math.sin(math.radians(10.0)))
    assert sensor["zacc"] == pytest.approx(-GRAVITY * math.cos(math.radians(10.0)))


def test_pressure_is_the_surface_air_plus_the_water_column():
    assert absolute_pressure_hpa(0.0) == pytest.approx(1013.25)
    assert absolute_pressure_hpa(10.0) - absolute_pressure_hpa(0.0) == pytest.approx(1025 * 9.80665 * 10 / 100)
    boat = hil_sensor_fields(_state(depth=0.0), [0.0, 0.0, 0.0])
    auv = hil_sensor_fields(_state(depth=5.0), [0.0, 0.0, 0.0])
    assert boat["abs_pressure"] == pytest.approx(1013.25)
    assert auv["abs_pressure"] - boat["abs_pressure"] == pytest.approx(502.6, abs=0.1)
    assert absolute_pressure_hpa(0.0, surface_altitude_m=500.0) == pytest.approx(954.6, abs=0.1)  # a lake


def test_noise_is_added_in_field_order():
    noise = [0.1] * 10
    quiet = hil_sensor_fields(_state(), [0.0, 0.0, 0.0])
    noisy = hil_sensor_fields(_state(), [0.0, 0.0, 0.0], noise=noise)
    for name in ("xacc", "zgyro", "xmag", "abs_pressure"):
        assert noisy[name] == pytest.approx(quiet[name] + 0.1)


def test_time_is_the_vehicle_time_in_microseconds():
    assert hil_sensor_fields(_state(time_s=12.34), [0.0, 0.0, 0.0])["time_usec"] == 12_340_000


# ---------------------------------------------------------------------------- HIL_GPS, STATE
def test_gps_position_velocity_and_course():
    home = Home(lat_deg=63.4, lon_deg=10.4, alt_m=0.0)
    gps = hil_gps_fields(_state(north=100.0, east=-50.0, depth=3.0, vel_north=0.0, vel_east=1.5), home)
    assert gps["fix_type"] == 3 and gps["satellites_visible"] >= 6
    assert gps["lat"] / 1e7 == pytest.approx(63.4 + math.degrees(100.0 / 6371000.0), abs=1e-7)
    assert gps["lon"] / 1e7 == pytest.approx(10.4 - math.degrees(50.0 / (6371000.0 * math.cos(math.radians(63.4)))),
                                             abs=1e-7)
    assert gps["alt"] == -3000  # mm: 3 m below the surface
    assert (gps["vel"], gps["vn"], gps["ve"]) == (150, 0, 150)
    assert gps["cog"] == 9000  # heading east
    assert gps["eph"] > 0 and gps["epv"] > 0
    assert hil_gps_fields(_state(), home)["cog"] == 65535  # at rest: course unknown


def test_state_quaternion_is_the_attitude():
    assert quaternion_from_euler(0.0, 0.0, math.pi / 2) == pytest.approx([math.sqrt(0.5), 0, 0, math.sqrt(0.5)])
    truth = hil_state_quaternion_fields(_state(yaw=math.pi / 2, yaw_rate=0.1), [0.0, 0.0, 0.0])
    assert truth["attitude_quaternion"] == pytest.approx([math.sqrt(0.5), 0, 0, math.sqrt(0.5)])
    assert truth["yawspeed"] == pytest.approx(0.1)
    assert truth["zacc"] == -1000  # mG


def test_messages_survive_a_round_trip_through_pymavlink():
    physics = HilPhysics(Vehicle(load_preset("boat"), depth=0.0, speed=0.0), AckermannDecoder())
    physics.step()
    encoder = mavlink.MAVLink(None, srcSystem=1, srcComponent=51)
    data = b"".join(m.pack(encoder) for m in physics.messages(encoder))
    parsed = mavlink.MAVLink(None).parse_buffer(data)
    assert [m.get_type() for m in parsed] == ["HIL_SENSOR", "HIL_GPS", "HIL_STATE_QUATERNION"]
    sensor = parsed[0]
    assert sensor.time_usec == 10_000 and sensor.fields_updated == FIELDS_ALL and sensor.id == 0
    assert sensor.zacc == pytest.approx(-GRAVITY, abs=0.2)  # with the default sensor noise
    physics.step()
    assert [m.get_type() for m in physics.messages(encoder)] == ["HIL_SENSOR", "HIL_STATE_QUATERNION"]  # GPS 10 Hz


# ------------------------------------------------------------------------------------ decoders
def _controls(**channels: float) -> list[float]:
    controls = [0.0] * 16
    for name, value in channels.items():
        controls[int(name[1:]) - 1] = value
    return controls


def test_ackermann_steering_is_the_rudder_and_reverse_is_no_thrust():
    decoder = AckermannDecoder()
    demand, heave = decoder.demand(_controls(c1=0.6, c2=0.5), True, ActuatorDemand())
    assert demand.rudder == pytest.approx(0.5 * 0.5236) and demand.thrust_ratio == pytest.approx(0.6)
    assert heave == 0.0
    demand, _ = decoder.demand(_controls(c1=-0.4, c2=-1.5), True, ActuatorDemand())
    assert demand.thrust_ratio == 0.0 and demand.rudder == pytest.approx(-0.5236)  # clamped


def test_differential_left_faster_turns_right():
    demand, _ = DifferentialDecoder().demand(_controls(c1=0.4, c2=0.8), True, ActuatorDemand())
    assert demand.thrust_ratio == pytest.approx(0.6)
    assert demand.rudder == pytest.approx(0.2 * 0.5236) and demand.rudder > 0


def test_quad_unmix_recovers_the_axes():
    yaw = [0.5, -0.5, -0.5, 0.5]  # starboard-side rotors... positive yaw moment: -y·T summed
    assert unmix_quad(yaw) == pytest.approx({"forward": 0.0, "yaw": 0.5, "pitch": 0.0})
    mixed = [0.6 + y + p for y, p in zip(yaw, [-0.2, -0.2, 0.2, 0.2])]
    assert unmix_quad(mixed) == pytest.approx({"forward": 0.6, "yaw": 0.5, "pitch": 0.2})


def test_uuv_decoder_holds_the_auv_in_its_cradle_until_armed_thrusters_run():
    preset = load_preset("starfish")
    decoder = UuvQuadDecoder.for_preset(preset)
    cradle = preset.dive_plane.buoyancy - preset.dive_plane.weight
    assert cradle > 0
    _, heave = decoder.demand(_controls(c1=0.5, c2=0.5, c3=0.5, c4=0.5), False, ActuatorDemand())
    assert heave == pytest.approx(cradle) and not decoder.launched  # disarmed: held
    demand, heave = decoder.demand(_controls(c1=1.0, c2=0.0, c3=0.0, c4=1.0), True, ActuatorDemand())
    assert decoder.launched and heave == 0.0
    assert demand.thrust_ratio == pytest.approx(0.5)
    assert demand.rudder == pytest.approx(0.5 * preset.actuators.rudder_max)  # yaw right = + rudder
    demand, _ = decoder.demand(_controls(c1=0.2, c2=0.2, c3=0.6, c4=0.6), True, ActuatorDemand())
    assert demand.elevator == pytest.approx(-0.2 * preset.actuators.elevator_max)  # nose up = − elevator


# ------------------------------------------------------------------------ lockstep, fake PX4
class FakePx4:
    """A ``simulator_mavlink`` stand-in: connects, answers each HIL_SENSOR with HIL_ACTUATOR_CONTROLS
    stamped with its time (steering ``steering``, throttle ``throttle``) until ``answer`` is False."""

    def __init__(self, port: int, steering: float = 0.5, throttle: float = 0.6) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=5)
        self.mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        self.steering, self.throttle = steering, throttle
        self.answer = True
        self.sensor_times: list[int] = []
        self.gps = 0
        self._stop = False
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self._stop:
            try:
                data = self.sock.recv(65536)
            except OSError:
                return
            if not data:
                return
            for message in self.mav.parse_buffer(data) or []:
                if message.get_type() == "HIL_GPS":
                    self.gps += 1
                if message.get_type() != "HIL_SENSOR":
                    continue
                self.sensor_times.append(message.time_usec)
                if self.answer:
                    controls = [self.throttle, self.steering] + [0.0] * 14
                    reply = self.mav.hil_actuator_controls_encode(message.time_usec, controls, MODE_FLAG_ARMED | 1, 1)
                    self.sock.sendall(reply.pack(self.mav))

    def close(self) -> None:
        self._stop = True
        self.sock.close()


@pytest.fixture
def endpoint():
    physics = HilPhysics(Vehicle(load_preset("boat"), depth=0.0, speed=0.0), AckermannDecoder())
    # a generous wait for each answer: on a busy machine the fake's thread may be scheduled late,
    # and a step that ran free for it would be the machine's doing, not the lockstep's
    hil = HilEndpoint(physics, port=0, speedup=0.0, actuator_timeout_s=2.0)
    yield hil
    hil.close()


def test_lockstep_one_step_per_answer_and_the_physics_respond(endpoint):
    fake = FakePx4(endpoint.port)
    try:
        endpoint.accept(5.0)
        endpoint.run(duration_s=20.0)
        stats = endpoint.stats
        assert stats.steps == 2000
        # the free steps are the first ones, before the fake's first answer (once flowing, no step
        # runs free without late ones first); how many depends on the machine's scheduling
        assert stats.late_steps == 0 and stats.free_steps >= 1
        assert stats.lockstep_steps == stats.steps - stats.free_steps
        assert fake.sensor_times[:3] == [10_000, 20_000, 30_000]
        assert fake.gps == 200  # 10 Hz
        state = endpoint.physics.vehicle.state
        assert state.rudder == pytest.approx(0.5 * 0.5236)
        assert state.surge > 1.0 and state.yaw_rate > 0.05  # steering right: clockwise
    finally:
        fake.close()


def test_when_outputs_stop_the_endpoint_runs_free_and_rejoins(endpoint):
    fake = FakePx4(endpoint.port)
    endpoint.actuator_timeout_s = 0.3  # each missed answer is waited for this long before it counts late
    try:
        endpoint.accept(5.0)
        endpoint.run(duration_s=1.0)
        fake.answer = False  # e.g. a rover disarmed: PX4 publishes no outputs
        endpoint.run(duration_s=1.0)
        assert endpoint.stats.late_steps == endpoint.free_after_missed
        assert not endpoint._flowing
        fake.answer = True
        endpoint.run(duration_s=1.0)
        assert endpoint._flowing and endpoint.stats.lockstep_steps > 150
    finally:
        fake.close()


def test_a_closed_connection_ends_the_run(endpoint):
    fake = FakePx4(endpoint.port)
    endpoint.accept(5.0)
    endpoint.run(duration_s=0.5)
    fake.close()
    endpoint.run(duration_s=60.0)
    assert endpoint.closed and endpoint.physics.vehicle.time_s < 30.0


def test_truth_log_rows_every_tenth_of_a_second(tmp_path):
    path = tmp_path / "truth.csv"
    with open(path, "w") as log:
        physics = HilPhysics(Vehicle(load_preset("boat"), depth=0.0, speed=0.0), AckermannDecoder(), truth_log=log)
        physics.apply_controls(_controls(c1=0.6, c2=0.2), MODE_FLAG_ARMED)
        for _ in range(100):
            physics.step()
    rows = path.read_text().splitlines()
    assert rows[0] == "time_s,model_speed_m_s,speed_ground_m_s,yaw_rate_rad_s,rudder_rad"
    assert [float(r.split(",")[0]) for r in rows[1:4]] == pytest.approx([0.01, 0.11, 0.21])
    assert len(rows) == 11


# ------------------------------------------------------------------------------------ launcher
def test_parameter_files_parse_and_set_the_outputs():
    for autopilot in AUTOPILOTS:
        params = parse_parameters(parameter_text(autopilot))
        assert params["SIM_GZ_EN"] == "0"  # never Gazebo: simulator_mavlink
        assert params["PWM_MAIN_FUNC1"] == "101"
        assert params["EKF2_DECL_TYPE"] == "0" and params["EKF2_MAG_DECL"] == "0"  # our field has no declination
    rover = parse_parameters(parameter_text("px4-rover"))
    assert float(rover["RA_MAX_STR_ANG"]) == pytest.approx(AckermannDecoder().rudder_full_scale)
    assert rover["PWM_MAIN_FUNC2"] == "201"
    uuv = parse_parameters(parameter_text("px4-uuv"))
    assert [uuv[f"PWM_MAIN_FUNC{i}"] for i in range(1, 5)] == ["101", "102", "103", "104"]
    assert parse_parameters("# c\n\nA 1  # x\nB -2.5\n") == {"A": "1", "B": "-2.5"}


def _fake_build(root: Path) -> Path:
    (root / "bin").mkdir(parents=True)
    (root / "bin" / "px4").write_text("")
    (root / "etc" / "init.d-posix").mkdir(parents=True)
    (root / "etc" / "init.d-posix" / "rcS").write_text("")
    return root


def test_build_folder_found_from_itself_or_its_bin(tmp_path):
    build = _fake_build(tmp_path / "px4_sitl_default")
    assert find_build(build) == build
    assert find_build(build / "bin") == build
    with pytest.raises(ValueError, match="no PX4 SITL build"):
        find_build(tmp_path)


def test_environment_selects_the_airframe_the_simulator_and_the_parameters(tmp_path):
    from sim.px4_sitl import Px4Sitl

    build = _fake_build(tmp_path / "build")
    sitl = Px4Sitl(Px4Config(autopilot="px4-rover", bin_dir=build, params={"RO_YAW_P": 2.0}, workdir=tmp_path / "wd"))
    try:
        env = sitl.environment()
        assert env["PX4_SYS_AUTOSTART"] == "51000" and env["PX4_SIMULATOR"] == "mavlink"
        assert env["PX4_PARAM_SIM_GZ_EN"] == "0" and env["PX4_PARAM_RO_YAW_P"] == "2"
        assert sitl.command()[1:3] == ["-i", str(sitl.instance)]
        assert sitl.endpoint_hil.port == 4560 + sitl.instance
        assert sitl.endpoint == f"udpout:127.0.0.1:{14580 + sitl.instance}"
    finally:
        sitl.close()


def test_free_instance_is_one_whose_ports_are_free():
    instance = free_instance()
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as busy:
        busy.bind(("127.0.0.1", 4560 + instance))
        assert free_instance() != instance


def test_cli_needs_the_px4_build(monkeypatch, capsys):
    from sim.__main__ import main

    monkeypatch.delenv("PX4_SITL_BIN", raising=False)
    assert main(["run", "--autopilot", "px4-rover"]) == 2
    assert "--px4-bin" in capsys.readouterr().err
    assert main(["run", "--autopilot", "px4-uuv", "--px4-bin", "/nonexistent"]) == 2
    assert "no PX4 SITL build" in capsys.readouterr().err


def test_wall_clock_pacing_at_the_speedup(endpoint):
    fake = FakePx4(endpoint.port)
    try:
        endpoint.accept(5.0)
        endpoint.speedup = 10.0
        start = time.monotonic()
        endpoint.run(duration_s=3.0)
        # never faster than the speed-up (3 s of vehicle time at 10x); how much slower a busy machine
        # makes it is a bench figure (bench/bench_lockstep.py), not this test's
        assert time.monotonic() - start >= 0.25
    finally:
        fake.close()


def test_a_claimed_px4_instance_is_not_claimed_again_until_released():
    """Like ArduPilot's: the instance is held from the claim to PX4's end, not probed free and left."""
    from sim.px4_sitl import Px4InstanceClaim

    first = Px4InstanceClaim()
    try:
        second = Px4InstanceClaim()
        assert second.instance != first.instance
        second.release()
        assert free_instance() == second.instance
    finally:
        first.release()
