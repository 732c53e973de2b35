"""A carrier process on a simulated host (:class:`CarrierDriver`): the real machine
(:func:`mission.carrier.step`) driven by the timer rules of :mod:`mission.timers` on its host's
clock, its durable log kept across a crash."""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from .. import carrier as mc
from .. import timers as tm
from ..peers import PeerBook
from .model import ROUTER, LogEntry, Msg, msg

class CarrierDriver:
    """A carrier process on a simulated host: its machine (:mod:`mission.carrier`), its durable
    log (``log``: the outcomes and observations it wrote, kept across a crash), its body's work
    towards each stage (seconds of its host's time, :meth:`Simulation.work`), its waits by
    :mod:`mission.timers`.

    Phases: ``joining`` (asked State), ``work`` (driving to stage ``j``), ``wait`` (waiting for
    the Decision of ``j``), ``alone`` (waiting for its peers before deciding ``j`` on board),
    ``end`` (waiting for End after its last stage), ``done``, ``dead``."""

    def __init__(self, sim, cid: str):
        self.sim, self.cid = sim, cid
        self.r = sim.fleet.ids.index(cid)
        self.log: dict = {}           # the durable log: stage -> LogEntry
        self.phase = "dead"
        self.alive = False
        self.life = 0

    def start(self, now: float) -> None:
        fleet = self.sim.fleet
        self.alive, self.life = True, self.life + 1
        self.machine = mc.initial(self.cid, fleet.valid[self.r], fleet.stage_times, fleet.passengers[self.r])
        self.present = False          # a coordinator's token is present
        self.coordinators: set = set()
        self.absent_since = now
        self.peers: set = set()
        self.heard: dict = {}
        self.book = PeerBook(fleet.ids, fleet.valid)
        self.listening = False
        self.asked = self.opened = self.waited_from = now
        self.last_progress: float | None = None
        self.gap, self.resync = None, False      # a State query to resynchronise from, outstanding
        self.answer = mc.HelloAnswer(fleet.fingerprint)  # the answer to its latest Hello [P-5.14]
        self.phase = "joining"
        self.sim.token(self.cid, True)
        self.sim.send(self.cid, ROUTER, msg("query", self.cid))
        self.sim.wake(self, now + self.sim.timeouts.state_query_s)

    def crash(self) -> None:
        self.alive, self.phase = False, "dead"
        self.sim.token(self.cid, False)

    # -------------------------------------------------------------- the machine and its effects
    def apply(self, event, now: float) -> None:
        before = self.machine
        self.machine, effects = self.sim.carrier_step(before, event)
        self.sim.check_carrier(self, before, event, effects)
        for effect in effects:
            self.execute(effect, now)
        self.sim.check_on_board(self)

    def execute(self, effect, now: float) -> None:
        s, cid = self.sim, self.cid
        if isinstance(effect, mc.LogObservation):
            self.log[effect.stage] = LogEntry(effect.stage, float(s.fleet.stage_times[effect.stage]), effect.x, True,
                                              effect.position)
            self.book.observation(cid, effect.stage, effect.x)
        elif isinstance(effect, mc.LogOutcome):
            entry = self.log.get(effect.stage) or LogEntry(effect.stage, float(s.fleet.stage_times[effect.stage]))
            self.log[effect.stage] = dataclasses.replace(entry, position=effect.position, status=effect.status,
                                                         deployed=effect.deployed,
                                                         passengers_left=effect.passengers_left)
            self.book.outcome(cid, effect.stage, effect.deployed)
        elif isinstance(effect, mc.Deploy):
            s.released(self, effect.stage)
        elif isinstance(effect, mc.SendConfirm):
            s.send(cid, "coordinators", msg("confirm", cid, stage=effect.stage, deployed=effect.deployed,
                                            status=effect.status, passengers_left=effect.passengers_left))
            self.book.outcome(cid, effect.stage, effect.deployed)
        elif isinstance(effect, mc.SendOwn):
            s.send(cid, "coordinators", msg("own", cid, stage=effect.stage, x=effect.x, deployed=effect.deployed,
                                            t=float(s.fleet.stage_times[effect.stage]),
                                            passengers_left=effect.passengers_left))
            s.to_listeners(cid, msg("peer-own", cid, stage=effect.stage, x=effect.x, deployed=effect.deployed))
        elif isinstance(effect, mc.SendHello):
            self.answer.sent(now, effect.again)
            s.send(cid, "coordinators", msg("hello", cid, next_stage=effect.next_stage,
                                            passengers_left=effect.passengers_left, fingerprint=s.fleet.fingerprint))
        elif isinstance(effect, mc.ResendObservation):
            self.publish_observation(effect.stage)
        elif isinstance(effect, mc.AskState):
            self.ask_state(now, effect.stage)
        elif isinstance(effect, mc.Reject):
            s.count_reject(effect.reason)

    def publish_observation(self, j: int) -> None:
        x = self.machine.sensed if self.machine.pending == j else None
        self.sim.send(self.cid, "coordinators", msg("obs", self.cid, stage=j, t=float(self.sim.fleet.stage_times[j]),
                                                    x=x, passengers_left=self.machine.passengers_left))
        self.sim.to_listeners(self.cid, msg("peer-obs", self.cid, stage=j, x=x))

    # -------------------------------------------------------------- inputs
    def hear(self, m: Msg, now: float) -> None:
        if m.garbled or m.mission != "m":
            return
        g = m.get
        if m.kind == "token":
            self._token(g("who"), g("alive"), now)
        elif m.kind == "state":
            self._state(m, now)
        elif m.kind == "decision" and (self.machine.flying or self.phase == "joining"):
            if g("stage") < self.sim.fleet.n_stages and mc.current(self.machine, g("epoch")):
                self.book.decision(g("stage"), tuple(g("deploy")))  # what it decides alone later knows (carriers/inbound.py)
            self.apply(mc.DecisionHeard(g("stage"), g("t"), tuple(g("deploy")), self.position(), g("epoch")), now)
        elif m.kind == "end":
            self.apply(mc.EndHeard(g("epoch")), now)
        elif m.kind in ("accepted", "refusal"):  # the simulated fleet builds one world: never refused for it
            self.answer.answered(self.sim.fleet.fingerprint)
        elif m.kind in ("peer-obs", "peer-own") and m.src in self.sim.fleet.ids:
            self.heard[m.src] = now
            if g("x") is not None or m.kind == "peer-obs":
                self.book.observation(m.src, g("stage"), g("x"))
            if m.kind == "peer-own":
                self.book.outcome(m.src, g("stage"), g("deployed"))
        elif m.kind == "progress" and m.src in self.sim.fleet.ids:
            self.heard[m.src] = now
            self.book.progress(m.src, g("stage"))
        self.advance(now)

    def _token(self, who: str, alive: bool, now: float) -> None:
        if who in self.sim.fleet.ids:
            (self.peers.add if alive else self.peers.discard)(who)
            return
        if who not in self.sim.coordinator_names:
            return
        was = self.present
        (self.coordinators.add if alive else self.coordinators.discard)(who)
        self.present = bool(self.coordinators)
        if was and not self.present:
            self.absent_since = now
        if not was and self.present and self.machine.flying and not self.machine.ended:
            self.ask_state(now)  # the coordinator is back: resynchronise from its State [P-5.12]

    def _state(self, m: Msg, now: float) -> None:
        g = m.get
        if g("fingerprint") != self.sim.fleet.fingerprint:
            return
        seen = mc.StateSeen(g("next_stage"), tuple(g("deployments")), g("last_decision"), g("ended"), g("epoch"))
        if self.phase == "joining":
            self.present = True  # it answered
            self.join_from_state(seen, now)
            if self.sim.fleet.mode == "hybrid":
                self.listen()
            self.begin_stage(self.machine.stage, now)
            return
        if not mc.current(self.machine, seen.epoch):
            return
        if self.resync:
            gap, self.gap, self.resync = self.gap, None, False
            self.apply(mc.Resync(seen, self.position(), gap=gap), now)
        elif self.phase == "wait":
            j = self.j
            if seen.next_stage == j:
                self.apply(mc.Collecting(j, seen.epoch), now)
            else:
                # past j: its Decision was lost; behind j: the coordinator never had this
                # carrier's Hello or accounts of the stages since (lost): both resynchronise
                self.apply(mc.Resync(seen, self.position()), now)

    def ask_state(self, now: float, gap: int | None = None) -> None:
        """Resynchronise from State (the coordinator's token came back, or a Decision came after a
        lost one: ``gap``). Like carriers/joining.py's ``_query_once``, the query waits
        ``state_query_s`` for a reply; none: :class:`mission.carrier.Resync` without a State (its
        Hello and answers go out all the same)."""
        self.gap, self.resync, self.asks = gap, True, getattr(self, "asks", 0) + 1
        self.sim.send(self.cid, ROUTER, msg("query", self.cid))
        self.sim.at(self.sim.true_of(self.cid, now + self.sim.timeouts.state_query_s), self._unanswered, self.life,
                    self.asks)

    def _unanswered(self, life: int, ask: int) -> None:
        if life != self.life or ask != self.asks or not self.resync or not self.alive:
            return
        if self.sim._frozen(self.cid):  # stuck in its query: it times out when it runs again
            self.sim.at(self.sim.frozen[self.cid], self._unanswered, life, ask)
            return
        now = self.sim.now_of(self.cid)
        gap, self.gap, self.resync = self.gap, None, False
        self.apply(mc.Resync(None, self.position(), gap=gap), now)
        self.advance(now)

    def join_from_state(self, seen: mc.StateSeen, now: float) -> None:
        """Join from the coordinator's State and the carrier's own log (carriers/joining.py's
        path): the deployments replayed, the stages it resolved itself recalled, the deployments
        on record it never made answered ``late``."""
        entries = {e.stage: e for e in self.log.values() if e.status is not None}
        logged = {j: e.deployed for j, e in entries.items()} or None  # no outcome logged: the record decides
        start = mc.join_stage(seen.next_stage, logged)
        forget = self.sim.plant == "forget-on-restart" and self.life > 1
        recalled = [j for j in sorted(entries) if j >= seen.next_stage]
        if not forget:
            for j in mc.replay_plan(self.machine, min(seen.next_stage, start), seen.deployments, logged):
                self.apply(mc.Replayed(j, self.position()), now)
                self.book.outcome(self.cid, j, True)
            for j in recalled:
                e = entries[j]
                self.apply(mc.Recalled(j, e.status, e.deployed, self.position(), e.x), now)
                self.book.outcome(self.cid, j, e.deployed)
        self.apply(mc.Joined(start if not forget else seen.next_stage, seen.ended, seen.epoch), now)
        self.apply_effect_hello(now)
        for j in mc.missed(seen.next_stage, seen.deployments, logged):
            self.apply(mc.Missed(j, self.position()), now)
        for effect in mc.accounts(self.machine, recalled):
            self.execute(effect, now)

    def apply_effect_hello(self, now: float) -> None:
        self.execute(mc.SendHello(self.machine.hello_stage(), self.machine.passengers_left), now)

    def position(self) -> tuple[float, float]:
        return (float(self.machine.stage), float(self.r))

    # -------------------------------------------------------------- the stage loop
    def begin_stage(self, j: int, now: float) -> None:
        fleet = self.sim.fleet
        if self.machine.ended or j >= fleet.n_stages:
            self.phase, self.opened = "end", now
            return
        self.j, self.phase = j, "work"
        self.work_done = now + (0.0 if self.machine.behind(j) else self.sim.work(self, j))

    def advance(self, now: float) -> None:
        while self.alive:
            until = self._rule(now)
            if until is None:
                continue
            # every coordinator of the simulator answers Hellos (revision >= 3)
            again = tm.hello_again(bool(self.answer.unanswered), True, self.present, self.answer.at,
                                   self.answer.tries, now, self.sim.timeouts.hello_s)
            if isinstance(again, tm.Attempt):
                self.apply(mc.HelloUnanswered(self.position()), now)
                continue
            until = min(until, again.until)
            if math.isfinite(until):
                self.sim.wake(self, until)
            return

    def _rule(self, now: float):
        """One step of the carrier's loop at ``now``: None when something changed (look again),
        else the time to wake up at."""
        t, fleet, m = self.sim.timeouts, self.sim.fleet, self.machine
        if self.phase == "joining":
            if now - self.opened >= t.coordinator_s:
                if fleet.mode == "hybrid":
                    self.join_alone(now)
                    return None
                self.finish("coordinator-lost", now)
                return None
            if now - self.asked >= t.state_query_s:
                self.asked = now
                self.sim.send(self.cid, ROUTER, msg("query", self.cid))
            return self.asked + t.state_query_s
        if m.ended and self.phase in ("work", "wait", "alone"):
            self.phase, self.opened = "end", now
        if self.phase == "work":
            if now < self.work_done:
                self.progress(now, t.progress_s)
                return min(self.work_done, self.last_progress + t.progress_s)
            j = self.j
            if m.behind(j):
                self.apply(mc.Passed(j, self.position()), now)
                self.begin_stage(j + 1, now)
                return None
            x = None if np.isnan(fleet.x[self.r, j]) else int(fleet.x[self.r, j])
            self.apply(mc.Observed(j, x, self.position()), now)
            self.publish_observation(j)
            self.phase, self.waited, self.waited_from = "wait", 0.0, now
            return None
        if self.phase in ("wait", "alone") and m.resolved(self.j):
            self.move_on(self.j, now)
            return None
        if self.phase == "wait":
            j = self.j
            if self.present:
                self.waited += now - self.waited_from
            self.waited_from = now
            rule = tm.decision_wait("sim", fleet.mode, self.present, self.waited, now - self.absent_since,
                                    t.decision_s, t.coordinator_s)
            if isinstance(rule, tm.AskState):
                self.waited = 0.0
                self.sim.send(self.cid, ROUTER, msg("query", self.cid))
                return None
            if isinstance(rule, tm.DecideAlone):
                self.phase, self.opened = "alone", now
                self.listen()
                return None
            if isinstance(rule, tm.GiveUp):
                self.finish(rule.reason, now)
                return None
            self.progress(now, t.silence_s / 3)
            wake = self.last_progress + t.silence_s / 3
            if self.present:
                wake = min(wake, now + (t.decision_s - self.waited))
            else:
                wake = min(wake, self.absent_since + t.coordinator_s)
            return wake
        if self.phase == "alone":
            j = self.j
            waiting = self.book.waiting(j, sorted(self.peers - {self.cid}))
            rule = tm.stage_wait("sim", waiting, frozenset(), self.heard, self.opened, now, t.peer_s, t.silence_s)
            if isinstance(rule, tm.Wait):
                if tm.due(self.last_progress, now, t.silence_s / 3):
                    # its peers may be waiting for its observation as it waits for theirs, and
                    # one of them lost: each Progress goes with the observation again (absorbed)
                    self.sim.to_listeners(self.cid, msg("peer-obs", self.cid, stage=j, x=self.machine.sensed))
                self.progress(now, t.silence_s / 3)
                return min(rule.until, self.last_progress + t.silence_s / 3)
            self.decide_alone(j, now)
            return None
        if self.phase == "end":
            if m.ended or now - self.opened >= t.end_s:
                self.finish("finished", now)
                return None
            return self.opened + t.end_s
        return math.inf

    def progress(self, now: float, interval: float) -> None:
        if tm.due(self.last_progress, now, interval):
            self.last_progress = now
            self.sim.send(self.cid, "coordinators", msg("progress", self.cid, stage=self.j))
            self.sim.to_listeners(self.cid, msg("progress", self.cid, stage=self.j))

    def listen(self) -> None:
        """Deciding alone from now on: subscribe to the peers' messages and tokens."""
        if not self.listening:
            self.listening = True
            self.sim.listeners.add(self.cid)
            self.peers = self.sim.peers_seen(self.cid)

    def decide_alone(self, j: int, now: float) -> None:
        fleet = self.sim.fleet
        self.book.observation(self.cid, j, self.machine.sensed)
        deploy = fleet.decide_local(self.book.local_view(fleet.problem, self.cid, j, fleet.seed))
        self.apply(mc.DecidedOwn(j, bool(deploy), self.position()), now)
        self.move_on(j, now)

    def move_on(self, j: int, now: float) -> None:
        """Stage j is resolved: leave it and drive to the next."""
        self.apply(mc.MovedOn(j), now)
        self.begin_stage(j + 1, now)

    def join_alone(self, now: float) -> None:
        """No coordinator answered: go on from the durable log (hybrid)."""
        done = [e for e in self.log.values() if e.status is not None]
        for e in done:  # its own log is what its on-board decisions know of its past (carriers/joining.py)
            if e.observed:
                self.book.observation(self.cid, e.stage, e.x)
            self.book.outcome(self.cid, e.stage, e.deployed)
        next_stage = max((e.stage + 1 for e in done), default=0)
        for j in mc.replay_plan(self.machine, next_stage, [e.stage for e in done if e.deployed]):
            self.apply(mc.Replayed(j, self.position()), now)
            self.book.outcome(self.cid, j, True)
        self.apply(mc.Joined(next_stage), now)
        self.listen()
        self.begin_stage(self.machine.stage, now)
        if self.present:  # its token came while no State answered: it is back, resynchronise [P-5.12]
            self.ask_state(now)

    def finish(self, reason: str, now: float) -> None:
        self.sim.send(self.cid, "coordinators", msg("bye", self.cid, deployments=self.machine.deployments(),
                                                    reason=reason))
        self.phase, self.alive = "done", False
        self.sim.finished(self, reason)
        self.sim.token(self.cid, False, after=0.05)
