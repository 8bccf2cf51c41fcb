"""An attack on the status page (``companion run --http``), from threads of a process of its own.

Three kinds of client, all at once, until told to stop:

* **slowloris**: several hundred connections that each send half a request (the request line and a
  ``Host``, never the blank line that ends the headers), then trickle one more byte of a header every
  ``trickle_s`` (shorter than the page's idle timeout, so an idle timeout alone never closes them). A
  connection the page closed (503 at once, or closed when it gave up on it) is opened again.
* **flood**: threads sending complete requests (``GET /status.json`` and ``GET /``, one per
  connection, ``Connection: close``) as fast as the answers come back.
* **malformed**: garbage bytes, a TLS ClientHello, a request line of 64 kB, one header line of
  70 kB, a thousand headers, an unknown method, an HTTP/0.9 line and a request cut in the middle.

Every answer is counted by its status code, every connection the kernel refused or reset, and every
one that timed out (:class:`AttackCounts`).

Why a process of its own: a test's ground station reads the simulator's stream with pymavlink in
Python, and the simulator's TCP flow control makes vehicle time wait for a client that lags. Attack
threads sharing the ground station's interpreter lock would slow the vehicle through the ground
station, which is the harness's weakness, not the companion's. In its own process the attack costs
the companion what a separate attacker costs it: CPU time and the page's own threads. The child is
started with ``spawn`` (the caller's main module must be safe to import).
"""
from __future__ import annotations

import logging
import multiprocessing
import os
import random
import re
import socket
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Any, Callable

log = logging.getLogger(__name__)

__all__ = ["AttackCounts", "AttackPlan", "AttackProcess", "PageAttack", "status_of"]

START_TIMEOUT_S = 20.0
STOP_TIMEOUT_S = 30.0
PARENT_CHECK_S = 1.0  # the child stops when its parent is gone (checked this often)
_ERROR_CODE = re.compile(rb"Error code: (\d{3})")

#: a TLS 1.2 ClientHello's record and handshake headers, as a browser sends to an https:// URL
TLS_CLIENT_HELLO = bytes.fromhex(
    "16030100a5010000a10303" + "00" * 32 + "00" + "0020c02bc02fc02cc030cca9cca8c009c013c00ac014009c009d002f0035000a"
    + "0100" + "0058" + "0000000e000c0000096c6f63616c686f7374" + "000b000403000102" + "000a000a0008001d001700180019"
    + "0023000000160000001700000d0020001e060106020603050105020503040104020403030103020303020102020203")


def status_of(answer: bytes) -> str:
    """The status code an answer carries (``"200"``, ``"503"``, ...), ``"closed"`` for no answer.

    The standard library answers a request line it cannot parse in the HTTP/0.9 style: no status
    line, the code in the body (``Error code: 400``)."""
    if not answer:
        return "closed"
    if answer.startswith(b"HTTP/1.") and len(answer) >= 12:
        return answer[9:12].decode("ascii", "replace")
    match = _ERROR_CODE.search(answer)
    return match.group(1).decode("ascii") if match else "unparsed"


@dataclass
class AttackPlan:
    """How hard to attack: connection counts, threads and pacing."""

    slowloris: int = 300  # half-open connections kept open (re-opened when closed)
    slowloris_threads: int = 3
    trickle_s: float = 1.0  # one more byte on every half-open connection this often (< the idle timeout)
    flooders: int = 4  # threads sending complete requests back to back
    malformed_threads: int = 1
    connect_timeout_s: float = 2.0
    answer_timeout_s: float = 10.0


@dataclass
class AttackCounts:
    """What the attack saw, by kind of client: answers by status code and connection failures.

    Per kind (``slowloris``, ``flood``, ``malformed``) a Counter of ``"200"``, ``"503"``, ``"400"``,
    ... (answers), ``"closed"`` (closed without an answer), ``"refused"`` (connect refused or timed
    out: the backlog was full), ``"reset"`` (reset by the page), ``"timeout"`` (no answer in time);
    ``slowloris["opened"]`` counts the half-open connections opened and ``slowloris["held_max"]`` the
    most open at once (the attacker's side: open until it sees the page's answer or close).
    ``flood_latency_max_s`` is the longest a complete request waited for its answer,
    ``flood_longest_without_200_s`` the longest stretch of the attack (its start and end included) in
    which no complete request was answered 200."""

    slowloris: Counter = field(default_factory=Counter)
    flood: Counter = field(default_factory=Counter)
    malformed: Counter = field(default_factory=Counter)
    flood_latency_max_s: float = 0.0
    flood_longest_without_200_s: float = 0.0
    duration_s: float = 0.0
    errors: list[str] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        return {"slowloris": dict(self.slowloris), "flood": dict(self.flood), "malformed": dict(self.malformed),
                "flood_latency_max_s": round(self.flood_latency_max_s, 3),
                "flood_longest_without_200_s": round(self.flood_longest_without_200_s, 3),
                "duration_s": round(self.duration_s, 3), "errors": list(self.errors)}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "AttackCounts":
        return cls(Counter(data["slowloris"]), Counter(data["flood"]), Counter(data["malformed"]),
                   data["flood_latency_max_s"], data["flood_longest_without_200_s"], data["duration_s"],
                   list(data["errors"]))

    def answered(self, *codes: str) -> int:
        """Answers with one of ``codes`` over every kind of client."""
        return sum(counts[code] for counts in (self.slowloris, self.flood, self.malformed) for code in codes)

    def refused(self) -> int:
        """Connections the kernel refused or that timed out connecting (the backlog was full)."""
        return sum(counts["refused"] for counts in (self.slowloris, self.flood, self.malformed))


