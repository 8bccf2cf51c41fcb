"""One module per autopilot: its profile (data) and its strategy (how the link commands it).

Adding an autopilot is one module here (a ``PROFILE`` and a ``Strategy`` class) and one name in
:data:`MODULES`. ``sim`` is our simulator (docs/PROTOCOL.md), ``ardurover`` ArduRover boats and
``ardusub`` ArduSub, ``px4_rover`` and ``px4_uuv`` PX4 boats and UUVs; ``ardupilot`` and ``px4``
hold what each family shares.
"""
from __future__ import annotations

import importlib

#: the registered autopilots (modules of this package); their profiles are detected in this order
MODULES = ("sim", "ardusub", "ardurover", "px4_rover", "px4_uuv")
#: the MAVLink dialect connections are opened with: one that covers every registered autopilot
#: (ArduPilot's is a superset of ``common``)
CONNECT_DIALECT = "ardupilotmega"


def module_of(name: str):
    """The module of a registered autopilot."""
    return importlib.import_module(f"companion.link.autopilots.{name}")


def registered_profiles() -> list:
    """The ``PROFILE`` of every registered autopilot, in :data:`MODULES` order."""
    return [module_of(name).PROFILE for name in MODULES]


def strategy_for(ports, profile):
    """The strategy object of ``profile`` (its module's ``Strategy`` class) bound to the link's ports."""
    return module_of(profile.strategy).Strategy(ports)
