"""The information-relaxation bound (planner/duality.py) against independent oracles.

* validity: on tiny conflicted instances the bound is never below the exact online optimum V*
  (by more than 3 standard errors), for every prior kind the exact solver takes (continuous
  priors through the same 12-atom stand-in V* uses); on a three-point prior the bound's
  expectation is computed exactly, by enumerating every observation matrix, and is >= V*;
* zero penalty: the inner maximum is the clairvoyant optimum on every sample;
* the adaptive penalty: the enumeration equals a brute force over every deployment set with the
  reference terms; mean zero along an online rule; exact expectation >= V* on a two-point prior;
* relaxations: LP, MIP and the separable bound are never below the exact inner maximum, with the
  adaptive penalty too; ``mixed`` (exact per component where it fits, MIP elsewhere) is ``exact``
  when every component fits, never below it otherwise, and valid against V*;
* no overlaps: the bound is exact (the sum of the carriers' DLR optima) with zero variance;
* determinism for a seed; cheap refusal beyond a budget; ``solve`` reports it.
"""
from __future__ import annotations

import itertools
import json
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from planner.cli import solve
from planner import clairvoyant, duality, online_optimal, priors, ssap
from planner.instance import load_instance, random_instance
from planner.problem import Problem, sample_observations

#: A two-point prior that keeps the enumeration of observation matrices small (2^8).
TWO = stats.rv_discrete(values=([1.0, 4.0], [0.6, 0.4]))()
#: R = 2, N = 4, D = 2, two overlap groups (one with a self-conflict).
TINY_VALID = np.ones((2, 4), bool)
TINY_OVERLAPS = [[[0, 1], [1, 1], [1, 2]], [[0, 3], [1, 0], [0, 2]]]

#: One spec per prior kind of planner.priors (parameters kept small so V* is quick).
KIND_SPECS = {
    "poisson": {"kind": "poisson", "mean": 2.0},
    "binomial": {"kind": "binomial", "n": 4, "p": 0.5},
    "geometric": {"kind": "geometric", "p": 0.7},
    "negative_binomial": {"kind": "negative_binomial", "n": 1, "p": 0.7},
    "discrete_uniform": {"kind": "discrete_uniform", "low": 0, "high": 4},
    "table": {"kind": "table", "values": [0, 1, 3], "probabilities": [0.3, 0.4, 0.3]},
    "gamma": {"kind": "gamma", "shape": 2.0, "scale": 1.0},
    "exponential": {"kind": "exponential", "mean": 2.0},
    "lognormal": {"kind": "lognormal", "mu": 0.5, "sigma": 0.5},
    "normal": {"kind": "normal", "mean": 1.0, "std": 1.5},  # negative observations too
    "uniform": {"kind": "uniform", "low": 0.0, "high": 4.0},
}


def test_every_prior_kind_is_covered():
    assert set(KIND_SPECS) == set(priors.PRIOR_KINDS)


def _stand_in(prior):
    """The prior V* is the exact value for: the prior itself (discrete) or its atoms (continuous)."""
    if priors.is_discrete(prior):
        return prior
    atoms = online_optimal.discretise(prior)
    return stats.rv_discrete(values=(atoms.points, atoms.probs))()


@pytest.mark.parametrize("kind", list(KIND_SPECS))
def test_bound_is_valid_against_the_online_optimum(kind):
    prior = _stand_in(priors.build_prior(KIND_SPECS[kind]))
    problem = Problem.build(2, TINY_VALID, TINY_OVERLAPS, prior, normalize=1.0)
    best = online_optimal.online_value(problem).expected_reward
    bound = duality.upper_bound(problem, np.random.default_rng(7), samples=150, method="exact")
    assert bound.method == "exact" and bound.samples == 150
    assert bound.expected_reward >= best - 3 * bound.stderr, (bound, best)
    # It is an upper bound on SSAP's exact value too, and far below the conflict-free online value
    # only when conflicts matter: never above the separable bound's mean on the same samples.
    separable = duality.upper_bound(problem, np.random.default_rng(7), samples=150, method="separable")
    assert bound.expected_reward <= separable.expected_reward + 1e-9


def test_exact_expectation_of_the_bound_is_at_least_the_online_optimum():
    """Every observation matrix of a two-point prior (2^8 of them), weighted by its probability."""
    problem = Problem.build(2, TINY_VALID, TINY_OVERLAPS, TWO, normalize=1.0)
    points, probs = priors.support(TWO)
    expectation = clairvoyant_mean = 0.0
    for outcome in itertools.product(range(len(points)), repeat=TINY_VALID.size):
        x = points[list(outcome)].reshape(TINY_VALID.shape)
        weight = float(np.prod(probs[list(outcome)]))
        expectation += weight * duality.inner_maximum(problem, x, "exact")
        clairvoyant_mean += weight * duality.inner_maximum(problem, x, "exact", penalty_scale=0.0)
    best = online_optimal.online_value(problem).expected_reward
    assert expectation >= best - 1e-9
    assert expectation < clairvoyant_mean  # tighter than clairvoyance on this instance


