"""The PX4 profiles without PX4: mode packing, MANUAL_CONTROL encoding, bytewise parameters, the
read-back, detection, the strategy's streaming, excitation and release over faked link parts, and
the native gain design (eq. P.1–P.6). Fast: no process, no socket."""
from __future__ import annotations

import math
import struct
from types import SimpleNamespace

import pytest

from companion.link import param_codec
from companion.link.autopilots import px4_rover, px4_uuv
from companion.link.autopilots.px4 import Sticks, custom_mode, main_sub, rcl_excepted
from companion.link.errors import ProfileError
from companion.link.profiles import detect_profile, marker_params
from companion.link.snapshot import TelemetryAssembler
from companion.numerics.cascade_gains import CascadeRules
from companion.numerics.identification import YawEstimate, YawModel
from companion.numerics.px4_gains import design_ackermann_gains, design_uuv_gains
from tests.fake_ports import FakePorts

ROVER, UUV = px4_rover.PROFILE, px4_uuv.PROFILE
ROVER_PARAMS = {"COM_RCL_EXCEPT": 2, "RO_MAX_THR_SPEED": 2.5, "RA_MAX_STR_ANG": 0.5236}
UUV_PARAMS = {"COM_RCL_EXCEPT": 2, "UUV_MGM_YAW": 1.0, "UUV_MGM_PITCH": 1.0, "UUV_MGM_THRTL": 1.0}


# ---------------------------------------------------------------------- modes, sticks, parameters
def test_custom_modes_pack_main_and_sub_as_px4_custom_mode_does():
    assert ROVER.modes["manual"] == 65536 and ROVER.modes["hold"] == 393216  # MANUAL, OFFBOARD
    assert ROVER.modes["stabilized"] == 458752 and ROVER.modes["acro"] == 327680
    assert ROVER.modes["loiter"] == 0x03040000 == custom_mode(4, 3)  # PX4's Hold: AUTO/LOITER
    assert main_sub(0x03040000) == (4, 3)
    assert ROVER.mode_command_params(0x03040000) == (1.0, 4.0, 3.0)  # DO_SET_MODE: custom, main, sub
    assert UUV.mode_command_params(UUV.mode_number("manual")) == (1.0, 1.0, 0.0)
    assert ROVER.mode_name(0x03040000) == "loiter" and ROVER.mode_name(393216) == "hold"


def test_manual_control_encoding_clamps_and_refuses_nan():
    assert Sticks().fields() == (0, 0, 500, 0)  # throttle 0 is z = 500 (z/500 − 1)
    assert Sticks(pitch=-0.25, roll=0.537, throttle=0.6, yaw=-0.3).fields() == (-250, 537, 800, -300)
    assert Sticks(roll=1.7, throttle=-3.0, yaw=-2.0).fields() == (0, 1000, 0, -1000)
    with pytest.raises(ValueError):
        Sticks(roll=math.nan).fields()


def test_manual_control_loss_exceptions_follow_com_rcl_except():
    assert rcl_excepted(ROVER.modes["loiter"], 2) and rcl_excepted(ROVER.modes["rtl"], 2)
    assert not rcl_excepted(ROVER.modes["mission"], 2) and rcl_excepted(ROVER.modes["mission"], 1)
    assert rcl_excepted(ROVER.modes["hold"], 4) and not rcl_excepted(ROVER.modes["hold"], 2)  # OFFBOARD: bit 2
    assert not rcl_excepted(ROVER.modes["manual"], 31)  # a manual mode needs sticks whatever the mask


def test_px4_integers_travel_bytewise():
    assert ROVER.int_encoding == UUV.int_encoding == "bytewise"
    wire = param_codec.encode_value(51000, param_codec.INT32, "bytewise")
    assert struct.pack("<f", wire) == struct.pack("<i", 51000)  # SYS_AUTOSTART as PX4 sends it
    assert param_codec.decode_value(wire, param_codec.INT32, "bytewise") == 51000.0
    assert param_codec.decode_value(1.401298464324817e-45, param_codec.INT32, "bytewise") == 1.0  # measured COM_RC_IN_MODE
    assert param_codec.encoding_from_capabilities(59647) == "bytewise"  # PX4 SITL's AUTOPILOT_VERSION


