"""What a carrier's lifecycle asks of it at a stage, between driving its body there and moving
on: sense and publish its Observation, pass a stage decided without it, move on (its process's
stage gate), decide a stage on board, say its Hello again.

:class:`StageWork` is a collaborator of :class:`carriers.node.Carrier`, given its parts when it
is built and the wire node and the handshake machine at each call. It calls nothing back: each
piece of work is a generator of the handshake events it asks the carrier to apply
(:class:`mission.joins.Apply`, answered with the machine after it), carried out with
:func:`mission.timers.drive` as a join path's are.
"""
from __future__ import annotations

from carriers.alone import Alone
from carriers.motion import Motion
from carriers.shared import GATE_HOLD_S, StageGate
from carriers.who import Who
from mission import carrier as mc
from mission import carrier_life as cl
from mission import joins
from mission.joins import Steps

#: The lifecycle's effects that are a stage's work (:meth:`StageWork.steps`).
WORK = (cl.Observe, cl.Pass, cl.MoveOn, cl.DecideOnBoard, cl.SayHelloAgain)


class StageWork:
    """A carrier's work at a stage.

    Args:
        who: which carrier of which mission (:class:`carriers.who.Who`); motion: its
        :class:`carriers.motion.Motion` (what it senses, the Observation it keeps, where it is);
        gate: its process's :class:`carriers.shared.StageGate`; alone: its
        :class:`carriers.alone.Alone` (the on-board decision).
    """

    def __init__(self, who: Who, motion: Motion, gate: StageGate, alone: Alone):
        self.who, self.motion, self.gate, self.alone = who, motion, gate, alone

    def steps(self, effect, node, machine: mc.Handshake) -> Steps:
        """The work of one lifecycle effect of :data:`WORK` (``node``: its wire node; ``machine``:
        the handshake machine now): the events it asks the carrier to apply, in order."""
        j = getattr(effect, "stage", None)
        if isinstance(effect, cl.Observe):
            x = self.motion.observe(j, self.who, machine.passengers_left)  # sensed, kept
            yield joins.Apply(mc.Observed(j, x, self.motion.position()))
            node.put(self.who.key("obs"), self.motion.pending)  # then it waits for the stage's decision
            self.gate.waiting(j)
        elif isinstance(effect, cl.Pass):
            # decided without its Observation (cut off, or too slow): ∅ for it; publishing it would
            # only be rejected as stale; its decision answered if it reached it
            yield joins.Apply(mc.Passed(j, self.motion.position()))
        elif isinstance(effect, cl.MoveOn):
            self.gate.answered(j)
            if effect.answered:
                self.gate.hold(j, GATE_HOLD_S)  # the process's other carriers confirm first
            yield joins.Apply(mc.MovedOn(j))
            self.motion.pending = None
        elif isinstance(effect, cl.DecideOnBoard):
            yield joins.Apply(mc.DecidedOwn(j, self.alone.deploy(j), self.motion.position()))
        elif isinstance(effect, cl.SayHelloAgain):
            yield joins.Apply(mc.HelloUnanswered(self.motion.position()))
