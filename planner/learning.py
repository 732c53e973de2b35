"""Priors learned online: an empirical-Bayes estimate of f(x) from the observations so far, and a
wrapper that gives any planner that estimate at every stage (the ``learn_prior`` option).

Counts are modelled as Poisson with a gamma-distributed local intensity (clusters), so the
predictive is negative binomial (Poisson when the data show no overdispersion), its two moments
estimated from the observations and shrunk towards the stated prior's with :data:`PRIOR_WEIGHT`
pseudo-observations; continuous priors become the gamma or normal distribution with the shrunk
moments; a discrete prior not on the counts is refused (:class:`UnsupportedPrior`).
:class:`LearnedPriorPlanner` decides stage j on the problem whose prior is the estimate from
``x[:, :j + 1]`` (strictly causal), keeping the original normalisation and no state across
stages. The model, the formulas and why: docs/planner.md, "Learned priors".
"""
from __future__ import annotations

import dataclasses
import weakref
from collections import OrderedDict
from typing import NamedTuple

import numpy as np

from planner import priors
from planner.problem import Problem, StageView

#: n0: pseudo-observations the stated prior is worth: about one stage of a 3-4 carrier fleet's
#: counts, against a mission's 40-60 (urban_alpha, open_field). After the first stage the data
#: weigh as much as the stated prior; a wrong prior is mostly forgotten by mid-mission. (10 was
#: too slow to forget a prior twice too high: see docs/results.md, "Learned priors".)
PRIOR_WEIGHT = 4.0
#: Relative overdispersion below which the count predictive stays Poisson (v <= m (1 + this)).
POISSON_TOLERANCE = 1e-9
#: Smallest mean of a fitted prior (all-zero observations and a stated mean of 0).
MIN_MEAN = 1e-6

FAMILIES = ("count", "positive", "real")


class UnsupportedPrior(ValueError):
    """A stated prior the learner has no family for (one line)."""


class Fit(NamedTuple):
    """One estimate.

    Attributes:
        prior: frozen scipy.stats distribution (the stated prior itself when ``n == 0``).
        family: ``"stated"`` (no data), ``"poisson"``, ``"negative_binomial"``, ``"gamma"`` or
            ``"normal"``.
        mean, var: the shrunk moments (the stated prior's when ``n == 0``).
        n: observations used.
    """

    prior: object
    family: str
    mean: float
    var: float
    n: int


def family_of(prior) -> str:
    """``"count"``, ``"positive"`` or ``"real"``: the family :func:`fit_prior` fits for this
    stated prior.

    Raises:
        UnsupportedPrior: a discrete prior not on the counts 0, 1, 2, ...
    """
    if priors.is_discrete(prior):
        lo, _ = prior.support()
        if hasattr(prior.dist, "xk"):
            points, _ = priors.support(prior)
            ok = bool(np.all(points >= 0) and np.all(points == np.floor(points)))
        else:
            ok = lo >= 0
        if not ok:
            raise UnsupportedPrior("learn_prior: expected a count prior (support in 0, 1, 2, ...) or a "
                                   f"continuous prior, found a discrete prior on other values ({prior.dist.name})")
        return "count"
    lo, _ = prior.support()
    return "positive" if lo >= 0 else "real"


def shrunk_moments(stated_mean: float, stated_var: float, obs: np.ndarray, weight: float) -> tuple[float, float]:
    """Mean and variance of the mixture ``weight`` × stated prior + ``len(obs)`` × empirical
    distribution of ``obs`` (see the module docstring)."""
    obs = np.asarray(obs, dtype=float)
    n = obs.size
    if n == 0:
        return float(stated_mean), float(stated_var)
    xbar = float(obs.mean())
    s2 = float(obs.var())
    m = (weight * stated_mean + n * xbar) / (weight + n)
    v = (weight * (stated_var + (stated_mean - m) ** 2) + n * (s2 + (xbar - m) ** 2)) / (weight + n)
    return float(m), float(v)


