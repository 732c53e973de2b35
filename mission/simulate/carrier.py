"""A carrier process on a simulated host (:class:`CarrierDriver`): the carrier's lifecycle
machine (:mod:`mission.carrier_life`) and its handshake machine (:func:`mission.carrier.step`),
the same machines the real carrier process drives, under its host's simulated clock and network;
its durable log kept across a crash."""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from .. import carrier as mc
from .. import carrier_life as cl
from .. import joins
from .. import timers as tm
from ..ballot import Ballot
from ..peers import PeerBook
from .model import ROUTER, LogEntry, Msg, msg
from ..modes import Mode

class CarrierDriver:
    """A carrier process on a simulated host: its lifecycle machine (``lifecycle``,
    :mod:`mission.carrier_life`), its handshake machine (``machine``, :mod:`mission.carrier`), its
    durable log (``log``: the outcomes and observations it wrote, kept across a crash) and its
    body's work towards each stage (seconds of its host's time, :meth:`Simulation.work`). This
    driver only feeds the machines its host's clock and messages and carries out their effects.

    ``phase``: the lifecycle's phase, or ``dead`` while its process is down."""

    def __init__(self, sim, cid: str):
        self.sim, self.cid = sim, cid
        self.r = sim.fleet.ids.index(cid)
        self.log: dict = {}           # the durable log: stage -> LogEntry
        self.alive = self.finished_now = False
        self.life = 0
        self.lifecycle = cl.initial(sim.fleet.mode, sim.timeouts)
        self.timers = mc.Timers("sim", float(sim.timeouts.silence_s), 0.0)

    @property
    def phase(self) -> str:
        return self.lifecycle.phase.value if self.alive or self.finished_now else "dead"

    def start(self, now: float) -> None:
        fleet = self.sim.fleet
        self.alive, self.life = True, self.life + 1
        self.sender, self.acted = "", Ballot(0)  # the coordinator of the Decision or State heard last; the
        # highest true ballot of a Decision this process acted on (Simulation.check_carrier)
        self.machine = mc.initial(self.cid, fleet.valid[self.r], fleet.stage_times, fleet.passengers[self.r])
        self.present = False          # a coordinator's token is present
        self.coordinators: set = set()
        self.absent_since = now
        self.peers: set = set()
        self.heard: dict = {}
        self.book = PeerBook(fleet.ids, fleet.valid)
        self.listening = False
        self.alone_next = 0           # joining alone: the stage after the last its log resolved
        self.gap, self.resync = None, False      # a State query to resynchronise from, outstanding
        self.answer = mc.HelloAnswer(fleet.fingerprint)  # the answer to its latest Hello [P-5.14]
        self.sim.token(self.cid, True)
        self.step(cl.Start(now), now)
        self.advance(now)

    def crash(self) -> None:
        self.alive = self.finished_now = False
        self.sim.token(self.cid, False)

    # -------------------------------------------------------------- the machine and its effects
    def apply(self, event, now: float) -> None:
        before = self.machine
        self.machine, effects = self.sim.carrier_step(before, event)
        self.sim.invariants.check_carrier(self, before, event, effects)
        for effect in effects:
            self.execute(effect, now)
        self.sim.invariants.check_on_board(self)

    def execute(self, effect, now: float) -> None:
        carry_out(self, effect, now)

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
        elif m.kind == "decision" and (self.machine.flying or self.lifecycle.phase is cl.Phase.JOINING):
            who, self.sender = self.sim.coordinator_of(m), m.src
            if g("stage") < self.sim.fleet.n_stages and mc.current(self.machine, g("epoch"), who):
                self.book.decision(g("stage"), tuple(g("deploy")))  # what it decides alone later knows (carriers/inbound.py)
            self.apply(mc.DecisionHeard(g("stage"), g("t"), tuple(g("deploy")), self.position(), g("epoch"), who), now)
        elif m.kind == "end":
            self.apply(mc.EndHeard(g("epoch"), self.sim.coordinator_of(m)), now)
        elif m.kind in ("accepted", "refusal"):  # the simulated fleet builds one world: never refused for it
            self.answer.answered(self.sim.fleet.fingerprint)
        elif m.kind in ("peer-obs", "peer-own") and m.src in self.sim.fleet.ids:
            self.heard[m.src] = now
            if not self.book.accepts(g("stage")):  # carriers/inbound.py: rejected out-of-range
                self.sim.count_reject("out-of-range")
                return
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
        self.sender = m.src
        seen = mc.StateSeen(g("next_stage"), tuple(g("deployments")), g("last_decision"), g("ended"), g("epoch"),
                            self.sim.coordinator_of(m))
        if self.lifecycle.phase is cl.Phase.JOINING:
            self.present = True  # it answered
            self.join_from_state(seen, now)
            if self.sim.fleet.mode == Mode.HYBRID:
                self.listen()
            self.step(cl.Answered(now), now)
            return
        if not mc.current(self.machine, seen.epoch, seen.coordinator):
            return
        if self.resync:
            gap, self.gap, self.resync = self.gap, None, False
            self.apply(mc.Resync(seen, self.position(), gap=gap), now)
        elif self.lifecycle.phase is cl.Phase.WAIT:
            self.apply(mc.waited_state(seen, self.lifecycle.stage, self.position()), now)

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
        """Join from the coordinator's State and the carrier's own log: the processes' path
        (:func:`mission.joins.from_state`), driven here. Planted ``forget-on-restart``: a
        restarted carrier forgets its log and the deployments on record."""
        if self.sim.plant == "forget-on-restart" and self.life > 1:
            seen, entries = dataclasses.replace(seen, deployments=()), ()
        else:
            entries = self.log.values()
        tm.drive(joins.from_state(self.machine, seen, entries, self.book), lambda asked: self._asked(asked, now))

    def _asked(self, asked, now: float):
        """What a join path asks (:mod:`mission.joins`): the simulated carrier has no body (its
        position is its stage), nothing to drive and nothing to release."""
        if isinstance(asked, (joins.Drive, joins.Here)):
            return self.position()
        if isinstance(asked, joins.Execute):
            self.execute(asked.effect, now)
        elif isinstance(asked, joins.Apply):
            self.apply(asked.event, now)
            return self.machine
        return None

    def apply_effect_hello(self, now: float) -> None:
        self.execute(mc.SendHello(self.machine.hello_stage(), self.machine.passengers_left), now)

    def position(self) -> tuple[float, float]:
        return (float(self.machine.stage), float(self.r))

    # -------------------------------------------------------------- the lifecycle and its effects
    def view(self) -> cl.View:
        a = self.answer
        others = {src for src, dsts in self.sim.listened_by.items() if self.cid in dsts and src != self.cid}
        # every coordinator of the simulator answers Hellos (revision >= 3)
        return cl.View(self.machine, self.present, self.absent_since, self.timers, frozenset(self.peers), self.heard,
                       self.book, others <= self.peers, cl.Hello(bool(a.unanswered), True, a.at, a.tries))

    def step(self, event, now: float) -> float | None:
        """Step the lifecycle with ``event`` and carry out its effects: the time to be woken at
        (its :class:`mission.timers.Wait`), None when it is to be stepped again at once."""
        self.lifecycle, effects = cl.step(self.lifecycle, event, self.view())
        until = None
        for effect in effects:
            if isinstance(effect, tm.Wait):
                until = effect.until
            elif self.alive:
                self.run(effect, now)
        return until

    def advance(self, now: float) -> None:
        while self.alive:
            until = self.step(cl.Tick(now), now)
            if until is None:
                continue
            if math.isfinite(until):
                self.sim.wake(self, until)
            return

    def run(self, effect, now: float) -> None:
        """Carry out one effect of the lifecycle machine."""
        s, cid, fleet = self.sim, self.cid, self.sim.fleet
        if isinstance(effect, cl.Drive):
            work = 0.0 if self.machine.behind(effect.stage) else s.work(self, effect.stage)
            s.at(s.true_of(cid, now + work), self._arrive, self.life, effect.stage)
        elif isinstance(effect, cl.Observe):
            j = effect.stage
            x = None if np.isnan(fleet.x[self.r, j]) else int(fleet.x[self.r, j])
            self.apply(mc.Observed(j, x, self.position()), now)
            self.publish_observation(j)
        elif isinstance(effect, cl.Pass):
            self.apply(mc.Passed(effect.stage, self.position()), now)
        elif isinstance(effect, cl.MoveOn):
            self.apply(mc.MovedOn(effect.stage), now)
        elif isinstance(effect, cl.DecideOnBoard):
            j = effect.stage
            self.book.observation(cid, j, self.machine.sensed)
            deploy = fleet.decide_local(self.book.local_view(fleet.problem, cid, j, fleet.seed))
            self.apply(mc.DecidedOwn(j, bool(deploy), self.position()), now)
        elif isinstance(effect, cl.SendProgress):
            s.send(cid, "coordinators", msg("progress", cid, stage=effect.stage))
            s.to_listeners(cid, msg("progress", cid, stage=effect.stage))
        elif isinstance(effect, cl.RepeatObservation):
            s.to_listeners(cid, msg("peer-obs", cid, stage=effect.stage, x=self.machine.sensed))
        elif isinstance(effect, (cl.Query, cl.AskState)):
            s.send(cid, ROUTER, msg("query", cid))
        elif isinstance(effect, cl.Listen):
            self.listen()
        elif isinstance(effect, cl.JoinAlone):
            self.join_alone(now)
        elif isinstance(effect, cl.Gathered):
            self.apply(mc.Joined(self.alone_next), now)
            if effect.resync:
                self.ask_state(now)
        elif isinstance(effect, cl.SayHelloAgain):
            self.apply(mc.HelloUnanswered(self.position()), now)
        elif isinstance(effect, cl.Finish):
            self.finish(effect.reason)

    def _arrive(self, life: int, j: int) -> None:
        """Its body reached t_j (the work of :class:`mission.carrier_life.Drive` is done)."""
        if life != self.life or not self.alive:
            return
        if self.sim._frozen(self.cid):  # stuck: it gets there when it runs again
            self.sim.at(self.sim.frozen[self.cid], self._arrive, life, j)
            return
        now = self.sim.now_of(self.cid)
        self.step(cl.Arrived(j, now), now)
        self.advance(now)

    def listen(self) -> None:
        """Deciding alone from now on: subscribe to the peers' messages and tokens."""
        if not self.listening:
            self.listening = True
            self.sim.listeners.add(self.cid)
            self.peers = self.sim.peers_seen(self.cid)

    def join_alone(self, now: float) -> None:
        """No coordinator answered: go on from the durable log (hybrid), once its peers' tokens
        are there (:class:`mission.carrier_life.Gathered`): the processes' path
        (:func:`mission.joins.alone`), driven here."""
        self.alone_next = tm.drive(joins.alone(self.machine, self.log.values(), self.book),
                                   lambda asked: self._asked(asked, now))
        self.listen()

    def finish(self, reason: str) -> None:
        self.sim.send(self.cid, "coordinators", msg("bye", self.cid, deployments=self.machine.deployments(),
                                                    reason=reason))
        self.alive, self.finished_now = False, True
        self.sim.finished(self, reason)
        self.sim.token(self.cid, False, after=0.05)


