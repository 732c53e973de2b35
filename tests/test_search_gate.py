"""closed-loop-gated: closed-loop's search choosing among sampled candidates through a gate
(planner.closedloop.GATE) and its base action deciding a stage's carriers by margin
(docs/planner.md, "closed-loop-gated")."""
from __future__ import annotations

import time

import numpy as np

from planner import priors
from planner.closedloop import GATE, ClosedLoopPlanner, GatedClosedLoopPlanner, Selection, base_action, base_rule
from planner.compiled import compile_problem
from planner.instance import random_instance
from planner.joint import sampled_mean
from planner.online import run_online
from planner.problem import Problem, make_view


def test_sampled_mean_gives_the_standard_error_of_each_gap_to_candidate_zero():
    values = np.random.default_rng(4).normal(size=(5, 40)) + np.arange(5)[:, None]
    mean, se = sampled_mean(5, 40, None, lambda batch: values[:, :batch], spread=True)
    np.testing.assert_allclose(mean, values.mean(axis=1))
    gaps = values - values[0]
    np.testing.assert_allclose(se, gaps.std(axis=1, ddof=1) / np.sqrt(40))
    assert se[0] == 0.0
    np.testing.assert_array_equal(sampled_mean(5, 40, None, lambda batch: values[:, :batch]), mean)
    # Anytime mode: batches until the deadline (here one batch, the deadline has passed).
    mean, se = sampled_mean(5, 40, time.perf_counter() - 1.0, lambda batch: values[:, :batch], spread=True)
    np.testing.assert_allclose(se, gaps[:, :32].std(axis=1, ddof=1) / np.sqrt(32))


def test_a_huge_gate_keeps_the_base_action_and_no_gate_searches():
    """With an enormous gate no sampled candidate beats the base action, so the decisions do not
    depend on the sampled futures (the planner seed); without the gate they do on this instance."""
    inst = random_instance(np.random.default_rng(11), 12, 3, 10, 60, 3.0)

    def runs(**options):
        return [run_online(inst.problem, inst.observations, ClosedLoopPlanner(iterations=200, **options), seed).deployed
                for seed in (1, 2, 3)]

    kept = runs(gate=1e12)
    for other in kept[1:]:
        np.testing.assert_array_equal(other, kept[0])
    searched = runs(gate=0.0)
    assert any((d != searched[0]).any() for d in searched[1:])
    assert GATE > 0


def test_the_base_action_lets_the_larger_margin_take_a_shared_point():
    """Two carriers share an overlap at stage 0, both over their thresholds: in index order
    carrier 0 (x = 5) takes the point and carrier 1 (x = 9) then stays; by margin carrier 1 goes
    first and carrier 0 stays."""
    valid = np.ones((2, 3), bool)
    problem = Problem.build(1, valid, [[[0, 0], [1, 0]]], priors.build_prior({"kind": "poisson", "mean": 3.0}))
    x = np.array([[5.0, 3.0, 3.0], [9.0, 3.0, 3.0]])
    view = make_view(problem, 0, x, np.zeros((2, 3), bool))
    prep = compile_problem(problem)
    left = view.passengers_left.astype(np.int64)
    rule = base_rule(view, prep, np.ascontiguousarray(view.valid), view.stages_left_table, left,
                     view.deployed.ravel(), 6)
    state = Selection(np.zeros(6, bool), prep.penalties(np.zeros(6, bool)), np.zeros(6))
    args = (np.arange(2, dtype=np.int64), 0, prep, state, view.stages_left_table, left, x[:, 0],
            view.must_deploy, view.can_deploy & ~view.must_deploy)
    np.testing.assert_array_equal(base_action(*args, rule=rule), [True, False])
    np.testing.assert_array_equal(base_action(*args, rule=rule, by_margin=True), [False, True])
    # The previous rule (no Rule: dec-closed-loop's partial-information path) keeps index order.
    np.testing.assert_array_equal(base_action(*args, by_margin=True), base_action(*args))


def test_the_registry_builds_both_and_closed_loop_is_unchanged():
    from planner.registry import make_planner

    gated = make_planner("closed-loop-gated", iterations=300)
    assert isinstance(gated, GatedClosedLoopPlanner) and gated.name == "closed-loop-gated"
    assert (gated.gate, gated.by_margin, gated.iterations) == (GATE, True, 300)
    plain = make_planner("closed-loop", iterations=300)
    assert type(plain) is ClosedLoopPlanner and (plain.gate, plain.by_margin) == (0.0, False)
    # Without overlaps both are SSAP (no search, no shared point).
    inst = random_instance(np.random.default_rng(5), 5, 3, 10, 0, 3.0)
    a = run_online(inst.problem, inst.observations, gated, 1).deployed
    b = run_online(inst.problem, inst.observations, plain, 1).deployed
    np.testing.assert_array_equal(a, b)


def test_gated_decisions_are_deterministic_and_differ_from_closed_loop():
    inst = random_instance(np.random.default_rng(7), 16, 3, 10, 80, 3.0)
    first = run_online(inst.problem, inst.observations, GatedClosedLoopPlanner(iterations=300), 4)
    again = run_online(inst.problem, inst.observations, GatedClosedLoopPlanner(iterations=300), 4)
    np.testing.assert_array_equal(first.deployed, again.deployed)
    plain = run_online(inst.problem, inst.observations, ClosedLoopPlanner(iterations=300), 4)
    assert (first.deployed != plain.deployed).any()


def test_measurement_command_prints_the_paired_figures(capsys):
    """``python -m tools.gated_search`` (docs/planner.md, "closed-loop-gated") on small configurations."""
    from tools import gated_search

    assert gated_search.parse_trials("3,20-22") == [3, 20, 21, 22]
    for family in gated_search.FAMILIES:
        assert gated_search.main(["--family", family, "--carriers", "4", "--trials", "0-1", "--obs", "2",
                                  "--iterations", "30", "--bound-samples", "2"]) == 0
        out = capsys.readouterr().out
        assert out.count("trial ") >= 2
        assert "paired difference new - previous" in out and "fraction of the bound" in out
    bounds = {}
    for method in ("mixed", "mixed-root"):  # R = 4: every component exact, so the root node changes nothing
        assert gated_search.main(["--family", "dense", "--carriers", "4", "--trials", "0", "--obs", "1",
                                  "--iterations", "30", "--bound-samples", "2", "--bound-method", method]) == 0
        bounds[method] = float(capsys.readouterr().out.split("bound   : ")[1].split()[0])
    assert bounds["mixed-root"] == bounds["mixed"] > 0
    problem, x = gated_search.instance("dense", 6, 0)
    assert len(problem.overlaps) == 48 and problem.prior.dist.name == "nbinom"
    again = gated_search.observations("dense", problem, x, 0, 1)
    np.testing.assert_array_equal(again, gated_search.observations("dense", problem, x, 0, 1))
    assert (again != x).any()
