"""PURE: a mission's results from whatever logs exist (``run_fleet.py --role report``).

The coordinator's events (mission.db, when there is one) and the carriers' own stage logs
(storage/carrierlog.py, one per carrier) are merged with the fold the live coordinator uses
(:func:`mission.state.step`), so the merged :class:`~mission.state.MissionState` is the one a
coordinator would have reached had it received every carrier's account itself:

1. fold mission.db's events (none when it is absent);
2. per carrier log (scenario order): a Hello for a carrier without an accepted one (from the
   log's meta; it flew, so its world is the mission's: the caller checked the fingerprint);
3. per log entry with an outcome, in stage order:

   * the coordinator decided the stage (on record) and the carrier answered it (a Confirm status
     in its log): a :class:`~mission.events.Confirmed` event — absorbed when mission.db holds
     that Confirm already, on record when the coordinator never received it;
   * otherwise a :class:`~mission.events.Accounted` event: the carrier's account is the truth (a
     stage it decided itself, status ``own``, or a stage decided by a coordinator whose
     mission.db is not here). Its observation comes in through the account's ``x``.

   A log entry the fold rejects (it contradicts mission.db: the first record stands) or that
   would release more passengers than the carrier carries is not counted; it is listed as a
   :class:`Conflict`. Entries without an outcome (the carrier sensed, nobody decided) change
   nothing in the state; the merged log still shows them.

No passenger is counted twice: the state keeps at most one record per (carrier, stage), a
Confirm and an account of the same stage must agree (else the second is a conflict), and a
carrier's counted deployments never exceed its passengers.

Log entries are ``storage.carrierlog.LogEntry`` values (or anything with their fields: ``stage``,
``t``, ``x``, ``observed``, ``position``, ``status``, ``deployed``, ``passengers_left``); this
module reads no file.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from functools import cached_property

from . import events as ev
from .state import MissionSpec, MissionState, Reject, fold, step

#: The log status of a stage a carrier decided itself (storage/carrierlog.py).
OWN = "own"
#: Who decided a stage, as the merged log and summary.json say it.
BY_COORDINATOR, BY_CARRIER = "coordinator", "carrier"


@dataclass(frozen=True)
class CarrierRecord:
    """One carrier's durable log, as read.

    Attributes:
        carrier: its id (checked against the log's meta by the reader).
        source: the file as the outputs name it, e.g. ``carriers/a.db``.
        meta: the log's identity (mission, carrier, scenario, fingerprint, seed, ...).
        entries: its stages, in stage order.
    """

    carrier: str
    source: str
    meta: dict = field(default_factory=dict)
    entries: tuple = ()


@dataclass(frozen=True)
class Conflict:
    """A log entry that is not counted, and why (one line)."""

    carrier: str
    stage: int
    source: str
    reason: str
    detail: str

    def line(self) -> str:
        return f"{self.source}: stage {self.stage}: {self.detail} ({self.reason}); not counted"


@dataclass(frozen=True)
class Merged:
    """The merge's result.

    Attributes:
        state: the merged mission state (the input of ``mission.summary.summary``).
        base: the state of mission.db's events alone.
        logs: the carrier logs merged, by carrier id.
        db_source: how the outputs name the coordinator's log (``mission.db``), None if absent.
        added: (carrier, stage) records the logs added to mission.db's (Confirms and accounts).
        by_coordinator: accounts of stages a coordinator decided (a Confirm status in the log, no
            decision on record: its mission.db is not here).
        conflicts: entries not counted.
    """

    state: MissionState
    base: MissionState
    logs: dict
    db_source: str | None
    added: frozenset
    by_coordinator: frozenset
    conflicts: tuple

    @property
    def adds_nothing(self) -> bool:
        """The logs hold nothing mission.db does not (every entry absorbed, no Hello added)."""
        return not self.added and self.state.accepted == self.base.accepted

    def decided_by(self, cid: str, j: int) -> str | None:
        """Who decided carrier ``cid``'s stage j: the carrier (its own account), the operator (a
        deployment forced at the console), a coordinator, or nobody on record (None)."""
        if (cid, j) in self.state.accounts and (cid, j) not in self.by_coordinator:
            return BY_CARRIER
        d = self.state.decisions.get(j)
        if d is not None and cid in d.forced:
            return "operator"  # forced at the operator's console
        if d is not None or (cid, j) in self.by_coordinator:
            return BY_COORDINATOR
        return None

    @cached_property
    def _by_stage(self) -> dict:
        return {cid: {e.stage: e for e in rec.entries} for cid, rec in self.logs.items()}

    @cached_property
    def counted(self):
        """bool ``[R, N]``: the deployments counted (``MissionState.confirmed_deployments``)."""
        return self.state.confirmed_deployments()

    def entry(self, cid: str, j: int):
        """Carrier ``cid``'s log entry of stage j, or None."""
        return self._by_stage.get(cid, {}).get(j)

    def sources(self, cid: str, j: int) -> list[str]:
        """The files holding a record of carrier ``cid`` at stage j."""
        out = []
        st = self.base
        if self.db_source is not None and (
                (cid, j) in st.reported or (cid, j) in st.confirms or (cid, j) in st.accounts
                or (cid, j) in st.missing or (j in st.decisions and cid in st.decisions[j].deploy)):
            out.append(self.db_source)
        if self.entry(cid, j) is not None:
            out.append(self.logs[cid].source)
        return out

    def counted_from(self, cid: str, j: int) -> str | None:
        """The file whose record of carrier ``cid``'s deployment at stage j counts."""
        if not self.counted[self.state.spec.index(cid), j]:
            return None
        if (cid, j) not in self.added and self.db_source is not None:
            return self.db_source
        return self.logs[cid].source

    def trails(self) -> dict:
        """carrier -> the points it drove through: the coordinator's trail (its Observations'),
        else the positions in its log, in stage order."""
        out = {}
        for cid in self.state.spec.carriers:
            pts = tuple(self.state.trails.get(cid, ()))
            if not pts and cid in self.logs:
                pts = tuple(tuple(e.position) for e in self.logs[cid].entries if e.position is not None)
            if pts:
                out[cid] = pts
        return out

    def rows(self) -> list[dict]:
        """The merged mission log: one row per stage per carrier (stage order, then scenario
        order) where anything is known: scheduled there, or on record in any file.

        Row fields: ``stage``, ``t`` (s), ``carrier``, ``x`` (features, None = ∅), ``deployed``
        (counted), ``decision`` (the coordinator's decision for this carrier; None: no decision of
        the stage on record), ``status`` (the carrier's answer: a Confirm status, ``own``, or
        None), ``decided_by`` (``coordinator``, ``carrier`` or None), ``sources`` (files with a
        record), and ``conflict`` (why a log entry was not counted) when there is one.
        """
        st, spec = self.state, self.state.spec
        counted = self.counted
        conflicts = {(c.carrier, c.stage): c for c in self.conflicts}
        out = []
        for j in range(spec.n_stages):
            for r, cid in enumerate(spec.carriers):
                sources = self.sources(cid, j)
                if not spec.valid[r][j] and not sources:
                    continue
                entry = self.entry(cid, j)
                x = st.observation(r, j)
                if math.isnan(x) and entry is not None and entry.observed and entry.x is not None and spec.valid[r][j]:
                    x = float(entry.x)  # sensed, never decided: shown, not counted
                # The status of the record that counts; the log's own only when nothing is on record.
                if (cid, j) in st.accounts:
                    status = entry.status if (cid, j) in self.by_coordinator else OWN
                elif (cid, j) in st.confirms:
                    status = st.confirms[(cid, j)].status
                else:
                    status = None if entry is None else entry.status
                row = {"stage": j, "t": spec.stage_times[j], "carrier": cid,
                       "x": None if math.isnan(x) else x, "deployed": bool(counted[r, j]),
                       "decision": (cid in st.decisions[j].deploy) if j in st.decisions else None,
                       "status": status, "decided_by": self.decided_by(cid, j), "sources": sources}
                if (cid, j) in conflicts:
                    row["conflict"] = conflicts[(cid, j)].line()
                out.append(row)
        return out