@pytest.mark.parametrize("seed", range(4))
def test_zero_penalty_is_the_clairvoyant_optimum(seed):
    rng = np.random.default_rng(seed)
    inst = random_instance(rng, carriers=3, passengers=2, stages=5, overlaps=4, invalid_fraction=0.1)
    problem = inst.problem
    for _ in range(5):
        x = sample_observations(problem, rng)
        offline = clairvoyant.solve(problem, x)
        assert offline.exact
        for method in ("exact", "mip"):
            assert duality.inner_maximum(problem, x, method, penalty_scale=0.0) == pytest.approx(offline.features, abs=1e-7)
    zero = duality.upper_bound(problem, np.random.default_rng(1), samples=20, penalty_scale=0.0)
    again = np.random.default_rng(1)
    mean = np.mean([clairvoyant.solve(problem, sample_observations(problem, again)).reward for _ in range(20)])
    assert zero.expected_reward == pytest.approx(mean, abs=1e-9)


@pytest.mark.parametrize("prior", [stats.poisson(3.0), stats.norm(0.5, 2.0)], ids=["poisson", "normal"])
def test_relaxations_are_never_below_the_exact_inner_maximum(prior):
    rng = np.random.default_rng(11)
    for _ in range(3):
        inst = random_instance(rng, carriers=3, passengers=2, stages=5, overlaps=5)
        problem = Problem.build(inst.problem.passengers, inst.problem.valid, inst.problem.overlaps, prior,
                                normalize=1.0)
        for _ in range(4):
            x = sample_observations(problem, rng)
            exact = duality.inner_maximum(problem, x, "exact")
            assert duality.inner_maximum(problem, x, "lp") >= exact - 1e-7
            assert duality.inner_maximum(problem, x, "separable") >= exact - 1e-9
            assert duality.inner_maximum(problem, x, "mip") == pytest.approx(exact, abs=1e-6)


def test_without_overlaps_the_bound_is_the_dlr_optimum_with_zero_variance():
    valid = np.array([[1, 1, 0, 1, 1], [0, 1, 1, 1, 1], [1, 1, 1, 1, 1]], bool)
    problem = Problem.build([2, 1, 3], valid)
    table = ssap.table_for(problem)
    expected = sum(ssap.expected_value(table, int(valid[r].sum()), d) for r, d in enumerate([2, 1, 3]))
    bound = duality.upper_bound(problem, np.random.default_rng(0), samples=10)
    assert bound.expected_reward * problem.scale == pytest.approx(expected, rel=1e-9)
    assert bound.stderr < 1e-9


def test_same_seed_same_bound():
    problem = random_instance(np.random.default_rng(2), carriers=3, passengers=2, stages=5, overlaps=5).problem
    a = duality.upper_bound(problem, np.random.default_rng(42), samples=12)
    b = duality.upper_bound(problem, np.random.default_rng(42), samples=12)
    c = duality.upper_bound(problem, np.random.default_rng(43), samples=12)
    assert a == b and a.expected_reward != c.expected_reward


def test_refuses_beyond_its_budget_from_sizes_alone():
    big = random_instance(np.random.default_rng(0), carriers=256, passengers=3, stages=12, overlaps=1200).problem
    with pytest.raises(duality.BoundTooLarge) as err:
        duality.check_budget(big, duality.auto_method(big), duality.DEFAULT_SAMPLES, duality.DEFAULT_BUDGET_S)
    assert isinstance(err.value, ValueError) and "\n" not in str(err.value) and "budget" in str(err.value)
    with pytest.raises(duality.BoundTooLarge):
        duality.inner_maximum(big, sample_observations(big, np.random.default_rng(1)), "exact")
    with pytest.raises(ValueError, match="passenger values"):
        duality.upper_bound(Problem.build(1, np.ones((1, 2), bool), weights=[[1.0]]), np.random.default_rng(0))


def test_solve_reports_the_bound_next_to_the_online_optimum(tmp_path, capsys):
    small = {"carriers": 2, "passengers": 2, "stages": 5, "overlaps": [[[0, 1], [1, 2]], [[1, 3], [0, 4]]]}
    path = tmp_path / "instance.json"
    path.write_text(json.dumps(small))
    assert solve.main([str(path), "--planner", "ssap", "--no-clairvoyant"]) == 0
    out = json.loads(capsys.readouterr().out)
    (problem, _), _ = load_instance(str(path))
    bound = out["upper_bound"]
    assert set(bound) >= {"expected_reward", "stderr", "method"} and bound["method"] == "exact"
    assert bound["expected_reward"] >= out["online_optimum"]["expected_reward"] - 3 * bound["stderr"]
    assert solve.main([str(path), "--planner", "ssap", "--no-clairvoyant", "--no-upper-bound"]) == 0
    assert "upper_bound" not in json.loads(capsys.readouterr().out)


