"""mission.db: the coordinator's durable, append-only mission log (SQLite, WAL).

Every input the coordinator acts on is committed here before anything that depends on it is
published: observations and liveliness events before the stage's decision, the decision before it
is sent. A restarted coordinator loads the mission events (:meth:`MissionStore.mission_events`)
and folds them through the same ``mission.state.step`` as live handling, then continues from the
first undecided stage, drawing the same planner random numbers (planners are stateless).

Each write is one SQLite transaction, or, inside :meth:`MissionStore.batch` (what the
coordinator holds while it drains its inbox), one savepoint of the batch's transaction, committed
when the batch ends or :meth:`MissionStore.flush` is called — the coordinator flushes before it
sends anything that depends on what it recorded (a Decision, an Accepted, a Refusal). A durable
commit (``synchronous=FULL``: an fsync) costs far more than a savepoint, and the coordinator's
loop waits for it, so a drained inbox costs one commit, not one per event (``python -m
tools.overhead_bench``; docs/performance.md, "Where a stage's wall time goes"). What a crash can
lose is what it always could:
messages received and not yet acted on, which the carriers send again when they resynchronise
(docs/protocol.md). The processes never raise KeyboardInterrupt (signals only set a stop request
honoured between steps), so no write is ever cut in half; should one fail anyway, its
transaction (or savepoint) is rolled back and the connection is usable again.

Tables:

* ``meta(key, value)`` — mission identity (mission id, scenario name and hash, seed, planner).
* ``events(seq, wall_time, kind, carrier, stage, payload)`` — every event in arrival order
  (``own``: a carrier's account of a stage it decided itself; an ``observation`` or ``own`` of a
  coverage mission has ``counts``, its region counts: a key added without a schema change, read
  as absent in older rows);
  append-only (triggers forbid UPDATE and DELETE). ``payload`` is JSON.
* ``observations(carrier, stage, ...)``, ``decisions(stage, ...)``, ``confirmations(carrier,
  stage, ...)`` — typed copies of the first event of each kind per key; their primary keys make a
  second decision for a stage, or a second observation per carrier and stage, impossible.
"""
from __future__ import annotations

import json
import sqlite3
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

from mission import events as ev
from mission.ballot import Ballot
from planner.limits import EPOCH_MAX
from storage.sqlite import LOCK_TIMEOUT_S, encoded_meta, first_mismatch, open_read_only, open_wal, read_meta

SCHEMA_VERSION = 1

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS events (
    seq INTEGER PRIMARY KEY AUTOINCREMENT,
    wall_time REAL NOT NULL,          -- seconds since the epoch
    kind TEXT NOT NULL,               -- see EVENT_KINDS
    carrier TEXT,                     -- carrier id or NULL
    stage INTEGER,                    -- stage index or NULL
    payload TEXT NOT NULL             -- JSON object
);
CREATE TRIGGER IF NOT EXISTS events_no_update BEFORE UPDATE ON events
    BEGIN SELECT RAISE(ABORT, 'events is append-only'); END;
CREATE TRIGGER IF NOT EXISTS events_no_delete BEFORE DELETE ON events
    BEGIN SELECT RAISE(ABORT, 'events is append-only'); END;
