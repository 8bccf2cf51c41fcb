"""The serial link: a telemetry radio at 57600 baud that loses bytes, and what the companion reports.

The end-to-end test runs ``companion identify --lockstep`` over a pseudo-terminal pair at 57600 baud
bridged to the simulator through a radio model each way (``harness.serial_bridge``: 5760 B/s, a
2 KB buffer that drops what does not fit, a seeded 2 % of bytes lost on the air in runs). The
campaign completes, the vehicle is as found (but for the gains the campaign wrote), and the link
quality it reports counts the vehicle's frames lost on the link and discarded as corrupt,
consistently with the frames the radio itself spoiled. The unit tests cover the counting (sequence
gaps, parse failures), the report, the radio model, the simulator's resynchronising parser and the
lockstep stall rule on a damaging link.
"""
from __future__ import annotations

import json
import math
import socket
import sys
import termios
import time
from types import SimpleNamespace

import pytest
from pymavlink.dialects.v20 import ardupilotmega as dialect

from companion.cli.commands._common import link_quality_line, link_quality_record
from companion.link.frame_loss import REORDER_WINDOW, FrameLoss, frame_check, next_whole_frame
from harness.fault_schedule import TO_COMPANION, TO_VEHICLE
from harness.serial_bridge import BAUD, ByteLoss, RadioConditions, RadioDirection, SerialBridge
from harness.serial_campaign import run_serial_campaign
from sim.frame_parser import ResyncParser

#: the radio of the end-to-end test, each way: 57600 baud (5760 B/s), 2 % of bytes lost on the air
RADIO = RadioConditions(rate_bytes_s=BAUD / 10.0, byte_loss=0.02, loss_burst_bytes=32, buffer_bytes=2048)
RADIO_SEED = 2


# ====================================================================== counting frames
def test_sequence_gaps_are_frames_lost_and_late_frames_are_taken_back():
    loss = FrameLoss()
    for seq in (250, 251, 252, 255, 0, 1):  # 253 and 254 lost, then the numbering wraps
        loss.frame((1, 1), seq)
    assert (loss.received, loss.lost) == (6, 2)
    loss.frame((1, 1), 254)  # late: fills a gap
    loss.frame((1, 1), 1)  # the newest again: a repeat
    loss.frame((1, 1), 200)  # far off: judged by the next frame ...
    loss.frame((1, 1), 2)  # ... which goes on from the newest: 200 was a stray, not 198 frames lost
    assert (loss.lost, loss.late, loss.duplicate) == (1, 1, 2)
    loss.frame((1, 2), 7)  # another component numbers its own frames
    loss.frame((1, 2), 9)
    assert loss.lost == 2
    assert loss.loss_fraction == pytest.approx(2 / (loss.received + 2))


def test_a_dropout_is_counted_a_stray_is_not_and_a_new_connection_is_no_gap():
    loss = FrameLoss()
    loss.frame((1, 1), 0)
    loss.frame((1, 1), 2)  # 1 lost
    for seq in range(3, 3 + REORDER_WINDOW + 1):
        loss.frame((1, 1), seq)
    loss.frame((1, 1), 1)  # too late to fill its gap: a stray once the next frame ...
    loss.frame((1, 1), 3 + REORDER_WINDOW + 1)  # ... goes on from the newest
    assert (loss.lost, loss.late, loss.duplicate) == (1, 0, 1)
    loss.frame((1, 1), 200)  # a jump of 130 ...
    loss.frame((1, 1), 201)  # ... that the numbering goes on from: a dropout
    assert loss.lost == 1 + 200 - (3 + REORDER_WINDOW + 2)
    loss.unchecked_frame((1, 1), 17)  # an unknown message (no CRC) out of turn: ignored
    loss.unchecked_frame((1, 1), 202)  # ... in turn: taken
    loss.unchecked_frame((9, 9), 5)  # ... of a sender never seen: ignored
    assert loss.received == 3 + REORDER_WINDOW + 5 and loss.lost == 132
    loss.forget_senders()
    loss.frame((1, 1), 100)  # numbered afresh after a reconnection
    assert loss.lost == 132
    loss.discarded(30)
    loss.discarded(-5)
    counts = loss.counts()
    assert counts["frames_corrupt"] == 2 and counts["bytes_corrupt"] == 30
    assert set(counts) == {"frames", "frames_lost", "frames_late", "frames_duplicate", "frames_corrupt",
                           "bytes_corrupt", "frame_loss_fraction"}
    assert FrameLoss().loss_fraction == 0.0  # nothing received: 0, never NaN


