"""Shared fixtures: the simulator as a subprocess on a free loopback port, and pymavlink clients.

Direction of the endpoints (get this right or nothing arrives):

* UDP: the simulator listens with ``udpin:127.0.0.1:PORT``; a client uses ``udpout:127.0.0.1:PORT``
  and must **send first** (any message, e.g. a HEARTBEAT) so the simulator learns its address.
  Every client that has sent something receives all traffic.
* TCP: the simulator listens with ``tcpin:127.0.0.1:PORT``; a client uses ``tcp:127.0.0.1:PORT``.

Usage::

    def test_something(sim_factory, mav_client):
        sim = sim_factory(speedup=30)            # SimProcess; sim.endpoint is the CLIENT string
        client = mav_client(sim.endpoint)        # connected, heartbeat seen, MAVLink 2
"""
from __future__ import annotations

import os

os.environ.setdefault("MAVLINK20", "1")  # before pymavlink is imported anywhere in the test run

import select  # noqa: E402
import socket  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from dataclasses import dataclass, field  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Callable, Iterator  # noqa: E402

import pytest  # noqa: E402

REPO_ROOT = Path(__file__).resolve().parents[1]
READY_TIMEOUT_S = 30.0
DEFAULT_SPEEDUP = 30.0


def free_port(kind: int = socket.SOCK_DGRAM) -> int:
    """A currently free loopback port for ``kind`` (SOCK_DGRAM or SOCK_STREAM)."""
    with socket.socket(socket.AF_INET, kind) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@dataclass
class SimProcess:
    """A running ``python -m sim run``. ``endpoint`` is what a CLIENT passes to pymavlink."""

    process: subprocess.Popen
    listen: str  # what the simulator listens on (udpin:/tcpin:, with the bound port)
    endpoint: str  # what a client connects to (udpout:/tcp:)
    port: int
    speedup: float
    log_path: Path
    extra: dict = field(default_factory=dict)

    def log_text(self) -> str:
        try:
            return self.log_path.read_text(errors="replace")
        except OSError:
            return ""

    def alive(self) -> bool:
        return self.process.poll() is None

    def stop(self, timeout: float = 5.0) -> int | None:
        """SIGTERM, then SIGKILL if it does not exit; returns the exit code."""
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(timeout)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(timeout)
        if self.process.stdout is not None:
            self.process.stdout.close()
        return self.process.returncode


def start_sim(
    transport: str = "udp",
    speedup: float = DEFAULT_SPEEDUP,
    preset: str = "starfish",
    seed: int = 0,
    extra_args: tuple[str, ...] = (),
    log_dir: str | None = None,
) -> SimProcess:
    """Start the simulator on a free loopback port and wait for its ``READY`` line.

    The simulator binds port 0 (the OS picks a free port, no race between tests) and reports the
    port it got in ``READY udpin:127.0.0.1:PORT``.
    """
    if transport not in ("udp", "tcp"):
        raise ValueError(f"transport must be 'udp' or 'tcp', not {transport!r}")
    listen = "udpin:127.0.0.1:0" if transport == "udp" else "tcpin:127.0.0.1:0"
    log_file = tempfile.NamedTemporaryFile(
        prefix="sim-", suffix=".log", dir=log_dir, delete=False
    )
    command = [
        sys.executable, "-m", "sim", "run", "--listen", listen, "--speedup", str(speedup),
        "--preset", preset, "--seed", str(seed), *extra_args,
    ]
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    process = subprocess.Popen(
        command, cwd=REPO_ROOT, stdout=subprocess.PIPE, stderr=log_file, text=True, env=env
    )
    log_file.close()
    sim = SimProcess(process, listen, "", 0, speedup, Path(log_file.name))
    deadline = time.monotonic() + READY_TIMEOUT_S
    while time.monotonic() < deadline:
        if process.poll() is not None:
            raise RuntimeError(f"simulator exited with {process.returncode}:\n{sim.log_text()}")
        ready, _, _ = select.select([process.stdout], [], [], 0.2)
        if ready:
            line = process.stdout.readline().strip()
            if line.startswith("READY "):
                sim.listen = line.split(" ", 1)[1]  # e.g. udpin:127.0.0.1:40892
                kind, host, port = sim.listen.split(":")
                sim.port = int(port)
                sim.endpoint = f"{'udpout' if kind == 'udpin' else 'tcp'}:{host}:{port}"
                return sim
    sim.stop()
    raise RuntimeError(f"simulator not READY within {READY_TIMEOUT_S} s:\n{sim.log_text()}")


class _SimPool:
    def __init__(self) -> None:
        self.sims: list[SimProcess] = []

    def __call__(self, **kwargs) -> SimProcess:
        sim = start_sim(**kwargs)
        self.sims.append(sim)
        return sim

    def close(self) -> None:
        for sim in self.sims:
            sim.stop()
            try:
                sim.log_path.unlink()
            except OSError:
                pass


@pytest.fixture
def sim_factory() -> Iterator[Callable[..., SimProcess]]:
    """``sim_factory(transport="udp"|"tcp", speedup=30, preset=..., seed=..., extra_args=())``;
    every simulator started is stopped at the end of the test."""
    pool = _SimPool()
    yield pool
    pool.close()


@pytest.fixture(scope="module")
def module_sim_factory() -> Iterator[Callable[..., SimProcess]]:
    """Like :func:`sim_factory` but the simulators live for the whole test module (cheaper)."""
    pool = _SimPool()
    yield pool
    pool.close()


def connect_client(endpoint: str, source_system: int = 255, source_component: int = 190,
                   timeout: float = 10.0):
    """A pymavlink connection that has announced itself (HEARTBEAT) and seen the vehicle's one."""
    from pymavlink import mavutil

    conn = mavutil.mavlink_connection(
        endpoint, source_system=source_system, source_component=source_component
    )
    mav = mavutil.mavlink
    if endpoint.startswith("udp"):
        try:  # room for bursts at high speed-up (UDP has no flow control; capped by rmem_max)
            conn.port.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 * 1024 * 1024)
        except OSError:
            pass
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        conn.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        if conn.recv_match(type="HEARTBEAT", blocking=True, timeout=0.5) is not None:
            return conn
    conn.close()
    raise TimeoutError(f"no HEARTBEAT from the simulator at {endpoint}")


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
