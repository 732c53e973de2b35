"""Online planners: feasibility, causality and determinism for every planner in conftest's list;
exact uniformity of the random planner; SSAP = per-carrier DLR; the registry."""
from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy import stats

from planner import registry as planners, ssap
from planner.instance import random_instance
from planner.policies import RandomPlanner, SSAPPlanner
from planner.registry import make_planner, planner_names, register
from planner.problem import Problem, sample_observations
from planner.online import run_online


def _instances(seed: int, count: int):
    """Varied small instances: per-carrier D (zeros too), ∅ stages, self-conflicts, D > stages."""
    rng = np.random.default_rng(seed)
    for _ in range(count):
        carriers = int(rng.integers(1, 5))
        stages = int(rng.integers(1, 9))
        passengers = rng.integers(0, 5, size=carriers).tolist()
        inst = random_instance(rng, carriers=carriers, passengers=passengers, stages=stages,
                               overlaps=int(rng.integers(0, 8)), mean=float(rng.uniform(0.5, 5)),
                               invalid_fraction=float(rng.choice([0.0, 0.2, 0.5])))
        yield inst


def _surprise(x: np.ndarray, rng: np.random.Generator, fraction: float = 0.15) -> np.ndarray:
    """Turn some scheduled stages ∅ online (a carrier that did not report)."""
    x = x.copy()
    x[rng.random(x.shape) < fraction] = np.nan
    return x


def test_feasibility_on_schedules_without_surprises(planner_spec):
    name, options = planner_spec
    planner = make_planner(name, **options)
    for k, (problem, x) in enumerate(_instances(1, 25)):
        result = run_online(problem, x, planner, seed=k)  # enforce() checks every stage's rules
        valid = ~np.isnan(x)
        assert not (result.deployed & ~valid).any()
        expected = np.minimum(problem.passengers, valid.sum(axis=1))
        assert result.deployed.sum(axis=1).tolist() == expected.tolist()  # every passenger deployed
        assert 0.0 <= result.features and len(result.decision_ms) == problem.n_stages


def test_feasibility_with_online_surprises(planner_spec):
    name, options = planner_spec
    planner = make_planner(name, **options)
    rng = np.random.default_rng(2)
    for k, (problem, x) in enumerate(_instances(3, 20)):
        x = _surprise(x, rng)
        result = run_online(problem, x, planner, seed=k)
        assert not (result.deployed & np.isnan(x)).any()
        assert (result.deployed.sum(axis=1) <= problem.passengers).all()


def test_causality(planner_spec):
    """Changing the observations after stage j never changes the decisions up to j."""
    name, options = planner_spec
    planner = make_planner(name, **options)
    rng = np.random.default_rng(4)
    for k, (problem, x) in enumerate(_instances(5, 12)):
        base = run_online(problem, x, planner, seed=k).deployed
        for j in range(problem.n_stages - 1):
            other = x.copy()
            fresh = _surprise(sample_observations(problem, rng), rng)
            other[:, j + 1:] = fresh[:, j + 1:]
            changed = run_online(problem, other, planner, seed=k).deployed
            assert np.array_equal(base[:, : j + 1], changed[:, : j + 1]), (k, j)


def test_determinism(planner_spec):
    name, options = planner_spec
    for k, (problem, x) in enumerate(_instances(6, 8)):
        first = run_online(problem, x, make_planner(name, **options), seed=100 + k)
        second = run_online(problem, x, make_planner(name, **options), seed=100 + k)
        assert np.array_equal(first.deployed, second.deployed)
        assert first.reward == second.reward


def test_random_planner_picks_uniform_subsets():
    problem = Problem.build(2, np.ones((1, 5), bool))
    x = np.ones((1, 5))
    counts = {}
    runs = 2000
    for seed in range(runs):
        stages = tuple(np.flatnonzero(run_online(problem, x, RandomPlanner(), seed).deployed[0]))
        counts[stages] = counts.get(stages, 0) + 1
    assert set(counts) == set(itertools.combinations(range(5), 2))
    # Each of the 10 subsets has probability 1/10: 200 expected, sd ~13.4; allow 5 sd.
    assert all(abs(c - runs / 10) < 67 for c in counts.values()), counts


