"""Which files the session commands open, and how: foreign files refused untouched, reading read-only."""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import sqlite3
import subprocess
import sys
import tempfile

import pytest

import gbo_envs  # noqa: F401  (registers the envs)
from agents.twin.csvio import read_csv
from evaluation.cli import main as gbo
from evaluation.sessions import NotASessionDatabase, SessionStore, TuningSession
from evaluation.sessions.identity import APPLICATION_ID
from tests.support import REPO_ROOT

ENV = "gbo_envs/DCMotor-v0"


def _folder_state(folder) -> dict:
    """File name -> SHA-256 of every file in ``folder``."""
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir())}


def _foreign_sqlite(path, wal: bool = False, application_id: int = 0) -> None:
    conn = sqlite3.connect(path)
    if application_id:
        conn.execute(f"PRAGMA application_id = {application_id}")
    if wal:
        conn.execute("PRAGMA journal_mode = WAL")
    conn.execute("CREATE TABLE users (id INTEGER PRIMARY KEY, name TEXT)")
    conn.execute("INSERT INTO users (name) VALUES ('ada')")
    conn.commit()
    conn.close()


@pytest.mark.parametrize("kind, message", [
    ("sqlite", "an SQLite database of another application (tables: users)"),
    ("sqlite-wal", "an SQLite database of another application (tables: users)"),
    ("sqlite-app-id", "an SQLite database of another application (application id 0x00001234)"),
    ("text", "not an SQLite database"),
])
def test_a_foreign_file_is_refused_with_one_line_and_left_untouched(tmp_path, capsys, kind, message):
    db = tmp_path / "other.db"
    if kind == "text":
        db.write_text("id,name\n1,ada\n" * 20)
    else:
        _foreign_sqlite(db, wal=kind == "sqlite-wal", application_id=0x1234 if kind == "sqlite-app-id" else 0)
    before = _folder_state(tmp_path)
    for argv in (["sessions"], ["export", "--csv", str(tmp_path / "out" / "x.csv")],
                 ["tune", "--tuner", "random", "--budget", "1", "--no-progress"]):
        assert gbo([*argv, "--db", str(db)]) == 2  # bad input: the CLI's one exit status
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and str(db) in err and message in err, err
    with pytest.raises(NotASessionDatabase, match=re.escape(message)):
        SessionStore(db)
    assert _folder_state(tmp_path) == before  # no table, no -wal or -shm file, not a byte changed


def test_a_session_database_is_marked_and_read_without_writing(tmp_path):
    db = tmp_path / "runs.sqlite"
    TuningSession(db, ENV, "random", budget=2, seed=0).run()
    header = db.read_bytes()[:100]
    assert int.from_bytes(header[68:72], "big") == APPLICATION_ID  # in the file's header, where identify() reads
    before = _folder_state(tmp_path)["runs.sqlite"]
    with SessionStore(db, read_only=True) as store:
        assert [s.done for s in store.sessions()] == [2]
        with pytest.raises(RuntimeError, match="read-only"):
            store.release_session(1, "done")
        with pytest.raises(sqlite3.OperationalError, match="readonly"):
            store.conn.execute("DELETE FROM experiments")
    assert _folder_state(tmp_path)["runs.sqlite"] == before  # (a WAL reader may leave SQLite's -shm beside it)
    with pytest.raises(FileNotFoundError, match="no such file"):
        SessionStore(tmp_path / "missing.sqlite", read_only=True)
    assert not (tmp_path / "missing.sqlite").exists()


def _as_reader(argv: list[str], cwd) -> subprocess.CompletedProcess:
    """``gbo ARGV`` run by a user who may read but not write the database (``nobody`` when we are root)."""
    command = [sys.executable, "-m", "evaluation.cli", *argv]
    if os.geteuid() == 0:
        command = [shutil.which("setpriv"), "--reuid=65534", "--regid=65534", "--clear-groups", *command]
    env = {**os.environ, "PYTHONPATH": str(REPO_ROOT), "HOME": str(cwd)}
    return subprocess.run(command, cwd=cwd, env=env, capture_output=True, text=True, timeout=120)


@pytest.mark.slow  # runs gbo in fresh interpreters
@pytest.mark.skipif(sys.platform == "win32" or (os.geteuid() == 0 and not shutil.which("setpriv")),
                    reason="POSIX permissions; as root, setpriv runs the reader as nobody")
