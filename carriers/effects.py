"""What a carrier does for its machines' effects that is I/O and nothing else: a passenger
released (its body, its robot's launcher), an observation or an outcome in its durable log and
its book, a message sent (Hello, Confirm, Own, its Observation again), a message rejected, a line
logged, its peers listened to; both machines' in one place (:meth:`CarrierEffects.carry_out`).

:class:`CarrierEffects` is a collaborator of :class:`carriers.node.Carrier`, given what it needs
when it is built and, while the carrier runs, its durable log and its ROS 2 node; it is handed
the wire node and the handshake machine at each call and changes nothing of the carrier's
(its machines and its timers change only in the carrier).
"""
from __future__ import annotations

import time

from carriers.motion import Motion
from carriers.who import Who
from mission import carrier as mc
from mission import carrier_life as cl
from mission.peers import PeerBook
from storage.carrierlog import CarrierLog


def record(store: CarrierLog | None, book: PeerBook, who: Who, effect, counts) -> None:
    """A :class:`mission.carrier.LogObservation` or :class:`mission.carrier.LogOutcome`: in the
    durable log (``store``, None: none) before the carrier acts on it, and in its book."""
    t = who.scenario.stage_time(effect.stage)
    if isinstance(effect, mc.LogObservation):
        if store is not None:
            store.observed(effect.stage, t, effect.x, effect.position)
        book.observation(who.cid, effect.stage, effect.x, counts)
        return
    if store is not None:
        store.outcome(effect.stage, t, effect.status, effect.deployed, effect.position, effect.passengers_left,
                      time.time())
    book.outcome(who.cid, effect.stage, effect.deployed)


class CarrierEffects:
    """A carrier's hands on the world.

    Args:
        who: which carrier of which mission (:class:`carriers.who.Who`: the messages it sends);
        motion: its :class:`carriers.motion.Motion` (its body, the Observation it keeps, the
        region counts behind what it sensed); inbound: its ``carriers.inbound.Inbound`` (its
        books: the passengers Decisions named, its Hello's answer, the
        :class:`mission.peers.PeerBook`); clock: its clock (when a Hello was sent); log: a
        callable taking one line.
    """

    def __init__(self, who: Who, motion: Motion, inbound, clock, log):
        self.who, self.motion, self.inbound, self.clock, self.log = who, motion, inbound, clock, log
        self.store: CarrierLog | None = None  # the durable log, open while running
        self.ros2 = None  # its ROS 2 node (ros2/publisher.py) while running with config.ros2

    def carry_out(self, effect, node, machine: mc.Handshake) -> None:
        """One I/O effect of the handshake machine (:func:`mission.carrier.step`) or of the
        lifecycle (:func:`mission.carrier_life.step`: its Observation sent again, its peers
        listened to, a note; the end, ``Finish``, is nothing to carry out: its reason is the
        lifecycle's), sent on ``node``, ``machine`` the handshake machine now."""
        if isinstance(effect, mc.Deploy):
            self.motion.body.deploy(self.who.cid)
            released = self.inbound.releases.release(effect.stage)
            if self.ros2 is not None:  # a robot's launcher gets the command
                self.ros2.release(effect.stage, released)
        elif isinstance(effect, mc.SendConfirm):
            node.put(*self.who.confirm(effect, self.inbound.releases.at(effect.stage)))
        elif isinstance(effect, (mc.LogObservation, mc.LogOutcome)):
            record(self.store, self.inbound.book, self.who, effect,
                   self.motion.counts(effect.stage, getattr(effect, "x", None)))
        elif isinstance(effect, mc.SendOwn):
            node.put(*self.who.own(effect, self.motion.counts(effect.stage, effect.x)))
        elif isinstance(effect, mc.SendHello):
            self.inbound.answer.sent(self.clock(), effect.again)
            node.put(*self.who.hello(effect, machine.passengers_left, machine.epoch))
        elif isinstance(effect, (mc.ResendObservation, cl.RepeatObservation)):
            pending = self.motion.pending
            if pending is not None and pending.stage == effect.stage:
                node.put(self.who.key("obs"), pending)
        elif isinstance(effect, mc.Reject):
            node.reject(effect.reason, effect.detail, self.log)
        elif isinstance(effect, cl.Listen):
            self.inbound.listen(node, wait=True)
        elif isinstance(effect, (mc.Log, cl.Note)):
            self.log(effect.line)
