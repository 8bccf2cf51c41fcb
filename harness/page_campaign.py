"""A ground station's identification campaign on ``companion run --http 127.0.0.1:0`` beside our
simulator, with its status page attacked for the whole campaign (``harness.page_attack``) or not.

The companion runs as a subprocess, as on the vehicle; the ground station is a pymavlink client of
the simulator that arms the vehicle, starts the campaign with ``MAV_CMD_USER_1`` (COMMAND_LONG to
component 191) and reads its COMMAND_ACKs (IN_PROGRESS with progress, then ACCEPTED or FAILED). The
attack starts just before the campaign's command and stops when its last acknowledgement came. Then
the page is asked for ``/status.json`` once more, and the companion is stopped with SIGTERM.

Used by ``tests/test_status_page_under_attack.py`` (with the attack) and
``bench/bench_status_page_attack.py`` (both, for the wall times side by side).
"""
from __future__ import annotations

import json
import logging
import os
import signal
import subprocess
import sys
import time
import urllib.error
import urllib.request
from dataclasses import dataclass, field
from pathlib import Path

from harness.mavlink_clients import arm_and_see_it, connect_client, wait_for_line
from harness.page_attack import AttackCounts, AttackPlan, AttackProcess

log = logging.getLogger(__name__)

__all__ = ["PageCampaign", "campaign_beside_the_page"]

ROOT = Path(__file__).resolve().parents[1]
MAV_CMD_USER_1 = 31010
MAV_CMD_COMPONENT_ARM_DISARM = 400
ACCEPTED, FAILED, IN_PROGRESS = 0, 4, 5
COMPANION = 191


@dataclass
class PageCampaign:
    """What one campaign beside the page gave (``counts`` None: the page was not attacked)."""

    acks: list[tuple[int, int]] = field(default_factory=list)  # USER_1's (result, progress), in order
    campaign_wall_s: float = 0.0  # from the command to its last acknowledgement
    counts: AttackCounts | None = None
    alive_after_campaign: bool = False  # the companion still ran when the campaign ended
    page_after: int | None = None  # the status of GET /status.json after the attack (None: no answer)
    page_after_wait_s: float = 0.0  # how long after the attack that answer took
    procedure_after: dict = field(default_factory=dict)  # the page's "procedure" section after the attack
    exit_code: int | None = None  # the companion's, after SIGTERM
    stderr: str = ""

    @property
    def completed(self) -> bool:
        """The campaign's last acknowledgement is ACCEPTED at 100 %."""
        return bool(self.acks) and self.acks[-1] == (ACCEPTED, 100)


def _heartbeat_of_companion(gcs, timeout_s: float = 30.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        msg = gcs.recv_match(type="HEARTBEAT", blocking=True, timeout=0.5)
        if msg is not None and msg.get_srcComponent() == COMPANION:
            return
    raise RuntimeError("no HEARTBEAT from the companion (component 191) through the simulator")


def _acks(gcs, command: int, seen: list[tuple[int, int]], until, timeout_s: float) -> None:
    """Append the companion's COMMAND_ACKs for ``command`` to ``seen`` until ``until(seen)``."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and not until(seen):
        msg = gcs.recv_match(type="COMMAND_ACK", blocking=True, timeout=0.5)
        if msg is not None and msg.command == command and msg.get_srcComponent() == COMPANION \
                and getattr(msg, "target_system", 0) in (0, gcs.mav.srcSystem):
            seen.append((msg.result, msg.progress))


def _start(gcs, command: int, seen: list[tuple[int, int]], timeout_s: float = 30.0) -> None:
    """COMMAND_LONG to component 191, sent again (confirmation + 1) until its first acknowledgement."""
    deadline = time.monotonic() + timeout_s
    confirmation = 0
    while time.monotonic() < deadline and not seen:
        gcs.mav.command_long_send(1, COMPANION, command, confirmation, 0, 0, 0, 0, 0, 0, 0)
        _acks(gcs, command, seen, bool, 2.0)
        confirmation = min(confirmation + 1, 255)


def _page_after(url: str, timeout_s: float = 15.0) -> tuple[int | None, float, dict]:
    """The first answer of ``/status.json`` (retried while it is not 200): status, seconds, procedure."""
    began = time.monotonic()
    status: int | None = None
    while time.monotonic() - began < timeout_s:
        try:
            with urllib.request.urlopen(url + "status.json", timeout=5) as response:
                return response.status, time.monotonic() - began, json.loads(response.read())["procedure"] or {}
        except urllib.error.HTTPError as exc:
            status = exc.code
        except OSError:
            status = None
        time.sleep(0.2)
    return status, time.monotonic() - began, {}


def campaign_beside_the_page(endpoint: str, workdir: Path, plan: AttackPlan | None,
                             thrusts: str | None = None, timeout_s: float = 300.0) -> PageCampaign:
    """One identification campaign from a ground station on the lockstep simulator at ``endpoint``
    (a TCP client string), the companion serving its page on a free loopback port, the page under
    ``plan``'s attack for the whole campaign (``None``: no attack)."""
    workdir.mkdir(parents=True, exist_ok=True)
    stderr_path = workdir / "companion.stderr"
    command = [sys.executable, "-m", "companion", "run", "--connect", endpoint, "--lockstep",
               "--store", str(workdir / "store.sqlite"), "--http", "127.0.0.1:0", "--preset", "starfish"]
    if thrusts:
        command += ["--thrusts", thrusts]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    result = PageCampaign()
    gcs = connect_client(endpoint)
    with open(stderr_path, "w") as stderr:
        process = subprocess.Popen(command, cwd=workdir, stdout=subprocess.DEVNULL, stderr=stderr, env=env)
    try:
        url = wait_for_line(stderr_path, "status page: ", process)
        port = int(url.rstrip("/").rsplit(":", 1)[1])
        _heartbeat_of_companion(gcs)
        arm_and_see_it(gcs)
        attack = AttackProcess("127.0.0.1", port, plan).start() if plan is not None else None
        began = time.monotonic()
        try:
            _start(gcs, MAV_CMD_USER_1, result.acks)
            if result.acks and result.acks[0][0] == IN_PROGRESS:
                _acks(gcs, MAV_CMD_USER_1, result.acks, lambda seen: seen[-1][0] != IN_PROGRESS,
                      timeout_s)
            result.campaign_wall_s = time.monotonic() - began
            result.alive_after_campaign = process.poll() is None
        finally:
            if attack is not None:
                result.counts = attack.stop()
        log.info("campaign: last acknowledgements %s after %.1f s of wall clock; attack: %s", result.acks[-3:],
                 result.campaign_wall_s, None if result.counts is None else result.counts.as_dict())
        result.page_after, result.page_after_wait_s, result.procedure_after = _page_after(url)
    finally:
        gcs.close()
        if process.poll() is None:
            process.send_signal(signal.SIGTERM)
        try:
            result.exit_code = process.wait(timeout=60)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(timeout=10)
        result.stderr = stderr_path.read_text()
    return result
