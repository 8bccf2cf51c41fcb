"""The UDP fault relay and the link conditions, between two local UDP sockets (no simulator): loss
at its rate and the same datagrams lost for the same seed, delay and jitter applied, reordering when
jitter exceeds the interval between datagrams, the byte-rate cap holding its rate (and the TCP
proxy's), one frame delayed on purpose so that a later set-point overtakes it, triggered faults on
single frames of multi-frame datagrams. Seeded; every wait is bounded; a few seconds in all.

Timing: what the relay *planned* (its ``trace``) is checked exactly; what the operating system then
did is checked from the kernel's arrival times, by what scheduling cannot change (a datagram is never
early, the cap is never exceeded, the order) and by medians, not by a worst case: on a loaded
machine a thread may wake up a few hundred milliseconds late.
"""
from __future__ import annotations

import socket
import statistics
import struct
import threading
import time

import pytest

from harness.fault_proxy import FaultProxy
from harness.fault_schedule import TO_COMPANION, TO_VEHICLE, Fault, Trigger, overtaken, timed_delay
from harness.link_conditions import FateDraws, LinkConditions, TokenBucket
from harness.relay_process import RelayProcess
from harness.udp_relay import SO_TIMESTAMPNS, UdpRelay, _arrival

DO_CHANGE_SPEED = 178
WAIT_S = 3.0  # the longest any test waits for datagrams that do not come


def _frame(msgid: int, payload: bytes) -> bytes:
    """A MAVLink 2 frame with its checksum (the delivery record reads only frames a receiver keeps)."""
    from pymavlink.dialects.v20 import ardupilotmega as dialect
    from pymavlink.mavutil import x25crc

    head = bytes([0xFD, len(payload), 0, 0, 7, 1, 1]) + msgid.to_bytes(3, "little")
    crc = x25crc(head[1:] + payload)
    crc.accumulate(bytes([dialect.mavlink_map[msgid].crc_extra]))
    return head + payload + crc.crc.to_bytes(2, "little")


def _attitude(number: int) -> bytes:
    return _frame(30, struct.pack("<I", number) + bytes(24))


def _speed(thrust_pct: float) -> bytes:
    """DO_CHANGE_SPEED as the companion sends a thrust set-point: throttle (%) in param 3."""
    return _frame(76, struct.pack("<7fHBBB", 0.0, -1.0, thrust_pct, 0, 0, 0, 0, DO_CHANGE_SPEED, 1, 1, 0))


def _param_set(name: str, value: float) -> bytes:
    return _frame(23, struct.pack("<fBB16sB", value, 1, 1, name.encode(), 9))


class _Ends:
    """A fake vehicle and a fake companion on loopback, around a relay."""

    def __init__(self) -> None:
        self.vehicle = self._socket()
        self.companion = self._socket()
        self.upstream: tuple[str, int] | None = None  # where the relay sends from (the vehicle answers it)

    @staticmethod
    def _socket() -> socket.socket:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
        if SO_TIMESTAMPNS is not None:  # arrival times from the kernel: this test's thread may be read late
            sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
        sock.bind(("127.0.0.1", 0))
        return sock

    @property
    def vehicle_port(self) -> int:
        return self.vehicle.getsockname()[1]

    def hello(self, relay: UdpRelay) -> None:
        """The companion sends first (as a ``udpout:`` peer must); the vehicle learns the relay."""
        self.companion.sendto(_frame(0, bytes(9)), ("127.0.0.1", relay.port))
        self.upstream = self.receive(self.vehicle, 1)[0][2]

    # The send time is read *before* the send: read after it, a thread descheduled between the two
    # would record a time later than the datagram left, and a delay could look early by that much.
    def to_companion(self, data: bytes) -> float:
        sent_at = time.monotonic()
        self.vehicle.sendto(data, self.upstream)
        return sent_at

    def to_vehicle(self, relay: UdpRelay, data: bytes) -> float:
        sent_at = time.monotonic()
        self.companion.sendto(data, ("127.0.0.1", relay.port))
        return sent_at

    @staticmethod
    def receive(sock: socket.socket, count: int, quiet_s: float = 1.0,
                limit_s: float = WAIT_S) -> list[tuple[bytes, float, tuple]]:
        """Up to ``count`` datagrams with their arrival times and senders; stops ``quiet_s`` after
        the last one or after ``limit_s`` in all."""
        got = []
        deadline = time.monotonic() + limit_s
        while len(got) < count and time.monotonic() < deadline:
            sock.settimeout(min(quiet_s, max(0.01, deadline - time.monotonic())))
            try:
                data, ancillary, _flags, sender = sock.recvmsg(65535, 64)
            except socket.timeout:
                if got:
                    break
                continue
            got.append((data, _arrival(ancillary, time.time() - time.monotonic())[0], sender))
        return got

    def close(self) -> None:
        self.vehicle.close()
        self.companion.close()


