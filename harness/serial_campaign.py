"""One identification campaign over a serial radio link (``harness.serial_bridge``), checked by the
vehicle's state afterwards: ``tests/test_serial_link.py`` and ``bench/bench_serial_link.py``.

On a ``--lockstep`` simulator listening on TCP:

1. a direct client puts the vehicle in hold, armed, and notes its state
   (``harness.fault_cases.vehicle_state``: every parameter, mode, armed, thrust, heading held);
2. ``companion identify --connect /dev/pts/N,57600 --lockstep --json`` runs as a process of its own
   through a :class:`~harness.serial_bridge.SerialBridge` with the given radio conditions (one thrust,
   yaw: the short campaign of ``harness.crash_cases``); its JSON (never NaN) and the radio's counts are
   kept, with the campaign's wall time;
3. a direct client reads the vehicle's state again and compares it with what was found, but for the
   gains a completed campaign wrote (``harness.fault_cases.state_differences``).
"""
from __future__ import annotations

import json
import logging
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from harness.fault_cases import native_names, state_differences, vehicle_state
from harness.fault_schedule import TO_COMPANION, TO_VEHICLE
from harness.serial_bridge import RadioConditions, SerialBridge

log = logging.getLogger(__name__)

__all__ = ["SerialRun", "run_serial_campaign"]

#: the campaign: one thrust, yaw only
THRUSTS = "0.7"


@dataclass
class SerialRun:
    """What one campaign over the serial link did."""

    conditions: RadioConditions
    seed: int
    endpoint: str = ""
    exit_code: int | None = None
    result: dict = field(default_factory=dict)  # identify's JSON
    stderr: str = ""
    radio: dict = field(default_factory=dict)  # SerialBridge.stats(), by direction
    wall_s: float = 0.0  # the campaign's wall clock (identify's process, connection to exit)
    state_problems: list[str] = field(default_factory=list)

    @property
    def status(self) -> str | None:
        return self.result.get("status")

    @property
    def quality(self) -> dict:
        """The link quality the companion reported (empty when it reported none)."""
        return self.result.get("link_quality") or {}

    def summary(self) -> str:
        """One line: the outcome, the wall time, what the radio dropped, what the companion reported."""
        down, up = self.radio.get(TO_COMPANION, {}), self.radio.get(TO_VEHICLE, {})
        q = self.quality
        return (f"{self.status} in {self.wall_s:.1f} s wall ({self.result.get('reason') or 'no reason'}); radio to the "
                f"companion: {down.get('bytes_lost', 0)} of {down.get('bytes_in', 0)} B lost "
                f"({100 * down.get('byte_drop_fraction', 0.0):.2f} %), {down.get('bytes_overflow', 0)} B overflowed, "
                f"{down.get('frames_hit', 0)} of {down.get('frames_in', 0)} frames hit; to the vehicle: "
                f"{up.get('bytes_lost', 0)} of {up.get('bytes_in', 0)} B lost, {up.get('frames_hit', 0)} frames hit; "
                f"companion: {q.get('frames', 0)} frames received, {q.get('frames_lost', 0)} lost "
                f"({100 * q.get('frame_loss_fraction', 0.0):.2f} %), {q.get('frames_corrupt', 0)} discarded as "
                f"corrupt, "
                f"{q.get('samples', 0)} samples")


def _json_without_nan(text: str) -> dict:
    def refuse(constant: str):
        raise ValueError(f"identify's JSON holds {constant}")

    return json.loads(text, parse_constant=refuse)


def run_serial_campaign(sim, store_path: Path, conditions: RadioConditions, seed: int, *,
                        timeout_s: float = 300.0) -> SerialRun:
    """The campaign on the running lockstep TCP simulator ``sim`` over a radio with ``conditions``
    each way, seeded ``seed`` (module docstring)."""
    from companion.link.vehicle import VehicleLink

    run = SerialRun(conditions, seed)
    names = native_names()
    with VehicleLink.connect(sim.endpoint, lockstep=True) as direct:
        direct.set_mode("hold")
        direct.arm(True)
        before = vehicle_state(direct, names, settle_s=2.0, window_s=1.0)
    with SerialBridge(sim.port, conditions=conditions, seed=seed) as bridge:
        run.endpoint = bridge.endpoint
        command = [sys.executable, "-m", "companion", "identify", "--connect", bridge.endpoint, "--lockstep",
                   "--store", str(store_path), "--thrusts", THRUSTS, "--axes", "yaw", "--json"]
        started = time.monotonic()
        done = subprocess.run(command, capture_output=True, text=True, timeout=timeout_s, stdin=subprocess.DEVNULL)
        run.wall_s = time.monotonic() - started
        run.radio = bridge.stats()
    run.exit_code, run.stderr = done.returncode, done.stderr
    run.result = _json_without_nan(done.stdout)
    kept = (run.result.get("final_gains") or {}) if run.status == "completed" else {}
    with VehicleLink.connect(sim.endpoint, lockstep=True) as direct:
        after = vehicle_state(direct, names, settle_s=8.0, window_s=2.0)
    run.state_problems = state_differences(before, after, names, run.result.get("reason"), kept)
    log.info("serial campaign (%s, seed %d): %s", conditions.describe(), seed, run.summary())
    return run
