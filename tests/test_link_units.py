"""Unit tests of the vehicle interface (companion.link): profiles, conversions, parameter encodings
and echo matching, override bookkeeping, snapshot assembly, and VehicleLink's protocol logic
against an in-process fake autopilot (real MAVLink 2 bytes both ways, no sockets)."""
from __future__ import annotations

import collections
import math
import os

import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402

from companion.interface import SetDepth, SetHeading, SetRollingMass, SetThrust  # noqa: E402
from companion.link import param_codec as pc  # noqa: E402
from companion.link.errors import (LinkLost, ParamRefused, ParamTimeout, ProfileError,  # noqa: E402
                                   VehicleRebooted)
from companion.link.overrides import OverrideTable, single_shot  # noqa: E402
from companion.link.profiles import ARDUROVER, ARDUSUB, PROFILES, SIM, detect_profile  # noqa: E402
from companion.link.snapshot import DepthSensor, TelemetryAssembler  # noqa: E402
from companion.link.vehicle import validate_named_value_name  # noqa: E402
from tests.fake_autopilot import FakeAutopilot, fake_link, wire  # noqa: E402,F401 - fake_link is a fixture


# ============================================================================ profiles
def test_detect_profile_from_marker_parameters():
    assert detect_profile({"HDG_P", "SYSID_MYGCS"}) is SIM
    assert detect_profile({"ATC_ANG_YAW_P", "ATC_RAT_YAW_P"}) is ARDUSUB
    assert detect_profile({"ATC_STR_ANG_P"}) is ARDUROVER
    with pytest.raises(ProfileError):
        detect_profile({"FOO"})
    with pytest.raises(ProfileError):
        detect_profile({"HDG_P", "ATC_STR_ANG_P"})


def test_sim_pwm_conversions_follow_protocol():
    assert SIM.pwm_to_angle(2000) == pytest.approx(0.5236)
    assert SIM.pwm_to_angle(1250) == pytest.approx(-0.2618)
    assert SIM.pwm_to_thrust(1700) == pytest.approx(0.70)
    assert SIM.angle_to_pwm(0.2618) == 1750
    assert SIM.angle_to_pwm(5.0) == 2000  # clamped to full scale
    assert SIM.thrust_to_pwm(0.7) == 1700 and SIM.thrust_to_pwm(-1.0) == 1000
    for no_data in (0, 65535, float("nan"), None):
        assert math.isnan(SIM.pwm_to_angle(no_data))
    with pytest.raises(ValueError):
        SIM.angle_to_pwm(float("nan"))
    # round trip within half a PWM step
    for angle in (-0.3, -0.01, 0.0, 0.123, 0.35):
        assert SIM.pwm_to_angle(SIM.angle_to_pwm(angle)) == pytest.approx(angle, abs=0.5236 / 500 / 2 + 1e-12)


def test_profiles_name_modes_channels_and_units():
    assert SIM.mode_number("hold") == 2 and SIM.mode_name(19) == "manual" and SIM.mode_name(7) == "custom_7"
    assert ARDUSUB.channel("rudder") == 4 and ARDUSUB.channel("thrust") == 5
    assert ARDUSUB.pwm_to_thrust(1900) == pytest.approx(1.0) and ARDUSUB.pwm_to_thrust(1500) == 0.0
    assert ARDUROVER.to_native_value("cruise_thrust", 0.45) == pytest.approx(45.0)
    assert ARDUSUB.native_candidates("gcs_sysid") == ("MAV_GCS_SYSID", "SYSID_MYGCS")  # renamed in 4.7
    with pytest.raises(ProfileError):
        ARDUROVER.channel("elevator")
    assert SIM.flown and ARDUROVER.flown  # ArduRover: against its 4.7 SITL firmware
    assert set(PROFILES) == {"sim", "ardusub", "ardurover", "px4-rover", "px4-uuv"}


