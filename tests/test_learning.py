"""planner.learning: the empirical-Bayes prior estimate and the ``learn_prior`` option of every
planner (scenario files, the solve command, run_fleet.py)."""
from __future__ import annotations

import copy
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.stats
import yaml

import world
from planner.cli import solve
from planner import learning
from planner.compiled import compile_problem
from planner.instance import random_instance
from planner.learning import LearnedPriorPlanner, UnsupportedPrior, fit_prior, learned_problem
from planner.problem import Problem
from planner.online import run_online
from planner.registry import OPTIONS, make_planner, parse_option, used_options

ROOT = Path(__file__).resolve().parents[1]


# ----------------------------------------------------------------------------- the estimator


def test_no_observation_gives_the_stated_prior_itself():
    stated = scipy.stats.poisson(3.14)
    fit = fit_prior(stated, np.full((3, 5), np.nan))
    assert fit.prior is stated and fit.family == "stated" and fit.n == 0


def test_many_samples_recover_negative_binomial_parameters():
    true = scipy.stats.nbinom(0.5, 0.165)  # mean 2.53, variance 15.3: urban_alpha's counts
    obs = true.rvs(size=20_000, random_state=np.random.default_rng(1)).astype(float)
    fit = fit_prior(scipy.stats.poisson(3.14), obs)
    assert fit.family == "negative_binomial"
    n, p = fit.prior.args
    assert abs(fit.mean - true.mean()) < 0.1 and abs(fit.var - true.var()) / true.var() < 0.1
    assert abs(n - 0.5) < 0.05 and abs(p - 0.165) < 0.02


def test_poisson_data_stay_poisson():
    obs = scipy.stats.poisson(4.0).rvs(size=20_000, random_state=np.random.default_rng(2)).astype(float)
    fit = fit_prior(scipy.stats.poisson(4.0), obs)
    # Sampling noise may leave a sliver of overdispersion; the predictive is then nearly Poisson.
    assert abs(fit.mean - 4.0) < 0.05 and abs(fit.var - 4.0) < 0.2
    underdispersed = fit_prior(scipy.stats.poisson(3.0), np.array([3.0, 3, 3, 3, 3, 3, 3, 3, 3, 3] * 5))
    assert underdispersed.family == "poisson" and underdispersed.prior.dist.name == "poisson"


def test_shrinkage_moves_from_the_stated_prior_to_the_data():
    stated = scipy.stats.poisson(6.0)
    data = np.array([1.0, 2.0, 0.0, 3.0, 1.0, 2.0, 0.0, 1.0] * 4)  # mean 1.25
    means = [fit_prior(stated, data[:k]).mean for k in (1, 4, 8, 16, 32)]
    assert all(a > b for a, b in zip(means, means[1:]))  # monotone towards the data
    assert 1.25 < means[-1] < 6.0
    w = learning.PRIOR_WEIGHT
    assert fit_prior(stated, data).mean == pytest.approx((w * 6.0 + 32 * 1.25) / (w + 32))
    # More weight on the stated prior: closer to it.
    assert fit_prior(stated, data, weight=100).mean > fit_prior(stated, data, weight=1).mean


def test_continuous_families_and_refusal():
    gamma = fit_prior(scipy.stats.gamma(2.0, scale=1.5), np.array([1.0, 5.0, 2.0, 9.0]))
    assert gamma.family == "gamma" and gamma.prior.mean() == pytest.approx(gamma.mean)
    normal = fit_prior(scipy.stats.norm(0.0, 1.0), np.array([-1.0, 2.0, 0.5]))
    assert normal.family == "normal" and normal.prior.var() == pytest.approx(normal.var)
    table = scipy.stats.rv_discrete(values=([0.0, 2.5, 5.0], [0.3, 0.4, 0.3]))()
    with pytest.raises(UnsupportedPrior, match="^learn_prior: expected a count prior"):
        fit_prior(table, np.array([2.5]))
    counts = scipy.stats.rv_discrete(values=([0, 1, 4], [0.3, 0.4, 0.3]))()
    assert fit_prior(counts, np.array([4.0, 4.0])).family in ("poisson", "negative_binomial")


# ----------------------------------------------------------------------------- the wrapper


def _instance(seed=3, overlaps=6):
    return random_instance(np.random.default_rng(seed), 3, 2, 8, overlaps, 3.0)


