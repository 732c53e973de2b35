"""What a carrier receives: its inbox (the coordinator's Decisions, End, the answers to its
Hello, liveliness tokens) and the messages of the peers it listens to, decoded and turned into
events of ``mission.carrier`` or facts for its :class:`mission.peers.PeerBook` and
:class:`mission.peers.Presence`.

:class:`Inbound` is a part of :class:`carriers.node.Carrier`.
"""
from __future__ import annotations

from mission import carrier as mc
from wire import keys
from wire.messages import Accepted, Confirm, Decision, End, Observation, Own, Progress, ProtocolError, Refusal, decode

#: What peers publish that a carrier reads, and the message type of each.
PEER_TOPICS = {"obs": Observation, "own": Own, "confirm": Confirm, "progress": Progress}


class Inbound:
    """The carrier's receiving side."""

    def _listen(self, wait: bool = False) -> None:
        """Subscribe to the carriers this one listens to (:func:`mission.peers.listened`: its
        conflict component, or its neighbours in a large one) once the on-board planner's
        instance is built (``wait``: build it now)."""
        if self.listening is not None or self.config.mode == "coordinated" or not (wait or self.onboard.ready()):
            return
        ids = self.scenario.carrier_ids
        self.listening = tuple(ids[b] for b in self.onboard.listened(self.r))
        for cid in self.listening:
            for topic in PEER_TOPICS:  # read when the carrier next looks: no wake-up per message
                self.node.subscribe(keys.carrier_key(self.mission, cid, topic), wake=False)
            self.node.watch_liveliness(keys.carrier_alive(self.mission, cid))

    def _pump(self, timeout_s: float) -> None:
        """Handle what arrived: the inbox (waiting up to ``timeout_s`` for its first item), then
        the peers' messages waiting in their channels."""
        if self.listening is None:
            self._listen()
        item = self.node.next(timeout_s)
        while item is not None:
            self._handle_safely(item)
            item = self.node.next(0.0)
        for item in self.node.drain():
            self._handle_safely(item)

    def _handle_safely(self, item) -> None:
        try:
            self._handle(item)
        except ProtocolError as exc:
            self.node.reject(exc.reason, exc.detail, self.log)

    def _handle(self, item) -> None:
        if item.kind == "wake":
            return
        if item.kind in ("alive", "gone"):
            parsed = keys.parse_carrier_key(self.mission, item.key)
            if parsed is not None and parsed[1] == "alive" and parsed[0] in self.book.index:
                self.presence.peer(parsed[0], item.kind == "alive")
                return
            if item.key != keys.coordinator_alive(self.mission):
                raise ProtocolError("bad-key", f"liveliness token on {item.key[:80]}")
            if item.kind == "alive":
                if self.presence.coordinator_alive():  # it came back
                    self.apply(mc.Resync(self.queries.seen(self.queries.once(self.node)), self.motion.position()))
            else:
                self.presence.coordinator_gone(item.received)
                if self.config.mode == "hybrid":
                    self.onboard.prepare()  # it may have to decide alone soon
                self.log("coordinator's liveliness token vanished; "
                         + ("holding" if self.config.mode == "coordinated" else "deciding on board"))
            return
        parsed = keys.parse_carrier_key(self.mission, item.key)
        if parsed is not None and parsed[1] in PEER_TOPICS:
            self._peer(parsed[0], parsed[1], item.payload, item.received)
            return
        if item.key == keys.end_key(self.mission):
            msg = decode(item.payload, End)
            if msg.mission != self.mission:
                raise ProtocolError("wrong-mission", f"mission {msg.mission!r}")
            self.apply(mc.EndHeard(msg.epoch))  # a deposed coordinator's is rejected (mission.carrier)
            return
        answer_type = {keys.refusal_key(self.mission, self.cid): Refusal,
                       keys.accepted_key(self.mission, self.cid): Accepted}.get(item.key)
        if answer_type is not None:
            msg = decode(item.payload, answer_type)  # each answer on its own key only [P-2.4]
            if msg.mission != self.mission:
                raise ProtocolError("wrong-mission", f"mission {msg.mission!r}")
            if msg.carrier != self.cid:
                raise ProtocolError("key-mismatch", f"answer for carrier {msg.carrier!r}")
            # Only the answer to our latest Hello counts (docs/protocol.md, "Refusal"); one naming
            # another fingerprint, or coming after our Hello was accepted, is about someone else's.
            self.answer.answered(msg.fingerprint, msg if isinstance(msg, Refusal) else None)
            if isinstance(msg, Accepted) and msg.fingerprint == self.fingerprint:
                self._follow_clock(msg)
            return
        if item.key != keys.decision_key(self.mission):
            raise ProtocolError("bad-key", f"message on {item.key[:80]}")
        msg = self.broadcasts.decode(item.payload, Decision)  # once per process (wire.messages.SharedDecoder)
        if msg.mission != self.mission:
            raise ProtocolError("wrong-mission", f"mission {msg.mission!r}")
        if msg.stage < self.n_stages and mc.current(self.machine, msg.epoch):  # not a deposed coordinator's
            self.book.decision(msg.stage, msg.deploy)
        self.releases.name(self.machine, msg.stage, msg.epoch, msg.passenger_of(self.cid))
        self.apply(mc.DecisionHeard(msg.stage, msg.t, msg.deploy, self.motion.position(), msg.epoch))

    def _follow_clock(self, msg: Accepted) -> None:
        """The mission's clock from an Accepted (revision 4; an earlier coordinator's says
        nothing of it): the carrier's timers follow it (:func:`mission.carrier.follow`), unless
        a deposed coordinator sent it."""
        if not mc.current(self.machine, msg.epoch):
            return
        told = mc.Timers(msg.clock, msg.silence_timeout_s, msg.realtime) if msg.revision >= 4 else None
        robot = getattr(self.ros2, "robot", None) is not None
        self.timers, lines = mc.follow(self.timers, told, repace=not robot)
        for line in lines:
            self.log(line)

    def _peer(self, cid: str, topic: str, payload: bytes, at: float) -> None:
        """Another carrier's Observation, Own, Confirm or Progress, heard at ``at`` (the carrier's
        clock): what it saw and did, for the book, and when it was last heard [P-10.5]."""
        if cid == self.cid:
            return  # our own puts, delivered to our own subscription
        if cid not in self.book.index:
            raise ProtocolError("unknown-carrier", f"message from carrier {cid!r}")
        msg = decode(payload, PEER_TOPICS[topic])
        if msg.mission != self.mission:
            raise ProtocolError("wrong-mission", f"mission {msg.mission!r}")
        if msg.carrier != cid:
            raise ProtocolError("key-mismatch", f"carrier {msg.carrier!r} on the key of {cid!r}")
        self.presence.heard_from(cid, at)
        if topic == "progress":
            self.book.progress(cid, msg.stage)  # a peer past a stage is not waited for there
            return
        if msg.stage >= self.n_stages:
            raise ProtocolError("out-of-range", f"stage {msg.stage} >= {self.n_stages}")
        if topic in ("obs", "own"):
            self.book.observation(cid, msg.stage, msg.x, msg.counts)
        if topic in ("own", "confirm"):
            self.book.outcome(cid, msg.stage, msg.deployed)