def test_ardupilot_profiles_name_their_native_heading_gains_one_to_one():
    """No PI-to-cascade translation any more: each native gain has its own neutral name."""
    assert ARDUROVER.natives_touched(["heading_angle_p", "heading_rate_ff"]) == ("ATC_STR_ANG_P", "ATC_STR_RAT_FF")
    assert ARDUSUB.natives_touched(["heading_rate_p", "nonexistent"]) == ("ATC_RAT_YAW_P",)
    assert "heading_p" not in ARDUROVER.params and "rudder_trim" not in ARDUROVER.params  # never write SERVO1_TRIM
    assert ARDUROVER.heading_schedule == ARDUSUB.heading_schedule == "cascade" and SIM.heading_schedule == "heading"


# ============================================================================ parameter values
def test_float32_echo_matching():
    sent = 1.2345678
    echoed = pc.float32(sent)
    assert echoed != sent and pc.echo_matches(sent, echoed, pc.REAL32)
    assert not pc.echo_matches(1.2345, 1.2346, pc.REAL32)
    assert not pc.echo_matches(float("nan"), float("nan"), pc.REAL32)
    assert pc.echo_matches(254.2, 254.0, pc.INT16) and not pc.echo_matches(254.0, 253.0, pc.INT16)


def test_integer_encodings():
    assert pc.encode_value(254.4, pc.INT16, "cast") == 254.0
    for param_type, value in ((pc.INT32, -5), (pc.UINT8, 200), (pc.INT16, 1234), (pc.UINT32, 70000)):
        wire_value = pc.encode_value(value, param_type, "bytewise")
        assert wire_value != value  # the bytes, not the number
        assert pc.decode_value(wire_value, param_type, "bytewise") == value
        assert pc.decode_value(pc.encode_value(value, param_type, "cast"), param_type, "cast") == value
    with pytest.raises(ValueError):
        pc.encode_value(300, pc.UINT8, "cast")
    assert pc.encoding_from_capabilities(pc.CAPABILITY_PARAM_ENCODE_C_CAST | 4) == "cast"
    assert pc.encoding_from_capabilities(pc.CAPABILITY_PARAM_ENCODE_BYTEWISE) == "bytewise"
    assert pc.encoding_from_capabilities(0, "bytewise") == "bytewise"
    assert pc.param_id_str(b"HDG_P\x00\x00junk") == "HDG_P"


def test_named_value_name_check():
    assert validate_named_value_name("a22_est") == "a22_est"
    for bad in ("", "eleven_char", "näme", "tab\tx", 3):
        with pytest.raises(ValueError):
            validate_named_value_name(bad)


# ============================================================================ overrides
def test_override_table_hold_release_and_extension_channels():
    table = OverrideTable(release_repeats=2)
    table.hold(1, 1700)
    values = table.channel_values()
    assert values[0] == 1700 and values[1:8] == [65535] * 7 and values[8:] == [0] * 10
    table.release(1)
    table.hold(12, 1600)
    table.release(12)
    first = table.channel_values()
    assert first[0] == 0 and first[11] == 65534
    assert table.channel_values()[0] == 0  # repeated once more
    assert table.channel_values()[0] == 65535 and not table.pending
    assert single_shot(3, 1800)[2] == 1800
    with pytest.raises(ValueError):
        table.hold(19, 1500)


