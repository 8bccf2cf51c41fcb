"""``companion run-behavior`` as a user runs it: a behaviour against our simulator over MAVLink, its
JSON summary on stdout and exit 0 only when the behaviour completed."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

pytestmark = pytest.mark.e2e


@pytest.mark.slow
def test_run_behavior_prints_its_summary_and_exits_by_its_status(sim_factory, mav_client, tmp_path):
    sim = sim_factory(transport="tcp", speedup=50, seed=3)
    gcs = mav_client(sim.endpoint)
    gcs.mav.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)  # armed, as a user leaves it
    done = subprocess.run([sys.executable, "-m", "companion", "run-behavior", "roll", "--connect", sim.endpoint,
                           "--duration", "8", "--store", str(tmp_path / "s.sqlite"), "--json"],
                          capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL)
    summary = json.loads(done.stdout, parse_constant=lambda c: (_ for _ in ()).throw(ValueError(c)))
    assert summary["status"] in ("completed", "failed", "aborted", "refused"), summary
    assert (done.returncode == 0) == (summary["status"] == "completed"), (done.returncode, summary)
    assert "Traceback" not in done.stderr, done.stderr[-2000:]
