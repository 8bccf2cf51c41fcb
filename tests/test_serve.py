"""The resident loop (``companion run``) on the in-process autopilot: scheduling and ground-station
procedures started, reported and aborted by MAV_CMD_USER_1..4 (SPEC C1, C5)."""
from __future__ import annotations


import pytest

from behaviors.gain_scheduling import SchedulingConfig
from behaviors.heading_schedule import HEADING
from behaviors.identification import IdentificationAttempt
from companion.numerics.identification import YawModel
from behaviors.identification import ManoeuvreConfig
from companion.procedures.app import AbortFlag
from companion.procedures.min_speed import MinSpeedProcedureConfig
from companion.procedures.campaign import CampaignConfig
from companion.procedures.resident import Companion, ServeConfig, schedule_from_store
from companion.records.store import Store
from harness.inprocess import InProcessLink
from pymavlink.dialects.v20.common import (MAV_CMD_USER_1, MAV_CMD_USER_3, MAV_CMD_USER_4, MAV_RESULT_ACCEPTED, MAV_RESULT_FAILED, MAV_RESULT_IN_PROGRESS,
                                           MAV_RESULT_TEMPORARILY_REJECTED)

CAMPAIGN = CampaignConfig(thrusts=(0.7, 1.0), axes=("yaw",), step_labels=(),
                          yaw=ManoeuvreConfig(settle_s=12.0, resettle_s=10.0))


def stored_models(store: Store) -> None:
    """A completed campaign as the campaign stores it: its accepted runs and the design it wrote."""
    vehicle = store.add_vehicle("v")
    campaign = store.start_campaign(vehicle, "identification")
    attempts = [IdentificationAttempt(attempt=1, axis="yaw", thrust=thrust, speed=speed, model=YawModel(a22, b2, 0.01),
                                      r2=0.98, accepted=True, converged=True, converged_s=10.0,
                                      criterion_met_from_s=9.0, training_s=10.0, samples=200)
                for thrust, speed, a22, b2 in ((0.6, 1.13, -1.0, 0.66), (0.8, 1.65, -1.1, 1.11), (1.0, 2.17, -1.2, 1.72))]
    for attempt in attempts:
        store.add_run(campaign, attempt)
    store.add_design(campaign, HEADING.design(attempts))
    store.finish_campaign(campaign, "completed")


def test_schedule_from_the_latest_campaign(tmp_path):
    with Store(tmp_path / "s.sqlite") as store:
        assert schedule_from_store(store) is None
        stored_models(store)
        schedule = schedule_from_store(store)
        assert schedule is not None and schedule.b2_slope == pytest.approx(0.31, abs=0.03)


def _speeding_up(tmp_path, seconds: float, also=None):
    """The resident loop scheduling the stored design while the vehicle speeds up from thrust 0.6 to
    1.0 at 60 s (``also(link, telemetry)`` runs at every snapshot); the companion and the link."""
    link = InProcessLink(seed=3)
    with Store(tmp_path / "s.sqlite") as store:
        stored_models(store)
        config = ServeConfig(max_vehicle_s=seconds, scheduling=SchedulingConfig(min_interval_s=10.0))
        companion = Companion(link, store, store.add_vehicle("v"), config, AbortFlag())
        link.simulated.set_thrust(0.6)
        read = link.next_telemetry

        def mission(timeout_s=5.0):
            telemetry = read(timeout_s)
            if also is not None:
                also(link, telemetry)
            if telemetry.time_s > 60.0:
                link.simulated.set_thrust(1.0)
            return telemetry

        link.next_telemetry = mission
        companion.run()
    return companion, link


def test_gains_follow_speed_between_procedures(tmp_path):
    companion, link = _speeding_up(tmp_path, 120.0)
    writes = companion.scheduler.writes
    assert len(writes) >= 2, writes
    assert writes[0]["speed"] < 1.45 and writes[-1]["speed"] > 1.9  # starts at cruise (~1.39 m/s)
    assert writes[-1]["heading_p"] < writes[0]["heading_p"]  # more rudder authority, less gain
    assert all(b["time_s"] - a["time_s"] >= 10.0 for a, b in zip(writes, writes[1:]))  # rate-limited
    assert ("heading_p", pytest.approx(writes[-1]["heading_p"])) in link.param_writes
    assert link.param("heading_p") == pytest.approx(0.64)  # stopping gives the unscheduled gains back
    assert all("rudder_trim" not in w for w in writes)  # the trim is the campaign's, never rescheduled


def test_a_refused_scheduled_write_rolls_back_and_the_loop_goes_on(tmp_path):
    link = InProcessLink(seed=3, refuse={"HDG_I"})
    with Store(tmp_path / "s.sqlite") as store:
        stored_models(store)
        companion = Companion(link, store, store.add_vehicle("v"),
                              ServeConfig(max_vehicle_s=60.0, scheduling=SchedulingConfig(min_interval_s=10.0)),
                              AbortFlag())
        companion.run()  # must not raise
    assert companion.scheduler.writes == []  # nothing was confirmed
    assert link.param("heading_p") == pytest.approx(0.64)  # HDG_P went through, then was rolled back
    assert any("write failed" in text for text in link.status_texts)


