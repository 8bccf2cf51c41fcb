"""Guarantees where the companion really lives: restores confirmed by the vehicle's state, a mode
change of its own however late it is seen, limits that fit the vehicle, a change by someone else
respected, a reboot recognised, a full disk said in a sentence (the crash-and-recover cases are in
tests/test_crash_recovery.py)."""
from __future__ import annotations

import math
import sqlite3
import time
from types import SimpleNamespace

import pytest

from companion.interface import SetThrust, Telemetry
from companion.link.profiles import ARDUROVER, ARDUSUB, SIM
from companion.procedures.limits import SafetyLimits
from companion.procedures.restore import RestorePoint
from companion.procedures.restore_items import NotConfirmed, StateCheck, set_and_confirm


# ---------------------------------------------------------------------------- restores by state
class ThrustVehicle:
    """A vehicle whose thrust output follows the set-points it receives, where the set-points it
    receives are scripted: ``late`` holds one the link delivers some samples after it was sent."""

    def __init__(self, thrust: float, late: tuple[float, int] | None = None, ignore: bool = False) -> None:
        self.thrust, self.late, self.ignore = thrust, late, ignore
        self.time_s = 100.0
        self.sent: list[float] = []
        self.clock = SimpleNamespace(lockstep=True)  # no wall-clock window: deterministic

    def execute(self, commands) -> None:
        for command in commands:
            assert isinstance(command, SetThrust)
            self.sent.append(command.thrust_level)
            if not self.ignore:
                self.thrust = command.thrust_level

    def await_setpoints(self) -> None:
        pass

    def skip_to_now(self) -> int:
        return 0

    def next_telemetry(self, timeout_s: float = 5.0) -> Telemetry:
        self.time_s += 0.05
        if self.late is not None:
            value, samples_left = self.late
            if samples_left == 0:
                self.thrust, self.late = value, None  # the procedure's set-point lands now
            else:
                self.late = (value, samples_left - 1)
        return Telemetry(time_s=self.time_s, thrust_ratio=self.thrust)


CHECK = StateCheck("thrust", lambda t: t.thrust_ratio, 0.70, 0.011)


def test_a_set_point_overtaken_by_a_late_one_is_sent_again_until_the_vehicle_holds_it():
    """The procedure's DO_CHANGE_SPEED 100 delivered after the restore's 70, both acknowledged alike:
    an acknowledgement cannot tell them apart, the thrust read back can."""
    vehicle = ThrustVehicle(thrust=1.0, late=(1.0, 3))
    set_and_confirm(vehicle, SetThrust(0.70), CHECK)
    assert vehicle.sent == [0.70, 0.70] and vehicle.thrust == pytest.approx(0.70)


def test_a_set_point_the_vehicle_never_shows_is_not_reported_restored():
    vehicle = ThrustVehicle(thrust=1.0, ignore=True)
    with pytest.raises(NotConfirmed, match="thrust reads 1.000"):
        set_and_confirm(vehicle, SetThrust(0.70), CHECK)


# ---------------------------------------------------------------------------- own mode seen late
def test_snapshots_older_than_the_companions_own_mode_change_are_not_a_takeover():
    """Over a lossy link the heartbeat that confirms the companion's own mode change comes late and
    snapshots queued before it still show the old mode: not someone else's change."""
    from companion.procedures.runner import _TakeoverWatchdog

    link = SimpleNamespace(profile=SIM, modes=SimpleNamespace(commanded_at_s=20.0), commanded_mode="hold")
    watchdog = _TakeoverWatchdog(SafetyLimits(mode_grace_s=1.0), link)
    watchdog.commanded([])
    old = [Telemetry(time_s=15.0 + 0.05 * i, mode="guided", armed=True) for i in range(80)]  # 4 s, before 20 s
    assert all(watchdog.check(t) is None for t in old)
    later = [Telemetry(time_s=20.1 + 0.05 * i, mode="guided", armed=True) for i in range(40)]
    assert any(watchdog.check(t) for t in later)  # after the confirmation, guided is someone else's


