"""The experiment log: one SQLite file, written through the standard library's ``sqlite3``.

The file is identified before it is opened (:mod:`evaluation.sessions.identity`):
a file that is not a session database is refused and never changed. Reading
commands (``gbo sessions``, ``gbo export``) open it read-only
(``SessionStore(path, read_only=True)``), which also works on a read-only file
or folder.

Every write is one short ``BEGIN IMMEDIATE ... COMMIT`` transaction, so a
crash leaves either the whole change or none of it. The database runs in WAL
mode with ``synchronous=FULL`` (a committed experiment survives a power cut),
a busy timeout (several processes may share one file: each waits for the
write lock instead of failing) and foreign keys on.

Tables
------
``sessions``
    One row per tuning session, keyed by a hash of its specification (env id
    and kwargs, tuner name and parameters, seed; not the budget, which a rerun
    may change: :func:`session_key`). The claiming process's ``owner_token``
    fences every write: a process whose session was taken over
    (``gbo tune --force``) cannot write to it any more.
``experiments``
    One row per plant experiment attempt or twin evaluation, in the order they
    happened (``seq``). Plant rows go through ``running`` (the intent, committed
    before the plant is touched) to ``ok`` / ``failed``; an intent found on
    resume becomes ``lost-in-crash``, one cut short by Ctrl-C ``interrupted``.
``snapshots``
    Per session, the tuner as it was when the last plant experiment finished
    (a pickle, :mod:`evaluation.sessions.snapshot`), committed with that
    experiment; a resume loads it instead of replaying the history.

Rows
----
:meth:`SessionStore.sessions` returns :class:`SessionInfo` (a ``sessions`` row with its
experiment counts, as ``gbo sessions`` lists them) and :meth:`SessionStore.experiments`
:class:`ExperimentRow` (an ``experiments`` row). Only the store builds them, one per SQL row,
and callers read them: they are importable from this module
(``from evaluation.sessions.store import ExperimentRow``) but not part of the package's ``__all__``.
"""

from __future__ import annotations

import hashlib
import io
import json
import math
import os
import secrets
import socket
import sqlite3
import time
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from agents.jsonable import to_json
from evaluation.sessions.identity import APPLICATION_ID, SCHEMA_VERSION, NotASessionDatabase, identify
from gbo_envs.experiment import SIGNALS, Experiment

__all__ = ["ARRAY_FIELDS", "PLANT_STATUSES", "DamagedDatabase", "NotASessionDatabase", "SessionBusy", "SessionStore",
           "array_from_blob", "array_to_blob", "check_sound", "session_key"]

#: Status values of an experiment row.
PLANT_STATUSES = ("running", "ok", "failed", "lost-in-crash", "interrupted")
#: Record arrays stored as BLOBs (the signals of :class:`~gbo_envs.Experiment`).
ARRAY_FIELDS = SIGNALS

BUSY_TIMEOUT_MS = 60_000

_SCHEMA = """
CREATE TABLE IF NOT EXISTS sessions (
    id          INTEGER PRIMARY KEY AUTOINCREMENT,
    key         TEXT NOT NULL UNIQUE,
    spec        TEXT NOT NULL,
    env_id      TEXT NOT NULL,
    tuner       TEXT NOT NULL,
    seed        INTEGER,
    budget      INTEGER NOT NULL CHECK (budget >= 1),
    gain_names  TEXT NOT NULL,
    status      TEXT NOT NULL DEFAULT 'new',
    message     TEXT,
    owner_host  TEXT,
    owner_pid   INTEGER,
    owner_token TEXT,
    created_at  REAL NOT NULL,
    updated_at  REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS experiments (
    id           INTEGER PRIMARY KEY AUTOINCREMENT,
    session_id   INTEGER NOT NULL REFERENCES sessions(id) ON DELETE CASCADE,
    seq          INTEGER NOT NULL,
    experiment   INTEGER NOT NULL,
    source       TEXT NOT NULL CHECK (source IN ('plant', 'twin')),
    parent_id    INTEGER REFERENCES experiments(id) ON DELETE CASCADE,
    phase        TEXT,
    status       TEXT NOT NULL CHECK (status IN ('running', 'ok', 'failed', 'lost-in-crash', 'interrupted')),
    reason       TEXT,
    told         INTEGER NOT NULL DEFAULT 0,
    gains        TEXT NOT NULL,
    cost         REAL,
    told_cost    REAL,
    true_cost    REAL,
    unstable     INTEGER,
    metrics      TEXT,
    t            BLOB,
    r            BLOB,
    u            BLOB,
    y            BLOB,
    extra        TEXT,
    env_state    TEXT,
    started_at   REAL NOT NULL,
    finished_at  REAL,
    UNIQUE (session_id, seq)
);
CREATE UNIQUE INDEX IF NOT EXISTS experiments_told_once
    ON experiments (session_id, experiment) WHERE source = 'plant' AND told = 1;
CREATE INDEX IF NOT EXISTS experiments_parent ON experiments (parent_id);
CREATE TABLE IF NOT EXISTS snapshots (
    session_id  INTEGER PRIMARY KEY REFERENCES sessions(id) ON DELETE CASCADE,
    row_id      INTEGER NOT NULL REFERENCES experiments(id) ON DELETE CASCADE,
    tuner       BLOB NOT NULL,
    updated_at  REAL NOT NULL
);
"""


