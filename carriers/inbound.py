"""What a carrier receives: its inbox (the coordinator's Decisions, End, the answers to its
Hello, liveliness tokens) and the messages of the peers it listens to, checked at the wire level
(key layout, decoding, mission id, the carrier id in the key), fed to the books of what it heard
(:class:`mission.peers.PeerBook`, :class:`mission.peers.Presence`,
:class:`mission.carrier.HelloAnswer`, :class:`mission.carrier.Releases`) and turned into events of
``mission.carrier`` or effects for the carrier to carry out; what the carrier's lifecycle reads
of them (:meth:`Inbound.view`).

:class:`Inbound` is a collaborator of :class:`carriers.node.Carrier`, given those books and what
else it needs when it is built; the carrier's machine and timers change only in the carrier, by
what :meth:`Inbound.read` returns (:meth:`carriers.node.Carrier.pump`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from carriers.exits import refused_exit
from mission import carrier as mc
from mission import carrier_life as cl
from mission.peers import PeerBook, Presence
from wire import keys
from wire.messages import Accepted, Confirm, Decision, End, Observation, Own, Progress, ProtocolError, Refusal, decode
from mission.modes import Mode

#: What peers publish that a carrier reads, and the message type of each.
PEER_TOPICS = {"obs": Observation, "own": Own, "confirm": Confirm, "progress": Progress}


@dataclass(frozen=True)
class Rejoin:
    """Effect: the coordinator's token came back; the carrier resynchronises from its State."""


@dataclass(frozen=True)
class Follow:
    """Effect: the coordinator told the mission's timers (its Accepted, revision 4 and later);
    the carrier times its waits by them (:func:`mission.carrier.follow`)."""

    timers: mc.Timers


