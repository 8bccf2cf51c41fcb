"""MAVLink's parameter protocol on the simulated autopilot (docs/PROTOCOL.md, "Parameters").

PARAM_REQUEST_LIST sends every parameter, PARAM_REQUEST_READ one (by index or name), PARAM_SET
answers with the value in effect: the new one, or on a refusal the old one after a STATUSTEXT
saying why (nothing is sent back for a name the table does not have). Integer parameters are
reported as MAV_PARAM_TYPE_INT32, the rest as REAL32, every value as a float (C cast encoding).
"""
from __future__ import annotations

import logging
from typing import Any, Callable, Protocol

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from sim.autopilot import Autopilot
from sim.params import ParamTable
from sim.routing import addressed_to

log = logging.getLogger(__name__)


class ParamHost(Protocol):
    """What the protocol needs of the autopilot it serves (``SimServer``)."""

    params: ParamTable
    autopilot: Autopilot

    def send(self, msg: Any) -> None: ...

    def status_text(self, text: str, severity: int = ...) -> None: ...

    def param_changed(self, name: str) -> None:
        """A parameter was set: apply what it changes outside the autopilot (stream rates, system id)."""


class ParamProtocol:
    """The handlers of the parameter messages, by message type (:attr:`handlers`)."""

    def __init__(self, host: ParamHost) -> None:
        self._host = host
        self.handlers: dict[str, Callable[[Any], None]] = {
            "PARAM_REQUEST_LIST": self.request_list,
            "PARAM_REQUEST_READ": self.request_read,
            "PARAM_SET": self.set,
        }

    def _for_us(self, msg: Any) -> bool:
        return addressed_to(msg, int(self._host.params["SYSID_THISMAV"]))

    def request_list(self, msg: Any) -> None:
        if self._for_us(msg):
            for name in self._host.params.names:
                self.send_value(name)

    def request_read(self, msg: Any) -> None:
        if not self._for_us(msg):
            return
        params = self._host.params
        if msg.param_index >= 0:
            name = params.name_at(msg.param_index)
        else:
            name = param_name(msg.param_id)
        if name is not None and name in params:
            self.send_value(name)
        else:
            log.info("PARAM_REQUEST_READ of unknown %r / %d", msg.param_id, msg.param_index)

    def set(self, msg: Any) -> None:
        if not self._for_us(msg):
            return
        host = self._host
        name = param_name(msg.param_id)
        result = host.autopilot.set_param(name, msg.param_value)
        if not result.accepted:
            host.status_text(f"Param {result.message}")
            if result.value is None:
                return
            self.send_value(name, result.value)
            return
        self.send_value(name, result.value)
        host.param_changed(name)

    def send_value(self, name: str, value: float | None = None) -> None:
        """PARAM_VALUE of ``name``: ``value``, or the table's."""
        params = self._host.params
        param_type = (
            mavlink.MAV_PARAM_TYPE_INT32 if params.is_integer(name) else mavlink.MAV_PARAM_TYPE_REAL32
        )
        self._host.send(
            mavlink.MAVLink_param_value_message(
                name.encode("ascii"),
                params[name] if value is None else value,
                param_type,
                len(params),
                params.index(name),
            )
        )


def param_name(raw: str | bytes | bytearray) -> str:
    """A PARAM_* ``param_id`` as text (pymavlink gives str; tolerate bytes and NUL padding)."""
    if isinstance(raw, (bytes, bytearray)):
        raw = raw.decode("ascii", "replace")
    return str(raw).split("\x00", 1)[0].strip()
