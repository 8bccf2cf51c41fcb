"""The embedded store: SQLite from the standard library (SPEC C10).

What it holds: vehicle configurations, campaigns, identification runs (every attempt, accepted or
not, with its time series), the accepted models, the gains written (before and after), the
behaviour results and the rows of parameter sweeps (``sweep_cases``, one per case, keyed by the hash
of its inputs). Each write is its own transaction in WAL mode, so a process killed at any moment
leaves every completed write on disk and no half-written row; a campaign that never finished stays
``running`` and is shown as such.

Schema changes go in ``MIGRATIONS`` (one SQL script per version, applied in order, tracked by
``PRAGMA user_version``); never edit a released migration.

Opening is careful with files that are not ours. Our stores carry
``PRAGMA application_id`` = :data:`APPLICATION_ID` (a store written before the mark existed is
recognised by its tables and marked on its next writable open). Before anything is written the
file is inspected: a directory, a non-SQLite or corrupt file, a read-only file (for writing), an
SQLite file of another application and a store of a newer schema each raise :class:`StoreError`
with one sentence and stay byte-for-byte untouched. Creation and migration run inside
``BEGIN IMMEDIATE`` with a busy timeout and re-check the version under that lock, so several
processes creating one fresh store at once all succeed. ``Store(path, read_only=True)`` opens a
``file:…?mode=ro`` URI: it never switches the journal mode, creates a table or sets a pragma.
"""
from __future__ import annotations

import json
import logging
import os
import sqlite3
import stat
import time
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING, Any

from companion.errors import UserError
from companion.records.owner import ProcessOwner
from companion.records.serialise import from_json, json_ready, to_json

if TYPE_CHECKING:
    from behaviors.gain_scheduling import GainDesign
    from behaviors.identification import IdentificationAttempt

log = logging.getLogger(__name__)

MIGRATIONS: tuple[str, ...] = (
    # version 1
    """
    CREATE TABLE vehicles (
        id INTEGER PRIMARY KEY,
        name TEXT NOT NULL,
        profile TEXT,
        config_json TEXT NOT NULL DEFAULT '{}',
        created_utc TEXT NOT NULL
    );
    CREATE TABLE campaigns (
        id INTEGER PRIMARY KEY,
        vehicle_id INTEGER NOT NULL REFERENCES vehicles(id),
        kind TEXT NOT NULL,
        status TEXT NOT NULL,
        reason TEXT,
        config_json TEXT NOT NULL DEFAULT '{}',
        started_utc TEXT NOT NULL,
        finished_utc TEXT
    );
    CREATE TABLE runs (
        id INTEGER PRIMARY KEY,
        campaign_id INTEGER NOT NULL REFERENCES campaigns(id),
        axis TEXT NOT NULL,
        thrust REAL,
        attempt INTEGER NOT NULL,
        speed REAL,
        r2 REAL,
        accepted INTEGER NOT NULL,
        converged_s REAL,
        training_s REAL,
        samples INTEGER,
        model_json TEXT NOT NULL,
        series_json TEXT NOT NULL DEFAULT '{}'
    );
    CREATE TABLE models (
        id INTEGER PRIMARY KEY,
        run_id INTEGER NOT NULL REFERENCES runs(id),
        campaign_id INTEGER NOT NULL REFERENCES campaigns(id),
        axis TEXT NOT NULL,
        thrust REAL,
        speed REAL,
        params_json TEXT NOT NULL,
        covariance_json TEXT,
        r2 REAL
    );
    CREATE TABLE gains (
        id INTEGER PRIMARY KEY,
        campaign_id INTEGER REFERENCES campaigns(id),
        speed REAL,
        before_json TEXT NOT NULL,
        after_json TEXT NOT NULL,
        written_utc TEXT NOT NULL
    );
    CREATE TABLE behavior_results (
        id INTEGER PRIMARY KEY,
        campaign_id INTEGER REFERENCES campaigns(id),
        kind TEXT NOT NULL,
        status TEXT NOT NULL,
        result_json TEXT NOT NULL,
        recorded_utc TEXT NOT NULL
    );
    CREATE INDEX runs_campaign ON runs(campaign_id);
    CREATE INDEX models_campaign ON models(campaign_id);
    """,
    # version 2: one row per case of a parameter sweep, keyed by the hash of its inputs
    """
    CREATE TABLE sweep_cases (
        id INTEGER PRIMARY KEY,
        case_key TEXT NOT NULL UNIQUE,
        sweep TEXT NOT NULL,
        status TEXT NOT NULL,
        reason TEXT,
        inputs_json TEXT NOT NULL,
        row_json TEXT NOT NULL,
        summary_json TEXT NOT NULL DEFAULT '{}',
        log_tail TEXT,
        recorded_utc TEXT NOT NULL
    );
    CREATE INDEX sweep_cases_sweep ON sweep_cases(sweep);
    """,
    # version 3: the trail a procedure leaves: which process runs it (from the campaign's start),
    # how the vehicle was found (stored before its first change) and every change as it is made;
    # the next start follows a trail whose process died. A campaign may hold several procedures
    # (a rehearsal's behaviours), each its own trail.
    """
    CREATE TABLE trails (
        id INTEGER PRIMARY KEY,
        campaign_id INTEGER NOT NULL REFERENCES campaigns(id),
        owner_pid INTEGER,
        owner_host TEXT,
        owner_boot TEXT,
        owner_started TEXT,
        opened_utc TEXT NOT NULL,
        restore_json TEXT,
        vehicle_json TEXT NOT NULL DEFAULT '{}',
        restored_utc TEXT,
        problems_json TEXT,
        notes_json TEXT
    );
    CREATE INDEX trails_campaign ON trails(campaign_id);
    CREATE TABLE changes (
        id INTEGER PRIMARY KEY,
        trail_id INTEGER NOT NULL REFERENCES trails(id),
        vehicle_time_s REAL,
        kind TEXT NOT NULL,
        detail_json TEXT NOT NULL,
        recorded_utc TEXT NOT NULL
    );
    CREATE INDEX changes_trail ON changes(trail_id);
    """,
)