class _Listener:
    """:meth:`_Ends.receive` in a thread, so arrival times are taken while the test still sends."""

    def __init__(self, sock: socket.socket, count: int) -> None:
        self.got: list = []
        self._thread = threading.Thread(target=lambda: self.got.extend(_Ends.receive(sock, count)), daemon=True)
        self._thread.start()

    def wait(self) -> list[tuple[bytes, float, tuple]]:
        self._thread.join(WAIT_S + 1.0)
        return self.got


@pytest.fixture
def ends():
    pair = _Ends()
    yield pair
    pair.close()


def _numbers(received) -> list[int]:
    return [struct.unpack_from("<I", data, 10)[0] for data, _, _ in received]


def _stream(ends: _Ends, count: int, interval_s: float) -> dict[int, float]:
    """``count`` ATTITUDE datagrams from the vehicle, ``interval_s`` apart; their send times."""
    sent = {}
    for number in range(count):
        sent[number] = ends.to_companion(_attitude(number))
        if interval_s:
            time.sleep(interval_s)
    return sent


# ---------------------------------------------------------------------------- link conditions
def test_the_fate_of_each_datagram_depends_on_the_seed_and_its_number_only():
    conditions = LinkConditions(loss=0.1, jitter_s=0.02, duplicate=0.05, reorder=0.05)

    def fates(seed: int) -> list:
        draws = FateDraws(conditions, seed)
        return [draws.next() for _ in range(500)]

    assert fates(7) == fates(7) and fates(7) != fates(8)
    assert all(0.0 <= fate.delay_s <= 0.02 for fate in fates(7))  # 0 ± 20 ms, never negative
    normal = FateDraws(LinkConditions(delay_s=0.05, jitter_s=0.01, jitter_shape="normal"), 1)
    delays = [normal.next().delay_s for _ in range(2000)]
    assert all(0.02 <= d <= 0.08 for d in delays) and abs(sum(delays) / len(delays) - 0.05) < 0.002


def test_link_conditions_are_checked_and_described():
    with pytest.raises(ValueError):
        LinkConditions(loss=1.5)
    with pytest.raises(ValueError):
        LinkConditions(jitter_shape="cauchy")
    with pytest.raises(ValueError):
        LinkConditions(rate_bytes_s=0)
    assert LinkConditions().clean and LinkConditions().describe() == "clean"
    assert LinkConditions(loss=0.02, delay_s=0.05, jitter_s=0.02).describe() == "2 % loss, 50 ± 20 ms"


def test_the_token_bucket_paces_at_its_rate_and_drops_what_its_queue_cannot_hold():
    bucket = TokenBucket(1000.0, burst_bytes=100, queue_bytes=10_000)
    departures = [bucket.admit(100, 0.0) for _ in range(11)]
    assert departures[0] == 0.0 and departures[-1] == pytest.approx(1.0)  # 1000 B more at 1000 B/s
    small = TokenBucket(1000.0, burst_bytes=100, queue_bytes=300)
    admitted = [small.admit(100, 0.0) for _ in range(10)]
    assert sum(a is not None for a in admitted) == 4 and small.dropped == 6  # the one leaving + 3 queued
    assert small.admit(100, 10.0) == 10.0  # the queue drained meanwhile