# ============================================================================ snapshot assembly
def test_snapshot_assembly_from_fabricated_messages():
    assembler = TelemetryAssembler(SIM, depth_sensor=DepthSensor(water_density=1000.0))
    assert assembler.on_message(wire(mavlink.MAVLink_heartbeat_message(12, 3, 128 | 1, 2, 4, 3))) is None
    assembler.on_message(wire(mavlink.MAVLink_servo_output_raw_message(
        100000, 0, 1750, 1250, 1700, 1500, 0, 0, 0, 0, 2000)))
    assembler.on_message(wire(mavlink.MAVLink_local_position_ned_message(100, 10.0, -3.0, 2.5, 1.0, 0.1, 0.0)))
    assembler.on_message(wire(mavlink.MAVLink_vfr_hud_message(1.4, 1.2, 90, 70, -2.5, 0.0)))
    snapshot = assembler.on_message(wire(mavlink.MAVLink_attitude_message(100, 0.01, -0.02, 3.5, 0.1, 0.2, 0.3)))
    assert snapshot.time_s == pytest.approx(0.1)
    assert snapshot.mode == "hold" and snapshot.armed
    assert snapshot.rudder == pytest.approx(0.2618) and snapshot.elevator == pytest.approx(-0.2618)
    assert snapshot.thrust_ratio == pytest.approx(0.7) and snapshot.mass_angle == pytest.approx(0.5236)
    assert snapshot.yaw == pytest.approx(3.5 - 2 * math.pi, abs=1e-6)  # wrapped to (-pi, pi]
    assert snapshot.depth == pytest.approx(2.5) and snapshot.north == 10.0  # no pressure yet: z
    assert snapshot.speed_water == pytest.approx(1.4) and snapshot.speed_ground == pytest.approx(1.2)
    depth = 4.0
    press = 1013.25 + 1000.0 * 9.80665 * depth / 100.0
    assembler.on_message(wire(mavlink.MAVLink_scaled_pressure_message(150, press, 0.0, 1500)))
    snapshot = assembler.on_message(wire(mavlink.MAVLink_attitude_message(150, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)))
    assert snapshot.depth == pytest.approx(depth, abs=1e-3)


def test_snapshot_turns_garbage_into_nan_without_raising(caplog):
    assembler = TelemetryAssembler(SIM)
    assembler.on_message(wire(mavlink.MAVLink_vfr_hud_message(float("nan"), float("inf"), 0, 0, 0.0, 0.0)))
    assembler.on_message(wire(mavlink.MAVLink_servo_output_raw_message(200000, 0, 0, 65535, 1500, 0, 0, 0, 0, 0)))
    snapshot = assembler.on_message(wire(mavlink.MAVLink_attitude_message(
        200, float("nan"), 0.0, float("nan"), 0.0, float("-inf"), 0.0)))
    assert snapshot is not None
    for name in ("roll", "yaw", "pitch_rate", "speed_water", "speed_ground", "rudder", "elevator", "mass_angle"):
        assert math.isnan(getattr(snapshot, name)), name
    assert snapshot.thrust_ratio == pytest.approx(0.5) and snapshot.pitch == 0.0
    assert "not a finite number" in caplog.text

    class Garbage:  # a field that is not a number at all
        time_boot_ms = 300
        roll = "x"
        pitch = None

        def get_type(self):
            return "ATTITUDE"

    snapshot = assembler.on_message(Garbage())
    assert math.isnan(snapshot.roll) and math.isnan(snapshot.pitch) and snapshot.time_s == 0.3


# ============================================================================ VehicleLink vs a fake autopilot
def test_setup_detects_profile_and_reads_gcs_sysid(fake_link):
    fake, link = fake_link
    assert link.profile is SIM and link.ground.gcs_sysid == 255 and link.override_timeout_s == 3.0
    assert {pc.param_id_str(m.param_id) for m in fake.sent_of("PARAM_REQUEST_READ")} >= {"HDG_P", "ATC_ANG_YAW_P"}


def test_set_param_trusts_only_a_matching_echo(fake_link):
    fake, link = fake_link
    assert link.set_param("HDG_P", 1.2345678) == pc.float32(1.2345678)
    assert link.get_param("HDG_P") == pc.float32(1.2345678)
    fake.echo_instead["HDG_P"] = 0.5  # the vehicle echoes another value: refused, not retried
    with pytest.raises(ParamRefused) as refused:
        link.set_param("HDG_P", 2.0)
    assert refused.value.echoed == 0.5
    with pytest.raises(ParamRefused):  # unknown name: STATUSTEXT refusal naming it
        link.set_param("NO_SUCH", 1.0)
    sets_before = len(fake.sent_of("PARAM_SET"))
    with pytest.raises(ParamRefused):  # non-finite: refused locally, never sent
        link.set_param("HDG_P", float("nan"))
    assert len(fake.sent_of("PARAM_SET")) == sets_before
    fake.silent_params.add("HDG_P")
    with pytest.raises(ParamTimeout):
        link.set_param("HDG_P", 1.0, retries=3)
    assert len(fake.sent_of("PARAM_SET")) == sets_before + 3  # resent on every try


