"""Deterministic simulation of a whole fleet: the real state machines on a simulated network and
clock, faults drawn from a seed, invariants after every event (docs/fleet.md, "Deterministic
simulation"; docs/architecture.md, "Time as an input").

One process runs a mission's coordinator(s) and carriers as drivers of the real pure machines —
:func:`mission.state.step` (the coordinator's rules, and :func:`mission.state.fold` over its
durable record for a restart), :func:`mission.carrier.step` (a carrier's), the timer rules of
:mod:`mission.timers` and the real planners (the stage step of ``planner.online``; on board,
``decide_local`` on a :class:`mission.peers.PeerBook` view) — on a discrete-event loop:

* **network**: every message goes through the router; per link and message a delay from a
  lognormal (per-link median from the seed), and in fault windows loss, duplication, reordering
  (a widened delay), a partition of one host (its messages and tokens lost both ways, the tokens
  vanishing a lease after the cut and reappearing at the heal) or the router lost (every host
  cut);
* **clocks**: one per host, with an offset, a drift and (a fault) forward jumps; the timer rules
  read the host's clock, never the simulated true time;
* **faults** (:data:`FAULT_KINDS`), drawn from the mission's seed: a schedule of timed actions.

Everything random comes from one ``numpy.random.Generator`` per mission, seeded by the mission's
seed; the loop breaks ties by insertion order. The same seed gives the same event trace: its
hash (:attr:`Outcome.trace_hash`) is the check.

This module is pure like the rest of mission/: it imports the planner core and numpy, nothing of
zenoh, pymunk, msgpack or sqlite. The scenario comes in as a :class:`Fleet` (built from a
scenario file by :mod:`launcher.simulate`, which ``python -m mission.simulate`` runs).
"""
from __future__ import annotations

import dataclasses
import hashlib
import heapq
import math
from dataclasses import dataclass, field

import numpy as np

from . import carrier as mc
from . import events as ev
from . import state as ms
from . import timers as tm
from .peers import PeerBook
from .timeouts import DEFAULTS

#: The fault kinds a schedule draws from (docs/fleet.md, "Deterministic simulation").
FAULT_KINDS = ("stale", "loss", "duplicate", "reorder", "partition", "router-lost", "crash", "coordinator-crash",
               "takeover", "dual-start", "pause", "freeze", "slow", "corrupt", "clock-jump")
#: Kinds under which the fleet must decide exactly like the offline planner: nothing is lost for
#: long and nobody is stuck, only slow, repeated, out of order or spoken to by strangers.
FAITHFUL_KINDS = frozenset({"duplicate", "reorder", "slow", "corrupt", "stale"})
#: Zenoh's lease: a cut-off session's tokens vanish this long after the cut (s).
LEASE_S = 10.0
#: The router: every message goes through it.
ROUTER = "router"


# --------------------------------------------------------------------------- the fleet

@dataclass(frozen=True)
class Fleet:
    """What the simulator needs of a scenario (all numbers; :mod:`launcher.simulate` builds it).

    Attributes:
        ids: carrier ids in scenario order; passengers: ``[R]``; valid: bool ``[R, N]``;
        stage_times: ``[N]`` s; x: float ``[R, N]``, what each carrier senses (NaN: invalid);
        problem: the planner core's instance; planner: the coordinator's planner (stateless);
        onboard: the on-board planner (``decide_local``); seed: the scenario's root seed;
        fingerprint: the world fingerprint every Hello carries; mode: the carriers' mode.
    """

    ids: tuple
    passengers: tuple
    valid: np.ndarray
    stage_times: tuple
    x: np.ndarray
    problem: object
    planner: object
    onboard: object
    seed: int
    fingerprint: str = "sim"
    mode: str = "hybrid"
    decisions: dict = field(default_factory=dict, compare=False, repr=False)  # the planner's memo

    @property
    def n_stages(self) -> int:
        return len(self.stage_times)

    def spec(self) -> ms.MissionSpec:
        return ms.MissionSpec.build(self.ids, self.valid, self.passengers, self.stage_times, self.fingerprint)

    def decide(self, state: ms.MissionState, j: int) -> tuple[tuple, tuple]:
        """(deploying ids, sorted; the passenger each releases): the coordinator's stage step on
        the mission's view. Planners are stateless, so the step is a function of its inputs and
        is memoised on them (the campaign's missions share most of their stages)."""
        from planner.online import stage_step

        x, deployed = state.planning_observations(j), state.deployed()
        released = state.releases() if self.problem.weights is not None else None
        key = (j, np.nan_to_num(x[:, : j + 1], nan=-1.0).tobytes(), deployed[:, :j].tobytes(),
               None if released is None else released[:, :j].tobytes())
        hit = self.decisions.get(key)
        if hit is None:
            step = stage_step(self.problem, x, deployed, self.planner, self.seed, j, released)
            rs = sorted(np.flatnonzero(step.deploy), key=lambda r: self.ids[r])
            hit = self.decisions[key] = (tuple(self.ids[r] for r in rs), tuple(int(step.passengers[r]) for r in rs))
        return hit

    def listened_by(self) -> dict:
        """carrier id -> the ids that listen to it (:func:`mission.peers.listened`: each carrier
        deciding on board listens to its conflict component), computed once."""
        key = ("listened",)
        if key not in self.decisions:
            from .peers import listened

            out = {cid: [] for cid in self.ids}
            for r, cid in enumerate(self.ids):
                for b in listened(self.problem, r):
                    out[self.ids[b]].append(cid)
            self.decisions[key] = {cid: tuple(v) for cid, v in out.items()}
        return self.decisions[key]

    def decide_local(self, local) -> bool:
        """A carrier's on-board decision of its stage on its local view (memoised on the view)."""
        from planner.decentralised import LocalDecision
        from planner.problem import stage_rng

        key = ("local", local.carrier, local.stage, np.nan_to_num(local.observations, nan=-1.0).tobytes(),
               local.deployed.tobytes(),
               local.seen.tobytes(), local.record.tobytes())
        hit = self.decisions.get(key)
        if hit is None:
            hit = self.decisions[key] = bool(LocalDecision.of(self.onboard.decide_local(
                local, stage_rng(self.seed, local.stage))).deploy)
        return hit

    def offline(self) -> dict:
        """The offline planner's decisions (stage -> deploying ids) with every observation known:
        what a fault-free mission must decide (computed once per fleet)."""
        if ("offline",) not in self.decisions:
            self.decisions[("offline",)] = self._offline()
        return self.decisions[("offline",)]

    def _offline(self) -> dict:
        state = ms.initial(self.spec())
        for cid in self.ids:
            state = ms.step(state, ev.LivelinessChanged(cid, True))[0]
            state = ms.step(state, ev.Hello(cid, 0, "sim", self.passengers[self.ids.index(cid)], 0, self.fingerprint,
                                            revision=4))[0]
        out = {}
        for j in range(self.n_stages):
            for r, cid in enumerate(self.ids):
                if self.valid[r, j]:
                    xv = None if np.isnan(self.x[r, j]) else int(self.x[r, j])
                    state = ms.step(state, ev.Observation(cid, j, self.stage_times[j], xv, (0.0, 0.0), 0))[0]
            deploy, passengers = self.decide(state, j)
            state = ms.step(state, ev.Decided(j, deploy, 0.0, 0.0, passengers))[0]
            out[j] = deploy
        return out


