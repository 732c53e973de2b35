"""A fault schedule flown on the one-host fleet's real processes (``run_fleet.py S --schedule
F.json``; docs/fleet.md, "Fault schedules on real processes").

Each fault strikes at its **mission point**: once mission.db holds ``decided`` stages' Decisions
(the number the simulated mission had decided when it struck; :mod:`mission.simulate.schedule`)
and, before the first Decision (``decided`` 0), an accepted Hello of each carrier in ``joined``
(those that had joined then), or once the mission is past ``decided`` — never at a wall time. A clock jump of a carrier the simulated
mission had not started yet (not in ``started``) is in force before any carrier starts: that
carrier's clock is ahead from its start, as the simulated one's was. A fault lasts ``until -
at`` seconds (the simulated mission's seconds, on the wall clock: what a timeout of the fleet
measures too), or, for a pause, ``size``:

==================== ==========================================================================
kind                 on the real processes
==================== ==========================================================================
crash                the carrier's process SIGKILLed; a new one started when the fault ends
coordinator-crash    the coordinator SIGKILLed; a new one on the same results directory then
takeover             the coordinator SIGKILLed for good; the standby (started with the fleet) decides
pause                the coordinator SIGSTOPped for ``size`` s (past Zenoh's lease: the standby takes
                     over), then SIGCONT (it is deposed)
standby-crash        the coordinator SIGKILLed; the standby (started with the fleet on a results
                     directory of its own, ``<out>/standby``) takes over and is SIGKILLed ``size`` s
                     later; at the fault's end the primary starts again on its own, staler directory
                     (it opens the standby's epoch again: the ballots' case, docs/fleet.md)
freeze               the carrier's process SIGSTOPped, SIGCONT when the fault ends
slow                 the carrier's process slowed: SIGSTOPped :data:`SLOW_STOP_S` of every
                     :data:`SLOW_PERIOD_S` (it still sends Progress, only slower)
router-lost          the fleet's router SIGSTOPped (every session's lease expires, as when it is out of
                     reach), SIGCONT when the fault ends
loss                 every process's receive filter drops each message with probability ``size``
                     (:mod:`wire.fault_windows`, a Generator of each receiver's from the root seed)
partition            the carrier's messages dropped by every receiver, and everything it receives
                     (its liveliness token stays: a real cut's vanishes a lease later)
clock-jump           the carrier's clock (what its lifecycle and waits read) moved ``size`` s
                     forward, for good (:func:`wire.fault_windows.fault_clock`)
==================== ==========================================================================

Other kinds are refused before anything starts (:data:`FLOWN`). What each struck, at which
point and when, goes to ``<out>/faults.json``.
"""
from __future__ import annotations

import json
import os
import signal
import threading
import time

#: The kinds a real fleet flies, and what it does to which process.
FLOWN = ("crash", "coordinator-crash", "takeover", "pause", "freeze", "slow", "router-lost", "loss", "partition",
         "standby-crash", "clock-jump")
#: Kinds that need a standby coordinator started with the fleet.
STANDBY = ("takeover", "pause", "standby-crash")
#: Kinds whose standby has a results directory (a disk) of its own: :data:`STANDBY_OUT` under --out.
OWN_DISK, STANDBY_OUT = ("standby-crash",), "standby"
#: How often the mission's progress is read (s): a mission on the sim clock decides a stage in
#: milliseconds, and a fault must strike at its point, not a few stages later.
POLL_S = 0.005
#: A slow carrier: stopped this long of every period (s); it runs the rest, sending Progress.
SLOW_STOP_S, SLOW_PERIOD_S = 0.8, 1.0


def unflown(faults) -> list[str]:
    """The kinds of ``faults`` a real fleet does not fly, in order, once each."""
    return list(dict.fromkeys(f.kind for f in faults if f.kind not in FLOWN))


def decided_anywhere(out) -> int:
    """Stages decided on the mission's records under ``out`` (the primary's, and a standby's on
    its own disk): the most either holds; -1 while neither exists."""
    dbs = [db for db in (out / "mission.db", out / STANDBY_OUT / "mission.db") if db.exists()]
    return max((decided(db) for db in dbs), default=-1)


