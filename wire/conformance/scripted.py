"""The kit as the coordinator, for the carrier kit's scripted flights (``--flight`` other than
``project``): a coordinator of the kit's own on a client session of the kit's router, which
serves State, answers Hellos (Accepted, or a Refusal when told to refuse), decides each stage
the moment the carrier under test has observed it, names the passenger it releases, and ends
the mission; at a revision of the kit's choosing, at an epoch of its choosing, truthful or (a
deposed coordinator) contradicting the truthful one.

Its decisions are simple and feasible: the carrier deploys at the first stage it observed with
features in sight, and wherever the forced rule binds it; the passenger named is the last on
board (not the one a carrier releases by default), so that obeying the name is seen."""
from __future__ import annotations

import time
from dataclasses import fields
from typing import Any

from .. import keys
from .. import messages as wm
from .flight import Flight, Seen, Target

END_REPEAT_S = 0.5  # how often End is repeated, seconds (docs/protocol.md, [P-9.1])
END_FOR_S = 2.0  # for how long, at most, seconds
CONFIRM_WAIT_S = 3.0  # how long End waits for the last stage's Confirm, seconds


def has_field(cls: type, name: str) -> bool:
    """Whether this code's revision of message ``cls`` has field ``name``."""
    return name in {f.name for f in fields(cls)}