# --------------------------------------------------------------------------- messages, hosts, faults

@dataclass(frozen=True)
class Msg:
    """A message on the simulated network: ``kind`` (the wire's message names), the sender's id,
    the fields. ``mission`` other than the fleet's: a foreign message; ``garbled``: it does not
    decode (both fail checks 1–3 of [P-3.3]: dropped, not heard)."""

    kind: str
    src: str
    body: tuple = ()
    mission: str = "m"
    garbled: bool = False

    def get(self, name, default=None):
        return dict(self.body).get(name, default)


def msg(kind: str, src: str, **body) -> Msg:
    return Msg(kind, src, tuple(sorted(body.items())))


@dataclass
class Clock:
    """A host's clock: ``offset + (1 + drift) * T`` plus its forward jumps (a monotonic clock
    never goes back)."""

    offset: float
    drift: float
    jumped: float = 0.0

    def now(self, t: float) -> float:
        return self.offset + (1.0 + self.drift) * t + self.jumped


@dataclass(frozen=True)
class Fault:
    """One fault of a schedule: ``kind``, ``at`` s of true time, ``until`` (its end), ``who``
    (a carrier id, or ``coordinator``), ``size`` (a probability, a factor or seconds)."""

    kind: str
    at: float
    until: float
    who: str = ""
    size: float = 0.0

    def as_json(self) -> dict:
        return {"kind": self.kind, "at": round(self.at, 6), "until": round(self.until, 6), "who": self.who,
                "size": round(self.size, 6)}


def draw_faults(rng: np.random.Generator, kinds, ids, horizon: float) -> tuple[Fault, ...]:
    """A fault schedule: 1 to 3 faults of ``kinds`` (none when empty) within ``horizon`` s."""
    kinds = tuple(kinds)
    if not kinds:
        return ()
    out = []
    for _ in range(int(rng.integers(1, 4))):
        kind = kinds[int(rng.integers(len(kinds)))]
        at = float(rng.uniform(0.0, horizon))
        length = float(rng.uniform(0.01, 1.0) if kind == "crash" else rng.uniform(2.0, 60.0))
        who = str(ids[int(rng.integers(len(ids)))])
        size = {"loss": rng.uniform(0.05, 0.5), "duplicate": rng.uniform(0.1, 0.9), "reorder": rng.uniform(5, 50),
                "slow": rng.uniform(20.0, 80.0), "corrupt": float(rng.integers(1, 20)),
                "clock-jump": rng.uniform(1.0, 90.0), "pause": rng.uniform(LEASE_S + 0.5, LEASE_S + 10.0)}.get(kind, 0.0)
        if kind in ("coordinator-crash", "takeover", "dual-start", "router-lost", "pause"):
            who = "coordinator"
        out.append(Fault(kind, at, at + length, who, float(size)))
    return tuple(sorted(out, key=lambda f: (f.at, f.kind, f.who)))


# --------------------------------------------------------------------------- the outcome