def test_bound_experiment_takes_every_prior_kind_within_the_exact_solvers_limits():
    """The experiment's tiny part has one instance per prior kind, each within V*'s automatic limit
    and under the prior V* is exact for (continuous kinds: its 12-atom stand-in)."""
    from experiments import bound as experiment

    assert set(experiment.TINY_PRIORS) == set(priors.PRIOR_KINDS)
    for i, kind in enumerate(experiment.TINY_PRIORS):
        problem, _ = experiment.tiny_instance(0, i, kind)
        assert priors.is_discrete(problem.prior), kind
        online_optimal.estimate(problem, max_seconds=online_optimal.AUTO_SECONDS)  # raises TooLarge beyond


def test_bound_experiment_targets_are_marked_met_or_not():
    from experiments import bound as experiment

    tiny = {"all": {"valid": "2/2", "all_valid": True, "bound_excess_pct": 1.2, "dlr_excess_pct": 1.4,
                    "clairvoyant_excess_pct": 2.0, "ratio": 0.5}}
    summary = [{"planner": "closed-loop", "carriers": 128, "config": "R = 128", "fraction_mean": 0.98,
                "fraction_sem": 0.01, "n": 5},
               {"planner": "closed-loop", "carriers": 256, "config": "R = 256", "fraction_mean": 0.96,
                "fraction_sem": 0.01, "n": 5},
               {"planner": "closed-loop", "carriers": 4, "config": "R = 4, 0 overlaps", "fraction_mean": 0.5,
                "fraction_sem": 0.01, "n": 5}]
    lines = experiment.targets(summary, tiny)
    assert lines[0].endswith("— met")  # validity
    assert lines[1].endswith("— NOT MET") and "1.4" in lines[1]  # 1.2 % > 1 %
    assert lines[2].endswith("— NOT MET")  # ratio 0.5 > 1/3
    assert lines[3].endswith("— met") and "R = 128" in lines[3] and lines[4].endswith("— NOT MET")
    assert len(lines) == 5  # the conflict-free configuration has no fraction target


def test_bound_experiment_split_table_names_the_best_planner_and_the_gap():
    from experiments import bound as experiment

    level = next(i for i, c in enumerate(experiment.CONFIGS) if c[1] == 32)
    summary = [{"level": level, "planner": experiment.UPPER_BOUND, "reward_mean": 86.0, "reward_sem": 0.1,
                "stderr_mean": 0.2},
               {"level": level, "planner": "closed-loop", "fraction_mean": 0.97, "fraction_sem": 0.01},
               {"level": level, "planner": "ssap", "fraction_mean": 0.80, "fraction_sem": 0.01},
               {"level": 0, "planner": "ssap", "fraction_mean": 0.99, "fraction_sem": 0.01}]
    table = experiment.split_table(summary).splitlines()
    assert len(table) == 3 and "R = 32" in table[2] and "0.970" in table[2] and "3.0 %" in table[2]


@pytest.mark.slow
def test_experiment_tasks_report_the_bound_against_v_star_and_the_planners(tmp_path):
    """One tiny-instance task and one R = 4 trial of ``python -m experiments bound``, written out."""
    from experiments import bound as experiment
    from experiments.trials import CLAIRVOYANT, Task

    tiny = experiment.run_task(Task("bound-tiny", 0, 0, experiment.TINY, 0, 0, samples=30))
    assert tiny["reward"] >= tiny["v_star"] - 3 * tiny["stderr"] and tiny["samples"] == 30
    assert tiny["fixed_bound"] >= tiny["v_star"] - 3 * tiny["fixed_stderr"]  # the bound before the adaptive penalty
    assert tiny["fixed_strength"] in duality.STRENGTHS
    kind = experiment.run_task(Task("bound-tiny", 1, 6, experiment.TINY, 0, 0, samples=30, variant="gamma"))
    assert kind["prior"] == "gamma" and kind["reward"] >= kind["v_star"] - 3 * kind["stderr"]
    level = 5  # R = 4, 20 overlaps
    _, carriers, overlaps, _, _ = experiment.CONFIGS[level]
    rows = [tiny, kind] + [experiment.run_task(Task("bound", level, 0, name, 0, 100, carriers=carriers, overlaps=overlaps,
                                              samples=3))
                     for name in ("ssap", CLAIRVOYANT, experiment.UPPER_BOUND)]
    assert rows[-1]["method"] == "lp" and rows[-1]["samples"] == 3
    experiment.write(rows, tmp_path, {"iterations": 100}, 1.0, 1)
    text = (tmp_path / "bound.md").read_text()
    assert "V*" in text and "R = 4, 20 overlaps" in text and (tmp_path / "bound.png").is_file()
    assert "fixed-penalty bound's excess" in text
    assert "One tiny instance per prior kind" in text and "| gamma |" in text and "### Targets" in text
    again = experiment.read_trials(tmp_path / "bound_trials.csv")
    assert len(again) == 5 and {r["planner"] for r in again} >= {"ssap", experiment.UPPER_BOUND}