class ScriptedCoordinator:
    """One coordinator the kit plays.

    Args:
        target: the carrier under test; ``flight``: where the kit's fakes are noted.
        node: a client session of the kit's router (wire.transport.Node), its own.
        epoch: its epoch; ``revision``: the newest revision it speaks.
        refuse: refuse the carrier's first Hello (a Refusal ``world-mismatch`` naming its
            fingerprint), after a Refusal naming another fingerprint, which the carrier must ignore;
            it then decides nothing (a refused carrier's Observations are rejected).
        deposed: a deposed coordinator: its Decisions from stage 1 on contradict the truth (marked
            fake in the flight), published at once; its End (revision 4) comes half-way.
        hold: stage -> seconds its Decision is held back after the Observation.
        lose: a stage whose Decision is decided (deploying nobody) but never published; the next
            stage is then decided at once without the carrier and published: a Decision gap.
        realtime: the mission's pace F, simulated seconds per wall second (0: unpaced), announced
            in Accepted (revision 4): Decision j goes out no earlier than (t_j - t_{j-1}) / F
            after Decision j - 1 ([P-6.1]).
        answer_from: the carrier's Hello of this number is the first it hears: the earlier ones
            are lost on their way (no answer, and no Observation read before it, as a coordinator
            without the carrier's Hello rejects them), noted as the fault ``unanswered``.

    :meth:`named` gives it a coordinator id, stated beside its epoch (revision 6: its ballot).
    """

    def __init__(self, target: Target, flight: Flight, node: Any, epoch: int = 1, revision: int = wm.REVISION,
                 refuse: bool = False, deposed: bool = False, hold: dict | None = None, realtime: float = 0.0,
                 lose: int | None = None, answer_from: int = 1):
        self.t, self.flight, self.node = target, flight, node
        self.ballot: dict = {}  # its id, on what states its epoch (:meth:`named`)
        self.epoch, self.revision, self.refuse, self.deposed = int(epoch), int(revision), refuse, deposed
        self.hold, self.realtime, self.lose = dict(hold or {}), float(realtime), lose
        self.answer_from, self.hellos = int(answer_from), 0  # the Hello it first hears, those that came
        self.published_at: float | None = None  # when its last Decision went out (monotonic s)
        self.hello_revision = wm.UNANNOUNCED_REVISION
        self.left, self.released = target.passengers, set()
        self.deployments: list[int] = []
        self.decisions: dict[int, wm.Decision] = {}
        self.due: dict[int, float] = {}  # stage -> when its Decision goes out
        self.observed: dict[int, Any] = {}
        self.end_from: float | None = None  # when it began publishing End
        self.end_after: float | None = None  # End goes out then at the latest (no last Confirm)
        self.last_end = 0.0
        self.bye = False
        m = target.mission
        node.subscribe(f"{keys.prefix(m)}/carrier/{target.cid}/*")
        node.serve(keys.state_key(m), self.state_reply)
        node.token(keys.coordinator_alive(m))

    def named(self, ident: str) -> "ScriptedCoordinator":
        """This coordinator with id ``ident``: its ballot is (epoch, ident) (revision 6)."""
        self.ballot = {"coordinator": ident}
        return self

    # ------------------------------------------------------------------ what it answers
    def state_reply(self, parameters: dict) -> bytes:
        t = self.t
        if parameters.get("carrier") == t.cid:
            self.flight.state_queries.append(time.monotonic())
        asked = keys.asked_revision(parameters, self.revision, wm.UNANNOUNCED_REVISION)
        mine = () if parameters.get("carrier", t.cid) != t.cid else (
            (t.cid, wm.CarrierState(self.left, tuple(self.deployments), True)),)
        last = self.decisions[max(self.decisions)] if self.decisions else None
        state = wm.State(t.mission, self.next_stage, t.n, t.fingerprint, self.end_from is not None, mine, last,
                         epoch=self.epoch, revision=self.revision, **self.ballot)
        return wm.encode(state, asked)

    @property
    def next_stage(self) -> int:
        return max(self.decisions) + 1 if self.decisions else 0

    @property
    def speaks(self) -> int:
        """The revision of what it sends the carrier ([P-4.2])."""
        return min(self.revision, self.hello_revision)

    def _fake(self, key: str, message: Any, topic: str) -> None:
        """Publish a message the carrier must ignore, noted as the kit's fake first."""
        payload = wm.encode(message, self.speaks)
        self.flight.fakes.add(payload)
        self.flight.faults.setdefault(topic, (getattr(message, "stage", None), time.monotonic()))
        self.node.put_raw(key, payload)

    def hello(self, h: wm.Hello) -> None:
        t = self.t
        self.hellos += 1
        if self.hellos < self.answer_from:  # lost on its way: nobody answers
            self.flight.faults.setdefault("unanswered", (None, time.monotonic()))
            return
        self.hello_revision = h.revision
        if self.refuse and "refusal" not in self.flight.faults:
            self._fake(keys.refusal_key(t.mission, t.cid), wm.refusal(
                t.mission, t.cid, "world-mismatch", "0" * 16, t.fingerprint, "another carrier's Hello",
                self.speaks), "refusal-foreign")
            time.sleep(1.0)  # the carrier must still be flying after it
            self._fake(keys.refusal_key(t.mission, t.cid), wm.refusal(
                t.mission, t.cid, "world-mismatch", h.fingerprint, t.fingerprint, "refused by the kit",
                self.speaks), "refusal")
            return
        if self.speaks < 3:
            return
        clock = {name: value for name, value in (("clock", "sim"), ("silence_timeout_s", 30.0), ("realtime", self.realtime))
                 if has_field(wm.Accepted, name)}
        answer = wm.Accepted(t.mission, t.cid, t.fingerprint, h.next_stage, self.next_stage, self.revision,
                             self.epoch, **clock, **self.ballot)
        self.node.put(keys.accepted_key(t.mission, t.cid), answer, self.speaks)

    def decide(self, j: int) -> wm.Decision:
        """Deploy at the first stage observed with features in sight and where the forced rule
        binds; a deposed coordinator says the opposite."""
        t, x = self.t, self.observed.get(j)
        able = x is not None and self.left > 0
        forced = able and int(sum(bool(v) for v in t.valid[j:])) <= self.left
        deploy = able and (forced or (x > 0 and not self.deployments))
        if self.deposed:
            deploy = not deploy
        on_board = sorted(set(range(t.passengers)) - self.released)
        named = (on_board[-1],) if deploy and on_board and self.speaks >= 2 else ()
        if deploy and not self.deposed and x is not None and self.left > 0:
            self.left -= 1
            self.deployments.append(j)
            self.released.add(named[0] if named else on_board[0])
        return wm.Decision(t.mission, j, t.times[j], (t.cid,) if deploy else (), 0.0, epoch=self.epoch,
                           passengers=named, **self.ballot)

    # ------------------------------------------------------------------ the loop
    def step(self, now: float) -> None:
        """Everything waiting in its inbox, then the Decisions and Ends that are due."""
        item = self.node.next(0.0)
        while item is not None:
            self._take(item)
            item = self.node.next(0.0)
        if self.end_after is not None and self.end_from is None and now >= self.end_after:
            self.end_from = now
        for j, at in sorted(self.due.items()):
            if now >= at:
                del self.due[j]
                self._publish(j)
        if self.end_from is not None and not self.bye and now - self.last_end >= END_REPEAT_S \
                and now - self.end_from <= END_FOR_S:
            self.last_end = now
            end = wm.End(self.t.mission, self.next_stage, "complete",
                         **({"epoch": self.epoch} if has_field(wm.End, "epoch") else {}), **self.ballot)
            if self.deposed:
                self._fake(keys.end_key(self.t.mission), end, "deposed-end")
            else:
                self.node.put(keys.end_key(self.t.mission), end, self.speaks)

    def _take(self, item: Any) -> None:
        if item.kind != "sample":
            return
        try:
            message = wm.decode(item.payload)
        except wm.ProtocolError:
            return
        if isinstance(message, wm.Hello):
            self.hello(message)
        elif isinstance(message, wm.Observation) and not self.refuse and message.stage == self.next_stage \
                and message.stage not in self.due and message.stage not in self.observed \
                and self.hellos >= self.answer_from:
            j = message.stage
            self.observed[j] = message.x
            due = time.monotonic() + self.hold.get(j, 0.0)
            if self.realtime > 0 and j > 0 and self.published_at is not None:
                due = max(due, self.published_at + (self.t.times[j] - self.t.times[j - 1]) / self.realtime)
            self.due[j] = due
        elif isinstance(message, wm.Confirm) and message.stage == self.t.n - 1 and self.end_after is not None:
            self.end_from = self.end_from or time.monotonic()  # the last Confirm is in: End ([P-9.1])
        elif isinstance(message, wm.Bye):
            self.bye = True

    def _publish(self, j: int) -> None:
        if j == self.lose and j + 1 < self.t.n:
            # Decision j is lost on its way; j + 1 is decided without the carrier, who waits at j.
            self.decisions[j] = wm.Decision(self.t.mission, j, self.t.times[j], (), 0.0, epoch=self.epoch, **self.ballot)
            self.flight.faults["lost"] = (j, time.monotonic())
            # the gap's time before Decision j + 1 goes out: the carrier's State query may come
            # back before this thread runs again (a loaded host)
            self.flight.faults["gap"] = (j + 1, time.monotonic())
            self._publish(j + 1)
            return
        d = self.decide(j)
        self.decisions[j] = d
        self.published_at = time.monotonic()
        if self.deposed and j == 0:
            return  # from stage 1 on: by then the carrier has heard epoch 2 in a Decision, whatever State it took
        if self.deposed:
            payload = wm.encode(d, self.speaks)
            self.flight.fakes.add(payload)
            self.flight.decisions.append(Seen(time.monotonic(), "decision", payload, d, fake=True))
            self.node.put_raw(keys.decision_key(self.t.mission), payload)
            if j == self.t.n // 2 and has_field(wm.End, "epoch") and self.speaks >= 4:  # End's epoch: revision 4
                self.end_from = time.monotonic()
        else:
            self.node.put(keys.decision_key(self.t.mission), d, self.speaks)
            if j == self.t.n - 1:
                self.end_after = time.monotonic() + CONFIRM_WAIT_S
