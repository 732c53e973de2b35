"""What the coordinator receives: its inbox (the carriers' messages on their keys, their
liveliness tokens, Decisions on the mission's decision key) checked at the wire level (key
layout, decoding, mission id, the carrier id in the key), turned into mission events and applied;
a message it cannot read is rejected (and a Hello it cannot read is answered).

:class:`Inbound` is a part of :class:`coordinator.node.Coordinator`.
"""
from __future__ import annotations

from mission import events as ev
from mission import state as ms
from wire import keys
from wire.messages import Bye, Confirm, Hello, Observation, Own, Progress, ProtocolError, announced, decode

#: Which message type each carrier topic carries.
TOPIC_TYPES = {"hello": Hello, "obs": Observation, "confirm": Confirm, "own": Own, "bye": Bye,
               "progress": Progress}


def to_event(msg, at: float):
    """The mission event of a decoded carrier message received at ``at`` (s, epoch)."""
    if isinstance(msg, Hello):
        return ev.Hello(msg.carrier, msg.pid, msg.host, msg.passengers_left, msg.next_stage, msg.fingerprint, at,
                        msg.revision)
    if isinstance(msg, Observation):
        return ev.Observation(msg.carrier, msg.stage, msg.t, msg.x, msg.position, msg.passengers_left, msg.trail, at,
                              msg.counts)
    if isinstance(msg, Confirm):
        return ev.Confirmed(msg.carrier, msg.stage, msg.deployed, msg.status, msg.position, msg.passengers_left, at,
                            msg.passenger)
    if isinstance(msg, Own):
        return ev.Accounted(msg.carrier, msg.stage, msg.t, msg.x, msg.deployed, msg.position, msg.passengers_left, at,
                            msg.counts)
    if isinstance(msg, Bye):
        return ev.Bye(msg.carrier, msg.deployments, msg.rejected, msg.reason, at)
    raise TypeError(type(msg).__name__)



#: At most this many inbox items share one mission.db commit (:meth:`Inbound.pump`).
BATCH_MAX = 1024


class Inbound:
    """The coordinator's receiving side."""

    def pump(self, timeout_s: float) -> None:
        """Wait up to ``timeout_s`` seconds for inbox items, then handle every queued one, their
        writes to mission.db committed together (storage.missiondb, :meth:`MissionStore.batch`).
        With Poses set aside and an empty inbox, record them instead of waiting, until an item
        arrives (:meth:`coordinator.recorder.Recording.record_poses`)."""
        item = self.node.next(0.0 if self.recording.poses else max(0.0, timeout_s))
        if item is None:
            self.recording.record_poses(busy=self.node.pending)
            return
        if self.store is None:
            self._drain(item)
            return
        with self.store.batch():
            self._drain(item)

    def _drain(self, item) -> None:
        handled = 0
        while item is not None:
            handled += 1
            if handled % BATCH_MAX == 0 and self.store is not None:
                self.store.flush()  # a long burst is committed in parts
            try:
                self._handle(item)
            except ProtocolError as exc:
                parsed = keys.parse_carrier_key(self.mission, item.key) if item.kind == "sample" else None
                self._reject(exc.reason, exc.detail, parsed[0] if parsed else None)
                if parsed is not None and parsed[1] == "hello":  # a Hello it could not read: answered too
                    revision, fp = announced(item.payload)
                    self._answer_hello(parsed[0], revision, ms.Refuse(parsed[0], fp, exc.reason, exc.detail))
            item = self.node.next(0.0)

    def _handle(self, item) -> None:
        """Decode one inbox item into a mission event and apply it (wire-level checks only here:
        key layout, decoding, mission id, the carrier id in the key)."""
        if item.kind in ("alive", "gone"):
            if item.key == keys.coordinator_alive(self.mission):
                return
            parsed = keys.parse_carrier_key(self.mission, item.key)
            if parsed is None or parsed[1] != "alive":
                raise ProtocolError("bad-key", f"liveliness token on {item.key[:80]}")
            self.apply(ev.LivelinessChanged(parsed[0], item.kind == "alive", item.wall))
            return
        if item.key == keys.decision_key(self.mission):
            self.epochs.decision_heard(item.payload)
            return
        parsed = keys.parse_carrier_key(self.mission, item.key)
        if parsed is not None and parsed[1] == "pose":
            self.recording.pose(parsed[0], item)
            return
        if parsed is None or parsed[1] not in TOPIC_TYPES:
            raise ProtocolError("bad-key", f"message on {item.key[:80]}")
        cid, topic = parsed
        if not self.spec.has(cid):
            raise ProtocolError("unknown-carrier", f"message from carrier {cid!r}")
        msg = decode(item.payload, TOPIC_TYPES[topic])
        if msg.mission != self.mission:
            raise ProtocolError("wrong-mission", f"mission {msg.mission!r} on {self.mission!r}")
        if msg.carrier != cid:
            raise ProtocolError("key-mismatch", f"carrier {msg.carrier!r} on the key of {cid!r}")
        if isinstance(msg, Progress):
            if msg.stage <= self.state.next_stage:  # one past the stage collected sends nothing more for it:
                self.heard[cid] = item.received  # its silence ends the wait (found by mission.simulate)
            return
        self.heard[cid] = item.received  # heard when it arrived [P-10.5]
        if isinstance(msg, Hello) and msg.epoch > self.epochs.epoch and msg.fingerprint == self.fingerprint:
            if self.epochs.carrier_heard(cid, msg.epoch, self.state.next_stage, self.store):
                self._refresh_state()  # State and the last Decision again, in the new epoch [P-7.5]
                if self.state.next_stage > 0:
                    self._publish_decision(self._decision(self.state.next_stage - 1))
        self.apply(to_event(msg, item.wall))