def test_bound_experiment_mixed_method_up_to_its_fleet_size():
    """The scale rows' bound by ``mixed`` up to MIXED_MAX_CARRIERS (--quick: its own smaller limit);
    beyond it, under ``mixed-root`` (the default) the same with every MIP stopped at its root node,
    under ``mixed`` the LP; ``--bound-method lp`` everywhere; a run_info.json record without
    ``bound_method`` (written when lp was the default) is rebuilt with lp."""
    from experiments import bound as experiment
    from experiments import check, run
    from experiments.trials import Task

    def bound_tasks(*flags):
        settings = run.settings_of(run.parse_args(["bound", *flags]))
        return [t for t in experiment.build_tasks(settings) if t.planner == experiment.UPPER_BOUND]

    assert all(t.variant == "" for t in bound_tasks("--quick", "--bound-method", "lp"))
    for flags, limit in ((("--quick",), experiment.QUICK["mixed_max_carriers"]), ((), experiment.MIXED_MAX_CARRIERS)):
        for method, beyond in (("mixed", ""), ("mixed-root", "mixed-root")):
            tasks = bound_tasks(*flags, *(("--bound-method", method) if method == "mixed" else ()))
            assert {t.carriers for t in tasks if t.variant == "mixed"} == {t.carriers for t in tasks if t.carriers <= limit}
            assert {t.variant for t in tasks if t.carriers > limit} == {beyond}  # the LP, or the root node's MIP
    assert experiment.MIXED_MAX_CARRIERS >= 128
    old = {"iterations": 40, "seed": 0, "planners": ["ssap"], "levels": [0], "bound_trials": None}
    assert check.sweep_args("bound", old, Path("out")).bound_method == "lp"
    assert check.sweep_args("bound", {**old, "bound_method": "mixed"}, Path("out")).bound_method == "mixed"
    assert run.parse_args(["bound"]).bound_method == "mixed-root"
    level = 3  # R = 4, 12 overlaps
    _, carriers, overlaps, _, _ = experiment.CONFIGS[level]
    row = experiment.run_task(Task("bound", level, 0, experiment.UPPER_BOUND, 0, 0, carriers=carriers,
                                   overlaps=overlaps, samples=3, variant="mixed"))
    assert row["method"] == "mixed" and row["samples"] == 3 and row["reward"] > 0
    root = experiment.run_task(Task("bound", level, 0, experiment.UPPER_BOUND, 0, 0, carriers=carriers,
                                    overlaps=overlaps, samples=3, variant="mixed-root"))
    assert root["method"] == "mixed-root" and root["reward"] >= row["reward"] - 1e-9  # a root node's bound: never tighter


@pytest.mark.slow
def test_bound_experiment_quick_run(tmp_path):
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-m", "experiments", "bound", "--quick", "--jobs", "1", "--no-progress",
                           "--out", str(tmp_path)], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert {"bound.md", "bound.png", "bound_trials.csv", "bound_summary.csv"} <= {p.name for p in tmp_path.iterdir()}
    text = (tmp_path / "bound.md").read_text()
    assert "### Where the gap is" in text and "| R = 32, 160 overlaps |" in text.split("### Where the gap is")[1]


# ----------------------------------------------------------------------------- the discounted penalty


def test_undiscounted_values_are_the_dlr_values_and_the_penalty_is_unchanged():
    valid = np.array([[1, 1, 0, 1, 1, 1], [0, 1, 1, 1, 1, 0], [1, 1, 1, 1, 1, 1]], bool)
    problem = Problem.build([2, 3, 1], valid, [[[0, 1], [1, 1]], [[2, 3], [1, 4], [0, 4]]], stats.poisson(3.0))
    values = duality.carrier_values(problem, np.ones(valid.shape))
    slot = ssap.table_for(problem)
    for r, d in enumerate([2, 3, 1]):
        assert values[r, 0, d] == pytest.approx(ssap.expected_value(slot, int(valid[r].sum()), d), rel=1e-9)
    x = sample_observations(problem, np.random.default_rng(3))
    np.testing.assert_allclose(duality.penalty_terms(problem, x, discount=np.ones(valid.shape)),
                               duality.penalty_terms(problem, x), atol=1e-9)


