"""What the carriers of one process share: the world derived once from the scenario
(:class:`SharedWorld`), the stage gate that lets them answer a Decision before any of them
runs the next stage's physics (:class:`StageGate`) and the thread that runs their physics at a
lower CPU priority than their messages (:class:`PhysicsThread`; docs/fleet.md, "Many carriers
per process")."""
from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from wire.messages import scenario_fingerprint


@dataclass(frozen=True)
class SharedWorld:
    """What every carrier of one process derives identically from the scenario, computed once
    per process (:func:`shared_world`) when it simulates several carriers.

    Attributes:
        valid: bool ``[R, N]``, carrier r scheduled at stage j.
        fingerprint: the scenario fingerprint.
        features: float ``[F, 2]`` feature positions (m), sorted by x.
    """

    valid: np.ndarray
    fingerprint: str
    features: np.ndarray


def shared_world(scenario) -> SharedWorld:
    from world import sample_features

    features = sample_features(scenario)
    features = features[np.argsort(features[:, 0], kind="stable")]  # sorted by x: see Simulation.sense
    if scenario.reward == "coverage":  # the regions too, before any carrier says it is live
        from world.regions import scenario_regions

        scenario_regions(scenario)
    return SharedWorld(scenario.valid(), scenario_fingerprint(scenario), features)


class StageGate:
    """The carriers of one process answer a stage's Decision before any of them moves on.

    One Decision reaches every carrier of the process at once; without the gate, the first
    carriers to wake run their next stage's physics while the others still wait for the CPU to
    send their Confirms, which spreads one stage's Confirms over the whole process's physics. A
    carrier that has its Decision holds its
    physics until every carrier of the process waiting on that stage has answered, at most
    :data:`GATE_HOLD_S`.
    """

    def __init__(self):
        self._cond = threading.Condition()
        self._waiting: dict[int, int] = {}

    def waiting(self, stage: int) -> None:
        """A carrier waits for the decision of ``stage``."""
        with self._cond:
            self._waiting[stage] = self._waiting.get(stage, 0) + 1

    def answered(self, stage: int) -> None:
        """A carrier stopped waiting for ``stage`` (answered, decided alone, or gave up)."""
        with self._cond:
            left = self._waiting.get(stage, 0) - 1
            if left > 0:
                self._waiting[stage] = left
            else:
                self._waiting.pop(stage, None)
                self._cond.notify_all()

    def hold(self, stage: int, timeout_s: float) -> bool:
        """Until no carrier waits for ``stage`` any more, at most ``timeout_s``; True if none does."""
        with self._cond:
            return self._cond.wait_for(lambda: stage not in self._waiting, timeout_s)


#: Longest a carrier holds its physics for the other carriers of its process (:class:`StageGate`).
GATE_HOLD_S = 0.5


#: How much lower (a ``nice`` increment) a carrier process runs its carriers' physics than their
#: messages (:class:`PhysicsThread`).
PHYSICS_NICE = 5
#: The interpreter's thread switch interval (s) in a process of several carriers (CPython's
#: default is 0.005): its carriers' threads then hand the interpreter over less often.
SWITCH_INTERVAL_S = 0.02


class PhysicsThread(ThreadPoolExecutor):
    """Runs the physics of a process's simulated carriers, one call at a time, in one thread
    whose CPU priority is :data:`PHYSICS_NICE` below the process's (an executor of one worker:
    ``submit`` gives a :class:`concurrent.futures.Future`).

    On one host every carrier process competes for the cores. When a Decision arrives, the
    processes that have answered it run their next stage's physics while the others are still
    answering it; with physics and messages at one priority the last Confirms waited for that
    physics (docs/performance.md, "Where a stage's wall time goes"). With the physics thread
    yielding to the carriers' own threads (which only handle messages), the
    scheduler runs every process's answers first. A carrier's physics is its own (one pymunk
    space per carrier), so the order in which the thread runs the calls changes no result. Where
    the priority cannot be lowered (not Linux) the thread runs at the process's.
    """

    def __init__(self, nice: int = PHYSICS_NICE):
        super().__init__(max_workers=1, initializer=_physics_worker, initargs=(nice,))


def _physics_worker(nice: int) -> None:
    """The physics thread's start: named, and its priority lowered where the system allows."""
    threading.current_thread().name = "physics"
    try:
        tid = threading.get_native_id()
        os.setpriority(os.PRIO_PROCESS, tid, os.getpriority(os.PRIO_PROCESS, tid) + nice)
    except (AttributeError, OSError):
        pass