def _frames(count: int, system: int = 1, component: int = 1) -> list[bytes]:
    """``count`` ATTITUDE frames of one sender, numbered in turn (as ``MAVLink.send`` numbers them)."""
    encoder = dialect.MAVLink(None, srcSystem=system, srcComponent=component)
    frames = []
    for i in range(count):
        frames.append(dialect.MAVLink_attitude_message(50 * i, 0.0, 0.0, 0.1, 0.0, 0.0, 0.0).pack(encoder))
        encoder.seq = (encoder.seq + 1) % 256
    return frames


def _transport_reading(messages: list):
    """A Transport whose connection hands out ``messages`` (pymavlink's, BAD_DATA included)."""
    from companion.link.transport import Transport

    queue = list(messages)
    master = SimpleNamespace(recv_match=lambda **_: queue.pop(0) if queue else None, mav=SimpleNamespace())
    return Transport(master, system_id=1, autopilot_component=1, component=191)


def test_the_transport_counts_the_frames_a_byte_losing_link_spoiled():
    frames = _frames(40)
    stream = bytearray(b"".join(frames))
    del stream[10 * len(frames[0]) + 5:10 * len(frames[0]) + 25]  # 20 bytes of frame 10 lost
    parser = dialect.MAVLink(None)
    parser.robust_parsing = True
    messages = parser.parse_buffer(stream) or []
    for system, component in ((1, 191), (255, 190)):  # our own component, a ground station: not counted
        heartbeat = dialect.MAVLink_heartbeat_message(18, 8, 0, 0, 4, 3)
        heartbeat.pack(dialect.MAVLink(None, srcSystem=system, srcComponent=component))
        messages.append(heartbeat)
    transport = _transport_reading(messages)
    while transport.pump(0.0) is not None:
        pass
    counts = transport.frame_loss.counts()
    intact = sum(1 for m in messages if m.get_type() == "ATTITUDE")
    assert counts["frames"] == intact and counts["frames_lost"] == 40 - intact >= 1
    assert counts["frames_corrupt"] >= 1 and counts["bytes_corrupt"] > 0


def test_a_parser_stuck_behind_a_damaged_frame_is_moved_on_to_the_whole_frames_after_it():
    encoder = dialect.MAVLink(None, srcSystem=1, srcComponent=1)
    text = dialect.MAVLink_statustext_message(4, b"x" * 50).pack(encoder)
    attitude = _frames(1)[0]
    parser = dialect.MAVLink(None)
    parser.robust_parsing = True
    assert not parser.parse_buffer(bytearray(text[:10] + attitude))  # waits for the text's 60 bytes
    transport = _transport_reading([])
    transport._master.mav = parser
    assert transport.unparsed_bytes == 10 + len(attitude)
    assert transport.resynchronise() and transport.frame_loss.counts()["bytes_corrupt"] == 10
    assert parser.parse_char(b"").get_type() == "ATTITUDE"  # the whole frame hidden behind it
    assert not transport.resynchronise()  # nothing waits any more
    check = frame_check(dialect)
    assert check(attitude) and not check(attitude[:-1] + bytes([attitude[-1] ^ 1]))
    assert next_whole_frame(text[:10] + attitude, check) == 10  # not the false start inside the text's header
    assert next_whole_frame(text[:10] + attitude[:20], check) is None