def test_learned_problem_keeps_units_and_structure_and_memory_is_bounded():
    inst = _instance()
    problem = inst.problem
    x = np.where(problem.valid, 12.0, np.nan)  # far above the stated Poisson(3)
    learned, fit = learned_problem(problem, 4, x)
    assert learned is not problem and learned.scale == problem.scale
    assert learned.conflict is problem.conflict and learned.valid is problem.valid
    assert fit.mean > 3.0 and compile_problem(learned).table[3, 1] > compile_problem(problem).table[3, 1]
    for j in range(problem.n_stages):
        learned_problem(problem, j, x + j)
    assert len(learning._LEARNED[problem]) <= learning._PER_PROBLEM
    assert learned_problem(problem, 0, np.full(x.shape, np.nan))[0] is problem


def test_learned_prior_is_strictly_causal():
    """Changing observations after stage j changes no decision up to j."""
    inst = _instance(5)
    problem, x = inst.problem, inst.observations
    planner = make_planner("closed-loop", iterations=40, learn_prior=True)
    base = run_online(problem, x, planner, seed=7).deployed
    for j in (1, 4):
        changed = x.copy()
        changed[:, j + 1:] = np.where(np.isnan(changed[:, j + 1:]), np.nan, 40.0)
        other = run_online(problem, changed, planner, seed=7).deployed
        np.testing.assert_array_equal(base[:, : j + 1], other[:, : j + 1])
    # The estimate at stage j reads x[:, :j + 1] only, whatever the view holds.
    full = np.where(problem.valid, 40.0, np.nan)
    early = np.where(np.arange(problem.n_stages) <= 2, x, 40.0)
    a, fit_a = learned_problem(problem, 2, early)
    b, fit_b = learned_problem(problem, 2, np.where(np.arange(problem.n_stages) <= 2, x, 0.0))
    assert fit_a[1:] == fit_b[1:] and a is b
    assert learned_problem(problem, 7, full)[1].mean > 25


@pytest.mark.parametrize("seed", [0, 1])
def test_every_planner_with_learn_prior_is_feasible_and_deterministic(planner_spec, seed):
    name, options = planner_spec
    inst = random_instance(np.random.default_rng(seed), 3, 2, 8, 8, 3.0, invalid_fraction=0.1)
    # Clustered observations: many zeros and a few large counts.
    x = np.where(inst.problem.valid, scipy.stats.nbinom(0.6, 0.15).rvs(
        size=inst.problem.valid.shape, random_state=np.random.default_rng(seed)), np.nan).astype(float)
    x[0, 3] = np.nan  # an online surprise
    planner = make_planner(name, learn_prior=True, **options)
    assert isinstance(planner, LearnedPriorPlanner) and planner.name == name
    a = run_online(inst.problem, x, planner, seed=11)  # run_online enforces every rule
    b = run_online(inst.problem, x, make_planner(name, learn_prior=True, **options), seed=11)
    np.testing.assert_array_equal(a.deployed, b.deployed)
    assert a.reward == b.reward


def test_learn_prior_false_is_todays_planner():
    assert "learn_prior" not in used_options("ssap", {"learn_prior": False, "iterations": 5})
    assert used_options("ssap", {"learn_prior": True}) == {"learn_prior": True}
    assert type(make_planner("ssap", learn_prior=False)).__name__ == "SSAPPlanner"
    inst = _instance(9)
    plain = run_online(inst.problem, inst.observations, make_planner("closed-loop", iterations=40), 3)
    off = run_online(inst.problem, inst.observations, make_planner("closed-loop", iterations=40, learn_prior=False), 3)
    np.testing.assert_array_equal(plain.deployed, off.deployed)


def test_learning_changes_decisions_when_the_prior_is_wrong():
    """SSAP stated Poisson(3) while the fleet sees counts around 11: carrier 0 (valid from stage 3)
    takes its first count, 7, under the stated prior, and waits under the learned one."""
    valid = np.ones((5, 10), bool)
    valid[0, :3] = False
    problem = Problem.build([1, 0, 0, 0, 0], valid, (), scipy.stats.poisson(3.0))
    x = np.vstack([np.full(10, np.nan), np.resize([10.0, 11, 12, 11, 10], (4, 10))])
    x[0, 3:] = [7, 9, 8, 10, 9, 12, 25]
    plain = run_online(problem, x, make_planner("ssap"), 0).deployed
    learned = run_online(problem, x, make_planner("ssap", learn_prior=True), 0).deployed
    assert plain[0, 3] and not learned[0, 3] and learned[0].sum() == 1


# ----------------------------------------------------------------------------- entry points


def test_option_is_in_the_registry_and_parses():
    assert OPTIONS["learn_prior"].default is False and OPTIONS["learn_prior"].kind is bool
    assert parse_option("learn_prior=true") == ("learn_prior", True)
    assert parse_option("learn-prior=0") == ("learn_prior", False)
    with pytest.raises(ValueError, match="^learn_prior: expected true or false, found 'maybe'$"):
        parse_option("learn_prior=maybe")
    with pytest.raises(ValueError, match="learn_prior must be true or false"):
        make_planner("ssap", learn_prior="yes")


