"""How a carrier joins a mission and catches up: from the coordinator's State (or, with no
coordinator answering, from its own durable log), replaying the deployments on record in its
world (one replay for both paths), and later resynchronising from State when a Decision was lost
or the coordinator came back.

:class:`Joining` and :class:`StateQueries` are collaborators of :class:`carriers.node.Carrier`:
each is given what it needs when it is built, and the carrier's machine, log and wire node at
each call. They call nothing back: a join path is a generator of what it asks of the carrier
(:mod:`mission.joins`, whose paths from State and from the log alone the simulator runs too:
an event applied, an effect carried out, the body driven), which the carrier carries out
(:func:`mission.timers.drive`, :meth:`carriers.node.Carrier._asked`).
"""
from __future__ import annotations

from carriers.exits import Exit
from carriers.inbound import Rejoin
from mission import carrier as mc
from mission import carrier_life as cl
from mission import joins
from mission.joins import Steps
from mission.ballot import Ballot
from mission.peers import PeerBook, Presence
from mission.timeouts import DEFAULTS
from wire import keys
from wire.messages import REVISION, ProtocolError, State, decode
from mission.modes import Mode


#: The lifecycle's effects that are a join or resynchronisation path (:meth:`Joining.path`).
PATHS = (cl.AskState, cl.Query, cl.JoinAlone, cl.Gathered)
#: What else asks for a resynchronisation from State (:meth:`Joining.path`): the handshake
#: machine's :class:`mission.carrier.AskState` (a Decision came without an earlier one) and
#: :class:`carriers.inbound.Rejoin` (the coordinator is back).
RESYNCS = (mc.AskState, Rejoin)


class Joining:
    """The carrier's join paths and its resynchronisation from State.

    Args:
        fingerprint: its world's; config: its ``CarrierConfig`` (``mode``, ``join_timeout_s``);
        queries: its :class:`StateQueries`; counts(j, x): the region counts behind what it sensed
        (``carriers.motion.Motion.counts``); inbound: its ``carriers.inbound.Inbound`` (whom it
        listens to; its books: the :class:`mission.peers.PeerBook`, the
        :class:`mission.peers.Presence`, the passengers Decisions named); log: a callable taking
        one line.
    """

    def __init__(self, fingerprint: str, config, queries: StateQueries, counts, inbound, log):
        self.fingerprint, self.config, self.queries = fingerprint, config, queries
        self.counts, self.inbound = counts, inbound
        self.book: PeerBook = inbound.book
        self.presence: Presence = inbound.presence
        self.releases: mc.Releases = inbound.releases
        self.log = log
        self.next_alone = 0  # joining alone: the stage after the last its log resolved

    def path(self, effect, machine: mc.Handshake, node, store) -> Steps:
        """The join or resynchronisation path one effect of :data:`PATHS` or :data:`RESYNCS` asks
        for (``machine``: the handshake machine now, ``node``: its wire node, ``store``: its
        durable log, None: none): a Decision recovered from State (the lifecycle's ``AskState``),
        a join from State (``Query``: State asked once), from its log alone (``JoinAlone``), its
        peers gathered (``Gathered``), a resynchronisation (:meth:`resync`: the gap of the
        handshake's ``AskState``, or none for a ``Rejoin``). Returns whether a State answered the
        Query."""
        if isinstance(effect, RESYNCS):
            yield from self.resync(machine, node, gap=effect.stage if isinstance(effect, mc.AskState) else None)
        elif isinstance(effect, cl.AskState):
            yield from self.recover_decision(machine, node, effect.stage)
        elif isinstance(effect, cl.Query):
            state = self.queries.once(node)
            if state is None:
                return False
            yield from self.from_state(machine, store, state)
            return True
        elif isinstance(effect, cl.JoinAlone):
            yield from self.alone_from_log(machine, store, node)
        elif isinstance(effect, cl.Gathered):
            yield from self.gathered(node, effect.resync)
        return False

    def from_state(self, machine: mc.Handshake, store, state: State) -> Steps:
        """Join from the coordinator's State (the answer to the lifecycle's
        :class:`mission.carrier_life.Query`) and the carrier's own durable log (``store``, None:
        none): :func:`mission.joins.from_state`, once State is of its world."""
        self.presence.coordinator_answered()  # present, even if its token is not pumped yet
        if state.fingerprint != self.fingerprint:
            self.log(f"the coordinator runs another world (fingerprint {state.fingerprint}, ours "
                     f"{self.fingerprint}): use the same scenario file and --seed")
            raise Exit("world-mismatch")
        entries = store.entries() if store is not None else ()
        yield from joins.from_state(machine, self.queries.seen(state), entries, self.book)

    def alone_from_log(self, machine: mc.Handshake, store, node) -> Steps:
        """Join with no coordinator (decentralised, or none answered: hybrid): go on from the
        carrier's own log (``store``: :func:`mission.joins.alone`) and listen to its peers (on
        ``node``); the lifecycle then waits (at most ``join_timeout_s``) for every other
        carrier's token, so that nobody starts the mission alone (:meth:`gathered`)."""
        if self.config.mode == Mode.HYBRID:
            # A coordinator that appears later (one slow to start) is one to resynchronise with:
            # its token's arrival makes this carrier say Hello and hand over what it decided.
            self.presence.coordinator_seen = True
        entries = store.entries() if store is not None else ()
        self.next_alone = yield from joins.alone(machine, entries, self.book, self.counts)
        self.inbound.listen(node, wait=True)

    def gathered(self, node, resync: bool) -> Steps:
        """The wait for the peers' tokens is over: the carrier joins at the stage after the last its
        log resolved; ``resync`` (the lifecycle's :class:`mission.carrier_life.Gathered`): the
        coordinator came back meanwhile, resynchronise with it."""
        missing = sorted(set(self.inbound.listening or ()) - self.presence.peers_live)
        if missing and self.next_alone == 0:
            self.log(f"starting without carrier(s) {', '.join(missing)} (no token after "
                     f"{self.config.join_timeout_s:.0f} s)")
        machine = yield joins.Apply(mc.Joined(self.next_alone))
        if resync:
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
        elif state.next_stage < j:
            self.log(f"the coordinator is at stage {state.next_stage}, this carrier at {j}; resynchronising")
        yield joins.Apply(mc.waited_state(self.queries.seen(state), j, (yield joins.Here())))

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
        yield joins.Apply(mc.Resync(self.queries.seen(state), (yield joins.Here()), gap=gap))

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