# ---------------------------------------------------------------------------- limits per vehicle
def test_a_boat_is_never_checked_on_a_depth_it_does_not_have():
    """ArduRover SITL's default home put a boat's GPS 'depth' at -584 m: every campaign aborted."""
    boat, auv = SafetyLimits.for_profile(ARDUROVER), SafetyLimits.for_profile(ARDUSUB)
    assert boat.max_depth is None and boat.violation(Telemetry(time_s=0.0, depth=-584.06)) is None
    assert "depth" in auv.violation(Telemetry(time_s=0.0, depth=-584.06))
    far = [Telemetry(time_s=float(i), north=10.0 + 2000.0 * i, east=0.0) for i in range(3)]
    unlimited = boat.watch()
    assert all(unlimited.check(t) is None for t in far)  # a campaign's straight runs: not limited unless asked
    watch = SafetyLimits.for_profile(ARDUROVER, max_distance_m=500.0).watch()
    assert watch.check(Telemetry(time_s=0.0, north=10.0, east=0.0)) is None
    assert watch.check(Telemetry(time_s=1.0, north=400.0, east=0.0)) is None
    assert "from where the procedure started" in watch.check(Telemetry(time_s=2.0, north=10.0, east=520.0))


def test_a_boat_has_no_depth_from_its_gps_altitude():
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    from companion.link.snapshot import TelemetryAssembler

    assembler = TelemetryAssembler(ARDUROVER)
    assembler.on_message(mavlink.MAVLink_global_position_int_message(1000, 0, 0, 584060, 584060, 0, 0, 0, 0))
    snapshot = assembler.on_message(mavlink.MAVLink_attitude_message(1000, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))
    assert math.isnan(snapshot.depth)


# ---------------------------------------------------------------------------- a full disk
def test_a_full_disk_is_a_sentence_and_the_store_keeps_what_it_had(tmp_path):
    from companion.records.store import Store, StoreError

    path = tmp_path / "s.sqlite"
    with Store(path) as store:
        vehicle = store.add_vehicle("v")
        campaign = store.start_campaign(vehicle, "identification")
        trail = store.save_restore_point(campaign, {"mode": "hold"}, {})
        store._db.execute("PRAGMA max_page_count = %d" % store._db.execute("PRAGMA page_count").fetchone()[0])
        with pytest.raises(StoreError, match="the disk is full"):
            for _ in range(200):
                store.add_change(trail, 1.0, "SetParameters", {"values": {"x" * 500: 1.0}})
    db = sqlite3.connect(path)
    assert db.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    assert db.execute("SELECT status FROM campaigns").fetchone()[0] == "running"  # nothing half-written


def test_a_full_disk_during_a_campaign_ends_it_restored_with_the_reason(tmp_path):
    from companion.procedures.app import AbortFlag, run_campaign
    from companion.procedures.campaign import CampaignConfig
    from companion.records.store import Store
    from harness.inprocess import InProcessLink

    link = InProcessLink(seed=2)
    found = {name: link.param(name) for name in ("heading_p", "heading_i", "rudder_trim")}
    with Store(tmp_path / "s.sqlite") as store:
        vehicle = store.add_vehicle("v")
        limit = store._db.execute("PRAGMA page_count").fetchone()[0] + 2
        store._db.execute(f"PRAGMA max_page_count = {limit}")
        config = CampaignConfig(thrusts=(0.7,), axes=("yaw",)).quick()
        campaign, outcome, _ = run_campaign(link, store, config, vehicle_id=vehicle, abort=AbortFlag())
    assert outcome.status == "aborted" and "disk is full" in outcome.reason
    assert {name: link.param(name) for name in found} == found and not link.overrides


