"""The status page of ``companion run --http``: the board (thread-safe, strict JSON), the server
(read-only, loopback, its routes) and the feed that fills the board from the resident loop."""
from __future__ import annotations

import http.client
import json
import math
import threading
from pathlib import Path
from types import SimpleNamespace

import pytest

from companion.interface import Telemetry
from companion.link.ground_station import Report
from companion.link.profiles import get_profile
from companion.procedures.resident import ServeConfig
from companion.records.store import Store
from companion.service.feed import StatusFeed
from companion.service.http import HttpConfigError, StatusServer, is_loopback
from companion.service.status import SECTIONS, StatusBoard, json_ready
from tests.test_serve import stored_models

USER_1, IN_PROGRESS = 31010, 5


def request(server: StatusServer, method: str, path: str, host: str | None = None, body: bytes | None = None):
    conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=5)
    headers = {"Host": host} if host is not None else {}
    conn.request(method, path, body=body, headers=headers)
    response = conn.getresponse()
    data = response.read()
    conn.close()
    return response.status, dict(response.getheaders()), data


@pytest.fixture
def served():
    board = StatusBoard()
    report: dict[str, Path | None] = {"path": None}
    with StatusServer(board, "127.0.0.1", 0, report=lambda: report["path"], poll_interval_s=0.02) as server:
        yield board, server, report


def test_json_never_holds_nan_or_infinity():
    board = StatusBoard()
    board.set("vehicle", {"time_s": 3.0, "depth": math.nan, "speed_water": math.inf, "list": (1.0, -math.inf)})
    data = json.loads(board.to_json())  # strict: allow_nan=False when written
    assert data["vehicle"]["depth"] is None and data["vehicle"]["speed_water"] is None
    assert data["vehicle"]["list"] == [1.0, None] and data["vehicle"]["telemetry_age_s"] >= 0.0
    assert list(data) == list(SECTIONS)
    assert json_ready({1: {"x": float("nan")}}) == {"1": {"x": None}}
    with pytest.raises(KeyError):
        board.set("commands", {})


def test_the_board_is_read_whole_while_written(served):
    board, _server, _ = served
    stop = threading.Event()

    def writer():
        i = 0
        while not stop.is_set():
            i += 1
            board.set("procedure", {"state": "running", "progress_pct": i, "copy": i})

    thread = threading.Thread(target=writer)
    thread.start()
    try:
        for _ in range(200):
            section = json.loads(board.to_json())["procedure"]
            assert section is None or section["progress_pct"] == section["copy"]
    finally:
        stop.set()
        thread.join()


def test_routes_of_a_read_only_page(served):
    board, server, report = served
    board.set("connection", {"endpoint": "udpin:0.0.0.0:14551", "system_id": 1, "profile": "sim"})
    status, headers, body = request(server, "GET", "/status.json")
    assert status == 200 and headers["Content-Type"] == "application/json" and headers["Cache-Control"] == "no-store"
    assert json.loads(body)["connection"]["profile"] == "sim"
    for path, kind in (("/", "text/html"), ("/status.js", "text/javascript"), ("/status.css", "text/css")):
        status, headers, body = request(server, "GET", path)
        assert status == 200 and headers["Content-Type"].startswith(kind) and body
        assert "default-src 'self'" in headers["Content-Security-Policy"]
    assert b"/status.json" in request(server, "GET", "/status.js")[2]
    assert request(server, "HEAD", "/status.json")[2] == b""
    assert request(server, "GET", "/nothing")[0] == 404
    assert request(server, "GET", "/report")[:2][0] == 302
    assert request(server, "GET", "/report/")[0] == 404  # no report yet


@pytest.mark.parametrize("method", ["POST", "PUT", "DELETE", "PATCH", "OPTIONS", "TRACE", "ARM"])
def test_every_other_method_is_405(served, method):
    _board, server, _ = served
    status, headers, _ = request(server, method, "/status.json", body=b"{}")
    assert status == 405 and headers["Allow"] == "GET, HEAD"


def test_only_loopback_host_names_are_answered(served):
    _board, server, _ = served
    for host in ("127.0.0.1", f"127.0.0.1:{server.port}", "localhost", "[::1]:80"):
        assert request(server, "GET", "/status.json", host=host)[0] == 200, host
    for host in ("attacker.example", "attacker.example:80", "10.0.0.2", ""):
        assert request(server, "GET", "/status.json", host=host)[0] == 403, host


