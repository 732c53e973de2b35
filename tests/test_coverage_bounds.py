"""Bounds under the coverage reward (issue 35): the clairvoyant by integer programming against brute
force, the LP and union bounds above it, the size refusal, the information-relaxation bound's
zero-mean penalty and its place between the planners and the clairvoyant mean."""
from __future__ import annotations

import itertools
import json
from pathlib import Path

import numpy as np
import pytest

from planner import clairvoyant, coverage as cov, coverage_bounds as cb, priors
from planner.instance import load_instance_counts
from planner.online import run_online
from planner.problem import Problem, evaluate
from planner.registry import make_planner

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "coverage_tiny.json"


def random_coverage(rng, carriers=3, passengers=2, stages=4, regions=8, invalid=0.0, weights=None, binomial=False):
    """A small seeded coverage instance: each valid point explores 1-3 random regions (Poisson
    means in 0.5..3; region 0 binomial(4, 0.5) with ``binomial``). Returns (problem, x, counts)."""
    valid = rng.random((carriers, stages)) >= invalid
    covers = [[sorted(rng.choice(regions, size=int(rng.integers(1, 4)), replace=False).tolist()) if valid[r, j]
               else None for j in range(stages)] for r in range(carriers)]
    specs = [{"kind": "poisson", "mean": float(mu)} for mu in rng.uniform(0.5, 3.0, regions)]
    if binomial:
        specs[0] = {"kind": "binomial", "n": 4, "p": 0.5}
    coverage = cov.Coverage.build(covers, [priors.build_prior(s) for s in specs])
    problem = Problem.build(passengers, valid, coverage.overlaps(stages),
                            priors.build_prior({"kind": "poisson", "mean": 4.0}), weights=weights, coverage=coverage)
    counts = cov.sample_counts(coverage, rng)
    return problem, cov.observations(coverage, counts, valid), counts


def brute_force(problem, x, counts) -> float:
    """The best value over every feasible deployment set (and every passenger assignment)."""
    feasible = cb.feasible_points(problem, x)
    ks = cb.quotas(problem, feasible)
    per_carrier = []
    for r in range(problem.n_carriers):
        options = []
        for stages in itertools.combinations(np.flatnonzero(feasible[r]).tolist(), int(ks[r])):
            for who in itertools.permutations(range(int(problem.passengers[r])), int(ks[r])):
                options.append((stages, who))
                if problem.weights is None:
                    break
        per_carrier.append(options)
    best = -1.0
    for choice in itertools.product(*per_carrier):
        deployed = np.zeros(problem.valid.shape, dtype=bool)
        released = np.full(problem.valid.shape, -1, dtype=np.int64)
        for r, (stages, who) in enumerate(choice):
            deployed[r, list(stages)] = True
            released[r, list(stages)] = who
        best = max(best, evaluate(problem, deployed, x, released, counts=counts)[1])
    return best


def _check_feasible(problem, x, result):
    feasible = cb.feasible_points(problem, x)
    assert not (result.deployed & ~feasible).any()
    assert (result.deployed.sum(axis=1) == cb.quotas(problem, feasible)).all()


@pytest.mark.parametrize("invalid", [0.0, 0.3])
@pytest.mark.parametrize("seed", range(6))
def test_the_integer_program_is_the_brute_force_optimum(seed, invalid):
    problem, x, counts = random_coverage(np.random.default_rng(seed), invalid=invalid)
    result = cb.solve(problem, x, counts)
    assert result.exact and result.method == "ilp" and result.gap == 0.0
    assert result.features == pytest.approx(brute_force(problem, x, counts))
    assert result.reward == pytest.approx(result.features / problem.scale)
    _check_feasible(problem, x, result)
    assert evaluate(problem, result.deployed, x, result.released, counts=counts)[1] == pytest.approx(result.features)


@pytest.mark.parametrize("seed", range(3))
def test_with_passenger_values_each_region_is_worth_its_best_passenger(seed):
    weights = [[3.0, 1.0], [1.0, 2.0], [0.5, 4.0]]
    problem, x, counts = random_coverage(np.random.default_rng(100 + seed), invalid=0.2, weights=weights)
    result = cb.solve(problem, x, counts)
    assert result.exact
    assert result.features == pytest.approx(brute_force(problem, x, counts))
    assert evaluate(problem, result.deployed, x, result.released, counts=counts)[1] == pytest.approx(result.features)


