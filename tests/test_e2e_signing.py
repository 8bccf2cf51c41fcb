"""MAVLink 2 signing end to end (SPEC C1): companion, simulator and ground station share a key."""
from __future__ import annotations

import time

import pytest

from companion.link.errors import HeartbeatTimeout, LinkError
from companion.link.vehicle import VehicleLink

pytestmark = pytest.mark.e2e

KEY = bytes(range(32))


@pytest.fixture(scope="module")
def signing_sim(module_sim_factory):
    return module_sim_factory(speedup=10, extra_args=("--signing-key", KEY.hex()))


def test_signed_companion_commands_a_signing_vehicle_and_its_frames_reach_the_gcs_signed(signing_sim):
    from pymavlink import mavutil

    gcs = mavutil.mavlink_connection(signing_sim.endpoint, source_system=255, source_component=190)
    gcs.setup_signing(KEY, sign_outgoing=True)
    gcs.mav.heartbeat_send(6, 8, 0, 0, 0)  # makes the simulator route to this client
    link = VehicleLink.connect(signing_sim.endpoint, signing_key=KEY)
    try:
        assert link.next_telemetry().time_s > 0
        assert link.set_param("HDG_P", 0.7) == pytest.approx(0.7)  # echoed, so the vehicle took it
        link.set_param("HDG_P", 0.64)
        link.status_text("signed hello")
        deadline = time.monotonic() + 10
        seen = None
        while seen is None and time.monotonic() < deadline:
            link.next_telemetry()
            msg = gcs.recv_match(type="STATUSTEXT", blocking=True, timeout=0.1)
            if msg is not None and msg.get_srcComponent() == 191:
                seen = msg
        assert seen is not None and seen.text == "signed hello" and seen._signed
    finally:
        link.close()
        gcs.close()


def test_an_unsigned_companion_cannot_command_a_signing_vehicle_and_is_told_why(signing_sim):
    """It hears the vehicle, but its requests are dropped: the refusal names signing, not the link."""
    with pytest.raises(LinkError, match="signs its messages") as refused:
        link = VehicleLink.connect(signing_sim.endpoint, heartbeat_timeout_s=5.0)
        try:
            link.set_param("HDG_P", 0.7)
        finally:
            link.close()
    assert "too slow" not in str(refused.value) and "--signing-key" in str(refused.value)


def test_a_wrong_key_is_reported_as_such(signing_sim):
    with pytest.raises(HeartbeatTimeout, match="signing"):
        VehicleLink.connect(signing_sim.endpoint, signing_key=bytes(32), heartbeat_timeout_s=3.0)