def test_a_network_address_needs_an_explicit_allowance():
    assert is_loopback("127.0.0.1") and is_loopback("localhost") and is_loopback("::1")
    assert not is_loopback("0.0.0.0") and not is_loopback("192.0.2.1")
    with pytest.raises(HttpConfigError, match="not a loopback address"):
        StatusServer(StatusBoard(), "0.0.0.0", 0)
    server = StatusServer(StatusBoard(), "0.0.0.0", 0, allow_remote=True)
    server.close()


def test_the_report_and_its_images_and_nothing_beside(served, tmp_path):
    _board, server, report = served
    folder = tmp_path / "reports" / "campaign-3"
    folder.mkdir(parents=True)
    (folder / "report.html").write_text("<img src='b2_law.png'>")
    (folder / "b2_law.png").write_bytes(b"\x89PNG")
    (tmp_path / "reports" / "secret.png").write_bytes(b"secret")
    report["path"] = folder / "report.html"
    assert request(server, "GET", "/report/")[2] == b"<img src='b2_law.png'>"
    status, headers, body = request(server, "GET", "/report/b2_law.png")
    assert status == 200 and headers["Content-Type"] == "image/png" and body == b"\x89PNG"
    for path in ("/report/../secret.png", "/report/%2e%2e/secret.png", "/report/missing.png", "/report/x.html"):
        assert request(server, "GET", path)[0] == 404, path


class FakeLink:
    """What the feed reads of a VehicleLink: profile, ids, parameter cache, latest snapshot, hooks."""

    def __init__(self) -> None:
        self.profile = get_profile("sim")
        self.transport = SimpleNamespace(system_id=1, component=191, autopilot_component=1)
        self.parameters = SimpleNamespace(cache={"HDG_P": 0.64, "HDG_I": 0.01})
        self.latest_telemetry = None
        self.vehicle_time_s = 0.0
        self.statustexts = [(5.0, 2, "PreArm: compass not calibrated"), (6.0, 6, "hello")]
        self.reports, self.snapshots = [], []
        self.ground = SimpleNamespace(on_report=self.reports.append)
        self.telemetry = SimpleNamespace(after_snapshot=self.snapshots.append)
        self.read = []

    def get_param(self, name: str) -> float:
        self.read.append(name)
        self.parameters.cache[name] = 0.02
        return 0.02

    def snapshot(self, telemetry: Telemetry) -> None:
        self.latest_telemetry, self.vehicle_time_s = telemetry, telemetry.time_s
        for listener in self.snapshots:
            listener()


def test_the_feed_fills_every_section_from_the_loop_and_the_reports(tmp_path):
    board, link = StatusBoard(), FakeLink()
    companion = SimpleNamespace(config=ServeConfig(), scheduler=None, health=None, stop=lambda: None)
    with Store(tmp_path / "s.sqlite") as store:
        stored_models(store)
        feed = StatusFeed(board, link, store, endpoint="udpin:0.0.0.0:14551", report_dir=tmp_path / "reports")
        feed.watch(companion, "9.9")
        assert link.read == ["HDG_TRIM"]  # the gains as found, read once; those in the cache are not asked again
        tell = link.reports[0]
        tell(Report("value", 12.0, name="a22", value=-1.1))
        tell(Report("value", 12.5, name="b2", value=math.nan))
        feed.procedure_started("identification", USER_1)
        tell(Report("ack", 13.0, command=USER_1, result=IN_PROGRESS, progress=40))
        tell(Report("text", 13.5, text="thrust 0.70: model accepted", severity=6))
        tell(Report("text", 14.0, text="gain scheduling: write failed", severity=4))
        link.snapshot(Telemetry(time_s=14.2, yaw=-0.5, depth=math.nan, speed_water=1.4, mode="hold", armed=True))
        during = json.loads(board.to_json())
        feed.procedure_finished({"procedure": "identification", "status": "completed", "reason": None,
                                 "campaign_id": 1})
        after = json.loads(board.to_json())
    assert during["companion"]["version"] == "9.9" and during["connection"]["system_id"] == 1
    assert during["vehicle"]["mode"] == "hold" and during["vehicle"]["depth"] is None
    assert during["vehicle"]["heading_deg"] == pytest.approx(math.degrees(-0.5) % 360)
    assert during["procedure"]["state"] == "running" and during["procedure"]["progress_pct"] == 40
    assert during["estimates"]["a22"]["value"] == -1.1 and during["estimates"]["b2"]["value"] is None
    assert during["models"]["accepted"] == 3 and during["models"]["runs"][0]["model"]["a22"] == -1.0
    assert during["schedule"]["designs"][0]["kind"] == "heading" and "b2 =" in during["schedule"]["designs"][0]["law"]
    gains = {g["name"]: g["value"] for g in during["gains"]["on_vehicle"]}
    assert gains == {"HDG_P": 0.64, "HDG_I": 0.01, "HDG_TRIM": 0.02}
    assert [a["text"] for a in during["alarms"]] == ["PreArm: compass not calibrated", "gain scheduling: write failed"]
    assert during["health"] == {"on": False, "reason": "health monitoring is off"}
    assert during["learning"] == {"on": False, "reason": "learning is off (companion run --learn)"}
    assert after["procedure"]["state"] == "idle" and after["procedure"]["last"]["status"] == "completed"
    assert after["history"][0]["campaign_id"] == 1
    assert after["report"]["url"] == "/report/" and Path(after["report"]["path"]).is_file()
    assert Path(after["report"]["path"]).parent.name == "campaign-1"


