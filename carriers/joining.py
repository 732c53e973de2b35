"""How a carrier joins a mission and catches up: from the coordinator's State (or, with no
coordinator answering, from its own durable log), replaying the deployments on record in its
world (one replay for both paths), and later resynchronising from State when a Decision was lost
or the coordinator came back.

:class:`Joining` and :class:`StateQueries` are collaborators of :class:`carriers.node.Carrier`:
each is given what it needs when it is built, and the carrier's machine, log and wire node at
each call. They call nothing back: a join path is a generator of what it asks of the carrier
(:class:`Apply` an event, answered with the machine after it; :class:`Execute` an effect;
:class:`Advance` the body), which the carrier carries out (:func:`mission.timers.drive`,
:meth:`carriers.node.Carrier._asked`).
"""
from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Any, Callable, Generator

from carriers.exits import Exit
from mission import carrier as mc
from mission.ballot import Ballot
from mission.peers import PeerBook, Presence
from mission.timeouts import DEFAULTS
from wire import keys
from wire.messages import REVISION, ProtocolError, State, decode
from mission.modes import Mode


@dataclass(frozen=True)
class Apply:
    """What a join path asks of its carrier: step its machine with ``event`` (and carry out the
    effects); the carrier sends back its machine after it."""

    event: Any


@dataclass(frozen=True)
class Execute:
    """What a join path asks of its carrier: carry out this effect of its machine."""

    effect: Any


@dataclass(frozen=True)
class Advance:
    """What a join path asks of its carrier: its body driven to mission time ``t`` (s), unpaced."""

    t: float


#: A join path: a generator of what it asks of its carrier, sent the carrier's machine after each
#: :class:`Apply` (None after the others).
Steps = Generator[Any, Any, Any]


