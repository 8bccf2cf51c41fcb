"""pymavlink clients of the simulator for tests and bench scripts (MAVLink 2)."""
from __future__ import annotations

import os
import socket
import time

os.environ.setdefault("MAVLINK20", "1")  # read when pymavlink.mavutil is first imported

__all__ = ["connect_client", "free_port"]


def free_port(kind: int = socket.SOCK_DGRAM) -> int:
    """A currently free loopback port for ``kind`` (SOCK_DGRAM or SOCK_STREAM)."""
    with socket.socket(socket.AF_INET, kind) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


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
