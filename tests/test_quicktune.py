"""QuickTune's steering rule on an identification record (companion/numerics/quicktune.py, eq. Q.1)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from companion.numerics.cascade_gains import CascadeRules
from companion.numerics.quicktune import record_feed_forward


def test_a_record_whose_steering_follows_its_turn_rate_gives_that_ratio_times_0_9():
    rules = CascadeRules()
    times = np.arange(0.0, 20.0, 0.05)
    turn_rate = 0.5 * np.sin(0.5 * times)  # rad/s, past ±10°/s most of the time
    heading = np.cumsum(turn_rate) * 0.05
    heading = (heading + math.pi) % (2 * math.pi) - math.pi  # wrapped, as telemetry reports it
    steering = 0.8 * turn_rate  # output per rad/s
    value = record_feed_forward(list(times), list(heading), list(steering * rules.full_scale), rules)
    assert value == pytest.approx(0.9 * 0.8, rel=0.02)


def test_the_feed_forward_is_kept_within_the_autopilots_range():
    rules = CascadeRules(rate_ff_range=(0.0, 0.5))
    times = np.arange(0.0, 10.0, 0.05)
    heading = 0.3 * times  # a steady turn at 0.3 rad/s
    rudder = np.full_like(times, 0.9 * rules.full_scale)
    assert record_feed_forward(times, heading, rudder, rules) == 0.5


def test_a_short_record_or_one_without_a_turn_gives_none():
    assert record_feed_forward([0.0, 0.1], [0.0, 0.1], [0.1, 0.1]) is None
    times = [0.0, 0.1, 0.2, 0.3]
    assert record_feed_forward(times, [0.2] * 4, [0.1] * 4) is None