def test_a_late_echo_of_an_earlier_write_of_ours_is_not_someone_elses_change(fake_link):
    fake, link = fake_link
    link.parameters.watch(["HDG_P"])
    link.set_param("HDG_P", 0.7)
    link.set_param("HDG_P", 0.8)
    fake.emit(mavlink.MAVLink_param_value_message(b"HDG_P", 0.7, pc.REAL32, 3, 0))  # the first echo, again, late
    link.next_telemetry()
    assert not link.parameters.foreign
    fake.emit(mavlink.MAVLink_param_value_message(b"HDG_P", 0.95, pc.REAL32, 3, 0))  # a ground station's
    link.next_telemetry()
    assert link.parameters.foreign["HDG_P"].value == pytest.approx(0.95)


def test_a_trigger_the_vehicle_resets_itself_is_not_someone_elses_change(fake_link):
    """The simulator applies a roll kick and sets SIM_ROLL_KICK back to 0 (a one-shot trigger)."""
    fake, link = fake_link
    link.parameters.watch(["HDG_P", "SIM_ROLL_KICK"])
    assert link.parameters.watched == {"HDG_P"}
    fake.emit(mavlink.MAVLink_param_value_message(b"SIM_ROLL_KICK", 0.0, pc.REAL32, 3, 0))
    link.next_telemetry()
    assert not link.parameters.foreign


@pytest.mark.parametrize("now_on_vehicle, kept", [(0.95, True), (0.8, False)])
def test_a_foreign_change_is_kept_only_while_the_vehicle_still_holds_it(fake_link, now_on_vehicle, kept):
    """The restore reads the parameter again: someone else's value still there is kept; one since
    replaced (here by a late write of ours) is not theirs any more, and the found value goes back."""
    from companion.procedures.restore import RestorePoint

    fake, link = fake_link
    point = RestorePoint(mode=None, native={"HDG_P": 0.6})
    link.parameters.watch(["HDG_P"])
    link.set_param("HDG_P", 0.8)
    fake.emit(mavlink.MAVLink_param_value_message(b"HDG_P", 0.95, pc.REAL32, 3, 0))
    link.next_telemetry()
    fake.params["HDG_P"] = (now_on_vehicle, pc.REAL32)
    assert point.restore(link, mode=False) == []
    expected = 0.95 if kept else 0.6
    assert fake.params["HDG_P"][0] == pytest.approx(expected)
    assert any("kept 0.95" in note for note in point.notes) == kept


@pytest.mark.parametrize("encoding", ["cast", "bytewise"])
def test_set_param_integer_encodings(fake_link, encoding):
    fake, link = fake_link
    fake.encoding = link.parameters.int_encoding = encoding
    link.parameters.types.clear()
    assert link.set_param("SYSID_MYGCS", 254) == 254.0
    assert fake.params["SYSID_MYGCS"][0] == 254.0
    assert link.get_params(["gcs_sysid"]) == {"gcs_sysid": 254.0}


def test_heartbeat_on_vehicle_time_and_override_refresh(fake_link):
    fake, link = fake_link
    fake.sent.clear()
    link.overrides.override("rudder", 0.2618)
    start = link.next_telemetry().time_s
    while link.next_telemetry().time_s - start < 5.0:
        pass
    heartbeats = fake.sent_of("HEARTBEAT")
    assert 4 <= len(heartbeats) <= 6  # 1 Hz of vehicle time over ~5 s (100 snapshots)
    overrides = fake.sent_of("RC_CHANNELS_OVERRIDE")
    assert len(overrides) >= 100  # refreshed at every snapshot
    assert all(m.get_srcSystem() == 255 and m.chan1_raw == 1750 and m.chan2_raw == 65535 for m in overrides)
    assert all(m.get_srcSystem() == 1 for m in heartbeats)  # own identity restored after overrides
    fake.sent.clear()
    link.release("rudder")
    for _ in range(10):
        link.next_telemetry()
    released = fake.sent_of("RC_CHANNELS_OVERRIDE")
    assert [m.chan1_raw for m in released] == [0, 0, 0]  # released (repeated), then no refresh
    fake.sent.clear()
    link.overrides.override("elevator", 0.1, keep_alive=False)
    for _ in range(10):
        link.next_telemetry()
    assert len(fake.sent_of("RC_CHANNELS_OVERRIDE")) == 1  # single shot, left to expire