@pytest.mark.parametrize("seed", range(5))
def test_relaxations_bound_the_optimum_from_above_and_greedy_from_below(seed):
    problem, x, counts = random_coverage(np.random.default_rng(200 + seed), carriers=4, stages=6, regions=10,
                                         invalid=0.2)
    exact = cb.solve(problem, x, counts, method="ilp")
    lp = cb.solve(problem, x, counts, method="lp")
    union = cb.solve(problem, x, counts, method="union")
    assert exact.exact and not lp.exact and not union.exact
    assert union.features + 1e-9 >= lp.features >= exact.features - 1e-9
    greedy = evaluate(problem, *cb.greedy(problem, cb.feasible_points(problem, x), counts), counts=counts)[1]
    assert greedy <= exact.features + 1e-9
    for bound in (lp, union):
        _check_feasible(problem, x, bound)
        found = evaluate(problem, bound.deployed, x, bound.released, counts=counts)[1]
        assert 0.0 <= bound.gap < 1.0 and bound.gap == pytest.approx((bound.features - found) / bound.features)


def test_the_clairvoyant_entry_point_dispatches_on_the_reward():
    (problem, x), counts, _ = load_instance_counts(EXAMPLE)
    assert clairvoyant.solve(problem, x, counts=counts).features == cb.solve(problem, x, counts).features == 13.0
    with pytest.raises(ValueError, match="region counts"):
        clairvoyant.solve(problem, x)


def test_a_model_beyond_its_size_is_refused_before_anything_is_built(monkeypatch):
    rng = np.random.default_rng(0)
    carriers, stages, regions = 100, 40, 1000
    covers = [[rng.choice(regions, size=60, replace=False).tolist() for _ in range(stages)] for _ in range(carriers)]
    prior = priors.build_prior({"kind": "poisson", "mean": 1.0})
    coverage = cov.Coverage.build(covers, [prior] * regions)
    problem = Problem.build(3, np.ones((carriers, stages), dtype=bool), (), prior, coverage=coverage)
    counts = np.ones(regions)
    x = cov.observations(coverage, counts, problem.valid)

    class Refused:
        def __init__(self, *args, **kwargs):
            raise AssertionError("a model was built")

    monkeypatch.setattr("planner.highs.Model", Refused)
    size = cb.model_size(problem, problem.valid)
    assert size.nonzeros > cb.ILP_NONZEROS and cb.method_for(size) == "lp"
    with pytest.raises(cb.TooLarge, match="ilp model of about"):
        cb.solve(problem, x, counts, method="ilp")
    from planner import duality

    with pytest.raises(duality.BoundTooLarge, match="coverage upper bound"):
        cb.plan(problem, 3.0, 200)


# ----------------------------------------------------------------------------- the upper bound


def _policy_penalty(problem, counts, phi, rng) -> float:
    """z along a non-anticipative policy's path: deploy when forced or when the observation beats
    a coin-dependent threshold (it reads x at the stage it decides, never later)."""
    x = cov.observations(problem.coverage, counts, problem.valid)
    left = problem.passengers.copy()
    stages_left = problem.valid[:, ::-1].cumsum(axis=1)[:, ::-1]
    z = 0.0
    for j in range(problem.n_stages):
        for r in np.flatnonzero(problem.valid[:, j]):
            z += phi[r, j, left[r]]
            if left[r] and (stages_left[r, j] <= left[r] or x[r, j] > 3 + rng.integers(0, 3)):
                left[r] -= 1
    return z


@pytest.mark.parametrize("binomial", [False, True])
def test_the_penalty_has_mean_zero_along_a_non_anticipative_policy(binomial):
    problem, _, _ = random_coverage(np.random.default_rng(7), carriers=3, passengers=2, stages=5, regions=6,
                                    invalid=0.2, binomial=binomial)
    rng = np.random.default_rng(1)
    z = np.array([_policy_penalty(problem, counts, cb.penalty_terms(problem, counts), rng)
                  for counts in (cov.sample_counts(problem.coverage, rng) for _ in range(2000))])
    assert np.abs(z).mean() > 0.1  # a real penalty, not zero
    assert abs(z.mean()) < 4 * z.std(ddof=1) / np.sqrt(len(z))


