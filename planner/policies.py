"""The two planners without a search: ``random`` and ``ssap`` (single-robot SSAP thresholds).

Both follow :class:`planner.problem.Planner`: ``decide(view, rng) -> bool[R]`` reads only the causal
:class:`~planner.problem.StageView` of the current stage and keeps no state across stages.
"""
from __future__ import annotations

import numpy as np

from planner import ssap
from planner.compiled import compile_problem
from planner.coverage_plan import plan_for
from planner.problem import Problem, StageView


class RandomPlanner:
    """Each carrier deploys at D uniformly random valid stages.

    Stateless form: a carrier with ``d`` passengers left and ``n`` valid stages left (this one
    included) deploys now with probability ``d / n``. Over a schedule without surprises this picks
    ``min(D, valid stages)`` stages uniformly at random among all such subsets. ``d >= n`` gives
    probability 1, which is exactly the forced deployment rule.
    """

    name = "random"

    def decide(self, view: StageView, rng: np.random.Generator) -> np.ndarray:
        d = view.passengers_left
        n = view.stages_left
        # One uniform per carrier, always drawn, so carrier r's draw does not depend on the others.
        u = rng.random(view.problem.n_carriers)
        prob = np.divide(d, n, out=np.zeros(len(d)), where=n > 0)
        return view.can_deploy & (u < prob)


class SSAPPlanner:
    """Single-robot SSAP: each carrier applies its own DLR thresholds and ignores conflicts.

    Deterministic (the random stream is unused): carrier r deploys iff its observation exceeds
    ``a[n, n - d]`` for its ``n`` valid stages left and ``d`` passengers left, or it must deploy.
    Under the coverage reward the observation is the sum of the point's region counts, overlap is
    still ignored, and the thresholds are the point's own (:mod:`planner.coverage_plan`: DLR over
    the carrier's per-point priors).
    """

    name = "ssap"

    def warm_up(self, problem: Problem) -> None:
        """Compute (and cache) the threshold table before the first timed decision."""
        if problem.coverage is not None:
            plan_for(problem)
        else:
            compile_problem(problem).table

    def decide(self, view: StageView, rng: np.random.Generator) -> np.ndarray:
        if view.problem.coverage is not None:
            return np.array([self._deploys_cover(view.problem, r, view.stage, view.observations[r, view.stage],
                                                 int(n), int(d)) if can else False
                             for r, (can, n, d) in enumerate(zip(view.can_deploy, view.stages_left,
                                                                 view.passengers_left))], dtype=bool)
        table = compile_problem(view.problem).table
        x = view.observations[:, view.stage]
        d = view.passengers_left
        n = view.stages_left
        can = view.can_deploy
        out = np.zeros(view.problem.n_carriers, dtype=bool)
        for r in np.flatnonzero(can):
            out[r] = ssap.decide(table, float(x[r]), int(n[r]), int(d[r]))
        return out

    def decide_local(self, local, rng: np.random.Generator) -> bool:
        """The same rule on board (:class:`planner.decentralised.LocalView`): it needs no message,
        so under any communication model every carrier deploys exactly as with perfect links."""
        can, must, n, d = local.own()
        if not can:
            return False
        x = float(local.observations[local.carrier, local.stage])
        if local.problem.coverage is not None:
            return self._deploys_cover(local.problem, local.carrier, local.stage, x, n, d)
        table = compile_problem(local.problem).table
        return bool(ssap.decide(table, x, n, d))

    @staticmethod
    def _deploys_cover(problem: Problem, r: int, stage: int, x: float, n: int, d: int) -> bool:
        """Coverage: the threshold rule on ``x`` with the point's own thresholds (overlap ignored)."""
        return d > 0 and n > 0 and plan_for(problem).deploys(r * problem.n_stages + stage, float(x), n, d)