def test_profiles_are_told_apart_by_mav_type():
    assert "SYS_AUTOSTART" in marker_params() and len(marker_params()) == len(set(marker_params()))
    assert detect_profile({"SYS_AUTOSTART"}, 10) is ROVER and detect_profile({"SYS_AUTOSTART"}, 11) is ROVER
    assert detect_profile({"SYS_AUTOSTART"}, 12) is UUV
    with pytest.raises(ProfileError):
        detect_profile({"SYS_AUTOSTART"}, None)  # both PX4 profiles match: name it with --profile


# ---------------------------------------------------------------------- read-back
def _msg(kind: str, **fields):
    return SimpleNamespace(get_type=lambda: kind, **fields)


def test_rover_reads_steering_and_motor_back_from_servo_output_raw():
    assembler = TelemetryAssembler(ROVER)
    earlier = {f"servo{i}_raw": 0 for i in range(1, 17)} | {"servo1_raw": 1500, "servo2_raw": 1500}
    for time_ms in (11460, 11480, 11500, 11520):  # a stream of outputs, each after its attitude (50 Hz)
        assembler.on_message(_msg("ATTITUDE", time_boot_ms=time_ms, roll=0.0, pitch=0.0, yaw=0.1, rollspeed=0.0,
                                  pitchspeed=0.0, yawspeed=0.0))
        assembler.on_message(_msg("SERVO_OUTPUT_RAW", time_usec=time_ms * 1000, **earlier))
    assert assembler.on_message(_msg("ATTITUDE", time_boot_ms=11540, roll=0.0, pitch=0.0, yaw=0.1, rollspeed=0.0,
                                     pitchspeed=0.0, yawspeed=0.0)) is None  # waits for the same loop's outputs
    outputs = {f"servo{i}_raw": 0 for i in range(1, 17)} | {"servo1_raw": 1800, "servo2_raw": 1750}
    snapshot = assembler.on_message(_msg("SERVO_OUTPUT_RAW", time_usec=11540000, **outputs))
    assert snapshot.time_s == 11.54
    assert snapshot.rudder == pytest.approx(0.5 * 0.5236)  # steering 0.5 (measured 1750 µs)
    assert snapshot.thrust_ratio == pytest.approx(0.6)  # reversible motor, 1500 µs = stop


def test_uuv_unmixes_the_four_thrusters_into_yaw_and_forward():
    axes = px4_uuv.unmix([1900, 1600, 1600, 1900])  # measured: yaw stick 0.3 at throttle 0.5
    assert axes["yaw"] == pytest.approx(0.3) and axes["forward"] == pytest.approx(0.5) and axes["pitch"] == 0.0
    assert px4_uuv.unmix([1500, 1500, 0, 1500]) is None
    ports = FakePorts(UUV, px4_uuv.Strategy, mode="loiter", params=UUV_PARAMS)
    ports.telemetry.pwm = [1900, 1600, 1600, 1900]
    snapshot = ports.snapshot(yaw=0.0)
    assert snapshot.rudder == pytest.approx(0.3 * 0.35) and snapshot.thrust_ratio == pytest.approx(0.5)


# ---------------------------------------------------------------------- the strategy
def _manual_controls(ports) -> list[tuple]:
    return [entry[2:6] for entry in ports.transport.mav.sent if entry[0] == "manual_control_send"]


def _rover(**kwargs) -> FakePorts:
    ports = FakePorts(ROVER, px4_rover.Strategy, mode="loiter", params=ROVER_PARAMS, **kwargs)
    ports.telemetry.latest = SimpleNamespace(yaw=0.3, speed_ground=1.5, rudder=0.02, thrust_ratio=0.6,
                                             finite=lambda *names: True)
    return ports