def test_the_shortfall_is_exact_against_enumeration():
    problem, _, _ = random_coverage(np.random.default_rng(3), regions=4, binomial=True)
    regions = np.array([0, 1, 2])
    rng = np.random.default_rng(5)
    draws = sum(problem.coverage.priors[m].rvs(size=40_000, random_state=rng) for m in regions)
    for t in (-1.0, 0.0, 2.5, 6.0):
        mc = np.maximum(t - draws, 0.0)
        assert cb._shortfall(problem.coverage, regions, t) == pytest.approx(mc.mean(), abs=4 * mc.std() / 200 + 1e-12)


# ----------------------------------------------------------------------------- V*


def _instance(covers, means, passengers):
    prior = priors.build_prior({"kind": "poisson", "mean": 3.0})
    coverage = cov.Coverage.build(covers, [priors.build_prior({"kind": "poisson", "mean": m}) for m in means])
    valid = np.array([[c is not None for c in row] for row in covers])
    return Problem.build(passengers, valid, coverage.overlaps(valid.shape[1]), prior, coverage=coverage)


def test_v_star_of_one_carrier_is_the_stopping_value_in_closed_form():
    from scipy import stats

    from planner import coverage_optimal as co

    # Deploy at stage 0 (worth C0, seen) or wait for stage 1 (worth C1, unseen, mean 1.5).
    problem = _instance([[[0], [1]]], [2.0, 1.5], 1)
    c = np.arange(200)
    exact = float(np.dot(np.maximum(c, 1.5), stats.poisson.pmf(c, 2.0))) / problem.scale
    for tail in (1e-2, 1e-6):
        best = co.online_value(problem, tail)
        assert best.expected_reward <= exact + 1e-12 <= best.expected_reward + best.truncation_error + 1e-12
    assert co.online_value(problem, 1e-6).truncation_error < 1e-5


def test_v_star_of_a_lone_carrier_with_disjoint_discs_is_its_dlr_value():
    """Alone and without overlaps, what was revealed says nothing of the future: V* is the
    single-carrier optimum, computed independently by the penalty's backward induction."""
    from planner import coverage_optimal as co

    problem = _instance([[[0], [1, 2], [3], [4, 5]]], [1.0, 0.5, 1.5, 2.0, 0.7, 0.4], 2)
    best = co.online_value(problem, 1e-6)
    dlr = cb.values_to_go(problem)[0, 0, 2] / problem.scale
    assert best.expected_reward <= dlr + 1e-12 <= best.expected_reward + best.truncation_error + 1e-12
    assert best.truncation_error < 1e-4


def test_v_star_values_a_shared_region_once():
    from planner import coverage_optimal as co

    # Two carriers forced at one stage, exploring {0, 1} and {1, 2}: V* = the three regions' means.
    problem = _instance([[[0, 1]], [[1, 2]]], [1.0, 2.0, 0.5], 1)
    best = co.online_value(problem, 1e-9)
    assert best.expected_reward * problem.scale == pytest.approx(3.5, abs=best.truncation_error * problem.scale + 1e-9)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1])
def test_v_star_lies_between_the_planners_and_the_bounds(seed):
    """planners' means <= V* <= the information-relaxation bound <= the clairvoyant mean (the last
    two on the same counts; each up to 3 standard errors)."""
    from planner import coverage_optimal as co

    problem, _, _ = random_coverage(np.random.default_rng(300 + seed), carriers=2, passengers=1, stages=4, regions=6)
    best = co.online_value(problem, 1e-3)
    bound = cb.upper_bound(problem, np.random.default_rng(9), 80, "mip")
    clair = cb.upper_bound(problem, np.random.default_rng(9), 80, "mip", penalty=False)
    assert bound.expected_reward + 3 * bound.stderr >= best.expected_reward
    assert bound.expected_reward <= clair.expected_reward + 3 * clair.stderr
    rng = np.random.default_rng(11)
    rewards, offline = {"ssap": [], "random": []}, []
    planners = {name: make_planner(name) for name in rewards}
    for t in range(200):
        counts = cov.sample_counts(problem.coverage, rng)
        x = cov.observations(problem.coverage, counts, problem.valid)
        offline.append(cb.solve(problem, x, counts).reward)
        for name in rewards:
            rewards[name].append(run_online(problem, x, planners[name], t, counts).reward)
    se = np.std(offline, ddof=1) / np.sqrt(len(offline))
    assert best.expected_reward <= np.mean(offline) + 3 * se
    for name, values in rewards.items():
        se = np.std(values, ddof=1) / np.sqrt(len(values))
        assert best.expected_reward + best.truncation_error + 3 * se >= np.mean(values), name


