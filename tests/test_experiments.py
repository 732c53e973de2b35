"""The experiments entry point (smoke test with tiny settings) and the closed-loop planner.

Closed-loop planner: feasibility (with ∅ stages, per-carrier D, online surprises, continuous and
table priors), causality, determinism, the selection bookkeeping against the exact penalty rule,
identity with SSAP when nothing conflicts, and a paired comparison showing it beats SSAP and
MCTS-SSAP at the same budget on conflicted instances.
"""
from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from planner import closedloop
from planner.compiled import compile_problem
from planner.instance import random_instance
from planner.registry import make_planner
from planner.problem import Problem, evaluate, make_view, sample_observations
from planner.online import run_online

ROOT = Path(__file__).resolve().parent.parent


def _instances(seed: int, count: int, **kw):
    rng = np.random.default_rng(seed)
    for _ in range(count):
        carriers = kw.get("carriers", int(rng.integers(1, 6)))
        stages = kw.get("stages", int(rng.integers(1, 10)))
        passengers = kw.get("passengers", rng.integers(0, 5, size=carriers).tolist())
        yield random_instance(rng, carriers=carriers, passengers=passengers, stages=stages,
                              overlaps=kw.get("overlaps", int(rng.integers(0, 15))),
                              mean=float(kw.get("mean", rng.uniform(0.5, 5))),
                              invalid_fraction=kw.get("invalid_fraction", float(rng.choice([0.0, 0.2, 0.5]))))


def _paired(a, b):
    d = np.asarray(a) - np.asarray(b)
    return d.mean(), d.std(ddof=1) / np.sqrt(len(d))


# ----------------------------------------------------------------------------- the planner


def test_feasible_and_every_passenger_deployed():
    planner = make_planner("closed-loop", iterations=200)
    for k, (problem, x) in enumerate(_instances(1, 40)):
        result = run_online(problem, x, planner, seed=k)  # enforce() checks every stage's rules
        valid = ~np.isnan(x)
        assert not (result.deployed & ~valid).any()
        expected = np.minimum(problem.passengers, valid.sum(axis=1))
        assert result.deployed.sum(axis=1).tolist() == expected.tolist()


def test_feasible_with_online_surprises_and_other_priors():
    rng = np.random.default_rng(5)
    priors = [stats.gamma(2.0, scale=1.5), stats.rv_discrete(values=([0.5, 2.0, 7.5], [0.5, 0.3, 0.2]))()]
    planner = make_planner("closed-loop", iterations=100)
    for k, (problem, x) in enumerate(_instances(2, 24)):
        prior = priors[k % 2]
        problem = Problem.build(problem.passengers, problem.valid, problem.overlaps, prior)
        x = sample_observations(problem, rng)
        x[rng.random(x.shape) < 0.15] = np.nan  # carriers that did not report
        result = run_online(problem, x, planner, seed=k)
        assert not (result.deployed & np.isnan(x)).any()
        assert (result.deployed.sum(axis=1) <= problem.passengers).all()


def test_time_budget_mode_is_feasible():
    planner = make_planner("closed-loop", plan_ms=3.0)
    for k, (problem, x) in enumerate(_instances(3, 5, carriers=6, stages=10, passengers=3, overlaps=20,
                                                 invalid_fraction=0.0)):
        result = run_online(problem, x, planner, seed=k)
        assert result.deployed.sum(axis=1).tolist() == [3] * 6


def test_causality():
    """Changing observations after stage j never changes the decisions up to j (same seed)."""
    planner = make_planner("closed-loop", iterations=300)
    rng = np.random.default_rng(7)
    for k, (problem, x) in enumerate(_instances(4, 12, carriers=4, stages=8, overlaps=12)):
        base = run_online(problem, x, planner, seed=k).deployed
        j = int(rng.integers(0, problem.n_stages))
        changed = x.copy()
        future = problem.valid.copy()
        future[:, : j + 1] = False
        changed[future] = rng.poisson(3.0, size=int(future.sum()))
        other = run_online(problem, changed, planner, seed=k).deployed
        assert (other[:, : j + 1] == base[:, : j + 1]).all()


