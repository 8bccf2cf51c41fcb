"""Thrust levels that give distinct speeds: a level repeating a lower one's speed is detected at its
settle, and the levels left are re-spaced within the thrusts that reached distinct speeds."""
from __future__ import annotations

import pytest

from companion.numerics.thrust_levels import respaced, same_speed_as
from companion.procedures.campaign import CampaignConfig, IdentificationCampaign


def test_a_level_repeating_a_lower_ones_speed_is_found_and_a_faster_one_is_not():
    assert same_speed_as({0.6: 3.0}, 0.8, 3.05) == 0.6
    assert same_speed_as({0.6: 3.0}, 0.8, 3.5) is None
    assert same_speed_as({0.6: 3.0}, 0.4, 3.0) is None  # only a lower thrust can be repeated


def test_the_levels_left_go_below_a_lowest_level_already_at_the_top_speed():
    assert respaced({0.6: 3.0, 0.8: 3.0}, 2) == pytest.approx([0.45, 0.3])


def test_the_levels_left_fill_the_range_that_gave_distinct_speeds():
    new = respaced({0.4: 2.0, 0.6: 3.0, 0.8: 3.02}, 2)
    assert len(new) == 2 and all(0.4 < t < 0.6 for t in new) and len(set(new)) == 2
    assert respaced({0.4: 2.0, 0.42: 3.0, 0.6: 3.0}, 3) == []  # no room left between 0.40 and 0.42


def test_the_campaign_skips_the_repeating_level_and_replans_what_is_left():
    campaign = IdentificationCampaign(CampaignConfig(thrusts=(0.6, 0.8, 1.0), axes=("yaw",)).quick())
    assert campaign._settled_speed(0.6, 3.0) is None
    note = campaign._settled_speed(0.8, 3.01)
    assert note is not None and "top speed" in note and "WP_SPEED" in note
    assert campaign._plan == pytest.approx([0.6, 0.45, 0.3])
    assert campaign.respacing == [note]
