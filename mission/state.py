"""The coordinator's mission state machine: ``step(state, event) -> (state, effects)``.

Like etcd-raft's ``Step``, :func:`step` takes one event (mission.events) and returns the new
state and the effects the process must carry out, in order: :class:`Record` (persist the event
in mission.db) always comes before :class:`Publish` or :class:`Refuse`, so what is published
was stored first. Rejections are effects too (:class:`Reject`, with the reason codes of
docs/protocol.md). The function does no I/O and reads no clock; a restarted coordinator folds
the stored events through it (:func:`fold`) and reaches the state the live process had.

Mission rules applied here (docs/protocol.md, "Stage handshake" and "Rejections"):

* a Hello is **required**: Observations and Confirms of a carrier without an accepted Hello are
  rejected (``no-hello``, or ``world-mismatch`` when its Hello was refused);
* every Hello is answered: accepted (:class:`Accept`), or refused (:class:`Refuse`: another
  fingerprint, an unknown carrier, a ``next_stage`` past the mission); a refusal never undoes
  an accepted Hello of the same carrier; a Bye needs an accepted Hello too;
* an Observation counts only for the stage being collected (``next_stage``): earlier ones are
  ``stale-stage``, later ones ``future-stage`` (rejected, never held), repeats ``duplicate``;
  an identical repeat is absorbed, also once its stage is decided; its ``t`` must be the stage
  time within :data:`T_TOLERANCE_S`;
* a Confirm of a stage not decided yet is ``stale-stage``; a repeat with the same outcome (or
  ``already``) is absorbed, a contradicting repeat is ``duplicate`` (the first one stands);
* an Own message (a carrier's account of a stage it decided without the coordinator) is the
  truth about what that carrier did there, whichever stage the coordinator is at; a carrier
  that has passed a stage (its account, or its Hello says it goes on from a later one) is
  neither waited for nor planned at that stage. What the planner takes as deployed is, per
  carrier and stage: its account, else its Confirm, else the decision (:meth:`deployed`).

The state is immutable by convention: :func:`step` never changes the state it is given (it
builds new dicts for the fields it changes), so two states can be compared with ``==``. The
maps keyed by (carrier, stage) that grow with every Observation and Confirm are
:class:`PairMap` objects, whose :meth:`PairMap.set` copies one stage's entries, not the whole map.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np

from . import events as ev
from . import operator_rules
from .evolve import evolve
from .timeouts import T_TOLERANCE_S


#: Confirm statuses that count for the decision round-trip latency.
LATENCY_STATUSES = ("deployed", "idle")


# --------------------------------------------------------------------------- the mission's constants

@dataclass(frozen=True)
class MissionSpec:
    """What every process knows before the mission starts (from the scenario).

    Attributes:
        carriers: carrier ids, in scenario order (index r).
        valid: ``[R][N]`` bools, carrier r scheduled at stage j.
        passengers: ``[R]`` passengers each carrier starts with.
        stage_times: ``[N]`` t_j, seconds.
        fingerprint: the scenario fingerprint (docs/protocol.md, "Fingerprint").
        min_revision: the lowest protocol revision a carrier may speak to fly this mission (a
            coverage mission needs region counts: wire.messages.COUNTS_REVISION); 1 otherwise.
        point_regions: under the coverage reward, ``[R][N]`` how many regions each point's disc
            covers (the length of its Observation's ``counts``); None under the penalty reward.
    """

    carriers: tuple[str, ...]
    valid: tuple[tuple[bool, ...], ...]
    passengers: tuple[int, ...]
    stage_times: tuple[float, ...]
    fingerprint: str
    min_revision: int = 1
    point_regions: tuple[tuple[int, ...], ...] | None = None
    _index: dict = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        object.__setattr__(self, "_index", {cid: r for r, cid in enumerate(self.carriers)})

    @classmethod
    def build(cls, carriers, valid, passengers, stage_times, fingerprint: str, min_revision: int = 1,
              point_regions=None) -> "MissionSpec":
        regions = None if point_regions is None else tuple(tuple(int(k) for k in row) for row in point_regions)
        return cls(tuple(carriers), tuple(tuple(bool(v) for v in row) for row in np.asarray(valid)),
                   tuple(int(p) for p in passengers), tuple(float(t) for t in stage_times), str(fingerprint),
                   int(min_revision), regions)

    @property
    def n_stages(self) -> int:
        return len(self.stage_times)

    def index(self, cid: str) -> int:
        """Carrier ``cid``'s index r (ValueError for an id not in the scenario)."""
        try:
            return self._index[cid]
        except KeyError:
            raise ValueError(f"{cid!r} is not a carrier of the scenario") from None

    def has(self, cid: str) -> bool:
        return cid in self._index

    def scheduled(self, cid: str, j: int) -> bool:
        return self.valid[self.index(cid)][j]


#: The first protocol revision whose carriers send Progress (docs/protocol.md, [P-10.4]).
PROGRESS_REVISION = 3


# --------------------------------------------------------------------------- records in the state

@dataclass(frozen=True)
class CarrierInfo:
    """An accepted Hello: process id, host, where the carrier said it goes on from, and the
    protocol revision it announced (docs/protocol.md, "Revisions")."""

    pid: int
    host: str
    next_stage: int
    revision: int = 1


@dataclass(frozen=True)
class DecisionRecord:
    deploy: tuple[str, ...]
    planning_ms: float
    passengers: tuple[int, ...] = ()  # parallel to deploy (sorted ids); empty: none named
    recommended: tuple[str, ...] | None = None  # operator mode: the planner's recommendation (sorted)
    forced: tuple[str, ...] = ()
    vetoed: tuple[str, ...] = ()
    hold: str = ""
    gain: float | None = None


@dataclass(frozen=True)
class ConfirmRecord:
    deployed: bool
    status: str
    position: tuple[float, float]
    passengers_left: int
    latency_ms: float | None
    passenger: int | None = None  # the passenger released, as the carrier said (None: not said)


@dataclass(frozen=True)
class AccountRecord:
    """A carrier's account of a stage it decided itself (:class:`mission.events.Accounted`)."""

    x: int | None
    deployed: bool
    position: tuple[float, float]
    passengers_left: int


_NOTHING: Mapping = MappingProxyType({})


class PairMap(Mapping):
    """An immutable map keyed by (carrier, stage), kept per stage: :meth:`set` returns a new map
    that shares every other stage's entries with this one, so adding an entry costs O(R + N),
    not O(R·N). :func:`step` makes a new state per event; copying the whole maps per
    Observation and Confirm would be O(R·N) each, O(R²·N²) a mission. A plain :class:`~collections.abc.Mapping`
    otherwise (``==`` with a dict compares the entries); entries iterate stage by stage."""

    __slots__ = ("_stages", "_len")

    def __init__(self, items=()):
        stages: dict = {}
        for (cid, j), value in (items.items() if isinstance(items, Mapping) else items):
            stages.setdefault(j, {})[cid] = value
        self._stages = stages
        self._len = sum(len(bucket) for bucket in stages.values())

    def __getitem__(self, key):
        cid, j = key
        bucket = self._stages.get(j)
        if bucket is None or cid not in bucket:
            raise KeyError(key)
        return bucket[cid]

    def __contains__(self, key) -> bool:
        try:
            cid, j = key
        except (TypeError, ValueError):
            return False
        bucket = self._stages.get(j)
        return bucket is not None and cid in bucket

    def __iter__(self):
        for j, bucket in self._stages.items():
            for cid in bucket:
                yield (cid, j)

    def __len__(self) -> int:
        return self._len

    def __repr__(self) -> str:
        return f"PairMap({dict(self.items())!r})"

    def at(self, j: int) -> Mapping:
        """Stage ``j``'s entries, carrier -> value (read only)."""
        return self._stages.get(j, _NOTHING)

    def set(self, key, value) -> "PairMap":
        """A new map with ``key`` -> ``value``."""
        cid, j = key
        bucket = dict(self._stages.get(j, ()))
        grown = cid not in bucket
        bucket[cid] = value
        new = PairMap.__new__(PairMap)
        new._stages = {**self._stages, j: bucket}
        new._len = self._len + grown
        return new


@dataclass(frozen=True)
class MissionState:
    """Everything the coordinator knows about a mission. Built by :func:`initial` and
    :func:`step` only.

    Attributes:
        spec: the mission's constants.
        opens: how many times a coordinator opened this mission (> 1: resumed).
        accepted: carrier -> :class:`CarrierInfo` of its accepted Hello (latest).
        refused: carrier -> the fingerprint of its refused Hello (carriers never accepted).
        live: carriers whose liveliness token this coordinator process sees.
        reported: (carrier, stage) -> x (None = ∅) of the accepted Observations.
        counts: (carrier, stage) -> the region counts of the accepted Observations and accounts
            that carry them (the coverage reward; mission/coverage.py reads them).
        missing: (carrier, stage) pairs scheduled but without an Observation when decided.
        positions: (carrier, stage) -> (x, y) m, from the Observations.
        trails: carrier -> the points it drove through, from its Observations.
        decisions: stage -> :class:`DecisionRecord`.
        next_stage: first undecided stage (stages are decided in order).
        published_at: stage -> when its decision was published in this process (s, epoch).
        confirms: (carrier, stage) -> :class:`ConfirmRecord` (the first one).
        accounts: (carrier, stage) -> :class:`AccountRecord` of the stages carriers decided
            themselves.
        byes: carriers that said Bye since their last accepted Hello.
        carrier_rejected: carrier -> its rejection counts, from its last Bye.
        bye_deployments: carrier -> the stages its last Bye lists as deployed.
        ended, end_reason: End was published (``complete`` or ``stopped``).
        operator_actions: stage -> the operator's accepted actions there, in order
            (:mod:`mission.operator_rules`).
    """

    spec: MissionSpec
    opens: int = 0
    accepted: dict = field(default_factory=dict)
    refused: dict = field(default_factory=dict)
    live: frozenset = frozenset()
    reported: PairMap = field(default_factory=PairMap)
    missing: frozenset = frozenset()
    positions: PairMap = field(default_factory=PairMap)
    trails: dict = field(default_factory=dict)
    decisions: dict = field(default_factory=dict)
    next_stage: int = 0
    published_at: dict = field(default_factory=dict)
    confirms: PairMap = field(default_factory=PairMap)
    accounts: dict = field(default_factory=dict)
    byes: frozenset = frozenset()
    carrier_rejected: dict = field(default_factory=dict)
    bye_deployments: dict = field(default_factory=dict)
    ended: bool = False
    end_reason: str | None = None
    counts: PairMap = field(default_factory=PairMap)
    operator_actions: dict = field(default_factory=dict)
    # Who is still waited for, remembered (the fields are never changed in place, so the same
    # objects give the same answer): :class:`_Expected` is handed from a state to the states made
    # from it (``dataclasses.replace`` passes it on); ``_waited`` is this state's own.
    _expected: "_Expected" = field(default_factory=lambda: _Expected(), compare=False, repr=False)
    _waited: dict = field(default_factory=dict, init=False, compare=False, repr=False)

    # ------------------------------------------------------------------ the stage clock's predicates
    @property
    def resumed(self) -> bool:
        return self.opens > 1

    def passed(self, cid: str, j: int) -> bool:
        """Carrier ``cid`` is past stage j without the coordinator: it decided j itself, or its
        latest Hello says it goes on from a later stage."""
        return _passed(self.accepted, self.accounts, cid, j)

    def behind(self, j: int) -> bool:
        """Every live carrier is past stage j (the coordinator catches up with them)."""
        return bool(self.live) and all(self.passed(cid, j) for cid in self.live)

    def expected(self, j: int) -> frozenset:
        """Carriers the coordinator waits for at stage j: live, Hello accepted, scheduled at j,
        not past it. Counted again (O(R)) only when what it reads is new: every Observation and
        Confirm makes a new state, but leaves these fields as they were (:class:`_Expected`)."""
        return self._expected.of(self, j)

    def waiting(self, j: int) -> frozenset:
        """Expected carriers whose Observation of j has not arrived."""
        return self.expected(j).difference(self.reported.at(j))

    def stage_complete(self, j: int) -> bool:
        return not self.waiting(j)

    def all_joined(self) -> bool:
        """Every carrier is live with an accepted Hello, or was refused (it will not fly)."""
        return all((cid in self.live and cid in self.accepted) or cid in self.refused
                   for cid in self.spec.carriers)

    def unconfirmed(self, j: int) -> frozenset:
        """Live carriers without a Confirm of stage j, but those whose accepted Hello named a
        later stage (one that joined after stage j has nothing of it to confirm)."""
        return frozenset(cid for cid in self.live.difference(self.confirms.at(j))
                         if (info := self.accepted.get(cid)) is None or info.next_stage <= j)

    def all_said_bye(self) -> bool:
        return self.live <= self.byes

    def bye_missing(self) -> bool:
        """Some carrier with an accepted Hello has not said Bye (live or not)."""
        return not set(self.accepted) <= self.byes

    def waited_for(self, j: int) -> tuple[frozenset, frozenset]:
        """Who the wait for stage j's Observations is still for, as (those that send Progress,
        those of a revision before it: :meth:`without_progress`): the input of
        :func:`mission.timers.stage_wait`. Remembered in this state: a wait asks after every
        inbox drain, and most drains apply no event (Progress, Poses)."""
        return self._remember(("stage", j), self.waiting)

    def confirms_awaited(self, j: int) -> tuple[frozenset, frozenset]:
        """:meth:`waited_for` of the wait for stage j's Confirms (:meth:`unconfirmed`)."""
        return self._remember(("confirm", j), self.unconfirmed)

    def _remember(self, key, who) -> tuple[frozenset, frozenset]:
        value = self._waited.get(key)
        if value is None:
            cids = who(key[1])
            mute = self.without_progress(cids)
            value = self._waited[key] = (frozenset(cids).difference(mute), mute)
        return value

    def without_progress(self, cids) -> frozenset:
        """Those of ``cids`` whose accepted Hello announced a revision before Progress
        (:data:`PROGRESS_REVISION`): they send none, so on the sim clock their silence says
        nothing and only the stage timeout ends a wait for them (docs/protocol.md, [P-10.4])."""
        return frozenset(cid for cid in cids
                         if (info := self.accepted.get(cid)) is not None and info.revision < PROGRESS_REVISION)

    def revision_of(self, cid: str, highest: int) -> int:
        """The protocol revision to speak to carrier ``cid``: the lower of ``highest`` (the
        coordinator's) and the one its accepted Hello announced (1 before any accepted Hello:
        docs/protocol.md, "Compatibility")."""
        info = self.accepted.get(cid)
        return min(highest, info.revision if info is not None else 1)

    def common_revision(self, highest: int) -> int:
        """The revision of what the coordinator broadcasts (Decisions): the lowest any carrier
        with an accepted Hello speaks, ``highest`` when none has one yet, so every carrier that
        hears it reads all of it."""
        return min([highest, *(info.revision for info in self.accepted.values())])

    # ------------------------------------------------------------------ the planner's inputs
    def observation(self, r: int, j: int) -> float:
        """x of carrier r at stage j (NaN = ∅: unscheduled, missing or not reported), from its
        Observation or else its account."""
        cid = self.spec.carriers[r]
        value = self.reported.get((cid, j))
        if value is None and (cid, j) in self.accounts:
            value = self.accounts[(cid, j)].x
        return float(value) if value is not None and self.spec.valid[r][j] else float("nan")

    def observations(self, upto: int | None = None) -> np.ndarray:
        """float ``[R, N]``: observations of stages ``< upto`` (all by default), NaN elsewhere."""
        n_r, n = len(self.spec.carriers), self.spec.n_stages
        upto = n if upto is None else upto
        x = np.full((n_r, n), np.nan)
        for r in range(n_r):
            for j in range(upto):
                x[r, j] = self.observation(r, j)
        return x

    def planning_observations(self, j: int) -> np.ndarray:
        """The planner's observations at stage j: those of stages ``<= j``, with the carriers past
        j (:meth:`passed`) as ∅ there (they decided it themselves, or never will see it)."""
        x = self.observations(upto=j + 1)
        for r, cid in enumerate(self.spec.carriers):
            if self.passed(cid, j):
                x[r, j] = np.nan
        return x

    def decided(self) -> np.ndarray:
        """bool ``[R, N]``: deployments decided."""
        out = np.zeros((len(self.spec.carriers), self.spec.n_stages), dtype=bool)
        for j, d in self.decisions.items():
            for cid in d.deploy:
                out[self.spec.index(cid), j] = True
        return out

    def deployed(self) -> np.ndarray:
        """bool ``[R, N]``: the planner's view of the past: per carrier and stage its account,
        else its Confirm, else the decision (a decision nobody answered is taken as done, within
        :meth:`_settle_guesses`)."""
        out = self.decided()
        reported = np.zeros_like(out)
        for (cid, j), c in self.confirms.items():
            out[self.spec.index(cid), j] = c.deployed
            reported[self.spec.index(cid), j] = True
        for (cid, j), a in self.accounts.items():
            out[self.spec.index(cid), j] = a.deployed
            reported[self.spec.index(cid), j] = True
        for r in np.flatnonzero((out & ~reported).any(axis=1)):
            self._settle_guesses(self.spec.carriers[r], out[r], reported[r])
        return out

    def _settle_guesses(self, cid: str, row: np.ndarray, reported: np.ndarray) -> None:
        """Carrier ``cid``'s unanswered decisions (``row`` True where ``reported`` is False),
        taken as done while it has a passenger left for them, the earliest first (a deployment
        it reported late, after the decision was planned, can leave it none: it refuses), and
        not after its Bye unless the Bye lists them (the carrier's own account of its
        deployments, [P-9.4]). In place."""
        guessed = np.flatnonzero(row & ~reported)
        if cid in self.byes:
            listed = self.bye_deployments.get(cid, ())
            row[[j for j in guessed if j not in listed]] = False
            guessed = np.flatnonzero(row & ~reported)
        room = max(0, self.spec.passengers[self.spec.index(cid)] - int((row & reported).sum()))
        row[guessed[room:]] = False

    def releases(self) -> np.ndarray:
        """int64 ``[R, N]``: the passenger index of each deployment :meth:`deployed` sees (its
        Confirm's ``passenger``, else the one its decision named; -1 where none or unknown, e.g.
        a stage the carrier decided itself): the planner's passenger types history."""
        deployed = self.deployed()
        out = np.full(deployed.shape, -1, dtype=np.int64)
        for j, d in self.decisions.items():
            for cid, i in zip(d.deploy, d.passengers):
                out[self.spec.index(cid), j] = i
        for (cid, j), c in self.confirms.items():
            if c.passenger is not None:
                out[self.spec.index(cid), j] = c.passenger
        for (cid, j) in self.accounts:
            out[self.spec.index(cid), j] = -1
        return np.where(deployed, out, -1)

    def deployments_of(self, cid: str) -> list[int]:
        """Stages of carrier ``cid``'s deployments as :meth:`deployed` sees them, O(N)."""
        row, reported = np.zeros(self.spec.n_stages, dtype=bool), np.zeros(self.spec.n_stages, dtype=bool)
        for j in range(self.spec.n_stages):
            record = self.accounts.get((cid, j)) or self.confirms.get((cid, j))
            reported[j] = record is not None
            row[j] = (record.deployed if record is not None
                      else j in self.decisions and cid in self.decisions[j].deploy)
        self._settle_guesses(cid, row, reported)
        return np.flatnonzero(row).tolist()

    def confirmed_deployments(self) -> np.ndarray:
        """bool ``[R, N]``: deployments a carrier reported, by its account or its Confirm (what
        summary.json counts)."""
        out = np.zeros((len(self.spec.carriers), self.spec.n_stages), dtype=bool)
        for (cid, j), c in self.confirms.items():
            if c.deployed and (cid, j) not in self.accounts:
                out[self.spec.index(cid), j] = True
        for (cid, j), a in self.accounts.items():
            out[self.spec.index(cid), j] = a.deployed
        return out

    def deployment_position(self, cid: str, j: int) -> tuple[float, float]:
        """Where carrier ``cid`` released its passenger of stage j (from its account or Confirm)."""
        record = self.accounts.get((cid, j)) or self.confirms[(cid, j)]
        return tuple(record.position)

    def passengers_left(self) -> np.ndarray:
        return np.asarray(self.spec.passengers) - self.deployed().sum(axis=1)

    def missing_stages(self, cid: str) -> list[int]:
        """Scheduled, decided stages where the carrier was ∅ (no Observation, or x = nil)."""
        r = self.spec.index(cid)
        return [j for j in range(self.next_stage) if self.spec.valid[r][j] and math.isnan(self.observation(r, j))
                and ((cid, j) in self.missing or (cid, j) in self.reported or (cid, j) in self.accounts)]

    def own_stages(self, cid: str) -> list[int]:
        """Stages carrier ``cid`` decided itself (it has an account of them)."""
        return sorted(j for (c, j) in self.accounts if c == cid)

    def latencies_ms(self) -> list[float]:
        return [c.latency_ms for c in self.confirms.values()
                if c.latency_ms is not None and c.status in LATENCY_STATUSES]


def initial(spec: MissionSpec) -> MissionState:
    return MissionState(spec=spec, trails={cid: () for cid in spec.carriers})


# --------------------------------------------------------------------------- effects

@dataclass(frozen=True)
class Record:
    """Persist ``event`` (mission.db) before carrying out the effects after it. ``stage`` is the
    stage the record is filed under (the stage being collected for liveliness changes)."""

    event: object
    stage: int | None = None
    missing: tuple[str, ...] = ()


@dataclass(frozen=True)
class Reject:
    """Drop the message that made the event; count it under ``reason``."""

    reason: str
    detail: str


@dataclass(frozen=True)
class Refuse:
    """Answer the carrier's Hello with a Refusal (docs/protocol.md, "Refusal"), in the revision
    the Hello announced."""

    carrier: str
    fingerprint: str
    reason: str
    detail: str
    revision: int = 1


@dataclass(frozen=True)
class Accept:
    """Answer the carrier's Hello: accepted (docs/protocol.md, "Accepted"; a carrier of revision
    3 or later is told, an earlier one learns it from its Decisions)."""

    carrier: str
    next_stage: int
    revision: int = 1


@dataclass(frozen=True)
class Publish:
    """Publish the decision of ``stage`` (it is recorded already)."""

    stage: int


@dataclass(frozen=True)
class Log:
    line: str


# --------------------------------------------------------------------------- the step function

def step(state: MissionState, event) -> tuple[MissionState, tuple]:
    """Fold one event into the state.

    Returns:
        ``(new state, effects)``; the state is unchanged (the same object) when the event is
        rejected or brings nothing new.

    Raises:
        ValueError: for an event the process must never make (a decision out of order).
    """
    handler = _HANDLERS.get(type(event))
    if handler is None:
        raise TypeError(f"not a mission event: {event!r}")
    return handler(state, event)


def fold(spec: MissionSpec, events, state: MissionState | None = None) -> MissionState:
    """The state after ``events`` (effects discarded): recovery from mission.db."""
    state = initial(spec) if state is None else state
    for event in events:
        state, _ = step(state, event)
    return state


def _replace(state: MissionState, **changes) -> MissionState:
    return evolve(state, **changes)


def _passed(accepted: dict, accounts: dict, cid: str, j: int) -> bool:
    info = accepted.get(cid)
    return (cid, j) in accounts or (info is not None and info.next_stage > j)


class _Expected:
    """:meth:`MissionState.expected`'s last count, with the objects it read (compared by
    identity: a state's fields are never changed in place, so the same objects give the same
    count). One per lineage of states (a coordinator's, a report's fold), handed on by
    :func:`step`: a wait asks after every event that makes a new state, and counting anew each
    time would be O(R) per Observation and Confirm, O(R²) per stage."""

    __slots__ = ("_last",)

    def __init__(self):
        self._last: tuple = ()

    def of(self, state: "MissionState", j: int) -> frozenset:
        spec, live, accepted, accounts = state.spec, state.live, state.accepted, state.accounts
        last = self._last
        if (last and last[0] is spec and last[1] == j and last[2] is live and last[3] is accepted
                and last[4] is accounts):
            return last[5]
        value = frozenset(cid for r, cid in enumerate(spec.carriers)
                          if spec.valid[r][j] and cid in live and cid in accepted
                          and not _passed(accepted, accounts, cid, j))
        self._last = (spec, j, live, accepted, accounts, value)  # replaced in one assignment
        return value


def _unknown(state, cid):
    if not state.spec.has(cid):
        return (Reject("unknown-carrier", f"carrier {cid!r} is not in the scenario"),)
    return None


def _no_hello(state, cid, what):
    if cid in state.accepted:
        return None
    if cid in state.refused:
        return (Reject("world-mismatch", f"{what} from carrier {cid}, whose Hello was refused"),)
    return (Reject("no-hello", f"{what} from carrier {cid} before its Hello"),)


def _on_opened(state: MissionState, e: ev.Opened):
    # A new process: liveliness and publication times belong to the old session. A stopped
    # mission resumes; only a complete one is final.
    changes = dict(opens=state.opens + 1, live=frozenset(), published_at={})
    if state.ended and state.end_reason != "complete":
        changes.update(ended=False, end_reason=None)
    return _replace(state, **changes), ()


def _on_hello(state: MissionState, e: ev.Hello):
    cid = e.carrier
    bad = _unknown(state, cid)
    if bad:
        return state, bad + (Refuse(cid, e.fingerprint, bad[0].reason, bad[0].detail, e.revision),)
    if e.next_stage > state.spec.n_stages:
        detail = f"next_stage {e.next_stage} > {state.spec.n_stages} (the mission's stages)"
        return state, (Reject("out-of-range", detail), Refuse(cid, e.fingerprint, "out-of-range", detail, e.revision))
    if e.fingerprint != state.spec.fingerprint:
        detail = f"carrier {cid} fingerprint {e.fingerprint} != {state.spec.fingerprint}"
        effects = []
        if cid in state.accepted:
            new = state
            effects.append(Log(f"coordinator: refused a later Hello of carrier {cid} (fingerprint "
                               f"{e.fingerprint}); its accepted Hello stands"))
        elif state.refused.get(cid) != e.fingerprint:
            new = _replace(state, refused={**state.refused, cid: e.fingerprint})
            effects.append(Record(e, None))
            effects.append(Log(f"coordinator: carrier {cid} built another world (scenario/seed fingerprint "
                               f"{e.fingerprint} != {state.spec.fingerprint}); its observations are ignored"))
        else:
            new = state
        effects += [Refuse(cid, e.fingerprint, "world-mismatch", detail, e.revision), Reject("world-mismatch", detail)]
        return new, tuple(effects)
    if e.revision < state.spec.min_revision:
        return _refuse_revision(state, e)
    refused = {k: v for k, v in state.refused.items() if k != cid}
    new = _replace(state, accepted={**state.accepted, cid: CarrierInfo(e.pid, e.host, e.next_stage, e.revision)},
                   refused=refused, byes=state.byes - {cid})  # a restarted carrier: its Bye is history
    return new, (Record(e, e.next_stage), Accept(cid, e.next_stage, e.revision))


def _refuse_revision(state: MissionState, e: ev.Hello):
    """A Hello of a revision too old for the mission (a coverage mission needs region counts):
    refused ``version`` with the revision it needs; like a refused fingerprint, the carrier then
    counts as joined (it will not fly) and a Hello accepted before stands."""
    cid = e.carrier
    detail = (f"carrier {cid} speaks protocol revision {e.revision}; this mission needs revision "
              f"{state.spec.min_revision} or later (region counts: reward coverage)")
    effects: list = [Refuse(cid, e.fingerprint, "version", detail, e.revision), Reject("version", detail)]
    if cid in state.accepted or state.refused.get(cid) == e.fingerprint:
        return state, tuple(effects)
    new = _replace(state, refused={**state.refused, cid: e.fingerprint})
    return new, (Record(e, None), Log(f"coordinator: refused carrier {cid}: {detail}"), *effects)


def _check_time(state, e):
    t_j = state.spec.stage_times[e.stage]
    if abs(e.t - t_j) > T_TOLERANCE_S:
        return (Reject("out-of-range", f"t: stage {e.stage} is at {t_j} s, found {e.t}"),)
    return None


def _check_carrier_stage(state, e, what: str, timed: bool):
    """The rejection of a carrier's message about a stage (unknown carrier, stage >= N, ``t`` not
    the stage time when ``timed``, no accepted Hello), or None."""
    j = e.stage
    return (_unknown(state, e.carrier)
            or (j >= state.spec.n_stages and (Reject("out-of-range", f"stage {j} >= {state.spec.n_stages}"),))
            or (timed and _check_time(state, e))
            or _no_hello(state, e.carrier, what))


def _same_observation(state: MissionState, e: ev.Observation) -> bool:
    """``e`` repeats the accepted Observation of its carrier and stage (same x, position and
    region counts)."""
    key = (e.carrier, e.stage)
    return (key in state.reported and state.reported[key] == e.x and state.positions.get(key) == tuple(e.position)
            and state.counts.get(key) == e.counts)


def _bad_counts(state: MissionState, e) -> tuple:
    """The rejection of an Observation or account whose region counts do not fit the mission: a
    coverage mission needs one count per region of the point's disc with every ``x``; a penalty
    mission takes none."""
    regions = state.spec.point_regions
    if e.x is None or not state.spec.scheduled(e.carrier, e.stage):
        return ()
    if regions is None:
        return () if e.counts is None else (Reject("out-of-range", "counts: expected none (a penalty mission)"),)
    n = regions[state.spec.index(e.carrier)][e.stage]
    if e.counts is None or len(e.counts) != n:
        return (Reject("out-of-range", f"counts: expected {n} region counts of carrier {e.carrier} at stage "
                                       f"{e.stage}, found {'none' if e.counts is None else len(e.counts)}"),)
    return ()


def _on_observation(state: MissionState, e: ev.Observation):
    cid, j = e.carrier, e.stage
    bad = _check_carrier_stage(state, e, "observation", timed=True)
    if bad:
        return state, bad
    if j < state.next_stage:
        if e.x is None and not state.spec.scheduled(cid, j):
            # The per-stage ∅ of a stage the carrier is not scheduled at: nobody waited for it
            # (a carrier joining at its staggered start sends one for the stage in progress).
            return state, ()
        if _same_observation(state, e):
            # The Observation the stage was decided with, again: a carrier that asked State while
            # the stage was still collected and re-sent it, the Decision crossing it on the way.
            return state, ()
        return state, (Reject("stale-stage", f"observation of carrier {cid} for decided stage {j}"),)
    if j > state.next_stage:
        return state, (Reject("future-stage", f"observation of carrier {cid} for stage {j}, "
                                              f"stage {state.next_stage} is being collected"),)
    if (cid, j) in state.reported:
        if _same_observation(state, e):
            return state, ()  # the same Observation again (a carrier that was not sure it arrived)
        return state, (Reject("duplicate", f"second observation of carrier {cid} at stage {j}"),)
    bad = _bad_counts(state, e)
    if bad:
        return state, bad
    counts = state.counts if e.counts is None else state.counts.set((cid, j), tuple(e.counts))
    new = _replace(state, counts=counts, reported=state.reported.set((cid, j), e.x),
                   positions=state.positions.set((cid, j), tuple(e.position)),
                   trails={**state.trails, cid: state.trails.get(cid, ()) + tuple(e.trail) + (tuple(e.position),)})
    return new, (Record(e, j),)


def _on_liveliness(state: MissionState, e: ev.LivelinessChanged):
    bad = _unknown(state, e.carrier)
    if bad:
        return state, bad
    cid = e.carrier
    if e.alive == (cid in state.live):
        return state, ()
    if e.alive:
        return (_replace(state, live=state.live | {cid}),
                (Record(e, state.next_stage), Log(f"coordinator: carrier {cid} is live")))
    return (_replace(state, live=state.live - {cid}),
            (Record(e, state.next_stage), Log(f"coordinator: carrier {cid} is gone (liveliness token vanished)")))


def _on_decided(state: MissionState, e: ev.Decided):
    j = e.stage
    if state.ended or j != state.next_stage or j >= state.spec.n_stages:
        raise ValueError(f"stage {j} cannot be decided now (next stage {state.next_stage}, ended {state.ended})")
    unknown = set(e.deploy) - set(state.spec.carriers)
    if unknown or len(set(e.deploy)) != len(e.deploy):
        raise ValueError(f"decision of stage {j} names carriers {e.deploy}")
    missing = tuple(cid for r, cid in enumerate(state.spec.carriers)
                    if state.spec.valid[r][j] and (cid, j) not in state.reported)
    order = sorted(range(len(e.deploy)), key=lambda k: e.deploy[k])
    named = tuple(int(e.passengers[k]) for k in order) if len(e.passengers) == len(e.deploy) else ()
    record = DecisionRecord(tuple(e.deploy[k] for k in order), float(e.planning_ms), named,
                            None if e.recommended is None else tuple(sorted(e.recommended)), tuple(sorted(e.forced)),
                            tuple(sorted(e.vetoed)), e.hold, e.gain)
    new = _replace(state, decisions={**state.decisions, j: record},
                   missing=state.missing | {(cid, j) for cid in missing}, next_stage=j + 1)
    return new, (Record(e, j, missing), Publish(j))


def _on_published(state: MissionState, e: ev.Published):
    if e.stage not in state.decisions:
        raise ValueError(f"stage {e.stage} published before it was decided")
    return _replace(state, published_at={**state.published_at, e.stage: e.at}), (Record(e, e.stage),)


def _on_confirmed(state: MissionState, e: ev.Confirmed):
    cid, j = e.carrier, e.stage
    bad = _check_carrier_stage(state, e, "confirmation", timed=False)
    if bad:
        return state, bad
    if j >= state.next_stage:
        return state, (Reject("stale-stage", f"confirmation of carrier {cid} for undecided stage {j}"),)
    if e.deployed and not state.spec.scheduled(cid, j):  # checked as for an Own making the same claim
        return state, (Reject("out-of-range", f"carrier {cid} confirms a deployment at stage {j}, where it is not "
                                              f"scheduled"),)
    account = state.accounts.get((cid, j))
    if account is not None and (cid, j) not in state.confirms:
        if e.deployed == account.deployed:
            # Its answer to a decision of a stage it had decided itself (``already``): on record.
            record = ConfirmRecord(bool(e.deployed), e.status, tuple(e.position), int(e.passengers_left), None,
                                   e.passenger)
            return _replace(state, confirms=state.confirms.set((cid, j), record)), (Record(e, j),)
        return state, (Reject("duplicate", f"confirmation of carrier {cid} at stage {j} contradicts its account"),)
    first = state.confirms.get((cid, j))
    if first is not None:
        if e.status == "already" or e.deployed == first.deployed:
            return state, ()  # the answer to a re-published decision, or a repeat: nothing new
        return state, (Reject("duplicate", f"second confirmation of carrier {cid} at stage {j}"),)
    beyond = _beyond_passengers(state, cid, j, e.deployed, "confirms")
    if beyond:
        return state, beyond
    latency = (e.at - state.published_at[j]) * 1e3 if j in state.published_at else None
    record = ConfirmRecord(bool(e.deployed), e.status, tuple(e.position), int(e.passengers_left), latency,
                           e.passenger)
    effects = [Record(e, j)]
    selected = cid in state.decisions[j].deploy
    if selected and not e.deployed:
        effects.append(Log(f"coordinator: carrier {cid} did not deploy at stage {j} ({e.status})"))
    if e.deployed and not selected:
        effects.append(Log(f"coordinator: carrier {cid} reports an unrequested deployment at stage {j}"))
    return _replace(state, confirms=state.confirms.set((cid, j), record)), tuple(effects)


def _beyond_passengers(state: MissionState, cid: str, j: int, deployed: bool, verb: str) -> tuple:
    """A deployment carrier ``cid`` reports at stage j while every one of its passengers is
    already reported released elsewhere (by its Confirms and accounts): no carrier can, so it is
    refused ``out-of-range`` [P-6.15] (a lying or broken carrier; the planner's view of the
    passengers on board stays within their number)."""
    if not deployed:
        return ()
    count = state.spec.passengers[state.spec.index(cid)]
    reported = {k for (c, k), rec in state.confirms.items() if c == cid and rec.deployed and k != j}
    reported |= {k for (c, k), rec in state.accounts.items() if c == cid and rec.deployed and k != j}
    if len(reported) < count:
        return ()
    return (Reject("out-of-range", f"carrier {cid} {verb} a deployment at stage {j}, but all its {count} "
                                   f"passenger(s) are reported released (stages {sorted(reported)})"),)


def _on_accounted(state: MissionState, e: ev.Accounted):
    cid, j = e.carrier, e.stage
    bad = _check_carrier_stage(state, e, "own decision", timed=True)
    if bad:
        return state, bad
    r = state.spec.index(cid)
    if e.deployed and not state.spec.valid[r][j]:
        return state, (Reject("out-of-range", f"carrier {cid} accounts a deployment at stage {j}, where it is not "
                                              f"scheduled"),)
    record = AccountRecord(e.x if state.spec.valid[r][j] else None, bool(e.deployed), tuple(e.position),
                           int(e.passengers_left))
    first = state.accounts.get((cid, j))
    if first is not None:
        if first == record:
            return state, ()  # repeated at a resynchronisation: nothing new
        return state, (Reject("duplicate", f"second account of carrier {cid} at stage {j}"),)
    confirm = state.confirms.get((cid, j))
    if confirm is not None and confirm.deployed != record.deployed:
        return state, (Reject("duplicate", f"account of carrier {cid} at stage {j} contradicts its confirmation"),)
    beyond = _beyond_passengers(state, cid, j, e.deployed and confirm is None, "accounts")
    if beyond:
        return state, beyond
    effects = [Record(e, j)]
    if e.deployed:
        effects.append(Log(f"coordinator: carrier {cid} deployed on its own at stage {j}"))
    new = _replace(state, accounts={**state.accounts, (cid, j): record},
                   positions=state.positions.set((cid, j), tuple(e.position)))
    if record.x is not None and e.counts is not None and not _bad_counts(state, e):
        new = _replace(new, counts=new.counts.set((cid, j), tuple(e.counts)))  # an account without them is kept
    return new, tuple(effects)


def _on_bye(state: MissionState, e: ev.Bye):
    bad = _unknown(state, e.carrier) or _no_hello(state, e.carrier, "bye")
    if bad:
        return state, bad
    new = _replace(state, byes=state.byes | {e.carrier},
                   carrier_rejected={**state.carrier_rejected, e.carrier: dict(e.rejected)},
                   bye_deployments={**state.bye_deployments, e.carrier: frozenset(e.deployments)})
    return new, (Record(e, None),)


def _on_ended(state: MissionState, e: ev.Ended):
    if state.ended:
        return state, ()
    return _replace(state, ended=True, end_reason=e.reason), (Record(e, state.next_stage),)


def _on_operator(state: MissionState, e: ev.OperatorAction):
    refused = operator_rules.refusal(state, e)
    if refused is not None:
        return state, (Reject(*refused),)
    actions = {**state.operator_actions, e.stage: state.operator_actions.get(e.stage, ()) + (e,)}
    what = "approved" if e.action == "approve" else f"{e.action} {e.carrier}"
    return (_replace(state, operator_actions=actions),
            (Record(e, e.stage), Log(f"coordinator: stage {e.stage}: operator {e.operator} {what}")))


_HANDLERS = {
    ev.Opened: _on_opened, ev.Hello: _on_hello, ev.Observation: _on_observation,
    ev.LivelinessChanged: _on_liveliness, ev.Decided: _on_decided, ev.Published: _on_published,
    ev.Confirmed: _on_confirmed, ev.Accounted: _on_accounted, ev.Bye: _on_bye, ev.Ended: _on_ended,
    ev.OperatorAction: _on_operator,
}
