"""What one carrier knows of the fleet's stages from the messages it heard: its input for
deciding a stage on its own (:class:`planner.decentralised.LocalView`).

A carrier hears the other carriers' Observations (x at each stage), their Own messages (a stage
they decided themselves: x and whether they deployed), their Confirms (whether they deployed on
the coordinator's decision) and the coordinator's Decisions (whom it selected). Per carrier b and
stage t the book keeps x (known once b's Observation or Own arrived) and b's action: its own word
(Confirm, Own) when heard, else the coordinator's decision (selected: taken as deployed, not
selected: not deployed). A stage b is not scheduled at is known at once (∅, no deployment). The
x of a stage where b is known not to have deployed is known too, as far as planning goes: what
a decision depends on is the current stage's observations and the past deployments with their
x (the state of the fleet), not the values of points passed by — so a lost Observation of such a
stage does not blind a carrier to b for the rest of the mission.

The book has no clock and does no I/O; the carrier process feeds it (its own observations and
outcomes too) and asks it for a :class:`LocalView`.

:class:`Presence` is who a carrier knows to be there (the coordinator's token, its peers'
tokens, when something last came from each peer); :func:`last_heard` is the silence rule both
processes wait by on the sim clock (docs/fleet.md, "Simulated time and wall time"). Times are
the process's monotonic seconds, handed in by the process.
"""
from __future__ import annotations

import numpy as np

#: Action codes of :attr:`PeerBook.source`.
UNKNOWN, FROM_DECISION, FROM_CARRIER = 0, 1, 2
#: A carrier listens to every carrier of its conflict component up to this many; in a larger
#: component, to its direct conflict neighbours only (what it hears grows with its degree, not
#: with the fleet).
COMPONENT_MAX = 64


def conflict_adjacency(problem) -> list[frozenset]:
    """Per carrier index, the carriers it shares an overlap group with (itself included): the
    conflict graph that :func:`listened` walks. O(sum of the groups' sizes squared); a process
    that runs many carriers computes it once for all of them (:class:`carriers.onboard.Onboard`),
    since each carrier computing it for itself costs the fleet O(R²) at every join."""
    adjacency = [set() for _ in range(problem.n_carriers)]
    for group in problem.overlaps:
        members = set(int(c) for c in np.asarray(group)[:, 0])
        for c in members:
            adjacency[c] |= members
    return [frozenset(a) for a in adjacency]


def listened(problem, r: int, component_max: int = COMPONENT_MAX, adjacency=None) -> list[int]:
    """The carriers (indices, r excluded) carrier r listens to: those its deployments can conflict
    with, directly or through others (its component of the conflict graph) when there are at most
    ``component_max``, else its direct neighbours. With its whole component heard, a carrier
    deciding alone knows everything its decision depends on. ``adjacency``: the problem's
    :func:`conflict_adjacency` when the caller has it (computed here otherwise); the walk itself
    stops after ``component_max`` carriers, so it costs O(component_max) given the adjacency."""
    if adjacency is None:
        adjacency = conflict_adjacency(problem)
    component, frontier = {r}, [r]
    while frontier and len(component) <= component_max:
        b = frontier.pop()
        for c in adjacency[b] - component:
            component.add(c)
            frontier.append(c)
    chosen = component if len(component) <= component_max else adjacency[r]
    return sorted(chosen - {r})


def last_heard(heard: dict, among, since: float) -> float:
    """When something last came from any of ``among`` (monotonic s; ``heard``: id -> time), not
    before ``since`` (a wait that opened then): a wait for them ends once nothing came from any
    of them for the silence timeout after this."""
    return max(since, max((heard.get(cid, since) for cid in among), default=since))


class Presence:
    """Who a carrier knows to be there: the coordinator (its liveliness token, or an answer to a
    State query) and its peers (their tokens, and when something last came from each).

    Attributes:
        coordinator_present: the coordinator's token is present (or it answered since it vanished).
        coordinator_seen: the coordinator was ever present.
        absent_since: since when the coordinator is absent (monotonic s).
        peers_live: ids of the peers whose token is present.
        heard: peer id -> when something (not only Progress) last came from it (monotonic s).
    """

    def __init__(self, now: float):
        self.coordinator_present = False
        self.coordinator_seen = False
        self.absent_since = now
        self.peers_live: set[str] = set()
        self.heard: dict[str, float] = {}

    def coordinator_alive(self) -> bool:
        """The coordinator's token appeared; True when it came back (present before, then gone):
        the carrier then resynchronises from its State."""
        returned = self.coordinator_seen and not self.coordinator_present
        self.coordinator_present = self.coordinator_seen = True
        return returned

    def coordinator_gone(self, now: float) -> None:
        self.coordinator_present = False
        self.absent_since = now

    def coordinator_answered(self) -> None:
        """A State answer at join: present, even before its token is seen (if never seen yet)."""
        if not self.coordinator_seen:
            self.coordinator_present = self.coordinator_seen = True

    def absent_for(self, now: float) -> float:
        """How long the coordinator has been absent (s); 0 while present."""
        return 0.0 if self.coordinator_present else now - self.absent_since

    def peer(self, cid: str, alive: bool) -> None:
        (self.peers_live.add if alive else self.peers_live.discard)(cid)

    def heard_from(self, cid: str, now: float) -> None:
        self.heard[cid] = now

    def last_heard(self, among, since: float) -> float:
        return last_heard(self.heard, among, since)


