"""The simulator's lockstep (sim/lockstep.py, docs/PROTOCOL.md "Lockstep"): vehicle time
waits at its start for the companion, and input acts at the last tick the companion allowed, never
at whatever tick the simulator happened to read it — so a rehearsal is a function of its seed."""
from __future__ import annotations

import pytest

import socket
import time

from pymavlink import mavutil

from sim.lockstep import SILENCE_S, Lockstep

mav = mavutil.mavlink
PERIOD_MS = 50  # ATTITUDE at SR_ATT_HZ = 20 Hz


def next_attitude(conn, wall_s: float = 5.0):
    deadline = time.monotonic() + wall_s
    while time.monotonic() < deadline:
        msg = conn.recv_match(type="ATTITUDE", blocking=True, timeout=0.2)
        if msg is not None:
            return msg
    return None


def acknowledge(conn, time_ms: int) -> None:
    conn.mav.system_time_send(0, time_ms)


def test_vehicle_time_waits_for_the_first_acknowledgement_then_for_each_one(sim_factory, mav_client):
    sim = sim_factory(transport="tcp", speedup=50, lockstep=True)
    companion = mav_client(sim.endpoint, source_system=1, source_component=191)  # greeted at once
    assert next_attitude(companion, 1.0) is None  # 1 s of wall clock = 50 s at 50x: nothing ran
    acknowledge(companion, 0)
    first = next_attitude(companion).time_boot_ms
    assert first <= PERIOD_MS
    assert next_attitude(companion, 0.5) is None  # one period past the acknowledgement, no further
    acknowledge(companion, first)
    assert next_attitude(companion).time_boot_ms == first + PERIOD_MS
    assert next_attitude(companion, 0.5) is None


def test_input_acts_at_the_limit_whatever_the_wall_clock_delay(sim_factory, mav_client):
    """A request sent after acknowledging sample A is answered at A + one period, however long the
    companion took to send it: at 1x the simulator is still on its way there when it arrives (the
    old lockstep answered it at whatever tick it had reached)."""
    sim = sim_factory(transport="tcp", speedup=1, lockstep=True)
    companion = mav_client(sim.endpoint, source_system=1, source_component=191)
    acknowledge(companion, 0)
    sample = next_attitude(companion).time_boot_ms
    answered = []
    for delay_s in (0.0, 0.02, 0.035):
        acknowledge(companion, sample)
        time.sleep(delay_s)
        companion.mav.command_long_send(1, 1, mav.MAV_CMD_REQUEST_MESSAGE, 0, mav.MAVLINK_MSG_ID_SYSTEM_TIME,
                                        0, 0, 0, 0, 0, 0)
        reply = attitude = None
        deadline = time.monotonic() + 5.0
        while (reply is None or attitude is None) and time.monotonic() < deadline:
            msg = companion.recv_match(type=["SYSTEM_TIME", "ATTITUDE"], blocking=True, timeout=0.2)
            if msg is not None and msg.get_type() == "ATTITUDE":
                attitude = msg
            elif msg is not None and msg.time_boot_ms > sample:  # the reply (the 1 Hz stream is at t = 1.01 s)
                reply = msg
        answered.append(reply.time_boot_ms - sample)
        sample = attitude.time_boot_ms
    assert answered == [PERIOD_MS] * 3


@pytest.mark.slow
def test_a_burst_left_queued_by_a_full_socket_still_reaches_the_companion(sim_factory):
    """Frames a full TCP socket did not take must drain although, in lockstep, no new frame follows
    until the companion has read them (found under load: a rehearsal stopped with LinkLost, the
    simulator waiting for an acknowledgement of a sample still queued behind a burst of replies)."""
    sim = sim_factory(transport="tcp", speedup=50, lockstep=True)
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # before connect: a small window
    sock.connect(("127.0.0.1", sim.port))
    sock.settimeout(0.2)
    mavlink = mav.MAVLink(None, srcSystem=1, srcComponent=191)
    mavlink.robust_parsing = True

    def attitudes(wall_s: float) -> list[int]:
        stamps: list[int] = []
        deadline = time.monotonic() + wall_s
        while time.monotonic() < deadline:
            try:
                data = sock.recv(65536)
            except socket.timeout:
                continue
            for msg in mavlink.parse_buffer(data) or []:
                if msg.get_type() == "ATTITUDE":
                    stamps.append(msg.time_boot_ms)
        return stamps

    try:
        sock.sendall(mavlink.system_time_encode(0, 0).pack(mavlink))
        first = attitudes(1.0)[0]
        burst = b"".join(mavlink.param_request_list_encode(1, 1).pack(mavlink) for _ in range(150))  # ~100 kB back
        time.sleep(0.3)
        sock.sendall(burst + mavlink.system_time_encode(0, first).pack(mavlink))
        time.sleep(1.0)  # the replies fill both socket buffers before we read
        assert attitudes(3.0) == [first + PERIOD_MS]
    finally:
        sock.close()


def test_interruptions_are_counted_only_when_a_companion_comes_back():
    lockstep = Lockstep(True, 0.01)
    assert lockstep.limit(0, 5, now=0.0) == 0  # waits at the start
    lockstep.acknowledge(0, 0, now=0.0, client="tcp-a")
    assert lockstep.limit(0, 5, now=1.0) == 5
    lockstep.client_left("tcp-a")  # disconnected: waits again where it is, not free
    assert lockstep.limit(5, 5, now=2.0) == 5
    lockstep.acknowledge(0, 5, now=2.0, client="tcp-b")  # a new companion engages from here
    assert lockstep.limit(5, 5, now=2.0) == 10
    assert lockstep.limit(10, 5, now=3.0 + SILENCE_S) is None  # silent: released, runs free
    lockstep.count_free(300)
    lockstep.acknowledge(4000, 310, now=40.0)
    assert lockstep.stats["engaged_at_s"] == 0.0
    assert (lockstep.stats["interruptions"], lockstep.stats["free_ticks"]) == (1, 300)