class Inbound:
    """The carrier's receiving side.

    Attributes:
        listening: the carriers whose messages and tokens it subscribed to (None: none yet).

    Args:
        mission, cid: the mission's and this carrier's ids; mode: the carrier's mode
        (:data:`mission.modes.MODES`); onboard: its ``carriers.onboard.Onboard`` (whom it listens to;
        loaded when the coordinator vanishes, hybrid); broadcasts: the process's
        :class:`wire.messages.SharedDecoder` (a Decision is decoded once per process); book,
        presence, answer, releases: the books it feeds; position(): where the carrier is now;
        log: a callable taking one line.
    """

    def __init__(self, mission: str, cid: str, mode: str, onboard, broadcasts, book: PeerBook,
                 presence: Presence, answer: mc.HelloAnswer, releases: mc.Releases, position, log):
        self.mission, self.cid, self.mode, self.onboard, self.broadcasts = mission, cid, mode, onboard, broadcasts
        self.book, self.presence, self.answer, self.releases = book, presence, answer, releases
        self.position, self.log = position, log
        self.listening: tuple[str, ...] | None = None

    def view(self, machine: mc.Handshake, timers: mc.Timers, revision: int) -> cl.View:
        """What the carrier's lifecycle machine reads now (:class:`mission.carrier_life.View`):
        its handshake ``machine`` and ``timers``, and what it heard: who is there, whether it
        listens to every live peer, its Hello's answer (``revision``: its session's, 3 and later
        answer Hellos)."""
        p, a = self.presence, self.answer
        return cl.View(machine, p.coordinator_present, p.absent_since, timers, frozenset(p.peers_live),
                       p.heard, self.book, set(self.listening or ()) <= p.peers_live,
                       cl.Hello(bool(a.unanswered), revision >= 3, a.at, a.tries))

    def subscribe(self, node) -> None:
        """The inbox's keys on ``node``: the mission's Decisions and End, the answers to this
        carrier's Hello, the coordinator's liveliness token."""
        node.subscribe(keys.decision_key(self.mission))
        node.subscribe(keys.end_key(self.mission))
        node.subscribe(keys.refusal_key(self.mission, self.cid))
        node.subscribe(keys.accepted_key(self.mission, self.cid))
        node.watch_liveliness(keys.coordinator_alive(self.mission))

    def listen(self, node, wait: bool = False) -> None:
        """Subscribe on ``node`` to the carriers this one listens to (:func:`mission.peers.listened`:
        its conflict component, or its neighbours in a large one) once the on-board planner's
        instance is built (``wait``: build it now)."""
        if self.listening is not None or self.mode == Mode.COORDINATED or not (wait or self.onboard.ready()):
            return
        ids = self.book.carriers
        self.listening = tuple(ids[b] for b in self.onboard.listened(self.book.index[self.cid]))
        for cid in self.listening:
            for topic in PEER_TOPICS:  # read when the carrier next looks: no wake-up per message
                node.subscribe(keys.carrier_key(self.mission, cid, topic), wake=False)
            node.watch_liveliness(keys.carrier_alive(self.mission, cid))

    def arrivals(self, node, timeout_s: float):
        """What arrived on ``node``, one item at a time: the inbox (waiting up to ``timeout_s``
        for its first item), then the peers' messages waiting in their channels. The carrier
        reads each against its machine then (:meth:`read`)."""
        if self.listening is None:
            self.listen(node)
        item = node.next(timeout_s)
        while item is not None:
            yield item
            item = node.next(0.0)
        yield from node.drain()

    def read(self, item, machine: mc.Handshake):
        """Feed the books what one inbox item says and return what the carrier does with it: an
        event of its machine (:class:`mission.carrier.DecisionHeard`,
        :class:`mission.carrier.EndHeard`), an effect (:class:`Rejoin`, :class:`Follow`,
        :class:`mission.carrier.Log`; :class:`mission.carrier.Reject` for a message it cannot
        read: its :class:`ProtocolError`'s reason and detail) or None. ``machine``: the carrier's
        machine now (a deposed coordinator's Decision names nothing, its Accepted tells no timers)."""
        try:
            return self._read(item, machine)
        except ProtocolError as exc:
            return mc.Reject(exc.reason, exc.detail)

    def _read(self, item, machine: mc.Handshake):
        """:meth:`read`, a message it cannot read raising :class:`ProtocolError`."""
        if item.kind == "wake":
            return None
        if item.kind in ("alive", "gone"):
            return self._token(item)
        parsed = keys.parse_carrier_key(self.mission, item.key)
        if parsed is not None and parsed[1] in PEER_TOPICS:
            self._peer(parsed[0], parsed[1], item.payload, item.received)
            return None
        if item.key == keys.end_key(self.mission):
            msg = self._ours(decode(item.payload, End))
            return mc.EndHeard(msg.epoch, msg.coordinator)  # a deposed coordinator's is rejected (mission.carrier)
        answer_type = {keys.refusal_key(self.mission, self.cid): Refusal,
                       keys.accepted_key(self.mission, self.cid): Accepted}.get(item.key)
        if answer_type is not None:
            return self._answer(self._ours(decode(item.payload, answer_type)), machine)  # on its own key only [P-2.4]
        if item.key != keys.decision_key(self.mission):
            raise ProtocolError("bad-key", f"message on {item.key[:80]}")
        msg = self._ours(self.broadcasts.decode(item.payload, Decision))  # once per process (SharedDecoder)
        if msg.stage < self.book.n_stages and mc.current(machine, msg.epoch, msg.coordinator):  # not a deposed coordinator's
            self.book.decision(msg.stage, msg.deploy)
        self.releases.name(machine, msg.stage, msg.epoch, msg.passenger_of(self.cid), msg.coordinator)
        return mc.DecisionHeard(msg.stage, msg.t, msg.deploy, self.position(), msg.epoch, msg.coordinator)

    def check_refused(self) -> None:
        """End the run when the coordinator refused its latest Hello
        (:func:`carriers.exits.refused_exit`: ``world-mismatch`` or ``refused``, logged)."""
        refused_exit(self.answer.refused, self.answer.fingerprint, self.log)

    def _ours(self, msg: Any) -> Any:
        """``msg``, checked to be of this mission."""
        if msg.mission != self.mission:
            raise ProtocolError("wrong-mission", f"mission {msg.mission!r}")
        return msg

    def _token(self, item):
        """A liveliness token appeared or vanished: a peer's, or the coordinator's (back:
        :class:`Rejoin`; gone: the on-board planner prepared when it may decide alone soon)."""
        parsed = keys.parse_carrier_key(self.mission, item.key)
        if parsed is not None and parsed[1] == "alive" and parsed[0] in self.book.index:
            self.presence.peer(parsed[0], item.kind == "alive")
            return None
        if item.key != keys.coordinator_alive(self.mission):
            raise ProtocolError("bad-key", f"liveliness token on {item.key[:80]}")
        if item.kind == "alive":
            return Rejoin() if self.presence.coordinator_alive() else None  # it came back
        self.presence.coordinator_gone(item.received)
        if self.mode == Mode.HYBRID:
            self.onboard.prepare()  # it may have to decide alone soon
        return mc.Log("coordinator's liveliness token vanished; "
                      + ("holding" if self.mode == Mode.COORDINATED else "deciding on board"))

    def _answer(self, msg, machine: mc.Handshake) -> Follow | None:
        """The coordinator's answer to a Hello. Only the answer to our latest Hello counts
        (docs/protocol.md, "Refusal"); one naming another fingerprint, or coming after our Hello
        was accepted, is about someone else's. An Accepted of our world tells the mission's clock
        (revision 4; an earlier coordinator's says nothing of it), unless a deposed coordinator
        sent it."""
        if msg.carrier != self.cid:
            raise ProtocolError("key-mismatch", f"answer for carrier {msg.carrier!r}")
        self.answer.answered(msg.fingerprint, msg if isinstance(msg, Refusal) else None)
        if (isinstance(msg, Accepted) and msg.fingerprint == self.answer.fingerprint
                and mc.current(machine, msg.epoch, msg.coordinator)
                and msg.revision >= 4):
            return Follow(mc.Timers(msg.clock, msg.silence_timeout_s, msg.realtime))
        return None

    def _peer(self, cid: str, topic: str, payload: bytes, at: float) -> None:
        """Another carrier's Observation, Own, Confirm or Progress, heard at ``at`` (the carrier's
        clock): what it saw and did, for the book, and when it was last heard [P-10.5]."""
        if cid == self.cid:
            return  # our own puts, delivered to our own subscription
        if cid not in self.book.index:
            raise ProtocolError("unknown-carrier", f"message from carrier {cid!r}")
        msg = self._ours(decode(payload, PEER_TOPICS[topic]))
        if msg.carrier != cid:
            raise ProtocolError("key-mismatch", f"carrier {msg.carrier!r} on the key of {cid!r}")
        self.presence.heard_from(cid, at)
        if topic == "progress":
            self.book.progress(cid, msg.stage)  # a peer past a stage is not waited for there
            return
        if not self.book.accepts(msg.stage):
            raise ProtocolError("out-of-range", f"stage {msg.stage} >= {self.book.n_stages}")
        if topic in ("obs", "own"):
            self.book.observation(cid, msg.stage, msg.x, msg.counts)
        if topic in ("own", "confirm"):
            self.book.outcome(cid, msg.stage, msg.deployed)