# ---------------------------------------------------------------------------- the relay
def test_loss_is_at_its_rate_and_the_same_datagrams_are_lost_for_the_same_seed(ends):
    lost_sets = []
    for seed in (3, 3, 4):
        with UdpRelay(ends.vehicle_port, seed=seed, conditions={TO_COMPANION: LinkConditions(loss=0.2)}) as relay:
            ends.hello(relay)
            _stream(ends, 400, 0.0)
            received = _numbers(ends.receive(ends.companion, 400, quiet_s=0.5))
            stats = relay.stats()[TO_COMPANION]
        assert stats["received"] == 400 and stats["lost"] + len(received) == 400
        assert received == sorted(received) and stats["out_of_order"] == 0  # loss alone never reorders
        assert 0.15 <= stats["lost"] / 400 <= 0.25  # 20 %: ±5 points is > 4 σ of a binomial
        lost_sets.append(set(range(400)) - set(received))
    assert lost_sets[0] == lost_sets[1] and lost_sets[0] != lost_sets[2]


def _planned_delays(relay: UdpRelay, direction: str = TO_COMPANION) -> list[float]:
    return [at - arrival for name, _index, arrival, at in relay.planned if name == direction]


def test_a_fixed_delay_is_applied_and_keeps_the_order(ends):
    with UdpRelay(ends.vehicle_port, conditions=LinkConditions(delay_s=0.05), trace=True) as relay:
        ends.hello(relay)
        listener = _Listener(ends.companion, 40)
        sent = _stream(ends, 40, 0.002)
        received = listener.wait()
    latencies = [at - sent[number] for number, (_, at, _) in zip(_numbers(received), received)]
    assert _numbers(received) == list(range(40))
    assert _planned_delays(relay) == pytest.approx([0.05] * 40, abs=1e-9)
    assert min(latencies) >= 0.049 and statistics.median(latencies) < 0.07  # never early


def test_a_relay_that_reads_late_still_delays_each_datagram_from_its_arrival(ends):
    """A busy machine may leave the relay unscheduled for a while: the delay counts from when the
    kernel received each datagram, not from when the relay read it."""
    relay = UdpRelay(ends.vehicle_port, conditions=LinkConditions(delay_s=0.2), trace=True)
    try:
        listener = _Listener(ends.vehicle, 5)
        sent = [ends.to_vehicle(relay, _attitude(n)) for n in range(5)]  # queued: the relay is not running yet
        time.sleep(0.12)
        relay.start()
        received = listener.wait()
    finally:
        relay.close()
    assert len(received) == 5 and all(at - sent[0] >= 0.19 for _, at, _ in received)
    planned = [at - sent[index] for _name, index, _arrival, at in relay.planned]
    assert planned == pytest.approx([0.2] * 5, abs=0.005)  # from the send, not from the read 0.12 s later
    assert relay.stats()[TO_VEHICLE]["max_read_lag_ms"] >= 100


