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


def wait_for_line(path, prefix: str, process, timeout_s: float = 30.0) -> str:
    """The rest of the first line of ``path`` (a process's stderr file) that starts with ``prefix``;
    RuntimeError when ``process`` ends or ``timeout_s`` of wall clock passes without one."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        for line in path.read_text().splitlines():
            if line.startswith(prefix):
                return line[len(prefix):].strip()
        if process.poll() is not None:
            break
        time.sleep(0.1)
    raise RuntimeError(f"no {prefix!r} line: {path.read_text()[-2000:]}")


def arm_and_see_it(gcs, timeout_s: float = 20.0) -> None:
    """Arm, and wait for the vehicle's HEARTBEAT to show it, as a ground station does before it
    starts anything: the companion hears the same heartbeat before the command routed after it
    (a start sent at once raced the companion's view of the armed flag)."""
    gcs.mav.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)  # MAV_CMD_COMPONENT_ARM_DISARM
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        msg = gcs.recv_match(type="HEARTBEAT", blocking=True, timeout=0.5)
        if msg is not None and msg.get_srcComponent() == 1 and msg.base_mode & 128:  # SAFETY_ARMED
            return
    raise RuntimeError("the vehicle's heartbeat never showed it armed")


def set_param_echoed(conn, name: str, value: float, timeout_s: float = 10.0) -> None:
    """A ground station's PARAM_SET of ``name`` to the autopilot (system 1, component 1), sent again
    until its PARAM_VALUE echoes ``value`` (wall clock: a test rig's set-up, not vehicle time)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        conn.mav.param_set_send(1, 1, name.encode(), value, 9)
        msg = conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=1.0)
        if msg is not None and msg.param_id == name and abs(msg.param_value - value) < 1e-6:
            return
    raise AssertionError(f"{name} was never echoed as {value}")


def read_parameters(endpoint: str, names: list[str], tries: int = 10) -> dict[str, float]:
    """The autopilot's (system 1, component 1) values of ``names``: PARAM_REQUEST_READ on a connection
    of the caller's own (system 254), each asked ``tries`` times at most; a name never answered is
    left out."""
    conn = connect_client(endpoint, source_system=254, timeout=30.0)
    try:
        values: dict[str, float] = {}
        for name in names:
            for _ in range(tries):
                conn.mav.param_request_read_send(1, 1, name.encode(), -1)
                msg = conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=1.0)
                if msg is not None and msg.param_id == name:
                    values[name] = msg.param_value
                    break
        return values
    finally:
        conn.close()
