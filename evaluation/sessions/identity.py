"""Tell a session database from any other file before opening it, without touching the file.

A session database carries :data:`APPLICATION_ID` in its SQLite header
(``PRAGMA application_id``, bytes 68-71) and its schema version in
``PRAGMA user_version`` (bytes 60-63). :func:`identify` reads those 100 header
bytes with a plain ``open``: no SQLite connection, so a foreign file gets no
lock, no ``-wal`` or ``-shm`` file and no table. Only a file whose application
id is 0 (what every SQLite file has unless its application sets one, and what
the session databases of schema version 1 have) is looked into, through an
``immutable`` read-only connection, for the tables of version 1.
"""

from __future__ import annotations

import sqlite3
from pathlib import Path

__all__ = ["APPLICATION_ID", "SCHEMA_VERSION", "NotASessionDatabase", "identify"]

#: ``PRAGMA application_id`` of a session database: ``b"GBOs"`` read as a big-endian integer.
APPLICATION_ID = int.from_bytes(b"GBOs", "big")
#: Schema version this code writes (``PRAGMA user_version``); version 1 (no application id) is upgraded.
SCHEMA_VERSION = 2

_MAGIC = b"SQLite format 3\x00"
_HEADER_BYTES = 100
#: Tables and some of their columns that identify a session database of schema version 1.
_V1_COLUMNS = {"sessions": {"key", "spec", "budget", "owner_pid"},
               "experiments": {"session_id", "seq", "told", "env_state"}}


class NotASessionDatabase(ValueError):
    """The file is not a session database (not SQLite, another application's, or a newer schema)."""


def identify(path: str | Path) -> str:
    """What ``path`` holds: ``"new"`` (missing or empty), ``"current"`` or ``"version 1"``.

    Raises
    ------
    NotASessionDatabase
        With one line naming the file: a folder, a file that is not SQLite, an
        SQLite database of another application, or a session database written
        by a newer version of this code.
    """
    path = Path(path)
    if path.is_dir():
        raise NotASessionDatabase(f"{path}: is a folder; give the database file (e.g. runs.sqlite)")
    if not path.exists():
        return "new"
    with open(path, "rb") as handle:
        header = handle.read(_HEADER_BYTES)
    if not header:
        return "new"
    if len(header) < _HEADER_BYTES or not header.startswith(_MAGIC):
        raise NotASessionDatabase(f"{path}: not an SQLite database (expected a gbo session database, e.g. "
                                  "runs.sqlite written by gbo tune); the file was not changed")
    application_id = int.from_bytes(header[68:72], "big")
    version = int.from_bytes(header[60:64], "big")
    if application_id == APPLICATION_ID:
        if version > SCHEMA_VERSION:
            raise NotASessionDatabase(f"{path}: session database of schema version {version}; this version of "
                                      f"gbo reads versions up to {SCHEMA_VERSION} (upgrade gbo-envs)")
        return "current"
    tables = {} if application_id else _tables(path)  # read once: for the version-1 check and the message
    if not application_id and all(columns <= tables.get(name, set()) for name, columns in _V1_COLUMNS.items()):
        return "version 1"
    raise NotASessionDatabase(f"{path}: an SQLite database of another application "
                              f"({_describe(application_id, tables)}), not a gbo session database; the file was not "
                              "changed (give another --db file)")


def _tables(path: Path) -> dict[str, set[str]]:
    """Table name -> column names, read through an ``immutable`` connection (no lock, no files created)."""
    conn = sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro&immutable=1", uri=True)
    try:
        names = [row[0] for row in conn.execute("SELECT name FROM sqlite_master WHERE type = 'table'")]
        return {name: {row[1] for row in conn.execute("SELECT * FROM pragma_table_info(?)", (name,))}
                for name in names}
    except sqlite3.DatabaseError:
        return {}
    finally:
        conn.close()


def _describe(application_id: int, tables: dict[str, set[str]]) -> str:
    if application_id:
        return f"application id {application_id:#010x}"
    names = sorted(tables)
    return f"tables: {', '.join(names[:5])}{', ...' if len(names) > 5 else ''}" if names else "no tables"