def test_jitter_spreads_the_delay_and_reorders_datagrams_closer_than_the_jitter(ends):
    with UdpRelay(ends.vehicle_port, seed=1, conditions=LinkConditions(delay_s=0.05, jitter_s=0.02),
                  trace=True) as relay:
        ends.hello(relay)
        listener = _Listener(ends.companion, 150)
        sent = _stream(ends, 150, 0.002)  # 2 ms apart: far closer than ±20 ms
        received = listener.wait()
        stats = relay.stats()[TO_COMPANION]
    numbers = _numbers(received)
    latencies = [at - sent[n] for n, (_, at, _) in zip(numbers, received)]
    assert sorted(numbers) == list(range(150))  # nothing lost, nothing doubled
    planned = _planned_delays(relay)
    assert len(planned) == 150 and all(0.03 - 1e-9 <= p <= 0.07 + 1e-9 for p in planned)  # 50 ± 20 ms
    assert max(planned) - min(planned) > 0.035 and abs(statistics.mean(planned) - 0.05) < 0.005
    assert min(latencies) >= 0.029 and 0.04 < statistics.median(latencies) < 0.07
    inversions = sum(1 for a, b in zip(numbers, numbers[1:]) if b < a)
    assert inversions > 20 and stats["out_of_order"] > 20
    assert stats["attitude_out_of_order"] == stats["out_of_order"]  # one ATTITUDE per datagram here


def test_explicit_reordering_and_duplication(ends):
    conditions = LinkConditions(reorder=0.2, reorder_max_s=0.1, duplicate=0.1)
    with UdpRelay(ends.vehicle_port, seed=2, conditions={TO_COMPANION: conditions}) as relay:
        ends.hello(relay)
        _stream(ends, 100, 0.001)
        numbers = _numbers(ends.receive(ends.companion, 200, quiet_s=0.5))
        stats = relay.stats()[TO_COMPANION]
    assert sorted(set(numbers)) == list(range(100))
    assert len(numbers) == 100 + stats["duplicated"] and stats["duplicated"] > 0
    assert stats["reordered"] > 0 and any(b < a for a, b in zip(numbers, numbers[1:]))


def test_the_byte_rate_cap_holds_its_rate_and_drops_beyond_its_queue(ends):
    payload, burst = 250, 512
    with UdpRelay(ends.vehicle_port, trace=True, conditions={TO_COMPANION: LinkConditions(
            rate_bytes_s=40_000, burst_bytes=burst, queue_bytes=1 << 20)}) as relay:
        ends.hello(relay)
        first = ends.to_companion(_attitude(0) + bytes(payload - 40))
        for number in range(1, 120):  # 120 × 250 B = 30 kB at once: 0.74 s at 40 kB/s after the burst
            ends.to_companion(_attitude(number) + bytes(payload - 40))
        received = ends.receive(ends.companion, 120)
        stats = relay.stats()[TO_COMPANION]
    assert len(received) == 120 and stats["bytes_delivered"] == 120 * payload
    planned = [at for name, _i, _arrival, at in relay.planned if name == TO_COMPANION]
    assert planned[-1] - planned[0] == pytest.approx((120 * payload - burst) / 40_000, abs=0.005)
    assert received[-1][1] - first >= (120 * payload - burst) / 40_000 - 0.005  # never faster than the cap
    assert received[-1][1] - first < 2.0
    with UdpRelay(ends.vehicle_port, conditions={TO_COMPANION: LinkConditions(
            rate_bytes_s=40_000, burst_bytes=burst, queue_bytes=2500)}) as relay:
        ends.hello(relay)
        for number in range(120):
            ends.to_companion(_attitude(number) + bytes(payload - 40))
        received = ends.receive(ends.companion, 120, quiet_s=0.5)
        stats = relay.stats()[TO_COMPANION]
    assert stats["rate_dropped"] + len(received) == 120 and stats["rate_dropped"] > 80


