"""ArduPilot SITL instances claimed, not merely seen free: two simulators started together (parallel
tests) must not both take the instance whose ports nobody has bound yet. No SITL binary needed."""
from __future__ import annotations

import socket
import subprocess
import sys

from sim.ardupilot_sitl import MAVLINK_BASE_PORT, InstanceClaim, free_instance

CLAIM_AND_WAIT = ("from sim.ardupilot_sitl import InstanceClaim; import sys; "
                  "claim = InstanceClaim(); print(claim.instance, flush=True); sys.stdin.read()")


def test_a_claimed_instance_is_not_claimed_again_until_released():
    first = InstanceClaim()
    try:
        second = InstanceClaim()
        assert second.instance != first.instance
        second.release()
        assert free_instance() == second.instance  # released: free again (the first is still held)
    finally:
        first.release()


def test_another_process_claim_is_respected_and_ends_with_it():
    """The claim is an OS lock: held by another process until it exits, whatever way it exits."""
    other = subprocess.Popen([sys.executable, "-c", CLAIM_AND_WAIT], stdin=subprocess.PIPE,
                             stdout=subprocess.PIPE, text=True)
    try:
        held = int(other.stdout.readline())
        mine = InstanceClaim()
        try:
            assert mine.instance != held
        finally:
            mine.release()
    finally:
        other.kill()
        other.wait(timeout=10)
    claim = InstanceClaim()
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