def test_random_planner_never_deploys_at_invalid_stages_and_still_deploys_all():
    valid = np.array([[False, True, False, True, True, False, True]])
    problem = Problem.build(3, valid)
    x = np.where(valid, 1.0, np.nan)
    seen = set()
    for seed in range(200):
        dep = run_online(problem, x, RandomPlanner(), seed).deployed[0]
        assert dep.sum() == 3 and not (dep & ~valid[0]).any()
        seen.add(tuple(np.flatnonzero(dep)))
    assert len(seen) == 4  # all C(4, 3) subsets of the valid stages occur


def test_ssap_planner_is_per_carrier_dlr_and_ignores_conflicts():
    rng = np.random.default_rng(7)
    for _ in range(20):
        with_conflicts, x = random_instance(rng, carriers=3, passengers=[1, 2, 3], stages=9, overlaps=15)
        no_conflicts = Problem.build([1, 2, 3], with_conflicts.valid, [], with_conflicts.prior)
        a = run_online(with_conflicts, x, SSAPPlanner(), 0).deployed
        b = run_online(no_conflicts, x, SSAPPlanner(), 0).deployed
        assert np.array_equal(a, b)
        table = ssap.table_for(no_conflicts)
        for r in range(3):
            left = int(no_conflicts.passengers[r])
            for j in range(9):
                expect = ssap.decide(table, x[r, j], 9 - j, left)
                assert a[r, j] == expect
                left -= int(expect)


def test_ssap_beats_random_in_expectation_without_conflicts():
    rng = np.random.default_rng(8)
    problem = Problem.build(3, np.ones((4, 10), bool), [], stats.poisson(3.0))
    ssap_total = random_total = 0.0
    for k in range(150):
        x = sample_observations(problem, rng)
        ssap_total += run_online(problem, x, SSAPPlanner(), k).features
        random_total += run_online(problem, x, RandomPlanner(), k).features
    # Exact expectations: random 4*3*3 = 36 per instance; SSAP = 4 * expected_value(10, 3).
    expected = 4 * ssap.expected_value(ssap.table_for(problem), 10, 3)
    assert expected > 36.0 + 5
    assert abs(ssap_total / 150 - expected) < 2.0
    assert abs(random_total / 150 - 36.0) < 2.0


def test_registry():
    assert {"random", "ssap", "mcts-random", "mcts-ssap"} <= set(planner_names())
    with pytest.raises(ValueError, match="expected one of: .*mcts-ssap.*random.*ssap"):
        make_planner("greedy")
    with pytest.raises(ValueError, match="unknown planner option"):
        make_planner("ssap", depth=3)
    assert isinstance(make_planner("ssap", iterations=None), SSAPPlanner)
    assert make_planner("mcts-ssap", iterations=5).name == "mcts-ssap"
    assert make_planner("mcts-random", iterations=5).name == "mcts-random"
    register("test-always-ssap", lambda **options: SSAPPlanner())
    try:
        assert isinstance(make_planner("test-always-ssap", iterations=3), SSAPPlanner)
        assert "test-always-ssap" in planner_names()
    finally:
        planners._REGISTRY.pop("test-always-ssap")


def test_scenario_files_accept_exactly_the_registered_planners():
    """world/ reads planner names from the registry (it keeps no list of its own), so a planner
    registered later is accepted by scenario files too, and an unregistered name is refused."""
    import world.scenario
    from planner.registry import check_settings

    assert not hasattr(world.scenario, "PLANNER_NAMES")
    register("test-late-planner", lambda **options: SSAPPlanner())
    try:
        assert check_settings("test-late-planner", {}) == []
        assert set(planner_names()) >= {"random", "ssap", "mcts-random", "mcts-ssap", "closed-loop"}
        assert all(check_settings(name, {}) == [] for name in planner_names())
    finally:
        planners._REGISTRY.pop("test-late-planner")
    assert [p.field for p in check_settings("test-late-planner", {})] == ["name"]