def test_a_read_only_database_in_a_read_only_folder_can_be_listed_and_exported():
    root = tempfile.mkdtemp()  # not under pytest's root-only folder: the reader may be another user
    try:
        folder, out = os.path.join(root, "ro"), os.path.join(root, "out")
        os.makedirs(out)
        TuningSession(os.path.join(folder, "runs.sqlite"), ENV, "random", budget=2, seed=0).run()
        db = os.path.join(folder, "runs.sqlite")
        os.chmod(db, 0o444)
        os.chmod(folder, 0o555)
        os.chmod(out, 0o777)
        os.chmod(root, 0o755)
        before = sorted(os.listdir(folder))
        listed = _as_reader(["sessions", "--db", db, "--json"], cwd=out)
        assert listed.returncode == 0, listed.stderr
        assert [s["done"] for s in json.loads(listed.stdout)] == [2]
        exported = _as_reader(["export", "--db", db, "--csv", os.path.join(out, "data.csv")], cwd=out)
        assert exported.returncode == 0, exported.stderr
        assert len(read_csv(os.path.join(out, "data.csv"), gain_names=("Kp", "Ki"))) == 2
        assert sorted(os.listdir(folder)) == before
    finally:
        os.chmod(os.path.join(root, "ro"), 0o755)
        shutil.rmtree(root)


def test_a_version_1_database_is_upgraded_in_place(tmp_path):
    # a database written before schema 2: no application id, no owner token or snapshots, budget in the key
    db = tmp_path / "runs.sqlite"
    TuningSession(db, ENV, "random", budget=3, seed=0).run()
    conn = sqlite3.connect(db)
    spec = json.loads(conn.execute("SELECT spec FROM sessions").fetchone()[0])
    from agents.jsonable import to_json

    conn.execute("UPDATE sessions SET key = ?", (hashlib.sha256(to_json(spec).encode()).hexdigest(),))
    conn.execute("DROP TABLE snapshots")
    conn.execute("ALTER TABLE sessions DROP COLUMN owner_token")
    conn.execute("PRAGMA application_id = 0")
    conn.execute("PRAGMA user_version = 1")
    conn.commit()
    conn.close()
    with SessionStore(db, read_only=True) as store:  # read as it is
        assert [s.done for s in store.sessions()] == [3]
    session = TuningSession(db, ENV, "random", budget=4, seed=0)  # upgraded, and found by its new key
    session.run()
    assert (session.session_id, session.n_replayed) == (1, 3)
    with SessionStore(db) as store:
        assert [s.done for s in store.sessions()] == [4]
        assert store.conn.execute("PRAGMA user_version").fetchone()[0] == 2


@pytest.mark.slow  # runs gbo in fresh interpreters
@pytest.mark.skipif(sys.platform == "win32" or (os.geteuid() == 0 and not shutil.which("setpriv")),
                    reason="POSIX permissions; as root, setpriv runs the reader as nobody")
def test_a_session_on_a_read_only_database_is_a_clear_error():
    root = tempfile.mkdtemp()
    try:
        db = os.path.join(root, "runs.sqlite")
        TuningSession(db, ENV, "random", budget=1, seed=0).run()
        os.chmod(db, 0o444)
        os.chmod(root, 0o755)
        code = ("import sys\nfrom evaluation.sessions import TuningSession\n"
                "try:\n    TuningSession(sys.argv[1], 'gbo_envs/DCMotor-v0', 'random', budget=2, seed=0).run()\n"
                "except PermissionError as exc:\n    print(exc)\n    raise SystemExit(3)\n")
        command = [sys.executable, "-c", code, db]
        if os.geteuid() == 0:
            command = [shutil.which("setpriv"), "--reuid=65534", "--regid=65534", "--clear-groups", *command]
        done = subprocess.run(command, cwd=root, env={**os.environ, "PYTHONPATH": str(REPO_ROOT), "HOME": root},
                              capture_output=True, text=True, timeout=120)
        assert done.returncode == 3, done.stderr
        assert f"{db}: cannot be written" in done.stdout and "needs write access" in done.stdout
    finally:
        shutil.rmtree(root)
