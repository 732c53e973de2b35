"""Planner plug-ins for the tests: one that follows the protocol, and one deliberately broken
plug-in per named failure of the conformance kit (planner/conformance.py). Loaded by dotted path,
``planner_plugins:Name``, with tests/ on the import path."""
from __future__ import annotations

import random
import time

import numpy as np

from planner.registry import Option


class Threshold:
    """Deploy when the observation is at least ``cut`` (forced deployments kept): honest."""

    name = "threshold"
    options = (Option("cut", float, 3.0, "observation at or above which a carrier deploys", minimum=0),)

    def __init__(self, cut: float = 3.0):
        self.cut = cut

    def decide(self, view, rng):
        x = view.observations[:, view.stage]
        return view.must_deploy | (view.can_deploy & (np.nan_to_num(x, nan=-1.0) >= self.cut))


class Budgeted(Threshold):
    """Threshold with a random tie rule, a plan_ms budget it keeps, iterations it shows: honest."""

    name = "budgeted"
    options = (*Threshold.options, "iterations", "plan_ms")

    def __init__(self, cut: float = 3.0, iterations: int = 100, plan_ms: float | None = None):
        super().__init__(cut)
        self.iterations, self.plan_ms = iterations, plan_ms
        self.last_iterations = 0

    def decide(self, view, rng):
        if self.plan_ms is not None:
            time.sleep(self.plan_ms / 2e3)  # spends half its budget
        self.last_iterations = min(self.iterations, 10)
        coin = rng.random(view.problem.n_carriers) < 0.5
        x = np.nan_to_num(view.observations[:, view.stage], nan=-1.0)
        return view.must_deploy | (view.can_deploy & ((x > self.cut) | ((x == self.cut) & coin)))


class DeploysTwice(Threshold):
    """Asks for two deployments of one carrier at a stage (a count, not a bool)."""

    def decide(self, view, rng):
        out = super().decide(view, rng).astype(np.int64)
        return out * 2


class BeyondPassengers(Threshold):
    """Deploys every carrier at every valid stage, passengers or not."""

    def decide(self, view, rng):
        return ~np.isnan(view.observations[:, view.stage])


class IgnoresForced(Threshold):
    """Never deploys, not even when it must."""

    def decide(self, view, rng):
        return np.zeros(view.problem.n_carriers, dtype=bool)


class GlobalRandom(Threshold):
    """Draws from the global random module instead of the rng it is given."""

    def decide(self, view, rng):
        coin = np.array([random.random() < 0.5 for _ in range(view.problem.n_carriers)])
        return view.must_deploy | (view.can_deploy & coin)


class Stateful(Threshold):
    """Remembers how many decisions it made (state across missions)."""

    def __init__(self, cut: float = 3.0):
        super().__init__(cut)
        self.calls = 0

    def decide(self, view, rng):
        self.calls += 1
        return view.must_deploy | (view.can_deploy & (self.calls % 3 == 0))


class OverBudget(Budgeted):
    """Declares plan_ms and takes ten times it."""

    def decide(self, view, rng):
        if self.plan_ms is not None:
            time.sleep(self.plan_ms * 10 / 1e3)
        return super().decide(view, rng) if self.plan_ms is None else Threshold.decide(self, view, rng)


class OverIterations(Budgeted):
    """Runs more iterations than it is given."""

    def decide(self, view, rng):
        out = super().decide(view, rng)
        self.last_iterations = self.iterations + 1
        return out


class _Lenient(Option):
    """An option whose check lets anything through."""

    def check(self, value):
        return value


class AcceptsBadOptions(Threshold):
    """Declares an option whose check accepts every value."""

    options = (_Lenient("cut", float, 3.0, "observation to deploy at", minimum=0),)

    def __init__(self, cut=3.0):
        super().__init__(float(cut) if isinstance(cut, (int, float)) else 3.0)


class BadDeclaration(Threshold):
    """Declares an option that is neither an Option nor a built-in name."""

    options = ("cut",)


class Raises(Threshold):
    """Fails at stage 2."""

    def decide(self, view, rng):
        if view.stage == 2:
            raise RuntimeError("no plan for stage 2")
        return super().decide(view, rng)


class OnBoard(Threshold):
    """Also decides on board (decide_local) by the same rule: honest."""

    def decide_local(self, local, rng):
        can, must, _, _ = local.own()
        x = local.observations[local.carrier, local.stage]
        return bool(must or (can and x >= self.cut))


class OnBoardBeyond(Threshold):
    """On board, deploys at every observed stage, passengers or not."""

    def decide_local(self, local, rng):
        return not np.isnan(local.observations[local.carrier, local.stage])


def make_threshold(cut: float = 3.0):
    """A factory function (not a class) declaring its options as an attribute."""
    return Threshold(cut)


make_threshold.options = Threshold.options
