"""What mission.db and the carrier logs share: a SQLite file in WAL mode, read-only access, and
the ``meta`` table of JSON values that names the mission a file belongs to."""
from __future__ import annotations

import json
import sqlite3
from pathlib import Path

#: Seconds a writer waits for another process's write lock before SQLite reports the file busy.
LOCK_TIMEOUT_S = 10.0


def open_wal(path: Path, synchronous: str, check_same_thread: bool = True) -> sqlite3.Connection:
    """Open (creating it and its directory) ``path`` in autocommit mode with a WAL journal and
    the given ``synchronous`` level (``FULL``: survives a power loss; ``NORMAL``: a process crash)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    db = sqlite3.connect(str(path), isolation_level=None, timeout=LOCK_TIMEOUT_S, check_same_thread=check_same_thread)
    db.execute("PRAGMA journal_mode=WAL")
    db.execute(f"PRAGMA synchronous={synchronous.upper()}")
    return db


def open_read_only(path: str | Path, timeout: float | None = None) -> sqlite3.Connection:
    """``path`` opened read-only (it must exist)."""
    uri = f"file:{Path(path)}?mode=ro"
    return sqlite3.connect(uri, uri=True) if timeout is None else sqlite3.connect(uri, uri=True, timeout=timeout)


def read_meta(db: sqlite3.Connection) -> dict:
    """The ``meta`` table, JSON values decoded."""
    return {k: json.loads(v) for k, v in db.execute("SELECT key, value FROM meta")}


def encoded_meta(meta: dict, schema: int) -> dict:
    """``meta`` with the schema version, as stored (JSON text, keys sorted)."""
    return {k: json.dumps(v, sort_keys=True) for k, v in dict(meta, schema=schema).items()}


def first_mismatch(db: sqlite3.Connection, wanted: dict) -> tuple[str, str, str] | None:
    """(key, stored, wanted) of the first ``meta`` entry of the file that differs from the
    encoded ``wanted`` (keys the file lacks do not count), or None."""
    stored = dict(db.execute("SELECT key, value FROM meta").fetchall())
    for key, value in wanted.items():
        if key in stored and stored[key] != value:
            return key, stored[key], value
    return None
