"""What the carriers of one process share: the world derived once from the scenario
(:class:`SharedWorld`) and the stage gate that lets them answer a Decision before any of them
runs the next stage's physics (:class:`StageGate`; docs/fleet.md, "Many carriers per process")."""
from __future__ import annotations

import threading
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
    return SharedWorld(scenario.valid(), scenario_fingerprint(scenario), features)


class StageGate:
    """The carriers of one process answer a stage's Decision before any of them moves on.

    One Decision reaches every carrier of the process at once; without the gate, the first
    carriers to wake run their next stage's physics while the others still wait for the CPU to
    send their Confirms, which spreads one stage's Confirms over the whole process's physics
    (about 1 s per stage at 32 carriers per process). A carrier that has its Decision holds its
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
