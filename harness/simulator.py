"""The simulator as a child process for tests and bench scripts, through the companion's one
launcher (:class:`companion.rehearsal.launcher.SimulatorProcess`).

Direction of the endpoints (get this right or nothing arrives):

* UDP: the simulator listens with ``udpin:127.0.0.1:PORT``; a client uses ``udpout:127.0.0.1:PORT``
  and must **send first** (any message, e.g. a HEARTBEAT) so the simulator learns its address.
  Every client that has sent something receives all traffic.
* TCP: the simulator listens with ``tcpin:127.0.0.1:PORT``; a client uses ``tcp:127.0.0.1:PORT``.

``sim.endpoint`` is always the CLIENT string.
"""
from __future__ import annotations

import tempfile
from pathlib import Path

from companion.rehearsal.launcher import SimulatorError, SimulatorProcess

__all__ = ["DEFAULT_SPEEDUP", "READY_TIMEOUT_S", "SimPool", "SimulatorError", "SimulatorProcess", "start_sim"]

READY_TIMEOUT_S = 30.0
DEFAULT_SPEEDUP = 30.0


def start_sim(
    transport: str = "udp",
    speedup: float = DEFAULT_SPEEDUP,
    preset: str = "starfish",
    seed: int = 0,
    extra_args: tuple[str, ...] = (),
    log_dir: str | None = None,
    lockstep: bool = False,
    current: tuple[float, float] = (0.0, 0.0),
) -> SimulatorProcess:
    """Start the simulator on a free loopback port and wait for its READY line.

    Its stderr goes to a fresh temporary file (``sim.log_path``, ``sim.log_text()``), which the
    caller deletes (:class:`SimPool` does). Lockstep is off unless asked: a client that does not
    acknowledge vehicle time must not hold the simulator back.
    """
    with tempfile.NamedTemporaryFile(prefix="sim-", suffix=".log", dir=log_dir, delete=False) as log_file:
        log_path = Path(log_file.name)
    sim = SimulatorProcess(preset=preset, speedup=speedup, seed=seed, current=current, extra_args=list(extra_args),
                           ready_timeout_s=READY_TIMEOUT_S, transport=transport, log_path=log_path,
                           lockstep=lockstep)
    try:
        return sim.start()
    except SimulatorError:
        log_path.unlink(missing_ok=True)
        raise


class SimPool:
    """``pool(**start_sim kwargs)`` starts a simulator; ``close()`` stops them all and deletes their logs."""

    def __init__(self) -> None:
        self.sims: list[SimulatorProcess] = []

    def __call__(self, **kwargs) -> SimulatorProcess:
        sim = start_sim(**kwargs)
        self.sims.append(sim)
        return sim

    def close(self) -> None:
        for sim in self.sims:
            sim.stop()
            if sim.log_path is not None:
                sim.log_path.unlink(missing_ok=True)
        self.sims.clear()