#: ``PRAGMA application_id`` of a companion store ("MCmp"): tells our files from other SQLite files
APPLICATION_ID = 0x4D436D70
#: the tables of schema version 1: an unmarked file holding all of them is a store written before
#: the application id existed
_V1_TABLES = frozenset({"vehicles", "campaigns", "runs", "models", "gains", "behavior_results"})
#: how long a writer waits for another process's lock (creation, migration, writes), s
BUSY_TIMEOUT_S = 30.0


class StoreError(UserError, RuntimeError):
    """The file cannot be used as a store; the message says why in one sentence. Nothing was written."""


@dataclass(frozen=True)
class _FileState:
    """What an SQLite file holds, read before anything is written."""

    application_id: int
    user_version: int
    tables: frozenset[str]

    @property
    def empty(self) -> bool:
        """A fresh database (SQLite's state of a new or zero-byte file): no tables, no marks."""
        return not self.tables and self.application_id == 0 and self.user_version == 0

    @property
    def ours(self) -> bool:
        return self.application_id == APPLICATION_ID or (self.application_id == 0 and _V1_TABLES <= self.tables)


def _read_state(db: sqlite3.Connection, path: Path) -> _FileState:
    """The marks and tables of the open file; StoreError when it is not a readable SQLite database.

    The three reads share one read transaction (unless the caller holds one already): read one by
    one, they could straddle another process's creation of the store and see its tables missing but
    its version set — a fresh store of ours taken for another application's file."""
    own = not db.in_transaction
    try:
        if own:
            db.execute("BEGIN")
        try:
            tables = frozenset(row[0] for row in db.execute("SELECT name FROM sqlite_master WHERE type='table'"))
            application_id = int(db.execute("PRAGMA application_id").fetchone()[0])
            user_version = int(db.execute("PRAGMA user_version").fetchone()[0])
        finally:
            if own and db.in_transaction:
                db.execute("COMMIT")
    except sqlite3.DatabaseError as exc:  # "file is not a database", "database disk image is malformed"
        raise StoreError(f"{path} is not a companion store: it is not a readable SQLite database ({exc})") from None
    return _FileState(application_id, user_version, tables)


