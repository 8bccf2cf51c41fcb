"""The status page's server: the standard library's ``ThreadingHTTPServer`` in a daemon thread.

Why this stack: the companion runs on a small ARM board next to the autopilot. The standard library
adds no dependency to install or keep patched, no build step and no event loop beside the resident
loop; the page is one static HTML file, one stylesheet and a little vanilla JavaScript that polls
``/status.json`` once a second. A thread answers a request by copying the board
(:class:`companion.service.status.StatusBoard`) under its lock: the resident loop is never blocked
by a browser, and a browser can never reach the vehicle.

Read-only: GET and HEAD only, every other method is answered 405; nothing served changes anything.
Routes: ``/`` the page, ``/status.js``, ``/status.css``, ``/status.json`` the board, ``/report``
(→ ``/report/``) the latest campaign report with its images (``/report/NAME.png``).

Bounded: at most ``MAX_CONNECTIONS`` connections are served at once (one thread each); one more is
answered 503 at once by the accepting thread and closed, a connection idle for ``IDLE_TIMEOUT_S``
(a half-open request, a client that stopped reading) is closed, and so is one whose request head
(request line and headers) has not arrived whole ``REQUEST_HEAD_S`` after the wait for it began,
however it trickles (a slowloris sending a byte every few seconds never lets a read time out). So a
flood of connections or a slowloris costs a bounded number of threads, never the resident loop's
time (700 half-open connections once starved it of telemetry for 5 s), and a slot held by a request
that never completes is free again within ``REQUEST_HEAD_S``; the standard library's server with
these bounds keeps the reasons above (no dependency, no event loop), where an asynchronous server
would add both. What it costs: while a slowloris keeps all the slots, complete requests are mostly
answered 503 (a share of them 200, each time the deadline frees the slots); the vehicle loop does
not notice (``tests/test_status_page_under_attack.py``). A handler's failure is logged at debug
level, never as a traceback.

Bound to loopback unless the caller allows another address (``--http-allow-remote``, logged as a
warning: anyone who can reach the port reads the vehicle's state). On loopback, a request whose
``Host`` is not a loopback name is refused (403), so a web page elsewhere cannot read the status
through a DNS name rebound to 127.0.0.1.
"""
from __future__ import annotations

import io
import ipaddress
import logging
import re
import socket
import threading
import time
from functools import partial
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from pathlib import Path
from typing import Callable

from companion.service.status import StatusBoard

log = logging.getLogger(__name__)

STATIC = {"/": ("status.html", "text/html; charset=utf-8"), "/index.html": ("status.html", "text/html; charset=utf-8"),
          "/status.js": ("status.js", "text/javascript; charset=utf-8"),
          "/status.css": ("status.css", "text/css; charset=utf-8")}
PAGE_POLICY = "default-src 'self'; img-src 'self' data:; frame-ancestors 'none'; base-uri 'none'; form-action 'none'"
_REPORT_FILE = re.compile(r"^/report/([A-Za-z0-9_.-]+\.png)$")
_LOOPBACK_NAMES = ("localhost", "localhost.localdomain", "ip6-localhost")


class HttpConfigError(ValueError):
    """An address the status page may not listen on (the message says why and what to do)."""


def is_loopback(host: str) -> bool:
    """True when every address ``host`` names is a loopback address."""
    name = host.strip("[]")
    if name.lower() in _LOOPBACK_NAMES:
        return True
    try:
        return ipaddress.ip_address(name).is_loopback
    except ValueError:
        pass
    try:
        infos = socket.getaddrinfo(name, None)
    except OSError:
        return False
    return bool(infos) and all(ipaddress.ip_address(info[4][0]).is_loopback for info in infos)


def static_file(name: str) -> bytes:
    return resources.files("companion.service").joinpath("static", name).read_bytes()


#: connections served at once; more are answered 503 and closed
MAX_CONNECTIONS = 16
#: seconds a connection may stay silent (reading a request, or a client not reading the answer)
IDLE_TIMEOUT_S = 5.0
#: seconds a request's head (request line and headers) may take to arrive whole, however it trickles
REQUEST_HEAD_S = 5.0
_BUSY = (b"HTTP/1.1 503 Service Unavailable\r\nContent-Type: text/plain; charset=utf-8\r\nContent-Length: 18\r\n"
         b"Retry-After: 1\r\nConnection: close\r\n\r\nbusy: retry later\n")