def test_execute_sends_set_points(fake_link):
    fake, link = fake_link
    fake.sent.clear()
    link.execute([SetHeading(math.radians(-90.0)), SetDepth(3.0), SetThrust(0.55), SetRollingMass(0.2618)])
    commands = {m.command: m for m in fake.sent_of("COMMAND_LONG")}
    assert commands[115].param1 == pytest.approx(270.0) and commands[115].param4 == 0
    assert commands[186].param1 == pytest.approx(-3.0)
    assert commands[178].param2 == -1 and commands[178].param3 == pytest.approx(55.0)
    assert commands[183].param1 == 9 and commands[183].param2 == 1750
    link.set_mode("hold")
    assert link.mode == "hold"


def test_user_commands_reach_the_callback_from_next_telemetry(fake_link):
    fake, link = fake_link
    received = []
    link.ground.on_user_command(lambda command, params: received.append((command, params)))
    fake.emit(mavlink.MAVLink_command_long_message(1, 191, 31011, 0, 0.7, 0, 0, 0, 0, 0, 0), src=255, comp=190)
    fake.emit(mavlink.MAVLink_command_long_message(1, 1, 31012, 0, 0, 0, 0, 0, 0, 0, 0), src=255, comp=190)  # for the autopilot
    link.next_telemetry()
    assert received == [(31011, (pytest.approx(0.7), 0, 0, 0, 0, 0, 0))]
    link.ground.send_command_ack(31011, 5, progress=40)
    ack = fake.sent_of("COMMAND_ACK")[-1]
    assert (ack.command, ack.result, ack.progress, ack.target_system, ack.target_component) == (31011, 5, 40, 255, 190)
    link.ground.on_user_command(None)
    fake.emit(mavlink.MAVLink_command_long_message(1, 191, 31010, 0, 0, 0, 0, 0, 0, 0, 0), src=255, comp=190)
    link.next_telemetry()
    assert fake.sent_of("COMMAND_ACK")[-1].result == 3  # UNSUPPORTED without a handler


def test_status_text_chunks_and_named_value(fake_link):
    fake, link = fake_link
    link.status_text("x" * 120, severity=4)
    texts = fake.sent_of("STATUSTEXT")
    assert [len(m.text) for m in texts] == [50, 50, 20]
    assert [m.chunk_seq for m in texts] == [0, 1, 2] and len({m.id for m in texts}) == 1 and texts[0].id != 0
    link.ground.named_value("b2_est", 1.08)
    assert fake.sent_of("NAMED_VALUE_FLOAT")[-1].value == pytest.approx(1.08)
    with pytest.raises(ValueError):
        link.ground.named_value("much_too_long", 1.0)


def test_every_snapshot_is_queued_in_order_during_blocking_calls(fake_link):
    fake, link = fake_link
    fake.reply_lag_ticks = 4
    link.set_param("HDG_P", 0.7)  # blocks while telemetry keeps arriving
    assert link.telemetry.pending >= 1
    times = [link.next_telemetry().time_s for _ in range(link.telemetry.pending + 3)]
    assert all(b - a == pytest.approx(0.05) for a, b in zip(times, times[1:]))  # no holes, in order
    link.set_param("HDG_P", 0.8)
    newest = link.latest_telemetry.time_s
    assert link.skip_to_now() >= 1 and link.next_telemetry().time_s > newest


def test_a_single_stray_stamp_is_not_a_reboot(fake_link):
    """One frame stamped far in the past (corrupted, or delivered very late) is dropped and counted;
    the clock and the stream carry on."""
    fake, link = fake_link
    before = link.next_telemetry().time_s
    fake.emit(mavlink.MAVLink_attitude_message(300, 0.0, 0.0, 0.1, 0.0, 0.0, 0.01))
    times = [link.next_telemetry().time_s for _ in range(3)]
    assert times[0] > before and all(b > a for a, b in zip(times, times[1:]))
    assert link.telemetry.quality()["stray"] == 1 and link.clock.reboots == 0