def session_key(spec: Mapping) -> str:
    """The key of a session: SHA-256 of its specification's JSON without the budget.

    A rerun with another budget is the same session, extended or shortened
    (as Optuna's ``n_trials``). Tuners that size themselves to the budget (a
    grid) carry it in their parameters, so for them another budget is another
    session.
    """
    return hashlib.sha256(to_json({k: v for k, v in spec.items() if k != "budget"}).encode()).hexdigest()


class SessionBusy(RuntimeError):
    """Another live process is running this session, or took it over from this one."""


@dataclass(frozen=True)
class SessionInfo:
    """A row of the ``sessions`` table with its experiment counts.

    Attributes
    ----------
    done : int
        Plant experiments the tuner learned from (``ok`` or penalised failures).
    failed : int
        Failed plant experiments (penalised or skipped).
    best_cost : float
        Lowest cost of an ``ok`` plant experiment (NaN if none).
    created_at, updated_at : float
        Unix times in s.
    """

    id: int
    key: str
    spec: dict
    env_id: str
    tuner: str
    seed: int | None
    budget: int
    gain_names: tuple[str, ...]
    status: str
    message: str | None
    created_at: float
    updated_at: float
    done: int = 0
    failed: int = 0
    best_cost: float = math.nan


@dataclass(frozen=True)
class ExperimentRow:
    """One stored experiment (plant attempt or twin evaluation) with its bookkeeping; arrays are decoded lazily.

    The experiment itself is :meth:`to_experiment`; the other fields are the
    session's: status, whether and what the tuner was told, timing, env state.
    """

    id: int
    seq: int
    experiment: int
    source: str
    parent_id: int | None
    phase: str | None
    status: str
    reason: str | None
    told: bool
    gains: tuple[float, ...]
    cost: float | None
    told_cost: float | None
    true_cost: float | None
    unstable: bool | None
    metrics: dict | None
    blobs: dict
    extra: dict
    env_state: dict | None
    started_at: float
    finished_at: float | None

    def arrays(self) -> dict[str, np.ndarray]:
        """The stored ``t, r, u, y`` arrays (those present), each of shape (n_steps,)."""
        return {name: array_from_blob(blob) for name, blob in self.blobs.items() if blob is not None}

    def to_experiment(self, arrays: dict[str, np.ndarray] | None = None) -> Experiment:
        """The stored experiment as the record type.

        Signals when all four were stored; ``cost`` the measured cost, else the
        cost the tuner was told (a penalised failure), else NaN; ``index`` the
        env's ``experiment_index`` when stored, else ``experiment - 1``.
        ``arrays`` are this row's :meth:`arrays` when the caller has decoded them already.
        """
        arrays = self.arrays() if arrays is None else arrays
        signals = {name: arrays[name] for name in ARRAY_FIELDS} if all(name in arrays for name in ARRAY_FIELDS) \
            else {}
        cost = self.cost if self.cost is not None else self.told_cost
        return Experiment(gains=self.gains, **signals, cost=math.nan if cost is None else cost,
                          metrics=self.metrics or {}, source=self.source,
                          index=self.extra.get("experiment_index", self.experiment - 1))

    def record(self) -> dict[str, Any]:
        """The experiment record as ``env.step`` reported it in ``info`` (the stored part of it).

        As in ``info``, ``record()["experiment"]`` is the :class:`~gbo_envs.Experiment`
        (:meth:`to_experiment`), beside the flat keys.
        """
        record: dict[str, Any] = dict(self.extra)
        arrays = self.arrays()
        record.update(arrays)
        record["gains"] = np.asarray(self.gains, dtype=float)
        if self.metrics is not None:
            record["metrics"] = dict(self.metrics)
        if self.cost is not None:
            record["cost"] = self.cost
        if self.true_cost is not None:
            record["true_cost"] = self.true_cost
        if self.unstable is not None:
            record["unstable"] = bool(self.unstable)
        record["experiment"] = self.to_experiment(arrays)
        return record