CREATE TABLE IF NOT EXISTS observations (
    carrier TEXT NOT NULL, stage INTEGER NOT NULL,
    x INTEGER,                        -- features sensed; NULL = ∅ (reported or missing)
    missing INTEGER NOT NULL,         -- 1 if no observation arrived in time (coordinator's ∅)
    pos_x REAL, pos_y REAL,           -- metres
    seq INTEGER NOT NULL,
    PRIMARY KEY (carrier, stage)
);
CREATE TABLE IF NOT EXISTS decisions (
    stage INTEGER PRIMARY KEY,
    deploy TEXT NOT NULL,             -- JSON array of carrier ids
    planning_ms REAL NOT NULL,
    seq INTEGER NOT NULL
);
CREATE TABLE IF NOT EXISTS confirmations (
    carrier TEXT NOT NULL, stage INTEGER NOT NULL,
    deployed INTEGER NOT NULL, status TEXT NOT NULL,
    pos_x REAL, pos_y REAL,
    latency_ms REAL,                  -- decision publication to confirmation, coordinator clock
    seq INTEGER NOT NULL,
    PRIMARY KEY (carrier, stage)
);
"""

#: Event kinds written to ``events``.
EVENT_KINDS = (
    "open", "hello", "alive", "dead", "observation", "missing", "decision", "published",
    "confirm", "own", "bye", "rejected", "end", "epoch", "planner-fault", "operator",
)


class StoreMismatch(RuntimeError):
    """The existing mission.db belongs to another mission (different scenario, seed or planner)."""


class StoreBusy(RuntimeError):
    """Another process holds mission.db's write lock longer than the busy timeout (a primary
    that hangs, or was frozen, in the middle of a write): try again later."""


class EpochsExhausted(RuntimeError):
    """The epoch this coordinator would take is above the highest the wire carries
    (``planner.limits.EPOCH_MAX``): it refuses to open the mission rather than wrap or
    publish what no carrier can read. Nothing was written."""


class StoreFenced(RuntimeError):
    """A decision's write refused in its own transaction: another coordinator opened this
    mission.db with a newer epoch (a standby that took over on the same disk while this process
    was paused or cut off between its check and its write). Nothing of it was written."""

    def __init__(self, path, ballot: Ballot):
        super().__init__(f"{path}: a coordinator of epoch {ballot.epoch}"
                         + (f" ({ballot.coordinator})" if ballot.coordinator else "") + " took over this mission")
        self.ballot, self.epoch = ballot, ballot.epoch


@dataclass
class MissionRecord:
    """Everything :meth:`MissionStore.replay` recovers.

    Attributes:
        observations: ``{(carrier, stage): x or None}``; None = ∅ (reported or missing).
        positions: ``{(carrier, stage): (x, y)}`` metres, where reported.
        decisions: ``{stage: (deploy ids tuple, planning_ms)}``.
        confirmations: ``{(carrier, stage): (deployed, status, (x, y))}``.
        carriers_info: ``{carrier: {"pid": int, "host": str}}`` from the last Hello.
        ended: an ``end`` event was written.
        end_reason: the reason of the last ``end`` event (``complete``, ``stopped``), or None.
        events: number of events.
    """

    observations: dict = field(default_factory=dict)
    positions: dict = field(default_factory=dict)
    decisions: dict = field(default_factory=dict)
    confirmations: dict = field(default_factory=dict)
    carriers_info: dict = field(default_factory=dict)
    ended: bool = False
    end_reason: str | None = None
    events: int = 0

    @property
    def next_stage(self) -> int:
        """First stage without a decision (stages are decided in order)."""
        j = 0
        while j in self.decisions:
            j += 1
        return j


class _Tx:
    """The context of one write of a :class:`MissionStore`: its own transaction, or a savepoint
    of the open batch's (:meth:`MissionStore.batch`)."""

    __slots__ = ("store",)

    def __init__(self, store: "MissionStore"):
        self.store = store

    def __enter__(self):
        db = self.store.db
        if self.store._batching:
            if not db.in_transaction:
                db.execute("BEGIN IMMEDIATE")
            db.execute("SAVEPOINT write")
            return
        if db.in_transaction:  # a write that failed half-way: never build on it
            db.execute("ROLLBACK")
        db.execute("BEGIN IMMEDIATE")

    def __exit__(self, kind, value, tb):
        db = self.store.db
        if self.store._batching:
            if kind is not None:
                db.execute("ROLLBACK TO write")
            db.execute("RELEASE write")
        elif kind is None:
            db.execute("COMMIT")
        elif db.in_transaction:
            db.execute("ROLLBACK")
        return False