def test_user_1_runs_the_campaign_and_reports_progress(tmp_path):
    link = InProcessLink(seed=3)
    link.inject_user_command(MAV_CMD_USER_1, at_s=2.0)
    with Store(tmp_path / "s.sqlite") as store:
        companion = Companion(link, store, store.add_vehicle("v"), ServeConfig(campaign=CAMPAIGN, max_vehicle_s=250.0), AbortFlag())
        history = companion.run()
        assert history and history[0]["status"] == "completed"
        assert len(store.models(history[0]["campaign_id"], axis="yaw")) == 2
        assert companion.scheduler is not None  # scheduling resumes from the new models
    acks = [a for a in link.acks if a[0] == MAV_CMD_USER_1]
    assert acks[0][1] == MAV_RESULT_IN_PROGRESS
    progress = [a[2] for a in acks if a[1] == MAV_RESULT_IN_PROGRESS]
    assert progress == sorted(progress) and max(progress) >= 50
    assert acks[-1][:2] == (MAV_CMD_USER_1, MAV_RESULT_ACCEPTED)


def test_user_4_aborts_the_running_procedure_and_restores(tmp_path):
    link = InProcessLink(seed=3)
    before = {name: link.param(name) for name in ("heading_p", "heading_i", "rudder_trim")}
    link.inject_user_command(MAV_CMD_USER_1, at_s=1.0)
    link.inject_user_command(MAV_CMD_USER_4, at_s=20.0)  # during the first training doublet
    with Store(tmp_path / "s.sqlite") as store:
        companion = Companion(link, store, store.add_vehicle("v"), ServeConfig(campaign=CAMPAIGN, max_vehicle_s=40.0), AbortFlag())
        history = companion.run()
        assert history[0]["status"] == "aborted" and "USER_4" in history[0]["reason"]
        assert store.campaigns()[0]["status"] == "aborted"
    assert (MAV_CMD_USER_4, MAV_RESULT_ACCEPTED, 0) in link.acks
    assert [a for a in link.acks if a[0] == MAV_CMD_USER_1][-1][1] == MAV_RESULT_FAILED
    assert not link.overrides and link.mode == "hold"
    assert {name: link.param(name) for name in before} == before


def test_abort_with_nothing_running_and_second_start_are_rejected(tmp_path):
    link = InProcessLink(seed=3)
    link.inject_user_command(MAV_CMD_USER_4, at_s=1.0)
    link.inject_user_command(MAV_CMD_USER_3, at_s=2.0)
    link.inject_user_command(MAV_CMD_USER_1, at_s=10.0)  # while seeking
    with Store(tmp_path / "s.sqlite") as store:
        config = ServeConfig(min_speed=MinSpeedProcedureConfig.levelled(settle_s=2.0, duration_s=60.0),
                             preset="starfish", max_vehicle_s=80.0)
        Companion(link, store, store.add_vehicle("v"), config, AbortFlag()).run()
    assert (MAV_CMD_USER_4, MAV_RESULT_TEMPORARILY_REJECTED, 0) in link.acks
    assert (MAV_CMD_USER_1, MAV_RESULT_TEMPORARILY_REJECTED, 0) in link.acks
    assert [a for a in link.acks if a[0] == MAV_CMD_USER_3][-1][1] == MAV_RESULT_ACCEPTED


def test_a_scheduled_gain_someone_else_sets_is_theirs_and_stays_on_exit(tmp_path):
    """A ground station sets HDG_P to 0.9 during ``run``: it is no longer scheduled (HDG_I still is),
    the ground station is told, and stopping does not restore over it."""
    def ground_station(link, telemetry):
        if 40.0 <= telemetry.time_s < 40.04:
            link.set_by_someone_else("HDG_P", 0.9)  # the speed changes after: HDG_I is rescheduled, HDG_P not

    companion, link = _speeding_up(tmp_path, 150.0, ground_station)
    later = [w for w in companion.scheduler.writes if w["time_s"] > 40.0]
    assert later and all("heading_p" not in w for w in later) and all("heading_i" in w for w in later)
    assert link.param("heading_p") == pytest.approx(0.9)  # theirs, after the exit's restore too
    assert link.param("heading_i") == pytest.approx(0.05)  # scheduled by us: the unscheduled value back
    assert any(text.startswith("scheduling stopped for HDG_P 0.9") for text in link.status_texts)


@pytest.mark.parametrize("found, said", [("manual", True), ("hold", False)])
def test_a_campaign_started_in_a_hand_flown_mode_says_it_takes_the_vehicle(tmp_path, found, said):
    from companion.procedures.app import run_campaign

    link = InProcessLink(seed=3)
    link.set_mode(found)
    abort = AbortFlag()
    abort.request("stopped at once: only the start is under test")
    with Store(tmp_path / "s.sqlite") as store:
        run_campaign(link, store, CAMPAIGN, vehicle_id=store.add_vehicle("v"), abort=abort)
    taken = [text for text in link.status_texts if text.startswith("campaign takes the vehicle from")]
    assert taken == (["campaign takes the vehicle from MANUAL"] if said else [])
    assert link.mode == found  # and it is given back as found
