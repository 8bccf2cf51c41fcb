"""End to end: a ground station starts and aborts procedures on the resident companion
(``companion run``) with COMMAND_LONG aimed at component 191, routed through the simulator like
through an autopilot (SPEC C1: COMMAND_ACK IN_PROGRESS with progress, then ACCEPTED or FAILED)."""
from __future__ import annotations

import subprocess
import sys
import time

import pytest
from pymavlink.dialects.v20.common import MAV_RESULT_ACCEPTED as ACCEPTED
from pymavlink.dialects.v20.common import MAV_RESULT_FAILED as FAILED
from pymavlink.dialects.v20.common import MAV_RESULT_IN_PROGRESS as IN_PROGRESS

from harness.mavlink_clients import arm_and_see_it

pytestmark = pytest.mark.e2e

MAV_CMD_USER_1, MAV_CMD_USER_3, MAV_CMD_USER_4 = 31010, 31012, 31013


def acks_for(gcs, command: int, until, timeout_s: float) -> list[tuple[int, int]]:
    """(result, progress) of the COMMAND_ACKs for ``command`` from component 191 until ``until``."""
    seen: list[tuple[int, int]] = []
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and not until(seen):
        msg = gcs.recv_match(type="COMMAND_ACK", blocking=True, timeout=0.5)
        if msg is not None and msg.command == command and msg.get_srcComponent() == 191 \
                and getattr(msg, "target_system", 0) in (0, gcs.mav.srcSystem):
            seen.append((msg.result, msg.progress))
    return seen


@pytest.fixture
def companion(sim_factory, tmp_path):
    # lockstep: the closed loops' outcomes (settled, accepted) are the vehicle's, not the machine's load
    sim = sim_factory(transport="tcp", speedup=20, seed=2, lockstep=True)
    process = subprocess.Popen([sys.executable, "-m", "companion", "run", "--connect", sim.endpoint, "--lockstep",
                                "--store", str(tmp_path / "store.sqlite"), "--max-vehicle-time", "600",
                                "--preset", "starfish"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    yield sim, process
    process.terminate()
    process.wait(timeout=20)


def start(gcs, command: int, param1: float = 0.0, timeout_s: float = 30.0) -> list[tuple[int, int]]:
    """Send a COMMAND_LONG to component 191 as a GCS does: retransmit (confirmation + 1) until the
    first COMMAND_ACK (the companion may still be connecting when its heartbeat first shows)."""
    deadline = time.monotonic() + timeout_s
    confirmation = 0
    while time.monotonic() < deadline:
        gcs.mav.command_long_send(1, 191, command, confirmation, param1, 0, 0, 0, 0, 0, 0)
        acks = acks_for(gcs, command, lambda seen: bool(seen), 2.0)
        if acks:
            return acks
        confirmation = min(confirmation + 1, 255)
    return []


arm = arm_and_see_it  # the shared step (harness.mavlink_clients)


def wait_for_companion(gcs, timeout_s: float = 20.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        msg = gcs.recv_match(type="HEARTBEAT", blocking=True, timeout=0.5)
        if msg is not None and msg.get_srcComponent() == 191:
            return
    raise AssertionError("no HEARTBEAT from the companion (component 191) through the simulator")


def test_a_disarmed_vehicle_is_refused(companion, mav_client):
    sim, process = companion
    gcs = mav_client(sim.endpoint)
    wait_for_companion(gcs)
    acks = start(gcs, MAV_CMD_USER_3, 20.0)
    assert acks and acks[0][0] == 1, acks  # TEMPORARILY_REJECTED: the simulator boots disarmed


@pytest.mark.slow
def test_user_3_runs_min_speed_seeking_and_reports(companion, mav_client):
    sim, process = companion
    gcs = mav_client(sim.endpoint)
    wait_for_companion(gcs)
    arm(gcs)
    first = start(gcs, MAV_CMD_USER_3, 60.0)  # 60 s of seeking: settled (the levelled start) -> ACCEPTED
    assert first and first[0][0] == IN_PROGRESS, first
    acks = acks_for(gcs, MAV_CMD_USER_3, lambda seen: seen and seen[-1][0] != IN_PROGRESS, 60.0)
    assert acks and acks[-1] == (ACCEPTED, 100), acks


def test_user_4_aborts_the_campaign(companion, mav_client):
    sim, process = companion
    gcs = mav_client(sim.endpoint)
    wait_for_companion(gcs)
    arm(gcs)
    started = start(gcs, MAV_CMD_USER_1)
    assert started and started[0][0] == IN_PROGRESS, started
    gcs.mav.command_long_send(1, 191, MAV_CMD_USER_4, 0, 0, 0, 0, 0, 0, 0, 0)
    final = acks_for(gcs, MAV_CMD_USER_1, lambda seen: seen and seen[-1][0] != IN_PROGRESS, 60.0)
    assert final and final[-1][0] == FAILED, final
    # the autopilot is back as found: the simulator boots in MANUAL with HDG_P at the preset's value
    gcs.mav.param_request_read_send(1, 1, b"HDG_P", -1)
    value = gcs.recv_match(type="PARAM_VALUE", blocking=True, timeout=10)
    assert value is not None and value.param_value == pytest.approx(0.64, abs=1e-6)


def test_a_stranger_cannot_start_a_procedure(companion, mav_client):
    """Procedure commands are obeyed only from the ground station's system id; another
    system gets DENIED and a STATUSTEXT, and nothing starts."""
    sim, process = companion
    gcs = mav_client(sim.endpoint)
    stranger = mav_client(sim.endpoint, source_system=77)
    wait_for_companion(gcs)
    arm(gcs)
    acks = start(stranger, MAV_CMD_USER_3, 20.0)
    assert acks and acks[0][0] == 2, acks  # MAV_RESULT_DENIED
    # nothing starts: no IN_PROGRESS follows (a retransmission the ground-station helper made while
    # the first answer was on its way is DENIED again, which is the same answer)
    later = acks_for(stranger, MAV_CMD_USER_3, lambda seen: any(r == IN_PROGRESS for r, _ in seen), 3.0)
    assert all(result == 2 for result, _ in later), later
    # the ground station itself is still obeyed
    first = start(gcs, MAV_CMD_USER_3, 5.0)
    assert first and first[0][0] == IN_PROGRESS, first


def test_a_procedure_longer_than_an_hour_is_refused(companion, mav_client):
    sim, process = companion
    gcs = mav_client(sim.endpoint)
    wait_for_companion(gcs)
    arm(gcs)
    start(gcs, MAV_CMD_USER_3, 1e30)
    final = acks_for(gcs, MAV_CMD_USER_3, lambda seen: seen and seen[-1][0] != IN_PROGRESS, 30.0)
    assert final and final[-1][0] == FAILED, final