class MissionStore:
    """Append-only mission log. Not thread-safe: use it from the coordinator's main thread only."""

    def __init__(self, path: str | Path, meta: dict, synchronous: str = "FULL", min_epoch: int = 1,
                 coordinator: str = ""):
        """Open or create ``path``.

        Args:
            path: the database file (created with its parent directory if missing).
            meta: the mission identity (JSON-able values). An existing file must hold the same.
            synchronous: SQLite ``synchronous`` level; FULL survives power loss, NORMAL a process crash.
            min_epoch: the lowest epoch the opening coordinator may take (one more than an
                epoch it learnt elsewhere, e.g. from a primary's State).
            coordinator: the opening coordinator's id ("": none), recorded with its epoch in its
                ``open`` event: its ballot (mission.ballot), by which this file fences writes.

        Attributes:
            epoch: the opening coordinator's epoch: ``min_epoch``, or one more than the highest
                epoch recorded here if that is higher (1 for a fresh mission); written in its
                ``open`` event in the same transaction that reads the recorded ones.

        Raises:
            StoreMismatch: when the file holds another mission.
            StoreBusy: when another process holds the write lock for more than ``LOCK_TIMEOUT_S``.
            EpochsExhausted: when that epoch would be above ``EPOCH_MAX``.
        """
        self.path = Path(path)
        self._batching = False
        self._after: list = []  # (callback, event) of writes not committed yet (:meth:`record`)
        self.existed = self.path.exists() and self.path.stat().st_size > 0
        self.db = open_wal(self.path, synchronous)
        self.db.executescript(_SCHEMA)
        wanted = encoded_meta(meta, SCHEMA_VERSION)
        stored = self.db.execute("SELECT 1 FROM meta LIMIT 1").fetchone() is not None
        bad = first_mismatch(self.db, wanted)
        if bad:
            self.db.close()
            key, had, value = bad
            raise StoreMismatch(f"{self.path}: holds another mission ({key} is {had}, this run has {value}); "
                                "use another --out directory")
        try:
            with self._tx():
                self.db.executemany("INSERT OR IGNORE INTO meta (key, value) VALUES (?, ?)", wanted.items())
                self.epoch = max(int(min_epoch), 1 + _highest_epoch(self.db))
                if self.epoch > EPOCH_MAX:
                    raise EpochsExhausted(f"{self.path}: epoch {self.epoch} is above the highest the protocol "
                                          f"carries ({EPOCH_MAX}); this mission cannot be resumed")
                self.coordinator = coordinator
                self._checked = self._event("open", None, None, {"resumed": bool(stored), "epoch": self.epoch,
                                                                 **({"coordinator": coordinator} if coordinator else {})})
        except EpochsExhausted:
            self.db.close()
            raise
        except sqlite3.OperationalError as exc:
            self.db.close()
            if "locked" in str(exc) or "busy" in str(exc):
                raise StoreBusy(f"{self.path}: locked by another process") from None
            raise

    # ------------------------------------------------------------------ writing
    def _tx(self) -> "_Tx":
        """One write: its own transaction, or a savepoint of the open batch's."""
        return _Tx(self)

    @contextmanager
    def batch(self):
        """A context in which writes share one transaction, committed at its end (or at
        :meth:`flush`); each write stays atomic on its own (a savepoint). Not reentrant."""
        self._batching = True
        try:
            yield
        finally:
            try:
                self.flush()
            finally:
                self._batching = False

    def flush(self) -> None:
        """Commit the open batch's writes (nothing to do outside a batch: every write committed),
        then hand each recorded event to its ``then`` callback (:meth:`record`)."""
        if self._batching and self.db.in_transaction:
            self.db.execute("COMMIT")
        done, self._after = self._after, []
        for then, event in done:
            then(event)

    def _event(self, kind: str, carrier, stage, payload: dict, wall_time: float | None = None) -> int:
        assert kind in EVENT_KINDS, kind
        cur = self.db.execute(
            "INSERT INTO events (wall_time, kind, carrier, stage, payload) VALUES (?, ?, ?, ?, ?)",
            (time.time() if wall_time is None else float(wall_time), kind, carrier, stage,
             json.dumps(payload, sort_keys=True)),
        )
        return cur.lastrowid

    def event(self, kind: str, carrier: str | None = None, stage: int | None = None, *,
              wall_time: float | None = None, **payload) -> None:
        """Append one event (committed on return); ``wall_time``: when it happened (s, epoch;
        now by default)."""
        with self._tx():
            self._event(kind, carrier, stage, payload, wall_time)

    def observation(self, carrier: str, stage: int, x: int | None, position, *, wall_time: float | None = None,
                    **payload) -> bool:
        """Record a carrier's observation; returns False (and records nothing) for a repeat."""
        with self._tx():
            if self.db.execute(
                "SELECT 1 FROM observations WHERE carrier=? AND stage=?", (carrier, stage)
            ).fetchone():
                return False
            seq = self._event("observation", carrier, stage, dict(payload, x=x, position=list(position)), wall_time)
            self.db.execute(
                "INSERT INTO observations VALUES (?, ?, ?, 0, ?, ?, ?)",
                (carrier, stage, x, float(position[0]), float(position[1]), seq),
            )
        return True

    def missing(self, stage: int, carriers) -> None:
        """Record that ``carriers`` sent no observation for ``stage`` in time (they are ∅)."""
        with self._tx():
            for cid in carriers:
                seq = self._event("missing", cid, stage, {})
                self.db.execute(
                    "INSERT OR IGNORE INTO observations VALUES (?, ?, NULL, 1, NULL, NULL, ?)", (cid, stage, seq)
                )

    def decision(self, stage: int, deploy, planning_ms: float, *, missing=(), wall_time: float | None = None,
                 **payload) -> None:
        """Record the decision of ``stage``, and in the same transaction the ``missing`` carriers
        (scheduled, no observation: ∅). Raises :class:`StoreFenced` when a newer ballot opened
        this file (checked under the write lock, in the decision's transaction), and
        sqlite3.IntegrityError if the stage was decided before."""
        with self._tx():
            newer = self.newer_ballot()
            if newer is not None:
                raise StoreFenced(self.path, newer)
            for cid in missing:
                seq = self._event("missing", cid, stage, {}, wall_time)
                self.db.execute(
                    "INSERT OR IGNORE INTO observations VALUES (?, ?, NULL, 1, NULL, NULL, ?)", (cid, stage, seq)
                )
            seq = self._event("decision", None, stage, dict(payload, deploy=list(deploy), planning_ms=planning_ms),
                              wall_time)
            self.db.execute(
                "INSERT INTO decisions VALUES (?, ?, ?, ?)", (stage, json.dumps(list(deploy)), planning_ms, seq)
            )

    def confirmation(self, carrier: str, stage: int, deployed: bool, status: str, position,
                     latency_ms: float | None, *, wall_time: float | None = None, **payload) -> bool:
        """Record a carrier's Confirm; returns False for a repeat (the first one stands)."""
        with self._tx():
            if self.db.execute(
                "SELECT 1 FROM confirmations WHERE carrier=? AND stage=?", (carrier, stage)
            ).fetchone():
                return False
            seq = self._event("confirm", carrier, stage, dict(
                payload, deployed=deployed, status=status, position=list(position), latency_ms=latency_ms,
            ), wall_time)
            self.db.execute(
                "INSERT INTO confirmations VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                (carrier, stage, int(deployed), status, float(position[0]), float(position[1]), latency_ms, seq),
            )
        return True

    # ------------------------------------------------------------------ reading
    def replay(self) -> MissionRecord:
        """The typed tables' summary of the log (for tools and tests). The coordinator itself
        recovers with :meth:`mission_events` folded through ``mission.state.step``."""
        rec = MissionRecord()
        for cid, stage, x, missing, px, py in self.db.execute(
            "SELECT carrier, stage, x, missing, pos_x, pos_y FROM observations"
        ):
            rec.observations[(cid, stage)] = None if missing or x is None else int(x)
            if px is not None:
                rec.positions[(cid, stage)] = (px, py)
        for stage, deploy, ms in self.db.execute("SELECT stage, deploy, planning_ms FROM decisions"):
            rec.decisions[stage] = (tuple(json.loads(deploy)), ms)
        for cid, stage, deployed, status, px, py in self.db.execute(
            "SELECT carrier, stage, deployed, status, pos_x, pos_y FROM confirmations"
        ):
            rec.confirmations[(cid, stage)] = (bool(deployed), status, (px, py))
        for cid, payload in self.db.execute(
            "SELECT carrier, payload FROM events WHERE kind='hello' ORDER BY seq"
        ):
            info = json.loads(payload)
            rec.carriers_info[cid] = {"pid": info.get("pid"), "host": info.get("host")}
        last_end = self.db.execute("SELECT payload FROM events WHERE kind='end' ORDER BY seq DESC LIMIT 1").fetchone()
        rec.ended = last_end is not None
        rec.end_reason = json.loads(last_end[0]).get("reason") if last_end else None
        rec.events = self.db.execute("SELECT COUNT(*) FROM events").fetchone()[0]
        return rec

    def record(self, record, state, then=None) -> None:
        """Persist the event of a ``mission.state.Record`` effect (one write), given the state the
        step produced (for the values the state derived: the latency, the column of
        observations the decision read); ``then(event)`` is called once it is committed (the
        recorder's mission.mcap follows mission.db)."""
        self._write(record, state)
        if then is not None:
            self._after.append((then, record.event))
            if not self._batching:
                self.flush()

    def _write(self, record, state) -> None:
        e = record.event
        if isinstance(e, ev.Hello):
            self.event("hello", e.carrier, record.stage, wall_time=e.at, pid=e.pid, host=e.host,
                       passengers_left=e.passengers_left, next_stage=e.next_stage, fingerprint=e.fingerprint,
                       revision=e.revision,
                       compatible=e.fingerprint == state.spec.fingerprint)
        elif isinstance(e, ev.Observation):
            extra = {} if e.counts is None else {"counts": list(e.counts)}  # the coverage reward's region counts
            self.observation(e.carrier, e.stage, e.x, e.position, wall_time=e.at, t=e.t,
                             passengers_left=e.passengers_left, trail=[list(p) for p in e.trail], **extra)
        elif isinstance(e, ev.LivelinessChanged):
            self.event("alive" if e.alive else "dead", e.carrier, record.stage, wall_time=e.at)
        elif isinstance(e, ev.Decided):
            column = {}
            for r, cid in enumerate(state.spec.carriers):
                value = state.observation(r, e.stage)
                column[cid] = None if value != value else value  # NaN = ∅
            self.decision(e.stage, e.deploy, e.planning_ms, missing=record.missing, wall_time=e.at,
                          observations=column, passengers=list(e.passengers), **_operator_fields(e))
        elif isinstance(e, ev.Published):
            self.event("published", None, e.stage, wall_time=e.at)
        elif isinstance(e, ev.Confirmed):
            self.confirmation(e.carrier, e.stage, e.deployed, e.status, e.position,
                              state.confirms[(e.carrier, e.stage)].latency_ms, wall_time=e.at,
                              passengers_left=e.passengers_left, passenger=e.passenger)
        elif isinstance(e, ev.Accounted):
            extra = {} if e.counts is None else {"counts": list(e.counts)}
            self.event("own", e.carrier, e.stage, wall_time=e.at, t=e.t, x=e.x, deployed=e.deployed,
                       position=list(e.position), passengers_left=e.passengers_left, **extra)
        elif isinstance(e, ev.Bye):
            self.event("bye", e.carrier, None, wall_time=e.at, reason=e.reason, rejected=dict(e.rejected),
                       deployments=list(e.deployments))
        elif isinstance(e, ev.Ended):
            self.event("end", None, record.stage, wall_time=e.at, reason=e.reason)
        elif isinstance(e, ev.OperatorAction):
            self.event("operator", e.carrier, e.stage, wall_time=e.at, action=e.action, operator=e.operator)
        else:
            raise TypeError(f"not a recorded mission event: {e!r}")

    def mission_events(self) -> list:
        """Every recorded mission event (mission.events), in the order they were committed: the
        input of ``mission.state.fold``. ``missing`` and ``rejected`` rows are not events (the
        fold derives the first from the decisions; the second changes nothing)."""
        return _mission_events(self.db)

    def latencies_ms(self) -> list[float]:
        """Decision-to-confirmation round trips recorded, milliseconds."""
        return [r[0] for r in self.db.execute(
            "SELECT latency_ms FROM confirmations WHERE latency_ms IS NOT NULL ORDER BY seq"
        )]

    def planner_faults(self) -> list[dict]:
        """Every ``planner-fault`` event: the stages the planner broke a rule at and the on-board
        fallback decided instead (``stage``, ``rule``, ``detail``, ``fallback``), in order."""
        return [dict(json.loads(p), stage=stage) for stage, p in self.db.execute(
            "SELECT stage, payload FROM events WHERE kind = 'planner-fault' ORDER BY seq")]

    @property
    def ballot(self) -> Ballot:
        """The opening coordinator's ballot: its epoch and its id."""
        return Ballot(self.epoch, self.coordinator)

    def newer_ballot(self) -> Ballot | None:
        """The highest ballot another coordinator recorded in this file since the last call (or
        since this store opened), if above ours: a standby that took over on the same disk while
        this process was cut off from everyone (docs/fleet.md, "Split brain"). Reads only the
        rows added since the last call (a range of the primary key)."""
        rows = self.db.execute("SELECT seq, payload FROM events WHERE seq > ? AND kind IN ('open', 'epoch')",
                               (self._checked,)).fetchall()
        last = self.db.execute("SELECT MAX(seq) FROM events").fetchone()[0]
        self._checked = max(self._checked, last or 0)
        top = Ballot(0)
        for _, p in rows:
            row = json.loads(p)
            top = top.highest(Ballot(int(row.get("epoch", 1)), str(row.get("coordinator", ""))))
        return top if self.ballot.below(top) else None

    def close(self) -> None:
        try:
            self.db.close()
        except Exception:
            pass