class Joining:
    """The carrier's join paths and its resynchronisation from State.

    Args:
        cid: the carrier's id; fingerprint: its world's; config: its ``CarrierConfig`` (``mode``,
        ``coordinator_timeout_s``, ``join_timeout_s``, ``hello_timeout_s``); stage_time(j): mission time (s) of stage
        j; queries: its :class:`StateQueries`; book: its :class:`mission.peers.PeerBook`; motion:
        its ``carriers.motion.Motion`` (position, body); inbound: its
        ``carriers.inbound.Inbound`` (whom it listens to; its ``presence``, the
        :class:`mission.peers.Presence`); clock: its clock (s); stop: its stop request; log: a
        callable taking one line.
    """

    def __init__(self, cid: str, fingerprint: str, config, stage_time: Callable[[int], float],
                 queries: StateQueries, book: PeerBook, motion, inbound, clock: Callable[[], float],
                 stop: threading.Event, log):
        self.cid, self.fingerprint, self.config, self.stage_time = cid, fingerprint, config, stage_time
        self.queries, self.book, self.motion, self.inbound = queries, book, motion, inbound
        self.presence: Presence = inbound.presence
        self.releases: mc.Releases = inbound.releases
        self.clock, self._stop, self.log = clock, stop, log
        self.next_alone = 0  # joining alone: the stage after the last its log resolved

    def from_state(self, machine: mc.Handshake, store, state: State) -> Steps:
        """Join from the coordinator's State (the answer to the lifecycle's
        :class:`mission.carrier_life.Query`) and the carrier's own durable log (``store``, None:
        none): the deployments on record replayed, the stages it resolved itself recalled, its
        Hello, then the deployments on record it never made answered ``late`` and its own
        decisions said again."""
        self.presence.coordinator_answered()  # present, even if its token is not pumped yet
        if state.fingerprint != self.fingerprint:
            self.log(f"the coordinator runs another world (fingerprint {state.fingerprint}, ours "
                     f"{self.fingerprint}): use the same scenario file and --seed")
            raise Exit("world-mismatch")
        mine = state.carrier(self.cid)
        recorded = tuple(mine.deployments) if mine else ()
        entries = {e.stage: e for e in store.entries() if e.status is not None} if store is not None else {}
        logged = {j: e.deployed for j, e in entries.items()} or None  # no outcome logged: the record decides
        start = mc.join_stage(state.next_stage, logged)
        recalled = [j for j in sorted(entries) if j >= state.next_stage]
        if not state.ended:
            machine = yield from self._replay(mc.replay_plan(machine, min(state.next_stage, start), recorded, logged),
                                              machine)
            machine = yield from self._recall([entries[j] for j in recalled], machine)
        machine = yield Apply(mc.Joined(start, state.ended, state.epoch, state.coordinator))
        yield Execute(mc.SendHello(machine.hello_stage(), machine.passengers_left))
        # after its Hello (it is accepted first): the deployments on record it never made answered
        # late, its own decisions of the recalled stages said again
        for j in mc.missed(state.next_stage, recorded, logged):
            machine = yield Apply(mc.Missed(j, self.motion.position()))
        for effect in mc.accounts(machine, recalled):
            yield Execute(effect)

    def _recall(self, entries, machine: mc.Handshake) -> Steps:
        """The stages its log resolved that the coordinator has not decided (it decided them on
        board while the coordinator was away): kept as they were (:class:`mission.carrier.Recalled`,
        its Own sent again), a deployment among them replayed in its world."""
        for e in entries:
            yield Advance(self.stage_time(e.stage))
            machine = yield Apply(mc.Recalled(e.stage, e.status, e.deployed, self.motion.position(), e.x))
            if e.deployed:
                self.motion.body.deploy(self.cid)
            self.book.outcome(self.cid, e.stage, e.deployed)
        return machine

    def _replay(self, stages, machine: mc.Handshake) -> Steps:
        """The deployments on record at ``stages`` (ascending, at most the passengers on board:
        :func:`mission.carrier.replay_plan`) replayed in the carrier's world: the body driven to
        each stage time unpaced and a passenger released there."""
        for j in stages:
            yield Advance(self.stage_time(j))
            machine = yield Apply(mc.Replayed(j, self.motion.position()))
            self.motion.body.deploy(self.cid)
            self.book.outcome(self.cid, j, True)
        return machine

    def alone_from_log(self, machine: mc.Handshake, store, node) -> Steps:
        """Join with no coordinator (decentralised, or none answered: hybrid): go on from the
        carrier's own log (``store``; the deployments on record replayed in its world) and listen
        to its peers (on ``node``); the lifecycle then waits (at most ``join_timeout_s``) for
        every other carrier's token, so that nobody starts the mission alone (:meth:`gathered`)."""
        if self.config.mode == Mode.HYBRID:
            # A coordinator that appears later (one slow to start) is one to resynchronise with:
            # its token's arrival makes this carrier say Hello and hand over what it decided.
            self.presence.coordinator_seen = True
        entries = [e for e in store.entries() if e.status is not None] if store is not None else []
        for e in entries:
            if e.observed:
                self.book.observation(self.cid, e.stage, e.x, self.motion.counts(e.stage, e.x))
            self.book.outcome(self.cid, e.stage, e.deployed)
        self.next_alone = max((e.stage + 1 for e in entries), default=0)
        yield from self._replay(mc.replay_plan(machine, self.next_alone, [e.stage for e in entries if e.deployed]),
                                machine)
        self.inbound.listen(node, wait=True)

    def gathered(self, node) -> Steps:
        """The wait for the peers' tokens is over: the carrier joins at the stage after the last its
        log resolved; a coordinator whose token came meanwhile is one to resynchronise with."""
        missing = sorted(set(self.inbound.listening or ()) - self.presence.peers_live)
        if missing and self.next_alone == 0:
            self.log(f"starting without carrier(s) {', '.join(missing)} (no token after "
                     f"{self.config.join_timeout_s:.0f} s)")
        machine = yield Apply(mc.Joined(self.next_alone))
        if self.config.mode == Mode.HYBRID and self.presence.coordinator_present:  # it is back [P-5.12]
            yield from self.resync(machine, node)

    def recover_decision(self, machine: mc.Handshake, node, j: int) -> Steps:
        """Sim clock, a long wait for the Decision of j: if the coordinator's State says it has
        decided j already, the Decision was lost on the way: resynchronise (it is taken from
        State). If it still collects j, it may not have our Observation (mission.carrier,
        Collecting). Otherwise the coordinator is still at work: go on waiting."""
        state = self.queries.once(node)
        if state is None or not mc.current(machine, state.epoch, state.coordinator):
            return
        if state.next_stage > j:
            self.log(f"stage {j} was decided but its Decision did not arrive; taking it from State")
            self._named(machine, state)
            yield Apply(mc.Resync(self.queries.seen(state), self.motion.position()))
        elif state.next_stage == j:
            yield Apply(mc.Collecting(j, state.epoch, state.coordinator))
        else:
            # the coordinator is behind this carrier: its Hello or its accounts of the stages
            # since were lost; saying them again lets it go on (found by mission.simulate)
            self.log(f"the coordinator is at stage {state.next_stage}, this carrier at {j}; resynchronising")
            yield Apply(mc.Resync(self.queries.seen(state), self.motion.position()))

    def resync(self, machine: mc.Handshake, node, gap: int | None = None) -> Steps:
        """Resynchronise from the coordinator's State (:class:`mission.carrier.Resync`): its token
        came back (``gap`` None), or the Decision of stage ``gap`` came without an earlier one
        this carrier needs (:class:`mission.carrier.AskState`): the lost stages are taken from a
        State of its world before it confirms anything more (docs/protocol.md, [P-6.6])."""
        state = self.queries.once(node)
        if gap is not None and state is not None and state.fingerprint != self.fingerprint:
            state = None
        if state is not None:
            self._named(machine, state)
        yield Apply(mc.Resync(self.queries.seen(state), self.motion.position(), gap=gap))

    def _named(self, machine: mc.Handshake, state: State) -> None:
        """The passenger State's last Decision names for this carrier, as a Decision heard names it
        (a Decision taken from State releases the passenger it names, [P-6.9])."""
        last = state.last_decision
        if last is not None:
            self.releases.name(machine, last.stage, state.epoch, last.passenger_of(machine.cid), state.coordinator)