def array_to_blob(array) -> bytes:
    """Serialise an array with ``np.save`` (dtype and shape kept, no pickle)."""
    buffer = io.BytesIO()
    np.save(buffer, np.asarray(array), allow_pickle=False)
    return buffer.getvalue()


def array_from_blob(blob: bytes) -> np.ndarray:
    """Inverse of :func:`array_to_blob`."""
    return np.load(io.BytesIO(blob), allow_pickle=False)


def _real(value) -> float | None:
    """A float for a REAL column (None for missing or NaN, which SQLite cannot store)."""
    if value is None:
        return None
    value = float(value)
    return None if math.isnan(value) else value


class SessionStore:
    """Connection to one experiment-log database.

    Parameters
    ----------
    path : str or Path
        SQLite file (created with its folder if missing, unless ``read_only``).
    read_only : bool, default False
        Open for reading only (``gbo sessions``, ``gbo export``): nothing is
        written, and a read-only file or folder can be read.

    Raises
    ------
    NotASessionDatabase
        If ``path`` is not a session database (see :func:`~evaluation.sessions.identity.identify`);
        the file is left untouched.
    FileNotFoundError
        With ``read_only``, if ``path`` does not exist.
    PermissionError
        Without ``read_only``, if the file or its folder cannot be written.
    """

    def __init__(self, path: str | Path, read_only: bool = False) -> None:
        self.path = Path(path)
        self.read_only = bool(read_only)
        self._claims: dict[int, str] = {}  # session id -> owner token of this connection's claim
        kind = identify(self.path)
        if self.read_only:
            self.conn = self._connect_read_only(kind)
            return
        if kind != "new":
            check_sound(self.path)  # a damaged file is refused before anything is written to it
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.conn = sqlite3.connect(str(self.path), timeout=BUSY_TIMEOUT_MS / 1000, isolation_level=None)
        self.conn.row_factory = sqlite3.Row
        try:
            self._set_up(kind)
        except sqlite3.OperationalError as exc:
            self.conn.close()
            if "readonly" not in str(exc) and "unable to open" not in str(exc):
                raise
            raise PermissionError(f"{self.path}: cannot be written ({exc}); running a session needs write access "
                                  "to the file and its folder (gbo sessions and gbo export only read)") from None

    def _set_up(self, kind: str) -> None:
        """Pragmas, the schema (created or upgraded) and the application id, on a read-write connection."""
        self.conn.execute(f"PRAGMA busy_timeout = {BUSY_TIMEOUT_MS}")
        if kind == "new":  # marked as ours first, in the rollback journal: straight into the file's header
            self.conn.execute(f"PRAGMA application_id = {APPLICATION_ID}")
        mode = self.conn.execute("PRAGMA journal_mode = WAL").fetchone()[0]
        if str(mode).lower() != "wal":
            raise RuntimeError(f"{self.path}: could not switch to WAL mode (got {mode!r})")
        self.conn.execute("PRAGMA synchronous = FULL")
        self.conn.execute("PRAGMA foreign_keys = ON")
        with self.transaction() as conn:
            version = conn.execute("PRAGMA user_version").fetchone()[0]
            for statement in _SCHEMA.split(";"):
                if statement.strip():
                    conn.execute(statement)
            if version == 1:
                _upgrade_from_version_1(conn)
            conn.execute(f"PRAGMA application_id = {APPLICATION_ID}")
            conn.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")
        if kind == "version 1":  # the header's new application id into the main file, where identify() reads it
            self.conn.execute("PRAGMA wal_checkpoint(PASSIVE)")

    def _connect_read_only(self, kind: str) -> sqlite3.Connection:
        if kind == "new":
            what = "no such file" if not self.path.exists() else "an empty file, not a gbo session database"
            error = FileNotFoundError if not self.path.exists() else NotASessionDatabase
            raise error(f"{self.path}: {what}")
        conn = self._connect_query_only()
        if conn is not None:
            return conn
        uri = self.path.resolve().as_uri()
        for options in ("mode=ro", "mode=ro&immutable=1"):  # immutable: a read-only folder without the -shm file
            conn = sqlite3.connect(f"{uri}?{options}", uri=True, timeout=BUSY_TIMEOUT_MS / 1000,
                                   isolation_level=None)
            conn.row_factory = sqlite3.Row
            try:
                conn.execute(f"PRAGMA busy_timeout = {BUSY_TIMEOUT_MS}")
                conn.execute("SELECT COUNT(*) FROM sessions").fetchone()
                return conn
            except sqlite3.OperationalError as exc:
                conn.close()
                error = exc
        raise NotASessionDatabase(f"{self.path}: cannot be read ({error})")

    def _connect_query_only(self) -> sqlite3.Connection | None:
        """:func:`query_only_connection` with the row factory, if the file holds the sessions table."""
        conn = query_only_connection(self.path)
        if conn is None:
            return None
        conn.row_factory = sqlite3.Row
        try:
            conn.execute("SELECT COUNT(*) FROM sessions").fetchone()
        except sqlite3.OperationalError:  # e.g. no sessions table: the read-only connection says what it is
            conn.close()
            return None
        except sqlite3.DatabaseError as exc:  # damaged: said here, where closing leaves no -wal or -shm behind
            conn.close()
            raise DamagedDatabase(f"{self.path}: the database is damaged ({exc}); the file was not changed; "
                                  "restore it from a backup or give another --db file") from None
        return conn

    def close(self) -> None:
        """Close the connection."""
        self.conn.close()

    def __enter__(self) -> SessionStore:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @contextmanager
    def transaction(self) -> Iterator[sqlite3.Connection]:
        """``BEGIN IMMEDIATE`` (takes the write lock up front, waiting up to the busy timeout) ... ``COMMIT``."""
        if self.read_only:
            raise RuntimeError(f"{self.path}: opened read-only; open SessionStore(path) to write")
        self.conn.execute("BEGIN IMMEDIATE")
        try:
            yield self.conn
        except BaseException:
            self.conn.execute("ROLLBACK")
            raise
        self.conn.execute("COMMIT")

    # -- sessions ------------------------------------------------------------------------------------
    def open_session(self, key: str, spec: dict, gain_names, claim: bool = True, force: bool = False) -> SessionInfo:
        """The session of ``key``, created if new; with ``claim``, this connection becomes its owner.

        A claim sets the session's budget to ``spec["budget"]`` (a rerun with
        another budget extends or shortens the session) and a fresh owner
        token: from then on only this connection can write to the session; a
        previous owner that is still running gets :class:`SessionBusy` at its
        next write, so two processes never interleave their experiments.

        Raises
        ------
        SessionBusy
            If another live process on this host, or any process on another
            host, owns the session (a process killed with SIGKILL leaves its
            claim behind; a dead owner on this host is replaced, one on another
            host only with ``force``).
        """
        now = time.time()
        host, pid = socket.gethostname(), os.getpid()
        with self.transaction() as conn:
            row = conn.execute("SELECT * FROM sessions WHERE key = ?", (key,)).fetchone()
            if row is None:
                conn.execute(
                    "INSERT INTO sessions (key, spec, env_id, tuner, seed, budget, gain_names, status, "
                    "created_at, updated_at) VALUES (?, ?, ?, ?, ?, ?, ?, 'new', ?, ?)",
                    (key, to_json(spec), spec["env"], spec["tuner"], spec["seed"], spec["budget"],
                     to_json(list(gain_names)), now, now))
                row = conn.execute("SELECT * FROM sessions WHERE key = ?", (key,)).fetchone()
            elif (claim and not force and row["owner_pid"] is not None
                  and (row["owner_host"], row["owner_pid"]) != (host, pid)):
                if row["owner_host"] != host or _alive(row["owner_pid"]):
                    raise SessionBusy(f"session {row['id']} is being run by process {row['owner_pid']} on "
                                      f"{row['owner_host']}; wait for it to finish (or end it) first, or take "
                                      "it over if that process is gone (gbo tune --force)")
            if claim:
                token = secrets.token_hex(8)
                conn.execute("UPDATE sessions SET owner_host = ?, owner_pid = ?, owner_token = ?, status = 'running', "
                             "message = NULL, budget = ?, spec = ?, updated_at = ? WHERE id = ?",
                             (host, pid, token, int(spec["budget"]), to_json(spec), now, row["id"]))
                self._claims[row["id"]] = token
        return self.session(row["id"])

    def release_session(self, session_id: int, status: str, message: str | None = None) -> None:
        """Drop this connection's claim and set the session status (``done``, ``stopped``, ``failed`` ...).

        A no-op when the session was taken over by another process meanwhile.
        """
        token = self._claims.pop(session_id, None)
        with self.transaction() as conn:
            conn.execute("UPDATE sessions SET owner_host = NULL, owner_pid = NULL, owner_token = NULL, status = ?, "
                         "message = ?, updated_at = ? WHERE id = ? AND owner_token = ?",
                         (status, message, time.time(), session_id, token))

    def _require_claim(self, conn: sqlite3.Connection, session_id: int) -> None:
        """Raise :class:`SessionBusy` unless this connection still owns the session (inside a transaction)."""
        row = conn.execute("SELECT owner_host, owner_pid, owner_token FROM sessions WHERE id = ?",
                           (session_id,)).fetchone()
        token = self._claims.get(session_id)
        if token is None or row is None or row["owner_token"] != token:
            owner = "another process (which has released it since)" if row is None or row["owner_pid"] is None \
                else f"process {row['owner_pid']} on {row['owner_host']}"
            raise SessionBusy(f"session {session_id} was taken over by {owner} (gbo tune --force); this process "
                              "stops without writing to it")

    def session(self, session_id: int) -> SessionInfo:
        """One session with its counts.

        Raises
        ------
        KeyError
            For an unknown id.
        """
        rows = self.sessions(session_id=session_id)
        if not rows:
            raise KeyError(f"session {session_id}: not in {self.path}")
        return rows[0]

    def sessions(self, session_id: int | None = None) -> list[SessionInfo]:
        """All sessions (or one), oldest first, with done / failed counts and best cost."""
        where, args = ("WHERE s.id = ?", (session_id,)) if session_id is not None else ("", ())
        query = f"""
            SELECT s.*,
                (SELECT COUNT(*) FROM experiments e WHERE e.session_id = s.id AND e.source = 'plant'
                    AND e.told = 1) AS done,
                (SELECT COUNT(*) FROM experiments e WHERE e.session_id = s.id AND e.source = 'plant'
                    AND e.status = 'failed') AS failed,
                (SELECT MIN(e.cost) FROM experiments e WHERE e.session_id = s.id AND e.source = 'plant'
                    AND e.status = 'ok') AS best_cost
            FROM sessions s {where} ORDER BY s.id"""
        return [SessionInfo(
            id=row["id"], key=row["key"], spec=json.loads(row["spec"]), env_id=row["env_id"], tuner=row["tuner"],
            seed=row["seed"], budget=row["budget"], gain_names=tuple(json.loads(row["gain_names"])),
            status=row["status"], message=row["message"], created_at=row["created_at"],
            updated_at=row["updated_at"], done=row["done"], failed=row["failed"],
            best_cost=math.nan if row["best_cost"] is None else row["best_cost"])
            for row in self.conn.execute(query, args)]

    def latest_session(self) -> SessionInfo:
        """The most recently updated session.

        Raises
        ------
        LookupError
            If the database holds no session.
        """
        row = self.conn.execute("SELECT id FROM sessions ORDER BY updated_at DESC, id DESC LIMIT 1").fetchone()
        if row is None:
            raise LookupError(f"{self.path}: no session stored yet")
        return self.session(row["id"])

    # -- experiments ---------------------------------------------------------------------------------
    def experiments(self, session_id: int, source: str | None = None) -> list[ExperimentRow]:
        """Rows of a session in the order they were written (``seq``)."""
        query = "SELECT * FROM experiments WHERE session_id = ?"
        args: tuple = (session_id,)
        if source is not None:
            query += " AND source = ?"
            args += (source,)
        return [_decode(row) for row in self.conn.execute(query + " ORDER BY seq", args)]

    def begin_plant(self, session_id: int, experiment: int, gains, twin_rows=()) -> int:
        """Commit the intent of a plant experiment (status ``running``) before the plant is touched.

        Twin evaluations the tuner made while proposing these gains are
        committed in the same transaction. Returns the row id.
        """
        now = time.time()
        with self.transaction() as conn:
            self._require_claim(conn, session_id)
            seq = self._next_seq(conn, session_id)
            cursor = conn.execute(
                "INSERT INTO experiments (session_id, seq, experiment, source, status, gains, started_at) "
                "VALUES (?, ?, ?, 'plant', 'running', ?, ?)", (session_id, seq, experiment, to_json(gains), now))
            row_id = cursor.lastrowid
            self._insert_twins(conn, session_id, seq + 1, experiment, row_id, "ask", twin_rows, now)
            self._touch(conn, session_id, now)
        return row_id

    def finish_plant(self, row_id: int, status: str, record: Mapping | None, *, reason: str | None = None,
                     told: bool, told_cost: float | None, env_state: dict | None,
                     snapshot: bytes | None = None) -> None:
        """Complete a plant row with the experiment record (arrays as BLOBs) in one transaction.

        ``snapshot``, the tuner as it proposed this experiment
        (:func:`evaluation.sessions.snapshot.tuner_snapshot`), replaces the
        session's snapshot in the same transaction.
        """
        if status not in ("ok", "failed"):
            raise ValueError(f"status: expected 'ok' or 'failed', got {status!r}")
        record = dict(record or {})
        blobs = {name: _blob_or_none(record.get(name)) for name in ARRAY_FIELDS}
        metrics = record.get("metrics")
        if metrics is not None and not isinstance(metrics, Mapping):
            metrics = list(np.asarray(metrics, dtype=float))
        extra = {k: v for k, v in record.items()
                 if k not in (*ARRAY_FIELDS, "gains", "metrics", "cost", "true_cost", "unstable", "experiment")}
        unstable = record.get("unstable")
        now = time.time()
        with self.transaction() as conn:
            session_id = self._session_of(conn, row_id)
            self._require_claim(conn, session_id)
            cursor = conn.execute(
                "UPDATE experiments SET status = ?, reason = ?, told = ?, cost = ?, told_cost = ?, true_cost = ?, "
                "unstable = ?, metrics = ?, t = ?, r = ?, u = ?, y = ?, extra = ?, env_state = ?, finished_at = ? "
                "WHERE id = ? AND status = 'running'",
                (status, reason, int(told), _real(record.get("cost")), _real(told_cost),
                 _real(record.get("true_cost")), None if unstable is None else int(bool(unstable)),
                 None if metrics is None else to_json(metrics), blobs["t"], blobs["r"], blobs["u"], blobs["y"],
                 to_json(extra), None if env_state is None else to_json(env_state), now, row_id))
            if cursor.rowcount != 1:
                raise RuntimeError(f"experiment row {row_id}: not an open intent (already completed?)")
            if snapshot is not None:
                conn.execute("INSERT OR REPLACE INTO snapshots (session_id, row_id, tuner, updated_at) "
                             "VALUES (?, ?, ?, ?)", (session_id, row_id, snapshot, now))
            self._touch(conn, session_id, now)

    def abandon_plant(self, row_id: int, status: str, reason: str) -> None:
        """Mark an intent (and its twin rows) ``lost-in-crash`` or ``interrupted``: it is not replayed."""
        if status not in ("lost-in-crash", "interrupted"):
            raise ValueError(f"status: expected 'lost-in-crash' or 'interrupted', got {status!r}")
        now = time.time()
        with self.transaction() as conn:
            session_id = self._session_of(conn, row_id)
            self._require_claim(conn, session_id)
            conn.execute("UPDATE experiments SET status = ?, reason = ?, finished_at = ? WHERE id = ? OR parent_id = ?",
                         (status, reason, now, row_id, row_id))
            self._touch(conn, session_id, now)

    def add_twins(self, session_id: int, experiment: int, parent_id: int, phase: str, twin_rows) -> None:
        """Commit twin evaluations made while the tuner learned from plant row ``parent_id``."""
        if not twin_rows:
            return
        now = time.time()
        with self.transaction() as conn:
            self._require_claim(conn, session_id)
            seq = self._next_seq(conn, session_id)
            self._insert_twins(conn, session_id, seq, experiment, parent_id, phase, twin_rows, now)
            self._touch(conn, session_id, now)

    def snapshot(self, session_id: int) -> tuple[int, bytes] | None:
        """The session's tuner snapshot as ``(row id of its experiment, pickle)``, or None."""
        row = self.conn.execute("SELECT row_id, tuner FROM snapshots WHERE session_id = ?", (session_id,)).fetchone()
        return None if row is None else (int(row["row_id"]), bytes(row["tuner"]))

    def integrity_check(self) -> str:
        """``PRAGMA integrity_check`` (``"ok"`` for a sound file)."""
        return "; ".join(str(row[0]) for row in self.conn.execute("PRAGMA integrity_check"))

    # -- helpers -------------------------------------------------------------------------------------
    @staticmethod
    def _next_seq(conn: sqlite3.Connection, session_id: int) -> int:
        return int(conn.execute("SELECT COALESCE(MAX(seq), 0) + 1 FROM experiments WHERE session_id = ?",
                                (session_id,)).fetchone()[0])

    @staticmethod
    def _insert_twins(conn, session_id, seq, experiment, parent_id, phase, twin_rows, now) -> None:
        for offset, twin in enumerate(twin_rows):
            twin = dict(twin)
            blobs = {name: _blob_or_none(twin.pop(name, None)) for name in ARRAY_FIELDS}
            gains = twin.pop("gains")
            cost = twin.pop("cost", None)
            metrics = twin.pop("metrics", None)
            if metrics is not None and not isinstance(metrics, Mapping):
                metrics = list(np.asarray(metrics, dtype=float))
            conn.execute(
                "INSERT INTO experiments (session_id, seq, experiment, source, parent_id, phase, status, told, gains,"
                " cost, metrics, t, r, u, y, extra, started_at, finished_at) "
                "VALUES (?, ?, ?, 'twin', ?, ?, 'ok', 0, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (session_id, seq + offset, experiment, parent_id, phase, to_json(gains), _real(cost),
                 None if metrics is None else to_json(metrics), blobs["t"], blobs["r"], blobs["u"], blobs["y"],
                 to_json(twin), now, now))

    @staticmethod
    def _touch(conn, session_id: int, now: float) -> None:
        conn.execute("UPDATE sessions SET updated_at = ? WHERE id = ?", (now, session_id))

    @staticmethod
    def _session_of(conn, row_id: int) -> int:
        row = conn.execute("SELECT session_id FROM experiments WHERE id = ?", (row_id,)).fetchone()
        if row is None:
            raise KeyError(f"experiment row {row_id}: not in the database")
        return int(row[0])


