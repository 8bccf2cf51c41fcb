"""ArduSub without SITL: the vectored frame's un-mix on both sides of the link (the companion's
read-back and the simulator's physics must agree), the launch cradle, and the strategy's stick
handling, pilot presence and depth, against a fake link."""
from __future__ import annotations

import math
import random

import pytest

from companion.rehearsal.rehearsal import ARDUSUB_THRUSTS, ardusub_campaign
from companion.interface import Telemetry
from companion.link.autopilots import ardusub
from companion.link.autopilots.ardusub import (
    PROFILE,
    RELEASE_AFTER_S,
    STICK_CENTRE,
    Strategy,
    throttle_stick,
    unmix_vectored,
)
from companion.link.overrides import IGNORE_HIGH, IGNORE_LOW
from companion.procedures.campaign import CampaignConfig
from sim.ardupilot_json import SubVectoredDecoder
from sim.preset import load_preset
from sim.vehicle import ActuatorDemand
from tests.fake_ports import FakePorts

NEUTRAL = [1500] * 6


def _frame(pwm: list[int]) -> list[int]:
    return pwm + [0] * (16 - len(pwm))


# ---------------------------------------------------------------------- un-mix
def test_unmix_recovers_yaw_forward_and_a_climb():
    yaw = unmix_vectored([1700, 1300, 1300, 1700, 1500, 1500])
    assert (yaw.yaw, yaw.forward, yaw.throttle) == pytest.approx((0.5, 0.0, 0.0))
    ahead = unmix_vectored([1300, 1300, 1700, 1700, 1340, 1340])  # motors 5/6 below 1500: climb
    assert (ahead.yaw, ahead.forward, ahead.throttle) == pytest.approx((0.0, 0.5, 0.4))
    assert unmix_vectored([1500] * 3) is None
    assert math.isnan(unmix_vectored([1500] * 4).throttle)
    assert unmix_vectored([1500, 0, 1500, 1500, 1500, 1500]) is None  # a motor reports no data


def test_saturated_motors_read_back_what_they_do():
    # forward 0.45 + yaw 0.8 asks motor 4 for 1.25 and motor 2 for -1.25: both clip at ±1
    forward, yaw = 0.45, 0.8
    wanted = [yaw - forward, -yaw - forward, -yaw + forward, yaw + forward]
    pwm = [round(1500 + 400 * max(-1.0, min(1.0, o))) for o in wanted] + [1500, 1500]
    axes = unmix_vectored(pwm)
    assert axes.yaw == pytest.approx(0.675) and axes.forward == pytest.approx(0.325)  # both reduced


def test_companion_read_back_equals_the_physics_equivalent_rudder():
    """What the strategy reports as rudder and thrust is what the simulator applies, for any outputs."""
    decoder = SubVectoredDecoder()
    rng = random.Random(3)
    for _ in range(200):
        pwm = [rng.randint(1100, 1900) for _ in range(6)]
        demand, heave = decoder.demand(_frame(pwm), ActuatorDemand())
        axes = unmix_vectored([float(p) for p in pwm])
        assert demand.rudder == pytest.approx(axes.yaw * PROFILE.angle_full_scale_rad, abs=1e-12)
        assert demand.thrust_ratio == pytest.approx(max(0.0, axes.forward), abs=1e-12)
        assert heave == pytest.approx(-axes.throttle * decoder.heave_force_max, abs=1e-9)
    assert decoder.rudder_full_scale == PROFILE.angle_full_scale_rad == 0.35


def test_a_climb_demand_pushes_up():
    decoder = SubVectoredDecoder()
    _, climb = decoder.demand(_frame([1500, 1500, 1500, 1500, 1300, 1300]), ActuatorDemand())
    _, dive = decoder.demand(_frame([1500, 1500, 1500, 1500, 1700, 1700]), ActuatorDemand())
    assert climb == pytest.approx(-30.0) and dive == pytest.approx(30.0)  # heave force positive down


