"""What the operator's page shows, as JSON: the map once (:meth:`ConsoleView.map`), and the
mission as it is (:meth:`ConsoleView.snapshot`): carriers, routes, the stage's observations,
passengers left, the recommendation with its reasons and countdown, the mission so far."""
from __future__ import annotations

import math

import numpy as np

from mission import state as ms
from planner.problem import evaluate

#: Features drawn on the page at most (a uniform subset of a larger map's).
MAX_FEATURES = 2000


def _round(points, digits: int = 2) -> list:
    return np.round(np.asarray(points, dtype=float), digits).tolist()


class ConsoleView:
    """Snapshots of one mission for the page.

    Args:
        scene: the mission's :class:`world.scene.Scene`; problem: its planner problem;
        mission: the mission id; planner: the planner's name; settings: the
        :class:`console.hold.OperatorSettings`.
    """

    def __init__(self, scene, problem, mission: str, planner: str, settings):
        self.scene, self.problem, self.mission, self.planner, self.settings = scene, problem, mission, planner, settings
        self._map = None

    def map(self) -> dict:
        """The static map (computed once): bounds, walls, obstacles, features, routes, planned
        decision points, overlap outlines, sensing radius, carrier colours."""
        if self._map is None:
            s = self.scene
            features = s.features
            if len(features) > MAX_FEATURES:
                features = features[np.linspace(0, len(features) - 1, MAX_FEATURES).astype(int)]
            self._map = {
                "name": s.name, "bounds": list(s.bounds), "walls": _round(s.walls),
                "obstacles": [_round(p) for p in s.obstacles], "features": _round(features, 1),
                "sensing_radius": s.sensing_radius, "stage_times": [float(t) for t in s.stage_times],
                "carriers": [{"id": c.id, "colour": c.colour, "passengers": c.passengers, "route": _round(c.path)}
                             for c in s.carriers],
                "planned": [[None if np.isnan(p[0]) else [round(float(p[0]), 2), round(float(p[1]), 2)] for p in row]
                            for row in s.planned],
                "overlaps": [{"members": [list(m) for m in o.members], "outline": _round(o.outline)}
                             for o in s.overlaps],
            }
        return self._map

    def snapshot(self, state: ms.MissionState, stage: dict | None) -> dict:
        """The page's view of ``state``; ``stage``: the stage being held (its recommendation,
        reasons, constraints and deadline), None between holds."""
        spec = state.spec
        left = state.passengers_left()
        actual = state.confirmed_deployments()
        x = state.observations()
        reward, features = evaluate(self.problem, actual, x) if self.problem.coverage is None else (None, None)
        carriers = []
        for r, cid in enumerate(spec.carriers):
            trail = state.trails.get(cid, ())
            carriers.append({"id": cid, "position": list(trail[-1]) if trail else None, "live": cid in state.live,
                             "passengers_left": int(left[r]), "trail": _round(trail[-400:]) if trail else []})
        deployments = []
        for r, j in zip(*np.nonzero(actual)):
            cid, j = spec.carriers[r], int(j)
            d = state.decisions.get(j)
            by = ("carrier" if (cid, j) in state.accounts else
                  "operator" if d is not None and cid in d.forced else "planner")
            deployments.append({"carrier": cid, "stage": j, "position": list(state.deployment_position(cid, j)),
                                "x": None if math.isnan(x[r, j]) else float(x[r, j]), "by": by})
        history = []
        for j in sorted(state.decisions):
            d = state.decisions[j]
            history.append({"stage": j, "deploy": list(d.deploy), "hold": d.hold, "forced": list(d.forced),
                            "vetoed": list(d.vetoed), "gain": d.gain,
                            "recommended": list(d.deploy if d.recommended is None else d.recommended),
                            "by": ("operator" if d.forced or d.vetoed else "approved" if d.hold == "approved"
                                   else "planner")})
        current = stage["stage"] if stage is not None else state.next_stage
        observations = {}
        if current < spec.n_stages:
            for r, cid in enumerate(spec.carriers):
                if spec.valid[r][current] and (cid, current) in state.reported:
                    value = state.reported[(cid, current)]
                    observations[cid] = None if value is None else float(value)
        return {
            "mission": self.mission, "planner": self.planner, "stages": spec.n_stages,
            "next_stage": state.next_stage, "ended": state.ended, "end_reason": state.end_reason,
            "timeout_s": self.settings.timeout_s, "required": self.settings.required,
            "carriers": carriers, "deployments": deployments, "history": history,
            "observations": {"stage": current, "x": observations},
            "reward": None if reward is None else float(reward), "features": None if features is None else float(features),
            "hold": _jsonable(stage),
        }


def _jsonable(value):
    """``value`` with numpy scalars and arrays as plain JSON values, NaN as None."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, (np.bool_,)):
        return bool(value)
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return None if not math.isfinite(float(value)) else float(value)
    return value
