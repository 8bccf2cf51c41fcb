"""End to end: companion.link.VehicleLink against the simulator subprocess over TCP loopback (lockstep),
sped up (shared fixture ``module_sim_factory`` from conftest.py). One simulator and one link for
the module; the tests run in file order and each leaves the vehicle in a known mode."""
from __future__ import annotations

import json
import math
import time

import pytest

from companion.interface import SetRollingMass
from companion.link import param_codec as pc
from companion.link.errors import CommandFailed, ParamRefused
from companion.link.vehicle import VehicleLink

pytestmark = pytest.mark.e2e
SPEEDUP = 50.0


@pytest.fixture(scope="module")
def sim(module_sim_factory):
    # TCP and lockstep: the vehicle waits for the companion, so a companion descheduled on a loaded
    # machine neither loses samples nor falls behind the override and expiry times these tests measure
    return module_sim_factory(speedup=SPEEDUP, seed=3, transport="tcp", lockstep=True)


@pytest.fixture(scope="module")
def link(sim):
    link = VehicleLink.connect(sim.endpoint, heartbeat_timeout_s=10.0, lockstep=True)
    yield link
    link.close()


def run_for(link: VehicleLink, vehicle_seconds: float) -> list:
    """Snapshots over the next ``vehicle_seconds`` of vehicle time from now (the backlog queued
    during earlier blocking calls is skipped: it predates what the test just did)."""
    link.skip_to_now()
    first = link.next_telemetry()
    samples = [first]
    while samples[-1].time_s - first.time_s < vehicle_seconds:
        samples.append(link.next_telemetry())
    return samples


def mean(values) -> float:
    values = list(values)
    return sum(values) / len(values)


def test_connect_identifies_the_simulated_vehicle(link):
    assert link.profile.name == "sim" and link.transport.system_id == 1 and link.transport.component == 191
    assert link.ground.gcs_sysid == 255 and link.override_timeout_s == pytest.approx(3.0)
    capabilities = link.announcements.capabilities
    assert capabilities is not None and capabilities & pc.CAPABILITY_PARAM_ENCODE_C_CAST
    assert link.parameters.int_encoding == "cast"


def test_vehicle_time_runs_faster_than_wall_time(link):
    link.skip_to_now()
    wall_start = time.monotonic()
    samples = [link.next_telemetry()]
    while time.monotonic() - wall_start < 0.5:
        samples.append(link.next_telemetry())
    wall = time.monotonic() - wall_start
    vehicle = samples[-1].time_s - samples[0].time_s
    assert vehicle > 5.0 * wall  # sped up (nominally 50x; loose because the machine is shared)
    steps = [b.time_s - a.time_s for a, b in zip(samples, samples[1:])]
    assert min(steps) > 0.0  # strictly increasing vehicle clock
    assert len(steps) / vehicle == pytest.approx(20.0, rel=0.15)  # SR_ATT_HZ, vehicle time
    last = samples[-1]
    assert last.finite("roll", "pitch", "yaw", "yaw_rate", "depth", "rudder", "thrust_ratio", "speed_water")


def test_gain_write_is_read_back(link):
    original = link.get_params(["heading_p"])["heading_p"]
    try:
        confirmed = link.set_params({"heading_p": 0.8765})
        assert confirmed == {"heading_p": pc.float32(0.8765)}
        assert link.get_param("HDG_P") == pc.float32(0.8765)
    finally:
        link.set_params({"heading_p": original})
    assert link.get_param("HDG_P") == original


def test_bad_writes_are_reported_as_refused(link):
    before = link.get_param("HDG_P")
    with pytest.raises(ParamRefused):
        link.set_param("NO_SUCH_PARAM", 1.0)
    with pytest.raises(ParamRefused):
        link.set_param("HDG_P", float("nan"))
    with pytest.raises(ParamRefused):
        link.set_param("HDG_P", 500.0)  # outside the simulator's bounds: echo unchanged + warning
    assert link.get_param("HDG_P") == before


def test_mode_change_is_verified_by_heartbeat(link):
    link.set_mode("guided")
    assert link.mode == "guided"
    link.set_mode("manual")
    assert link.mode == "manual"
    assert run_for(link, 1.5)[-1].mode == "manual"


def test_rolling_mass_moves_and_function_channels_are_refused(link):
    with pytest.raises(CommandFailed):
        link.commands.set_servo(1, 1600, wait=True)  # the rudder output has a function: denied
    link.arm(True)
    assert link.armed
    link.execute([SetRollingMass(0.2)])
    assert run_for(link, 4.0)[-1].mass_angle == pytest.approx(0.2, abs=0.01)
    link.execute([SetRollingMass(0.0)])


