"""The fault schedule struck on a simulated mission (:class:`Injector`): each fault kind of
:data:`mission.simulate.model.FAULT_KINDS` as what it does to the simulated hosts, processes and
network of :class:`mission.simulate.simulation.Simulation` (docs/fleet.md, "Deterministic
simulation": the fault kinds)."""
from __future__ import annotations

import dataclasses
from collections import Counter

from .. import timers
from .coordinator import CoordinatorDriver
from .model import LEASE_S, OPEN_RETRY_S, Fault, msg


class Injector:
    """Strikes a mission's faults at their times. What a fault changes lives in the simulation
    (cut hosts, frozen processes, clocks, the processes themselves); this class holds only the
    faults still to strike (``paused``: the pauses struck; ``slow``: carrier id -> its slow
    fault) and how many cuts cover each host (``cuts``: a host partitioned during a router loss
    reaches nobody until both are over).

    Args:
        sim: the :class:`mission.simulate.simulation.Simulation` it strikes.
    """

    def __init__(self, sim):
        self.sim = sim
        self.paused: set = set()
        self.slow: dict = {}
        self.cuts: Counter = Counter()

    def schedule(self) -> None:
        sim = self.sim
        primary = sim.coordinators["coordinator"]
        for f in sim.faults:
            if f.kind == "partition":
                sim.at(f.at, self.cut, (f.who,), f.until)
            elif f.kind == "router-lost":
                sim.at(f.at, self.cut, (*sim.coordinator_names, *sim.fleet.ids), f.until)
            elif f.kind == "crash":
                sim.at(f.at, self.crash, sim.carriers[f.who], f.until)
            elif f.kind == "coordinator-crash":
                sim.at(f.at, self.crash, primary, f.until)
            elif f.kind == "takeover":
                sim.at(f.at, self.crash, primary, None)
            elif f.kind == "standby-crash":  # the primary dies, the standby takes over and dies,
                sim.at(f.at, self.crash, primary, f.until)  # the primary restarts
                sim.at(f.at + f.size, self.crash, sim.coordinators["standby"], None)
            elif f.kind == "freeze":
                sim.at(f.at, self.freeze, f.who, f.until)
            elif f.kind == "slow":
                self.slow[f.who] = f
            elif f.kind == "clock-jump":
                sim.at(f.at, self.jump, f.who, f.size)
            elif f.kind in ("corrupt", "stale"):
                self.inject(f)
            elif f.kind == "compromised":
                for _ in range(int(f.size)):
                    sim.at(float(sim.rng.uniform(f.at, f.until)), self.lie, f.who)

    # -------------------------------------------------------------- the network
    def cut(self, hosts, until: float) -> None:
        """``hosts`` reach nobody until ``until`` (a partition: one host; a router loss: all):
        their sessions lapse a lease later (or when the cut heals, if sooner)."""
        sim = self.sim
        newly = tuple(h for h in hosts if not self.cuts[h])
        self.cuts.update(hosts)
        sim.cut.update(newly)
        sim.at(sim.t + min(LEASE_S, until - sim.t), sim.lease, newly, False)
        sim.at(until, self.heal, tuple(hosts))

    def heal(self, hosts) -> None:
        """One cut over: the hosts no other cut covers reach the router again, and the tokens
        between them and every host the network reaches reappear (a host still cut off learns
        them when its own cut heals)."""
        self.cuts.subtract(hosts)
        healed = tuple(h for h in hosts if not self.cuts[h])
        self.sim.cut.difference_update(healed)
        self.sim.lease(healed, True, reached=True)

    def inject(self, f: Fault) -> None:
        """Messages nobody of this mission sent: garbled ones, another mission's, and (``stale``)
        a carrier's from an earlier run of the mission, arriving before its Hello."""
        sim = self.sim
        ids = sim.fleet.ids
        for k in range(max(1, int(f.size))):
            cid = str(ids[int(sim.rng.integers(len(ids)))])
            if f.kind == "stale":
                when = float(sim.rng.uniform(0.0, 0.009))
                m = [msg("bye", cid, deployments=(0,), reason="finished"),
                     msg("confirm", cid, stage=0, deployed=True, status="deployed", passengers_left=0),
                     msg("obs", cid, stage=0, t=float(sim.fleet.stage_times[0]), x=99, passengers_left=0)][k % 3]
            else:
                when = float(sim.rng.uniform(f.at, f.until))
                m = dataclasses.replace(msg("obs", cid, stage=0, t=0.0, x=1, passengers_left=0),
                                        **({"garbled": True} if k % 2 == 0 else {"mission": "other"}))
            dst = "coordinator" if k % 4 != 3 else cid
            sim.at(when, sim.arrive, "intruder", dst, m)

    def lie(self, cid: str) -> None:
        """One message carrier ``cid``'s credential allows (its own keys: Hello, Observation,
        Confirm, Own, Bye, Progress, and its copies to the peers listening), with adversarial
        values inside the wire's ranges: stages past the mission's end or long decided, counts
        out of all proportion, deployments it never made, statuses that answer nothing, claims of
        passengers it does not have. The wire's range checks are :mod:`wire.messages`'s; what is
        left to the mission's rules is what this sends."""
        sim = self.sim
        rng, fleet = sim.rng, sim.fleet
        n = fleet.n_stages
        j = int(rng.integers(0, n + 3))
        t = float(fleet.stage_times[j]) if j < n else float(rng.uniform(-1e3, 1e6))
        x, left, deployed = int(rng.integers(0, 10_000)), int(rng.integers(0, 100)), bool(rng.integers(2))
        kind = int(rng.integers(8))
        if kind == 0:
            m = msg("hello", cid, next_stage=int(rng.integers(0, n + 1)), passengers_left=left,
                    fingerprint=fleet.fingerprint, epoch=int(rng.integers(1, 2**31)))
        elif kind == 1:
            m = msg("obs", cid, stage=j, t=t, x=x if rng.random() < 0.8 else None, passengers_left=left)
        elif kind == 2:
            status = ("deployed", "idle", "late", "refused", "already")[int(rng.integers(5))]
            m = msg("confirm", cid, stage=j, deployed=deployed, status=status, passengers_left=left)
        elif kind == 3:
            m = msg("own", cid, stage=j, t=t, x=x, deployed=deployed, passengers_left=left)
        elif kind == 4:
            stages = sorted({int(s) for s in rng.integers(0, n + 3, size=int(rng.integers(0, 6)))})
            m = msg("bye", cid, deployments=tuple(stages), reason="finished")
        elif kind == 5:
            m = msg("progress", cid, stage=j)
        elif kind == 6:
            sim.to_listeners(cid, msg("peer-obs", cid, stage=j, x=x))
            return
        else:
            sim.to_listeners(cid, msg("peer-own", cid, stage=j, x=x, deployed=deployed))
            return
        sim.send(cid, "coordinators", m)

    # -------------------------------------------------------------- the processes
    def crash(self, driver, restart: float | None) -> None:
        if driver.alive or driver.phase == "standby":
            driver.crash()
        if restart is not None:
            self.sim.at(restart, self.restart, driver)

    def restart(self, driver) -> None:
        # a refused or deposed coordinator exited too (another's token was live at its start, or a
        # newer one decides): its supervisor starts it again when its restart is due
        if not driver.alive and driver.phase in ("dead", "dead-standby", "refused", "deposed"):
            self.sim.frozen.pop(driver.name if isinstance(driver, CoordinatorDriver) else driver.cid, None)  # new process
            if isinstance(driver, CoordinatorDriver):
                driver.phase = "standby" if driver.phase == "dead-standby" else "new"
                self.open(driver, driver.life)
                return
            driver.start(self.sim.now_of(driver.cid))

    def open(self, driver: CoordinatorDriver, life: int) -> None:
        """A coordinator process opening its session, a client of the router: while its host is
        cut off it cannot (wire.zconfig.open_session tries every ``OPEN_RETRY_S``; one that
        gives up after its timeout is started again by its supervisor, as if it went on
        trying); once open, one that is no standby refuses to start while another coordinator's
        token is live (coordinator.epochs: DuplicateCoordinator, it exits). A coordinator
        restarted during a router loss thus never opens a second epoch beside a live standby's."""
        sim = self.sim
        if driver.life != life or driver.alive:
            return
        if driver.name in sim.cut:
            sim.at(sim.t + OPEN_RETRY_S, self.open, driver, life)
            return
        if driver.phase == "new" and self.claimed(driver.name):
            driver.phase = "refused"
            return
        driver.start(sim.now_of(driver.name))

    def claimed(self, name: str) -> bool:
        """Another coordinator's token is live where ``name`` looks for it at its start
        (:meth:`coordinator.epochs.Epochs.claim`): it lives, has a token (a waiting standby has
        none), its lease has not lapsed, and ``name`` reaches the router."""
        sim = self.sim
        return name not in sim.cut and any(
            sim.has_token(other) and other not in sim.lapsed for other in sim.coordinator_names if other != name)

    def pause(self, driver: CoordinatorDriver) -> float:
        """Seconds ``driver`` pauses now (0: none): the first decision of the primary at or after
        a ``pause`` fault's start. Its whole process stops, its session too: its token vanishes
        a lease later and reappears when it runs again."""
        sim = self.sim
        f = next((f for f in sim.faults if f.kind == "pause" and f.at <= sim.t and f not in self.paused), None)
        if f is None or driver.name != "coordinator":
            return 0.0
        self.paused.add(f)
        sim.frozen[driver.name] = sim.t + f.size
        sim.at(sim.t + min(LEASE_S, f.size), self.paused_lease, driver, driver.life, False)
        sim.at(sim.t + f.size, self.paused_lease, driver, driver.life, True)
        return f.size

    def paused_lease(self, driver, life: int, alive: bool) -> None:
        """A paused (or frozen) process's session lapses and comes back with it; a process killed
        while paused took its session along (:meth:`CoordinatorDriver.crash`), a restarted one has
        its own."""
        if driver.life == life and driver.alive:
            self.sim.lease((driver.name if isinstance(driver, CoordinatorDriver) else driver.cid,), alive, reached=True)

    def freeze(self, who: str, until: float) -> None:
        """Carrier ``who`` stuck until ``until``: alive and silent; stuck longer than a lease, its
        session lapses too (its token vanishes a lease after, and reappears when it runs again),
        as a stopped process's does on the real network."""
        sim = self.sim
        sim.frozen[who] = until
        driver = sim.carriers[who]
        if timers.lapses(sim.t, until, LEASE_S) and driver.alive:
            sim.at(sim.t + LEASE_S, self.paused_lease, driver, driver.life, False)
            sim.at(until, self.paused_lease, driver, driver.life, True)
        sim.at(until, lambda: driver.alive and driver.advance(sim.now_of(who)))

    def jump(self, host: str, seconds: float) -> None:
        sim = self.sim
        sim.clocks[host].jumped += seconds
        driver = sim.carriers.get(host) or sim.coordinators.get(host)
        if driver is not None and driver.alive:
            driver.advance(sim.now_of(host))

    def slowness(self, cid: str):
        """The ``slow`` fault of carrier ``cid`` while it lasts (its work stays slow three of its
        sizes after its window), else None."""
        f = self.slow.get(cid)
        return f if f is not None and f.at <= self.sim.t < f.until + f.size * 3 else None