# ---------------------------------------------------------------------------- over MAVLink
pytestmark_e2e = pytest.mark.e2e


def _gcs(sim):
    """A ground station on the simulator (kept open: in lockstep what it sends acts at the next
    vehicle tick the companion allows, which may come after a wall-clock wait)."""
    from harness.mavlink_clients import connect_client

    return connect_client(sim.endpoint)


@pytest.mark.e2e
def test_a_parameter_someone_else_changes_is_kept_and_said(sim_factory, tmp_path):
    """A ground station sets HDG_P in the middle of a campaign: the campaign stops, the restore puts
    every other parameter back and keeps the ground station's value, and says so."""
    from companion.link.vehicle import VehicleLink
    from companion.procedures.app import AbortFlag, run_campaign
    from companion.procedures.campaign import CampaignConfig
    from companion.records.store import Store

    sim = sim_factory(transport="tcp", speedup=20, seed=3, lockstep=True)  # the closed loop at a fixed pace
    link = VehicleLink.connect(sim.endpoint, lockstep=True)
    gcs = _gcs(sim)
    try:
        link.set_mode("hold")
        link.arm(True)
        found = {name: link.get_param(name) for name in ("HDG_I", "HDG_TRIM")}

        class ChangeAtSettle(AbortFlag):
            def __call__(self):
                if not self.done and link.vehicle_time_s - start > 6.0:
                    self.done = True
                    gcs.mav.param_set_send(1, 1, b"HDG_P", 0.9, 9)
                return None

        abort = ChangeAtSettle()
        abort.done, start = False, link.vehicle_time_s
        with Store(tmp_path / "s.sqlite") as store:
            config = CampaignConfig(thrusts=(0.7,), axes=("yaw",)).quick()
            _, outcome, _ = run_campaign(link, store, config, vehicle_id=store.add_vehicle("v"), abort=abort)
        assert outcome.status == "aborted" and "HDG_P was changed to 0.9 by someone else" in outcome.reason
        assert outcome.restore_problems == []
        assert any(note.startswith("HDG_P: kept 0.9") for note in outcome.restore_notes)
        assert link.get_param("HDG_P") == pytest.approx(0.9)
        assert {name: link.get_param(name) for name in found} == found
    finally:
        gcs.close()
        link.close()


@pytest.mark.e2e
def test_a_reboot_is_recognised_and_the_new_boot_keeps_its_own_mode(sim_factory, tmp_path):
    """The autopilot reboots during the step checks (trial gains on it): the procedure stops on the
    reboot, the parameters (kept in its flash) are put back, the freshly booted vehicle's mode and
    set-points are left alone, and the outcome says so."""
    from companion.link.vehicle import VehicleLink
    from companion.procedures.app import AbortFlag, run_campaign
    from companion.procedures.campaign import CampaignConfig
    from companion.records.store import Store

    sim = sim_factory(transport="tcp", speedup=20, seed=3, lockstep=True)  # the reboot lands at a fixed vehicle time
    link = VehicleLink.connect(sim.endpoint, lockstep=True)
    try:
        link.set_mode("hold")
        link.arm(True)
        found = {name: link.get_param(name) for name in ("HDG_P", "HDG_I", "HDG_TRIM")}

        class RebootInTheChecks(AbortFlag):
            def __call__(self):
                if not self.sent and link.parameters.cache.get("HDG_P") != found["HDG_P"]:
                    self.sent = True  # trial gains are on the vehicle: reboot it
                    link.transport.command_long(246, (1.0,))
                return None

        abort = RebootInTheChecks()
        abort.sent = False
        with Store(tmp_path / "s.sqlite") as store:
            config = CampaignConfig(thrusts=(0.7,), axes=("yaw",)).quick()
            _, outcome, _ = run_campaign(link, store, config, vehicle_id=store.add_vehicle("v"), abort=abort)
        assert abort.sent
        assert outcome.status == "aborted" and "rebooted" in outcome.reason
        assert any("rebooted" in note for note in outcome.restore_notes)
        assert {name: link.get_param(name) for name in found} == found  # parameters back
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline and link.announcements.heartbeat_count < 3:
            link.next_telemetry()
        assert link.mode == "manual" and not link.armed  # the new boot's own: never switched
    finally:
        link.close()


