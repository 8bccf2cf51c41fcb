"""Same seed, same numbers: a rehearsal is a function of its seed and options alone.

Two runs of one short rehearsal, at 50x (the simulator paced on the wall clock, so the companion's
messages arrive while it is between two samples) and at 100x (the simulator as fast as the companion
lets it), must give the same summary, bit for bit, apart from its wall-clock field and the speed-up
it was asked for: scheduling, load and the speed-up must not matter (lockstep, sim/lockstep.py).
About 25 s on an idle 2-core machine (the rehearsal's 387 s of vehicle time at 50x is 8 s). Run as
a user runs it: ``companion rehearse --json`` in a child process, each in a fresh directory with the
same relative ``--out``.
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from companion.rehearsal.reproducibility import comparable, differences

pytestmark = pytest.mark.e2e

SHORT = ["--axes", "yaw", "--thrusts", "0.7", "--no-steps", "--behaviors", "min-speed"]


def rehearse(workdir: Path, speedup: float, seed: int = 1) -> dict:
    workdir.mkdir()
    done = subprocess.run([sys.executable, "-m", "companion", "rehearse", *SHORT, "--seed", str(seed),
                           "--speedup", f"{speedup:g}", "--json", "--out", "rehearsal"],
                          cwd=workdir, capture_output=True, text=True, timeout=300, check=False)
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout)


@pytest.mark.slow
def test_same_seed_gives_the_same_summary_bit_for_bit(tmp_path):
    slow = rehearse(tmp_path / "at50", 50.0)
    fast = rehearse(tmp_path / "at100", 100.0)
    assert slow["status"] == "completed" and slow["runs"] and slow["min_speed"]["status"] == "completed"
    assert slow["reproducibility"] == {"exact": True, "varied": [],
                                       "lockstep": {"engaged_at_s": 0.0, "interruptions": 0, "free_ticks": 0}}
    slow.pop("speedup"), fast.pop("speedup")
    assert differences(comparable(slow), comparable(fast)) == []


def test_the_record_says_what_could_have_varied():
    from companion.rehearsal.reproducibility import reproducibility_record

    real = reproducibility_record("ardusub", False, None, 0)
    assert real["exact"] is False and "ArduPilot" in real["varied"][0]
    stats = {"dropped": 0, "lockstep": {"engaged_at_s": 2.06, "acks": 9, "interruptions": 1, "free_ticks": 300}}
    late = reproducibility_record("builtin", True, stats, snapshots_dropped=0, wall_timeouts=2)
    assert late["exact"] is False and len(late["varied"]) == 3
    assert late["lockstep"] == {"engaged_at_s": 2.06, "interruptions": 1, "free_ticks": 300}
    assert reproducibility_record("builtin", True, None, 0)["exact"] is False  # no report: not known to be exact
