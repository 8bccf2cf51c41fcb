"""Learning during missions on a twin-thruster boat: the designer predicts its steps through ArduRover's
skid mixer, the thrust the steering leaves and the speed it costs (eq. A.2k), from the throttle the
mission holds on its straights, as a campaign on the same boat predicts them."""
from __future__ import annotations

import math
from dataclasses import replace

import pytest

from companion.interface import Telemetry
from companion.link.autopilots.ardurover import PROFILE as ROVER
from companion.numerics.identification import YawModel
from companion.numerics.skid_step import SkidMixer
from companion.numerics.step_response import predict_step
from companion.procedures.campaign import CampaignConfig
from companion.procedures.learning import PREDICTED_S, HeadingDesigner, StraightRunning, heading_kind_for
from companion.procedures.verified_design import HeadingLimits, limits_case, skid_plant

VALIDATED = [(1.2, YawModel(-1.0, 0.95, 0.0)), (1.5, YawModel(-1.1, 1.25, 0.0))]
SPEED_GAINS = {"speed_p": 0.2, "speed_i": 0.2}


def _straights(throttle: float) -> StraightRunning:
    straights = StraightRunning()
    for k in range(60):
        for speed in (1.2, 1.5):  # the mission's straights at two speeds, the law U ∝ t
            straights.add(Telemetry(time_s=0.04 * k, yaw_rate=0.01, thrust_ratio=throttle * speed / 1.5,
                                    speed_water=speed))
        straights.add(Telemetry(time_s=0.04 * k, yaw_rate=0.2, thrust_ratio=0.1, speed_water=1.5))  # a turn
    return straights


def _designer(skid: bool, throttle: float = 0.9) -> HeadingDesigner:
    config = CampaignConfig(thrusts=(0.5, 0.6), axes=("yaw",)).resolved_for(ROVER)
    config = replace(config, skid_mixer=SkidMixer() if skid else None, speed_law="u")
    kind = heading_kind_for(config)
    shipped = {n: ROVER.shipped_gains[native] for n, native in ROVER.params.items() if native in ROVER.shipped_gains}
    limits = HeadingLimits.from_vehicle(shipped, full_scale=ROVER.angle_full_scale_rad,
                                        rudder_rate=ROVER.actuator_rate_rad_s, output_scale_base=None)
    original = {k: v for k, v in shipped.items() if k in kind.scheduled}
    return HeadingDesigner(config, kind, original, limits, _straights(throttle), SPEED_GAINS)


def test_the_straights_give_the_steady_law_and_turns_are_left_out():
    levels = _straights(0.9).levels()
    assert levels == [pytest.approx((0.72, 1.2)), pytest.approx((0.9, 1.5))]


def test_a_skid_boats_design_is_predicted_through_its_mixer_as_the_campaign_predicts_it():
    designer = _designer(skid=True)
    limits = designer.limits_for(VALIDATED)
    assert limits.skid is not None and _designer(skid=False).limits_for(VALIDATED).skid is None
    outcome = designer(VALIDATED)
    design = outcome.design
    assert design is not None, outcome.reason
    gains = design.gains_at(1.5)
    # the campaign's own prediction for the same drive (eq. A.2k)
    plant = skid_plant(SkidMixer(), _straights(0.9).levels(), None, [1.2, 1.5], [-1.0, -1.1], [0.95, 1.25], "u",
                       SPEED_GAINS)
    case = limits_case("cascade", design.schedule.model_at(1.5), 1.5, replace(designer.limits, skid=plant))
    step = math.radians(40.0)
    expected = predict_step(case.plant, case.controller, gains, step, PREDICTED_S, skid=case.skid, **case.limits)
    iae, overshoot = design.predict(gains, 1.5, step)
    assert (iae, overshoot) == pytest.approx((expected.figures.iae_s, expected.figures.overshoot_pct), rel=1e-9)
    # near full throttle the mixer binds: the same gains are predicted otherwise without it
    free = limits_case("cascade", design.schedule.model_at(1.5), 1.5, designer.limits)
    unmixed = predict_step(free.plant, free.controller, gains, step, PREDICTED_S, **free.limits)
    assert abs(unmixed.figures.iae_s - iae) > 0.05