def test_rudder_override_in_hold_turns_then_autopilot_takes_back(link):
    link.arm(True)
    link.set_mode("hold")
    settle = run_for(link, 25.0)  # cruise thrust: reach speed on the held heading
    assert settle[-1].speed_water > 0.8
    assert abs(mean(s.yaw_rate for s in settle[-40:])) < 0.01

    link.overrides.override("rudder", 0.15)
    held = run_for(link, 6.0)
    assert all(s.mode == "hold" for s in held)
    assert held[-1].rudder == pytest.approx(0.15, abs=0.01)  # open loop on the rudder
    turn_rate = mean(s.yaw_rate for s in held[-40:])
    assert abs(turn_rate) > 0.05  # the yaw rate answers the rudder
    assert math.isfinite(held[-1].depth)

    link.release("rudder")
    after = run_for(link, 30.0)
    # the autopilot steers back: rudder against the turn, then the turn stops
    assert min(s.rudder * math.copysign(1.0, turn_rate) for s in after[:60]) < -0.05
    assert abs(mean(s.yaw_rate for s in after[-40:])) < 0.02


def test_override_expires_when_not_refreshed(link):
    # its own start, whatever ran before it on this worker's shared vehicle
    link.set_mode("hold")
    link.arm(True)
    timeout = link.override_timeout_s
    try:
        link.skip_to_now()
        start = link.next_telemetry().time_s
        link.overrides.override("rudder", 0.15, keep_alive=False)  # sent once, never refreshed
        # every snapshot from the send on, queued ones included: a companion running behind on a
        # loaded machine must not skip the override's whole life (run_for drops the backlog)
        samples = [link.next_telemetry()]
        while samples[-1].time_s - start < timeout + 4.0:
            samples.append(link.next_telemetry())
        # measured from when the rudder got there (the link may see the vehicle a little late)
        onset = next(s.time_s for s in samples if abs(s.rudder - 0.15) < 0.01)
        during = [s for s in samples if onset <= s.time_s <= onset + timeout - 0.7]
        later = [s for s in samples if s.time_s >= onset + timeout + 1.0]
        assert len(during) > 20 and all(s.rudder == pytest.approx(0.15, abs=0.01) for s in during)
        assert later and all(abs(s.rudder - 0.15) > 0.05 for s in later)  # the autopilot took it back
    finally:
        link.set_mode("manual")
        link.arm(False)


def status_main(argv: list[str]) -> int:
    """``companion status`` through its own subparser (the full CLI imports every subcommand)."""
    import argparse

    from companion.cli.commands import status

    parser = argparse.ArgumentParser()
    status.add_parser(parser.add_subparsers())
    args = parser.parse_args(argv)
    return args.func(args)


def test_status_command_prints_json(sim, link, capsys):
    import threading

    link.set_mode("manual")  # its own start, whatever ran before it on this worker's shared vehicle
    # in lockstep the vehicle only moves on while the link acknowledges: keep it reading meanwhile
    answer: list[int] = []
    status = threading.Thread(target=lambda: answer.append(status_main(["status", "--connect", sim.endpoint,
                                                                         "--json"])))
    status.start()
    while status.is_alive():
        link.next_telemetry()
    assert answer == [0]
    record = json.loads(capsys.readouterr().out)
    assert record["profile"] == "sim" and record["mode"] == "manual" and record["vehicle_time_s"] > 0
    assert set(record["attitude_deg"]) == {"roll", "pitch", "yaw"}


def test_status_command_fails_clearly_when_nothing_answers(capsys):
    from harness.mavlink_clients import free_port

    assert status_main(["status", "--connect", f"udpout:127.0.0.1:{free_port()}", "--timeout", "0.5"]) == 1
    assert "no autopilot HEARTBEAT" in capsys.readouterr().err


def test_a_simulator_killed_under_a_tcp_link_is_link_loss_not_a_print_loop(sim_factory, capfd):
    """EOF on TCP becomes LinkLost at once; pymavlink prints nothing to stdout."""
    import os
    import signal

    from companion.link.errors import LinkLost
    from companion.link.vehicle import VehicleLink

    sim = sim_factory(transport="tcp", speedup=20)
    link = VehicleLink.connect(sim.endpoint)
    link.next_telemetry()
    os.kill(sim.process.pid, signal.SIGKILL)
    sim.process.wait()
    with pytest.raises(LinkLost):
        for _ in range(10000):
            link.next_telemetry(timeout_s=5.0)
    with pytest.raises(LinkLost):
        link.get_param("HDG_P", retries=1)
    link.close()
    assert "EOF on TCP socket" not in capfd.readouterr().out
