"""One module per autopilot: its profile (data) and its strategy (how the link commands it).

``sim`` (our simulator, docs/PROTOCOL.md), ``ardurover`` (ArduRover boats) and ``ardusub``
(ArduSub). :func:`strategy_for` builds the strategy a link uses for a profile.
"""
from __future__ import annotations

import importlib


def strategy_for(link, profile):
    """The strategy object of ``profile`` (its module's ``Strategy`` class) bound to ``link``."""
    module = importlib.import_module(f"companion.link.autopilots.{profile.strategy}")
    return module.Strategy(link)