class PeerBook:
    """Observations and deployments of every carrier of a mission, as heard.

    Args:
        carriers: carrier ids in scenario order (index r).
        valid: bool ``[R, N]``, carrier r scheduled at stage j.
    """

    def __init__(self, carriers, valid):
        self.carriers = tuple(carriers)
        self.index = {cid: r for r, cid in enumerate(self.carriers)}
        self.valid = np.asarray(valid, dtype=bool)
        R, N = self.valid.shape
        self.x = np.full((R, N), np.nan)
        self.x_known = ~self.valid.copy()          # unscheduled stages are ∅, known in advance
        self.deployed = np.zeros((R, N), dtype=bool)
        self.source = np.where(self.valid, UNKNOWN, FROM_CARRIER).astype(np.int8)
        self.at: dict = {}                         # carrier id -> the latest stage its Progress named
        self.counts: dict = {}                     # (r, stage) -> region counts behind x (coverage reward)
        self.coordinated = False                   # a coordinator's Decision was heard: a hybrid fleet

    @property
    def n_stages(self) -> int:
        return self.valid.shape[1]

    def accepts(self, stage: int) -> bool:
        """A peer's message of ``stage`` is of this mission (0 <= stage < N); one past its end is
        rejected ``out-of-range`` before it reaches the book."""
        return 0 <= stage < self.n_stages

    def observation(self, cid: str, stage: int, x, counts=None) -> None:
        """Carrier ``cid`` observed ``x`` (None = ∅) at ``stage``; ``counts``: the region counts
        behind it under the coverage reward (in the order of the point's regions), else None."""
        r = self.index[cid]
        if self.valid[r, stage]:
            self.x[r, stage] = np.nan if x is None else float(x)
            self.x_known[r, stage] = True
            if counts is not None:
                self.counts[r, int(stage)] = tuple(counts)

    def outcome(self, cid: str, stage: int, deployed: bool) -> None:
        """Carrier ``cid`` says whether it deployed at ``stage`` (its Confirm or Own)."""
        r = self.index[cid]
        if self.valid[r, stage]:
            self.deployed[r, stage] = bool(deployed)
            self.source[r, stage] = FROM_CARRIER
            if not deployed:
                self.x_known[r, stage] = True

    def decision(self, stage: int, deploy) -> None:
        """The coordinator's decision of ``stage`` selected ``deploy``; carriers whose own word
        about the stage is heard already keep it."""
        self.coordinated = True
        selected = np.zeros(len(self.carriers), dtype=bool)
        for cid in deploy:
            if cid in self.index:
                selected[self.index[cid]] = True
        col = self.source[:, stage] < FROM_CARRIER
        self.deployed[col, stage] = selected[col]
        self.source[col, stage] = FROM_DECISION
        self.x_known[col & ~selected, stage] = True

    def progress(self, cid: str, stage: int) -> None:
        """Carrier ``cid``'s Progress names ``stage`` (the stage it works towards or waits at,
        [P-10.6])."""
        self.at[cid] = max(self.at.get(cid, 0), int(stage))

    def waiting(self, stage: int, among) -> list[str]:
        """Carriers of ``among`` whose observation of ``stage`` has not been heard, and which are
        not past it (a Progress naming a later stage: its observation of ``stage`` went out and
        was lost; waiting for it would wait for nothing, as long as it is heard from)."""
        return [cid for cid in among if not self.x_known[self.index[cid], stage] and self.at.get(cid, 0) <= stage]

    def local_view(self, problem, carrier: str, stage: int, seed: int):
        """Carrier ``carrier``'s :class:`~planner.decentralised.LocalView` of ``stage``: per other
        carrier, its observations up to the first one not heard and its deployments up to the
        first stage whose action is unknown; its own row through ``stage`` (observations) and
        ``stage - 1`` (deployments), which it must have fed in. ``coordinated`` once a
        coordinator's Decision was heard (its peers are decided by a coordinator)."""
        from planner.decentralised import LocalView

        r, j = self.index[carrier], int(stage)
        R, N = self.valid.shape
        seen = _prefix(self.x_known)
        record = _prefix(self.source > UNKNOWN)
        seen = np.minimum(seen, j + 1)
        record = np.minimum(record, j)
        seen[r], record[r] = j + 1, j
        stages = np.arange(N)
        obs = np.where(stages[None, :] < seen[:, None], self.x, np.nan)
        dep = self.deployed & (stages[None, :] < record[:, None])
        return LocalView(problem, r, j, int(seed), obs, dep, seen.astype(np.int64), record.astype(np.int64),
                         (None,) * R, counts=self._known_counts(problem, seen), coordinated=self.coordinated)

    def _known_counts(self, problem, seen: np.ndarray):
        """Under the coverage reward, float ``[M]``: the region counts of the observations in the
        view (``t < seen[b]``), NaN for the others (:func:`planner.coverage.revealed`'s rule);
        None under the penalty reward."""
        coverage = problem.coverage
        if coverage is None:
            return None
        out = np.full(coverage.n_regions, np.nan)
        n_stages = self.n_stages
        for (b, t), counts in self.counts.items():
            if t < seen[b]:
                out[coverage.regions(b * n_stages + t)] = counts
        return out


def _prefix(known: np.ndarray) -> np.ndarray:
    """int ``[R]``: per row, the length of the leading run of True."""
    out = np.full(known.shape[0], known.shape[1], dtype=np.int64)
    gaps = ~known
    has = gaps.any(axis=1)
    out[has] = np.argmax(gaps[has], axis=1)
    return out
