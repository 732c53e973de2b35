"""What the coordinator receives: its inbox (the carriers' messages on their keys, their
liveliness tokens, Decisions on the mission's decision key) checked at the wire level (key
layout, decoding, mission id, the carrier id in the key) and turned into what each says
(:class:`Heard`: a mission event, the carrier heard from, a higher epoch it heard); a message it
cannot read is rejected (and a Hello it cannot read is answered).

:class:`Inbound` is a collaborator of :class:`coordinator.node.Coordinator`, given what it needs
when it is built; it hands a Decision on the decision key to the split-brain collaborator
(``coordinator.epochs.Epochs``) and a Pose to the recorder (``coordinator.recorder.Recording``),
and changes nothing of the coordinator's: it yields what it reads, and the coordinator takes
it (:meth:`coordinator.node.Coordinator.pump`).
"""
from __future__ import annotations

from typing import Any, NamedTuple

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



#: At most this many inbox items share one mission.db commit (:meth:`Inbound.arrivals`).
BATCH_MAX = 1024


class Heard(NamedTuple):
    """What one inbox item says (:meth:`Inbound.read`).

    Attributes:
        event: its mission event (None: none).
        carrier: the carrier it came from, heard at ``at`` (the inbox's clock, s) [P-10.5];
            None: no carrier's message.
        progress: a Progress of this stage (None: not a Progress): heard only while the stage it
            names is not past the stage collected (one past it sends nothing more for that stage:
            its silence ends the wait; found by mission.simulate).
        epoch: the epoch a Hello of its world claims above this coordinator's: on record, never
            adopted [P-7.3] (None: none).
    """

    event: Any = None
    carrier: str | None = None
    at: float = 0.0
    progress: int | None = None
    epoch: int | None = None


class Unreadable(NamedTuple):
    """An inbox item the coordinator cannot read (:meth:`Inbound.arrivals`): rejected for
    ``reason`` (``detail``), of carrier ``carrier`` (None: no carrier's key); a Hello among them
    is refused too (``refuse``, in the ``revision`` it announced; None: not a Hello)."""

    reason: str
    detail: str
    carrier: str | None = None
    refuse: ms.Refuse | None = None
    revision: int = 0