def test_the_link_quality_reports_the_frames_lost_in_its_json_and_its_line():
    from companion.link.vehicle import VehicleLink

    link = VehicleLink(SimpleNamespace(mav=SimpleNamespace()), system_id=1, autopilot_component=1, component=191)
    quality = link.telemetry.quality()
    assert quality["frames"] == quality["frames_lost"] == 0 and quality["frame_loss_fraction"] == 0.0
    frame_loss = link.transport.frame_loss
    for seq in range(200):
        if seq % 10 != 3:  # one frame in ten lost
            frame_loss.frame((1, 1), seq)
    frame_loss.discarded(40)
    counts = dict(link.telemetry.quality(), samples=1000)
    record = link_quality_record(SimpleNamespace(telemetry=SimpleNamespace(quality=lambda: counts)))
    assert record["frames_lost"] == 20 and record["frame_loss_fraction"] == pytest.approx(0.1)
    assert record["lost_fraction"] == 0.0
    assert "10.0 % of the vehicle's frames (20 of 200; 1 discarded" in record["warning"]
    json.dumps(record, allow_nan=False)  # never NaN or Infinity
    line = link_quality_line(record)
    assert "frames: 180 received, 20 lost on the link (10.0 %), 1 discarded as corrupt" in line and "WARNING" in line
    clean = link_quality_record(SimpleNamespace(telemetry=SimpleNamespace(
        quality=lambda: {"samples": 1000, "outputs_lost": 10, "frames": 5000, "frames_lost": 20, "frames_corrupt": 0})))
    assert clean["warning"] is None and clean["frame_loss_fraction"] == pytest.approx(20 / 5020)


# ====================================================================== the lockstep stall rule on a damaging link
class _Mav:
    """pymavlink's encoder and parser counters: ``<message>_send`` calls are recorded."""

    def __init__(self) -> None:
        self.sent: list[tuple] = []
        self.total_bytes_received = 0

    def __getattr__(self, name):
        return lambda *args: self.sent.append((name, *args))


def _lockstep_link():
    from companion.link.vehicle import VehicleLink

    mav = _Mav()
    link = VehicleLink(SimpleNamespace(mav=mav), system_id=1, autopilot_component=1, component=191)
    link.clock.lockstep = True
    return link, mav


def _link_acknowledged_at_1000_ms():
    """A lockstep link that took samples at 900, 950 and 1000 ms and acknowledged the last."""
    link, mav = _lockstep_link()
    for time_ms in (900, 950, 1000):
        link.clock.sample(time_ms)
    link.clock.acknowledge(1000)
    return link, mav


def _acks(mav: _Mav) -> list[int]:
    return [args[1] for name, *args in mav.sent if name == "system_time_send"]


def test_a_stall_steps_on_by_the_period_asked_for_else_by_the_samples_spacing():
    link, mav = _lockstep_link()
    clock, transport = link.clock, link.transport
    for time_ms in (0, 50, 100, 200, 250, 260):  # 150 lost; 260: the stream re-requested out of phase
        clock.sample(time_ms)
    assert clock.sample_period_ms == 50
    clock.requested_period_ms = 100.0  # the handshake asked for 10 Hz
    clock.acknowledge(260)
    transport.frame_loss.discarded(40)
    mav.total_bytes_received += 100  # answered, damaged: the sample was lost
    transport.last_rx_wall = time.monotonic() - 10.0
    clock.unstall()
    assert _acks(mav) == [260, 360]


def test_on_a_damaging_link_a_stall_skips_the_lost_sample_at_once():
    link, mav = _link_acknowledged_at_1000_ms()
    clock, transport = link.clock, link.transport
    transport.last_rx_wall = time.monotonic() - 0.5  # quiet for 0.5 s: below the 1 s of a clean link
    clock.unstall()
    assert _acks(mav) == [1000]
    mav.total_bytes_received += 300  # the vehicle answered (bytes came) ...
    transport.frame_loss.discarded(40)  # ... damaged: its sample was lost
    clock.unstall()
    assert _acks(mav) == [1000, 1050] and clock.wall_timeouts == 1


def test_unanswered_acknowledgements_go_no_further_than_a_period_past_the_vehicle_time_heard():
    link, mav = _link_acknowledged_at_1000_ms()
    clock, transport = link.clock, link.transport
    transport.frame_loss.discarded(40)  # a damaging link; nothing more arrives
    for _ in range(5):
        transport.last_rx_wall = clock._last_nudge_wall = time.monotonic() - 10.0
        clock.unstall()
    # the same again (ours was lost), one further, then no further: the simulator ignores an
    # acknowledgement more than two periods ahead of its clock
    assert _acks(mav) == [1000, 1000, 1050, 1050, 1050, 1050]
    transport.heard_time_ms = 1200  # the autopilot's frames say its clock is further on (its samples lost)
    transport.last_rx_wall = clock._last_nudge_wall = time.monotonic() - 10.0
    clock.unstall()
    assert _acks(mav)[-1] == 1200