def load_events(path: str | Path) -> list:
    """The mission events of the mission.db at ``path``, read-only (for tools and tests)."""
    db = open_read_only(path)
    try:
        return _mission_events(db)
    finally:
        db.close()


def load_meta(path: str | Path) -> dict:
    """The mission identity in the ``meta`` table of the mission.db at ``path`` (JSON values
    decoded), read-only."""
    db = open_read_only(path)
    try:
        return read_meta(db)
    finally:
        db.close()


def highest_epoch(path: str | Path) -> int:
    """The highest coordinator epoch recorded in the mission.db at ``path`` (read-only; in the
    ``open`` events and the ``epoch`` events that coordinators of protocol revisions 1 to 5 wrote
    when a carrier's Hello raised their epoch; none are written since): 0 when there is no such
    file or it holds no mission; an ``open`` written before epochs existed counts as epoch 1 (its
    decisions carried none, which means 1)."""
    path = Path(path)
    if not path.is_file() or path.stat().st_size == 0:
        return 0
    db = open_read_only(path, timeout=LOCK_TIMEOUT_S)
    try:
        return _highest_epoch(db)
    finally:
        db.close()


def _highest_epoch(db) -> int:
    rows = db.execute("SELECT payload FROM events WHERE kind IN ('open', 'epoch')").fetchall()
    return max((int(json.loads(p).get("epoch", 1)) for (p,) in rows), default=0)