def test_nothing_streams_until_the_companion_asks_for_a_streamed_mode():
    ports = _rover()
    ports.snapshot()
    ports.modes.set_mode("loiter")  # a restore to an auto mode takes nothing
    assert not ports.strategy.taken and not _manual_controls(ports)
    ports.modes.set_mode("hold")
    assert ports.strategy.taken and _manual_controls(ports)[0] == (0, 0, 500, 0)
    targets = [e for e in ports.transport.mav.sent if e[0] == "set_position_target_local_ned_send"]
    assert targets, "OFFBOARD needs its set-points before the mode change"


def test_sticks_and_set_points_are_refreshed_on_vehicle_time():
    ports = _rover()
    ports.modes.set_mode("hold")
    ports.strategy.set_thrust(0.6)
    ports.strategy.set_heading(math.pi / 2)
    sent = len(_manual_controls(ports))
    for _ in range(50):  # 1 s of snapshots at 50 Hz
        ports.snapshot()
    assert 9 <= len(_manual_controls(ports)) - sent <= 10  # every 0.1 s of vehicle time (PX4 wants ≥ 2 Hz)
    velocity = [e for e in ports.transport.mav.sent if e[0] == "set_position_target_local_ned_send"][-1]
    vn, ve = velocity[9], velocity[10]
    assert vn == pytest.approx(0.0, abs=1e-9) and ve == pytest.approx(1.5)  # 0.6 × RO_MAX_THR_SPEED, east


def test_a_vehicle_without_manual_control_is_refused_unless_its_mode_is_excepted():
    ports = _rover()
    ports.parameters.params["COM_RCL_EXCEPT"] = 0
    with pytest.raises(ProfileError, match="COM_RCL_EXCEPT"):
        ports.modes.set_mode("hold")
    assert not _manual_controls(ports)
    ports.transport.emit("SYS_STATUS", onboard_control_sensors_present=1 << 16)  # someone's sticks
    ports.modes.set_mode("hold")
    assert ports.strategy.taken


def test_rudder_full_scale_must_equal_ra_max_str_ang():
    ports = _rover()
    ports.parameters.params["RA_MAX_STR_ANG"] = 0.6
    with pytest.raises(ProfileError, match="RA_MAX_STR_ANG"):
        ports.modes.set_mode("hold")


def test_excitation_holds_the_outputs_in_manual_and_release_keeps_the_steering():
    ports = _rover()
    ports.modes.set_mode("hold")
    ports.strategy.override("rudder", 0.02 + 0.26)
    assert ports.modes.changes[-1] == "manual"
    first = _manual_controls(ports)[-1]
    assert first == (0, round(0.28 / 0.5236 * 1000), 800, 0)  # doublet on the held throttle 0.6
    ports.strategy.release("rudder")
    assert _manual_controls(ports)[-1] == (0, round(0.02 / 0.5236 * 1000), 800, 0)  # the steering it had
    ports.modes.set_mode("hold")  # the manoeuvre's next hold ends the excitation
    assert _manual_controls(ports)[-1] == (0, 0, 500, 0)


def test_release_streams_until_back_in_the_found_mode_then_stops():
    ports = _rover()
    ports.modes.set_mode("hold")
    ports.strategy.override("rudder", 0.1)
    ports.strategy.release(None)  # an abort in MANUAL: back to the holding mode, sticks centred
    assert ports.modes.changes[-1] == "hold" and ports.strategy.taken
    ports.modes.set_mode("loiter")  # the restore's mode
    assert not ports.strategy.taken
    sent = len(_manual_controls(ports))
    ports.snapshot()
    assert len(_manual_controls(ports)) == sent  # nothing streams any more


def test_release_never_fights_a_pilots_mode_choice():
    ports = _rover()
    ports.modes.set_mode("hold")
    ports.announcements.custom_mode = ROVER.modes["rtl"]  # someone else chose Return
    ports.strategy.release(None)
    assert not ports.strategy.taken and ports.modes.changes == ["hold"]


def test_sticks_px4_ignores_abort_the_next_excitation_command():
    ports = _rover()
    ports.modes.set_mode("hold")
    ports.strategy.override("rudder", 0.28)
    for _ in range(60):  # 1.2 s in MANUAL with the steering another source gives
        ports.snapshot(rudder=-0.2, mode="manual")
    with pytest.raises(ProfileError, match="ignores the companion's sticks"):
        ports.strategy.override("rudder", -0.24)


