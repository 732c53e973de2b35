"""One simulated mission (:class:`Simulation`): the fleet's processes, the network, the clocks,
the fault schedule and the invariants checked after every event; :func:`simulate` runs one."""
from __future__ import annotations

import hashlib
import heapq
import math
import traceback
from pathlib import Path

import numpy as np

from .carrier import CarrierDriver
from .coordinator import CoordinatorDriver, coordinator_processes
from .injector import Injector
from .invariants import Invariants
from .plants import planted_carrier_step, planted_coordinator_step, read_coordinator
from .fleet import Fleet
from .links import LinkLayer
from .model import (FAULT_KINDS, LEASE_S, ROUTER, Clock, Msg, Outcome, draw_faults,
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
        self.listeners: set = set()
        self.listened_by = fleet.listened_by() if fleet.mode != Mode.COORDINATED else {}
        self.finished_ids: dict = {}
        # true times: stage -> its first Decision's; carrier -> its first acceptance, its start
        self.decided_at, self.accepted_at, self.started_at = {}, {}, {}
        ids = fleet.ids
        horizon = 0.5 + 0.05 * fleet.n_stages
        drawn = draw_faults(self.rng, kinds, ids, horizon)  # drawn always: a given schedule replays the same draws after
        self.faults = tuple(faults) if faults is not None else drawn
        self.windows: dict = {}                 # kind -> its faults, in schedule order
        for f in self.faults:
            self.windows.setdefault(f.kind, []).append(f)
        self.carriers = {cid: CarrierDriver(self, cid) for cid in ids}
        self.coordinators, self.separate = coordinator_processes(self, self.faults)
        names = list(self.coordinators)
        self.coordinator_names = tuple(names)  # ordered: every iteration that sends is in a fixed order
        hosts = [*names, *ids]
        self.clocks = {h: Clock(float(self.rng.uniform(0, 1e4)), float(self.rng.uniform(-1e-4, 1e-4))) for h in hosts}
        self.median = {h: float(self.rng.uniform(2e-4, 3e-3)) for h in hosts}   # one-way to the router, s
        self.cut: set = set()
        self.lapsed: set = set()                 # hosts whose tokens vanished a lease after a cut or pause
        self.fifo: dict = {}                     # (src, dst) -> the last delivery time scheduled
        self.frozen: dict = {}
        self.work_s = {cid: float(self.rng.uniform(0.005, 0.05)) for cid in ids}
        # the scenario's link model (its own Generator: a perfect mission draws and delays as without one)
        links = fleet.links
        self.links = LinkLayer(self, links, seed) if links is not None and links.spec.model != "perfect" else None
        self.invariants = Invariants(self)
        self.injector = Injector(self)
        self.injector.schedule()
        self.at(0.0, self._start, self.coordinators["coordinator"], "coordinator")
        if "standby" in self.coordinators:
            self.at(0.002, self._start, self.coordinators["standby"], "standby")
        for cid in ids:
            self.started_at[cid] = float(self.rng.uniform(0.01, 0.5))
            self.at(self.started_at[cid], self._start, self.carriers[cid], cid)

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
        return self.invariants.conclude(bound)

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
        """The coordinator id a carrier reads in ``m`` (mission.simulate.plants.read_coordinator)."""
        return read_coordinator(self.plant, m)

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
        self.at(arrive, self.arrive, src, dst, m)
        dup = None if reliable else self._window("duplicate")
        if dup is not None and self.rng.random() < dup.size:
            self.at(arrive + self._delay(src, dst), self.arrive, src, dst, m)

    def _delay(self, src: str, dst: str) -> float:
        d = sum(self.median[h] * math.exp(0.5 * self.rng.standard_normal()) for h in (src, dst) if h in self.median)
        wide = self._window("reorder")
        return d * (1.0 + float(self.rng.uniform(0, wide.size))) if wide is not None else d

    def arrive(self, src: str, dst: str, m: Msg) -> None:
        if src in self.cut or dst in self.cut:
            return
        until = self.frozen.get(dst)
        if until is not None and self.t < until:
            self.at(until, self.arrive, src, dst, m)  # held in its socket until it runs again
            return
        driver = self.carriers.get(dst) or self.coordinators.get(dst)
        if driver is None or not driver.alive and driver.phase != "standby":
            return
        self.events += 1
        self.trace.update(f"{self.t:.9f}|{dst}|{m.kind}|{m.src}|{m.body}|{m.mission}|{m.garbled}\n".encode())
        if isinstance(driver, CoordinatorDriver) and m.src in self.carriers:
            before = driver.authority()
            driver.hear(m, self.now_of(dst))
            self.invariants.check_authority(driver, before, m)
            return
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

    def lease(self, hosts, alive: bool, reached: bool = False) -> None:
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

    # -------------------------------------------------------------- the machines, as planted
    def coordinator_step(self, state, event):
        return planted_coordinator_step(self.plant, state, event)

    def carrier_step(self, state, event):
        return planted_carrier_step(self.plant, state, event)

    def work(self, driver, j: int) -> float:
        """Seconds of its host's time carrier ``driver`` works towards stage j's observation."""
        f = self.injector.slowness(driver.cid)
        if f is not None:
            return f.size
        return self.work_s[driver.cid] * float(self.rng.uniform(0.5, 1.5))

    # -------------------------------------------------------------- findings
    def violate(self, line: str) -> None:
        self.invariants.violate(line)

    def count_reject(self, reason: str) -> None:
        self.rejects[reason] = self.rejects.get(reason, 0) + 1

    def finished(self, driver: CarrierDriver, reason: str) -> None:
        self.finished_ids[driver.cid] = reason

    @property
    def db(self) -> list:
        """The mission's record: the disk of the coordinator that completed it (else the primary's)."""
        final = next((d for d in self.coordinators.values() if d.phase == "done"), self.coordinators["coordinator"])
        return final.disk.events


def simulate(fleet: Fleet, seed: int, kinds=FAULT_KINDS, faults=None, plant: str | None = None) -> Outcome:
    """One mission of ``fleet`` with seed ``seed``: faults drawn from ``kinds`` (or ``faults``,
    a given schedule: a replay, a shrunk schedule)."""
    return Simulation(fleet, seed, faults=faults, kinds=kinds, plant=plant).run()



def combined_hash(hashes) -> str:
    """One hash of a campaign's trace hashes, in seed order."""
    return hashlib.blake2b("".join(hashes).encode(), digest_size=16).hexdigest()