# ====================================================================== the radio model
def test_the_air_loses_the_fraction_asked_in_runs_by_position_alone():
    loss = ByteLoss(0.02, 32, seed=5)
    mask = loss.mask(2_000_000)
    assert sum(mask) / len(mask) == pytest.approx(0.02, rel=0.1)
    runs = sum(1 for i in range(1, len(mask)) if mask[i] and not mask[i - 1])
    assert sum(mask) / runs == pytest.approx(32, rel=0.15)  # mean run length
    pieces = ByteLoss(0.02, 32, seed=5)
    chunked = bytearray()
    for size in (1, 7, 64, 4096, 3) * 400:
        chunked += pieces.mask(size)
    assert chunked == mask[:len(chunked)]  # how the stream is cut does not matter
    assert sum(ByteLoss(0.0, 32, seed=5).mask(1000)) == 0
    single = ByteLoss(0.05, 1, seed=2).mask(400_000)
    assert sum(single) / len(single) == pytest.approx(0.05, rel=0.1)


def test_the_radio_paces_bytes_at_its_rate_and_drops_what_its_buffer_cannot_hold():
    radio = RadioDirection(TO_COMPANION, RadioConditions(rate_bytes_s=5760.0, buffer_bytes=2048), seed=1)
    radio.take(bytes(1500), now=0.0)
    assert radio.release(0.0) == b""  # a byte takes its time on the wire
    assert abs(len(radio.release(0.2)) - 5760 * 0.2) <= 64  # 57600 baud: 5760 bytes a second
    radio.release(10.0)
    assert radio.counts["bytes_delivered"] == 1500 and radio.counts["bytes_overflow"] == 0
    radio.take(bytes(10_000), now=20.0)  # far more than the buffer at once
    stats = radio.stats()
    assert 10_000 - 2048 - 64 <= stats["bytes_overflow"] <= 10_000 - 2048 + 64
    assert stats["bytes_dropped"] == stats["bytes_overflow"] and stats["bytes_lost"] == 0


def test_the_radio_counts_the_frames_it_spoiled():
    frames = _frames(2000)
    radio = RadioDirection(TO_COMPANION, RadioConditions(rate_bytes_s=1e9, byte_loss=0.02, buffer_bytes=10**7), seed=3)
    stream = b"".join(frames)
    for start in range(0, len(stream), 333):
        radio.take(stream[start:start + 333], now=0.0)
    delivered = radio.release(1.0)
    parser = dialect.MAVLink(None)
    parser.robust_parsing = True
    intact = {m.time_boot_ms for m in parser.parse_buffer(bytearray(delivered)) or [] if m.get_type() == "ATTITUDE"}
    stats = radio.stats()
    assert stats["frames_in"] == 2000 and stats["frames_hit_by_name"] == {"ATTITUDE": stats["frames_hit"]}
    assert stats["bytes_lost"] == len(stream) - len(delivered)
    assert stats["byte_drop_fraction"] == pytest.approx(0.02, rel=0.3)
    # a spoiled frame never arrives; pymavlink also loses some intact neighbours of a spoiled one
    assert 2000 - len(intact) >= stats["frames_hit"] >= 1


def test_the_bridge_is_a_raw_57600_baud_serial_port_to_a_tcp_peer():
    import serial

    server = socket.create_server(("127.0.0.1", 0))
    server.settimeout(5.0)
    with SerialBridge(server.getsockname()[1], conditions=RadioConditions(), seed=0) as bridge:
        assert bridge.endpoint == f"{bridge.device},57600" and bridge.device.startswith("/dev/")
        attrs = termios.tcgetattr(bridge.slave_fd)
        assert attrs[4] == attrs[5] == termios.B57600 and not attrs[3] & termios.ECHO
        port = serial.Serial(bridge.device, 57600, timeout=2.0)
        try:
            port.write(b"hello vehicle")  # the companion speaks first: the bridge connects
            peer, _ = server.accept()
            peer.settimeout(5.0)
            received = b""
            while len(received) < 13:
                received += peer.recv(100)
            assert received == b"hello vehicle"
            started = time.monotonic()
            peer.sendall(bytes(2000))  # within the radio's buffer: 0.35 s at 57600 baud
            got = port.read(2000)
            assert len(got) == 2000 and time.monotonic() - started >= 0.3
            peer.close()
        finally:
            port.close()
        stats = bridge.stats()
    server.close()
    assert stats[TO_VEHICLE]["bytes_delivered"] == 13 and stats[TO_COMPANION]["bytes_delivered"] == 2000