class _Server(ThreadingHTTPServer):
    daemon_threads = True
    allow_reuse_address = True
    request_queue_size = 128  # the listen backlog: a burst of connections waits here, not in SYN retries

    def server_activate(self) -> None:
        super().server_activate()
        self._slots = threading.BoundedSemaphore(MAX_CONNECTIONS)

    def process_request(self, request, client_address) -> None:
        """A thread for the connection while a slot is free; else 503 from this thread, at once."""
        if not self._slots.acquire(blocking=False):
            try:
                request.settimeout(0.2)
                request.sendall(_BUSY)
            except OSError:
                pass
            self.shutdown_request(request)
            return
        try:
            super().process_request(request, client_address)
        except BaseException:
            self._slots.release()
            raise

    def process_request_thread(self, request, client_address) -> None:
        try:
            super().process_request_thread(request, client_address)
        finally:
            self._slots.release()

    def handle_error(self, request, client_address) -> None:
        log.debug("status page: connection from %s failed", client_address, exc_info=True)


class StatusServer:
    """The page and its JSON on ``host:port`` (port 0: a free one; :attr:`port` is the bound one)."""

    def __init__(self, board: StatusBoard, host: str = "127.0.0.1", port: int = 0, *, allow_remote: bool = False,
                 report: Callable[[], Path | None] = lambda: None, poll_interval_s: float = 0.5) -> None:
        loopback = is_loopback(host)
        if not loopback and not allow_remote:
            raise HttpConfigError(f"the status page would listen on {host}, which is not a loopback address: "
                                  "give --http-allow-remote (or allow_remote = true in [http]) to serve it to the network")
        family = socket.AF_INET6 if ":" in host.strip("[]") else socket.AF_INET
        server_class = type("StatusHTTPServer", (_Server,), {"address_family": family})
        handler = partial(StatusHandler, board=board, report=report, loopback_only=loopback,
                          files={path: (static_file(name), kind) for path, (name, kind) in STATIC.items()})
        try:
            self.httpd = server_class((host.strip("[]"), port), handler)
        except OSError as exc:
            raise HttpConfigError(f"the status page cannot listen on {host}:{port}: {exc.strerror or exc}") from None
        self.host, self.port = host, int(self.httpd.server_address[1])
        # the thread checks for a shutdown request every poll_interval_s (a close waits up to that long)
        self.thread = threading.Thread(target=self.httpd.serve_forever, args=(poll_interval_s,), name="status-page",
                                       daemon=True)
        if not loopback:
            log.warning("status page served to the network on %s:%d: read-only, without authentication; "
                        "anyone who reaches the port reads the vehicle's state", host, self.port)

    @property
    def url(self) -> str:
        host = f"[{self.host.strip('[]')}]" if ":" in self.host.strip("[]") else self.host
        return f"http://{host}:{self.port}/"

    def start(self) -> "StatusServer":
        self.thread.start()
        return self

    def close(self) -> None:
        if self.thread.is_alive():
            self.httpd.shutdown()
        self.httpd.server_close()

    def __enter__(self) -> "StatusServer":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()


class _HeadDeadlineReader(io.RawIOBase):
    """The connection's reads, each bounded by the idle timeout and, while a request's head is being
    read, by that head's deadline.

    Why: a socket timeout bounds one read, not a request. A slowloris client that sends one more
    byte of a header every few seconds never lets a read time out, so with the idle timeout alone it
    held its connection's slot for as long as it liked, and ``MAX_CONNECTIONS`` such clients made
    the page answer everyone else 503 for good (measured: not one complete request answered 200 in
    the 20 s of a campaign against 300 trickling connections). With the deadline a slot is held at
    most ``REQUEST_HEAD_S`` by a request that never completes."""

    def __init__(self, sock: socket.socket, idle_s: float | None) -> None:
        super().__init__()
        self.sock, self.idle_s = sock, idle_s
        self.deadline: float | None = None  # time.monotonic() by which the current head must be whole

    def readable(self) -> bool:
        return True

    def readinto(self, buffer) -> int:
        timeout = self.idle_s
        if self.deadline is not None:
            remaining = self.deadline - time.monotonic()
            if remaining <= 0:
                raise TimeoutError("the request's head did not arrive in time")
            timeout = remaining if timeout is None else min(timeout, remaining)
        self.sock.settimeout(timeout)
        try:
            return self.sock.recv_into(buffer)
        finally:
            self.sock.settimeout(self.idle_s)  # writes keep the idle timeout