@dataclass
class Outcome:
    """One simulated mission: its seed, faults, the trace's hash and length, the violations
    found (each a one-line string), what each carrier deployed, the reward, simulated seconds."""

    seed: int
    faults: tuple
    trace_hash: str = ""
    events: int = 0
    violations: list = field(default_factory=list)
    deployments: dict = field(default_factory=dict)
    reward: float = 0.0
    seconds: float = 0.0
    completed: bool = False

    def as_json(self) -> dict:
        return {"seed": self.seed, "trace_hash": self.trace_hash, "faults": [f.as_json() for f in self.faults],
                "deployments": self.deployments, "reward": round(self.reward, 9), "events": self.events,
                "seconds": round(self.seconds, 6), "completed": self.completed, "violations": self.violations}


@dataclass(frozen=True)
class LogEntry:
    """One stage of a carrier's durable log (the fields of ``storage.carrierlog.LogEntry`` that
    :func:`mission.report.merge` reads)."""

    stage: int
    t: float
    x: int | None = None
    observed: bool = False
    position: tuple = (0.0, 0.0)
    status: str | None = None
    deployed: bool = False
    passengers_left: int = 0


# --------------------------------------------------------------------------- the coordinator's driver

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

    def __init__(self, sim: "Simulation", name: str, disk: Disk, standby: bool = False):
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
            self.sim.wake(self, now + DEFAULTS.standby_poll_s)
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
            join_s = min(t.join_s, t.stage_s) if st.resumed else t.join_s
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
        self.apply(ev.Decided(j, deploy, 0.0, now, passengers))
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


# --------------------------------------------------------------------------- a carrier's driver

class CarrierDriver:
    """A carrier process on a simulated host: its machine (:mod:`mission.carrier`), its durable
    log (``log``: the outcomes and observations it wrote, kept across a crash), its body's work
    towards each stage (seconds of its host's time, :meth:`Simulation.work`), its waits by
    :mod:`mission.timers`.

    Phases: ``joining`` (asked State), ``work`` (driving to stage ``j``), ``wait`` (waiting for
    the Decision of ``j``), ``alone`` (waiting for its peers before deciding ``j`` on board),
    ``end`` (waiting for End after its last stage), ``done``, ``dead``."""

    def __init__(self, sim: "Simulation", cid: str):
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
        self.phase = "joining"
        self.sim.token(self.cid, True)
        self.sim.send(self.cid, ROUTER, msg("query", self.cid))
        self.sim.wake(self, now + DEFAULTS.state_query_s)

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
        elif isinstance(effect, mc.LogOutcome):
            entry = self.log.get(effect.stage) or LogEntry(effect.stage, float(s.fleet.stage_times[effect.stage]))
            self.log[effect.stage] = dataclasses.replace(entry, position=effect.position, status=effect.status,
                                                         deployed=effect.deployed,
                                                         passengers_left=effect.passengers_left)
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
            self.apply(mc.DecisionHeard(g("stage"), g("t"), tuple(g("deploy")), self.position(), g("epoch")), now)
        elif m.kind == "end":
            self.apply(mc.EndHeard(g("epoch")), now)
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
            for j in recalled:
                e = entries[j]
                self.apply(mc.Recalled(j, e.status, e.deployed, self.position(), e.x), now)
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
            if until is not None:
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
        next_stage = max((e.stage + 1 for e in done), default=0)
        for j in mc.replay_plan(self.machine, next_stage, [e.stage for e in done if e.deployed]):
            self.apply(mc.Replayed(j, self.position()), now)
        self.apply(mc.Joined(next_stage), now)
        self.listen()
        self.begin_stage(self.machine.stage, now)

    def finish(self, reason: str, now: float) -> None:
        self.sim.send(self.cid, "coordinators", msg("bye", self.cid, deployments=self.machine.deployments(),
                                                    reason=reason))
        self.phase, self.alive = "done", False
        self.sim.finished(self, reason)
        self.sim.token(self.cid, False, after=0.05)


# --------------------------------------------------------------------------- the simulation

#: Stop a mission this long (simulated s) after its liveness bound: it did not complete.
OVERRUN_S = 60.0


