"""ArduRover scales a rudder's steering output by MOT_SPD_SCA_BASE/U above the base speed, before
the output's limit (``AP_MotorsUGV::output_regular``): the heading design, its predicted steps, the
campaign that reads the vehicle's base speed, and the service that keeps the stored schedule (eq. A.2)."""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from behaviors.cascade_schedule import cascade_kind
from companion.link.actuation import Actuation, OutputScale
from companion.link.profiles import get_profile
from companion.numerics.cascade_gains import CascadeRules, design_cascade_gains, output_speed_scale
from companion.numerics.identification import YawModel
from companion.numerics.step_response import RudderPlant, simulate_step
from companion.procedures.campaign import CampaignConfig, IdentificationCampaign
from behaviors.schedules import kind_of
from companion.records.store import Store
from tests.test_param_export import attempts, campaign_store

WIDE = dict(rate_ff_range=(0.0, 50.0), rate_p_range=(0.0, 50.0), rate_i_range=(0.0, 50.0))


def test_the_scale_is_one_up_to_the_base_speed_and_base_over_speed_above_it():
    assert output_speed_scale(1.0, 0.8) == output_speed_scale(1.0, 1.0) == 1.0
    assert output_speed_scale(1.0, 2.5) == pytest.approx(0.4)
    assert output_speed_scale(1.0, -2.0) == pytest.approx(0.5)  # astern: by the speed's size
    assert output_speed_scale(None, 2.5) == output_speed_scale(0.0, 2.5) == output_speed_scale(1.0, None) == 1.0


def test_the_design_sees_the_scaled_plant():
    model = YawModel(-1.25, 1.96, 0.02)
    plain = design_cascade_gains(model, CascadeRules(**WIDE), speed=2.5)
    scaled = design_cascade_gains(model, CascadeRules(output_scale_base=1.0, **WIDE), speed=2.5)
    # b = k·b2·δfs with k = 0.4: the output gains grow by 1/k, the loop they close is the same
    for name in ("rate_ff", "rate_p", "rate_i"):
        assert getattr(scaled, name) == pytest.approx(getattr(plain, name) / 0.4)
    assert scaled.angle_p == pytest.approx(plain.angle_p) and scaled.rate_bandwidth == pytest.approx(plain.rate_bandwidth)


def test_a_scaled_output_flies_as_the_unscaled_one_with_gains_times_the_scale():
    plant = RudderPlant(-1.25, 1.96, 0.02, rudder_max=0.5236)
    gains = {"heading_angle_p": 1.5, "heading_rate_p": 2.0, "heading_rate_i": 0.5, "heading_rate_ff": 3.0,
             "heading_rate_imax": 10.0}
    shrunk = {**gains, **{k: gains[k] * 0.4 for k in ("heading_rate_p", "heading_rate_i", "heading_rate_ff")}}
    step = math.radians(40.0)  # large enough to saturate the rudder: the limit comes after the scaling
    _, scaled, peak = simulate_step(plant, "cascade", gains, step, 15.0, output_scale=0.4)
    _, unscaled, peak_unscaled = simulate_step(plant, "cascade", shrunk, step, 15.0)
    assert peak == pytest.approx(0.5236) and peak_unscaled == pytest.approx(0.5236)
    np.testing.assert_allclose(scaled, unscaled, atol=1e-9)
    _, clipped_first, _ = simulate_step(plant, "cascade", gains, step, 15.0)  # what a limit before k would do
    assert np.max(np.abs(clipped_first - scaled)) > math.radians(1.0)


def test_the_turn_acceleration_limit_slows_the_start_of_a_step():
    plant = RudderPlant(-1.25, 1.96, 0.02, rudder_max=0.5236)
    gains = {"heading_angle_p": 3.0, "heading_rate_p": 1.0, "heading_rate_i": 0.2, "heading_rate_ff": 0.6}
    times, free, _ = simulate_step(plant, "cascade", gains, math.radians(20.0), 6.0)
    _, limited, _ = simulate_step(plant, "cascade", gains, math.radians(20.0), 6.0, rate_accel_max=math.radians(30.0))
    early = times <= 1.0
    assert np.all(limited[early] <= free[early] + 1e-12) and limited[early][-1] < 0.8 * free[early][-1]


def _rover(skid: bool = False):
    profile = get_profile("ardurover")
    if skid:
        profile = replace(profile, actuation=Actuation("skid", left=OutputScale(1), right=OutputScale(3)))
    return profile


def test_the_campaign_designs_for_the_vehicles_base_speed_and_not_for_a_skid_boat():
    config = CampaignConfig(thrusts=(0.6, 1.0), axes=("yaw",)).resolved_for(_rover())
    assert config.cascade.output_scale_base == 1.0  # ArduPilot's default until the vehicle says
    campaign = IdentificationCampaign(config)
    assert "steering_scale_speed" in campaign.footprint.parameters  # read, and restored unchanged
    before = campaign.heading_kind.model_gains(YawModel(-1.25, 1.96, 0.02), 2.5)
    assert campaign.adopt_original({"steering_scale_speed": 2.0, "heading_rate_ff": 0.75}) is True
    assert campaign.config.cascade.output_scale_base == 2.0 and campaign.original_gains["heading_rate_ff"] == 0.75
    after = campaign.heading_kind.model_gains(YawModel(-1.25, 1.96, 0.02), 2.5)
    assert after["heading_rate_ff"] < before["heading_rate_ff"]  # k 0.8 instead of 0.4
    assert campaign.adopt_original({"steering_scale_speed": 2.0}) is False  # nothing new
    skid = CampaignConfig(thrusts=(0.6,), axes=("yaw",)).resolved_for(_rover(skid=True))
    assert skid.cascade.output_scale_base is None  # the skid mixer does not scale
    assert IdentificationCampaign(skid).adopt_original({"steering_scale_speed": 2.0}) is False


def test_the_service_keeps_the_schedule_with_the_rules_it_was_designed_by(tmp_path):
    config = CampaignConfig().resolved_for(_rover())
    config = replace(config, cascade=replace(config.cascade, output_scale_base=0.8))
    kind = cascade_kind(config.cascade)
    store_path = tmp_path / "store.sqlite"
    campaign_id = campaign_store(store_path, "ardurover", kind, config.to_dict())
    with Store(store_path) as store:
        design = store.latest_design("cascade")[1]
    rebuilt = kind_of(design)  # the rules the stored design carries
    assert rebuilt is not None and design.rules == config.cascade
    for point in design.points:
        assert rebuilt.gains(design.schedule, point.speed) == pytest.approx(point.scheduled)
    default = cascade_kind(CascadeRules())
    assert default.gains(design.schedule, 2.0) != pytest.approx(design.points[-1].scheduled)
    assert len(attempts()) == len(design.points)