class PageAttack:
    """The attack's threads in this process (:meth:`start`, :meth:`stop` → :class:`AttackCounts`)."""

    def __init__(self, host: str, port: int, plan: AttackPlan | None = None, seed: int = 1) -> None:
        self.address = (host, port)
        self.plan = plan or AttackPlan()
        self.counts = AttackCounts()
        self._lock = threading.Lock()  # guards self.counts
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._rng = random.Random(seed)
        self._started = 0.0
        self._last_ok = 0.0  # time.monotonic() of the last 200 to a complete request (the start before one)
        self._held: dict[str, int] = {}  # half-open connections each slowloris thread holds open

    # -- running -------------------------------------------------------------------------------------
    def start(self) -> "PageAttack":
        self._started = self._last_ok = time.monotonic()
        plan = self.plan
        share = [plan.slowloris // plan.slowloris_threads + (i < plan.slowloris % plan.slowloris_threads)
                 for i in range(plan.slowloris_threads)]
        for i, count in enumerate(share):
            self._spawn(f"slowloris-{i}", self._slowloris, count)
        for i in range(plan.flooders):
            self._spawn(f"flood-{i}", self._flood, ("/status.json", "/")[i % 2])
        for i in range(plan.malformed_threads):
            self._spawn(f"malformed-{i}", self._malformed, i)
        return self

    def stop(self) -> AttackCounts:
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=self.plan.answer_timeout_s + 5.0)
        with self._lock:
            now = time.monotonic()
            self.counts.duration_s = now - self._started
            self.counts.flood_longest_without_200_s = max(self.counts.flood_longest_without_200_s, now - self._last_ok)
            return self.counts

    def _spawn(self, name: str, target: Callable[..., None], arg: Any) -> None:
        thread = threading.Thread(target=self._guarded, args=(target, arg), name=name, daemon=True)
        self._threads.append(thread)
        thread.start()

    def _guarded(self, target: Callable[..., None], arg: Any) -> None:
        try:
            target(arg)
        except Exception as exc:  # noqa: BLE001 - said in the counts, never lost
            log.exception("attack thread failed")
            with self._lock:
                self.counts.errors.append(f"{threading.current_thread().name}: {exc!r}")

    def _count(self, kind: str, outcome: str, amount: int = 1) -> None:
        with self._lock:
            getattr(self.counts, kind)[outcome] += amount

    def _connect(self, kind: str) -> socket.socket | None:
        try:
            return socket.create_connection(self.address, timeout=self.plan.connect_timeout_s)
        except (ConnectionRefusedError, TimeoutError, socket.timeout):
            self._count(kind, "refused")
        except OSError:
            self._count(kind, "reset")
        return None

    def _exchange(self, kind: str, payload: bytes, chunked: bool = False) -> str:
        """Send ``payload`` on a fresh connection and read the answer to its end: the outcome."""
        sock = self._connect(kind)
        if sock is None:
            return "refused"
        outcome = "closed"
        try:
            sock.settimeout(self.plan.answer_timeout_s)
            try:
                if chunked:  # a large payload may be answered (and closed) before it is all sent
                    for offset in range(0, len(payload), 16384):
                        sock.sendall(payload[offset:offset + 16384])
                else:
                    sock.sendall(payload)
            except (BrokenPipeError, ConnectionResetError):
                pass  # the page answered and closed early: read what it said
            answer = bytearray()
            while chunk := sock.recv(65536):  # to the end, as a client does; the head is enough to count
                if len(answer) < 4096:
                    answer += chunk
            outcome = status_of(bytes(answer))
        except (TimeoutError, socket.timeout):
            outcome = "timeout"
        except OSError:
            outcome = "reset"
        finally:
            sock.close()
        self._count(kind, outcome)
        return outcome

    # -- the three kinds of client -------------------------------------------------------------------
    def _slowloris(self, count: int) -> None:
        """``count`` half-open connections, each trickled one byte every ``trickle_s``."""
        held: list[socket.socket] = []
        while not self._stop.is_set():
            while len(held) < count and not self._stop.is_set():
                sock = self._connect("slowloris")
                if sock is None:
                    break
                try:
                    sock.sendall(b"GET /status.json HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ")
                    sock.setblocking(False)
                except OSError:
                    sock.close()
                    self._count("slowloris", "reset")
                    continue
                held.append(sock)
                self._count("slowloris", "opened")
            with self._lock:
                self._held[threading.current_thread().name] = len(held)
                self.counts.slowloris["held_max"] = max(self.counts.slowloris["held_max"], sum(self._held.values()))
            self._stop.wait(self.plan.trickle_s)
            still: list[socket.socket] = []
            for sock in held:
                outcome = self._trickle(sock)
                if outcome is None:
                    still.append(sock)
                else:
                    sock.close()
                    self._count("slowloris", outcome)
            held = still
        for sock in held:
            sock.close()

    @staticmethod
    def _trickle(sock: socket.socket) -> str | None:
        """One more byte on a half-open connection; the outcome if the page ended it, else None."""
        try:
            answer = sock.recv(4096)
            return status_of(answer)  # an answer (503 at once, or a timeout's 408/400) or a close
        except BlockingIOError:
            pass
        except OSError:
            return "reset"
        try:
            sock.send(b"a")
        except BlockingIOError:
            pass
        except OSError:
            return "reset"
        return None

    def _flood(self, path: str) -> None:
        """Complete requests back to back, one per connection."""
        request = f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n".encode("ascii")
        while not self._stop.is_set():
            began = time.monotonic()
            outcome = self._exchange("flood", request)
            if outcome in ("refused", "reset", "timeout"):
                continue
            now = time.monotonic()
            with self._lock:
                self.counts.flood_latency_max_s = max(self.counts.flood_latency_max_s, now - began)
                if outcome == "200":
                    gap = now - self._last_ok
                    self.counts.flood_longest_without_200_s = max(self.counts.flood_longest_without_200_s, gap)
                    self._last_ok = now

    def _malformed(self, index: int) -> None:
        """Malformed requests in turn, each on a fresh connection."""
        payloads: list[tuple[bytes, bool]] = [
            (TLS_CLIENT_HELLO, False),
            (b"GET /" + b"a" * 65536 + b" HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n", True),  # a 64 kB request line
            (b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Big: " + b"b" * 70000 + b"\r\n\r\n", True),  # one huge header
            (b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n" + b"".join(b"X-%d: y\r\n" % i for i in range(1000)) + b"\r\n",
             True),  # a thousand headers
            (b"BREW /pot HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n", False),
            (b"GET /\r\n", False),  # HTTP/0.9
            (b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: 100\r\n\r\nshort", False),
            (b"\x00\xff\r\n\r\n", False),
        ]
        turn = index
        while not self._stop.is_set():
            if turn % len(payloads) == len(payloads) - 1:
                payload = bytes(self._rng.getrandbits(8) for _ in range(self._rng.randint(1, 2048))) + b"\r\n\r\n"
                self._exchange("malformed", payload)  # random garbage
            else:
                self._exchange("malformed", *payloads[turn % len(payloads)])
            turn += 1


def _child(host: str, port: int, plan: AttackPlan, started, stop, results, parent_pid: int) -> None:
    """The attack process: attack until ``stop`` is set (or the parent is gone), then report."""
    attack = PageAttack(host, port, plan).start()
    started.set()
    while not stop.wait(PARENT_CHECK_S):
        if os.getppid() != parent_pid:
            break
    results.put(attack.stop().as_dict())


class AttackProcess:
    """:class:`PageAttack` in a child process (module docstring: why). ``with AttackProcess(...) as a:``
    attacks for the block; :attr:`counts` holds what it saw afterwards."""

    def __init__(self, host: str, port: int, plan: AttackPlan | None = None) -> None:
        context = multiprocessing.get_context("spawn")
        self._started, self._stop, self._results = context.Event(), context.Event(), context.Queue()
        self._process = context.Process(target=_child, name="page-attack", daemon=True,
                                        args=(host, port, plan or AttackPlan(), self._started, self._stop,
                                              self._results, os.getpid()))
        self.counts: AttackCounts | None = None

    def start(self) -> "AttackProcess":
        self._process.start()
        if not self._started.wait(START_TIMEOUT_S):
            self._process.kill()
            raise RuntimeError("the attack process did not start")
        return self

    def stop(self) -> AttackCounts:
        self._stop.set()
        try:
            self.counts = AttackCounts.from_dict(self._results.get(timeout=STOP_TIMEOUT_S))
        finally:
            self._process.join(timeout=5.0)
            if self._process.is_alive():
                self._process.kill()
                self._process.join(timeout=5.0)
        return self.counts

    def __enter__(self) -> "AttackProcess":
        return self.start()

    def __exit__(self, *exc) -> None:
        if self.counts is None:
            self.stop()
