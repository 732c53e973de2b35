"""Closed-loop's rollout base policy (planner.closedloop.conflict_values): thresholds and
externalities with the conflicts to come, case by case against values computed by hand from the
prior (scipy's Poisson pmf, independent of the planner's sampler and tables)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from planner import priors
from planner.closedloop import RULE_ROUNDS, ClosedLoopPlanner, base_rule
from planner.compiled import compile_problem
from planner.instance import random_instance
from planner.online import run_online
from planner.problem import Problem, make_view

MEAN = 3.0
PRIOR = {"kind": "poisson", "mean": MEAN}


def excess(c: float) -> float:
    """E[(X - c)^+] for X ~ Poisson(MEAN), from scipy's pmf."""
    k = np.arange(0, 200)
    return float(np.sum(stats.poisson.pmf(k, MEAN) * np.maximum(k - c, 0.0)))


def rule_of(valid, overlaps, passengers, stage, deployed=None, rounds=RULE_ROUNDS):
    """(problem, rule, table) of the stage view with ``deployed`` (bool [R, N]) in the past."""
    valid = np.asarray(valid, dtype=bool)
    problem = Problem.build(passengers, valid, overlaps, priors.build_prior(PRIOR))
    x = np.where(valid, 3.0, np.nan)
    deployed = np.zeros(valid.shape, bool) if deployed is None else np.asarray(deployed, dtype=bool)
    view = make_view(problem, stage, x, deployed)
    prep = compile_problem(problem)
    rule = base_rule(view, prep, np.ascontiguousarray(view.valid), view.stages_left_table,
                     view.passengers_left.astype(np.int64), view.deployed.ravel(), rounds)
    return problem, rule, prep.table


def point(problem, r, t):
    return r * problem.n_stages + t


# (case, valid, overlaps, passengers, stage, past deployments, point (r, t), d,
#  expected threshold as a function of the DLR table, expected externality)
CASES = [
    ("no overlaps: DLR's threshold, 3 stages left",
     [[1, 1, 1]], [], 1, 0, None, (0, 0), 1, lambda a: a[3, 2], 0.0),
    ("no overlaps: DLR's threshold, 2 stages left",
     [[1, 1, 1]], [], 1, 0, None, (0, 1), 1, lambda a: a[2, 1], 0.0),
    # Carrier 1 deployed at stage 0 where carrier 0's last point lies: that point is worth 0 to
    # carrier 0 (forced there, it shares), so at stage 1 waiting is worth nothing.
    ("last point taken by a past deployment: waiting worth 0",
     [[1, 1, 1], [1, 0, 0]], [[[1, 0], [0, 2]]], 1, 1, [[0, 0, 0], [1, 0, 0]], (0, 1), 1, lambda a: 0.0, 0.0),
    # Carrier 1 must deploy at stage 2 (its only valid stage), where it shares an overlap with
    # carrier 0's stage-1 point: deploying there takes E[X] from carrier 1.
    ("a forced neighbour after: deploying takes its whole value",
     [[1, 1, 1], [0, 0, 1]], [[[0, 1], [1, 2]]], 1, 0, None, (0, 1), 1, lambda a: a[2, 1], MEAN),
    # ...and so waiting at stage 0 for that point is worth E[max(X - MEAN, MEAN)] instead of
    # DLR's E[max(X, MEAN)]: the stage-0 threshold is MEAN + E[(X - 2 MEAN)^+].
    ("a forced neighbour after: waiting for the shared point is worth less",
     [[1, 1, 1], [0, 0, 1]], [[[0, 1], [1, 2]]], 1, 0, None, (0, 0), 1, lambda a: MEAN + excess(2 * MEAN), 0.0),
    # Carrier 1 must deploy at stage 1, before carrier 0's stage-2 point in the same overlap: that
    # point is unavailable, so carrier 0's stage-1 threshold is 0 (and carrier 1 is charged
    # nothing: the point it blocks had no chance anyway).
    ("a forced neighbour before: the later point is unavailable",
     [[1, 1, 1], [0, 1, 0]], [[[1, 1], [0, 2]]], 1, 0, None, (0, 1), 1, lambda a: 0.0, 0.0),
    ("a forced neighbour before: no externality on a point it makes unavailable",
     [[1, 1, 1], [0, 1, 0]], [[[1, 1], [0, 2]]], 1, 0, None, (1, 1), 1, None, 0.0),
    # Two passengers, the last stage made unavailable by a forced neighbour: at stage 0 both
    # passengers effectively have stages 0 and 1 only, so the second deploys on anything
    # positive (threshold 0) and the first waits for stage 1 (threshold E[X]).
    ("two passengers, last stage unavailable: d = 2 deploys on anything positive",
     [[1, 1, 1], [0, 1, 0]], [[[1, 1], [0, 2]]], [2, 1], 0, None, (0, 0), 2, lambda a: 0.0, 0.0),
    ("two passengers, last stage unavailable: d = 1 waits for E[X]",
     [[1, 1, 1], [0, 1, 0]], [[[1, 1], [0, 2]]], [2, 1], 0, None, (0, 0), 1, lambda a: MEAN, 0.0),
]