def test_scenario_planner_block_takes_learn_prior(tmp_path):
    data = yaml.safe_load((ROOT / "scenarios" / "tiny.yaml").read_text())
    data["planner"] = {"name": "ssap", "learn_prior": True}
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(data))
    scenario = world.load_scenario(path)
    assert scenario.planner.learn_prior is True and scenario.planner.options()["learn_prior"] is True
    assert isinstance(make_planner(scenario.planner.name, **scenario.planner.options()), LearnedPriorPlanner)
    data["planner"]["learn_prior"] = "yes"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(world.ScenarioError) as err:
        world.load_scenario(path)
    assert err.value.problems[0].endswith("planner.learn_prior: expected true or false, found 'yes'")


def test_run_fleet_and_coordinator_take_learn_prior():
    from planner.registry import planner_settings

    scenario = world.load_scenario(ROOT / "scenarios" / "tiny.yaml")
    name, options = planner_settings(scenario, "closed-loop", 50, None, (parse_option("learn_prior=true"),))
    assert options["learn_prior"] is True
    assert used_options(name, options)["learn_prior"] is True  # what the coordinator keeps and records
    assert isinstance(make_planner(name, **options), LearnedPriorPlanner)
    proc = subprocess.run([sys.executable, "run_fleet.py", "scenarios/tiny.yaml", "--planner-option", "learn_prior=maybe"],
                          cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [
        "run_fleet.py: --planner-option: learn_prior: expected true or false, found 'maybe'"]


def _solve(tmp_path, capsys, *flags, prior=None):
    inst = {"carriers": 2, "passengers": 2, "stages": 6, "overlaps": [[[0, 2], [1, 2]]],
            "observations": [[0, 9, 0, 12, 1, 0], [8, 0, 0, 0, 11, 2]]}
    if prior is not None:
        inst["prior"] = prior
    path = tmp_path / "i.json"
    path.write_text(json.dumps(inst))
    code = solve.main([str(path), "--planner", "ssap", "--no-clairvoyant", *flags])
    captured = capsys.readouterr()
    return code, captured


def test_solve_command_takes_learn_prior(tmp_path, capsys):
    code, plain = _solve(tmp_path, capsys)
    assert code == 0
    code, learned = _solve(tmp_path, capsys, "--learn-prior")
    assert code == 0
    code, explicit = _solve(tmp_path, capsys, "--learn-prior", "true")
    assert code == 0 and json.loads(explicit.out)["deployments"] == json.loads(learned.out)["deployments"]
    code, off = _solve(tmp_path, capsys, "--learn-prior", "false")
    assert code == 0 and json.loads(off.out)["deployments"] == json.loads(plain.out)["deployments"]
    # The exact value of plain SSAP is not the learned planner's: not reported for it.
    assert "planner_expected_reward" not in json.loads(learned.out).get("online_optimum", {})
    code, bad = _solve(tmp_path, capsys, "--learn-prior", prior={"kind": "table", "values": [0, 1, 2, 2.5, 8, 9, 11, 12],
                                                                  "probabilities": [0.3, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1]})
    assert code == 2 and bad.err.strip().startswith("learn_prior: expected a count prior")
    with pytest.raises(SystemExit) as stop:
        _solve(tmp_path, capsys, "--learn-prior", "maybe")
    assert stop.value.code == 2


def test_used_options_keep_copy_semantics():
    options = {"learn_prior": True, "iterations": 10}
    before = copy.deepcopy(options)
    make_planner("mcts-ssap", **options)
    assert options == before


def test_priors_sweep_tasks_share_units_seeds_and_observations():
    from experiments.priors import CASES, summarise
    from experiments.run import run_task
    from experiments.trials import Task

    level = [c[0] for c in CASES].index("open_field ×2")
    rows = [run_task(Task("priors", level, 1, "ssap", 0, 50, scenario=str(ROOT / CASES[level][1]), variant=v,
                          prior_factor=CASES[level][2], oracle=(3.16, 3.26)))
            for v in ("stated", "learned", "oracle")]
    assert len({(r["scale"], r["world_seed"], r["planner_seed"]) for r in rows}) == 1
    assert rows[0]["stated_mean"] == pytest.approx(2 * np.pi * 0.04 * 25)
    (row,) = summarise(rows)
    assert row["n"] == 1 and row["learned_oracle_ratio"] == pytest.approx(rows[1]["reward"] / rows[2]["reward"])