def test_determinism_and_seed_matters():
    planner = make_planner("closed-loop", iterations=60)
    differs = False
    for k, (problem, x) in enumerate(_instances(5, 15, carriers=4, stages=10, passengers=3, overlaps=20,
                                                 invalid_fraction=0.0)):
        a = run_online(problem, x, planner, seed=k)
        b = run_online(problem, x, make_planner("closed-loop", iterations=60), seed=k)
        assert (a.deployed == b.deployed).all() and a.reward == b.reward
        differs |= not (run_online(problem, x, planner, seed=k + 1000).deployed == a.deployed).all()
    assert differs, "60 noisy iterations should make some decision depend on the seed"


def test_selection_bookkeeping_matches_the_penalty_rule():
    """Marginal gains summed over a selection sequence equal evaluate(); undo restores the state."""
    rng = np.random.default_rng(11)
    for problem, x in _instances(6, 30, carriers=4, stages=6, passengers=6, overlaps=10, invalid_fraction=0.0):
        prep = compile_problem(problem)
        size = problem.n_carriers * problem.n_stages
        order = rng.permutation(size)[: int(rng.integers(1, size + 1))]
        n_past = int(rng.integers(0, len(order) + 1))
        sel = np.zeros(size, dtype=bool)
        sel[order[:n_past]] = True
        p = (1 + problem.conflict[:, sel].sum(axis=1)).astype(np.int64)
        xv = np.where(sel, x.ravel(), 0.0)
        start = (sel.copy(), p.copy())
        log = np.empty(size + len(prep.nbr) + 1, dtype=np.int64)
        total = evaluate(problem, sel.reshape(x.shape), x)[1]
        nlog = 0
        for q in order[n_past:]:
            total += closedloop.marginal_gain(q, x.ravel()[q], sel, p, xv, prep.indptr, prep.nbr)
            nlog = closedloop.select_point(q, x.ravel()[q], sel, p, xv, prep.indptr, prep.nbr, log, nlog)
        deployed = np.zeros(size, dtype=bool)
        deployed[order] = True
        assert total == pytest.approx(evaluate(problem, deployed.reshape(x.shape), x)[1], abs=1e-9)
        assert (p[deployed] == 1 + problem.conflict[np.ix_(deployed, deployed)].sum(axis=1)).all()
        closedloop.undo_selection(sel, p, log, nlog)
        assert (sel == start[0]).all() and (p[start[0]] == start[1][start[0]]).all()


def test_without_overlaps_it_is_ssap():
    """No conflicts: every carrier is its own component and decides by SSAP, which is optimal."""
    closed, plain = [], []
    planner, ssap_planner = make_planner("closed-loop", iterations=500), make_planner("ssap")
    for k, (problem, x) in enumerate(_instances(8, 40, carriers=4, stages=10, passengers=3, overlaps=0,
                                                 invalid_fraction=0.1)):
        a = run_online(problem, x, planner, seed=k)
        b = run_online(problem, x, ssap_planner, seed=k)
        assert (a.deployed == b.deployed).all()
        closed.append(a.reward)
        plain.append(b.reward)
    assert np.mean(closed) >= np.mean(plain)


@pytest.mark.slow
def test_beats_ssap_and_mcts_ssap_with_many_overlaps():
    """Paired on 50 seeded instances (R = 4, D = 3, N = 10, 20 overlaps), the paper's 10,000 iterations."""
    rewards = {name: [] for name in ("closed-loop", "mcts-ssap", "ssap")}
    planners = {name: make_planner(name, iterations=10_000) for name in rewards}
    for k, (problem, x) in enumerate(_instances(9, 50, carriers=4, stages=10, passengers=3, overlaps=20,
                                                 mean=3.0, invalid_fraction=0.0)):
        for name, planner in planners.items():
            rewards[name].append(run_online(problem, x, planner, seed=k).reward)
    for other in ("mcts-ssap", "ssap"):
        mean, err = _paired(rewards["closed-loop"], rewards[other])
        assert mean > 2 * err and mean > 0, (other, mean, err)