def test_one_set_point_delayed_is_overtaken_by_the_next_and_the_vehicle_keeps_the_late_one(ends):
    """A late DO_CHANGE_SPEED 100 overtaking the restore's DO_CHANGE_SPEED 70 (sent 5 ms later):
    the vehicle's last thrust demand is 100, whatever was acknowledged."""
    trigger = Trigger("COMMAND_LONG", 2, command=DO_CHANGE_SPEED)
    with UdpRelay(ends.vehicle_port) as relay:
        ends.hello(relay)
        relay.arm([timed_delay(trigger, 0.08, messages=("COMMAND_LONG",))])
        ends.to_vehicle(relay, _speed(60.0))
        ends.receive(ends.vehicle, 1)
        listener = _Listener(ends.vehicle, 2)
        late = ends.to_vehicle(relay, _speed(100.0))
        time.sleep(0.005)
        ends.to_vehicle(relay, _speed(70.0))
        received = listener.wait()
        summary = relay.summary()
    history = [d.params[2] for d in relay.delivered.history(DO_CHANGE_SPEED)]  # the relay stopped: all noted
    assert [struct.unpack_from("<f", data, 18)[0] for data, _, _ in received] == [70.0, 100.0]
    assert 0.079 <= received[1][1] - late < 0.5
    assert history == [60.0, 70.0, 100.0] and relay.delivered_commands[DO_CHANGE_SPEED][2] == 100.0
    assert summary[0]["triggered"] and summary[0]["affected"] == 1
    assert "delay by 80 ms" in summary[0]["fault"]


def test_a_set_point_held_until_the_next_one_passed_arrives_after_it_whatever_the_gap(ends):
    trigger, partner = Trigger("COMMAND_LONG", 1, command=DO_CHANGE_SPEED), Trigger("COMMAND_LONG", command=DO_CHANGE_SPEED)
    yaw = _frame(76, struct.pack("<7fHBBB", 90.0, 0, 0, 0, 0, 0, 0, 115, 1, 1, 0))
    with UdpRelay(ends.vehicle_port) as relay:
        ends.hello(relay)
        relay.arm([overtaken(trigger, partner, messages=("COMMAND_LONG",))])
        listener = _Listener(ends.vehicle, 2)  # the held frame travels in its partner's datagram
        ends.to_vehicle(relay, _speed(100.0))
        time.sleep(0.2)  # far longer than any jitter: still overtaken
        ends.to_vehicle(relay, yaw)
        ends.to_vehicle(relay, _speed(70.0))
        received = listener.wait()
        summary = relay.summary()
    assert [struct.unpack_from("<H", data, 38)[0] for data, _, _ in received] == [115, 178]  # the yaw passes
    assert relay.delivered.commands[DO_CHANGE_SPEED][2] == 100.0  # the vehicle's last thrust: the late one
    assert received[1][0].count(b"\xfd") >= 2 and "after the next COMMAND_LONG 178" in summary[0]["fault"]


def test_triggered_faults_take_single_frames_of_a_multi_frame_datagram(ends):
    with UdpRelay(ends.vehicle_port) as relay:
        ends.hello(relay)
        relay.arm([Fault("drop", Trigger("PARAM_SET", 3), direction=TO_VEHICLE, messages=("PARAM_SET",), frames=1),
                   Fault("duplicate", Trigger("PARAM_SET", 4), direction=TO_VEHICLE, messages=("PARAM_SET",),
                         frames=1)])
        for number in range(1, 6):  # each datagram: a heartbeat, then PARAM_SET number
            ends.to_vehicle(relay, _frame(0, bytes(9)) + _param_set("HDG_P", float(number)))
        received = ends.receive(ends.vehicle, 5)
        summary = relay.summary()
    assert len(received) == 5 and all(data.startswith(_frame(0, bytes(9))) for data, _, _ in received)
    params = [data.count(b"HDG_P") for data, _, _ in received]
    assert params == [1, 1, 0, 2, 1]  # the 3rd dropped, the 4th doubled, the heartbeats untouched
    assert [s["triggered"] for s in summary] == [True, True] and relay.count("PARAM_SET") == 5


def test_a_silent_cut_drops_everything_for_its_time(ends):
    with UdpRelay(ends.vehicle_port) as relay:
        ends.hello(relay)
        relay.arm([Fault("cut", Trigger(nth=0), cut_s=0.2, reconnect=True)])  # UDP: a closing cut is silent
        time.sleep(0.02)
        _stream(ends, 10, 0.0)
        assert ends.receive(ends.companion, 10, limit_s=0.1) == []
        time.sleep(0.25)
        _stream(ends, 10, 0.0)
        assert len(ends.receive(ends.companion, 10)) == 10
        assert relay.summary()[0]["affected"] == 10