def _mission_events(db) -> list:
    out = []
    for wall, kind, cid, stage, payload in db.execute(
        "SELECT wall_time, kind, carrier, stage, payload FROM events ORDER BY seq"
    ):
        event = _EVENT_FROM_ROW.get(kind, lambda *a: None)(cid, stage, json.loads(payload), wall)
        if event is not None:
            out.append(event)
    return out


def _point(value) -> tuple[float, float]:
    return (float(value[0]), float(value[1]))


def _counts(p: dict) -> tuple[int, ...] | None:
    """An observation's or account's region counts (the coverage reward); None in a row without
    them (the penalty reward, and every row written before they existed)."""
    counts = p.get("counts")
    return None if counts is None else tuple(int(c) for c in counts)


def _operator_fields(e: ev.Decided) -> dict:
    """A decision's operator-mode keys (docs/fleet.md, "The operator console"): written only when
    the mission runs with an operator, so a mission without one writes the rows it always did."""
    if not e.hold:
        return {}
    return {"hold": e.hold, "forced": list(e.forced), "vetoed": list(e.vetoed), "gain": e.gain,
            "recommended": None if e.recommended is None else list(e.recommended)}


def _decided(cid, stage, p, at) -> ev.Decided:
    recommended = p.get("recommended")
    return ev.Decided(stage, tuple(p["deploy"]), p["planning_ms"], at, tuple(p.get("passengers", ())),
                      None if recommended is None else tuple(recommended), tuple(p.get("forced", ())),
                      tuple(p.get("vetoed", ())), p.get("hold", ""), p.get("gain"))