def test_bad_budget_is_a_clear_error():
    with pytest.raises(ValueError, match="iterations"):
        make_planner("closed-loop", iterations=0)
    with pytest.raises(ValueError, match="plan_ms"):
        make_planner("closed-loop", plan_ms=-1)


def test_stage_without_choice_returns_forced_action():
    problem = Problem.build([1, 2], np.ones((2, 2), dtype=bool), [[[0, 0], [1, 0]]])
    view = make_view(problem, 0, np.array([[1.0, 0.0], [5.0, 1.0]]), np.zeros((2, 2), dtype=bool))
    decision = closedloop.ClosedLoopPlanner(iterations=10).decide(view, np.random.default_rng(0))
    assert decision[1]  # carrier 1 must deploy at both of its stages


# ----------------------------------------------------------------------------- entry point


def _run(*args, timeout=240):
    return subprocess.run([sys.executable, "-m", "experiments", *args], cwd=ROOT, capture_output=True,
                          text=True, timeout=timeout)


@pytest.mark.slow
def test_entry_point_smoke(tmp_path):
    out = tmp_path / "results"
    proc = _run("all", "--quick", "--trials", "2", "--iterations", "64", "--urban-trials", "1", "--jobs", "2",
                "--overlaps", "0,12", "--carriers", "2,5", "--out", str(out), "--no-progress")
    assert proc.returncode == 0, proc.stderr
    for name in ("overlap", "scaling", "urban"):
        for suffix in ("_trials.csv", "_summary.csv", ".md"):
            assert (out / f"{name}{suffix}").is_file(), name + suffix
    for png in ("overlap.png", "scaling.png", "urban_map_mcts-ssap.png", "urban_map_closed-loop.png"):
        assert (out / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    names = {"mcts-ssap", "mcts-random", "ssap", "random", "closed-loop", "clairvoyant"}
    with open(out / "overlap_trials.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 2 * 2 * len(names) and {r["planner"] for r in rows} == names
    by_trial = {}
    for r in rows:
        by_trial.setdefault((r["level"], r["trial"]), []).append(r)
    for group in by_trial.values():
        # Common random numbers: one planner seed per trial; the exact bound beats every planner.
        assert len({r["planner_seed"] for r in group}) == 1
        bound = next(r for r in group if r["planner"] == "clairvoyant")
        assert bound["exact"] == "1"
        assert all(float(r["reward"]) <= float(bound["reward"]) + 1e-9 for r in group)
    with open(out / "scaling_summary.csv") as f:
        summary = list(csv.DictReader(f))
    assert {(r["level"], r["n"]) for r in summary} == {("2", "2"), ("5", "2")}
    info = json.loads((out / "run_info.json").read_text())
    assert set(info["sweeps"]) == {"overlap", "scaling", "urban"}
    assert all(s["seconds"] >= 0 for s in info["sweeps"].values())
    assert "| MCTS-SSAP |" in (out / "urban.md").read_text()


def test_entry_point_is_reproducible(tmp_path):
    from experiments.run import main

    args = ["overlap", "--trials", "2", "--iterations", "50", "--overlaps", "15", "--jobs", "1",
            "--planners", "closed-loop,mcts-ssap,random", "--no-progress", "--seed", "3"]
    columns = []
    for k in range(2):
        assert main([*args, "--out", str(tmp_path / str(k))]) == 0
        with open(tmp_path / str(k) / "overlap_trials.csv") as f:
            columns.append([(r["planner"], r["trial"], r["reward"], r["deployed"]) for r in csv.DictReader(f)])
    assert columns[0] == columns[1]
    # The report is a pure function of the CSV: rewriting it from the CSV changes nothing.
    def summary():  # everything but the timings
        with open(tmp_path / "0" / "overlap_summary.csv") as f:
            return [{k: v for k, v in r.items() if not k.startswith("decision_ms")} for r in csv.DictReader(f)]

    before = summary()
    assert main(["overlap", "--report-only", "--out", str(tmp_path / "0")]) == 0
    assert summary() == before


@pytest.mark.parametrize("args, text", [
    (["--trials", "0"], "--trials: expected an integer >= 1"),
    (["--planners", "ssap,greedy"], "--planners: expected names among"),
    (["--overlaps", "1,x"], "--overlaps: expected comma-separated integers"),
    (["--scenario", "nope.yaml"], "--scenario: expected an existing scenario file"),
], ids=["trials", "planner", "overlaps", "scenario"])
def test_bad_arguments_exit_2_with_one_line(args, text, capsys):
    from experiments.run import main

    assert main(["all", *args]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and text in err


def test_bad_argument_in_a_real_process():
    proc = _run("overlap", "--jobs", "0")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1 and "--jobs" in proc.stderr


def test_control_variate_estimator_agrees_with_plain_monte_carlo():
    """Both estimators of the candidates' values have the same expectation (differences agree)."""
    import itertools

    for seed in range(4):
        problem, x = random_instance(np.random.default_rng(seed), 3, 2, 6, 8, 3.0)
        deployed = np.zeros(x.shape, dtype=bool)
        deployed[0, 0] = True
        view = make_view(problem, 1, x, deployed)
        free = view.can_deploy & ~view.must_deploy
        actions = []
        for bits in itertools.product([False, True], repeat=int(free.sum())):
            a = view.must_deploy.copy()
            a[free] = bits
            actions.append(a)
        actions = np.array(actions)
        cv = closedloop.estimate(view, actions, 100_000, np.random.default_rng(1))
        mc = closedloop.estimate(view, actions, 100_000, np.random.default_rng(2), control_variate=False)
        assert np.abs((cv - cv[0]) - (mc - mc[0])).max() < 0.08


@pytest.mark.slow
def test_your_own_scenario_writes_a_fresh_folder_without_the_papers_column(tmp_path):
    """``python -m experiments urban --scenario mine.yaml`` without --out: a fresh folder under the
    current directory (never the shipped docs/results), no paper's column on another scenario and
    no ``± nan`` for one trial."""
    import shutil

    shipped = {p: p.stat().st_mtime_ns for p in (ROOT / "docs" / "results").iterdir() if p.is_file()}
    shutil.copy(ROOT / "scenarios" / "tiny.yaml", tmp_path / "mine.yaml")
    proc = subprocess.run([sys.executable, "-m", "experiments", "urban", "--scenario", "mine.yaml", "--urban-trials",
                           "1", "--iterations", "20", "--planners", "ssap,random", "--jobs", "1", "--no-progress"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=300,
                          env={**__import__("os").environ, "PYTHONPATH": str(ROOT)})
    assert proc.returncode == 0, proc.stderr
    outs = list((tmp_path / "results").iterdir())
    assert len(outs) == 1 and outs[0].name.startswith("urban-") and (outs[0] / "urban_trials.csv").is_file()
    table = (outs[0] / "urban.md").read_text()
    assert "nan" not in table and "paper" not in table.lower(), table
    assert {p: p.stat().st_mtime_ns for p in (ROOT / "docs" / "results").iterdir() if p.is_file()} == shipped
    # --report-only needs the folder to redraw; --out naming a file is one line
    from experiments.run import main

    assert main(["urban", "--report-only"]) == 2
    (tmp_path / "f").write_text("x")
    assert main(["urban", "--out", str(tmp_path / "f")]) == 2