def _ballot(state: State) -> Ballot:
    return Ballot(state.epoch, state.coordinator)


class StateQueries:
    """A carrier's State queries ([P-5.2]): one query's reply of the highest ballot, the revision
    it speaks from then on, and what its machine takes from a State. A collaborator of
    :class:`carriers.node.Carrier`, handed the node each time (it opens with the run)."""

    def __init__(self, mission: str, cid: str, log):
        self.mission, self.cid, self.log = mission, cid, log

    def once(self, node) -> State | None:
        """The State reply of the highest ballot (two coordinators may answer across a split)."""
        best = None
        selector = keys.state_selector(self.mission, self.cid, REVISION)
        for payload in node.query(selector, timeout_s=DEFAULTS.state_query_s):
            try:
                state = decode(payload, State)
            except ProtocolError as exc:
                node.reject(exc.reason, exc.detail, self.log)
                continue
            if state.mission == self.mission and (best is None or _ballot(best).below(_ballot(state))):
                best = state
        if best is not None:  # speak the coordinator's revision from now on (docs/protocol.md, "Compatibility")
            node.revision = min(REVISION, best.revision)
        return best

    def seen(self, state: State | None) -> mc.StateSeen | None:
        """What :mod:`mission.carrier` takes from a State (None: none)."""
        if state is None:
            return None
        mine = state.carrier(self.cid)
        last = state.last_decision
        return mc.StateSeen(state.next_stage, tuple(mine.deployments) if mine else (),
                            None if last is None else (last.stage, last.t, tuple(last.deploy)), state.ended,
                            state.epoch, state.coordinator)