@pytest.mark.parametrize("prior", [stats.poisson(2.0), stats.norm(1.0, 1.5)], ids=["poisson", "normal"])
def test_discounted_penalty_has_mean_zero_along_a_non_anticipative_policy(prior):
    """The validity argument, measured: along a fixed online rule (deploy when x > 2, or when
    forced) the discounted penalty's mean is zero within 4 standard errors."""
    inst = random_instance(np.random.default_rng(5), carriers=4, passengers=2, stages=6, overlaps=8)
    problem = Problem.build(inst.problem.passengers, inst.problem.valid, inst.problem.overlaps, prior, normalize=1.0)
    discount = duality.conflict_discount(problem, 1.0)
    assert (discount[problem.valid] < 1).any()
    left_stages = problem.valid[:, ::-1].cumsum(axis=1)[:, ::-1]
    rng, totals = np.random.default_rng(8), []
    for _ in range(3000):
        x = sample_observations(problem, rng)
        phi = duality.penalty_terms(problem, x, discount=discount)
        total = 0.0
        for r in range(problem.n_carriers):
            d = int(problem.passengers[r])
            for j in np.flatnonzero(problem.valid[r]):
                total += phi[r, j, d]
                if d > 0 and (x[r, j] > 2 or left_stages[r, j] <= d):
                    d -= 1
        totals.append(total)
    assert abs(np.mean(totals)) <= 4 * np.std(totals) / np.sqrt(len(totals)), np.mean(totals)


@pytest.mark.parametrize("strength", [0.5, 1.0])
def test_exact_expectation_of_the_discounted_bound_is_at_least_the_online_optimum(strength):
    problem = Problem.build(2, TINY_VALID, TINY_OVERLAPS, TWO, normalize=1.0)
    discount = duality.conflict_discount(problem, strength)
    points, probs = priors.support(TWO)
    expectation = 0.0
    for outcome in itertools.product(range(len(points)), repeat=TINY_VALID.size):
        x = points[list(outcome)].reshape(TINY_VALID.shape)
        weight = float(np.prod(probs[list(outcome)]))
        expectation += weight * duality.inner_maximum(problem, x, "exact", discount=discount)
    assert expectation >= online_optimal.online_value(problem).expected_reward - 1e-9


@pytest.mark.parametrize("kind", list(KIND_SPECS))
def test_chosen_strength_bound_is_valid_against_the_online_optimum(kind):
    prior = _stand_in(priors.build_prior(KIND_SPECS[kind]))
    problem = Problem.build(2, TINY_VALID, TINY_OVERLAPS, prior, normalize=1.0)
    best = online_optimal.online_value(problem).expected_reward
    for strength in ("auto", max(duality.STRENGTHS)):
        bound = duality.upper_bound(problem, np.random.default_rng(7), samples=150, method="exact", strength=strength)
        pilot = duality.EXACT_PILOT_SAMPLES if strength == "auto" else 0
        assert bound.strength in duality.STRENGTHS and bound.pilot_samples == pilot
        assert bound.adaptive and bound.expected_reward >= best - 3 * bound.stderr, (kind, bound, best)


def test_the_pilot_chooses_the_smallest_mean_and_is_discarded():
    problem = random_instance(np.random.default_rng(2), carriers=3, passengers=2, stages=6, overlaps=6).problem
    chosen = duality.choose_strength(problem, np.random.default_rng(4), "exact", 6, adaptive=True)
    again = np.random.default_rng(4)
    xs = [sample_observations(problem, again) for _ in range(6)]
    means = [np.mean([duality.inner_maximum(problem, x, "exact", discount=duality.conflict_discount(problem, c, True),
                                            adaptive=True)
                      for x in xs]) for c in duality.STRENGTHS]
    assert chosen == duality.STRENGTHS[int(np.argmin(means))]
    # The bound's own samples follow the pilot's: the same as a fixed-strength bound drawn after it.
    auto = duality.upper_bound(problem, np.random.default_rng(4), samples=10, method="exact", pilot=6)
    fixed = duality.upper_bound(problem, again, samples=10, method="exact", strength=chosen)
    assert auto.strength == chosen and auto.expected_reward == pytest.approx(fixed.expected_reward, abs=1e-12)
    assert auto.adaptive and fixed.adaptive  # exact inner maxima: the adaptive penalty by default


# ----------------------------------------------------------------------------- the adaptive penalty


