"""The SQLite store (SPEC C10): schema migrations, strict JSON, and nothing lost or half-written when
the process is killed in the middle of writing."""
from __future__ import annotations

import json
import math
import signal
import sqlite3
import subprocess
import sys
import time

import pytest

from dataclasses import replace

from behaviors.identification import IdentificationAttempt
from companion.numerics.identification import YawModel
from companion.records.serialise import to_json
from companion.records.store import MIGRATIONS, Store

ATTEMPT = IdentificationAttempt(
    attempt=1, axis="yaw", thrust=0.7, speed=1.39, r2=0.98, accepted=True, converged=True, converged_s=12.1,
    criterion_met_from_s=11.0, training_s=12.1, samples=242,
    model=YawModel(a22=-1.05, b2=0.86, delta0=0.01, covariance=[[1e-4, 0.0], [0.0, 1e-4]]),
    training={"time": [0.0, 0.05], "history": {"a22": [0.0, math.nan]}}, validation={})


def test_round_trip_of_a_campaign(tmp_path):
    with Store(tmp_path / "s.sqlite") as store:
        assert store.schema_version == len(MIGRATIONS)
        vehicle = store.add_vehicle("auv", "sim", {"preset": "starfish"})
        campaign = store.start_campaign(vehicle, "identification", {"thrusts": [0.7]})
        run = store.add_run(campaign, ATTEMPT)
        store.add_run(campaign, replace(ATTEMPT, attempt=2, accepted=False, r2=0.4))
        store.add_gains(campaign, 1.39, {"heading_p": 0.64}, {"heading_p": 0.67})
        store.add_behavior_result(campaign, "roll", "completed", {"std_open_deg": 1.6, "nan": math.nan})
        store.finish_campaign(campaign, "completed")
    with Store(tmp_path / "s.sqlite") as store:  # reopened: everything is there
        assert [c["status"] for c in store.campaigns()] == ["completed"]
        runs = store.runs(campaign, with_series=True)
        assert [r["accepted"] for r in runs] == [True, False] and runs[0]["id"] == run
        assert runs[0]["series"]["training"]["history"]["a22"] == [0.0, None]  # NaN stored as null
        models = store.models(campaign, axis="yaw")
        assert len(models) == 1 and models[0].params == {"a22": -1.05, "b2": 0.86, "delta0": 0.01}
        assert store.gains(campaign)[0]["after"] == {"heading_p": 0.67}
        assert store.behavior_results(kind="roll")[0]["result"]["nan"] is None


def test_a_store_from_a_newer_version_is_refused(tmp_path):
    path = tmp_path / "s.sqlite"
    Store(path).close()
    with sqlite3.connect(path) as db:
        db.execute(f"PRAGMA user_version={len(MIGRATIONS) + 1}")
    with pytest.raises(RuntimeError, match="newer version"):
        Store(path)


def test_unknown_campaign_is_a_clear_error(tmp_path):
    with Store(tmp_path / "s.sqlite") as store, pytest.raises(KeyError, match="no campaign 7"):
        store.campaign(7)


WRITER = """
import sys, time
from dataclasses import replace
from companion.records.serialise import from_json
from companion.records.store import Store
store = Store(sys.argv[1])
vehicle = store.add_vehicle("auv")
campaign = store.start_campaign(vehicle, "identification")
attempt = from_json({ATTEMPT!r})
print(campaign, flush=True)
n = 0
while True:
    store.add_run(campaign, replace(attempt, attempt=n))
    n += 1
    print(n, flush=True)
"""


def test_a_killed_process_loses_nothing_it_committed(tmp_path):
    path = tmp_path / "s.sqlite"
    code = WRITER.replace("{ATTEMPT!r}", repr(to_json(replace(ATTEMPT, training={}))))
    writer = subprocess.Popen([sys.executable, "-c", code, str(path)], stdout=subprocess.PIPE, text=True)
    assert writer.stdout is not None
    campaign = int(writer.stdout.readline())
    committed = 0
    deadline = time.monotonic() + 30.0
    while committed < 40 and time.monotonic() < deadline:
        committed = int(writer.stdout.readline())
    writer.send_signal(signal.SIGKILL)  # mid-write, no clean-up of any kind
    writer.wait()
    with Store(path) as store:
        runs = store.runs(campaign)
        assert len(runs) >= committed  # every write it reported is there (one more may have landed)
        assert len(store.models(campaign)) == len(runs)  # a run and its model land together or not at all
        assert store.campaigns()[0]["status"] == "running"  # shown as unfinished, not lost
        with sqlite3.connect(path) as db:
            assert db.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    json.dumps(runs)  # strict JSON all the way
