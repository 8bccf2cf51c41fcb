"""The UDP relay in a process of its own (``harness.udp_relay``), for benchmarks.

In the companion's process the relay's thread shares the interpreter lock with the companion's
numerics: while the companion computes, the relay is late, and while the relay runs, the companion
reads its socket late (at 20× its receive buffer overflows sooner). A relay in its own process is
what a router or a radio is: another machine's clock. :class:`RelayProcess` starts one and offers the
relay's methods that a run needs (arm, count, stats, what was sent and delivered), each a round trip
over a pipe (a few hundred microseconds: poll it, don't spin on it).

The child is started with ``spawn``: as for any such process, the caller's main module must be safe
to import (its work under ``if __name__ == "__main__":``), or the child runs it again.
"""
from __future__ import annotations

import logging
import multiprocessing
import os
from typing import Any, Iterable

from harness.delivery_log import CommandDelivery
from harness.fault_schedule import TO_VEHICLE, Fault
from harness.link_conditions import LinkConditions

log = logging.getLogger(__name__)

__all__ = ["RelayProcess"]

START_TIMEOUT_S = 20.0
CALL_TIMEOUT_S = 10.0
PARENT_CHECK_S = 1.0  # the child stops when its parent is gone (checked this often)


def _serve(conn, vehicle_port: int, seed: int, conditions) -> None:
    """The child: a relay, answering the parent's calls until told to close or the parent is gone."""
    from harness.udp_relay import UdpRelay

    parent = os.getppid()
    relay = UdpRelay(vehicle_port, seed=seed, conditions=conditions).start()
    conn.send(("ready", relay.port))
    try:
        while True:
            if not conn.poll(PARENT_CHECK_S):
                if os.getppid() != parent:
                    return
                continue
            try:
                name, args = conn.recv()
            except EOFError:
                return
            if name == "close":
                relay.close()
                conn.send(("ok", relay.stats()))
                return
            try:
                conn.send(("ok", _call(relay, name, args)))
            except Exception as exc:  # noqa: BLE001 - the parent gets the error
                conn.send(("error", f"{type(exc).__name__}: {exc}"))
    finally:
        relay.close()


def _call(relay, name: str, args: tuple) -> Any:
    if name == "history":
        command, sent = args
        return relay.history(command, sent=sent)
    if name == "vehicle_time_ms":
        return relay.vehicle_time_ms
    return getattr(relay, name)(*args)


class RelayProcess:
    """``with RelayProcess(sim.port, seed=1, conditions=LinkConditions(loss=0.02)) as relay:`` — the
    companion connects to ``relay.endpoint``; the methods mirror :class:`harness.udp_relay.UdpRelay`'s."""

    transport = "udp"

    def __init__(self, vehicle_port: int, *, seed: int = 0,
                 conditions: LinkConditions | dict[str, LinkConditions] | None = None) -> None:
        context = multiprocessing.get_context("spawn")
        self._conn, child = context.Pipe()
        self._process = context.Process(target=_serve, args=(child, vehicle_port, seed, conditions),
                                        name="udp-relay", daemon=True)
        self._process.start()
        child.close()
        if not self._conn.poll(START_TIMEOUT_S):
            self._process.kill()
            raise RuntimeError("the relay process did not start")
        _, self.port = self._conn.recv()
        self.final_stats: dict | None = None

    @property
    def endpoint(self) -> str:
        return f"udpout:127.0.0.1:{self.port}"

    def _request(self, name: str, *args: Any) -> Any:
        self._conn.send((name, args))
        if not self._conn.poll(CALL_TIMEOUT_S):
            raise RuntimeError(f"the relay process did not answer {name}")
        status, value = self._conn.recv()
        if status != "ok":
            raise RuntimeError(f"relay {name}: {value}")
        return value

    def arm(self, faults: Iterable[Fault]) -> None:
        self._request("arm", list(faults))

    def disarm(self) -> None:
        self._request("disarm")

    def count(self, message: str, direction: str = TO_VEHICLE) -> int:
        return self._request("count", message, direction)

    def summary(self) -> list[dict]:
        return self._request("summary")

    def stats(self) -> dict:
        return self.final_stats if self.final_stats is not None else self._request("stats")

    def socket_drops(self) -> dict[str, int]:
        return self._request("socket_drops")

    def drain(self, timeout_s: float = 1.0) -> bool:
        return self._request("drain", timeout_s)

    def history(self, command: int, *, sent: bool = False) -> list[CommandDelivery]:
        """The COMMAND_LONGs ``command`` delivered to the vehicle (``sent``: as the companion sent them)."""
        return self._request("history", command, sent)

    def acks(self) -> list[tuple[float, int, int]]:
        return self._request("acks")

    @property
    def vehicle_time_ms(self) -> int | None:
        return self._request("vehicle_time_ms")

    def close(self) -> None:
        """Stop the relay (its last stats are kept: :meth:`stats`) and the process."""
        if self.final_stats is None and self._process.is_alive():
            try:
                self.final_stats = self._request("close")
            except (RuntimeError, OSError, EOFError) as exc:
                log.warning("relay process: %s", exc)
        self._process.join(timeout=5.0)
        if self._process.is_alive():
            self._process.kill()
            self._process.join(timeout=5.0)
        self._conn.close()

    def __enter__(self) -> "RelayProcess":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