def _check_state(state: _FileState, path: Path, read_only: bool) -> None:
    """Refuse (StoreError) a file that is not ours, is newer, or (read-only) holds nothing."""
    if state.empty:
        if read_only:
            raise StoreError(f"{path} is an empty database, not a companion store")
        return
    if not state.ours:
        owner = f"application id {state.application_id:#010x}" if state.application_id else "tables " + \
            ", ".join(sorted(state.tables)[:6])
        raise StoreError(f"{path} is an SQLite file of another application ({owner}), not a companion store; "
                         "pass another --store")
    if state.user_version > len(MIGRATIONS):
        raise StoreError(f"{path} was written by a newer version (schema {state.user_version}, this companion "
                         f"knows {len(MIGRATIONS)}); upgrade the companion")
    if read_only and state.user_version < len(MIGRATIONS):
        raise StoreError(f"{path} has an older schema ({state.user_version}); open it once with a writing command "
                         "(identify, run) to upgrade it")


def _check_path(path: Path, read_only: bool) -> None:
    """Refuse a directory, a missing file (read-only) and a read-only file (for writing) before SQLite opens it."""
    if path.is_dir():
        raise StoreError(f"{path} is a directory, not a store file")
    if not path.exists():
        if read_only:
            raise StoreError(f"no store at {path}")
        return
    if not path.is_file():
        raise StoreError(f"{path} is not a regular file")
    if not read_only and (not os.access(path, os.W_OK) or not path.stat().st_mode & (stat.S_IWUSR | stat.S_IWGRP
                                                                                       | stat.S_IWOTH)):
        raise StoreError(f"{path} is read-only; make it writable or pass another --store")


def _statements(script: str) -> list[str]:
    """The SQL statements of a migration script, one by one (so they run inside our own transaction;
    ``executescript`` would commit it first)."""
    out, current = [], ""
    for line in script.splitlines(keepends=True):
        current += line
        if sqlite3.complete_statement(current):
            out.append(current.strip())
            current = ""
    if current.strip():
        out.append(current.strip())
    return out


def _row_id(cursor: sqlite3.Cursor) -> int:
    """The id of the row an INSERT just made (``lastrowid``; None only where no row was inserted)."""
    if cursor.lastrowid is None:
        raise sqlite3.DatabaseError("the INSERT made no row")
    return int(cursor.lastrowid)


def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def _json(value: Any) -> str:
    """JSON with NaN/inf written as null (strict JSON readers reject NaN)."""
    return json.dumps(json_safe(value), separators=(",", ":"))


#: ``value`` with NaN/inf as None, numpy values as plain Python and records tagged (every JSON we write)
json_safe = json_ready


@dataclass(frozen=True)
class StoredModel:
    campaign_id: int
    axis: str
    thrust: float | None
    speed: float | None
    params: dict
    r2: float | None


