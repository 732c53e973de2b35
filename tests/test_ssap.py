"""DLR thresholds against a brute-force dynamic programme, for discrete and continuous priors."""
from __future__ import annotations

import numpy as np
import pytest
from scipy import integrate, stats

from planner import priors, ssap
from planner.problem import Problem


def _dp_discrete(prior, n_max):
    """V[n, d]: optimal expected total with n stages and d passengers (forced deployment)."""
    points = np.arange(0, 400, dtype=float)
    mass = prior.pmf(points)
    assert abs(mass.sum() - 1) < 1e-12

    def expect_max(a, b):  # E[max(X + a, b)]
        return float(np.dot(mass, np.maximum(points + a, b)))

    return _dp(expect_max, float(np.dot(mass, points)), n_max)


def _dp_continuous(prior, n_max):
    lo, hi = prior.support()

    def expect_max(a, b):  # E[max(X + a, b)] = b F(c) + ∫_c^hi (x + a) f(x) dx, c = b - a
        c = b - a
        if c <= lo:
            return prior.mean() + a
        tail, _ = integrate.quad(lambda v: (v + a) * prior.pdf(v), c, hi, epsabs=1e-12, epsrel=1e-12, limit=200)
        return b * prior.cdf(c) + tail

    return _dp(expect_max, prior.mean(), n_max)


def _dp(expect_max, mean, n_max):
    value = np.zeros((n_max + 1, n_max + 2))
    for n in range(1, n_max + 1):
        for d in range(1, n_max + 2):
            if d >= n:
                value[n, d] = n * mean  # forced: every remaining stage deploys
            else:
                value[n, d] = expect_max(value[n - 1, d - 1], value[n - 1, d])
    return value


#: name -> (prior, brute-force DP, tolerance, largest number of stages checked).
PRIORS = {
    "poisson3": (stats.poisson(3.0), _dp_discrete, 1e-9, 14),
    "poisson0.7": (stats.poisson(0.7), _dp_discrete, 1e-9, 14),
    "binomial": (stats.binom(8, 0.4), _dp_discrete, 1e-9, 14),
    "gamma": (stats.gamma(2.0, scale=1.5), _dp_continuous, 1e-6, 10),
    "lognormal": (stats.lognorm(0.6, scale=2.0), _dp_continuous, 1e-6, 10),
    "normal": (stats.norm(3.0, 1.5), _dp_continuous, 1e-6, 10),
}


@pytest.mark.parametrize("prior_name", list(PRIORS))
def test_thresholds_match_dynamic_programme(prior_name):
    prior, dp, tol, n_max = PRIORS[prior_name]
    table = ssap.thresholds(prior, n_max)
    value = dp(prior, n_max)
    checked = 0
    for n in range(1, n_max + 1):
        for d in range(0, n + 2):
            assert ssap.expected_value(table, n, d) == pytest.approx(value[n, min(d, n)], rel=tol, abs=tol)
            if d == 0:
                assert not ssap.decide(table, 1e9, n, d)
                continue
            if d >= n:
                assert ssap.decide(table, -1e9, n, d)  # forced
                continue
            # The DP deploys iff x + V(n-1, d-1) > V(n-1, d): the indifference point is the threshold.
            indifference = value[n - 1, d] - value[n - 1, d - 1]
            assert table[n, n - d] == pytest.approx(indifference, rel=tol, abs=tol)
            for x in np.concatenate([np.arange(-2.0, 15.0), indifference + np.array([-1e-3, 1e-3])]):
                if abs(x - indifference) < 1e-4:
                    continue  # a tie: both choices are optimal
                assert ssap.decide(table, x, n, d) == (x + value[n - 1, d - 1] > value[n - 1, d]), (n, d, x)
                checked += 1
    assert checked > 300


def test_thresholds_for_a_table_prior_with_non_integer_support():
    prior = stats.rv_discrete(values=([0.5, 2.25, 7.0], [0.5, 0.3, 0.2]))()
    table = ssap.thresholds(prior, 6)
    points, mass = priors.support(prior)
    assert points.tolist() == [0.5, 2.25, 7.0]

    def expect_max(a, b):
        return float(np.dot(mass, np.maximum(points + a, b)))

    value = _dp(expect_max, float(np.dot(mass, points)), 6)
    for n in range(1, 7):
        for d in range(1, n + 1):
            assert ssap.expected_value(table, n, d) == pytest.approx(value[n, d], rel=1e-12)