def _brute_force_adaptive(problem, x, discount):
    """max over every deployment set of (reward - the adaptive penalty along it), by
    :func:`planner.duality.adaptive_terms` (the reference) and the penalty rule itself."""
    n_carriers, n_stages = problem.valid.shape
    xv = np.where(problem.valid, x, 0.0)
    options = [list(itertools.combinations(np.flatnonzero(problem.valid[r]),
                                           min(int(problem.passengers[r]), int(problem.valid[r].sum()))))
               for r in range(n_carriers)]
    best = -np.inf
    for combo in itertools.product(*options):
        y = np.zeros((n_carriers, n_stages), bool)
        for r, stages in enumerate(combo):
            y[r, list(stages)] = True
        terms = duality.adaptive_terms(problem, x, y, discount)
        penalty = 0.0
        for r in range(n_carriers):
            d = int(problem.passengers[r])
            for j in np.flatnonzero(problem.valid[r]):
                penalty += terms[r, j, d]
                d -= int(y[r, j])
        flat = y.ravel().astype(float)
        reward = float((flat * xv.ravel() / (1.0 + problem.conflict.astype(float) @ flat)).sum())
        best = max(best, reward - penalty)
    return best


@pytest.mark.parametrize("prior", [stats.poisson(3.0), stats.norm(0.5, 2.0)], ids=["poisson", "normal"])
def test_adaptive_enumeration_is_the_brute_force_maximum(prior):
    rng = np.random.default_rng(21)
    changed = 0
    for _ in range(3):
        inst = random_instance(rng, carriers=3, passengers=2, stages=4, overlaps=4)
        problem = Problem.build(inst.problem.passengers, inst.problem.valid, inst.problem.overlaps, prior,
                                normalize=1.0)
        for strength in (0.0, 0.5):
            discount = duality.conflict_discount(problem, strength) if strength else None
            for _ in range(2):
                x = sample_observations(problem, rng)
                fast = duality.inner_maximum(problem, x, "exact", discount=discount, adaptive=True)
                assert fast == pytest.approx(_brute_force_adaptive(problem, x, discount), abs=1e-9)
                changed += abs(fast - duality.inner_maximum(problem, x, "exact", discount=discount)) > 1e-9
    assert changed  # the adaptive terms do change the inner maximum


def test_adaptive_terms_without_earlier_conflicting_deployments_are_the_fixed_terms():
    problem = Problem.build(2, TINY_VALID, TINY_OVERLAPS, stats.poisson(2.0), normalize=1.0)
    x = sample_observations(problem, np.random.default_rng(0))
    discount = duality.conflict_discount(problem, 0.5)
    np.testing.assert_allclose(duality.adaptive_terms(problem, x, np.zeros(TINY_VALID.shape, bool), discount),
                               duality.penalty_terms(problem, x, discount=discount), atol=1e-12)


@pytest.mark.parametrize("prior", [stats.poisson(2.0), stats.norm(1.0, 1.5)], ids=["poisson", "normal"])
def test_adaptive_penalty_has_mean_zero_along_a_non_anticipative_policy(prior):
    """Along a fixed online rule (deploy when x > 2, or when forced), the adaptive penalty's terms
    at the rule's own (passengers left, earlier conflicting deployments) sum to mean zero."""
    inst = random_instance(np.random.default_rng(5), carriers=4, passengers=2, stages=6, overlaps=8)
    problem = Problem.build(inst.problem.passengers, inst.problem.valid, inst.problem.overlaps, prior, normalize=1.0)
    discount = duality.conflict_discount(problem, 0.5)
    left_stages = problem.valid[:, ::-1].cumsum(axis=1)[:, ::-1]
    rng, totals, adapted = np.random.default_rng(8), [], 0
    for _ in range(2000):
        x = sample_observations(problem, rng)
        y = np.zeros(problem.valid.shape, bool)
        d = problem.passengers.astype(int).copy()
        for j in range(problem.n_stages):  # the rule, stage by stage
            for r in np.flatnonzero(problem.valid[:, j]):
                if d[r] > 0 and (x[r, j] > 2 or left_stages[r, j] <= d[r]):
                    y[r, j], d[r] = True, d[r] - 1
        terms = duality.adaptive_terms(problem, x, y, discount)
        adapted += not np.allclose(terms, duality.penalty_terms(problem, x, discount=discount))
        total = 0.0
        for r in range(problem.n_carriers):
            left = int(problem.passengers[r])
            for j in np.flatnonzero(problem.valid[r]):
                total += terms[r, j, left]
                left -= int(y[r, j])
        totals.append(total)
    assert adapted > 100
    assert abs(np.mean(totals)) <= 4 * np.std(totals) / np.sqrt(len(totals)), np.mean(totals)


@pytest.mark.parametrize("strength", [0.0, 0.5])
def test_exact_expectation_of_the_adaptive_bound_is_at_least_the_online_optimum(strength):
    problem = Problem.build(2, TINY_VALID, TINY_OVERLAPS, TWO, normalize=1.0)
    discount = duality.conflict_discount(problem, strength) if strength else None
    points, probs = priors.support(TWO)
    adaptive = fixed = 0.0
    for outcome in itertools.product(range(len(points)), repeat=TINY_VALID.size):
        x = points[list(outcome)].reshape(TINY_VALID.shape)
        weight = float(np.prod(probs[list(outcome)]))
        adaptive += weight * duality.inner_maximum(problem, x, "exact", discount=discount, adaptive=True)
        fixed += weight * duality.inner_maximum(problem, x, "exact", discount=discount)
    best = online_optimal.online_value(problem).expected_reward
    assert adaptive >= best - 1e-9
    assert adaptive < fixed  # tighter than the fixed penalty on this instance