class Store:
    """A handle on one SQLite file. Cheap to open; safe to use from one thread.

    ``read_only=True`` (what ``companion results`` uses) opens the file with ``mode=ro`` and never
    writes to it; the writing methods then fail with ``sqlite3.OperationalError``. Either way an
    unusable file raises :class:`StoreError` before anything is written.
    """

    def __init__(self, path: str | Path, read_only: bool = False) -> None:
        self.path = Path(path)
        self.read_only = read_only
        _check_path(self.path, read_only)
        if not read_only:
            try:
                self.path.parent.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise StoreError(f"cannot create the folder of {self.path} ({exc.strerror or exc})") from None
        self._db = self._connect()
        try:
            _check_state(_read_state(self._db, self.path), self.path, read_only)
            if not read_only:
                self._prepare_for_writing()
        except BaseException:
            self._db.close()
            raise

    # ------------------------------------------------------------------ plumbing
    def _connect(self) -> sqlite3.Connection:
        """The connection (autocommit; explicit transactions), with a busy timeout for other processes' locks."""
        try:
            if self.read_only:
                db = sqlite3.connect(f"{self.path.resolve().as_uri()}?mode=ro", uri=True, isolation_level=None,
                                     timeout=BUSY_TIMEOUT_S)
            else:
                db = sqlite3.connect(str(self.path), isolation_level=None, timeout=BUSY_TIMEOUT_S)
        except sqlite3.Error as exc:
            raise StoreError(f"cannot open {self.path} as a store ({exc})") from None
        db.row_factory = sqlite3.Row
        return db

    def _prepare_for_writing(self) -> None:
        """WAL, durability and foreign keys, then the schema; the file was checked to be ours or empty."""
        try:
            self._use_wal()
            self._db.execute("PRAGMA synchronous=FULL")
            self._db.execute("PRAGMA foreign_keys=ON")
            self._migrate()
        except sqlite3.OperationalError as exc:  # e.g. a read-only directory, a disk full, a lock held too long
            raise StoreError(f"cannot prepare {self.path} for writing ({exc})") from None

    def _use_wal(self) -> None:
        """Switch the file to WAL (persistent: once per file). SQLite answers a journal-mode switch
        that meets another process's lock with "database is locked" at once, without its busy
        handler, so the switch is retried for up to :data:`BUSY_TIMEOUT_S` (a process-level wait)."""
        deadline = time.monotonic() + BUSY_TIMEOUT_S
        delay = 0.002
        while True:
            try:
                if self._db.execute("PRAGMA journal_mode").fetchone()[0].lower() != "wal":
                    self._db.execute("PRAGMA journal_mode=WAL")
                return
            except sqlite3.OperationalError as exc:
                if "locked" not in str(exc) or time.monotonic() > deadline:
                    raise
            time.sleep(delay)
            delay = min(2 * delay, 0.1)

    def _migrate(self) -> None:
        """Bring the schema to the current version, race-free: the version is re-read under the
        write lock, so of several processes creating one store only the first creates it."""
        state = _read_state(self._db, self.path)
        if state.user_version == len(MIGRATIONS) and state.application_id == APPLICATION_ID:
            return
        with self._transaction():
            state = _read_state(self._db, self.path)  # under the lock: another process may have done it
            _check_state(state, self.path, read_only=False)
            for number, script in enumerate(MIGRATIONS[state.user_version:], start=state.user_version + 1):
                log.info("%s: migrating the store to schema %d", self.path, number)
                for statement in _statements(script):
                    self._db.execute(statement)
                self._db.execute(f"PRAGMA user_version={number}")
            if state.application_id != APPLICATION_ID:
                self._db.execute(f"PRAGMA application_id={APPLICATION_ID}")

    def _transaction(self):
        return _Transaction(self._db, self.path)

    @property
    def schema_version(self) -> int:
        return self._db.execute("PRAGMA user_version").fetchone()[0]

    def _insert(self, sql: str, args: tuple) -> int:
        with self._transaction():
            return _row_id(self._db.execute(sql, args))

    def close(self) -> None:
        self._db.close()

    def __enter__(self) -> "Store":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ writes
    def add_vehicle(self, name: str, profile: str | None = None, config: dict | None = None) -> int:
        return self._insert("INSERT INTO vehicles(name, profile, config_json, created_utc) VALUES (?,?,?,?)",
                            (name, profile, _json(config or {}), _now()))

    def start_campaign(self, vehicle_id: int, kind: str, config: dict | None = None) -> int:
        """A campaign row, ``running``, with a trail naming this process as its owner (so another
        process can tell a live campaign from one whose process died)."""
        with self._transaction():
            campaign_id = _row_id(self._db.execute(
                "INSERT INTO campaigns(vehicle_id, kind, status, config_json, started_utc) VALUES (?,?,?,?,?)",
                (vehicle_id, kind, "running", _json(config or {}), _now())))
            self._open_trail(campaign_id)
        return campaign_id

    def _open_trail(self, campaign_id: int) -> int:
        owner = ProcessOwner.current()
        return _row_id(self._db.execute(
            "INSERT INTO trails(campaign_id, owner_pid, owner_host, owner_boot, owner_started, opened_utc)"
            " VALUES (?,?,?,?,?,?)", (campaign_id, owner.pid, owner.host, owner.boot_id, owner.started, _now())))

    def update_campaign_config(self, campaign_id: int, config: dict) -> None:
        """The campaign's configuration as resolved on the vehicle (what it read there, e.g. the
        output scaling its heading design accounts for), replacing the one it started with."""
        with self._transaction():
            self._db.execute("UPDATE campaigns SET config_json=? WHERE id=?", (_json(config), campaign_id))

    def finish_campaign(self, campaign_id: int, status: str, reason: str | None = None) -> None:
        with self._transaction():
            self._db.execute("UPDATE campaigns SET status=?, reason=?, finished_utc=? WHERE id=?",
                             (status, reason, _now(), campaign_id))

    # ------------------------------------------------------------------ the trail
    def save_restore_point(self, campaign_id: int, restore: dict, vehicle: dict) -> int:
        """How the vehicle was found, before a procedure's first change: stored in the campaign's
        trail not yet used, or a new trail of this campaign (its next procedure); returns the
        trail's id (its changes and its restore are recorded under it)."""
        owner = ProcessOwner.current()
        with self._transaction():
            row = self._db.execute("SELECT id FROM trails WHERE campaign_id=? AND restore_json IS NULL"
                                   " AND restored_utc IS NULL ORDER BY id DESC LIMIT 1", (campaign_id,)).fetchone()
            trail_id = int(row[0]) if row is not None else self._open_trail(campaign_id)
            self._db.execute("UPDATE trails SET restore_json=?, vehicle_json=?, owner_pid=?, owner_host=?,"
                             " owner_boot=?, owner_started=? WHERE id=?",
                             (_json(restore), _json(vehicle), owner.pid, owner.host, owner.boot_id, owner.started,
                              trail_id))
        return trail_id

    def add_change(self, trail_id: int, vehicle_time_s: float | None, kind: str, detail: dict) -> None:
        """One change to the vehicle, recorded before it is sent."""
        self._insert("INSERT INTO changes(trail_id, vehicle_time_s, kind, detail_json, recorded_utc)"
                     " VALUES (?,?,?,?,?)", (trail_id, vehicle_time_s, kind, _json(detail), _now()))

    def finish_restore(self, trail_id: int, problems: list[str], notes: list[str]) -> None:
        """The restore ran: what it could not do and what it decided. The trail is closed only when
        nothing failed; otherwise it stays open, so the next start (or ``companion recover``) finds the
        vehicle still differing from how it was found and puts it back."""
        with self._transaction():
            self._db.execute("UPDATE trails SET restored_utc=?, problems_json=?, notes_json=? WHERE id=?",
                             (None if problems else _now(), _json(problems), _json(notes), trail_id))

    def open_trails(self) -> list[dict]:
        """Trails not closed, oldest first: a procedure whose restore point was stored and whose
        restore never ran, and the latest trail of a campaign still ``running`` (its restore point
        left out when its restore already ran: nothing of it is left to put back); each with its
        owner, restore point, vehicle and changes (the caller decides whether the owner is gone).
        A ``running`` campaign with no trail at all (written by other code) comes with no owner."""
        rows = self._db.execute(
            "SELECT t.id AS trail_id, c.id AS campaign_id, c.kind, c.status, c.started_utc, t.restore_json,"
            " t.restored_utc, t.vehicle_json, t.owner_pid, t.owner_host, t.owner_boot, t.owner_started"
            " FROM campaigns c LEFT JOIN trails t ON t.campaign_id = c.id"
            " WHERE (t.restored_utc IS NULL AND t.restore_json IS NOT NULL)"
            "   OR (c.status = 'running' AND (t.id IS NULL OR t.id = (SELECT MAX(id) FROM trails WHERE campaign_id = c.id)))"
            " ORDER BY c.id, t.id").fetchall()
        out = []
        for row in rows:
            item = dict(row)
            restore_json = item.pop("restore_json")
            restored = item.pop("restored_utc") is not None
            item["restore"] = json.loads(restore_json) if restore_json and not restored else None
            item["vehicle"] = json.loads(item.pop("vehicle_json")) if item["vehicle_json"] else {}
            item["owner"] = ProcessOwner(item.pop("owner_pid"), item.pop("owner_host") or "",
                                         item.pop("owner_boot") or "", item.pop("owner_started") or "")
            item["changes"] = [] if item["trail_id"] is None or restored else [
                {"vehicle_time_s": c["vehicle_time_s"], "kind": c["kind"], "detail": json.loads(c["detail_json"])}
                for c in self._select("changes", trail_id=item["trail_id"])]
            out.append(item)
        return out

    def close_trail(self, trail_id: int | None, campaign_id: int, status: str, reason: str) -> None:
        """An interrupted trail followed (or with nothing to follow): the trail closed and, if the
        campaign still reads ``running``, the campaign ended with ``status`` and ``reason``."""
        with self._transaction():
            if trail_id is not None:
                self._db.execute("UPDATE trails SET restored_utc=COALESCE(restored_utc, ?) WHERE id=?",
                                 (_now(), trail_id))
            self._db.execute("UPDATE campaigns SET status=?, reason=?, finished_utc=? WHERE id=? AND status='running'",
                             (status, reason, _now(), campaign_id))

    def add_run(self, campaign_id: int, attempt: IdentificationAttempt) -> int:
        """Store one identification attempt; an accepted attempt also becomes a model row, in the
        same transaction. The model is written by the one serialiser (its type tag included)."""
        model = to_json(attempt.model)
        with self._transaction():
            run_id = _row_id(self._db.execute(
                "INSERT INTO runs(campaign_id, axis, thrust, attempt, speed, r2, accepted, converged_s, training_s,"
                " samples, model_json, series_json) VALUES (?,?,?,?,?,?,?,?,?,?,?,?)",
                (campaign_id, attempt.axis, attempt.thrust, attempt.attempt, json_safe(attempt.speed),
                 json_safe(attempt.r2), int(bool(attempt.accepted)), json_safe(attempt.converged_s),
                 json_safe(attempt.training_s), attempt.samples,
                 _json(model), _json({"training": attempt.training, "validation": attempt.validation})),
            ))
            if attempt.accepted:
                params = {k: v for k, v in model.items() if k not in ("covariance", "type")}
                self._db.execute(
                    "INSERT INTO models(run_id, campaign_id, axis, thrust, speed, params_json, covariance_json, r2)"
                    " VALUES (?,?,?,?,?,?,?,?)",
                    (run_id, campaign_id, attempt.axis, attempt.thrust, json_safe(attempt.speed),
                     _json(params), _json(model.get("covariance")), json_safe(attempt.r2)))
        return run_id

    def add_design(self, campaign_id: int | None, design: GainDesign) -> int:
        """Store a gain design (its schedule exactly as fitted, trend included) as a ``gain_design``
        result; :meth:`designs` gives the same typed record back."""
        return self.add_behavior_result(campaign_id, "gain_design", "completed", to_json(design))

    def designs(self, campaign_id: int | None = None, kind: str | None = None) -> list[GainDesign]:
        """The stored gain designs (typed), oldest first, optionally of one schedule kind."""
        out = []
        for row in self.behavior_results(campaign_id, "gain_design"):
            try:
                design = from_json(row["result"])
            except (ValueError, TypeError) as exc:  # a design stored before typed records
                log.info("gain design %d not readable as a record: %s", row["id"], exc)
                continue
            if kind is None or design.kind == kind:
                out.append(design)
        return out

    def latest_design(self, kind: str) -> tuple[int, GainDesign] | None:
        """(campaign id, design) of the newest stored design of ``kind`` from a campaign that
        completed, or None."""
        for campaign in reversed(self.campaigns()):
            if campaign["kind"] != "identification" or campaign["status"] != "completed":
                continue
            designs = self.designs(campaign["id"], kind)
            if designs:
                return campaign["id"], designs[-1]
        return None

    def add_gains(self, campaign_id: int | None, speed: float | None, before: dict, after: dict) -> int:
        return self._insert("INSERT INTO gains(campaign_id, speed, before_json, after_json, written_utc) VALUES (?,?,?,?,?)",
                            (campaign_id, json_safe(speed), _json(before), _json(after), _now()))

    def add_behavior_result(self, campaign_id: int | None, kind: str, status: str, result: dict) -> int:
        return self._insert(
            "INSERT INTO behavior_results(campaign_id, kind, status, result_json, recorded_utc) VALUES (?,?,?,?,?)",
            (campaign_id, kind, status, _json(result), _now()))

    def put_sweep_case(self, case_key: str, sweep: str, status: str, reason: str | None, inputs: dict, row: dict,
                       summary: dict | None = None, log_tail: str | None = None) -> None:
        """Record one finished sweep case (one transaction): its row, the rehearsal's summary and, for
        a case that did not complete, the end of its log. A case recorded before under the same key
        (a rerun of a failed case) is replaced."""
        with self._transaction():
            self._db.execute(
                "INSERT INTO sweep_cases(case_key, sweep, status, reason, inputs_json, row_json, summary_json,"
                " log_tail, recorded_utc) VALUES (?,?,?,?,?,?,?,?,?) ON CONFLICT(case_key) DO UPDATE SET"
                " sweep=excluded.sweep, status=excluded.status, reason=excluded.reason,"
                " inputs_json=excluded.inputs_json, row_json=excluded.row_json, summary_json=excluded.summary_json,"
                " log_tail=excluded.log_tail, recorded_utc=excluded.recorded_utc",
                (case_key, sweep, status, reason, _json(inputs), _json(row), _json(summary or {}), log_tail, _now()))

    def sweep_cases(self, sweep: str | None = None, with_summary: bool = False) -> list[dict]:
        """The recorded sweep cases (all, or those a sweep named ``sweep`` ran), oldest first: ``case_key``,
        ``sweep``, ``status``, ``reason``, ``inputs``, ``row``, ``recorded_utc`` (and ``summary``, ``log_tail``)."""
        out = []
        for r in self._select("sweep_cases", sweep=sweep):
            item = {"case_key": r["case_key"], "sweep": r["sweep"], "status": r["status"], "reason": r["reason"],
                    "inputs": json.loads(r["inputs_json"]), "row": json.loads(r["row_json"]),
                    "recorded_utc": r["recorded_utc"]}
            if with_summary:
                item["summary"] = json.loads(r["summary_json"])
                item["log_tail"] = r["log_tail"]
            out.append(item)
        return out

    # ------------------------------------------------------------------ reads
    def campaigns(self) -> list[dict]:
        rows = self._db.execute(
            "SELECT c.*, v.name AS vehicle, v.profile AS profile,"
            " (SELECT COUNT(*) FROM runs r WHERE r.campaign_id=c.id) AS runs,"
            " (SELECT COUNT(*) FROM models m WHERE m.campaign_id=c.id) AS models"
            " FROM campaigns c JOIN vehicles v ON v.id=c.vehicle_id ORDER BY c.id").fetchall()
        return [self._campaign_dict(row) for row in rows]

    @staticmethod
    def _campaign_dict(row: sqlite3.Row) -> dict:
        out = dict(row)
        out["config"] = json.loads(out.pop("config_json"))
        return out

    def campaign(self, campaign_id: int) -> dict:
        row = self._db.execute("SELECT c.*, v.name AS vehicle, v.profile AS profile, v.config_json AS vehicle_config"
                               " FROM campaigns c JOIN vehicles v ON v.id=c.vehicle_id WHERE c.id=?",
                               (campaign_id,)).fetchone()
        if row is None:
            raise KeyError(f"no campaign {campaign_id} in {self.path}")
        out = self._campaign_dict(row)
        out["vehicle_config"] = json.loads(out["vehicle_config"])
        return out

    def latest_campaign_id(self, kind: str | None = None) -> int | None:
        sql = "SELECT MAX(id) FROM campaigns"
        args: tuple[str, ...] = ()
        if kind:
            sql, args = sql + " WHERE kind=?", (kind,)
        value = self._db.execute(sql, args).fetchone()[0]
        return None if value is None else int(value)

    def runs(self, campaign_id: int, with_series: bool = False) -> list[dict]:
        rows = self._select("runs", campaign_id=campaign_id)
        out = []
        for row in rows:
            item = dict(row)
            item["model"] = json.loads(item.pop("model_json"))
            series = item.pop("series_json")
            if with_series:
                item["series"] = json.loads(series)
            item["accepted"] = bool(item["accepted"])
            out.append(item)
        return out

    def _select(self, table: str, **equal) -> list[sqlite3.Row]:
        """Rows of ``table`` whose columns equal the given non-None values, in insertion order."""
        filters = {column: value for column, value in equal.items() if value is not None}
        where = " AND ".join(f"{column}=?" for column in filters) or "1=1"
        return self._db.execute(f"SELECT * FROM {table} WHERE {where} ORDER BY id", tuple(filters.values())).fetchall()

    def models(self, campaign_id: int | None = None, axis: str | None = None) -> list[StoredModel]:
        rows = self._select("models", campaign_id=campaign_id, axis=axis)
        return [StoredModel(row["campaign_id"], row["axis"], row["thrust"], row["speed"],
                            json.loads(row["params_json"]), row["r2"]) for row in rows]

    def gains(self, campaign_id: int | None = None) -> list[dict]:
        rows = self._select("gains", campaign_id=campaign_id)
        return [{"id": r["id"], "campaign_id": r["campaign_id"], "speed": r["speed"], "written_utc": r["written_utc"],
                 "before": json.loads(r["before_json"]), "after": json.loads(r["after_json"])} for r in rows]

    def behavior_results(self, campaign_id: int | None = None, kind: str | None = None) -> list[dict]:
        rows = self._select("behavior_results", campaign_id=campaign_id, kind=kind)
        return [{"id": r["id"], "campaign_id": r["campaign_id"], "kind": r["kind"], "status": r["status"],
                 "recorded_utc": r["recorded_utc"], "result": json.loads(r["result_json"])} for r in rows]