class StatusHandler(BaseHTTPRequestHandler):
    """GET/HEAD of the routes in the module docstring; 405 for every other method. A request's head
    must arrive whole within ``REQUEST_HEAD_S`` (:class:`_HeadDeadlineReader`)."""

    server_version = "marine-companion"
    sys_version = ""
    protocol_version = "HTTP/1.1"
    timeout = IDLE_TIMEOUT_S  # StreamRequestHandler: the connection's socket timeout

    def __init__(self, *args, board: StatusBoard, report: Callable[[], Path | None], loopback_only: bool,
                 files: dict[str, tuple[bytes, str]], **kwargs) -> None:
        self.board, self.report, self.loopback_only, self.files = board, report, loopback_only, files
        super().__init__(*args, **kwargs)

    def setup(self) -> None:
        super().setup()
        self.rfile.close()  # the standard library's reader, replaced by one that keeps the head's deadline
        self._reader = _HeadDeadlineReader(self.connection, self.timeout)
        self.rfile = io.BufferedReader(self._reader)

    def handle_one_request(self) -> None:
        """One request, its head read under the deadline (lifted once the head is parsed)."""
        self._reader.deadline = time.monotonic() + REQUEST_HEAD_S
        try:
            super().handle_one_request()
        finally:
            self._reader.deadline = None

    def parse_request(self) -> bool:
        parsed = super().parse_request()
        self._reader.deadline = None
        return parsed

    def __getattr__(self, name: str):
        # http.server answers a method without a do_<METHOD> with 501; every method but GET and HEAD is 405 here
        if name.startswith("do_"):
            return self._not_allowed
        raise AttributeError(name)

    def _not_allowed(self) -> None:
        self._send(HTTPStatus.METHOD_NOT_ALLOWED, b"read-only: GET and HEAD only\n", "text/plain; charset=utf-8",
                   {"Allow": "GET, HEAD"})

    def do_GET(self) -> None:  # noqa: N802 - http.server's naming
        self._route(body=True)

    def do_HEAD(self) -> None:  # noqa: N802
        self._route(body=False)

    def _route(self, body: bool) -> None:
        if self.loopback_only and not self._host_is_loopback():
            self._send(HTTPStatus.FORBIDDEN, b"this page answers loopback host names only\n",
                       "text/plain; charset=utf-8", body=body)
            return
        path = self.path.split("?", 1)[0].split("#", 1)[0]
        if path in self.files:
            content, kind = self.files[path]
            self._send(HTTPStatus.OK, content, kind, {"Content-Security-Policy": PAGE_POLICY}, body=body)
        elif path == "/status.json":
            self._send(HTTPStatus.OK, self.board.to_json(), "application/json", body=body)
        elif path == "/report":
            self._send(HTTPStatus.FOUND, b"", "text/plain; charset=utf-8", {"Location": "/report/"}, body=body)
        elif path == "/report/" or _REPORT_FILE.match(path):
            self._report(path, body)
        else:
            self._send(HTTPStatus.NOT_FOUND, b"not found\n", "text/plain; charset=utf-8", body=body)

    def _report(self, path: str, body: bool) -> None:
        report = self.report()
        if report is None or not report.is_file():
            self._send(HTTPStatus.NOT_FOUND, b"<!doctype html><title>No report</title><p>No report yet: one is written "
                       b"after each identification campaign when a report directory is configured. <a href='/'>Back</a>",
                       "text/html; charset=utf-8", body=body)
            return
        match = _REPORT_FILE.match(path)
        target = report if match is None else report.parent / match.group(1)
        try:
            content = target.read_bytes()
        except OSError:
            self._send(HTTPStatus.NOT_FOUND, b"not found\n", "text/plain; charset=utf-8", body=body)
            return
        self._send(HTTPStatus.OK, content, "image/png" if match else "text/html; charset=utf-8", body=body)

    def _host_is_loopback(self) -> bool:
        """The request's Host names a loopback address literally (never resolved: a rebound name
        resolves to 127.0.0.1, which is exactly what must not pass)."""
        host = self.headers.get("Host", "").strip()
        if host.startswith("["):
            name = host[1:host.find("]")] if "]" in host else ""
        else:
            name = host.rsplit(":", 1)[0] if ":" in host else host
        return name.lower() in _LOOPBACK_NAMES or _is_loopback_ip(name)

    def _send(self, status: HTTPStatus, content: bytes, kind: str, headers: dict | None = None, body: bool = True) -> None:
        self.send_response(status)
        self.send_header("Content-Type", kind)
        self.send_header("Content-Length", str(len(content)))
        self.send_header("Cache-Control", "no-store")
        self.send_header("X-Content-Type-Options", "nosniff")
        for name, value in (headers or {}).items():
            self.send_header(name, value)
        self.end_headers()
        if body and self.command != "HEAD":
            self.wfile.write(content)

    def log_message(self, format: str, *args) -> None:  # noqa: A002 - http.server's signature
        log.debug("status page: %s %s", self.address_string(), format % args)


def _is_loopback_ip(text: str) -> bool:
    try:
        return ipaddress.ip_address(text).is_loopback
    except ValueError:
        return False
