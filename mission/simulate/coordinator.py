"""A coordinator process on a simulated host (:class:`CoordinatorDriver`) and its mission.db
(:class:`Disk`): the coordinator's lifecycle machine (:mod:`mission.coordinator_life`) and its
mission machine (:func:`mission.state.step`), the machines the real coordinator drives, on its
host's simulated clock and network."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .. import coordinator_life as cl
from .. import events as ev
from .. import state as ms
from .. import timers as tm
from ..ballot import Ballot
from .model import Msg, msg

@dataclass
class Disk:
    """A coordinator's mission.db: its durable record (``events``, what :func:`mission.state.fold`
    reads at a restart) and the highest ballot opened on it (``ballot``: the store fences a write
    of a lower one). A primary and its standby share one, or each has its own
    (:attr:`Simulation.separate`)."""

    name: str
    events: list = field(default_factory=list)
    ballot: Ballot = Ballot(0)



class CoordinatorDriver:
    """A coordinator process on a simulated host: its lifecycle (``lifecycle``), its mission state,
    its durable record (``db``, shared with a standby: mission.db on the disk they share).

    ``status``: its process — ``standby`` (waiting for the primary's token to go), ``new`` (not
    started), ``open`` (serving the mission: :attr:`phase` is then its lifecycle's), ``dead``,
    ``dead-standby``, ``refused`` (another coordinator's token was live at its start)."""

    def __init__(self, sim, name: str, disk: Disk, standby: bool = False):
        self.sim, self.name, self.disk = sim, name, disk
        self.status = "standby" if standby else "new"
        self.lifecycle = cl.initial(sim.timeouts)
        self.alive = False
        self.state: ms.MissionState | None = None
        self.epoch = 0
        self.heard: dict = {}
        self.primary_lost: float | None = None
        self.resuming = None  # (stage, deploy, passengers) of the decision a pause interrupted
        self.life = 0         # its process's starts: what a paused process left scheduled dies with it

    @property
    def phase(self) -> str:
        return self.lifecycle.phase.value if self.status == "open" else self.status

    @phase.setter
    def phase(self, value: str) -> None:
        self.status = value

    # -------------------------------------------------------------- life
    def start(self, now: float) -> None:
        self.alive, self.life = True, self.life + 1
        if self.status == "standby":  # no State and no token of its own: it watches the primary's
            self.lifecycle = cl.initial(self.sim.timeouts, standby=True)
            self.advance(now)
            return
        self.open(now)

    def open(self, now: float, known: int = 0) -> None:
        """Open the mission: a fresh start, a restart or a takeover (the record folded, a new
        epoch above every one opened on its disk and ``known``, the primary's that a standby
        learnt from its State: storage.missiondb's ``min_epoch``)."""
        self.disk.events.append(ev.Opened(now))
        self.state = ms.fold(self.sim.spec, self.disk.events)
        self.epoch = max(self.disk.ballot.epoch, known) + 1
        self.disk.ballot = self.ballot
        self.status, self.heard = "open", {}
        self.sim.token(self.name, True)
        self.step(cl.Opened(now), now)
        self.sim.wake(self, now)

    def crash(self) -> None:
        self.alive, self.resuming = False, None  # a paused process killed does not resume
        self.status = "dead" if self.status != "standby" else "dead-standby"
        self.sim.token(self.name, False)

    # -------------------------------------------------------------- inputs
    def hear(self, m: Msg, now: float) -> None:
        if m.garbled or m.mission != "m":
            return  # checks 1-3 of [P-3.3]: dropped, not heard
        if m.kind == "token":
            self._token(m, now)
            return
        if self.status != "open" or self.state is None:
            return
        cid = m.src
        if m.kind in ("hello", "obs", "confirm", "own", "bye", "progress") and cid in self.sim.fleet.ids \
                and not (self.sim.plant == "slow-as-empty" and m.kind == "progress") \
                and not (m.kind == "progress" and m.get("stage") > self.state.next_stage):
            self.heard[cid] = now  # [P-10.5]; a carrier past the stage collected sends nothing more for it
        g = m.get
        if m.kind == "hello":
            self.apply(ev.Hello(cid, 1, cid, g("passengers_left"), g("next_stage"), g("fingerprint"), now, 4))
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
        elif m.kind == "decision" and self.ballot.below(Ballot(m.get("epoch"), m.get("coordinator", ""))):
            self.depose()  # coordinator.epochs.Epochs.decision_heard: a newer coordinator decides
            return
        self.advance(now)

    @property
    def ballot(self) -> Ballot:
        """Its authority: its epoch and its name (mission.ballot)."""
        return Ballot(self.epoch, self.name)

    def authority(self) -> tuple:
        """Who decides, as this process holds it: its ballot, and whether it stepped down without
        its store recording a newer ballot (the fence is the store's doing, not a message's)."""
        return self.ballot, self.lifecycle.phase is cl.Phase.DEPOSED and not self.fenced()

    def fenced(self) -> bool:
        """mission.db records a newer ballot than this process's (a standby took over on the
        shared disk): the store refuses its writes."""
        return self.ballot.below(self.disk.ballot)

    def depose(self) -> None:
        """Stop deciding, without End: a coordinator of a newer ballot took over."""
        self.lifecycle, _ = cl.step(self.lifecycle, cl.Deposed(), self.view())
        self.alive, self.resuming = False, None
        self.sim.token(self.name, False)

    def _token(self, m: Msg, now: float) -> None:
        who, alive = m.get("who"), m.get("alive")
        if who in self.sim.fleet.ids:
            if self.state is not None and self.status == "open":
                self.apply(ev.LivelinessChanged(who, alive, now))
                self.advance(now)
        elif who != self.name and self.status == "standby":
            self.primary_lost = None if alive else now

    def state_reply(self, cid: str) -> Msg:
        st = self.state
        last = st.next_stage - 1
        decision = None
        if last in st.decisions:
            decision = (last, float(self.sim.fleet.stage_times[last]), tuple(st.decisions[last].deploy))
        return msg("state", self.name, next_stage=st.next_stage, deployments=tuple(st.deployments_of(cid)),
                   last_decision=decision, ended=st.ended, epoch=self.epoch, coordinator=self.name,
                   fingerprint=self.sim.fleet.fingerprint)

    def apply(self, event) -> None:
        before = self.state
        self.state, effects = self.sim.coordinator_step(before, event)
        self.sim.invariants.check_coordinator(self, before, event, effects)
        for effect in effects:
            if isinstance(effect, ms.Record):
                self.disk.events.append(effect.event)
            elif isinstance(effect, ms.Accept):
                self.sim.accepted_at.setdefault(effect.carrier, self.sim.t)
                self.sim.send(self.name, effect.carrier, msg("accepted", self.name, next_stage=effect.next_stage,
                                                              epoch=self.epoch, coordinator=self.name))
            elif isinstance(effect, ms.Refuse):
                self.sim.send(self.name, effect.carrier, msg("refusal", self.name, reason=effect.reason))
            elif isinstance(effect, ms.Publish):
                d = self.state.decisions[effect.stage]
                self.sim.broadcast(self.name, msg("decision", self.name, stage=effect.stage, deploy=tuple(d.deploy),
                                                  t=float(self.sim.fleet.stage_times[effect.stage]), epoch=self.epoch,
                                                  coordinator=self.name))
            elif isinstance(effect, ms.Reject):
                self.sim.count_reject(effect.reason)

    # -------------------------------------------------------------- the lifecycle and its effects
    def view(self) -> cl.View:
        return cl.View(self.state, self.heard, self.primary_lost is None, self.primary_lost)

    def step(self, event, now: float) -> float | None:
        """Step the lifecycle with ``event`` and carry out its effects: the time to be woken at, None
        when it is to be stepped again at once."""
        self.lifecycle, effects = cl.step(self.lifecycle, event, self.view())
        until = None
        for effect in effects:
            if isinstance(effect, tm.Wait):
                until = effect.until
            else:
                self.run(effect, now)
        return until

    def advance(self, now: float) -> None:
        """Step the lifecycle at ``now`` and carry out what it says, until it says wait."""
        while self.alive:
            until = self.step(cl.Tick(now), now)
            if until is None:
                continue
            if math.isfinite(until):
                self.sim.wake(self, until)
            return

    def run(self, effect, now: float) -> None:
        if isinstance(effect, cl.TakeOver):
            self.open(now, max(d.epoch for d in self.sim.coordinators.values()))
        elif isinstance(effect, cl.Decide):
            self.decide(effect.stage, now)
        elif isinstance(effect, cl.RecordEnd):
            self.apply(ev.Ended(effect.reason, now))
        elif isinstance(effect, cl.PublishEnd):
            self.sim.broadcast(self.name, msg("end", self.name, epoch=self.epoch, coordinator=self.name))
        elif isinstance(effect, cl.Finish):
            self.sim.token(self.name, False)
            self.alive = False

    def decide(self, j: int, now: float) -> None:
        if self.fenced():  # a standby took over on the shared disk: deposed, no Decision
            self.depose()
            return
        for action in self.sim.fleet.operator_actions(self.state, j, now):  # a simulated operator's
            self.apply(action)
        deploy, passengers = self.sim.fleet.decide(self.state, j)
        paused = self.sim.injector.pause(self)
        if paused:  # the process stops between its epoch check and its record (a GC or VM pause)
            self.resuming = (j, deploy, passengers)
            self.sim.at(self.sim.t + paused, self._resume, self.life)
            return
        self.publish(j, deploy, passengers, now)

    def publish(self, j: int, deploy, passengers, now: float) -> None:
        if self.fenced():
            # the store fences a deposed coordinator's write: a newer epoch opened the mission
            # while this one was paused after its check; it steps down
            self.depose()
            return
        self.apply(self.sim.fleet.operator_decided(self.state, j, deploy, passengers, now))
        self.apply(ev.Published(j, now))
        self.sim.decided_at.setdefault(j, self.sim.t)
        self.step(cl.Decided(j, now), now)

    def _resume(self, life: int) -> None:
        if life != self.life or self.resuming is None:
            return  # it was killed while paused (and maybe restarted: a new process)
        (j, deploy, passengers), self.resuming = self.resuming, None
        if self.alive:
            now = self.sim.now_of(self.name)
            self.publish(j, deploy, passengers, now)
            self.advance(now)


def coordinator_processes(sim, faults) -> tuple[dict, bool]:
    """The mission's coordinator processes (name -> :class:`CoordinatorDriver`, the primary
    first) and whether a standby has a disk of its own. A standby watches the primary (takeover,
    pause, standby-crash); two coordinators started together (dual-start) both open the mission:
    the first is deposed at its first decision. A waiting standby has its own disk in half the
    missions (from a stream of its own: the draws of the rest stay the same): a deposed primary
    keeps its stale store, and a Decision of its older epoch can reach a carrier (docs/fleet.md,
    "Split brain"); always when it dies after its takeover and the primary restarts
    (standby-crash): on its own, staler disk the primary takes the standby's epoch again, and
    ballots tell the two apart."""
    names = ["coordinator"]
    if any(f.kind in ("takeover", "dual-start", "pause", "standby-crash") for f in faults):
        names.append("standby")
    together = any(f.kind == "dual-start" for f in faults)
    separate = ("standby" in names and not together
                and (np.random.default_rng([int(sim.fleet.seed) & 0xFFFFFFFF, sim.seed, 2]).random() < 0.5
                     or any(f.kind == "standby-crash" for f in faults)))
    shared = Disk("mission.db")
    return {n: CoordinatorDriver(sim, n, Disk(f"{n}/mission.db") if separate and n == "standby" else shared,
                                 standby=n == "standby" and not together) for n in names}, separate