# ====================================================================== the simulator's parser
def test_the_simulators_parser_finds_the_frame_after_a_damaged_one():
    encoder = dialect.MAVLink(None, srcSystem=1, srcComponent=191)
    acks = [dialect.MAVLink_system_time_message(0, 1000 + 50 * i).pack(encoder) for i in range(4)]
    override = dialect.MAVLink_rc_channels_override_message(1, 1, 1600, 1500, 1500, 0, 0, 0, 0, 0).pack(encoder)
    parser = ResyncParser(dialect.MAVLink(None))
    clean = b"".join(acks)
    assert [m.time_boot_ms for m in parser.parse_buffer(clean[:30]) + parser.parse_buffer(clean[30:])] == \
        [1000, 1050, 1100, 1150]
    # an override that lost its last 10 bytes waits for bytes that never come: pymavlink's own parser
    # swallows the acknowledgement behind it; this one finds it
    damaged = override[:-10] + acks[0]
    plain = dialect.MAVLink(None)
    plain.robust_parsing = True
    assert not [m for m in plain.parse_buffer(bytearray(damaged)) or [] if m.get_type() == "SYSTEM_TIME"]
    got = parser.parse_buffer(damaged)
    assert [m.get_type() for m in got] == ["BAD_DATA", "SYSTEM_TIME"] and got[1].time_boot_ms == 1000
    assert parser.discarded_bytes == len(override) - 10
    got = parser.parse_buffer(b"\x00\xfd\x09" + acks[1])  # junk and a false start
    assert [m.get_type() for m in got] == ["BAD_DATA", "SYSTEM_TIME"]


# ====================================================================== end to end
@pytest.mark.slow
@pytest.mark.e2e
@pytest.mark.skipif(sys.platform == "win32", reason="pseudo-terminals")
def test_a_campaign_over_a_lossy_57600_baud_radio_completes_and_reports_the_frames_lost(sim_factory, tmp_path):
    sim = sim_factory(transport="tcp", speedup=0, seed=1, lockstep=True)
    run = run_serial_campaign(sim, tmp_path / "store.sqlite", RADIO, RADIO_SEED)
    summary = run.summary()
    down, up = run.radio[TO_COMPANION], run.radio[TO_VEHICLE]
    quality = run.quality
    assert run.endpoint.endswith(",57600") and run.endpoint.startswith("/dev/")
    # the radio did what it says, both ways: about 2 % of the bytes lost, whole frames spoiled
    for direction in (down, up):
        assert 0.005 <= direction["byte_drop_fraction"] <= 0.05 and direction["frames_hit"] >= 1, summary
    # the campaign completes over it (lockstep: vehicle time waits for the link), and says so
    assert run.exit_code == 0 and run.status == "completed", summary + run.stderr[-2000:]
    assert run.result["restore_problems"] == [] and run.result["final_gains"], summary
    # what the companion reports: the vehicle's frames lost on the link and discarded as corrupt,
    # consistent with the frames the radio spoiled on the way to it (each spoiled frame is lost; a
    # spoiled frame can make the parser lose an intact neighbour too, never many)
    assert quality["frames_lost"] >= 1 and quality["frames_corrupt"] >= 1, summary
    assert 0.9 * down["frames_hit"] <= quality["frames_lost"] <= 3 * down["frames_hit"], summary
    assert 0.8 <= quality["frame_loss_fraction"] / down["frame_hit_fraction"] <= 3.0, summary
    assert quality["frame_loss_fraction"] == pytest.approx(
        quality["frames_lost"] / (quality["frames"] + quality["frames_lost"]))
    line = link_quality_line(quality)  # identify's text summary prints this line
    assert f"{quality['frames_lost']} lost on the link" in line, line
    if quality["frame_loss_fraction"] > 0.05:
        assert "of the vehicle's frames" in quality["warning"] and "warning:" in run.stderr, summary
    # the vehicle is as found, but for the gains the campaign wrote
    assert run.state_problems == [], summary
    assert all(math.isfinite(value) for value in run.result["final_gains"].values())