def test_thresholds_are_monotone():
    table = ssap.thresholds(stats.poisson(3.0), 10)
    for n in range(2, 12):
        row = table[n, : n + 1]
        assert np.all(np.diff(row) > 0), n


def test_table_for_is_cached_per_prior_parameters():
    a = Problem.build(3, np.ones((2, 10), bool), prior=stats.poisson(3.0))
    b = Problem.build(1, np.ones((4, 10), bool), prior=stats.poisson(3.0))
    c = Problem.build(3, np.ones((2, 10), bool), prior=stats.poisson(4.0))
    assert ssap.table_for(a) is ssap.table_for(b)
    assert ssap.table_for(a) is not ssap.table_for(c)
    assert ssap.table_for(a).shape == (12, 12)
    assert not ssap.table_for(a).flags.writeable


@pytest.mark.parametrize("mean", [0.4, 3.0, 9.5])
def test_poisson_closed_form_equals_enumeration(mean):
    """Poisson thresholds use a closed form; the same distribution as a table uses the finite sum."""
    points = np.arange(0, 120)
    mass = stats.poisson(mean).pmf(points)
    as_table = stats.rv_discrete(values=(points, mass / mass.sum()))()
    closed = ssap.thresholds(stats.poisson(mean), 12)
    summed = ssap.thresholds(as_table, 12)
    finite = np.isfinite(closed)
    assert np.array_equal(finite, np.isfinite(summed))
    assert np.allclose(closed[finite], summed[finite], rtol=1e-12, atol=1e-12)


#: Two parameter sets per continuous prior kind of planner.priors.
CONTINUOUS_SPECS = {
    "gamma": ({"kind": "gamma", "shape": 2.0, "scale": 1.5}, {"kind": "gamma", "shape": 0.7, "scale": 3.0}),
    "exponential": ({"kind": "exponential", "mean": 3.0}, {"kind": "exponential", "mean": 0.4}),
    "lognormal": ({"kind": "lognormal", "mu": 1.0, "sigma": 0.5}, {"kind": "lognormal", "mu": -0.3, "sigma": 1.2}),
    "normal": ({"kind": "normal", "mean": 1.0, "std": 2.0}, {"kind": "normal", "mean": -4.0, "std": 0.3}),
    "uniform": ({"kind": "uniform", "low": 0.0, "high": 6.0}, {"kind": "uniform", "low": 2.5, "high": 3.0}),
}


def test_every_continuous_prior_kind_has_pointwise_specs():
    from experiments.bound import TINY_PRIORS  # one spec per prior kind

    assert set(TINY_PRIORS) == set(priors.PRIOR_KINDS)
    assert {k for k, spec in TINY_PRIORS.items() if not priors.is_discrete(priors.build_prior(spec))} == set(CONTINUOUS_SPECS)


@pytest.mark.parametrize("spec", [s for pair in CONTINUOUS_SPECS.values() for s in pair],
                         ids=[f"{k}-{i}" for k, pair in CONTINUOUS_SPECS.items() for i in range(len(pair))])
def test_the_quadratures_pointwise_cdf_and_sf_are_the_frozen_distributions_bit_for_bit(spec, monkeypatch):
    """The threshold tables' quadrature calls ``ssap._pointwise`` (without the frozen
    distribution's per-call argument handling): the same bits as ``prior.cdf`` and ``prior.sf`` at
    points inside, on the edges of and outside the support, and so the same table."""
    prior = priors.build_prior(spec)
    lo, hi = prior.support()
    rng = np.random.default_rng(4)
    points = [*rng.normal(prior.mean(), 3 * prior.std() + 1, 600).tolist(), *rng.uniform(-20, 20, 200).tolist(),
              float(lo), float(hi), float(np.nextafter(lo, np.inf)), float(np.nextafter(hi, -np.inf)), -1e300, 1e300]
    for name in ("cdf", "sf"):
        fast, frozen = ssap._pointwise(prior, name), getattr(prior, name)
        with np.errstate(over="ignore"):  # the frozen method's division at +-1e300
            mismatched = [(x, fast(x), float(frozen(x))) for x in points if np.isfinite(x) and fast(x) != float(frozen(x))]
        assert mismatched == [], (name, mismatched[:3])
    fast_table = ssap.thresholds(prior, 5)
    monkeypatch.setattr(ssap, "_pointwise", lambda prior, name: getattr(prior, name))
    assert np.array_equal(fast_table, ssap.thresholds(prior, 5), equal_nan=True)
