"""Safety paths found in review: the autopilot is left as found, whatever stops a procedure."""
from __future__ import annotations

from dataclasses import replace


from behaviors.identification import ManoeuvreConfig
from companion.procedures.app import AbortFlag, GcsProgress, run_campaign
from companion.procedures.app import run_named_behavior
from companion.procedures.roll import RollProcedureConfig, roll_procedure
from companion.procedures.campaign import CampaignConfig
from companion.link.profiles import ARDUROVER
import pytest

from behaviors.base import Footprint
from companion.procedures.runner import RestorePoint, RunOutcome
from companion.records.store import Store
from harness.inprocess import InProcessLink
from harness.port_stub import PortStub
from pymavlink.dialects.v20.common import MAV_RESULT_FAILED

SHORT = CampaignConfig(thrusts=(0.7, 1.0), axes=("yaw",), step_labels=("scheduled",),
                       yaw=ManoeuvreConfig(settle_s=12.0, resettle_s=10.0))


class CascadedFake(PortStub):
    """An ArduRover-like parameter store behind the link API (no vehicle needed for restore points)."""

    def __init__(self, fail: set[str] = frozenset()) -> None:
        super().__init__(ARDUROVER)
        self.params = {"ATC_STR_ANG_P": 2.0, "ATC_STR_RAT_P": 0.2, "ATC_STR_RAT_I": 0.2, "ATC_STR_RAT_D": 0.01,
                       "ATC_STR_RAT_FF": 0.2, "ATC_STR_RAT_IMAX": 1.0}
        self.fail = set(fail)
        self.writes: list[str] = []

    def get_param(self, name):
        return self.params[name]

    def set_param(self, name, value):
        if name in self.fail:
            raise RuntimeError(f"{name} refused")
        self.writes.append(name)
        self.params[name] = value
        return value

    def get_params(self, names):
        return {n: 0.0 for n in names}

    def release(self, actuator=None):
        pass

    def set_mode(self, mode):
        self.mode = mode


#: what a cascaded heading-gain procedure declares it touches (the restore point is derived from it)
HEADING_GAINS = Footprint.of(parameters=("heading_angle_p", "heading_rate_p", "heading_rate_i", "heading_rate_d",
                                         "heading_rate_ff", "heading_rate_imax"))


def test_restore_gives_back_every_native_parameter_of_a_cascaded_autopilot():
    link = CascadedFake()
    found = dict(link.params)
    restore = RestorePoint.capture(link, HEADING_GAINS)
    link.params.update({"ATC_STR_ANG_P": 3.0, "ATC_STR_RAT_D": 0.0, "ATC_STR_RAT_FF": 0.0})  # what a design writes
    assert restore.restore(link) == []
    assert link.params == found
    assert sorted(link.writes) == ["ATC_STR_ANG_P", "ATC_STR_RAT_D", "ATC_STR_RAT_FF"]  # only what changed


def test_one_failing_parameter_does_not_stop_the_restore():
    link = CascadedFake(fail={"ATC_STR_ANG_P"})
    restore = RestorePoint.capture(link, HEADING_GAINS)
    link.params.update({"ATC_STR_ANG_P": 3.0, "ATC_STR_RAT_FF": 0.0})
    problems = restore.restore(link)
    assert len(problems) == 1 and "ATC_STR_ANG_P" in problems[0]
    assert link.params["ATC_STR_RAT_FF"] == 0.2


def test_a_mode_the_profile_does_not_name_is_restored_by_number():
    assert ARDUROVER.mode_number("custom_11") == 11


def _run(link, config=SHORT, abort=None):
    with Store(":memory:") as store:
        return run_campaign(link, store, config, vehicle_id=store.add_vehicle("v"), abort=abort or AbortFlag())


def test_pilot_switching_to_manual_aborts_and_the_companion_does_not_fight_back():
    link = InProcessLink(seed=2)
    original_step = link.next_telemetry

    def pilot(timeout_s=5.0):
        telemetry = original_step(timeout_s)
        if 25.0 <= telemetry.time_s < 25.06:
            link.simulated.set_mode(19)  # the pilot takes MANUAL during the first doublet
        return telemetry

    link.next_telemetry = pilot
    _, outcome, _ = _run(link)
    assert outcome.status == "aborted" and "mode changed to manual" in outcome.reason
    assert link.mode_changes.count("guided") == 0  # no hold re-engagement against the pilot
    assert link.mode == "manual"  # the pilot's mode stands: the restore does not switch back
    assert not link.overrides


def test_disarming_aborts():
    link = InProcessLink(seed=2)
    original_step = link.next_telemetry

    def disarm(timeout_s=5.0):
        telemetry = original_step(timeout_s)
        if telemetry.time_s >= 20.0:
            link.simulated.arm(False)
        return telemetry

    link.next_telemetry = disarm
    _, outcome, _ = _run(link)
    assert outcome.status == "aborted" and "disarmed" in outcome.reason


def test_a_disarmed_vehicle_is_refused_at_once():
    link = InProcessLink(seed=2)
    link.simulated.arm(False)
    _, outcome, _ = _run(link)
    assert outcome.status == "aborted" and "not armed" in outcome.reason and outcome.samples == 1


def test_designing_without_writing_leaves_the_found_gains():
    link = InProcessLink(seed=2)
    found = {n: link.param(n) for n in ("heading_p", "heading_i", "rudder_trim")}
    campaign, outcome, _ = _run(link, replace(SHORT, write_gains=False))
    assert outcome.status == "completed" and campaign.final_gains is None
    assert link.param_writes  # the step checks did write trial gains ...
    assert {n: link.param(n) for n in found} == found  # ... and they were given back


