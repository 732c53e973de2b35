"""The clairvoyant optimum: exact against brute force, never below an online planner, and an
honest upper bound when the exact search is cut short."""
from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy import stats

from planner import clairvoyant
from planner.instance import random_instance
from planner.registry import make_planner
from planner.problem import Problem, evaluate
from planner.online import run_online


def brute_force(problem: Problem, x: np.ndarray) -> float:
    """Largest raw total over every feasible offline plan (min(D_r, valid) stages per carrier)."""
    valid = problem.valid & ~np.isnan(x)
    per_carrier = []
    for r in range(problem.n_carriers):
        stages = np.flatnonzero(valid[r])
        per_carrier.append(list(itertools.combinations(stages, min(int(problem.passengers[r]), len(stages)))))
    best = -np.inf
    for plan in itertools.product(*per_carrier):
        deployed = np.zeros(valid.shape, dtype=bool)
        for r, stages in enumerate(plan):
            deployed[r, list(stages)] = True
        best = max(best, evaluate(problem, deployed, x)[1])
    return best


def brute_force_vectorised(problem: Problem, x: np.ndarray) -> float:
    """The same maximum as :func:`brute_force`, with all plans evaluated at once (matrix form)."""
    valid = problem.valid & ~np.isnan(x)
    n_stages = problem.n_stages
    plans = np.zeros((1, 0), dtype=bool)
    for r in range(problem.n_carriers):
        stages = np.flatnonzero(valid[r])
        rows = np.zeros((0, n_stages), dtype=bool)
        for chosen in itertools.combinations(stages, min(int(problem.passengers[r]), len(stages))):
            row = np.zeros((1, n_stages), dtype=bool)
            row[0, list(chosen)] = True
            rows = np.vstack([rows, row])
        plans = np.hstack([np.repeat(plans, len(rows), axis=0), np.tile(rows, (len(plans), 1))])
    sel = plans.astype(float)
    p = 1.0 + sel @ problem.conflict.astype(float)
    return float((sel * np.nan_to_num(x.ravel(), nan=0.0) / p).sum(axis=1).max())


def _small_instances(seed: int, count: int, prior=None):
    rng = np.random.default_rng(seed)
    for _ in range(count):
        carriers, stages = int(rng.integers(1, 4)), int(rng.integers(1, 7))
        valid = rng.random((carriers, stages)) > 0.2
        overlaps = [[[int(rng.integers(carriers)), int(rng.integers(stages))] for _ in range(int(rng.integers(2, 4)))]
                    for _ in range(int(rng.integers(0, 7)))]
        problem = Problem.build(rng.integers(0, 4, size=carriers), valid, overlaps,
                                prior or stats.poisson(3.0), normalize="none")
        x = problem.prior.rvs(size=valid.shape, random_state=rng).astype(float)
        yield problem, np.where(valid, x, np.nan)


@pytest.mark.parametrize("prior", [stats.poisson(3.0), stats.norm(0.5, 2.0)], ids=["poisson", "normal-negatives"])
def test_exact_matches_brute_force(prior):
    for problem, x in _small_instances(11, 150, prior):
        result = clairvoyant.solve(problem, x)
        assert result.exact
        assert result.features == pytest.approx(brute_force(problem, x), abs=1e-9)
        # The plan is feasible and its evaluation is the reported value.
        valid = ~np.isnan(x)
        assert not (result.deployed & ~valid).any()
        assert result.deployed.sum(axis=1).tolist() == np.minimum(problem.passengers, valid.sum(axis=1)).tolist()
        assert evaluate(problem, result.deployed, x) == pytest.approx((result.reward, result.features))


def test_exact_matches_brute_force_with_many_carriers_and_heavy_tails():
    """Many carriers, few stages, dense overlaps, occasional large observations: the instances where
    the search bound decides most (a bound that is too tight shows up here as a wrong optimum)."""
    rng = np.random.default_rng(16)
    for _ in range(150):
        problem, x = random_instance(rng, carriers=6, passengers=2, stages=3, overlaps=12, mean=1.0)
        x = x + (rng.random(x.shape) < 0.3) * rng.integers(0, 10, x.shape)
        result = clairvoyant.solve(problem, x)
        assert result.exact
        assert result.features == pytest.approx(brute_force_vectorised(problem, x), abs=1e-9)


def test_exact_on_paper_sized_instances_with_heavy_conflicts():
    rng = np.random.default_rng(12)
    for _ in range(5):
        problem, x = random_instance(rng, carriers=3, passengers=2, stages=6, overlaps=14)
        result = clairvoyant.solve(problem, x)
        assert result.exact and result.features == pytest.approx(brute_force(problem, x))
        assert brute_force_vectorised(problem, x) == pytest.approx(result.features)
    for _ in range(20):
        problem, x = random_instance(rng, carriers=4, passengers=3, stages=10, overlaps=20)
        result = clairvoyant.solve(problem, x)
        assert result.exact
        bound = clairvoyant.conflict_free_bound(problem, x)
        assert result.reward <= bound.reward + 1e-12


def test_never_below_an_online_planner(planner_spec):
    name, options = planner_spec
    planner = make_planner(name, **options)
    rng = np.random.default_rng(13)
    for k in range(10):
        problem, x = random_instance(rng, carriers=4, passengers=3, stages=10, overlaps=20,
                                     invalid_fraction=0.1)
        best = clairvoyant.solve(problem, x)
        online = run_online(problem, x, planner, seed=k)
        assert best.exact and online.reward <= best.reward + 1e-12


def test_node_limit_returns_the_conflict_free_upper_bound():
    rng = np.random.default_rng(14)
    problem, x = random_instance(rng, carriers=4, passengers=3, stages=10, overlaps=30)
    exact = clairvoyant.solve(problem, x)
    cut = clairvoyant.solve(problem, x, max_nodes=1)
    assert exact.exact and not cut.exact
    top = sum(np.sort(x[r])[-3:].sum() for r in range(4))
    assert cut.features == pytest.approx(top)
    assert cut.reward >= exact.reward
    assert cut.deployed.sum() == 12


def test_too_many_options_falls_back_without_searching():
    rng = np.random.default_rng(15)
    # 40 overlapped stages, 12 passengers: C(40, 12) options for a carrier.
    problem, x = random_instance(rng, carriers=2, passengers=12, stages=40, overlaps=200)
    result = clairvoyant.solve(problem, x)
    assert not result.exact and result.nodes == 0
    assert result.features == pytest.approx(sum(np.sort(x[r])[-12:].sum() for r in range(2)))