def _swap_next_two(fake):
    """The next two attitude samples arrive in the wrong order (a link that reorders)."""
    first, second = fake.time_ms + 50, fake.time_ms + 100
    for stamp in (second, first):
        fake.emit(mavlink.MAVLink_attitude_message(stamp, 0.0, 0.0, 0.1, 0.0, 0.0, 0.01))
    fake.time_ms = second


def test_a_late_sample_is_placed_in_order_once_the_link_has_reordered_and_the_hold_ends_when_it_calms(fake_link):
    from companion.link.telemetry import REORDER_CALM_SAMPLES

    fake, link = fake_link
    link.next_telemetry()
    _swap_next_two(fake)  # the first reorder: the late sample comes after its successor was returned
    times = [round(link.next_telemetry().time_s * 1000) for _ in range(3)]
    assert times == sorted(times) and link.telemetry.quality()["late_dropped"] == 1
    hold = link.telemetry.quality()["hold_ms"]
    assert 0.0 < hold <= 2 * 50.0  # two nominal sample periods
    _swap_next_two(fake)  # now snapshots are held: the late one takes its place
    times = [round(link.next_telemetry().time_s * 1000) for _ in range(4)]
    assert times == sorted(times) and all(b - a == 50 for a, b in zip(times, times[1:]))
    quality = link.telemetry.quality()
    assert quality["late"] == 2 and quality["late_dropped"] == 1
    for _ in range(REORDER_CALM_SAMPLES + 2):
        link.next_telemetry()
    assert link.telemetry.quality()["hold_ms"] == 0.0  # in order for long enough: no longer held


def test_reboot_and_silence_are_reported(fake_link):
    fake, link = fake_link
    link.next_telemetry()
    fake.time_ms = 2_000  # time_boot_ms jumps back
    with pytest.raises(VehicleRebooted):
        link.next_telemetry()
    assert link.next_telemetry().time_s > 2.0  # the link carries on from the new boot
    fake.silent = True
    with pytest.raises(LinkLost):
        link.next_telemetry(timeout_s=0.2)


# ============================================================================ pairing by time stamp
def _stream(assembler, messages):
    out = []
    for msg in messages:
        out += assembler.take(wire(msg))
    return out


def _attitude(ms):
    return mavlink.MAVLink_attitude_message(ms, 0.0, 0.0, 0.1, 0.0, 0.0, 0.0)


def _outputs(ms, rudder_pwm):
    return mavlink.MAVLink_servo_output_raw_message(ms * 1000, 0, rudder_pwm, 1500, 1700, 1500, 0, 0, 0, 0, 1500)