def carry_out(driver: CarrierDriver, effect, now: float) -> None:
    """One effect of the handshake machine (:mod:`mission.carrier`) on the simulated host: the
    durable log, the peer book, a passenger's release, a message sent."""
    s, cid = driver.sim, driver.cid
    if isinstance(effect, mc.LogObservation):
        driver.log[effect.stage] = LogEntry(effect.stage, float(s.fleet.stage_times[effect.stage]), effect.x, True,
                                            effect.position)
        driver.book.observation(cid, effect.stage, effect.x)
    elif isinstance(effect, mc.LogOutcome):
        entry = driver.log.get(effect.stage) or LogEntry(effect.stage, float(s.fleet.stage_times[effect.stage]))
        driver.log[effect.stage] = dataclasses.replace(entry, position=effect.position, status=effect.status,
                                                       deployed=effect.deployed, passengers_left=effect.passengers_left)
        driver.book.outcome(cid, effect.stage, effect.deployed)
    elif isinstance(effect, mc.Deploy):
        s.invariants.released(driver, effect.stage)
    elif isinstance(effect, mc.SendConfirm):
        s.send(cid, "coordinators", msg("confirm", cid, stage=effect.stage, deployed=effect.deployed,
                                        status=effect.status, passengers_left=effect.passengers_left))
        driver.book.outcome(cid, effect.stage, effect.deployed)
    elif isinstance(effect, mc.SendOwn):
        s.send(cid, "coordinators", msg("own", cid, stage=effect.stage, x=effect.x, deployed=effect.deployed,
                                        t=float(s.fleet.stage_times[effect.stage]),
                                        passengers_left=effect.passengers_left))
        s.to_listeners(cid, msg("peer-own", cid, stage=effect.stage, x=effect.x, deployed=effect.deployed))
    elif isinstance(effect, mc.SendHello):
        driver.answer.sent(now, effect.again)
        s.send(cid, "coordinators", msg("hello", cid, next_stage=effect.next_stage,
                                        passengers_left=effect.passengers_left, fingerprint=s.fleet.fingerprint))
    elif isinstance(effect, mc.ResendObservation):
        driver.publish_observation(effect.stage)
    elif isinstance(effect, mc.AskState):
        driver.ask_state(now, effect.stage)
    elif isinstance(effect, mc.Reject):
        s.count_reject(effect.reason)
