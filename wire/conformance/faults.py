"""The scripted coordinator side of a conformance flight: the kit's deliberate faults, each made
once, triggered by what the carrier under test has just sent."""
from __future__ import annotations

import time

from .. import keys
from .. import messages as wm
from .flight import Flight, Observer, Seen, Target
from .harness import Harness

#: Every fault the kit can make, with what it does (the command line's help prints these).
FAULT_TEXT = {
    "late": "the coordinator is frozen (SIGSTOP) for --late seconds once the carrier has sent its "
            "Observation of stage 1: that Decision comes late",
    "duplicate": "the Decision of stage 0 is published again once the carrier has answered it",
    "restart": "the coordinator is killed (SIGKILL) once the carrier has answered stage 1, and "
               "restarted on its mission.db: epoch 2",
    "deposed": "after the restart, once the carrier has shown it heard epoch 2, the coordinator is "
               "frozen and a Decision of epoch 1 for the stage the carrier waits at, selecting it, "
               "is published (tried at a later stage if the real one came first)",
}
FAULTS = tuple(FAULT_TEXT)
SETTLE_S = 1.0  # loopback delivers a Decision already published well within this, on a busy host too (deposed fault)
DEPOSED_FREEZE_S = 1.5  # the coordinator stays frozen this long after the fake Decision


class Faults:
    """Makes the faults of ``enabled`` (a subset of :data:`FAULTS`), each once, recording in
    ``flight.faults`` the stage and the time (or window) of each.

    Args:
        target: the carrier under test.
        flight: what has been seen so far (the triggers read it).
        harness: the coordinator process to freeze or restart, the router to publish on.
        observer: records what arrives while the kit waits; banks the coordinator's rejection
            counts at a restart.
        enabled: the faults to make.
        late_s: how long the late Decision is late, seconds.
    """

    def __init__(self, target: Target, flight: Flight, harness: Harness, observer: Observer,
                 enabled: tuple[str, ...], late_s: float):
        self.target, self.flight, self.harness, self.observer = target, flight, harness, observer
        self.enabled, self.late_s = tuple(enabled), float(late_s)
        self.restarted = False

    def _due(self, fault: str) -> bool:
        return fault in self.enabled and fault not in self.flight.faults

    def react(self, seen: Seen) -> None:
        """The carrier under test just sent ``seen`` (an Observation or a Confirm): make the first
        fault it triggers, if any."""
        f, t, h = self.flight, self.target, self.harness
        msg = seen.message
        if self._due("late") and isinstance(msg, wm.Observation) and msg.stage == 1 and t.n > 1 and not f.decided(1):
            h.freeze(self.late_s)
            f.faults["late"] = (1, time.monotonic())
        elif self._due("duplicate") and isinstance(msg, wm.Confirm) and msg.stage == 0 and f.decided(0):
            original = next(d for d in f.decisions if d.message.stage == 0 and not d.fake)
            h.node.put_raw(keys.decision_key(t.mission), original.payload)
            f.faults["duplicate"] = (0, time.monotonic())
        elif (self._due("restart") and isinstance(msg, wm.Confirm) and msg.stage == 1 and t.n > 2
              and not h.frozen and msg.status != "already"):
            h.restart_coordinator()
            self.observer.bank_rejections()
            self.restarted = True
            f.faults["restart"] = (1, time.monotonic())
        elif (self._due("deposed") and self.restarted and f.coordinator_back and isinstance(msg, wm.Observation)
              and seen.at > f.coordinator_back[0] and not h.frozen and f.heard_epoch(2)):
            self._depose(msg.stage)

    def _depose(self, stage: int) -> None:
        """Freeze the coordinator and publish a Decision of epoch 1 for ``stage`` selecting the
        carrier, unless the real Decision was already on its way (then resume: a later stage)."""
        f, t, h = self.flight, self.target, self.harness
        if f.decided(stage):
            return
        h.freeze()
        self.observer.settle(SETTLE_S)
        if f.decided(stage):  # sent before the stop: try again at a later stage
            h.thaw()
            return
        fake = wm.Decision(t.mission, stage, t.times[stage], (t.cid,), 0.0, epoch=1)
        payload = wm.encode(fake, 1)
        f.decisions.append(Seen(time.monotonic(), "decision", payload, fake, fake=True))
        h.node.put_raw(keys.decision_key(t.mission), payload)
        h.thaw_after(DEPOSED_FREEZE_S)
        assert h.thaw_at is not None
        f.faults["deposed"] = (stage, (time.monotonic(), h.thaw_at))