def test_v_star_refuses_beyond_its_limits_in_one_line():
    from planner import coverage_optimal as co

    problem, _, _ = random_coverage(np.random.default_rng(0), carriers=8, passengers=2, stages=4, regions=40)
    with pytest.raises(co.TooLarge, match="outcome, action") as err:
        co.online_value(problem)
    assert "\n" not in str(err.value)
    small, _, _ = random_coverage(np.random.default_rng(1), carriers=3, passengers=1, stages=4, regions=8)
    with pytest.raises(co.TooLarge, match="evaluations"):
        co.online_value(small, max_nodes=10)


@pytest.mark.slow
def test_solve_reports_the_coverage_bounds_with_fractions(monkeypatch):
    from planner.solve import solve_instance

    # The bound's sample count comes from the sizes; only its wall-clock safety net depends on the
    # host's load, which must not decide this test.
    monkeypatch.setattr("planner.duality.DEADLINE_FACTOR", 1e6)

    out = solve_instance(EXAMPLE, make_planner("ssap"), "ssap", 1)
    clair = out["clairvoyant"]
    assert clair["exact"] and clair["features"] == 13.0 and clair["reward"] == pytest.approx(13.0 / 5.0)
    assert clair["fraction"] == pytest.approx(out["reward"] / clair["reward"]) and "gap" not in clair
    assert out["upper_bound"]["method"] == "mip" and out["upper_bound"]["expected_reward"] > 0
    best = out["online_optimum"]
    assert not best["exact"] and 0 < best["truncation_error"] < 0.01
    assert best["expected_reward"] <= out["upper_bound"]["expected_reward"]
    json.dumps(out)


# ----------------------------------------------------------------------------- experiments


def _coverage_trial(task):
    """A coverage trial for experiments.trials.run_trial: the counts ride in ``extra``."""
    problem, x, counts = random_coverage(np.random.default_rng(task.trial), invalid=0.2)
    return problem, x, 1000 + task.trial, {"counts": counts}


def test_experiments_report_each_planner_as_a_fraction_of_the_coverage_clairvoyant():
    from experiments.report import summarise
    from experiments.trials import CLAIRVOYANT, Sweep, Task, run_trial

    sweep = Sweep(instance=_coverage_trial)
    rows = [run_trial(Task("coverage", 0, t, name, 0, 16), sweep) for t in range(3) for name in (CLAIRVOYANT, "ssap")]
    for t in range(3):
        problem, x, counts = random_coverage(np.random.default_rng(t), invalid=0.2)
        clair = next(r for r in rows if r["trial"] == t and r["planner"] == CLAIRVOYANT)
        assert clair["features"] == pytest.approx(brute_force(problem, x, counts)) and clair["exact"] == 1
    summary = {r["planner"]: r for r in summarise(rows)}
    assert summary[CLAIRVOYANT]["fraction_mean"] == 1.0 and summary[CLAIRVOYANT]["bound_exact"] == "3/3"
    ssap = [r["reward"] / c["reward"] for r, c in zip(rows[1::2], rows[0::2])]
    assert summary["ssap"]["fraction_mean"] == pytest.approx(np.mean(ssap)) and 0 < np.mean(ssap) <= 1


def test_an_integer_program_stopped_by_its_time_limit_reports_its_dual_bound_and_gap():
    problem, x, counts = random_coverage(np.random.default_rng(5), carriers=12, passengers=3, stages=10, regions=40)
    exact = cb.solve(problem, x, counts)
    stopped = cb.solve(problem, x, counts, time_limit_s=1e-9)
    assert exact.exact and not stopped.exact and stopped.method == "ilp"
    found = evaluate(problem, stopped.deployed, x, stopped.released, counts=counts)[1]
    assert found <= exact.features + 1e-9 <= stopped.features + 2e-9
    assert stopped.gap == pytest.approx((stopped.features - found) / stopped.features)
    _check_feasible(problem, x, stopped)
