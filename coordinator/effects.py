"""What the coordinator does for its machines' effects that is I/O and nothing else: an event
recorded in mission.db (the recorder's copy once mission.db has it), a message rejected (one it
cannot read among them), a Hello answered, a Decision or End published, a line logged.

:class:`MissionEffects` is a collaborator of :class:`coordinator.node.Coordinator`, given what it
needs when it is built and the session and mission.db when the mission opens (:meth:`open`); it
is handed the mission state at each call and changes nothing of the coordinator's: where an
effect is followed by an event of the mission (a Decision published: ``Published``) it returns
that event, and the coordinator applies it.
"""
from __future__ import annotations

import time

from coordinator.answers import Answers
from coordinator.clock import progress_line
from coordinator.inbound import Unreadable
from coordinator.recorder import Recording
from mission import coordinator_life as cl
from mission import events as ev
from mission import state as ms
from storage.missiondb import MissionStore
from wire import keys
from wire.messages import REVISION, End
from wire.transport import Node


class MissionEffects:
    """The coordinator's hands on the world.

    Args:
        mission: the mission id; spec: its mission machine's spec (for the stage's progress
        line); answers: its :class:`coordinator.answers.Answers`; recording: its
        :class:`coordinator.recorder.Recording`; log: where lines go.
    """

    def __init__(self, mission: str, spec: ms.MissionSpec, answers: Answers, recording: Recording, log):
        self.mission, self.spec, self.answers, self.recording, self.log = mission, spec, answers, recording, log
        self.node: Node | None = None  # the session, once the mission opens (None: stopped before it opened)
        self.store: MissionStore | None = None  # mission.db, once the mission opens
        self.end_message: End | None = None  # the End it repeats, once recorded

    def open(self, node: Node | None, store: MissionStore) -> None:
        """The mission's session and mission.db, opened (:func:`coordinator.opening.open_mission`)."""
        self.node, self.store = node, store

    # ------------------------------------------------------------------ of its mission state
    def carry_out(self, effect, state: ms.MissionState, carrier: str | None = None) -> ev.Published | None:
        """One effect of :func:`mission.state.step` or of what the inbox said
        (:meth:`coordinator.inbound.Inbound.take`: an item it cannot read, a claim's answer),
        ``state`` the state that step made (or the state now) and ``carrier`` the carrier of the
        event stepped (a rejection's); the event that follows it (``Published``, the coordinator
        applies it at once), or None."""
        if isinstance(effect, ms.Record):  # the recorder gets it once mission.db has it
            self.store.record(effect, state, self.recording.event)
        elif isinstance(effect, ms.Reject):
            self.reject(effect.reason, effect.detail, carrier)
        elif isinstance(effect, Unreadable):
            self.unreadable(effect, state)
        elif isinstance(effect, (ms.Refuse, ms.Accept)):
            self.answer_hello(state, effect.carrier, effect.revision, effect if isinstance(effect, ms.Refuse) else None)
        elif isinstance(effect, ms.Publish):
            self.answers.serve(state)
            return self.publish_decision(state, effect.stage)
        elif isinstance(effect, ms.Log):
            self.log(effect.line)
        return None

    def reject(self, reason: str, detail: str, cid: str | None = None) -> None:
        """A message rejected (counted and logged by the session, the first of its reason in
        mission.db), and what State tells its carrier (docs/protocol.md, "Rejections")."""
        first = reason not in self.node.rejected
        self.node.reject(reason, detail, lambda line: self.log(f"coordinator: {line}"))
        if first:
            self.store.event("rejected", reason=reason, detail=detail[:200])
        self.answers.rejected(cid, reason)

    def unreadable(self, item: Unreadable, state: ms.MissionState) -> None:
        """An inbox item it cannot read (:class:`coordinator.inbound.Unreadable`): rejected, and
        a Hello among them refused."""
        self.reject(item.reason, item.detail, item.carrier)
        if item.refuse is not None:
            self.answer_hello(state, item.carrier, item.revision, item.refuse)

    def answer_hello(self, state: ms.MissionState, cid: str, revision: int, refused: ms.Refuse | None = None) -> None:
        """Every Hello is answered, once it is on record (:meth:`coordinator.answers.Answers.hello`)."""
        self.store.flush()
        answer = self.answers.hello(state, cid, revision, refused)
        if answer is not None:
            self.node.put(*answer)

    def publish_decision(self, state: ms.MissionState, j: int) -> ev.Published:
        """The Decision of stage j, on record, published: the event that says so."""
        # In the revision every carrier that said Hello reads (docs/protocol.md, "Compatibility").
        self.store.flush()
        self.node.put(keys.decision_key(self.mission), self.answers.decision(state, j),
                      state.common_revision(REVISION))
        return ev.Published(j, time.time())

    # ------------------------------------------------------------------ of its lifecycle
    def end_recorded(self, state: ms.MissionState, reason: str, epochs) -> None:
        """The End it repeats, once ``Ended`` is on record (``state`` after it), with its ballot
        (``epochs``: revision 4, a carrier ignores a deposed coordinator's End)."""
        self.end_message = End(self.mission, state.next_stage,
                               state.end_reason or reason, epochs.epoch, epochs.ident)

    def life(self, effect, state: ms.MissionState) -> None:
        """One I/O effect of :func:`mission.coordinator_life.step`: the stage's progress line,
        End published (in the revision every carrier that said Hello reads, as the Decisions
        are), a note."""
        if isinstance(effect, cl.StageLine):
            self.log(progress_line(self.spec, state, effect.stage, effect.waited_ms))
        elif isinstance(effect, cl.PublishEnd) and self.end_message is not None:
            self.node.put(keys.end_key(self.mission), self.end_message, state.common_revision(REVISION))
        elif isinstance(effect, cl.Note):
            self.log(effect.line)
