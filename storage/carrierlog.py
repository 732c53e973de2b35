"""A carrier's durable log (SQLite, one file per carrier): what it observed and what it did at
each stage, committed before it acts on it.

It is what lets a carrier go on without the coordinator and lets nothing be lost when the
coordinator is gone: a restarted carrier picks up from its own log when no coordinator answers,
and ``run_fleet.py --role report`` assembles a mission's results from these logs (with the
coordinator's mission.db when there is one). Written in ``<out>/carriers/<id>.db``.

Tables:

* ``meta(key, value)`` — identity (mission, carrier, scenario, fingerprint, seed), JSON values; a
  log is never reused for another mission or world (:class:`LogMismatch`);
* ``stages(stage, t, x, observed, position, status, deployed, passengers_left, wall_time)`` — one
  row per stage the carrier reached: ``observed`` 1 once it sensed (``x`` NULL = ∅), ``status``
  NULL until the stage was resolved, else how: a Confirm status of docs/protocol.md (``deployed``,
  ``idle``, ``late``, ``refused``) for a coordinator's decision, or ``own`` for a stage it decided
  itself. An outcome is never overwritten (at most once per stage).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from storage.sqlite import encoded_meta, first_mismatch, open_read_only, open_wal, read_meta

SCHEMA_VERSION = 1

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS stages (
    stage INTEGER PRIMARY KEY,
    t REAL NOT NULL,                  -- mission time of the stage, s
    x INTEGER,                        -- features sensed; NULL = ∅
    observed INTEGER NOT NULL,        -- 1 once the carrier sensed at this stage
    pos_x REAL, pos_y REAL,           -- metres, at the stage time
    status TEXT,                      -- NULL = not resolved; a Confirm status, or 'own'
    deployed INTEGER,                 -- 1 if a passenger was released here
    passengers_left INTEGER,          -- on board after the stage
    wall_time REAL                    -- when the outcome was written, s since the epoch
);
"""


class LogMismatch(RuntimeError):
    """The log file belongs to another mission, carrier or world."""


@dataclass(frozen=True)
class LogEntry:
    """One stage of a carrier's log (``status`` None: reached but not resolved)."""

    stage: int
    t: float
    x: int | None
    observed: bool
    position: tuple[float, float] | None
    status: str | None
    deployed: bool
    passengers_left: int | None

    @property
    def own(self) -> bool:
        return self.status == "own"


def log_path(out_dir: str | Path, carrier: str) -> Path:
    return Path(out_dir) / "carriers" / f"{carrier}.db"


#: How a carrier log commits (SQLite ``synchronous`` in WAL mode): ``full`` survives a power loss
#: of the carrier's host (an fsync per commit, which queues behind every other carrier of the
#: host committing at once); ``normal`` survives the carrier process's crash, not
#: its host's power loss. The one-host launcher uses ``normal``: a power loss there takes the
#: whole fleet, coordinator included.
SYNC_MODES = ("full", "normal")


class CarrierLog:
    """Open or create a carrier's log. ``meta``: mission, carrier, scenario, fingerprint, seed;
    ``sync``: one of :data:`SYNC_MODES`."""

    def __init__(self, path: str | Path, meta: dict, sync: str = "full"):
        if sync not in SYNC_MODES:
            raise ValueError(f"sync must be one of {SYNC_MODES}, found {sync!r}")
        self.path = Path(path)
        self.db = open_wal(self.path, sync, check_same_thread=False)
        self.db.executescript(_SCHEMA)
        wanted = encoded_meta(meta, SCHEMA_VERSION)
        bad = first_mismatch(self.db, wanted)
        if bad:
            self.db.close()
            key, had, value = bad
            raise LogMismatch(f"{self.path}: holds another mission ({key} is {had}, this carrier has "
                              f"{value}); use another --out directory")
        self.db.execute("INSERT OR IGNORE INTO meta (key, value) VALUES " + ", ".join("(?, ?)" for _ in wanted),
                        [v for kv in wanted.items() for v in kv])

    def observed(self, stage: int, t: float, x: int | None, position) -> None:
        """The carrier sensed ``x`` at ``stage`` (committed on return)."""
        self.db.execute(
            "INSERT INTO stages (stage, t, x, observed, pos_x, pos_y) VALUES (?, ?, ?, 1, ?, ?) "
            "ON CONFLICT(stage) DO UPDATE SET x=excluded.x, observed=1, pos_x=excluded.pos_x, pos_y=excluded.pos_y "
            "WHERE status IS NULL",
            (int(stage), float(t), None if x is None else int(x), float(position[0]), float(position[1])))

    def outcome(self, stage: int, t: float, status: str, deployed: bool, position, passengers_left: int,
                wall_time: float) -> bool:
        """How ``stage`` was resolved (committed on return, before the carrier acts on it).
        Returns False, writing nothing, if the stage has an outcome already."""
        cur = self.db.execute(
            "INSERT INTO stages (stage, t, observed, pos_x, pos_y, status, deployed, passengers_left, wall_time) "
            "VALUES (?, ?, 0, ?, ?, ?, ?, ?, ?) ON CONFLICT(stage) DO UPDATE SET status=excluded.status, "
            "deployed=excluded.deployed, passengers_left=excluded.passengers_left, wall_time=excluded.wall_time, "
            "pos_x=excluded.pos_x, pos_y=excluded.pos_y WHERE status IS NULL",
            (int(stage), float(t), float(position[0]), float(position[1]), status, int(bool(deployed)),
             int(passengers_left), float(wall_time)))
        return cur.rowcount > 0

    def entries(self) -> list[LogEntry]:
        return _entries(self.db)

    def close(self) -> None:
        try:
            self.db.close()
        except Exception:
            pass


def read_log(path: str | Path) -> tuple[dict, list[LogEntry]]:
    """(meta, entries) of the log at ``path``, read-only."""
    db = open_read_only(path)
    try:
        meta = read_meta(db)
        return meta, _entries(db)
    finally:
        db.close()


def _entries(db) -> list[LogEntry]:
    return [LogEntry(int(stage), float(t), None if x is None else int(x), bool(observed),
                     None if px is None else (float(px), float(py)), status, bool(deployed), left)
            for stage, t, x, observed, px, py, status, deployed, left in db.execute(
                "SELECT stage, t, x, observed, pos_x, pos_y, status, deployed, passengers_left FROM stages "
                "ORDER BY stage")]
