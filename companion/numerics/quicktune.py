"""ArduRover QuickTune's steering rule, the gains the campaign compares its own design with (eq. Q.1–Q.2).

QuickTune (``rover-quicktune.lua``) sets the steering rate loop's feed-forward from recorded turns,
FF = 0.9·Σ|steering| / Σ|turn rate| over the samples it accepts (eq. Q.1), and P = I = 0.5·FF
(eq. Q.2); ANG_P is not its to change. Here the rule runs on an identification record (the yaw
manoeuvre's training data): the turn rate is the derivative of the unwrapped heading, the steering
the rudder over the autopilot's full-scale angle. Pure functions; docs/method.md, §6.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from .cascade_gains import CascadeRules

#: Rover QuickTune's steering rules (``rover-quicktune.lua``: RTUN_STR_FFRATIO, _P_RATIO, _I_RATIO
#: defaults) and the samples it accepts (steering output ≥ 0.10, turn rate > 10°/s)
QUICKTUNE_FF_RATIO = 0.9
QUICKTUNE_P_RATIO = 0.5
QUICKTUNE_I_RATIO = 0.5
QUICKTUNE_STEERING_MIN = 0.10
QUICKTUNE_TURN_RATE_MIN = math.radians(10.0)


def quicktune_feed_forward(steering: list[float], turn_rate: list[float]) -> float:
    """ArduRover QuickTune's rule on recorded data (eq. Q.1): FF = 0.9·Σ|steering| / Σ|turn rate|
    (output per rad/s) over the samples QuickTune accepts (|steering| ≥ 0.10 and |turn rate| > 10°/s).
    Where no sample is accepted (a doublet scaled down on a skid boat at low throttle, a slow hull),
    over every sample: QuickTune itself would ask for more steering, the rule still defines a gain to
    compare with. ValueError when the data hold no turn at all."""
    finite = [(abs(s), abs(r)) for s, r in zip(steering, turn_rate) if math.isfinite(s) and math.isfinite(r)]
    pairs = [(s, r) for s, r in finite if s >= QUICKTUNE_STEERING_MIN and r > QUICKTUNE_TURN_RATE_MIN] or finite
    total_rate = sum(r for _, r in pairs)
    if total_rate <= 0.0:
        raise ValueError("no turn rate in the data")
    return QUICKTUNE_FF_RATIO * sum(s for s, _ in pairs) / total_rate


def quicktune_gains(feed_forward: float, rules: CascadeRules = CascadeRules()) -> dict[str, float]:
    """QuickTune's steering gains from its FF (eq. Q.2): P = 0.5·FF, I = 0.5·FF (each within the
    autopilot's range); ANG_P is not QuickTune's to change."""
    def within(value: float, limits: tuple[float, float]) -> float:
        return min(max(value, limits[0]), limits[1])

    ff = within(feed_forward, rules.rate_ff_range)
    return {"heading_rate_ff": ff, "heading_rate_p": within(QUICKTUNE_P_RATIO * ff, rules.rate_p_range),
            "heading_rate_i": within(QUICKTUNE_I_RATIO * ff, rules.rate_i_range)}


def record_feed_forward(times: Sequence[float], heading: Sequence[float], rudder: Sequence[float],
                        rules: CascadeRules = CascadeRules()) -> float | None:
    """eq. Q.1 on one record: the turn rate dψ/dt of the unwrapped heading ``heading`` (rad) over
    ``times`` (s), the steering ``rudder`` (rad) over ``rules.full_scale``; the FF within
    ``rules.rate_ff_range``. None when the record has fewer than three samples or holds no turn."""
    t, psi, delta = (np.asarray(series, dtype=float) for series in (times, heading, rudder))
    if len(t) < 3:
        return None
    turn_rate = np.gradient(np.unwrap(psi), t)
    try:
        value = quicktune_feed_forward(list(delta / rules.full_scale), list(turn_rate))
    except ValueError:
        return None
    low, high = rules.rate_ff_range
    return float(min(max(value, low), high))