def _blob_or_none(value) -> bytes | None:
    if value is None:
        return None
    array = np.asarray(value)
    if array.dtype == object:
        return None
    return array_to_blob(array)


def _decode(row: sqlite3.Row) -> ExperimentRow:
    return ExperimentRow(
        id=row["id"], seq=row["seq"], experiment=row["experiment"], source=row["source"],
        parent_id=row["parent_id"], phase=row["phase"], status=row["status"], reason=row["reason"],
        told=bool(row["told"]), gains=tuple(json.loads(row["gains"])), cost=row["cost"],
        told_cost=row["told_cost"], true_cost=row["true_cost"],
        unstable=None if row["unstable"] is None else bool(row["unstable"]),
        metrics=None if row["metrics"] is None else json.loads(row["metrics"]),
        blobs={name: row[name] for name in ARRAY_FIELDS}, extra=json.loads(row["extra"] or "{}"),
        env_state=None if row["env_state"] is None else json.loads(row["env_state"]),
        started_at=row["started_at"], finished_at=row["finished_at"])


def _upgrade_from_version_1(conn: sqlite3.Connection) -> None:
    """Schema 1 -> 2 (inside the opening transaction): the owner token, and keys without the budget.

    A key shared by several version-1 sessions that differ only in their
    budget stays with the most recently updated one; the others keep their old key.
    """
    columns = {row[1] for row in conn.execute("SELECT * FROM pragma_table_info('sessions')")}
    if "owner_token" not in columns:
        conn.execute("ALTER TABLE sessions ADD COLUMN owner_token TEXT")
    taken = {row[0] for row in conn.execute("SELECT key FROM sessions")}
    for row in conn.execute("SELECT id, key, spec FROM sessions ORDER BY updated_at DESC").fetchall():
        key = session_key(json.loads(row[2]))
        if key not in taken:
            conn.execute("UPDATE sessions SET key = ? WHERE id = ?", (key, row[0]))
            taken.add(key)