def fit_prior(stated, obs, weight: float = PRIOR_WEIGHT) -> Fit:
    """The predictive prior of the next observation given observations ``obs`` (any shape; NaN
    entries are ignored) and the stated prior worth ``weight`` pseudo-observations.

    Raises:
        UnsupportedPrior: see :func:`family_of`.
    """
    import scipy.stats

    family = family_of(stated)
    obs = np.asarray(obs, dtype=float).ravel()
    obs = obs[~np.isnan(obs)]
    m0, v0 = float(stated.mean()), float(stated.var())
    if obs.size == 0:
        return Fit(stated, "stated", m0, v0, 0)
    m, v = shrunk_moments(m0, v0, obs, weight)
    if family == "real":
        return Fit(scipy.stats.norm(m, np.sqrt(max(v, 1e-12))), "normal", m, v, int(obs.size))
    m = max(m, MIN_MEAN)
    if family == "positive":
        v = max(v, 1e-12)
        return Fit(scipy.stats.gamma(m * m / v, scale=v / m), "gamma", m, v, int(obs.size))
    if v <= m * (1.0 + POISSON_TOLERANCE):
        return Fit(priors.Poisson(m), "poisson", m, v, int(obs.size))
    # Negative binomial with mean m and variance v: n = m² / (v - m), p = m / v.
    return Fit(scipy.stats.nbinom(m * m / (v - m), m / v), "negative_binomial", m, v, int(obs.size))


#: Learned problems per original problem: at most _PER_PROBLEM (the latest), dropped with it.
_LEARNED: "weakref.WeakKeyDictionary[Problem, OrderedDict]" = weakref.WeakKeyDictionary()
_PER_PROBLEM = 2


def learned_problem(problem: Problem, stage: int, x: np.ndarray, weight: float = PRIOR_WEIGHT) -> tuple[Problem, Fit]:
    """The problem as planned at stage ``stage``: ``problem`` with its prior replaced by
    :func:`fit_prior` of ``x[:, :stage + 1]`` (later columns are never read), the same passengers,
    validity, overlaps, conflict matrix and normalisation scale. ``problem`` itself when there is
    no observation yet.

    A few recent learned problems are kept per original problem (so their compiled forms, e.g.
    threshold tables, are reused when the same stage is decided again); memory stays bounded.
    """
    seen = np.asarray(x, dtype=float)[:, : stage + 1]
    fit = fit_prior(problem.prior, seen, weight)
    if fit.family == "stated":
        return problem, fit
    key = (fit.family, fit.mean, fit.var, float(weight))
    per = _LEARNED.setdefault(problem, OrderedDict())
    learned = per.get(key)
    if learned is None:
        # Same arrays (read-only, shared), same scale: only the prior differs.
        learned = dataclasses.replace(problem, prior=fit.prior)
        per[key] = learned
        while len(per) > _PER_PROBLEM:
            per.popitem(last=False)
    return learned, fit


class LearnedPriorPlanner:
    """Any planner, deciding every stage with the prior learned from the observations so far.

    Built by ``planner.registry.make_planner(name, learn_prior=True, ...)``. ``name`` is the inner
    planner's. Stateless across stages; its random stream is handed to the inner planner unchanged.
    """

    learn_prior = True

    def __init__(self, inner, weight: float = PRIOR_WEIGHT):
        if not weight > 0:
            raise ValueError(f"prior weight must be > 0, got {weight!r}")
        self.inner = inner
        self.weight = float(weight)
        self.name = inner.name

    def warm_up(self, problem: Problem) -> None:
        """Refuse an unsupported prior before the mission; warm the inner planner up."""
        family_of(problem.prior)
        warm = getattr(self.inner, "warm_up", None)
        if callable(warm):
            warm(problem)

    def view_for(self, view: StageView) -> StageView:
        """The view the inner planner sees: the same stage, observations, validity and decisions,
        bound to the learned problem."""
        problem, _ = learned_problem(view.problem, view.stage, view.observations, self.weight)
        if problem is view.problem:
            return view
        return dataclasses.replace(view, problem=problem)  # released passengers kept (passenger types)

    def decide(self, view: StageView, rng: np.random.Generator) -> np.ndarray:
        return self.inner.decide(self.view_for(view), rng)