def test_a_refused_simulator_hook_keeps_the_measured_data_and_closes_the_record():
    link = InProcessLink(seed=2, refuse={"SIM_ROLL_KICK"})
    config = RollProcedureConfig(settle_s=5.0, open_s=10.0, closed_s=15.0)
    with Store(":memory:") as store:
        out = run_named_behavior("roll", link, store, vehicle_id=store.add_vehicle("v"), campaign_id=None,
                                 abort=AbortFlag(), simulator=True, config=config)
        # a refused write aborts the procedure with the reason (never a warning that carries on)
        result = out.result
        assert result.status == "aborted" and "SIM_ROLL_KICK" in result.reason
        assert result.figures.std_open_deg > 0 and result.figures.std_closed_deg > 0  # measured before
        assert store.campaigns()[0]["status"] == "aborted"
        assert store.behavior_results()[0]["kind"] == "roll"
    assert link.simulated.params["SIM_ROLL_DIST"] == 0.0  # the disturbance hook is switched off again
    assert link.mode == "hold"


def test_roll_procedure_leaves_the_mode_it_found():
    link = InProcessLink(seed=2)
    link.simulated.set_mode(4)  # found in GUIDED
    result = roll_procedure(link, AbortFlag(), RollProcedureConfig(settle_s=5.0, open_s=10.0, closed_s=10.0,
                                                                     kick_deg=0.0), simulator=True).to_json()
    assert result["status"] == "completed" and link.mode == "guided"


def test_a_failure_before_any_progress_is_still_acknowledged():
    class Recorder:
        acks: list = []

        def send_command_ack(self, command, result, progress, *_):
            self.acks.append((command, result, progress))

        @property
        def ground(self):
            return self

    link = Recorder()
    GcsProgress(link, 31010).finish(RunOutcome("aborted", "link lost", {}))
    assert link.acks == [(31010, MAV_RESULT_FAILED, 0)]


def test_pilot_takeover_during_roll_stabilisation_keeps_the_pilots_mode():
    link = InProcessLink(seed=2)
    original_step = link.next_telemetry

    def pilot(timeout_s=5.0):
        telemetry = original_step(timeout_s)
        if 20.0 <= telemetry.time_s < 20.06:
            link.simulated.set_mode(19)
        return telemetry

    link.next_telemetry = pilot
    result = roll_procedure(link, AbortFlag(), RollProcedureConfig(settle_s=5.0, open_s=10.0, closed_s=30.0,
                                                                     kick_deg=0.0), simulator=True).to_json()
    assert result["status"] == "aborted" and result["pilot_has_it"]
    assert link.mode == "manual" and link.simulated.mass_angle_demand == 0.0


@pytest.mark.parametrize("name, why", [("roll", "rolling mass"), ("min_speed", "depth loop")])
def test_a_procedure_that_does_not_apply_refuses_with_the_reason(name, why):
    """Roll stabilisation without a rolling mass, minimum-speed seeking on a boat: refused, never completed."""
    link = CascadedFake()  # an ArduRover boat: no mass servo, no elevator, no depth set-point
    link.status_text = lambda text, severity=6: None
    with Store(":memory:") as store:
        out = run_named_behavior(name, link, store, vehicle_id=store.add_vehicle("boat"), campaign_id=None,
                                 abort=AbortFlag(), simulator=False)
        assert out.result.status == "refused" and why in out.result.reason and out.outcome is None
        assert out.summary["status"] == "refused"
        assert store.campaigns()[0]["status"] == "refused"


def test_a_second_companion_on_the_vehicle_stops_the_procedure_and_the_vehicle_is_restored(sim_factory, mav_client,
                                                                                          tmp_path):
    """Two companions flying one vehicle. Another onboard controller's HEARTBEAT on our
    component id (191) aborts the procedure with that reason; everything is put back as found."""
    import threading

    from companion.link.vehicle import VehicleLink
    from behaviors.schedules import GAIN_SCHEDULES  # noqa: F401 - the campaign's schedules load
    from pymavlink import mavutil

    sim = sim_factory(transport="tcp", speedup=20.0, seed=4, lockstep=True)
    link = VehicleLink.connect(sim.endpoint, heartbeat_timeout_s=10.0, lockstep=True)
    other = mav_client(sim.endpoint, source_system=1, source_component=191)
    stop = threading.Event()

    def second_companion() -> None:  # announces itself as a companion does, about every vehicle second
        while not stop.wait(0.05):
            other.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavutil.mavlink.MAV_AUTOPILOT_INVALID,
                                     0, 0, mavutil.mavlink.MAV_STATE_ACTIVE)

    try:
        link.set_mode("hold")
        link.arm(True)
        found = link.get_params(["heading_p", "heading_i"]), link.mode
        thread = threading.Thread(target=second_companion, daemon=True)
        thread.start()
        with Store(tmp_path / "s.sqlite") as store:
            _campaign, outcome, _ = run_campaign(link, store, SHORT, vehicle_id=store.add_vehicle("v"),
                                                 abort=AbortFlag())
        assert outcome.status == "aborted"
        assert "another companion (system 1, component 191)" in outcome.reason
        assert outcome.restore_problems == []
        assert link.get_params(["heading_p", "heading_i"]) == found[0]
        assert link.mode == found[1] and not link.overrides.active
    finally:
        stop.set()
        link.close()