@pytest.mark.parametrize("case,valid,overlaps,passengers,stage,past,at,d,threshold,externality", CASES,
                         ids=[c[0] for c in CASES])
def test_rule_case(case, valid, overlaps, passengers, stage, past, at, d, threshold, externality):
    problem, rule, table = rule_of(valid, overlaps, passengers, stage, past)
    q = point(problem, *at)
    if threshold is not None:
        assert rule.thr[q, d] == pytest.approx(threshold(table), abs=1e-9), case
    assert rule.ext[q] == pytest.approx(externality, abs=1e-9), case


def test_without_conflicts_the_rule_is_dlr_exactly():
    """No overlaps: every threshold is DLR's bit for bit and nothing is charged."""
    valid = np.ones((3, 6), dtype=bool)
    valid[1, 2] = False
    problem, rule, table = rule_of(valid, [], 3, 0)
    nleft = make_view(problem, 0, np.where(valid, 3.0, np.nan), np.zeros(valid.shape, bool)).stages_left_table
    for r in range(3):
        for t in range(6):
            if not valid[r, t]:
                continue
            n = nleft[r, t]
            for d in range(1, min(3, n - 1) + 1):
                assert rule.thr[point(problem, r, t), d] == table[n, n - d]
    assert not rule.ext.any()


def test_zero_rounds_is_the_conflict_aware_ssap_rule():
    """``rule_rounds = 0``: DLR's thresholds and no externality even with dense overlaps."""
    inst = random_instance(np.random.default_rng(3), 8, 3, 10, 40, MEAN)
    view = make_view(inst.problem, 2, inst.observations, np.zeros((8, 10), bool))
    prep = compile_problem(inst.problem)
    rule = base_rule(view, prep, np.ascontiguousarray(view.valid), view.stages_left_table,
                     view.passengers_left.astype(np.int64), view.deployed.ravel(), 0)
    assert not rule.ext.any()
    for r in range(8):
        for t in range(2, 10):
            n = view.stages_left_table[r, t]
            for d in range(1, min(3, n - 1) + 1):
                assert rule.thr[r * 10 + t, d] == prep.table[n, n - d]
    full = base_rule(view, prep, np.ascontiguousarray(view.valid), view.stages_left_table,
                     view.passengers_left.astype(np.int64), view.deployed.ravel(), RULE_ROUNDS)
    assert full.ext.any() and (full.ext >= 0).all()


def test_closed_loop_is_ssap_without_conflicts_with_either_rule():
    inst = random_instance(np.random.default_rng(5), 5, 3, 10, 0, MEAN)
    from planner.policies import SSAPPlanner

    ssap = run_online(inst.problem, inst.observations, SSAPPlanner(), 1).deployed
    for rounds in (0, RULE_ROUNDS):
        got = run_online(inst.problem, inst.observations, ClosedLoopPlanner(iterations=50, rule_rounds=rounds), 1)
        np.testing.assert_array_equal(got.deployed, ssap)


def test_measurement_command_prints_the_paired_figures(capsys):
    """``python -m tools.base_policy`` (docs/results.md) on a small configuration."""
    from tools import base_policy

    assert base_policy.parse_trials("3,60-62") == [3, 60, 61, 62]
    assert base_policy.main(["--carriers", "4", "--trials", "0-1", "--iterations", "30", "--bound-samples", "2"]) == 0
    out = capsys.readouterr().out
    assert out.count("trial ") >= 2
    assert "paired difference new - previous" in out and "fraction of the bound" in out


@pytest.mark.slow
def test_bound_nodes_pairs_the_mixed_bound_with_the_node_limited_one(tmp_path):
    """tools.bound_nodes on the experiment's R = 6 configuration (every component within the exact
    limit, so both bounds are the same numbers), its CSV, and a size the experiment does not have."""
    import csv

    from cli_helpers import in_process
    from tools import bound_nodes

    out = tmp_path / "rows.csv"
    run = in_process(bound_nodes.main, ["--carriers", "6", "--trials", "0", "--out", out])
    assert run.returncode == 0, run.stderr
    assert "bound at 1 node(s) / mixed bound = 1.0000" in run.stdout
    [row] = list(csv.DictReader(out.open()))
    assert row["config"] == "R = 6, 10 overlaps" and row["mixed_method"] == "mixed"
    assert float(row["mixed"]) == float(row["nodes"]) > 0
    bad = in_process(bound_nodes.main, ["--carriers", "7"])
    assert bad.returncode == 1 and "expected one of the experiment's sizes" in bad.stderr
