"""A coordinator process on a simulated host (:class:`CoordinatorDriver`) and its mission.db
(:class:`Disk`): the real machine (:func:`mission.state.step`) driven by the timer rules of
:mod:`mission.timers` on its host's clock."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from .. import events as ev
from .. import state as ms
from .. import timers as tm
from .model import Msg, msg

@dataclass
class Disk:
    """A coordinator's mission.db: its durable record (``events``, what :func:`mission.state.fold`
    reads at a restart) and the highest epoch opened on it (``epoch``: the store fences a write
    of a lower one). A primary and its standby share one, or each has its own
    (:attr:`Simulation.separate`)."""

    name: str
    events: list = field(default_factory=list)
    epoch: int = 0



class CoordinatorDriver:
    """A coordinator process on a simulated host: its mission state, its durable record (``db``,
    shared with a standby: mission.db on the disk they share), its waits by :mod:`mission.timers`.

    Phases: ``standby`` (a live primary exists), ``join``, ``stage``, ``confirm``, ``end`` (the
    Bye wait), ``done``, ``deposed``."""

    def __init__(self, sim, name: str, disk: Disk, standby: bool = False):
        self.sim, self.name, self.disk = sim, name, disk
        self.phase = "standby" if standby else "new"
        self.alive = False
        self.state: ms.MissionState | None = None
        self.epoch = 0
        self.heard: dict = {}
        self.opened = self.last_join = self.ended_at = 0.0
        self.last_end: float | None = None
        self.grace: float | None = None
        self.primary_lost: float | None = None
        self.resuming = None  # (stage, deploy, passengers) of the decision a pause interrupted
        self.life = 0         # its process's starts: what a paused process left scheduled dies with it

    # -------------------------------------------------------------- life
    def start(self, now: float) -> None:
        self.alive, self.life = True, self.life + 1
        if self.phase == "standby":  # no State and no token of its own: it watches the primary's
            self.sim.wake(self, now + self.sim.timeouts.standby_poll_s)
            return
        self.open(now)

    def open(self, now: float, known: int = 0) -> None:
        """Open the mission: a fresh start, a restart or a takeover (the record folded, a new
        epoch above every one opened on its disk and ``known``, the primary's that a standby
        learnt from its State: storage.missiondb's ``min_epoch``)."""
        self.disk.events.append(ev.Opened(now))
        self.state = ms.fold(self.sim.spec, self.disk.events)
        self.epoch = self.disk.epoch = max(self.disk.epoch, known) + 1
        self.phase, self.opened, self.last_join, self.heard = "join", now, now, {}
        self.joined_count = sum(1 for cid in self.state.live if cid in self.state.accepted)
        self.sim.token(self.name, True)
        if self.state.ended:  # a complete mission is final: nothing to do
            self.phase = "end"
            self.ended_at = now
        self.sim.wake(self, now)

    def crash(self) -> None:
        self.alive, self.resuming = False, None  # a paused process killed does not resume
        self.phase = "dead" if self.phase != "standby" else "dead-standby"
        self.sim.token(self.name, False)

    # -------------------------------------------------------------- inputs
    def hear(self, m: Msg, now: float) -> None:
        if m.garbled or m.mission != "m":
            return  # checks 1-3 of [P-3.3]: dropped, not heard
        if m.kind == "token":
            self._token(m, now)
            return
        if self.phase in ("standby", "new", "dead", "dead-standby") or self.state is None:
            return
        cid = m.src
        if m.kind in ("hello", "obs", "confirm", "own", "bye", "progress") and cid in self.sim.fleet.ids \
                and not (self.sim.plant == "slow-as-empty" and m.kind == "progress") \
                and not (m.kind == "progress" and m.get("stage") > self.state.next_stage):
            self.heard[cid] = now  # [P-10.5]; a carrier past the stage collected sends nothing more for it
        g = m.get
        if m.kind == "hello":
            self.apply(ev.Hello(cid, 1, cid, g("passengers_left"), g("next_stage"), g("fingerprint"), now, 4))
            self.joined(now)
        elif m.kind == "obs":
            self.apply(ev.Observation(cid, g("stage"), g("t"), g("x"), (0.0, 0.0), g("passengers_left"), (), now))
        elif m.kind == "confirm":
            self.apply(ev.Confirmed(cid, g("stage"), g("deployed"), g("status"), (0.0, 0.0), g("passengers_left"), now))
        elif m.kind == "own":
            self.apply(ev.Accounted(cid, g("stage"), g("t"), g("x"), g("deployed"), (0.0, 0.0), g("passengers_left"),
                                    now))
        elif m.kind == "bye":
            self.apply(ev.Bye(cid, tuple(g("deployments", ())), (), g("reason", "finished"), now))
        elif m.kind == "query":
            self.sim.send(self.name, cid, self.state_reply(cid))
        elif m.kind == "decision" and m.get("epoch") > self.epoch:
            self.depose()  # coordinator.epochs._heard_decision: a newer coordinator decides
            return
        self.advance(now)

    def depose(self) -> None:
        """Stop deciding, without End: a coordinator of a newer epoch took over."""
        self.phase, self.alive, self.resuming = "deposed", False, None
        self.sim.token(self.name, False)

    def joined(self, now: float) -> None:
        """The join wait runs from when the count of live carriers with an accepted Hello last grew
        (coordinator/clock.py's ``_wait_for_carriers``): a Hello said again does not restart it."""
        st = self.state
        count = sum(1 for cid in st.live if cid in st.accepted)
        if count > self.joined_count:
            self.last_join, self.joined_count = now, count

    def _token(self, m: Msg, now: float) -> None:
        who, alive = m.get("who"), m.get("alive")
        if who in self.sim.fleet.ids:
            if self.state is not None and self.phase not in ("standby", "dead", "dead-standby"):
                self.apply(ev.LivelinessChanged(who, alive, now))
                self.joined(now)
                self.advance(now)
        elif who != self.name and self.phase == "standby":
            self.primary_lost = None if alive else now

    def state_reply(self, cid: str) -> Msg:
        st = self.state
        last = st.next_stage - 1
        decision = None
        if last in st.decisions:
            decision = (last, float(self.sim.fleet.stage_times[last]), tuple(st.decisions[last].deploy))
        return msg("state", self.name, next_stage=st.next_stage, deployments=tuple(st.deployments_of(cid)),
                   last_decision=decision, ended=st.ended, epoch=self.epoch, fingerprint=self.sim.fleet.fingerprint)

    def apply(self, event) -> None:
        before = self.state
        self.state, effects = self.sim.coordinator_step(before, event)
        self.sim.check_coordinator(self, before, event, effects)
        for effect in effects:
            if isinstance(effect, ms.Record):
                self.disk.events.append(effect.event)
            elif isinstance(effect, ms.Accept):
                self.sim.send(self.name, effect.carrier, msg("accepted", self.name, next_stage=effect.next_stage,
                                                              epoch=self.epoch))
            elif isinstance(effect, ms.Refuse):
                self.sim.send(self.name, effect.carrier, msg("refusal", self.name, reason=effect.reason))
            elif isinstance(effect, ms.Publish):
                d = self.state.decisions[effect.stage]
                self.sim.broadcast(self.name, msg("decision", self.name, stage=effect.stage, deploy=tuple(d.deploy),
                                                  t=float(self.sim.fleet.stage_times[effect.stage]), epoch=self.epoch))
            elif isinstance(effect, ms.Reject):
                self.sim.count_reject(effect.reason)

    # -------------------------------------------------------------- the waits
    def advance(self, now: float) -> None:
        """Run the phase's timer rule at ``now`` and carry out what it says, until it says wait."""
        while self.alive:
            rule = self._rule(now)
            if isinstance(rule, tm.Wait):
                if math.isfinite(rule.until):
                    self.sim.wake(self, rule.until)
                return

    def _rule(self, now: float):
        st, fleet, t = self.state, self.sim.fleet, self.sim.timeouts
        if self.resuming is not None:
            return tm.Wait()  # paused in the middle of a decision: it goes on where it stopped
        if self.phase == "standby":
            rule = tm.standby(self.primary_lost is None, self.primary_lost, now, t.standby_poll_s)
            if isinstance(rule, tm.TakeOver):
                self.open(now, max(d.epoch for d in self.sim.coordinators.values()))
                return tm.Wait()
            return rule
        if self.phase == "join":
            join_s = t.resumed_join_s() if st.resumed else t.join_s
            rule = tm.join_wait("sim", st.all_joined(), self.opened, self.last_join, now, join_s)
            if isinstance(rule, tm.GoOn):
                self.phase, self.opened = ("stage", now) if st.next_stage < fleet.n_stages else ("confirm", now)
                return None
            return rule
        if self.phase == "stage":
            j = st.next_stage
            if j > 0 and not st.live and now - self.opened < t.join_s:
                return tm.Wait(self.opened + t.join_s)  # nobody to decide for: hold
            waiting = st.waiting(j)
            rule = tm.stage_wait("sim", waiting, frozenset(), self.heard, self.opened, now, t.stage_s, t.silence_s)
            if isinstance(rule, tm.GoOn):
                self.decide(j, now)
                return None
            return rule
        if self.phase == "confirm":
            last = fleet.n_stages - 1
            loud = st.unconfirmed(last) if last in st.decisions else frozenset()
            rule = tm.stage_wait("sim", loud, frozenset(), self.heard, self.opened, now, t.confirm_s, t.silence_s)
            if isinstance(rule, tm.GoOn):
                self.apply(ev.Ended("complete", now))
                self.phase, self.ended_at, self.grace, self.last_end = "end", now, None, None
                return None
            return rule
        if self.phase == "end":
            if tm.due(self.last_end, now, t.end_repeat_s):
                self.sim.broadcast(self.name, msg("end", self.name, epoch=self.epoch))
                self.last_end = now
            if st.all_said_bye() and self.grace is None:
                self.grace = now
            rule = tm.bye_wait(st.all_said_bye(), st.bye_missing(), self.ended_at, self.grace, now, t.bye_s,
                               t.bye_grace_s)
            if isinstance(rule, tm.GoOn):
                self.phase = "done"
                self.sim.token(self.name, False)
                self.alive = False
                return tm.Wait()
            return tm.Wait(min(rule.until, self.last_end + t.end_repeat_s))
        return tm.Wait()

    def decide(self, j: int, now: float) -> None:
        if self.disk.epoch > self.epoch:  # a standby took over on the shared disk: deposed, no Decision
            self.depose()
            return
        for action in self.sim.fleet.operator_actions(self.state, j, now):  # a simulated operator's
            self.apply(action)
        deploy, passengers = self.sim.fleet.decide(self.state, j)
        paused = self.sim.pause(self)
        if paused:  # the process stops between its epoch check and its record (a GC or VM pause)
            self.resuming = (j, deploy, passengers)
            self.sim.at(self.sim.t + paused, self._resume, self.life)
            return
        self.publish(j, deploy, passengers, now)

    def publish(self, j: int, deploy, passengers, now: float) -> None:
        if self.disk.epoch > self.epoch:
            # the store fences a deposed coordinator's write: a newer epoch opened the mission
            # while this one was paused after its check; it steps down
            self.depose()
            return
        self.apply(self.sim.fleet.operator_decided(self.state, j, deploy, passengers, now))
        self.apply(ev.Published(j, now))
        self.sim.decided_at.setdefault(j, self.sim.t)
        self.opened = now
        if self.state.next_stage >= self.sim.fleet.n_stages:
            self.phase = "confirm"

    def _resume(self, life: int) -> None:
        if life != self.life or self.resuming is None:
            return  # it was killed while paused (and maybe restarted: a new process)
        (j, deploy, passengers), self.resuming = self.resuming, None
        if self.alive:
            now = self.sim.now_of(self.name)
            self.publish(j, deploy, passengers, now)
            self.advance(now)