def test_the_cradle_holds_the_auv_until_the_thrusters_first_run():
    preset = load_preset("starfish")
    decoder = SubVectoredDecoder.for_preset(preset)
    assert decoder.cradle_force == pytest.approx(preset.dive_plane.buoyancy - preset.dive_plane.weight)
    assert decoder.cradle_force > 0  # a buoyant AUV is held down
    for pwm in ([0] * 16, _frame(NEUTRAL)):  # outputs off, then disarmed / centred
        demand, heave = decoder.demand(pwm, ActuatorDemand())
        assert heave == decoder.cradle_force and demand.thrust_ratio == 0.0 and not decoder.launched
    _, heave = decoder.demand(_frame([1500, 1500, 1500, 1500, 1510, 1510]), ActuatorDemand())
    assert decoder.launched and heave == pytest.approx(1.5)
    _, heave = decoder.demand(_frame(NEUTRAL), ActuatorDemand())
    assert heave == 0.0  # released for good


def test_throttle_stick_maps_manual_throttle_to_rc3():
    assert throttle_stick(0.0) == STICK_CENTRE and throttle_stick(-0.05) == 1480
    assert throttle_stick(2.0) == 1900 and throttle_stick(math.nan) == STICK_CENTRE


# ---------------------------------------------------------------------- strategy
@pytest.fixture
def ports() -> FakePorts:
    ports = FakePorts(PROFILE, Strategy, params={"ACRO_YAW_P": 3.375})
    ports.telemetry.latest = Telemetry(time_s=100.0, depth=2.0)
    ports.telemetry.pwm = [1500.0] * 6
    return ports


def _snapshot(ports: FakePorts, dt: float = 0.02) -> Telemetry:
    return ports.snapshot(dt, depth=1.5)


def _channel(values: list[int], name: str) -> int:
    return values[PROFILE.channel(name) - 1]


def test_a_released_stick_is_centred_first_and_released_a_moment_later(ports):
    strategy, held = ports.strategy, ports.overrides.active
    strategy.set_thrust(0.5)
    assert _channel(ports.override_values[-1], "thrust") == 1700
    strategy.release("thrust")
    assert _channel(ports.override_values[-1], "thrust") == STICK_CENTRE  # centred, still held
    _snapshot(ports, RELEASE_AFTER_S / 2)
    assert PROFILE.channel("thrust") in held
    _snapshot(ports, RELEASE_AFTER_S)
    assert PROFILE.channel("thrust") not in held
    assert _channel(ports.override_values[-1], "thrust") == 0  # channels 1..8: 0 releases


def test_a_new_thrust_cancels_a_pending_release(ports):
    strategy = ports.strategy
    strategy.set_thrust(0.5)
    strategy.release(None)
    strategy.set_thrust(0.6)
    _snapshot(ports, 2 * RELEASE_AFTER_S)
    assert ports.overrides.active[PROFILE.channel("thrust")] == 1740


def test_the_doublet_switches_to_manual_holding_the_vertical_thrust_alt_hold_had(ports):
    strategy = ports.strategy
    ports.telemetry.pwm = [1500, 1500, 1500, 1500, 1540, 1540]  # ALT_HOLD pushing down 0.1 against buoyancy
    for _ in range(400):  # 8 s of ALT_HOLD: the mean settles
        _snapshot(ports)
    ports.parameters.params["ACRO_YAW_P"] = 6.75  # MANUAL would double the yaw stick
    strategy.override("rudder", 0.07)  # 0.2 of full scale
    assert ports.modes.changes == ["manual"]
    held = ports.overrides.active
    assert held[PROFILE.channel("vertical")] == throttle_stick(-0.1) == 1460
    assert held[PROFILE.channel("rudder")] == 1540  # 0.1 of stick: doubled by MANUAL to 0.2
    strategy.release("rudder")  # end of the doublet: centred yaw stick, still MANUAL
    assert held[PROFILE.channel("rudder")] == STICK_CENTRE and ports.modes.changes == ["manual"]
    ports.modes.set_mode("hold")  # the manoeuvre re-engages: sticks centred, then given back
    assert held[PROFILE.channel("vertical")] == STICK_CENTRE
    _snapshot(ports, 2 * RELEASE_AFTER_S)
    assert PROFILE.channel("vertical") not in held
    assert PROFILE.channel("rudder") not in held


