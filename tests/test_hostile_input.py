"""Hostile and careless input (issue 9): every case gets one clear sentence and a non-zero exit, or a
correct answer; never a traceback, a silent wrong answer, NaN in JSON, or a modified file that is
not ours.

Each test feeds the input through the real command line (:func:`companion.cli.main.main`) or the
library function the command calls. No network, no wall clock: the store race uses a barrier, not
timing.
"""
from __future__ import annotations

import csv
import hashlib
import json
import math
import multiprocessing
import os
import sqlite3
import stat
from pathlib import Path

import numpy as np
import pytest

from companion.cli.main import main
from companion.records.store import APPLICATION_ID, MIGRATIONS, Store, StoreError


def run_cli(capsys, *argv: str) -> tuple[int, str, str]:
    """(exit code, stdout, stderr) of ``companion ARGV`` run in this process."""
    try:
        code = main(list(argv))
    except SystemExit as exc:  # argparse refusing an option
        code = exc.code if isinstance(exc.code, int) else 1
    out = capsys.readouterr()
    return code, out.out, out.err


def assert_clear_error(code: int, err: str, *words: str) -> None:
    """A non-zero exit with a one-line message naming ``words``, and no traceback."""
    assert code != 0
    assert "Traceback" not in err
    for word in words:
        assert word.lower() in err.lower(), err


def strict_json(text: str):
    """Parse JSON refusing NaN and Infinity (what a strict reader does)."""
    def refuse(constant: str):
        raise AssertionError(f"non-standard JSON constant {constant} in output")
    return json.loads(text, parse_constant=refuse)


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


# =========================================================================== store (item 6)
def _create_store(path: str, barrier, results) -> None:
    barrier.wait()  # every process opens the fresh file at the same moment
    try:
        with Store(path) as store:
            store.add_vehicle("auv")
        results.put("ok")
    except Exception as exc:  # noqa: BLE001 - reported to the parent
        results.put(f"{type(exc).__name__}: {exc}")


def test_three_processes_creating_one_fresh_store_all_succeed(tmp_path):
    context = multiprocessing.get_context("fork")
    for round_ in range(5):  # several rounds: a race that loses 1 time in 5 still fails here
        path = str(tmp_path / f"s{round_}.sqlite")
        barrier, results = context.Barrier(3), context.Queue()
        workers = [context.Process(target=_create_store, args=(path, barrier, results)) for _ in range(3)]
        for worker in workers:
            worker.start()
        for worker in workers:
            worker.join(60)
        assert [results.get(timeout=5) for _ in workers] == ["ok"] * 3
        with Store(path, read_only=True) as store:
            assert store.schema_version == len(MIGRATIONS)
            assert len(store._db.execute("SELECT * FROM vehicles").fetchall()) == 3


def _foreign_sqlite(path: Path) -> None:
    with sqlite3.connect(path) as db:
        db.execute("CREATE TABLE notes(body TEXT)")
        db.execute("INSERT INTO notes VALUES ('mine')")
    db.close()


def _newer_store(path: Path) -> None:
    Store(path).close()
    db = sqlite3.connect(path)
    db.execute(f"PRAGMA user_version={len(MIGRATIONS) + 1}")
    db.close()


def _corrupt_store(path: Path) -> None:
    Store(path).close()
    data = path.read_bytes()
    path.write_bytes(data[:100] + b"\xff" * (len(data) - 100))  # header intact, pages garbage


def _other_application(path: Path) -> None:
    db = sqlite3.connect(path)
    db.execute("PRAGMA application_id=1234")
    for table in ("vehicles", "campaigns", "runs", "models", "gains", "behavior_results"):
        db.execute(f"CREATE TABLE {table}(id INTEGER)")  # same names, another application's mark
    db.close()


BAD_STORES = {
    "foreign": (_foreign_sqlite, "another application"),
    "other-application-id": (_other_application, "another application"),
    "newer": (_newer_store, "newer version"),
    "corrupt": (_corrupt_store, "not a readable SQLite database"),
    "not-sqlite": (lambda p: p.write_bytes(b"hello, I am a text file\n" * 50), "not a readable SQLite database"),
}


@pytest.mark.parametrize("kind", sorted(BAD_STORES))
def test_a_store_that_is_not_ours_is_refused_and_left_untouched(tmp_path, capsys, kind):
    path = tmp_path / "x.sqlite"
    make, message = BAD_STORES[kind]
    make(path)
    before = digest(path)
    for read_only in (False, True):
        with pytest.raises(StoreError, match=message):
            Store(path, read_only=read_only)
    code, out, err = run_cli(capsys, "results", "--store", str(path), "--json")
    assert_clear_error(code, err, message, str(path))
    assert out == ""
    assert digest(path) == before  # byte for byte
    assert not Path(f"{path}-wal").exists() or Path(f"{path}-wal").stat().st_size == 0


def test_a_directory_as_store_is_one_sentence(tmp_path, capsys):
    folder = tmp_path / "store.sqlite"
    folder.mkdir()
    with pytest.raises(StoreError, match="is a directory"):
        Store(folder)
    code, _, err = run_cli(capsys, "results", "--store", str(folder))
    assert_clear_error(code, err, "is a directory")
    assert list(folder.iterdir()) == []


def test_a_read_only_store_is_refused_for_writing_but_readable(tmp_path, capsys):
    path = tmp_path / "ro.sqlite"
    with Store(path) as store:
        store.add_vehicle("auv")
    os.chmod(path, stat.S_IRUSR | stat.S_IRGRP)
    try:
        before = digest(path)
        with pytest.raises(StoreError, match="read-only"):
            Store(path)
        code, out, err = run_cli(capsys, "results", "--store", str(path), "--json")
        assert code == 0, err
        assert strict_json(out)["campaigns"] == []
        assert digest(path) == before
    finally:
        os.chmod(path, stat.S_IRUSR | stat.S_IWUSR)


def test_results_opens_read_only_and_never_writes(tmp_path, capsys):
    """The issue's probe: a reading command switched a foreign file to WAL and added tables. Now a
    store of ours is read in ``mode=ro`` too: its journal mode and every byte stay as they were."""
    path = tmp_path / "s.sqlite"
    with Store(path) as store:
        vehicle = store.add_vehicle("auv")
        store.finish_campaign(store.start_campaign(vehicle, "identification"), "completed")
    db = sqlite3.connect(path)
    db.execute("PRAGMA journal_mode=DELETE")  # as another tool may leave it
    db.close()
    before = digest(path)
    code, out, err = run_cli(capsys, "results", "--store", str(path), "--json")
    assert code == 0, err
    assert [c["status"] for c in strict_json(out)["campaigns"]] == ["completed"]
    assert digest(path) == before
    with Store(path, read_only=True) as store, pytest.raises(sqlite3.OperationalError, match="readonly"):
        store.add_vehicle("intruder")
    assert digest(path) == before


def test_a_store_written_before_the_application_id_stays_openable(tmp_path):
    path = tmp_path / "old.sqlite"
    with Store(path) as store:
        store.add_vehicle("auv")
    db = sqlite3.connect(path)
    db.execute("PRAGMA application_id=0")  # as every store was before the mark existed
    db.close()
    with Store(path, read_only=True) as store:
        assert store.schema_version == len(MIGRATIONS)
    with Store(path) as store:  # a writing open adopts it
        assert store._db.execute("PRAGMA application_id").fetchone()[0] == APPLICATION_ID
        assert len(store._db.execute("SELECT * FROM vehicles").fetchall()) == 1
