"""Shared fixtures: the simulator as a subprocess on a free loopback port, and pymavlink clients.

The plumbing lives in :mod:`harness` (importable without pytest, shared with bench/): the
simulator is started by :func:`harness.simulator.start_sim` through the companion's launcher, the
clients come from :func:`harness.mavlink_clients.connect_client`. See harness/simulator.py for the
direction of the endpoints.

Usage::

    def test_something(sim_factory, mav_client):
        sim = sim_factory(speedup=30)            # SimulatorProcess; sim.endpoint is the CLIENT string
        client = mav_client(sim.endpoint)        # connected, heartbeat seen, MAVLink 2
"""
from __future__ import annotations

import os

os.environ.setdefault("MAVLINK20", "1")  # before pymavlink is imported anywhere in the test run

from typing import Callable, Iterator  # noqa: E402

import pytest  # noqa: E402

from harness.mavlink_clients import connect_client  # noqa: E402
from harness.simulator import SimPool, SimulatorProcess  # noqa: E402


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The modules that hold a slow test run first, each kept whole (its module-scoped fixtures set
    up once), the rest in their collected order: the two workers take the long tests while the many
    short ones are still left to balance them (longest first), instead of one worker running the
    serial radio's campaign (45 s of wall clock, collected late) alone at the end."""
    slow_modules = {item.module.__name__ for item in items
                    if item.get_closest_marker("slow") is not None and getattr(item, "module", None) is not None}
    order = {id(item): index for index, item in enumerate(items)}
    items.sort(key=lambda item: (getattr(getattr(item, "module", None), "__name__", "") not in slow_modules,
                                 order[id(item)]))


@pytest.fixture
def sim_factory() -> Iterator[Callable[..., SimulatorProcess]]:
    """``sim_factory(transport="udp"|"tcp", speedup=30, preset=..., seed=..., extra_args=())``;
    every simulator started is stopped at the end of the test."""
    pool = SimPool()
    yield pool
    pool.close()


@pytest.fixture(scope="module")
def module_sim_factory() -> Iterator[Callable[..., SimulatorProcess]]:
    """Like :func:`sim_factory` but the simulators live for the whole test module (cheaper)."""
    pool = SimPool()
    yield pool
    pool.close()


@pytest.fixture
def mav_client() -> Iterator[Callable[..., object]]:
    """``mav_client(endpoint, source_system=255, source_component=190)`` → connected pymavlink
    connection; all are closed at the end of the test."""
    conns = []

    def make(endpoint: str, **kwargs):
        conn = connect_client(endpoint, **kwargs)
        conns.append(conn)
        return conn

    yield make
    for conn in conns:
        conn.close()