def test_an_autopilot_that_restarts_is_named_a_reboot_not_a_lost_link():
    """The autopilot process dies and comes back: the procedure first sees silence (LinkLost), then
    the restore finds the new boot. The headline says reboot; before, it said only the lost link."""
    from behaviors.base import Behaviour
    from companion.link.errors import LinkLost
    from harness.port_stub import PortStub
    from companion.procedures.runner import RestorePoint, run_procedure

    class Waiting(Behaviour):
        def update(self, telemetry):
            return []

    link = PortStub()
    clock = link.clock
    samples = iter([Telemetry(time_s=1.0, roll=0.0, pitch=0.0, yaw=0.0, mode="hold", armed=True)])

    def next_telemetry(timeout_s=5.0):
        try:
            return next(samples)
        except StopIteration:
            clock.reboots = 1  # what the link sees once it hears the vehicle again: a new boot
            raise LinkLost("no telemetry snapshot for 5 s") from None

    link.next_telemetry = next_telemetry  # type: ignore[method-assign]
    outcome = run_procedure(link, Waiting(), restore=RestorePoint(mode=None, boot=0))
    assert outcome.status == "aborted"
    assert outcome.reason.startswith("the autopilot rebooted during the procedure")
    assert "LinkLost" in outcome.reason  # how it was first seen stays in the sentence


def test_a_restore_the_vehicle_refused_leaves_the_trail_open_for_recover(tmp_path):
    """The vehicle refuses the restore's writes of HDG_P (its trial value stays): the outcome lists
    the problem, the trail stays open, and once the process is gone the next start puts HDG_P back
    (before, the trail was closed and `recover` said there was nothing to recover)."""
    import subprocess
    import sys

    from behaviors.base import Behaviour, Footprint
    from companion.interface import SetParameters
    from companion.procedures.runner import run_procedure
    from companion.procedures.trail import TrailRecorder, interrupted, recover, vehicle_identity
    from companion.records.store import Store
    from harness.inprocess import InProcessLink

    link = InProcessLink(seed=2)
    found = link.param("heading_p")

    class TrialGains(Behaviour):
        footprint = Footprint.of(parameters=("heading_p",))

        def update(self, telemetry):
            if telemetry.time_s > 1.0:
                link.refuse.add("HDG_P")  # from now on the vehicle drops every write of HDG_P
                self.finish()
            return [SetParameters({"heading_p": 0.9})]

    with Store(tmp_path / "s.sqlite") as store:  # as run_named_procedure runs a procedure
        procedure = TrialGains()
        restore = RestorePoint.capture(link, procedure.footprint)
        campaign = store.start_campaign(store.add_vehicle("v"), "trial")
        trail_id = store.save_restore_point(campaign, restore.as_json(), vehicle_identity(link))
        recorder = TrailRecorder(store, trail_id, link)
        outcome = run_procedure(link, procedure, restore=restore, on_change=recorder)
        recorder.close()
        store.finish_restore(trail_id, outcome.restore_problems, outcome.restore_notes)
        assert any("HDG_P" in problem for problem in outcome.restore_problems)
        assert link.param("heading_p") == pytest.approx(0.9)
        (open_trail,) = store.open_trails()
        child = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
        store._db.execute("UPDATE trails SET owner_pid=?, owner_started=?", (int(child.stdout), "1"))
        store._db.commit()
        link.refuse.clear()
        (trail,) = interrupted(store)
        recovery = recover(link, store, trail, decide=lambda differences: True)
    assert recovery.complete and link.param("heading_p") == pytest.approx(found)
