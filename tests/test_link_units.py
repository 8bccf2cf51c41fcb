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
from companion.link.vehicle import LinkTimeouts, VehicleLink, validate_named_value_name  # noqa: E402


def wire(msg, src: int = 1, comp: int = 1):
    """``msg`` as the link would receive it: packed by a sender with that identity and decoded."""
    sender = mavlink.MAVLink(None, srcSystem=src, srcComponent=comp)
    return mavlink.MAVLink(None).decode(bytearray(msg.pack(sender)))


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
    assembler.on_message(wire(mavlink.MAVLink_servo_output_raw_message(0, 0, 0, 65535, 1500, 0, 0, 0, 0, 0)))
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
class FakeAutopilot:
    """Stands in for pymavlink's mavfile: decodes what the link sends (real MAVLink 2 bytes),
    answers like a tiny ArduPilot-style autopilot, and streams one ATTITUDE every 50 ms of
    vehicle time whenever the link asks for a message and none is queued."""

    def __init__(self) -> None:
        self.mav = mavlink.MAVLink(self, srcSystem=1, srcComponent=191)  # the link's sender
        self._parser = mavlink.MAVLink(None)
        self._parser.robust_parsing = True
        self.queue: collections.deque = collections.deque()
        self.sent: list = []
        self.time_ms = 10_000
        self.params = {"HDG_P": (0.6, pc.REAL32), "SYSID_MYGCS": (255.0, pc.INT16), "RC_OVR_TIME": (3.0, pc.REAL32)}
        self.echo_instead: dict[str, float] = {}  # name -> value echoed instead of the written one
        self.silent_params: set[str] = set()
        self.encoding = "cast"
        self.custom_mode = 19
        self.silent = False
        self.reply_lag_ticks = 0

    # -- mavfile surface used by VehicleLink
    def write(self, buf) -> None:
        for msg in self._parser.parse_buffer(bytes(buf)) or []:
            self.sent.append(msg)
            self._answer(msg)

    def recv_match(self, blocking=True, timeout=None, **_):
        if self.silent:
            return None
        if not self.queue:
            self.tick()
        return self.queue.popleft()

    def tick(self) -> None:
        self.time_ms += 50
        self.emit(mavlink.MAVLink_attitude_message(self.time_ms, 0.0, 0.0, 0.1, 0.0, 0.0, 0.01))

    def close(self) -> None:
        pass

    # -- autopilot behaviour
    def emit(self, msg, src: int = 1, comp: int = 1) -> None:
        self.queue.append(wire(msg, src, comp))

    def _param_value(self, name: str) -> None:
        for _ in range(self.reply_lag_ticks):  # telemetry keeps flowing before the answer
            self.tick()
        value, param_type = self.params[name]
        on_wire = pc.encode_value(value, param_type, self.encoding)
        self.emit(mavlink.MAVLink_param_value_message(name.encode(), on_wire, param_type, len(self.params), 0))

    def _answer(self, msg) -> None:
        kind = msg.get_type()
        if kind == "PARAM_REQUEST_READ":
            name = pc.param_id_str(msg.param_id)
            if name in self.params:
                self._param_value(name)
        elif kind == "PARAM_SET":
            name = pc.param_id_str(msg.param_id)
            if name in self.silent_params:
                return
            if name not in self.params:
                self.emit(mavlink.MAVLink_statustext_message(4, f"Unknown parameter {name}".encode()))
                return
            param_type = self.params[name][1]
            value = pc.decode_value(msg.param_value, param_type, self.encoding)
            self.params[name] = (self.echo_instead.get(name, value), param_type)
            self._param_value(name)
        elif kind == "COMMAND_LONG":
            if msg.command == 176:
                self.custom_mode = int(msg.param2)
                self.emit(mavlink.MAVLink_heartbeat_message(12, 3, 1, self.custom_mode, 4, 3))
            self.emit(mavlink.MAVLink_command_ack_message(msg.command, 0, 0, 0, msg.get_srcSystem(),
                                                          msg.get_srcComponent()))

    def sent_of(self, kind: str) -> list:
        return [m for m in self.sent if m.get_type() == kind]


@pytest.fixture
def fake_link():
    fake = FakeAutopilot()
    # the fake answers synchronously (no lag), so a try needs no minimum wall time
    link = VehicleLink(fake, system_id=1, autopilot_component=1, component=191,
                       timeouts=LinkTimeouts(min_try_wall_s=0.0))
    link.setup(None, {}, DepthSensor())
    link.skip_to_now()  # snapshots queued during set-up
    return fake, link


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