def merge(spec: MissionSpec, events=(), logs=(), db_source: str | None = "mission.db") -> Merged:
    """Merge mission.db's ``events`` (``storage.missiondb.load_events``; empty when there is no
    mission.db, then pass ``db_source=None``) with the carriers' ``logs``
    (:class:`CarrierRecord`, any order) into one mission state (module docstring).

    The caller has checked that every input belongs to this mission (``spec.fingerprint``)."""
    base = fold(spec, events)
    # The report is no coordinator session: publication times are the coordinator's clock, so a
    # Confirm that only a carrier's log holds gets no round-trip latency (as after ``Opened``).
    state = dataclasses.replace(base, published_at={})
    logs = sorted(logs, key=lambda rec: spec.index(rec.carrier))
    added, by_coordinator, conflicts = set(), set(), []
    counted = state.confirmed_deployments()  # kept up to date cell by cell: O(1) per entry
    for record in logs:
        cid, r = record.carrier, spec.index(record.carrier)
        if cid not in state.accepted:
            meta = record.meta
            state, _ = step(state, ev.Hello(cid, meta.get("pid"), meta.get("host"), spec.passengers[r], 0,
                                            spec.fingerprint))
        for entry in record.entries:
            if entry.status is None:
                continue  # sensed, never resolved: no event (shown in the merged log)
            j = entry.stage

            def conflict(reason, detail):
                conflicts.append(Conflict(cid, j, record.source, reason, detail))

            if entry.position is None:
                conflict("incomplete", "outcome without a position")
                continue
            if (entry.deployed and not (0 <= j < spec.n_stages and counted[r, j])
                    and counted[r].sum() >= spec.passengers[r]):
                conflict("passengers", f"carrier {cid} would release more than its {spec.passengers[r]} "
                                       f"passenger(s)")
                continue
            position = (float(entry.position[0]), float(entry.position[1]))
            left = int(entry.passengers_left) if entry.passengers_left is not None else 0
            coordinator_decided = entry.status != OWN
            if coordinator_decided and j in state.decisions:
                event = ev.Confirmed(cid, j, bool(entry.deployed), entry.status, position, left)
            else:
                event = ev.Accounted(cid, j, float(entry.t), entry.x if entry.observed else None,
                                     bool(entry.deployed), position, left)
            before = state
            state, effects = step(state, event)
            for effect in effects:
                if isinstance(effect, Reject):
                    conflict(effect.reason, effect.detail)
            if state is not before:
                added.add((cid, j))
                record_now = state.accounts.get((cid, j)) or state.confirms.get((cid, j))
                counted[r, j] = record_now is not None and record_now.deployed
                if coordinator_decided and isinstance(event, ev.Accounted):
                    by_coordinator.add((cid, j))
    return Merged(state=state, base=base, logs={rec.carrier: rec for rec in logs},
                  db_source=db_source if events else None, added=frozenset(added),
                  by_coordinator=frozenset(by_coordinator), conflicts=tuple(conflicts))


def annotate(summary: dict, merged: Merged) -> dict:
    """summary.json (``mission.summary.summary`` of ``merged.state``) with where each
    deployment came from: ``by`` (who decided it) and ``source`` (the file whose record counts)
    per deployment, ``log`` (its log file or None) per carrier. Returns a new dict."""
    out = dict(summary)
    carriers = []
    for c in summary["carriers"]:
        c = dict(c, log=merged.logs[c["id"]].source if c["id"] in merged.logs else None)
        c["deployments"] = [dict(d, by=merged.decided_by(c["id"], d["stage"]),
                                 source=merged.counted_from(c["id"], d["stage"])) for d in c["deployments"]]
        carriers.append(c)
    out["carriers"] = carriers
    return out