def test_outputs_are_paired_with_their_own_sample_whatever_the_arrival_order():
    """Over a link that reorders, the outputs of the next sample can arrive before an attitude and
    those of its own sample after it: each snapshot gets the rudder stamped with its own time, and
    the snapshots come out in time order."""
    assembler = TelemetryAssembler(SIM)
    pwm = {ms: 1500 + ms // 10 for ms in range(1000, 1400, 50)}  # a different rudder every sample
    in_order = [m for ms in (1000, 1050) for m in (_outputs(ms, pwm[ms]), _attitude(ms))]
    shuffled = [_attitude(1100), _outputs(1150, pwm[1150]), _outputs(1100, pwm[1100]), _attitude(1150),
                _attitude(1200), _attitude(1250), _outputs(1250, pwm[1250]), _outputs(1200, pwm[1200]),
                _outputs(1300, pwm[1300]), _attitude(1300)]
    snapshots = _stream(assembler, in_order + shuffled)
    assert [round(s.time_s * 1000) for s in snapshots] == list(range(1000, 1350, 50))
    for snapshot in snapshots:
        ms = round(snapshot.time_s * 1000)
        assert snapshot.rudder == pytest.approx(SIM.pwm_to_angle(pwm[ms])), ms


def test_a_lost_output_message_releases_its_snapshot_with_the_outputs_held_then():
    assembler = TelemetryAssembler(SIM)
    messages = [m for ms in (1000, 1050, 1100) for m in (_outputs(ms, 1600), _attitude(ms))]
    messages += [_attitude(1150)]  # its outputs are lost
    messages += [m for ms in (1200, 1250) for m in (_outputs(ms, 1700), _attitude(ms))]
    snapshots = _stream(assembler, messages)
    assert [round(s.time_s * 1000) for s in snapshots] == [1000, 1050, 1100, 1150, 1200, 1250]
    assert snapshots[3].rudder == pytest.approx(SIM.pwm_to_angle(1600))  # held, not the later 1700
    assert assembler.released_without_outputs == 1


def test_without_an_output_stream_no_snapshot_waits():
    assembler = TelemetryAssembler(SIM)
    snapshots = _stream(assembler, [_attitude(ms) for ms in (1000, 1050, 1100)])
    assert [round(s.time_s * 1000) for s in snapshots] == [1000, 1050, 1100]


def test_every_message_the_snapshot_reads_reaches_it():
    """The feed subscribes the transport to each message the assembler has a handler for (a message
    left out is silently never seen: PID_TUNING's turn rates were NaN on ArduRover)."""
    from companion.link.telemetry import TELEMETRY_TYPES

    handled = TelemetryAssembler(ARDUROVER).message_types - {"ATTITUDE", "HEARTBEAT"}
    assert handled <= set(TELEMETRY_TYPES)


def test_the_steering_loops_pid_tuning_is_read_as_turn_rates():
    assembler = TelemetryAssembler(ARDUROVER)
    steer = mavlink.MAVLink_pid_tuning_message(5, 12.0, 9.0, 0.1, 0.02, 0.0, 0.0, 0.0, 0.0)
    roll = mavlink.MAVLink_pid_tuning_message(1, 50.0, 40.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    assembler.take(steer)
    assembler.take(roll)  # another loop's message changes nothing
    assert assembler._fields["turn_rate_target"] == pytest.approx(math.radians(12.0))
    assert assembler._fields["turn_rate_achieved"] == pytest.approx(math.radians(9.0))


def test_ardusubs_yaw_rate_loop_is_read_from_its_own_axis_in_its_own_units():
    """ArduSub 4.7 sends its yaw rate loop on PID_TUNING axis YAW (3), the target in rad/s × 0.01
    and the gyro in deg/s (GCS_MAVLink_Sub.cpp); a steering axis (5) is not its."""
    assembler = TelemetryAssembler(ARDUSUB)
    yaw = mavlink.MAVLink_pid_tuning_message(3, 0.002, 9.0, 0.0, 0.001, 0.0, 0.0, 0.0, 0.0)  # 0.2 rad/s asked
    steer = mavlink.MAVLink_pid_tuning_message(5, 12.0, 9.0, 0.1, 0.02, 0.0, 0.0, 0.0, 0.0)
    assembler.take(yaw)
    assembler.take(steer)
    assert assembler._fields["turn_rate_target"] == pytest.approx(0.2, rel=1e-5)
    assert assembler._fields["turn_rate_achieved"] == pytest.approx(math.radians(9.0))
    rover = TelemetryAssembler(ARDUROVER)
    rover.take(yaw)  # ArduRover's steering loop is axis 5: a yaw axis is not it
    assert "turn_rate_target" not in rover._fields


def test_a_pid_tuning_report_is_one_bit_of_a_real_axis():
    from companion.link.profile import PidTuningReport

    assert ARDUSUB.pid_tuning.with_bit(1.0) == 5.0 and ARDUROVER.pid_tuning.with_bit(4.0) == 5.0
    with pytest.raises(ValueError, match="one bit"):
        PidTuningReport("pid_tuning_mask", 6, 3)
    with pytest.raises(ValueError, match="PID_TUNING_AXIS"):
        PidTuningReport("pid_tuning_mask", 4, 9)
    with pytest.raises(ValueError, match="desired_to_rad_s"):
        PidTuningReport("pid_tuning_mask", 4, 3, desired_to_rad_s=0.0)
