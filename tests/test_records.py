"""Typed records end to end: the schedule the campaign fits is the one written, stored,
reported, and read back by ``companion run`` — one serialiser, one fit, no re-packing on the way."""
from __future__ import annotations

import json
import math
import re

import pytest

from behaviors.heading_schedule import HEADING
from behaviors.identification import ManoeuvreConfig
from behaviors.pitch_schedule import PITCH
from companion.interface import SetParameters
from companion.numerics.identification import PitchModel, YawModel
from companion.numerics.schedule import YawSchedule, schedule_from_models
from companion.procedures.app import AbortFlag, run_campaign
from companion.procedures.campaign import CampaignConfig
from companion.procedures.resident import schedule_from_store
from companion.records.report import write_report
from companion.records.serialise import from_json, to_json
from companion.records.store import Store
from harness.inprocess import InProcessLink

# three speeds: enough for the a22 trend test (the simulator's STARFISH damping grows with speed)
TREND = CampaignConfig(thrusts=(0.6, 0.8, 1.0), axes=("yaw",), step_labels=("scheduled",),
                       yaw=ManoeuvreConfig(settle_s=15.0, resettle_s=12.0))


def test_serialiser_round_trips_every_record_type():
    schedule = schedule_from_models([1.1, 1.6, 2.2], [YawModel(-1.0, 0.66, 0.01), YawModel(-1.1, 1.1, 0.012),
                                                      YawModel(-1.2, 1.72, 0.011)])
    for record in (schedule, YawModel(-1.0, 0.6, 0.01, covariance=[[1.0, 0.0], [0.0, 2.0]]),
                   PitchModel(0.8, 0.14, -0.2, -0.002)):
        data = json.loads(json.dumps(to_json(record), allow_nan=False))  # strict JSON
        assert from_json(data) == record
    assert isinstance(from_json(to_json(schedule)).speed_range, tuple)
    with pytest.raises(ValueError, match="not a stored record"):
        from_json({"type": "Nothing"})
    with pytest.raises(TypeError, match="not a registered record"):
        to_json(object())


def test_nan_is_null_in_json_and_nan_again_when_read():
    schedule = YawSchedule(a22=-1.0, b2_slope=0.3, b2_intercept=0.2, delta0=0.01, speed_range=(1.0, 2.0))
    data = to_json(schedule)
    assert data["b2_residual_rms"] is None  # NaN written as null
    assert math.isnan(from_json(data).b2_residual_rms)


@pytest.fixture(scope="module")
def trend_campaign(tmp_path_factory):
    out = tmp_path_factory.mktemp("trend")
    link = InProcessLink(seed=7)
    store = Store(out / "store.sqlite")
    campaign, outcome, campaign_id = run_campaign(link, store, TREND, vehicle_id=store.add_vehicle("v"),
                                                  abort=AbortFlag())
    report = write_report(store, campaign_id, out)
    yield campaign, outcome, campaign_id, store, report.read_text(encoding="utf-8"), link
    store.close()


def test_the_report_shows_exactly_the_schedule_that_was_written(trend_campaign):
    campaign, outcome, campaign_id, store, html, link = trend_campaign
    assert outcome.status == "completed", outcome.reason
    written = campaign.heading_design.schedule
    assert written.a22_per_speed != 0.0, "this case must have a significant a22 trend"
    shown = from_json(json.loads(re.search(r"id='schedule-heading'>(.*?)</script>", html).group(1)))
    assert shown == written
    assert "significant trend with speed" in html and written.describe() in html
    # the gains on the vehicle are that schedule's gains at the speed they were written for
    gains = store.gains(campaign_id)[-1]
    expected = HEADING.gains(shown, gains["speed"])
    assert gains["after"] == pytest.approx(expected, rel=1e-12)
    for name, value in expected.items():
        assert link.param(name) == pytest.approx(value, rel=1e-6)


def test_companion_run_reads_the_same_schedule_back(trend_campaign):
    campaign, _, _, store, _, _ = trend_campaign
    assert schedule_from_store(store) == campaign.heading_design.schedule  # read back, never re-fitted


def test_pitch_schedule_is_designed_written_and_restored_like_the_heading_gains():
    """The pitch-gain schedule (added as a behaviour module, its numerics and one registration line)."""
    link = InProcessLink(seed=4)
    found = {name: link.param(name) for name in ("pitch_p", "pitch_i")}
    config = CampaignConfig(thrusts=(0.7, 1.0), axes=("pitch",), step_labels=(), schedules=("pitch",))
    with Store(":memory:") as store:
        campaign, outcome, campaign_id = run_campaign(link, store, config, vehicle_id=store.add_vehicle("v"),
                                                      abort=AbortFlag())
        assert outcome.status == "completed", outcome.reason
        design = store.designs(campaign_id, "pitch")[-1]
        assert design == campaign.designs["pitch"]
    gains = campaign.final_gains
    assert set(gains) == {"pitch_p", "pitch_i"}
    assert gains["pitch_p"] < 0  # the sign of d2 (elevator down pitches the nose down)
    for name, value in gains.items():
        assert link.param(name) == pytest.approx(value, rel=1e-6)
        assert value != pytest.approx(found[name], rel=1e-3)
    # gains at the identified speeds follow the damping rule on the interpolated model
    for point in design.points:
        assert point.scheduled == pytest.approx(PITCH.gains(design.schedule, point.speed))

    # an abort puts the found pitch gains back: they are in the campaign's declared footprint, so the
    # restore point covers them (here a changed gain stands in for a step that wrote one)
    link = InProcessLink(seed=4)

    def abort_after_write():
        if link.vehicle.time_s > 30.0:
            link.execute([SetParameters({"pitch_p": -7.0})])
            return "operator abort"
        return None

    with Store(":memory:") as store:
        _, outcome, _ = run_campaign(link, store, config, vehicle_id=store.add_vehicle("v"), abort=abort_after_write)
    assert outcome.status == "aborted"
    for name, value in found.items():
        assert link.param(name) == pytest.approx(value, rel=1e-6)
