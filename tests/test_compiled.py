"""The compiled problem (planner.compiled): one exact sampler for every prior kind, thresholds and
their CDF table, CSR conflicts, built once per problem."""
from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from planner import priors
from planner.compiled import compile_problem
from planner.mcts import kernel
from planner.problem import Problem

#: One spec per prior kind (11), the table prior with non-integer values among them.
SPECS = {
    "poisson": {"kind": "poisson", "mean": 3.0},
    "binomial": {"kind": "binomial", "n": 8, "p": 0.4},
    "geometric": {"kind": "geometric", "p": 0.3},
    "negative_binomial": {"kind": "negative_binomial", "n": 2.0, "p": 0.4},
    "discrete_uniform": {"kind": "discrete_uniform", "low": -2, "high": 6},
    "table": {"kind": "table", "values": [0, 2.5, 5], "probabilities": [0.3, 0.4, 0.3]},
    "gamma": {"kind": "gamma", "shape": 2.0, "scale": 1.5},
    "exponential": {"kind": "exponential", "mean": 3.0},
    "lognormal": {"kind": "lognormal", "mu": 1.0, "sigma": 0.5},
    "normal": {"kind": "normal", "mean": 5.0, "std": 1.5},
    "uniform": {"kind": "uniform", "low": 0.0, "high": 6.0},
}
DRAWS = 100_000


def test_every_prior_kind_is_covered():
    assert set(SPECS) == set(priors.PRIOR_KINDS)


def _compiled(spec):
    prior = priors.build_prior(spec)
    return prior, compile_problem(Problem.build(1, np.ones((1, 3), dtype=bool), prior=prior))


def _samples(compiled):
    """The same sampler seen from the numba kernels and from Python."""
    s = compiled.sampler
    in_kernel = kernel.sample_many(np.array([2024], dtype=np.uint64), s.points, s.cdf, s.guide, DRAWS)
    in_python = s.sample(np.random.default_rng(2024), DRAWS)
    return {"kernel": in_kernel, "python": in_python}


@pytest.mark.parametrize("kind", list(SPECS))
def test_sampler_distribution_matches_the_prior(kind):
    prior, compiled = _compiled(SPECS[kind])
    for where, draws in _samples(compiled).items():
        if priors.is_discrete(prior):
            # Chi-square over the support points (tail beyond 99.9% pooled into one cell).
            points, mass = priors.support(prior)
            assert set(np.unique(draws)) <= set(points.tolist()), where  # no value off the support
            keep = np.cumsum(mass) <= 0.999
            keep[0] = True
            observed = np.array([np.sum(draws == v) for v in points[keep]] + [np.sum(~np.isin(draws, points[keep]))])
            expected = DRAWS * np.append(mass[keep], 1.0 - mass[keep].sum())
            ok = expected > 0
            chi2 = float(np.sum((observed[ok] - expected[ok]) ** 2 / expected[ok]))
            assert stats.chi2.sf(chi2, ok.sum() - 1) > 1e-3, (where, chi2)
        else:
            # Python draws are exact; the kernel's 4096 equiprobable atoms are within 1/4096 in CDF.
            assert stats.kstest(draws, prior.cdf).pvalue > 1e-3, where


def test_table_prior_with_non_integer_values_is_sampled_on_its_values():
    """The bug this module fixed: MCTS used to sample a table prior on the integers 0..5."""
    _, compiled = _compiled(SPECS["table"])
    for where, draws in _samples(compiled).items():
        values, counts = np.unique(draws, return_counts=True)
        assert values.tolist() == [0.0, 2.5, 5.0], where
        assert np.allclose(counts / DRAWS, [0.3, 0.4, 0.3], atol=0.01), where


def test_compiled_once_per_problem_and_consistent():
    problem = Problem.build(2, np.ones((3, 5), dtype=bool), [[(0, 1), (1, 1), (2, 3)], [(0, 4), (0, 2)]])
    cp = compile_problem(problem)
    assert compile_problem(problem) is cp
    assert cp.table is cp.table and cp.conflict is problem.conflict
    dense = np.zeros_like(problem.conflict)
    for a in range(dense.shape[0]):
        dense[a, cp.nbr[cp.indptr[a]:cp.indptr[a + 1]]] = True
    assert np.array_equal(dense, problem.conflict)
    with pytest.raises(ValueError):
        cp.table[2, 1] = 0.0  # shared: read-only