class _Transaction:
    """``BEGIN IMMEDIATE`` … ``COMMIT`` (rolled back on an error); an SQLite error inside becomes a
    StoreError with one sentence (a full disk, a lock held too long), never a traceback."""

    def __init__(self, db: sqlite3.Connection, path: Path) -> None:
        self._db = db
        self._path = path
        self._outer = False

    def __enter__(self):
        self._outer = not self._db.in_transaction
        if self._outer:
            try:
                self._db.execute("BEGIN IMMEDIATE")
            except sqlite3.Error as exc:
                raise StoreError(_write_failure(self._path, exc)) from None
        return self._db

    def __exit__(self, exc_type, exc, tb) -> None:
        if not self._outer:
            return
        if exc_type is None:
            try:
                self._db.execute("COMMIT")
                return
            except sqlite3.Error as commit_error:
                self._rollback()
                raise StoreError(_write_failure(self._path, commit_error)) from None
        self._rollback()
        if isinstance(exc, sqlite3.Error):
            raise StoreError(_write_failure(self._path, exc)) from None

    def _rollback(self) -> None:
        try:
            self._db.execute("ROLLBACK")
        except sqlite3.Error:  # nothing to roll back (SQLite already did)
            pass


def _write_failure(path: Path, exc: sqlite3.Error) -> str:
    """One sentence for an SQLite write error."""
    text = str(exc)
    if "full" in text:
        return (f"the store {path} could not be written: the disk is full (everything written before is kept; "
                "free some space)")
    if "locked" in text or "busy" in text:
        return f"the store {path} could not be written: another process held it locked for {BUSY_TIMEOUT_S:g} s"
    return f"the store {path} could not be written ({text})"
