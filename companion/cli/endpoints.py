"""MAVLink connection strings, checked in one place before pymavlink sees them.

pymavlink's :func:`~pymavlink.mavutil.mavlink_connection` takes almost any string and fails late
with a traceback (``foo:bar`` becomes a UDP socket bound to port "bar"). :func:`check_endpoint`
accepts the forms pymavlink documents and refuses everything else with one sentence:

* ``tcp:HOST:PORT``, ``tcpin:HOST:PORT``, ``udp:HOST:PORT``, ``udpin:HOST:PORT``,
  ``udpout:HOST:PORT``, ``udpbcast:HOST:PORT``, ``wsserver:HOST:PORT``, ``mcast:`` (or
  ``mcast:HOST:PORT``), ``ws:URL``/``wss:URL``, ``uds:PATH``/``unix:PATH``;
* ``HOST:PORT`` (pymavlink's legacy UDP form);
* a serial device, optionally with a baud rate: ``/dev/ttyUSB0``, ``/dev/ttyUSB0,57600``, ``COM3``.

HOST is a host name or IPv4 address (pymavlink splits on ``:``, so no IPv6), empty only for the
listening forms (``udpin::14550``); PORT is 1–65535.
"""
from __future__ import annotations

import argparse
import re

#: schemes followed by HOST:PORT (True: a listening form, whose HOST may be empty)
HOST_PORT_SCHEMES: dict[str, bool] = {
    "tcp": False, "tcpin": True, "udp": True, "udpin": True, "udpout": False, "udpbcast": False,
    "wsserver": True, "mcast": False,
}
#: schemes followed by a path or URL
PATH_SCHEMES = ("uds", "unix", "ws", "wss")

_HOST = re.compile(r"^[A-Za-z0-9]([A-Za-z0-9.-]*[A-Za-z0-9])?$")
_SERIAL = re.compile(r"^(/[^,]+|COM[0-9]+|\\\\\.\\COM[0-9]+)(,[0-9]+)?$", re.IGNORECASE)
EXAMPLES = "tcp:127.0.0.1:5760, udpin:0.0.0.0:14550, udpout:127.0.0.1:14550 or /dev/ttyUSB0,57600"


class EndpointError(ValueError):
    """A connection string pymavlink would misread; the message says what to write."""


def check_endpoint(text: str) -> str:
    """``text`` unchanged if it is a connection string of a form listed in the module docstring,
    else :class:`EndpointError` with one sentence."""
    text = text.strip()
    if not text:
        raise EndpointError(f"the connection string is empty; write e.g. {EXAMPLES}")
    scheme, sep, rest = text.partition(":")
    if sep and scheme.lower() in HOST_PORT_SCHEMES:
        if scheme.lower() == "mcast" and rest == "":
            return text  # pymavlink's default multicast group
        _check_host_port(text, rest, may_omit_host=HOST_PORT_SCHEMES[scheme.lower()])
        return text
    if sep and scheme.lower() in PATH_SCHEMES:
        if not rest.strip():
            raise EndpointError(f"{text!r} names no path or URL after {scheme}:")
        return text
    if _SERIAL.match(text):
        return text
    if sep and rest.count(":") == 0 and _HOST.match(scheme):  # legacy HOST:PORT (UDP)
        if rest.isdigit():
            _check_host_port(text, text, may_omit_host=False)
            return text
        raise EndpointError(f"{text!r} is not a connection string: {scheme!r} is not a known scheme "
                            f"and {rest!r} is not a port; write e.g. {EXAMPLES}")
    raise EndpointError(f"{text!r} is not a connection string pymavlink understands; write e.g. {EXAMPLES}")


def _check_host_port(text: str, host_port: str, may_omit_host: bool) -> None:
    host, sep, port = host_port.rpartition(":")
    if not sep:
        raise EndpointError(f"{text!r} needs HOST:PORT after the scheme, e.g. {EXAMPLES}")
    if not port.isdigit() or not 1 <= int(port) <= 65535:
        raise EndpointError(f"{text!r}: the port {port!r} is not a number in 1-65535")
    if host == "" and may_omit_host:
        return
    if not _HOST.match(host):
        raise EndpointError(f"{text!r}: {host!r} is not a host name or IPv4 address")


def endpoint_argument(text: str) -> str:
    """:func:`check_endpoint` as an argparse type (the message becomes argparse's error)."""
    try:
        return check_endpoint(text)
    except EndpointError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