def test_adaptive_discount_leaves_out_what_the_count_replaces():
    """The adaptive penalty's discount guesses only the conflicts its count k does not see: a
    point whose every conflict is another carrier's point at an earlier stage keeps its x (1)."""
    valid = np.ones((2, 4), bool)
    problem = Problem.build(1, valid, [[[0, 0], [1, 2]], [[0, 1], [1, 1]]], stats.poisson(2.0))
    fixed, adaptive = duality.conflict_discount(problem, 1.0), duality.conflict_discount(problem, 1.0, adaptive=True)
    assert fixed[1, 2] < 1 and adaptive[1, 2] == 1.0  # (1, 2)'s only conflict is (0, 0), earlier
    assert adaptive[0, 0] == fixed[0, 0] < 1  # (0, 0)'s conflict is later: still guessed
    assert adaptive[0, 1] == fixed[0, 1] < 1 and adaptive[1, 1] == fixed[1, 1] < 1  # same stage: guessed
    assert duality.pilot_samples("exact") == duality.EXACT_PILOT_SAMPLES > duality.pilot_samples("lp")


# ----------------------------------------------------------------------------- per component, adaptive in HiGHS


@pytest.mark.parametrize("prior", [stats.poisson(3.0), stats.norm(0.5, 2.0)], ids=["poisson", "normal"])
def test_adaptive_relaxations_are_never_below_the_exact_adaptive_maximum(prior):
    """The adaptive penalty in the flow model: the MIP is the enumeration's maximum, the LP and the
    separable fallback never below it; ``mixed`` is ``exact`` when every component fits."""
    rng = np.random.default_rng(11)
    for _ in range(2):
        inst = random_instance(rng, carriers=3, passengers=2, stages=5, overlaps=5)
        problem = Problem.build(inst.problem.passengers, inst.problem.valid, inst.problem.overlaps, prior,
                                normalize=1.0)
        for strength in (0.0, 0.5):
            discount = duality.conflict_discount(problem, strength, adaptive=True) if strength else None
            for _ in range(2):
                x = sample_observations(problem, rng)
                exact = duality.inner_maximum(problem, x, "exact", discount=discount, adaptive=True)
                mip = duality.inner_maximum(problem, x, "mip", discount=discount, adaptive=True)
                assert mip == pytest.approx(exact, abs=1e-6)
                assert duality.inner_maximum(problem, x, "lp", discount=discount, adaptive=True) >= exact - 1e-7
                assert duality.inner_maximum(problem, x, "separable", discount=discount, adaptive=True) >= exact - 1e-9
                assert duality.inner_maximum(problem, x, "mixed", discount=discount, adaptive=True) == exact


#: Two multi-carrier components, of 36 and 216 stage-set combinations, and a carrier alone.
MIXED_INSTANCE = dict(carriers=5, passengers=2, stages=4, overlaps=4)


@pytest.mark.parametrize("adaptive", [False, True], ids=["fixed", "adaptive"])
def test_mixed_solves_each_component_by_its_own_method(monkeypatch, adaptive):
    """With the exact limit between the two components' sizes, ``mixed`` enumerates the small one
    and takes the MIP of the large one: never below ``exact`` (computed under the usual limit) on
    any sample, equal to it here (the MIPs finish), below ``lp``'s value."""
    problem = random_instance(np.random.default_rng(23), **MIXED_INSTANCE).problem
    sizes = sorted(p.combinations() for p in duality._components(problem) if len(p.carriers) > 1)
    assert sizes == [36.0, 216.0]
    discount = duality.conflict_discount(problem, 0.5, adaptive)
    rng = np.random.default_rng(3)
    for _ in range(6):
        x = sample_observations(problem, rng)
        exact = duality.inner_maximum(problem, x, "exact", discount=discount, adaptive=adaptive)
        lp = duality.inner_maximum(problem, x, "lp", discount=discount, adaptive=adaptive)
        with monkeypatch.context() as m:
            m.setattr(duality, "MAX_COMBINATIONS", 100)
            with pytest.raises(duality.BoundTooLarge):
                duality.inner_maximum(problem, x, "exact", discount=discount, adaptive=adaptive)
            mixed = duality.inner_maximum(problem, x, "mixed", discount=discount, adaptive=adaptive)
        assert mixed >= exact - 1e-7
        assert mixed == pytest.approx(exact, abs=1e-6)
        assert mixed <= lp + 1e-7