def query_only_connection(path: Path) -> sqlite3.Connection | None:
    """A read-write connection that may only read (``PRAGMA query_only``), for a file without ``-wal`` and
    ``-shm`` companions that this process could write; None otherwise.

    A read-only connection (``mode=ro``) to a WAL database creates those two files and cannot remove
    them: ``gbo sessions`` would leave them behind. SQLite removes them when the last read-write
    connection closes, and reading changes nothing in the file.
    """
    path = Path(path)
    if any(Path(f"{path}{suffix}").exists() for suffix in ("-wal", "-shm")) or not os.access(path.parent, os.W_OK):
        return None
    try:
        with open(path, "r+b"):  # writable (chattr +i refuses root too); opening it changes nothing
            pass
    except OSError:
        return None
    conn = sqlite3.connect(str(path), timeout=BUSY_TIMEOUT_MS / 1000, isolation_level=None)
    try:
        conn.execute("PRAGMA query_only = ON")
        conn.execute(f"PRAGMA busy_timeout = {BUSY_TIMEOUT_MS}")
    except sqlite3.DatabaseError:
        conn.close()
        return None
    return conn


def check_sound(path: Path) -> None:
    """Raise :class:`DamagedDatabase` if the SQLite file at ``path`` fails ``PRAGMA quick_check``.

    The check only reads (:func:`query_only_connection`, else a read-only connection), so a damaged
    file is refused before a session writes to it (a write into a damaged b-tree can damage more,
    and would mark the session failed).
    """
    conn = query_only_connection(path)
    if conn is None:
        try:
            conn = sqlite3.connect(f"{Path(path).resolve().as_uri()}?mode=ro", uri=True,
                                   timeout=BUSY_TIMEOUT_MS / 1000)
        except sqlite3.Error:
            return  # cannot be opened to read (a read-only folder with a write-ahead log): the opening says why
    try:
        problems = [str(row[0]) for row in conn.execute("PRAGMA quick_check(5)")]
    except sqlite3.OperationalError:  # cannot be read here (a read-only folder without its -shm): the opening says why
        return
    except sqlite3.DatabaseError as exc:  # "database disk image is malformed"
        problems = [str(exc)]
    finally:
        conn.close()
    if problems != ["ok"]:
        raise DamagedDatabase(f"{path}: the database is damaged (SQLite's quick_check: {'; '.join(problems)[:200]}); "
                              "the file was not changed; restore it from a backup or give another --db file")


class DamagedDatabase(ValueError):
    """A session database that fails SQLite's ``PRAGMA quick_check``; it is refused unchanged."""


def _alive(pid: int) -> bool:
    """Whether a process with this id exists on this host."""
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