class Simulation:
    """One mission: the fleet's processes, the network, the clocks, the fault schedule, the
    invariants. ``plant``: a known bug class put back for the campaign's power test
    (:data:`PLANTS`), None for the real rules."""

    def __init__(self, fleet: Fleet, seed: int, faults=None, kinds=FAULT_KINDS, plant: str | None = None,
                 timeouts=DEFAULTS):
        self.fleet, self.seed, self.timeouts, self.plant = fleet, int(seed), timeouts, plant
        self.rng = np.random.default_rng([int(fleet.seed) & 0xFFFFFFFF, int(seed)])
        self.spec = fleet.spec()
        self.heap: list = []
        self.ticks: dict = {}                    # host -> (true time, life) of its one pending tick
        self.seq = 0
        self.t = 0.0
        self.trace = hashlib.blake2b(digest_size=16)
        self.events = 0
        self.rejects: dict = {}
        self.violations: list = []
        self.releases: dict = {cid: [] for cid in fleet.ids}
        self.confirmed: set = set()
        self.listeners: set = set()
        self.listened_by = fleet.listened_by() if fleet.mode != "coordinated" else {}
        self.epochs: dict = {}                   # (epoch, stage) -> the coordinator that published it
        self.finished_ids: dict = {}
        self.decided_at: dict = {}               # stage -> the true time its first Decision was published
        ids = fleet.ids
        horizon = 0.5 + 0.05 * fleet.n_stages
        drawn = draw_faults(self.rng, kinds, ids, horizon)  # drawn always: a given schedule replays the same draws after
        self.faults = tuple(faults) if faults is not None else drawn
        self.windows: dict = {}                 # kind -> its faults, in schedule order
        for f in self.faults:
            self.windows.setdefault(f.kind, []).append(f)
        self.carriers = {cid: CarrierDriver(self, cid) for cid in ids}
        names = ["coordinator"]
        if any(f.kind in ("takeover", "dual-start", "pause") for f in self.faults):
            names.append("standby")
        # a standby watches the primary (takeover, pause); two coordinators started together
        # (dual-start) both open the mission: the first is deposed at its first decision
        together = any(f.kind == "dual-start" for f in self.faults)
        # a waiting standby has its own disk in half the missions (from a stream of its own: the
        # draws of the rest stay the same): a deposed primary keeps its stale store, and a
        # Decision of its older epoch can reach a carrier (docs/fleet.md, "Split brain")
        self.separate = ("standby" in names and not together
                         and np.random.default_rng([int(fleet.seed) & 0xFFFFFFFF, int(seed), 2]).random() < 0.5)
        shared = Disk("mission.db")
        self.coordinators = {n: CoordinatorDriver(self, n, Disk(f"{n}/mission.db") if self.separate and n == "standby"
                                                  else shared, standby=n == "standby" and not together) for n in names}
        self.coordinator_names = tuple(names)  # ordered: every iteration that sends is in a fixed order
        hosts = [*names, *ids]
        self.clocks = {h: Clock(float(self.rng.uniform(0, 1e4)), float(self.rng.uniform(-1e-4, 1e-4))) for h in hosts}
        self.median = {h: float(self.rng.uniform(2e-4, 3e-3)) for h in hosts}   # one-way to the router, s
        self.cut: set = set()
        self.lapsed: set = set()                 # hosts whose tokens vanished a lease after a cut or pause
        self.fifo: dict = {}                     # (src, dst) -> the last delivery time scheduled
        self.frozen: dict = {}
        self.slow: dict = {}
        self.paused: set = set()
        self.work_s = {cid: float(self.rng.uniform(0.005, 0.05)) for cid in ids}
        self._schedule_faults()
        self.at(0.0, self._start, self.coordinators["coordinator"], "coordinator")
        if "standby" in self.coordinators:
            self.at(0.002, self._start, self.coordinators["standby"], "standby")
        for cid in ids:
            self.at(float(self.rng.uniform(0.01, 0.5)), self._start, self.carriers[cid], cid)

    # -------------------------------------------------------------- the loop
    def _start(self, driver, host: str) -> None:
        driver.start(self.now_of(host))

    def at(self, t: float, fn, *args) -> None:
        self.seq += 1
        heapq.heappush(self.heap, (t, self.seq, fn, args))

    def now_of(self, host: str) -> float:
        return self.clocks[host].now(self.t)

    def true_of(self, host: str, local: float) -> float:
        c = self.clocks[host]
        return (local - c.offset - c.jumped) / (1.0 + c.drift)

    def wake(self, driver, local: float) -> None:
        """Tick ``driver`` when its host's clock reads ``local`` (a stale tick of an earlier life
        is dropped). A driver has one pending tick, its earliest: a tick runs its whole rule, so a
        later one asked for meanwhile is asked again by that run if it is still wanted."""
        name = driver.name if isinstance(driver, CoordinatorDriver) else driver.cid
        life = getattr(driver, "life", 0)
        t = max(self.t, self.true_of(name, local)) + 1e-9
        pending = self.ticks.get(name)
        if pending is not None and pending[1] == life and pending[0] <= t:
            return
        self.ticks[name] = (t, life)
        self.at(t, self._tick, driver, name, life)

    def _tick(self, driver, name: str, life: int) -> None:
        if self.ticks.get(name) != (self.t, life):
            return  # superseded by an earlier tick, which asked again for what it still wants
        del self.ticks[name]
        if not driver.alive or getattr(driver, "life", 0) != life or self._frozen(name):
            return
        driver.advance(self.now_of(name))

    def _frozen(self, name: str) -> bool:
        until = self.frozen.get(name)
        return until is not None and self.t < until

    def run(self) -> Outcome:
        bound = self.liveness_bound()
        while self.heap:
            t, _, fn, args = heapq.heappop(self.heap)
            if t > bound + OVERRUN_S:
                break
            self.t = t
            try:
                fn(*args)
            except Exception as exc:  # a process of the fleet would have crashed: a finding, not the end of a campaign
                self.violate(f"a process raised {type(exc).__name__}: {exc}")
                break
            if self.done():
                break
        return self.outcome(bound)

    def done(self) -> bool:
        return (any(d.phase == "done" for d in self.coordinators.values())  # first: the cheap, rarely true test
                and all(d.phase in ("done", "dead", "deposed", "dead-standby", "standby", "refused")
                        for d in self.coordinators.values())
                and all(d.phase in ("done", "dead") for d in self.carriers.values()))

    def liveness_bound(self) -> float:
        """Simulated seconds within which a mission whose schedule heals completes: the last
        fault's end, then per stage the longest work and the waits a lost message costs."""
        t = self.timeouts
        healed = max((f.until for f in self.faults), default=0.0)
        slow = max((f.size for f in self.faults if f.kind == "slow"), default=0.05)
        per_stage = slow + t.decision_s + t.silence_s + LEASE_S + 1.0
        return healed + t.join_s + t.coordinator_s + self.fleet.n_stages * per_stage + t.end_s + t.bye_s + 5.0

    # -------------------------------------------------------------- the network
    def send(self, src: str, dst: str, m: Msg) -> None:
        """``dst``: a participant, ``coordinators`` (every coordinator) or the router (a State
        query: every coordinator answers)."""
        if dst in (ROUTER, "coordinators"):
            for name in self.coordinator_names:
                self._deliver(src, name, m)
        else:
            self._deliver(src, dst, m)

    def broadcast(self, src: str, m: Msg) -> None:
        """To every carrier; a Decision also to the other live coordinators (they subscribe to
        the decision key: coordinator.epochs._heard_decision)."""
        for cid in self.fleet.ids:
            self._deliver(src, cid, m)
        if m.kind == "decision" and self.separate:
            for name in self.coordinator_names:
                if name != src and self.has_token(name):
                    self._deliver(src, name, m)

    def to_listeners(self, src: str, m: Msg) -> None:
        """To the carriers listening to ``src`` (its conflict component's, once they listen)."""
        for cid in self.listened_by.get(src, ()):
            if cid in self.listeners:
                self._deliver(src, cid, m)

    def hears(self, dst: str, src: str) -> bool:
        """Carrier ``dst`` is subscribed to carrier ``src``'s messages and token."""
        return dst in self.listeners and dst in self.listened_by.get(src, ())

    def _window(self, kind: str):
        for f in self.windows.get(kind, ()):
            if f.at <= self.t < f.until:
                return f
        return None

    def _deliver(self, src: str, dst: str, m: Msg, reliable: bool = False) -> None:
        """``reliable``: a liveliness token's change, which is state kept in step by the session
        (Zenoh's liveliness), not a message: never lost or repeated while the link is up."""
        if src in self.cut or dst in self.cut:
            return
        lost = None if reliable else self._window("loss")
        if lost is not None and self.rng.random() < lost.size:
            return
        arrive = self.t + self._delay(src, dst)
        if self._window("reorder") is None:  # one session, one link: first sent, first delivered
            arrive = max(arrive, self.fifo.get((src, dst), 0.0))
            self.fifo[(src, dst)] = arrive
        self.at(arrive, self._arrive, src, dst, m)
        dup = None if reliable else self._window("duplicate")
        if dup is not None and self.rng.random() < dup.size:
            self.at(arrive + self._delay(src, dst), self._arrive, src, dst, m)

    def _delay(self, src: str, dst: str) -> float:
        d = sum(self.median[h] * math.exp(0.5 * self.rng.standard_normal()) for h in (src, dst) if h in self.median)
        wide = self._window("reorder")
        return d * (1.0 + float(self.rng.uniform(0, wide.size))) if wide is not None else d

    def _arrive(self, src: str, dst: str, m: Msg) -> None:
        if src in self.cut or dst in self.cut:
            return
        until = self.frozen.get(dst)
        if until is not None and self.t < until:
            self.at(until, self._arrive, src, dst, m)  # held in its socket until it runs again
            return
        driver = self.carriers.get(dst) or self.coordinators.get(dst)
        if driver is None or not driver.alive and driver.phase != "standby":
            return
        self.events += 1
        self.trace.update(f"{self.t:.9f}|{dst}|{m.kind}|{m.src}|{m.body}|{m.mission}|{m.garbled}\n".encode())
        driver.hear(m, self.now_of(dst))

    def token(self, name: str, alive: bool, after: float = 0.0) -> None:
        """``name``'s liveliness token appears or vanishes: the coordinators see every token; a
        carrier sees the coordinators' and, once it listens to its peers, theirs."""
        self.at(self.t + after, self._token_now, name, alive)

    def _token_now(self, name: str, alive: bool) -> None:
        for other in [*self.coordinator_names, *self.fleet.ids]:
            if other == name:
                continue
            if other in self.fleet.ids and name in self.fleet.ids and not self.hears(other, name):
                continue
            self._deliver(name, other, msg("token", name, who=name, alive=alive), reliable=True)
        if alive:  # a newcomer's subscriptions see the tokens that are there (liveliness history)
            for other in self._present(name):
                self._deliver(other, name, msg("token", other, who=other, alive=True), reliable=True)

    def has_token(self, name: str) -> bool:
        """``name``'s process lives and has declared its token (a waiting standby has none)."""
        d = self.carriers.get(name) or self.coordinators.get(name)
        return d is not None and d.alive and getattr(d, "phase", "") != "standby"

    def _present(self, name: str):
        coords = [n for n in self.coordinator_names if n != name and self.has_token(n)]
        if name in self.coordinator_names:
            return [*coords, *(cid for cid, d in self.carriers.items() if d.alive)]
        return coords

    def peers_seen(self, cid: str) -> set:
        return {o for o, d in self.carriers.items() if d.alive and o != cid and o not in self.cut and self.hears(cid, o)}

    # -------------------------------------------------------------- the machines, as planted
    def coordinator_step(self, state, event):
        new, effects = ms.step(state, event)
        if self.plant == "confirm-twice" and isinstance(event, ev.Confirmed) and not effects:
            first = state.confirms.get((event.carrier, event.stage))
            if first is not None and first.deployed == event.deployed:
                effects = (ms.Record(event, event.stage),)  # the planted bug: a repeat counted again
        if self.plant == "bye-without-hello" and isinstance(event, ev.Bye) and effects and isinstance(effects[0], ms.Reject) \
                and effects[0].reason in ("no-hello",):
            new = dataclasses.replace(state, byes=state.byes | {event.carrier})
            effects = (ms.Record(event, None),)
        return new, effects

    def carrier_step(self, state, event):
        if self.plant == "older-epoch" and isinstance(event, mc.DecisionHeard) and event.epoch < state.epoch:
            event = dataclasses.replace(event, epoch=state.epoch)  # the planted bug: no epoch check
        return mc.step(state, event)

    # -------------------------------------------------------------- faults
    def _schedule_faults(self) -> None:
        for f in self.faults:
            if f.kind == "partition":
                self.at(f.at, self._cut, (f.who,), f.until)
            elif f.kind == "router-lost":
                self.at(f.at, self._cut, (*self.coordinator_names, *self.fleet.ids), f.until)
            elif f.kind == "crash":
                self.at(f.at, self._crash, self.carriers[f.who], f.until)
            elif f.kind == "coordinator-crash":
                self.at(f.at, self._crash, self.coordinators["coordinator"], f.until)
            elif f.kind == "takeover":
                self.at(f.at, self._crash, self.coordinators["coordinator"], None)
            elif f.kind == "freeze":
                self.at(f.at, self._freeze, f.who, f.until)
            elif f.kind == "slow":
                self.slow[f.who] = f
            elif f.kind == "clock-jump":
                self.at(f.at, self._jump, f.who, f.size)
            elif f.kind in ("corrupt", "stale"):
                self._inject(f)

    def _cut(self, hosts, until: float) -> None:
        hosts = [h for h in hosts if h not in self.cut]
        self.cut.update(hosts)
        self.at(self.t + min(LEASE_S, until - self.t), self._lease, tuple(hosts), False)
        self.at(until, self._heal, tuple(hosts))

    def _lease(self, hosts, alive: bool, reached: bool = False) -> None:
        """The tokens across the cut vanish (the lease expired) or reappear (it healed).
        ``reached``: only between hosts the network reaches (a paused process's session; a host
        cut off meanwhile learns the truth when its own cut heals)."""
        (self.lapsed.difference_update if alive else self.lapsed.update)(hosts)
        for h in hosts:
            for other in [*self.coordinator_names, *self.fleet.ids]:
                if other == h or reached and (other in self.cut or h in self.cut):
                    continue
                self._notify(other, h, alive)
                self._notify(h, other, alive)

    def _notify(self, dst: str, who: str, alive: bool) -> None:
        if alive and not self.has_token(who):
            return
        if dst in self.fleet.ids and who in self.fleet.ids and not self.hears(dst, who):
            return
        target = self.carriers.get(dst) or self.coordinators.get(dst)
        if target is None or not (target.alive or target.phase == "standby"):
            return
        if self._frozen(dst):
            self.at(self.frozen[dst], self._notify, dst, who, alive)
            return
        self.events += 1
        self.trace.update(f"{self.t:.9f}|{dst}|token|{who}|{alive}\n".encode())
        target.hear(msg("token", who, who=who, alive=alive), self.now_of(dst))

    def claimed(self, name: str) -> bool:
        """Another coordinator's token is live where ``name`` looks for it at its start
        (:meth:`coordinator.epochs.Epochs._claim`): it lives, has a token (a waiting standby has
        none), its lease has not lapsed, and ``name`` reaches the router."""
        return name not in self.cut and any(
            self.has_token(other) and other not in self.lapsed for other in self.coordinator_names if other != name)

    def _heal(self, hosts) -> None:
        self.cut.difference_update(hosts)
        self._lease(hosts, True)

    def _crash(self, driver, restart: float | None) -> None:
        if driver.alive or driver.phase == "standby":
            driver.crash()
        if restart is not None:
            self.at(restart, self._restart, driver)

    def _restart(self, driver) -> None:
        if not driver.alive and driver.phase in ("dead", "dead-standby"):
            self.frozen.pop(driver.name if isinstance(driver, CoordinatorDriver) else driver.cid, None)  # a new process
            if isinstance(driver, CoordinatorDriver):
                driver.phase = "new" if driver.phase == "dead" else "standby"
                if driver.phase == "new" and self.claimed(driver.name):
                    driver.phase = "refused"  # coordinator.epochs: DuplicateCoordinator, it exits
                    return
            driver.start(self.now_of(driver.name if isinstance(driver, CoordinatorDriver) else driver.cid))

    def pause(self, driver: CoordinatorDriver) -> float:
        """Seconds ``driver`` pauses now (0: none): the first decision of the primary at or after
        a ``pause`` fault's start. Its whole process stops, its session too: its token vanishes
        a lease later and reappears when it runs again."""
        f = next((f for f in self.faults if f.kind == "pause" and f.at <= self.t and f not in self.paused), None)
        if f is None or driver.name != "coordinator":
            return 0.0
        self.paused.add(f)
        self.frozen[driver.name] = self.t + f.size
        self.at(self.t + min(LEASE_S, f.size), self._paused_lease, driver, driver.life, False)
        self.at(self.t + f.size, self._paused_lease, driver, driver.life, True)
        return f.size

    def _paused_lease(self, driver: CoordinatorDriver, life: int, alive: bool) -> None:
        """A paused process's session lapses and comes back with it; a process killed while paused
        took its session along (:meth:`CoordinatorDriver.crash`), a restarted one has its own."""
        if driver.life == life and driver.alive:
            self._lease((driver.name,), alive, reached=True)

    def _freeze(self, who: str, until: float) -> None:
        self.frozen[who] = until
        driver = self.carriers[who]
        self.at(until, lambda: driver.alive and driver.advance(self.now_of(who)))

    def _jump(self, host: str, seconds: float) -> None:
        self.clocks[host].jumped += seconds
        driver = self.carriers.get(host) or self.coordinators.get(host)
        if driver is not None and driver.alive:
            driver.advance(self.now_of(host))

    def _inject(self, f: Fault) -> None:
        """Messages nobody of this mission sent: garbled ones, another mission's, and (``stale``)
        a carrier's from an earlier run of the mission, arriving before its Hello."""
        ids = self.fleet.ids
        for k in range(max(1, int(f.size))):
            cid = str(ids[int(self.rng.integers(len(ids)))])
            if f.kind == "stale":
                when = float(self.rng.uniform(0.0, 0.009))
                m = [msg("bye", cid, deployments=(0,), reason="finished"),
                     msg("confirm", cid, stage=0, deployed=True, status="deployed", passengers_left=0),
                     msg("obs", cid, stage=0, t=float(self.fleet.stage_times[0]), x=99, passengers_left=0)][k % 3]
            else:
                when = float(self.rng.uniform(f.at, f.until))
                m = dataclasses.replace(msg("obs", cid, stage=0, t=0.0, x=1, passengers_left=0),
                                        **({"garbled": True} if k % 2 == 0 else {"mission": "other"}))
            dst = "coordinator" if k % 4 != 3 else cid
            self.at(when, self._arrive, "intruder", dst, m)

    def work(self, driver, j: int) -> float:
        """Seconds of its host's time carrier ``driver`` works towards stage j's observation."""
        f = self.slow.get(driver.cid)
        if f is not None and f.at <= self.t < f.until + f.size * 3:
            return f.size
        return self.work_s[driver.cid] * float(self.rng.uniform(0.5, 1.5))

    # -------------------------------------------------------------- the invariants
    def violate(self, line: str) -> None:
        if len(self.violations) < 20:
            self.violations.append(f"t={self.t:.3f} s: {line}")

    def count_reject(self, reason: str) -> None:
        self.rejects[reason] = self.rejects.get(reason, 0) + 1

    def released(self, driver: CarrierDriver, j: int) -> None:
        """A passenger left carrier ``driver`` at stage j: the physical truth."""
        cid = driver.cid
        if j in self.releases[cid]:
            self.violate(f"carrier {cid} deployed a second passenger at stage {j}")
        self.releases[cid].append(j)
        if len(self.releases[cid]) > self.fleet.passengers[driver.r]:
            self.violate(f"carrier {cid} deployed {len(self.releases[cid])} passengers, it has "
                         f"{self.fleet.passengers[driver.r]}")

    def finished(self, driver: CarrierDriver, reason: str) -> None:
        self.finished_ids[driver.cid] = reason

    def check_carrier(self, driver: CarrierDriver, before, event, effects) -> None:
        for effect in effects:
            if isinstance(effect, mc.Deploy) and effect.stage != before.stage:
                self.violate(f"carrier {driver.cid} deployed at stage {effect.stage} while at stage {before.stage}")
            if isinstance(effect, mc.LogOutcome) and isinstance(event, mc.DecisionHeard) and event.epoch < before.epoch:
                self.violate(f"carrier {driver.cid} acted on a Decision of epoch {event.epoch} for stage "
                             f"{event.stage} after hearing epoch {before.epoch}")

    def check_on_board(self, driver: CarrierDriver) -> None:
        """A flying carrier counts the passengers it carries (its restarts included)."""
        m, carried = driver.machine, self.fleet.passengers[driver.r] - len(self.releases[driver.cid])
        if m.flying and m.passengers_left != carried:
            self.violate(f"carrier {driver.cid} counts {m.passengers_left} passenger(s) on board, it carries {carried}")

    @property
    def db(self) -> list:
        """The mission's record: the disk of the coordinator that completed it (else the primary's)."""
        final = next((d for d in self.coordinators.values() if d.phase == "done"), self.coordinators["coordinator"])
        return final.disk.events

    def check_coordinator(self, driver: CoordinatorDriver, before, event, effects) -> None:
        for effect in effects:
            if not isinstance(effect, ms.Record):
                continue
            e = effect.event
            if isinstance(e, (ev.Bye, ev.Observation, ev.Confirmed)) and e.carrier not in before.accepted:
                self.violate(f"{driver.name} recorded a {type(e).__name__} of {e.carrier} without its accepted Hello")
            if isinstance(e, ev.Confirmed):
                key = (driver.disk.name, e.carrier, e.stage)  # each store records it once
                if key in self.confirmed:
                    self.violate(f"{driver.name} recorded a second Confirm of {e.carrier} at stage {e.stage}")
                self.confirmed.add(key)
            if isinstance(e, ev.Decided):
                first = self.epochs.setdefault((driver.epoch, e.stage), driver.name)
                if first != driver.name:
                    self.violate(f"two coordinators decided stage {e.stage} in epoch {driver.epoch}")

    def outcome(self, bound: float) -> Outcome:
        from planner.problem import evaluate

        fleet = self.fleet
        out = Outcome(self.seed, self.faults, self.trace.hexdigest(), self.events, self.violations, seconds=self.t)
        out.deployments = {cid: sorted(js) for cid, js in self.releases.items()}
        deployed = np.zeros(fleet.valid.shape, dtype=bool)
        for cid, js in self.releases.items():
            deployed[fleet.ids.index(cid), js] = True
        out.reward = float(evaluate(fleet.problem, deployed, fleet.x)[0])
        out.completed = self.done()
        final = next((d for d in self.coordinators.values() if d.phase == "done"), None)
        if not out.completed:
            self.violate(f"the mission did not complete within its liveness bound of {bound:.0f} s "
                         + ", ".join(f"{n}:{d.phase}" for n, d in self.coordinators.items()) + " "
                         + ", ".join(f"{c}:{d.phase}" for c, d in self.carriers.items() if d.phase != "done"))
        else:
            self.check_record(out.deployments)
        if out.completed and self.faults_faithful():
            offline = fleet.offline()
            if final is not None and {j: d.deploy for j, d in final.state.decisions.items()} != offline:
                self.violate("the fleet's decisions differ from the offline planner's (faults: "
                             + ", ".join(f.kind for f in self.faults) + ")")
        out.violations = self.violations
        return out

    def check_record(self, physical: dict) -> None:
        """No deployment lost or counted twice: the mission's record — mission.db merged with the
        carriers' logs, as the report merges them (:func:`mission.report.merge`) — holds exactly
        the passengers that left each carrier."""
        from .report import CarrierRecord, merge

        logs = [CarrierRecord(cid, f"carriers/{cid}.db", {}, tuple(sorted(d.log.values(), key=lambda e: e.stage)))
                for cid, d in self.carriers.items()]
        merged = merge(self.spec, self.db, logs)
        confirmed = merged.state.confirmed_deployments()
        for r, cid in enumerate(self.fleet.ids):
            record, made = merged.state.deployments_of(cid), set(physical[cid])
            sure = set(np.flatnonzero(confirmed[r]).tolist())
            if self.carriers[cid].phase == "done" and cid in merged.state.byes and record != physical[cid]:
                # its Bye on record: it told the coordinator all it made (one whose Bye was lost, e.g.
                # a coordinated carrier giving up while the coordinator was down, is as one that
                # never came back: a Decision for it after it left counts as gone)
                self.violate(f"the mission's record (mission.db and the carriers' logs) has deployments {record} "
                             f"of {cid}, which deployed at {physical[cid]}")
            elif not sure <= made <= set(record):
                # a carrier that never came back: its unanswered decisions may or may not have been made
                self.violate(f"the mission's record has deployments {record} (confirmed {sorted(sure)}) of {cid}, "
                             f"which never came back and deployed at {physical[cid]}")

    def faults_faithful(self) -> bool:
        return all(f.kind in FAITHFUL_KINDS for f in self.faults)


def simulate(fleet: Fleet, seed: int, kinds=FAULT_KINDS, faults=None, plant: str | None = None) -> Outcome:
    """One mission of ``fleet`` with seed ``seed``: faults drawn from ``kinds`` (or ``faults``,
    a given schedule: a replay, a shrunk schedule)."""
    return Simulation(fleet, seed, faults=faults, kinds=kinds, plant=plant).run()


#: The bug classes the campaign's power test puts back, one at a time (docs/fleet.md,
#: "Deterministic simulation"): an identical repeated Confirm counted twice, a deployment
#: forgotten on restart, a Decision of an older epoch accepted, a slow carrier taken as ∅ (its
#: Progress not heard), a Bye without Hello accepted.
PLANTS = ("confirm-twice", "forget-on-restart", "older-epoch", "slow-as-empty", "bye-without-hello")


def combined_hash(hashes) -> str:
    """One hash of a campaign's trace hashes, in seed order."""
    return hashlib.blake2b("".join(hashes).encode(), digest_size=16).hexdigest()


if __name__ == "__main__":
    from launcher.simulate import main

    raise SystemExit(main())