def joined_anywhere(out) -> frozenset:
    """The carriers whose Hello the mission's records (the primary's, a standby's) accepted."""
    dbs = [db for db in (out / "mission.db", out / STANDBY_OUT / "mission.db") if db.exists()]
    query = "SELECT DISTINCT carrier FROM events WHERE kind='hello' AND json_extract(payload, '$.compatible')"
    return frozenset(c for db in dbs for (c,) in _rows(db, query))


def decided(db_path) -> int:
    """Stages decided on the mission's record (0 while it does not exist yet)."""
    rows = _rows(db_path, "SELECT COUNT(*) FROM decisions")
    return int(rows[0][0]) if rows else 0


def _rows(db_path, query: str) -> list:
    """The rows ``query`` gives on the mission's record (none while it does not exist yet)."""
    from storage.sqlite import open_read_only

    if not db_path.exists():
        return []
    try:
        db = open_read_only(db_path, timeout=1.0)
        try:
            return db.execute(query).fetchall()
        finally:
            db.close()
    except Exception:  # noqa: BLE001 - the schema is not written yet
        return []


class Injector:
    """Strikes each fault of the schedule at its mission point and ends it (a thread of the
    supervisor). ``fleet``: the supervisor's :class:`launcher.supervisor.Fleet` (its processes
    are replaced here as they are restarted); ``restart``: kind -> a callable starting the
    process again."""

    def __init__(self, fleet, faults, points, restart: dict, stop: threading.Event):
        self.fleet, self.restart, self.stop = fleet, restart, stop
        # (fault index, fault, decided, joined): who had joined tells apart only the moments
        # before the first Decision; later, reading it would slow the polls a fast mission outruns
        self.pending = [(k, f, (p.get("decided") or 0), frozenset((p.get("joined") or ()) if not p.get("decided") else ()))
                        for k, (f, p) in enumerate(zip(faults, points))]
        self.ends: list = []                      # (wall time, fault index, action, a resume)
        self.log: list = []
        self.loss: list = []                      # the loss windows in force (their sizes)
        self.cut: list = []                       # the carriers cut off
        self.jumps: dict = {}                     # host -> its clock's jumps so far (s)
        self.joined: frozenset = frozenset()      # the carriers seen accepted so far
        for item in list(self.pending):  # in force before the carriers start (they start after this)
            k, f = item[:2]
            started = points[k].get("started")
            if f.kind == "clock-jump" and item[2] == 0 and started is not None and f.who not in started:
                self.pending.remove(item)
                self.jumps[f.who] = self.jumps.get(f.who, 0.0) + f.size
                self._note(k, "struck", 0)
        self.slowed: dict = {}                    # carrier -> the wall time its slowness ends
        self.write_windows()
        self.thread = threading.Thread(target=self._run, name="faults", daemon=True)

    def start(self) -> None:
        self.thread.start()

    def _run(self) -> None:
        out = self.fleet.out
        while not self.stop.is_set() and (self.pending or self.ends):
            reached = decided_anywhere(out)
            if any(not p[3] <= self.joined for p in self.pending):  # read ahead of the point: it may pass fast
                self.joined |= joined_anywhere(out)
            for item in [p for p in self.pending if reached > p[2] or (reached == p[2] and p[3] <= self.joined)]:
                self.pending.remove(item)
                self._strike(item[0], item[1], reached)
            now = time.monotonic()
            for end in sorted((e for e in self.ends if e[0] <= now), key=lambda e: e[:2]):
                self.ends.remove(end)
                end[2]()
                self._note(end[1], "ended", decided_anywhere(out))
            self._slow(now)
            self.stop.wait(POLL_S)
        self.write()

    def _slow(self, now: float) -> None:
        """Each slow carrier stopped for the first :data:`SLOW_STOP_S` of every period."""
        for cid, until in list(self.slowed.items()):
            proc = self.fleet.carriers.get(cid)
            if now >= until:
                del self.slowed[cid]
                _signal(proc, signal.SIGCONT)
                continue
            _signal(proc, signal.SIGSTOP if now % SLOW_PERIOD_S < SLOW_STOP_S else signal.SIGCONT)

    def write_windows(self) -> None:
        """The message faults in force, for every process's receive filter (replaced atomically)."""
        path = self.fleet.windows
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps({"loss": self.loss, "cut": self.cut, "jumps": self.jumps}))
        os.replace(tmp, path)

    def _window(self, kind: str, value, on: bool) -> None:
        held = self.loss if kind == "loss" else self.cut
        if on:
            held.append(value)
        else:
            held.remove(value)
        self.write_windows()

    def _note(self, k: int, what: str, reached: int) -> None:
        self.log.append({"fault": k, "what": what, "decided": reached, "wall": round(time.time(), 3)})

    def _strike(self, k: int, f, reached: int) -> None:
        fleet, length = self.fleet, max(0.0, f.until - f.at)
        end, resume = None, False
        if f.kind in ("crash", "freeze"):
            proc = fleet.carriers.get(f.who)
            if f.kind == "crash":
                _signal(proc, signal.SIGKILL)
                end = lambda: self.restart["carrier"](f.who)  # noqa: E731
            else:
                _signal(proc, signal.SIGSTOP)
                end, resume = (lambda: _signal(proc, signal.SIGCONT)), True
        elif f.kind in ("coordinator-crash", "takeover"):
            _signal(fleet.coordinator, signal.SIGKILL)
            if f.kind == "takeover":
                fleet.coordinator, fleet.standby = fleet.standby, None  # the standby decides from now on
            else:
                end = self.restart["coordinator"]
        elif f.kind == "standby-crash":
            _signal(fleet.coordinator, signal.SIGKILL)
            standby = fleet.coordinator = fleet.standby  # it takes over on its own disk
            fleet.standby = None
            self.ends.append((time.monotonic() + min(f.size, length), k, lambda: _signal(standby, signal.SIGKILL),
                              False))
            end = self.restart["coordinator"]  # the primary, on its own staler disk
        elif f.kind == "pause":
            paused, length = fleet.coordinator, f.size
            _signal(paused, signal.SIGSTOP)
            fleet.coordinator, fleet.standby = fleet.standby, paused  # the standby takes over; this one is deposed
            end, resume = (lambda: _signal(paused, signal.SIGCONT)), True
        elif f.kind == "router-lost":
            router = fleet.routers[0]
            _signal(router, signal.SIGSTOP)
            end, resume = (lambda: _signal(router, signal.SIGCONT)), True
        elif f.kind in ("loss", "partition"):
            value = f.size if f.kind == "loss" else f.who
            self._window(f.kind, value, True)
            end = lambda: self._window(f.kind, value, False)  # noqa: E731
        elif f.kind == "slow":
            self.slowed[f.who] = max(self.slowed.get(f.who, 0.0), time.monotonic() + length)
        elif f.kind == "clock-jump":  # instantaneous and for good, as the simulator's
            self.jumps[f.who] = self.jumps.get(f.who, 0.0) + f.size
            self.write_windows()
        self._note(k, "struck", reached)
        if end is not None:
            self.ends.append((time.monotonic() + length, k, end, resume))

    def finish(self) -> None:
        """The mission is over: a process still stopped continues (so that it can be stopped;
        nothing is restarted), and the record is written."""
        self.stop.set()
        self.thread.join(timeout=5.0)
        for _, k, end, resume in self.ends:
            if resume:
                end()
        self.ends.clear()
        for cid in self.slowed:
            _signal(self.fleet.carriers.get(cid), signal.SIGCONT)
        self.slowed.clear()
        self.write()

    def write(self) -> None:
        (self.fleet.out / "faults.json").write_text(json.dumps(self.log, indent=1) + "\n")


def _signal(proc, sig) -> None:
    """``sig`` to ``proc`` if it runs; a killed one is waited for (reaped: then it is not
    running, and a restart at the fault's end, however soon, starts a new one)."""
    if proc is not None and proc.poll() is None:
        try:
            proc.send_signal(sig)
        except ProcessLookupError:
            return
        if sig == signal.SIGKILL:
            try:
                proc.wait(timeout=10.0)
            except Exception:  # noqa: BLE001 - a process that does not die is the kernel's to end
                pass