def test_uuv_holds_depth_with_the_pitch_set_point_and_scales_the_yaw_stick():
    ports = FakePorts(UUV, px4_uuv.Strategy, mode="loiter", params={**UUV_PARAMS, "UUV_MGM_YAW": 0.5})
    ports.telemetry.latest = SimpleNamespace(depth=2.0, yaw=0.0, thrust_ratio=0.0, rudder=0.0)
    ports.telemetry.pwm = [1500, 1500, 1500, 1500]
    ports.modes.set_mode("hold")
    ports.snapshot(depth=2.5, vel_down=0.0, yaw=0.0)  # 0.5 m too deep: nose up
    assert ports.strategy.pitch_setpoint == pytest.approx(0.15 * 0.5)
    assert ports.strategy.stick_value("rudder", 0.035) == pytest.approx(0.035 / 0.35 / 0.5)
    with pytest.raises(ProfileError, match="UUV_MGM_YAW"):
        ports.strategy.stick_value("rudder", 0.2)


# ---------------------------------------------------------------------- native gains
def test_ackermann_design_makes_the_feed_forward_the_boats_steady_turn():
    model = YawModel(a22=-0.975, b2=0.735, delta0=0.02)  # our boat at 1.5 m/s
    gains = design_ackermann_gains(model, 1.5, CascadeRules(**px4_rover.GAIN_RANGES))
    assert gains.ff_length == pytest.approx(0.975 / 0.735 * 1.5)  # eq. P.1: 1.99 m, the sim's 2 m
    assert gains.rate_p == pytest.approx((3.0 - 0.975) / 0.735)  # eq. P.2
    assert gains.rate_bandwidth == pytest.approx(3.0)
    assert gains.rate_i == pytest.approx(3.0 / (10 * 0.735))  # eq. P.3
    assert gains.angle_p == pytest.approx(1.5) and gains.heading_damping == pytest.approx(math.sqrt(0.5))  # eq. P.4
    assert gains.params()["heading_ff_correction"] == 1.0 and not gains.clamped


def test_uuv_design_places_the_heading_loop_at_0_7071():
    rules = CascadeRules(full_scale=0.35, **px4_uuv.GAIN_RANGES)
    gains = design_uuv_gains(YawModel(a22=-0.948, b2=0.489, delta0=0.01), rules, speed=0.86)
    b = 0.489 * 0.35
    assert gains.rate_d == pytest.approx((3.0 - 0.948) / b)  # eq. P.5
    assert gains.angle_p == pytest.approx(9.0 / (2 * b))  # eq. P.6
    assert gains.heading_damping == pytest.approx(math.sqrt(0.5))
    slow = design_uuv_gains(YawModel(a22=-0.9, b2=0.2, delta0=0.0), rules)  # D bounded at ten times the default
    assert slow.clamped == ("rate_d",) and slow.rate_d == 20.0 and slow.rate_bandwidth == pytest.approx(0.9 + 0.07 * 20)
    assert slow.heading_damping == pytest.approx(math.sqrt(0.5))  # P follows the bandwidth achieved


def test_the_campaign_designs_each_px4_profiles_own_gains_in_its_ranges():
    from companion.procedures.campaign import CampaignConfig

    rover = CampaignConfig().resolved_for(ROVER)
    assert rover.schedules == ("px4_rover",) and rover.depth is None and rover.thrusts == (0.5, 0.7, 0.9)
    assert rover.cascade.angle_p_range == (0.0, 100.0)
    kind = rover.kinds()[0]
    assert set(kind.parameters) <= set(ROVER.params)  # every gain in the restore point's footprint
    uuv = CampaignConfig().resolved_for(UUV)
    assert uuv.kinds()[0].name == "px4_uuv" and uuv.cascade.full_scale == 0.35 and uuv.axes == ("yaw",)
    assert set(uuv.kinds()[0].parameters) <= set(UUV.params)
    with pytest.raises(ValueError):
        design_ackermann_gains(YawEstimate(a22=0.1, b2=0.5, delta0=0.0), 1.0)
