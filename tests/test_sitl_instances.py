"""SITL instances claimed, not merely seen free: two simulators started together (parallel tests) must
not both take the instance whose ports nobody has bound yet (ArduPilot's, and PX4's through the same
claim, sim/instance_claim.py). No SITL binary needed."""
from __future__ import annotations

import importlib
import socket
import subprocess
import sys

import pytest

from sim.ardupilot_sitl import MAVLINK_BASE_PORT, InstanceClaim, free_instance

CLAIM_AND_WAIT = ("from {module} import {name}; import sys; "
                  "claim = {name}(); print(claim.instance, flush=True); sys.stdin.read()")
#: the launchers' claims: ArduPilot's, and PX4's, held for PX4's lifetime
CLAIMS = [("sim.ardupilot_sitl", "InstanceClaim"), ("sim.px4_sitl", "Px4InstanceClaim")]


def test_a_claimed_instance_is_not_claimed_again_until_released():
    first = InstanceClaim()
    try:
        second = InstanceClaim()
        assert second.instance != first.instance
        second.release()
        assert free_instance() == second.instance  # released: free again (the first is still held)
    finally:
        first.release()


@pytest.mark.parametrize("module, name", CLAIMS)
def test_another_process_claim_is_respected_and_ends_with_it(module, name):
    """The claim is an OS lock: held by another process until it exits, whatever way it exits."""
    claim_type = getattr(importlib.import_module(module), name)
    other = subprocess.Popen([sys.executable, "-c", CLAIM_AND_WAIT.format(module=module, name=name)],
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        held = int(other.stdout.readline())
        mine = claim_type()
        try:
            assert mine.instance != held
        finally:
            mine.release()
    finally:
        other.kill()
        other.wait(timeout=10)
    claim = claim_type()
    try:
        assert claim.instance <= held  # the dead process's instance (or a lower one) is free again
    finally:
        claim.release()


def test_an_instance_whose_port_is_bound_elsewhere_is_skipped():
    instance = free_instance()
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as busy:
        busy.bind(("127.0.0.1", MAVLINK_BASE_PORT + 10 * instance))
        claim = InstanceClaim()
        try:
            assert claim.instance != instance
        finally:
            claim.release()
