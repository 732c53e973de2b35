"""An example planner plug-in for marsupial-fleet (docs/planner.md, "Writing a planner plug-in").

``greedy``: a carrier deploys when its observation beats the prior's quantile ``q`` (and always
when it must: as many valid stages left as passengers). Installed, it is the entry point
``greedy`` of the group ``marsupial_fleet.planners``; uninstalled but importable, it is
``greedy_planner:GreedyPlanner``.
"""
from __future__ import annotations

import numpy as np

from planner.registry import Option


class GreedyPlanner:
    """Deploy a carrier at a stage when ``x > prior.ppf(q)``; forced deployments kept.

    Stateless across stages (everything it reads is in the view) and deterministic (it draws
    nothing, so it never touches the ``rng`` it is given).
    """

    name = "greedy"
    #: The registry reads this declaration: its own option ``q`` (no built-in budget: it does no search).
    options = (Option("q", float, 0.7, "prior quantile an observation must beat to deploy", minimum=0,
                      exclusive=True, maximum=1),)

    def __init__(self, q: float = 0.7):
        self.q = q

    def warm_up(self, problem) -> None:
        """Nothing to compile: the threshold is one ppf call per problem."""
        self.threshold(problem)

    def threshold(self, problem) -> float:
        """The observation to beat: the prior's ``q`` quantile."""
        return float(problem.prior.ppf(self.q))

    def decide(self, view, rng: np.random.Generator) -> np.ndarray:
        """bool ``[R]``: the carriers deploying at ``view.stage``."""
        x = view.observations[:, view.stage]
        beats = np.nan_to_num(x, nan=-np.inf) > self.threshold(view.problem)
        return view.must_deploy | (view.can_deploy & beats)