def test_a_feed_that_fails_never_stops_the_loop(tmp_path):
    board, link = StatusBoard(), FakeLink()
    with Store(tmp_path / "s.sqlite") as store:
        feed = StatusFeed(board, link, store, endpoint="x")
        feed.watch(SimpleNamespace(config=ServeConfig(), scheduler=None, health=None, stop=lambda: None))
        store.close()  # every store read now fails
        link.snapshot(Telemetry(time_s=1.0, mode="hold"))  # must not raise
    assert json.loads(board.to_json())["vehicle"]["mode"] == "hold"


def test_a_flood_of_half_open_connections_costs_bounded_threads_and_passes(served, monkeypatch):
    """300 connections that send half a request and wait (slowloris): at most MAX_CONNECTIONS
    threads serve them, the rest are answered 503 at once, the idle ones are closed after the idle
    timeout, and the page answers again; malformed HTTP is a 400. (700 such connections once made
    700 threads and starved the resident loop of telemetry.)"""
    import socket
    import time

    from companion.service import http as page

    monkeypatch.setattr(page.StatusHandler, "timeout", 0.5)  # the idle timeout, short for the test
    board, server, _ = served
    board.set("companion", {"version": "x"})
    before = threading.active_count()
    sockets = []
    try:
        for _ in range(300):
            s = socket.create_connection(("127.0.0.1", server.port), timeout=2)
            s.sendall(b"GET /status.json HTTP/1.1\r\nHost: 127.0.0.1\r\n")  # never finished
            sockets.append(s)
        assert threading.active_count() - before <= page.MAX_CONNECTIONS
        answers = []
        for s in sockets:  # each one answered 503 at once, or closed once idle: none left hanging
            s.settimeout(2.0)
            answers.append(s.recv(64))
        busy = sum(answer.startswith(b"HTTP/1.1 503") for answer in answers)
        assert busy >= 100 and all(answer == b"" or answer.startswith(b"HTTP/1.1 503") for answer in answers)
    finally:
        for s in sockets:
            s.close()
    deadline = time.monotonic() + 5.0
    while threading.active_count() > before and time.monotonic() < deadline:  # the idle ones time out
        time.sleep(0.05)
    assert request(server, "GET", "/status.json")[0] == 200
    garbage = socket.create_connection(("127.0.0.1", server.port), timeout=2)
    garbage.sendall(b"\x16\x03\x01 not http at all\r\n\r\n")
    answer = b""
    while chunk := garbage.recv(4096):  # an HTTP/0.9-style error page: no status line, code in the body
        answer += chunk
    assert b"Error code: 400" in answer
    garbage.close()


def test_a_request_head_that_trickles_is_closed_at_its_deadline(served, monkeypatch):
    """A slowloris that sends one more byte of a header before each idle timeout never lets a read
    time out; the head's deadline closes it all the same, and the slot serves a complete request."""
    import socket
    import time

    from companion.service import http as page

    monkeypatch.setattr(page.StatusHandler, "timeout", 0.5)  # the idle timeout, short for the test
    monkeypatch.setattr(page, "REQUEST_HEAD_S", 1.0)
    _, server, _ = served
    slow = socket.create_connection(("127.0.0.1", server.port), timeout=2)
    began = time.monotonic()
    slow.sendall(b"GET /status.json HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ")
    slow.settimeout(0.2)
    closed_after = None
    while time.monotonic() - began < 3.0:  # a byte every 0.2 s: well inside the idle timeout
        try:
            if slow.recv(4096) == b"":
                closed_after = time.monotonic() - began
                break
        except socket.timeout:
            pass
        try:
            slow.send(b"a")
        except OSError:
            closed_after = time.monotonic() - began
            break
    slow.close()
    assert closed_after is not None and 0.9 <= closed_after < 2.0, closed_after
    assert request(server, "GET", "/status.json")[0] == 200
