"""Crash-and-recover cases: ``companion identify`` killed with SIGKILL at a chosen point of a campaign,
then ``companion recover --yes``, checked against the vehicle as it was found. Shared by
``tests/test_crash_recovery.py`` and ``bench/bench_crash_recovery.py``.

A case runs against a ``--lockstep`` simulator over TCP (vehicle time advances only as the
companion in charge reads it, so where the kill lands is a function of the kill point, not of the
machine's load): the vehicle is put in hold, armed, with its RC override timeout off (an override
held by the dead companion would never expire); the campaign is started as a child process; the
store's trail is watched until the kill point (the N-th recorded change, or the first change of a
kind) and the child killed; the vehicle's state is read (what the crash left); the next start is
checked to refuse without an answer; ``companion recover --yes`` runs; the vehicle must be as found:
the heading gains, the mode, the thrust, the rudder back with the heading loop.
"""
from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

__all__ = ["GAINS", "CrashResult", "campaign_command", "prepare_vehicle", "run_crash_case", "store_changes"]

GAINS = ("HDG_P", "HDG_I", "HDG_TRIM")
THRUST_TOLERANCE = 0.011
SETTLED_RUDDER = 0.05  # rad: the heading loop holds its course again (no override left)


def store_changes(store_path: Path) -> list[tuple[str, dict]]:
    """The changes the trail holds so far (read-only, as another process would read them)."""
    if not store_path.exists():
        return []
    try:
        db = sqlite3.connect(f"file:{store_path}?mode=ro", uri=True, timeout=1.0)
        try:
            rows = db.execute("SELECT kind, detail_json FROM changes ORDER BY id").fetchall()
        finally:
            db.close()
    except sqlite3.Error:  # not created yet
        return []
    return [(kind, json.loads(detail)) for kind, detail in rows]


def _vehicle(endpoint: str):
    from companion.link.vehicle import VehicleLink

    return VehicleLink.connect(endpoint, lockstep=True)


def vehicle_state(endpoint: str, settle_samples: int = 0) -> dict:
    """Heading gains, mode, thrust and the largest rudder over 10 samples (after ``settle_samples``)."""
    link = _vehicle(endpoint)
    try:
        link.skip_to_now()
        samples = [link.next_telemetry() for _ in range(settle_samples + 10)][-10:]
        return {"params": {name: link.get_param(name) for name in GAINS}, "mode": link.mode,
                "thrust": samples[-1].thrust_ratio, "rudder": max(abs(s.rudder) for s in samples)}
    finally:
        link.close()


def prepare_vehicle(endpoint: str) -> None:
    """In hold, armed, its RC override timeout off (an override a dead companion held never expires)."""
    link = _vehicle(endpoint)
    try:
        link.set_param("RC_OVR_TIME", -1.0)
        link.set_mode("hold")
        link.arm(True)
    finally:
        link.close()


def campaign_command(endpoint: str, store_path: Path) -> list[str]:
    """The campaign each case runs (one thrust, yaw)."""
    return [sys.executable, "-m", "companion", "identify", "--connect", endpoint, "--lockstep",
            "--store", str(store_path), "--thrusts", "0.8", "--axes", "yaw"]


@dataclass
class CrashResult:
    """What a case did: where it killed, what the crash left, the next start's refusal, the recovery."""

    kill_point: str
    killed: bool = False
    changes_at_kill: int = 0
    damaged: dict = field(default_factory=dict)
    refused: bool = False
    recovery_exit: int | None = None
    recovery: dict = field(default_factory=dict)
    after: dict = field(default_factory=dict)
    problems: list[str] = field(default_factory=list)

    @property
    def restored(self) -> bool:
        return self.killed and not self.problems


def run_crash_case(sim, store_path: Path, kill_point: str, until: Callable[[list[tuple[str, dict]], dict], bool],
                   *, timeout_s: float = 60.0) -> CrashResult:
    """Start a campaign on ``sim`` (lockstep TCP), kill it once ``until(changes, found)`` holds, then
    recover and compare (module docstring)."""
    result = CrashResult(kill_point)
    prepare_vehicle(sim.endpoint)
    found = vehicle_state(sim.endpoint)
    command = campaign_command(sim.endpoint, store_path)
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and process.poll() is None and not until(store_changes(store_path), found):
            time.sleep(0.005)
        if process.poll() is not None:
            result.problems.append(f"the campaign ended (exit {process.returncode}) before the kill point")
            return result
        os.kill(process.pid, signal.SIGKILL)
        result.killed = True
    finally:
        if process.poll() is None and not result.killed:
            process.kill()
        process.wait(timeout=10)
    result.changes_at_kill = len(store_changes(store_path))
    result.damaged = vehicle_state(sim.endpoint)
    refused = subprocess.run(command, capture_output=True, text=True, timeout=timeout_s, stdin=subprocess.DEVNULL)
    result.refused = refused.returncode == 1 and "was interrupted" in refused.stderr
    if not result.refused:
        result.problems.append(f"the next start did not refuse (exit {refused.returncode})")
    recovered = subprocess.run([sys.executable, "-m", "companion", "recover", "--connect", sim.endpoint, "--lockstep",
                                "--store", str(store_path), "--yes", "--json"],
                               capture_output=True, text=True, timeout=timeout_s)
    result.recovery_exit = recovered.returncode
    try:
        result.recovery = json.loads(recovered.stdout)
    except json.JSONDecodeError:
        result.problems.append(f"recover printed no JSON: {recovered.stderr[-300:]}")
    if recovered.returncode != 0:
        result.problems.append(f"recover exited {recovered.returncode}: {recovered.stderr[-300:]}")
    result.after = after = vehicle_state(sim.endpoint, settle_samples=300)  # 15 s: the heading loop settles
    if after["params"] != found["params"]:
        result.problems.append(f"gains {after['params']}, found {found['params']}")
    if after["mode"] != found["mode"]:
        result.problems.append(f"mode {after['mode']}, found {found['mode']}")
    if abs(after["thrust"] - found["thrust"]) > THRUST_TOLERANCE:
        result.problems.append(f"thrust {after['thrust']:.3f}, found {found['thrust']:.3f}")
    if after["rudder"] > SETTLED_RUDDER:
        result.problems.append(f"rudder {after['rudder']:.3f} rad 15 s after recovery: an override still held?")
    db = sqlite3.connect(store_path)
    try:
        status = db.execute("SELECT status FROM campaigns ORDER BY id LIMIT 1").fetchone()[0]
    finally:
        db.close()
    if status != "interrupted":
        result.problems.append(f"campaign row {status!r}, not 'interrupted'")
    return result
