"""One simulated mission (:class:`Simulation`): the fleet's processes, the network, the clocks,
the fault schedule and the invariants checked after every event; :func:`simulate` runs one."""
from __future__ import annotations

import dataclasses
import hashlib
import heapq
import math
import traceback
from pathlib import Path

import numpy as np

from .. import carrier as mc
from .. import events as ev
from .. import state as ms
from ..ballot import Ballot
from .carrier import CarrierDriver
from .coordinator import CoordinatorDriver, Disk
from .fleet import Fleet
from .links import LinkLayer
from .model import (FAITHFUL_KINDS, FAULT_KINDS, LEASE_S, OPEN_RETRY_S, ROUTER, Clock, Fault, Msg, Outcome, draw_faults,
                    msg)
from ..modes import Mode

#: Stop a mission this long (simulated s) after its liveness bound: it did not complete.
OVERRUN_S = 60.0


class Simulation:
    """One mission: the fleet's processes, the network, the clocks, the fault schedule, the
    invariants. ``plant``: a known bug class put back for the campaign's power test
    (:data:`PLANTS`), None for the real rules."""

    def __init__(self, fleet: Fleet, seed: int, faults=None, kinds=FAULT_KINDS, plant: str | None = None,
                 timeouts=None):
        self.fleet, self.seed, self.plant = fleet, int(seed), plant
        self.timeouts = fleet.timeouts if timeouts is None else timeouts  # the fleet's: its links' waits
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
        self.listened_by = fleet.listened_by() if fleet.mode != Mode.COORDINATED else {}
        self.epochs: dict = {}                   # (ballot, stage) -> the coordinator that published it
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
        if any(f.kind in ("takeover", "dual-start", "pause", "standby-crash") for f in self.faults):
            names.append("standby")
        # a standby watches the primary (takeover, pause); two coordinators started together
        # (dual-start) both open the mission: the first is deposed at its first decision
        together = any(f.kind == "dual-start" for f in self.faults)
        # a waiting standby has its own disk in half the missions (from a stream of its own: the
        # draws of the rest stay the same): a deposed primary keeps its stale store, and a
        # Decision of its older epoch can reach a carrier (docs/fleet.md, "Split brain")
        # (always, when the standby dies after its takeover and the primary restarts: on its
        # own, staler disk it takes the standby's epoch again; ballots tell the two apart)
        self.separate = ("standby" in names and not together
                         and (np.random.default_rng([int(fleet.seed) & 0xFFFFFFFF, int(seed), 2]).random() < 0.5
                              or any(f.kind == "standby-crash" for f in self.faults)))
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
        # the scenario's link model (its own Generator: a perfect mission draws and delays as without one)
        links = fleet.links
        self.links = LinkLayer(self, links, seed) if links is not None and links.spec.model != "perfect" else None
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
                where = traceback.extract_tb(exc.__traceback__)[-1]
                self.violate(f"a process raised {type(exc).__name__}: {exc} "
                             f"({Path(where.filename).name}:{where.lineno} in {where.name})")
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

    def coordinator_of(self, m: Msg) -> str:
        """The coordinator id a carrier reads in ``m`` (its ballot's; "" under the ``no-ballot``
        plant, as before revision 6)."""
        return "" if self.plant == "no-ballot" else m.get("coordinator", "")

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
        extra = 0.0
        if self.links is not None and not reliable:
            extra = self.links.delay(src, dst, m)
            if extra is None:
                return
        arrive = self.t + self._delay(src, dst) + extra
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
        if self.plant == "older-epoch" and isinstance(event, mc.DecisionHeard) \
                and Ballot(event.epoch, event.coordinator).below(state.ballot):
            event = dataclasses.replace(event, epoch=state.epoch, coordinator=state.coordinator)  # no ballot check
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
            elif f.kind == "standby-crash":  # the primary dies, the standby takes over and dies,
                self.at(f.at, self._crash, self.coordinators["coordinator"], f.until)  # the primary restarts
                self.at(f.at + f.size, self._crash, self.coordinators["standby"], None)
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
        # a refused or deposed coordinator exited too (another's token was live at its start, or a
        # newer one decides): its supervisor starts it again when its restart is due
        if not driver.alive and driver.phase in ("dead", "dead-standby", "refused", "deposed"):
            self.frozen.pop(driver.name if isinstance(driver, CoordinatorDriver) else driver.cid, None)  # a new process
            if isinstance(driver, CoordinatorDriver):
                driver.phase = "standby" if driver.phase == "dead-standby" else "new"
                self._open(driver, driver.life)
                return
            driver.start(self.now_of(driver.cid))

    def _open(self, driver: CoordinatorDriver, life: int) -> None:
        """A coordinator process opening its session, a client of the router: while its host is
        cut off it cannot (wire.zconfig.open_session tries every ``OPEN_RETRY_S``; one that
        gives up after its timeout is started again by its supervisor, as if it went on
        trying); once open, one that is no standby refuses to start while another coordinator's
        token is live (coordinator.epochs: DuplicateCoordinator, it exits). A coordinator
        restarted during a router loss thus never opens a second epoch beside a live standby's."""
        if driver.life != life or driver.alive:
            return
        if driver.name in self.cut:
            self.at(self.t + OPEN_RETRY_S, self._open, driver, life)
            return
        if driver.phase == "new" and self.claimed(driver.name):
            driver.phase = "refused"
            return
        driver.start(self.now_of(driver.name))

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

    def _paused_lease(self, driver, life: int, alive: bool) -> None:
        """A paused (or frozen) process's session lapses and comes back with it; a process killed
        while paused took its session along (:meth:`CoordinatorDriver.crash`), a restarted one has
        its own."""
        if driver.life == life and driver.alive:
            self._lease((driver.name if isinstance(driver, CoordinatorDriver) else driver.cid,), alive, reached=True)

    def _freeze(self, who: str, until: float) -> None:
        """Carrier ``who`` stuck until ``until``: alive and silent; stuck longer than a lease, its
        session lapses too (its token vanishes a lease after, and reappears when it runs again),
        as a stopped process's does on the real network."""
        self.frozen[who] = until
        driver = self.carriers[who]
        if until - self.t > LEASE_S and driver.alive:
            self.at(self.t + LEASE_S, self._paused_lease, driver, driver.life, False)
            self.at(until, self._paused_lease, driver, driver.life, True)
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
            if isinstance(effect, mc.LogOutcome) and isinstance(event, mc.DecisionHeard):
                said = Ballot(event.epoch, event.coordinator)
                if said.below(before.ballot):
                    self.violate(f"carrier {driver.cid} acted on a Decision of ballot {said} for stage "
                                 f"{event.stage} after hearing ballot {before.ballot}")
                true = Ballot(event.epoch, driver.sender)  # who sent it, whatever the message says
                if true.below(driver.acted):
                    self.violate(f"carrier {driver.cid} acted on a Decision of ballot {true} for stage {event.stage} "
                                 f"after acting on one of ballot {driver.acted}")
                driver.acted = driver.acted.highest(true)

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
                first = self.epochs.setdefault((driver.ballot, e.stage), driver.name)
                if first != driver.name:
                    self.violate(f"two coordinators decided stage {e.stage} in ballot {driver.ballot}")

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
        if self.links is not None:
            out.links = {"sent": self.links.sent, "lost": self.links.lost}
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
        from ..report import CarrierRecord, merge

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
        """Nothing lost for long: faithful fault kinds only, and no message lost by the link model
        (its delays alone are faithful)."""
        return all(f.kind in FAITHFUL_KINDS for f in self.faults) and (self.links is None or self.links.lost == 0)


def simulate(fleet: Fleet, seed: int, kinds=FAULT_KINDS, faults=None, plant: str | None = None) -> Outcome:
    """One mission of ``fleet`` with seed ``seed``: faults drawn from ``kinds`` (or ``faults``,
    a given schedule: a replay, a shrunk schedule)."""
    return Simulation(fleet, seed, faults=faults, kinds=kinds, plant=plant).run()


#: The bug classes the campaign's power test puts back, one at a time (docs/fleet.md,
#: "Deterministic simulation"): an identical repeated Confirm counted twice, a deployment
#: forgotten on restart, a Decision of an older epoch accepted, a slow carrier taken as ∅ (its
#: Progress not heard), a Bye without Hello accepted, carriers that rank coordinators by their
#: epoch alone (no ballots: the coordinator id not read).
PLANTS = ("confirm-twice", "forget-on-restart", "older-epoch", "slow-as-empty", "bye-without-hello", "no-ballot")


def combined_hash(hashes) -> str:
    """One hash of a campaign's trace hashes, in seed order."""
    return hashlib.blake2b("".join(hashes).encode(), digest_size=16).hexdigest()