class Inbound:
    """The coordinator's receiving side.

    Args:
        mission: the mission id; has(cid): whether ``cid`` is one of its carriers; fingerprint:
        its world's; epochs: its ``coordinator.epochs.Epochs``; recording: its
        ``coordinator.recorder.Recording``.
    """

    def __init__(self, mission: str, has, fingerprint: str, epochs, recording):
        self.mission, self.has, self.fingerprint = mission, has, fingerprint
        self.epochs, self.recording = epochs, recording
        # When each carrier was last heard (the coordinator's clock, s): a slow one (Progress) or
        # a stuck one, sim clock [P-10.5]; what the stage clock's waits read.
        self.heard: dict[str, float] = {}

    def subscribe(self, node) -> None:
        """The inbox's keys on ``node``: the carriers' messages and tokens, the mission's
        Decisions (a newer epoch's deposes this coordinator)."""
        node.subscribe(f"{keys.prefix(self.mission)}/carrier/**")
        node.subscribe(keys.decision_key(self.mission))
        node.watch_liveliness(keys.carrier_alive_pattern(self.mission))

    def note(self, heard: Heard, stage: int) -> None:
        """What one item it read tells of its sender: when its carrier was heard (when it arrived
        [P-10.5]; a Progress only while the stage it names is not past ``stage``, the stage
        collected: see :class:`Heard`), and the higher epoch it claims, on record
        (:meth:`coordinator.epochs.Epochs.carrier_claimed`, never adopted [P-7.3])."""
        if heard.carrier is not None and (heard.progress is None or heard.progress <= stage):
            self.heard[heard.carrier] = heard.at
        if heard.epoch is not None:
            self.epochs.carrier_claimed(heard.carrier, heard.epoch)

    def arrivals(self, node, timeout_s: float, store):
        """What arrived on ``node``, one item at a time, waiting up to ``timeout_s`` for the
        first: what each says (:class:`Heard`, from :meth:`read`), or :class:`Unreadable` for one
        it cannot read; every queued item is read before it returns. The coordinator takes them
        in one mission.db batch (``store``: :meth:`storage.missiondb.MissionStore.batch`); a long
        burst is committed in parts, every :data:`BATCH_MAX` items. With Poses set aside and an
        empty inbox, record them instead of waiting, until an item arrives
        (:meth:`coordinator.recorder.Recording.record_poses`)."""
        item = node.next(0.0 if self.recording.poses else max(0.0, timeout_s))
        if item is None:
            self.recording.record_poses(busy=node.pending)
            return
        handled = 0
        while item is not None:
            try:
                heard = self.read(item)
            except ProtocolError as exc:
                heard = self._unreadable(item, exc)
            if heard is not None:
                handled += 1
                if handled % BATCH_MAX == 0:
                    store.flush()  # the items before it committed together
                yield heard
            item = node.next(0.0)

    def take(self, heard: Heard | Unreadable, state: ms.MissionState):
        """What the coordinator does with one item of :meth:`arrivals` in mission state ``state``:
        its mission event to apply, its sender noted first (:meth:`note`); for a higher epoch
        claimed by a carrier already accepted, the :class:`mission.state.Accept` its Hello gets
        instead ([P-7.3]: answered, it changes nothing held of the carrier); an
        :class:`Unreadable` as it is (rejected, a Hello among them refused); None: nothing."""
        if isinstance(heard, Unreadable):
            return heard
        self.note(heard, state.next_stage)
        if heard.epoch is not None and heard.carrier in state.accepted:
            return ms.Accept(heard.carrier, state.next_stage, heard.event.revision)
        return heard.event

    def _unreadable(self, item, exc: ProtocolError) -> Unreadable:
        parsed = keys.parse_carrier_key(self.mission, item.key) if item.kind == "sample" else None
        if parsed is None:
            return Unreadable(exc.reason, exc.detail)
        cid, topic = parsed
        if topic != "hello":
            return Unreadable(exc.reason, exc.detail, cid)
        revision, fp = announced(item.payload)  # a Hello it could not read is answered too
        return Unreadable(exc.reason, exc.detail, cid, ms.Refuse(cid, fp, exc.reason, exc.detail), revision)

    def read(self, item) -> Heard | None:
        """What one inbox item says (wire-level checks only here: key layout, decoding, mission
        id, the carrier id in the key); None: nothing for the coordinator (its own token, a
        Decision: :meth:`coordinator.epochs.Epochs.decision_heard`, a Pose: set aside for the
        recorder). Raises :class:`ProtocolError`."""
        if item.kind in ("alive", "gone"):
            if item.key == keys.coordinator_alive(self.mission):
                return None
            parsed = keys.parse_carrier_key(self.mission, item.key)
            if parsed is None or parsed[1] != "alive":
                raise ProtocolError("bad-key", f"liveliness token on {item.key[:80]}")
            return Heard(ev.LivelinessChanged(parsed[0], item.kind == "alive", item.wall))
        if item.key == keys.decision_key(self.mission):
            self.epochs.decision_heard(item.payload)
            return None
        parsed = keys.parse_carrier_key(self.mission, item.key)
        if parsed is not None and parsed[1] == "pose":
            self.recording.pose(parsed[0], item)
            return None
        if parsed is None or parsed[1] not in TOPIC_TYPES:
            raise ProtocolError("bad-key", f"message on {item.key[:80]}")
        cid, topic = parsed
        if not self.has(cid):
            raise ProtocolError("unknown-carrier", f"message from carrier {cid!r}")
        msg: Any = decode(item.payload, TOPIC_TYPES[topic])
        if msg.mission != self.mission:
            raise ProtocolError("wrong-mission", f"mission {msg.mission!r} on {self.mission!r}")
        if msg.carrier != cid:
            raise ProtocolError("key-mismatch", f"carrier {msg.carrier!r} on the key of {cid!r}")
        if isinstance(msg, Progress):
            return Heard(carrier=cid, at=item.received, progress=msg.stage)
        newer = isinstance(msg, Hello) and msg.epoch > self.epochs.epoch and msg.fingerprint == self.fingerprint
        return Heard(to_event(msg, item.wall), cid, item.received, epoch=msg.epoch if newer else None)