def _hello(cid, stage, p, at):
    if "fingerprint" not in p:
        return None  # written by an older version: pid and host only
    return ev.Hello(cid, p.get("pid"), p.get("host"), p.get("passengers_left", 0), p.get("next_stage", stage or 0),
                    p["fingerprint"], at, p.get("revision", 1))


#: How each kind of ``events`` row becomes a mission event: (carrier, stage, payload, wall_time).
_EVENT_FROM_ROW = {
    "open": lambda cid, stage, p, at: ev.Opened(at),
    "hello": _hello,
    "alive": lambda cid, stage, p, at: ev.LivelinessChanged(cid, True, at),
    "dead": lambda cid, stage, p, at: ev.LivelinessChanged(cid, False, at),
    "observation": lambda cid, stage, p, at: ev.Observation(
        cid, stage, p.get("t", 0.0), p["x"], _point(p["position"]), p.get("passengers_left", 0),
        tuple(_point(q) for q in p.get("trail", ())), at, _counts(p)),
    "decision": _decided,
    "operator": lambda cid, stage, p, at: ev.OperatorAction(stage, p["action"], cid, p.get("operator", ""), at),
    "published": lambda cid, stage, p, at: ev.Published(stage, at),
    "confirm": lambda cid, stage, p, at: ev.Confirmed(
        cid, stage, p["deployed"], p["status"], _point(p["position"]), p.get("passengers_left", 0), at,
        p.get("passenger")),
    "own": lambda cid, stage, p, at: ev.Accounted(
        cid, stage, p["t"], p["x"], p["deployed"], _point(p["position"]), p["passengers_left"], at, _counts(p)),
    "bye": lambda cid, stage, p, at: ev.Bye(
        cid, tuple(p.get("deployments", ())), tuple(sorted(p.get("rejected", {}).items())), p["reason"], at),
    "end": lambda cid, stage, p, at: ev.Ended(p["reason"], at),
}