def test_in_manual_the_throttle_stick_keeps_the_depth_manual_was_entered_at(ports):
    strategy = ports.strategy
    ports.telemetry.pwm = [1500, 1500, 1500, 1500, 1520, 1520]  # ALT_HOLD's mean: -0.05, down against buoyancy
    for _ in range(1000):
        _snapshot(ports)
    ports.telemetry.latest = Telemetry(time_s=ports.clock.vehicle_time_s, depth=1.5)  # entered at 1.5 m
    strategy.override("rudder", 0.05)
    vertical = PROFILE.channel("vertical")
    _snapshot(ports)  # at 1.5 m: the mean thrust alone
    assert ports.overrides.active[vertical] == throttle_stick(-0.05) == 1480
    ports.transport.emit("HOME_POSITION", altitude=0)
    ports.transport.emit("GLOBAL_POSITION_INT", alt=-1000)  # risen to 1.0 m
    _snapshot(ports)
    assert ports.overrides.active[vertical] == throttle_stick(-0.05 - 0.15)  # push down: 0.3 per metre
    ports.transport.emit("GLOBAL_POSITION_INT", alt=-5000)  # far too deep
    _snapshot(ports)
    assert ports.overrides.active[vertical] == throttle_stick(-0.05 + 0.3)  # climb, limited


def test_the_companion_stays_present_as_a_pilot_without_moving_a_stick(ports):
    for _ in range(150):  # 3 s with nothing held
        _snapshot(ports)
    presence = [values for values in ports.override_values if set(values[:8]) == {IGNORE_LOW}]
    assert len(presence) == 3 and all(set(v[8:]) == {IGNORE_HIGH} for v in presence)
    ports.strategy.set_thrust(0.4)
    count = len(ports.override_values)
    for _ in range(100):
        _snapshot(ports)
    assert all(_channel(v, "thrust") == 1660 for v in ports.override_values[count:])  # the held override is the presence


def test_the_ground_station_heartbeat_goes_out_as_the_ground_station(ports):
    for _ in range(110):  # 2.2 s
        _snapshot(ports)
    heartbeats = [entry for entry in ports.transport.mav.sent if entry[0] == "heartbeat_send"]
    assert len(heartbeats) == 3 and set(ports.transport.sent_as) == {(255, 190)}


def test_heading_target_refreshed_every_vehicle_second_in_alt_hold_only(ports):
    ports.strategy.set_heading(0.5)
    for _ in range(160):  # 3.2 s
        _snapshot(ports)
    assert len(ports.attitude_targets) == 4
    ports.announcements.custom_mode = PROFILE.modes["manual"]
    for _ in range(150):
        _snapshot(ports)
    assert len(ports.attitude_targets) == 4


def test_depth_is_home_altitude_minus_the_vehicles(ports):
    assert _snapshot(ports).depth == 1.5  # before home is known: relative_alt as reported
    ports.transport.emit("HOME_POSITION", altitude=120)  # mm above sea level
    ports.transport.emit("GLOBAL_POSITION_INT", alt=-2080, relative_alt=40)
    assert _snapshot(ports).depth == pytest.approx(2.2)


def test_read_back_replaces_rudder_and_thrust(ports):
    ports.telemetry.pwm = [1240, 1360, 1760, 1640, 1500, 1500]  # forward 0.5, yaw -0.15
    telemetry = _snapshot(ports)
    assert telemetry.thrust_ratio == pytest.approx(0.5)
    assert telemetry.rudder == pytest.approx(-0.15 * 0.35)


# ---------------------------------------------------------------------- campaign defaults
def test_ardusub_campaign_keeps_the_motors_out_of_saturation_and_arduSub_gain_ranges():
    config = ardusub_campaign(CampaignConfig()).resolved_for(PROFILE)
    assert config.thrusts == ARDUSUB_THRUSTS and config.axes == ("yaw",)
    trim = 0.03  # ALT_HOLD's yaw output at the rudder offset
    for thrust in config.thrusts:
        assert thrust + config.yaw.training_amplitude / PROFILE.angle_full_scale_rad + trim <= 1.0
    assert config.cascade.full_scale == 0.35 and config.cascade.rate_ff_range == (0.0, 0.0)
    assert config.cascade.rate_i_range == (0.0, 0.05) and config.cascade.angle_p_range == (0.0, 6.0)
    assert config.depth is None and config.step_labels == ("original", "quicktune", "scheduled")
    assert config.yaw.stop_on_convergence is False and config.yaw.input_hold == "zoh"


def test_streams_pair_attitude_and_outputs_at_50_hz():
    assert ardusub.STREAMS[30] == ardusub.STREAMS[36] == 50.0
    assert 242 in ardusub.STREAMS and 33 in ardusub.STREAMS  # home and position: the depth