def test_the_relay_runs_in_a_process_of_its_own_with_the_same_methods(ends):
    with RelayProcess(ends.vehicle_port, seed=3, conditions={TO_COMPANION: LinkConditions(loss=0.2)}) as relay:
        ends.hello(relay)
        relay.arm([Fault("drop", Trigger("PARAM_SET", 1), direction=TO_VEHICLE, messages=("PARAM_SET",), frames=1)])
        ends.to_vehicle(relay, _param_set("HDG_P", 1.0) + _speed(70.0))
        _stream(ends, 100, 0.0)
        received = _numbers(ends.receive(ends.companion, 100, quiet_s=0.5))
        at_vehicle = ends.receive(ends.vehicle, 1)
        assert relay.count("PARAM_SET") == 1 and relay.summary()[0]["affected"] == 1
        assert [d.params[2] for d in relay.history(DO_CHANGE_SPEED)] == [70.0]
    stats = relay.stats()  # kept from the closed relay
    assert b"HDG_P" not in at_vehicle[0][0]
    assert stats[TO_COMPANION]["lost"] + len(received) == 100 and stats[TO_COMPANION]["lost"] > 0


# ---------------------------------------------------------------------------- the TCP proxy's rate cap
def test_the_tcp_proxy_caps_the_byte_rate_and_refuses_datagram_conditions():
    with pytest.raises(ValueError):
        FaultProxy(1, conditions=LinkConditions(loss=0.1))
    server = socket.create_server(("127.0.0.1", 0))
    try:
        with FaultProxy(server.getsockname()[1], conditions={TO_COMPANION: LinkConditions(
                rate_bytes_s=50_000, queue_bytes=1 << 20)}) as proxy:
            companion = socket.create_connection(("127.0.0.1", proxy.port), timeout=WAIT_S)
            vehicle, _ = server.accept()
            data = b"".join(_attitude(n) + bytes(0) for n in range(600))  # 600 × 40 B = 24 kB: ~0.48 s
            started = time.monotonic()
            vehicle.sendall(data)
            got = bytearray()
            deadline = started + WAIT_S
            while len(got) < len(data) and time.monotonic() < deadline:
                got += companion.recv(65536)
            span = time.monotonic() - started
            companion.close()
            vehicle.close()
        assert bytes(got) == data and (len(data) - 512) / 50_000 - 0.01 <= span < 1.5  # never above the cap
        assert proxy.delivered.attitude_delivered == 600 and proxy.rate_dropped[TO_COMPANION] == 0
    finally:
        server.close()


def test_a_corrupted_frame_is_delivered_but_not_read_as_what_the_vehicle_was_told():
    """The vehicle's CRC check discards a corrupted frame: the delivery record must not count an
    RC override in it as held (the UDP fault matrix reported a channel 'held at 65280')."""
    import random

    from pymavlink.dialects.v20 import ardupilotmega as dialect

    from harness.delivery_log import DeliveryLog
    from harness.fault_schedule import TO_VEHICLE
    from harness.mavlink_frames import split_datagram

    mav = dialect.MAVLink(None, srcSystem=255)
    held = split_datagram(dialect.MAVLink_rc_channels_override_message(1, 1, 1700, 0, 0, 0, 0, 0, 0, 0).pack(mav))[0]
    log = DeliveryLog()
    log.note(split_datagram(held.corrupted(random.Random(3)))[0], TO_VEHICLE)
    assert log.frames[TO_VEHICLE] == 1 and log.held_overrides() == {}
    log.note(held, TO_VEHICLE)
    assert log.held_overrides() == {1: 1700}