def _knapsack(seed: int, items: int = 70, rows: int = 10):
    """A 0-1 multidimensional knapsack whose root node does not close (HiGHS branches)."""
    from planner.highs import Model

    rng = np.random.default_rng(seed)
    weights, values = rng.integers(10, 60, size=(rows, items)), rng.integers(10, 60, size=items)
    model = Model()
    cols = [model.var(float(v), is_int=True) for v in values]
    for w in weights:
        model.row(-np.inf, float(w.sum() // 2), cols, [float(a) for a in w])
    return model


def test_a_node_limited_mip_stops_at_a_valid_dual_bound_the_same_every_time():
    """``max_nodes``: the branch and bound stops after the root node, not optimal, at a dual bound
    above the optimum and at least its best solution; the same bound on every run (no clock in it)."""
    for seed in range(2):
        full = _knapsack(seed).solve(True, 60.0)
        root = [_knapsack(seed).solve(True, 60.0, max_nodes=1) for _ in range(2)]
        assert full.optimal and not root[0].optimal
        assert root[0].bound > full.bound + 0.5 >= full.objective + 0.5 > root[0].objective - 1e-9
        assert root[0].bound == root[1].bound and root[0].objective == root[1].objective


def test_the_node_limit_reaches_every_branch_and_bound_of_the_bound(monkeypatch):
    """``mip_max_nodes`` of ``upper_bound`` and ``inner_maximum`` is the limit of every MIP they
    solve (the pilot's included), and the node-limited bound stays between the exact and the LP."""
    from planner import highs

    problem = random_instance(np.random.default_rng(23), **MIXED_INSTANCE).problem
    seen = []
    solve = highs.Model.solve

    def recorded(self, integer, time_limit_s, max_nodes=None):
        if integer:
            seen.append(max_nodes)
        return solve(self, integer, time_limit_s, max_nodes)

    monkeypatch.setattr(highs.Model, "solve", recorded)
    bound = duality.upper_bound(problem, np.random.default_rng(3), samples=3, method="mip", pilot=2, mip_max_nodes=1)
    assert seen and set(seen) == {1} and bound.method == "mip"
    discount = duality.conflict_discount(problem, 0.5, True)
    x = sample_observations(problem, np.random.default_rng(4))
    exact = duality.inner_maximum(problem, x, "exact", discount=discount, adaptive=True)
    lp = duality.inner_maximum(problem, x, "lp", discount=discount, adaptive=True)
    root = duality.inner_maximum(problem, x, "mip", discount=discount, adaptive=True, mip_max_nodes=1)
    assert exact - 1e-7 <= root <= lp + 1e-7


@pytest.mark.parametrize("kind", ["poisson", "normal"])
def test_mixed_adaptive_bound_is_valid_against_the_online_optimum(monkeypatch, kind):
    """The bound with the adaptive penalty and the component solved by HiGHS (the exact limit
    lowered below its 36 combinations) stays >= V* - 3 SE, and is the exact bound's estimate."""
    prior = _stand_in(priors.build_prior(KIND_SPECS[kind]))
    problem = Problem.build(2, TINY_VALID, TINY_OVERLAPS, prior, normalize=1.0)
    best = online_optimal.online_value(problem).expected_reward
    exact = duality.upper_bound(problem, np.random.default_rng(7), samples=120, method="exact", pilot=4)
    monkeypatch.setattr(duality, "MAX_COMBINATIONS", 10)
    bound = duality.upper_bound(problem, np.random.default_rng(7), samples=120, method="mixed", pilot=4)
    assert bound.method == "mixed" and bound.adaptive and bound.samples == 120
    assert bound.expected_reward >= best - 3 * bound.stderr, (bound, best)
    assert bound.expected_reward == pytest.approx(exact.expected_reward, abs=1e-6)
    small = [duality.upper_bound(problem, np.random.default_rng(7), samples=4, method="mixed", pilot=2)
             for _ in range(2)]
    assert small[0] == small[1]  # same seed, same bound


def test_a_cheaper_pilot_only_chooses_the_strength():
    """``pilot_method``: the pilot's inner maxima by that method choose the strength
    (``choose_strength`` on the same matrices); the bound itself is the method's own, on the
    matrices after the pilot's, exactly as with that strength given."""
    problem = random_instance(np.random.default_rng(23), **MIXED_INSTANCE).problem
    pilot = 3
    bound = duality.upper_bound(problem, np.random.default_rng(5), samples=4, method="mixed", pilot=pilot,
                                pilot_method="lp")
    rng = np.random.default_rng(5)
    chosen = duality.choose_strength(problem, rng, "lp", pilot, adaptive=True)
    assert bound.strength == chosen and bound.method == "mixed" and bound.adaptive
    given = duality.upper_bound(problem, rng, samples=4, method="mixed", strength=chosen)
    assert bound.expected_reward == given.expected_reward and bound.stderr == given.stderr
