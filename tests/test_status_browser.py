"""The status page in a real browser: headless Chromium (Debian's ``chromium``) loads the page of
``companion run --http 127.0.0.1:0`` beside the simulator while a ground station's campaign runs,
its JavaScript fetches ``/status.json`` and fills the cards: the DOM shows the vehicle and the
procedure, and a screenshot is taken (``STATUS_PAGE_SCREENSHOT=FILE`` keeps a copy, e.g. for
docs/status_page.png). The same checks fail on a page whose data never loads (the page's own files
served beside a ``/status.json`` that answers 503), so the test can tell a broken page. Skipped when
``/usr/bin/chromium`` is not installed, except in CI (``CI`` set: ``.ci/run`` installs it), where a
missing browser fails. Loopback only.
"""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest

from tests.test_e2e_gcs import arm, start, wait_for_companion
from tests.test_service_unit import _wait_for_line

CHROMIUM = Path("/usr/bin/chromium")
ROOT = Path(__file__).resolve().parents[1]
MAV_CMD_USER_1 = 31010

STATIC = ROOT / "companion" / "service" / "static"

pytestmark = [pytest.mark.e2e,
              pytest.mark.skipif(not CHROMIUM.is_file() and not os.environ.get("CI"),
                                 reason="no /usr/bin/chromium (apt-get install chromium; .ci/run installs it)")]


def not_drawn(dom: str) -> list[str]:
    """What the page should show once its data loaded and is not in ``dom`` (empty: all drawn)."""
    wanted = ("vehicle connected", "identification running", "profile sim", "<dt>mode</dt><dd>hold</dd>",
              "<td>a22</td>", "Identification runs")
    return [text for text in wanted if text not in dom]


def chromium(tmp_path: Path, url: str, *extra: str) -> subprocess.CompletedProcess:
    """One headless Chromium run on a fresh profile, loopback only, with 4 s of the page's time to
    fetch and draw (virtual time: its timers run without waiting for the wall clock)."""
    profile = tmp_path / f"chromium-{time.monotonic_ns()}"
    flags = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
             "--disable-background-networking", "--disable-component-update", "--disable-sync",
             "--disable-extensions", f"--user-data-dir={profile}", "--virtual-time-budget=4000", *extra, url]
    try:
        return subprocess.run([str(CHROMIUM), *flags], capture_output=True, text=True, timeout=90)
    finally:
        shutil.rmtree(profile, ignore_errors=True)


def page_state(url: str) -> dict:
    with urllib.request.urlopen(url + "status.json", timeout=5) as response:
        return json.loads(response.read())


@pytest.mark.slow
def test_the_page_shows_the_vehicle_and_the_procedure(sim_factory, mav_client, tmp_path):
    # TCP: lossless; 5x: acknowledgements keep their margin on a loaded machine (the product runs at 1x)
    sim = sim_factory(transport="tcp", speedup=5, seed=2)
    gcs = mav_client(sim.endpoint)
    stderr = tmp_path / "stderr.log"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    with open(stderr, "w") as err:
        process = subprocess.Popen([sys.executable, "-m", "companion", "run", "--connect", sim.endpoint,
                                    "--store", str(tmp_path / "store.sqlite"), "--http", "127.0.0.1:0"],
                                   cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=err, env=env)
    try:
        url = _wait_for_line(stderr, "status page: ", process)
        assert url.startswith("http://127.0.0.1:") and not url.endswith(":0/")
        wait_for_companion(gcs)
        arm(gcs)
        assert start(gcs, MAV_CMD_USER_1)
        deadline = time.monotonic() + 60.0
        state = page_state(url)  # until the first training streams its live estimates
        while not (state["procedure"]["state"] == "running" and "a22" in (state["estimates"] or {})) \
                and time.monotonic() < deadline:
            time.sleep(0.25)
            state = page_state(url)
        assert state["procedure"]["name"] == "identification" and "a22" in state["estimates"], state
        shot = tmp_path / "status_page.png"  # one run: the DOM after the page's fetches, and its picture
        done = chromium(tmp_path, url, "--dump-dom", f"--screenshot={shot}", "--window-size=1280,1150",
                        "--hide-scrollbars")
        dom = done.stdout
    finally:
        process.send_signal(signal.SIGTERM)
        process.wait(timeout=60)
    assert not_drawn(dom) == [], dom[:3000]  # the vehicle, the procedure and the live estimates were drawn
    assert shot.is_file() and shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and shot.stat().st_size > 20_000, done.stderr
    keep = os.environ.get("STATUS_PAGE_SCREENSHOT")
    if keep:
        shutil.copyfile(shot, keep)


def test_the_same_checks_fail_on_a_page_whose_data_never_loads(tmp_path):
    """The page's own files, served beside a /status.json that answers 503: nothing is drawn, and
    the checks of the test above say so."""
    import http.server
    import threading

    class BrokenStatus(http.server.BaseHTTPRequestHandler):
        def do_GET(self):  # noqa: N802 - the standard library's name
            name = self.path.split("?")[0].lstrip("/") or "status.html"
            path = STATIC / name
            if name == "status.json" or not path.is_file():
                self.send_error(503, "no data")
                return
            body = path.read_bytes()
            kind = {".html": "text/html", ".js": "text/javascript", ".css": "text/css"}[path.suffix]
            self.send_response(200)
            self.send_header("Content-Type", kind)
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args):
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), BrokenStatus)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        dom = chromium(tmp_path, f"http://127.0.0.1:{server.server_address[1]}/", "--dump-dom").stdout
    finally:
        server.shutdown()
        server.server_close()
    assert "<html" in dom.lower()  # the browser did load the page itself
    assert set(not_drawn(dom)) >= {"vehicle connected", "<td>a22</td>"}, dom[:3000]
