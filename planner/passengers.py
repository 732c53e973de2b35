"""Passenger types: which passenger a deployment releases, and type-blind carriers.

A problem with passenger values (``Problem.weights``) earns ``w_i * x / p`` for releasing
passenger i. Every planner decides *whether* each carrier deploys (``decide(view, rng) ->
bool[R]``); :func:`choose` completes the joint action with *which* passenger each deploying carrier
releases, by the generalised DLR rule (:func:`planner.ssap.release`): the observation's interval
among the thresholds of the carrier's ``n`` valid stages left is the weight rank of the passenger
it releases. A planner may override it with a ``release_passengers(view, deploy) -> int[R]`` method
(:class:`TypeBlind` does).
"""
from __future__ import annotations

import dataclasses
import weakref

import numpy as np

from planner import ssap
from planner.compiled import compile_problem
from planner.problem import Problem, StageView, in_order, penalties


def choose(view: StageView, deploy: np.ndarray) -> np.ndarray:
    """int64 ``[R]``: the passenger index each deploying carrier releases (-1 for the others).

    Without passenger values: the lowest index still aboard (index order). With them:
    :func:`planner.ssap.release` on the carrier's current observation and valid stages left.
    """
    deploy = np.asarray(deploy, dtype=bool)
    out = np.full(view.problem.n_carriers, -1, dtype=np.int64)
    aboard = view.aboard
    weights = view.problem.weights
    table = None if weights is None else compile_problem(view.problem).table
    x = view.observations[:, view.stage]
    n = view.stages_left
    for r in np.flatnonzero(deploy):
        idx = np.flatnonzero(aboard[r])
        if len(idx) == 0:
            continue
        if table is None:
            out[r] = idx[0]
        else:
            out[r] = idx[ssap.release(table, float(x[r]), max(int(n[r]), 1), weights[r, idx])]
    return out


def release(planner, view: StageView, deploy: np.ndarray) -> np.ndarray:
    """The planner's own passenger choice when it has one (``release_passengers(view, deploy)``),
    else :func:`choose`."""
    own = getattr(planner, "release_passengers", None)
    return own(view, deploy) if callable(own) else choose(view, deploy)


_UNWEIGHTED: "weakref.WeakKeyDictionary[Problem, Problem]" = weakref.WeakKeyDictionary()


def unweighted(problem: Problem) -> Problem:
    """The same problem with its passenger values dropped (every passenger weighs 1); shares the
    arrays and, for a problem without values, is the problem itself. Cached with the problem, so
    its compiled form is built once."""
    if problem.weights is None:
        return problem
    out = _UNWEIGHTED.get(problem)
    if out is None:
        out = _UNWEIGHTED[problem] = dataclasses.replace(problem, weights=None)
    return out


class UnweightedSearch:
    """``inner`` deciding *whether* to deploy as if every passenger weighed 1, with the passenger
    chosen by the rank rule (:func:`choose`): isolates what a planner's use of the values in its
    search is worth (an experiment variant).

    Args:
        inner: any planner.
    """

    def __init__(self, inner):
        self.inner = inner
        self.name = f"{inner.name} (unweighted search)"

    def warm_up(self, problem: Problem) -> None:
        warm_up = getattr(self.inner, "warm_up", None)
        if callable(warm_up):
            warm_up(unweighted(problem))

    def decide(self, view: StageView, rng: np.random.Generator) -> np.ndarray:
        blind = StageView(unweighted(view.problem), view.stage, view.observations, view.valid, view.deployed)
        return self.inner.decide(blind, rng)


class TypeBlind(UnweightedSearch):
    """A type-blind carrier fleet: ``inner`` decides as if every passenger weighed 1 and passengers
    go in a fixed order (index order, the order a scenario lists them). The baseline of the types
    experiment.

    Args:
        inner: any planner.
    """

    def __init__(self, inner):
        super().__init__(inner)
        self.name = f"{inner.name} (type-blind)"

    def release_passengers(self, view: StageView, deploy: np.ndarray) -> np.ndarray:
        out = np.full(view.problem.n_carriers, -1, dtype=np.int64)
        aboard = view.aboard
        for r in np.flatnonzero(np.asarray(deploy, dtype=bool)):
            idx = np.flatnonzero(aboard[r])
            if len(idx):
                out[r] = idx[0]
        return out


def best_assignment(problem: Problem, deployed: np.ndarray, x: np.ndarray) -> np.ndarray:
    """int64 ``[R, N]``: the offline best passenger for each deployment when every observation is
    known: per carrier, positive ``x / p`` go to the heaviest passengers, largest value first, and
    negative ones (continuous priors on the whole line) to the lightest, most negative first
    (rearrangement inequality; equal weights or values: lower index, earlier stage). Index order
    without values."""
    deployed = np.asarray(deployed, dtype=bool)
    if problem.weights is None:
        return in_order(deployed)
    value = np.nan_to_num(np.asarray(x, dtype=float), nan=0.0) / penalties(problem, deployed)
    out = np.full(deployed.shape, -1, dtype=np.int64)
    for r in range(problem.n_carriers):
        stages = np.flatnonzero(deployed[r])
        k = int(problem.passengers[r])
        by_value = stages[np.argsort(-value[r, stages], kind="stable")]
        by_weight = np.argsort(-problem.weights[r, :k], kind="stable")
        m = int((value[r, by_value] >= 0).sum())
        negatives = len(by_value) - m
        out[r, by_value[:m]] = by_weight[:m]
        out[r, by_value[m:]] = by_weight[k - negatives:]
    return out
