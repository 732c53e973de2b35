"""What recordings and ROS 2 topics say about a mission, as plain values: the records of the
JSON channels (mission.mcap's ``/observations``, ``/decisions``, ``/confirmations``; the ROS 2
``/mission/...`` topics) and :class:`Tally`, the running score.

Pure (numpy and the planner core), so that every sink of the mission stream — recording/,
viewer/, ros2/ — counts and writes the same thing.
"""
from __future__ import annotations

import numpy as np


def observation_record(stage, carrier, x, position, passengers_left) -> dict:
    """The fields of an observation as the recordings' JSON channels carry them (mission.mcap's
    ``/observations``, the ROS 2 ``/mission/observations``); ``t`` is added by the channel."""
    return {"stage": int(stage), "carrier": carrier, "x": x, "position": [float(v) for v in position],
            "passengers_left": int(passengers_left)}


def decision_record(stage, deploy, planning_ms) -> dict:
    return {"stage": int(stage), "deploy": list(deploy), "planning_ms": float(planning_ms)}


def operator_action_record(e) -> dict:
    """An operator's action (mission.events.OperatorAction) on the ``/operator`` channel."""
    return {"kind": "action", "stage": int(e.stage), "action": e.action, "carrier": e.carrier,
            "operator": e.operator}


def operator_decision_record(e) -> dict:
    """How an operator-mode stage was decided (mission.events.Decided) on the ``/operator`` channel."""
    return {"kind": "decision", "stage": int(e.stage), "deploy": list(e.deploy),
            "recommended": list(e.deploy if e.recommended is None else e.recommended),
            "forced": list(e.forced), "vetoed": list(e.vetoed), "hold": e.hold, "gain": e.gain}


def confirm_record(stage, carrier, deployed, status, position, passengers_left) -> dict:
    return {"stage": int(stage), "carrier": carrier, "deployed": bool(deployed), "status": status,
            "position": [float(v) for v in position], "passengers_left": int(passengers_left)}


class Tally:
    """Observations ``x [R, N]`` (NaN = ∅), confirmed deployments ``[R, N]`` and the reward so
    far (normalised, raw features) of a mission, given its planner problem (or None: no reward).

    The recordings ask for the reward after every confirmed deployment, so the penalties are kept
    as deployments come (a confirmation adds or removes its point's conflict row: O(R·N)), not
    counted again over every deployment so far (O(R·N) per deployment, R²·N per stage, which
    makes a large fleet's stages slower as the mission goes on)."""

    def __init__(self, carrier_ids, n_stages: int, problem=None):
        self.ids = tuple(carrier_ids)
        self.index = {cid: r for r, cid in enumerate(self.ids)}
        self.x = np.full((len(self.ids), n_stages), np.nan)
        self.deployed = np.zeros((len(self.ids), n_stages), dtype=bool)
        self.problem = problem
        self._p = None if problem is None else np.ones(self.deployed.size, dtype=np.int64)

    def observe(self, carrier, stage, x) -> None:
        r = self.index.get(carrier)
        if r is not None and x is not None and 0 <= stage < self.x.shape[1]:
            self.x[r, stage] = float(x)

    def confirm(self, carrier, stage, deployed: bool) -> None:
        r = self.index.get(carrier)
        if r is None or not 0 <= stage < self.x.shape[1] or self.deployed[r, stage] == bool(deployed):
            return
        self.deployed[r, stage] = bool(deployed)
        if self._p is not None:
            row = self.problem.conflict[r * self.deployed.shape[1] + stage]
            if deployed:
                self._p += row
            else:
                self._p -= row

    def reward(self) -> tuple[float, float]:
        """(normalised reward, raw features) of the confirmed deployments so far."""
        if self.problem is None or not self.deployed.any():
            return 0.0, 0.0
        from planner.problem import evaluate

        return evaluate(self.problem, self.deployed, np.nan_to_num(self.x, nan=0.0),
                        p=self._p.reshape(self.deployed.shape))
