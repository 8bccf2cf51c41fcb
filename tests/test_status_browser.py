"""The status page in a real browser: headless Chromium (Debian's ``chromium``) loads the page of
``companion run --http 127.0.0.1:0`` beside the simulator while a ground station's campaign runs,
its JavaScript fetches ``/status.json`` and fills the cards: the DOM shows the vehicle and the
procedure, and a screenshot is taken (``STATUS_PAGE_SCREENSHOT=FILE`` keeps a copy, e.g. for
docs/status_page.png). Skipped when ``/usr/bin/chromium`` is not installed. Loopback only.
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

pytestmark = [pytest.mark.e2e, pytest.mark.skipif(not CHROMIUM.is_file(), reason="no /usr/bin/chromium")]


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
    assert "vehicle connected" in dom, dom[:3000]
    assert "identification running" in dom and "profile sim" in dom and "<dt>mode</dt><dd>hold</dd>" in dom
    assert "<td>a22</td>" in dom and "Identification runs" in dom  # the live estimates were drawn
    assert shot.is_file() and shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and shot.stat().st_size > 20_000, done.stderr
    keep = os.environ.get("STATUS_PAGE_SCREENSHOT")
    if keep:
        shutil.copyfile(shot, keep)
