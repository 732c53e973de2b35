"""The problem model: penalty rule on hand-computed cases, the causal view, the online loop."""
from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from planner.online import run_online
from planner.problem import (
    Problem, enforce, evaluate, make_view, normalisation_scale, penalties, rewards, stage_rng,
)

NAN = np.nan


def _deployed(shape, points):
    out = np.zeros(shape, dtype=bool)
    for r, j in points:
        out[r, j] = True
    return out


def test_penalty_chain_hand_computed():
    # (0,0)-(1,0) share overlap A; (1,0)-(0,2) share overlap B; (0,0) and (0,2) share none.
    problem = Problem.build(2, np.ones((2, 3), bool), [[[0, 0], [1, 0]], [[1, 0], [0, 2]]], normalize="none")
    x = np.array([[6.0, 1.0, 4.0], [9.0, 2.0, 5.0]])
    dep = _deployed((2, 3), [(0, 0), (1, 0), (0, 2)])
    p = penalties(problem, dep)
    assert (p[0, 0], p[1, 0], p[0, 2]) == (2, 3, 2)
    assert rewards(problem, dep, x)[dep].tolist() == [6 / 2, 4 / 2, 9 / 3]
    assert evaluate(problem, dep, x) == pytest.approx((3 + 2 + 3, 3 + 2 + 3))


def test_carrier_conflicting_with_itself():
    # One overlap holding two stages of carrier 0: deploying at both halves each.
    problem = Problem.build(2, np.ones((1, 4), bool), [[[0, 1], [0, 3]]], normalize="none")
    x = np.array([[1.0, 8.0, 1.0, 6.0]])
    both = _deployed((1, 4), [(0, 1), (0, 3)])
    assert penalties(problem, both)[0, [1, 3]].tolist() == [2, 2]
    assert evaluate(problem, both, x)[1] == pytest.approx(7.0)
    # Deploying at 1 and 2 avoids the self-conflict.
    assert evaluate(problem, _deployed((1, 4), [(0, 1), (0, 2)]), x)[1] == pytest.approx(9.0)


def test_point_in_two_overlaps_counts_each_other_deployment_once():
    # (0,0) and (1,0) share two overlaps; (2,1) shares only the second with them.
    overlaps = [[[0, 0], [1, 0]], [[0, 0], [1, 0], [2, 1]]]
    problem = Problem.build(1, np.ones((3, 2), bool), overlaps, normalize="none")
    x = np.full((3, 2), 6.0)
    dep = _deployed((3, 2), [(0, 0), (1, 0), (2, 1)])
    p = penalties(problem, dep)
    assert (p[0, 0], p[1, 0], p[2, 1]) == (3, 3, 3)
    assert evaluate(problem, dep, x)[1] == pytest.approx(6.0)
    # Without (2,1): the pair conflicts once (union over overlaps), p = 2 not 3.
    dep2 = _deployed((3, 2), [(0, 0), (1, 0)])
    assert penalties(problem, dep2)[0, 0] == 2


def test_past_rewards_shrink_when_later_deployments_join():
    problem = Problem.build(1, np.ones((2, 3), bool), [[[0, 0], [1, 2]]], normalize="none")
    x = np.array([[10.0, 0.0, 0.0], [0.0, 0.0, 4.0]])
    early = _deployed((2, 3), [(0, 0)])
    assert rewards(problem, early, x)[0, 0] == 10.0
    later = _deployed((2, 3), [(0, 0), (1, 2)])
    r = rewards(problem, later, x)
    assert r[0, 0] == 5.0 and r[1, 2] == 2.0


def test_duplicate_point_in_an_overlap_is_not_a_self_conflict():
    problem = Problem.build(1, np.ones((1, 2), bool), [[[0, 1], [0, 1]]], normalize="none")
    assert penalties(problem, _deployed((1, 2), [(0, 1)]))[0, 1] == 1


def test_normalisation():
    assert normalisation_scale(stats.poisson(3.0), "q90") == 5.0
    assert normalisation_scale(stats.poisson(3.0), "q50") == 3.0
    assert normalisation_scale(stats.poisson(3.0), "none") == 1.0
    assert normalisation_scale(stats.poisson(3.0), 2.5) == 2.5
    problem = Problem.build(1, np.ones((1, 2), bool))
    assert evaluate(problem, _deployed((1, 2), [(0, 0)]), np.array([[10.0, 0.0]])) == (2.0, 10.0)
    for bad in ("p90", "q100", "median", -1.0):
        with pytest.raises(ValueError):
            normalisation_scale(stats.poisson(3.0), bad)
    with pytest.raises(ValueError, match="positive"):
        normalisation_scale(stats.poisson(0.01), "q90")  # 90th percentile is 0


def test_build_rejects_bad_input_and_freezes_arrays():
    with pytest.raises(ValueError, match="one per carrier"):
        Problem.build([1, 2, 3], np.ones((2, 4), bool))
    with pytest.raises(ValueError, match=">= 0"):
        Problem.build([1, -1], np.ones((2, 4), bool))
    with pytest.raises(ValueError, match="overlaps\\[1\\]"):
        Problem.build(1, np.ones((2, 4), bool), [[[0, 0]], [[2, 0]]])
    mine_valid, mine_group = np.ones((2, 4), bool), np.array([[0, 0], [1, 3]], dtype=np.int64)
    problem = Problem.build([1, 2], mine_valid, [mine_group])
    assert mine_valid.flags.writeable and mine_group.flags.writeable  # the caller's arrays stay theirs
    assert problem.passengers.tolist() == [1, 2]
    for arr in (problem.passengers, problem.valid, problem.conflict, problem.overlaps[0]):
        with pytest.raises(ValueError):
            arr[...] = 0


def test_view_masks_future_and_applies_surprises():
    valid = np.array([[True, True, True, True], [False, True, True, True]])
    problem = Problem.build([2, 3], valid)
    x = np.array([[1.0, NAN, 3.0, 4.0], [NAN, 5.0, 6.0, 7.0]])  # (0,1) is a surprise ∅
    deployed = np.array([[True, False, True, True], [False, True, True, True]])  # columns >= j ignored
    view = make_view(problem, 2, x, deployed)
    assert np.isnan(view.observations[:, 3]).all()
    assert view.observations[0, 2] == 3.0 and view.observations[1, 2] == 6.0
    assert not view.valid[0, 1] and view.valid[0, 3]  # surprise applied, future scheduled
    assert not view.deployed[:, 2:].any()
    assert view.passengers_left.tolist() == [1, 2]
    assert view.stages_left.tolist() == [2, 2]
    assert view.can_deploy.tolist() == [True, True]
    assert view.must_deploy.tolist() == [False, True]
    with pytest.raises(ValueError):
        make_view(problem, 4, x, deployed)


def test_enforce_catches_rule_breaking_decisions():
    problem = Problem.build(1, np.array([[True, True], [True, False]]))
    x = np.array([[1.0, 1.0], [NAN, NAN]])
    view = make_view(problem, 0, x, np.zeros((2, 2), bool))
    assert not view.can_deploy[1]
    with pytest.raises(AssertionError, match="cannot deploy"):
        enforce(view, [False, True])
    last = make_view(problem, 1, x, np.zeros((2, 2), bool))
    with pytest.raises(AssertionError, match="must deploy"):
        enforce(last, [False, False])


class _Recorder:
    """A planner deploying whenever allowed; checks warm_up ran before the first decision."""

    name = "recorder"

    def __init__(self):
        self.warmed = False
        self.stages = []

    def warm_up(self, problem):
        self.warmed = True

    def decide(self, view, rng):
        assert self.warmed
        self.stages.append(view.stage)
        return view.can_deploy


def test_run_online_warms_up_and_evaluates():
    problem = Problem.build(2, np.ones((2, 3), bool), [[[0, 0], [1, 0]]], normalize="none")
    x = np.array([[2.0, 3.0, 4.0], [6.0, 1.0, 1.0]])
    planner = _Recorder()
    result = run_online(problem, x, planner, seed=0)
    assert planner.stages == [0, 1, 2]
    assert result.deployed.tolist() == [[True, True, False], [True, True, False]]
    assert result.features == pytest.approx(2 / 2 + 3 + 6 / 2 + 1)
    assert len(result.decision_ms) == 3


def test_stage_rng_depends_on_seed_and_stage_only():
    a = stage_rng(7, 3).random(4)
    assert np.array_equal(a, stage_rng(7, 3).random(4))
    assert not np.array_equal(a, stage_rng(7, 4).random(4))
    assert not np.array_equal(a, stage_rng(8, 3).random(4))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_tally_keeps_the_penalties_of_every_confirmation_so_far(seed):
    # The running score (mission.records.Tally) adds or removes a point's conflict row as it is
    # confirmed; after every step its reward must be evaluate()'s over all deployments so far,
    # bit for bit, through confirmations that are repeated and taken back.
    from mission.records import Tally

    rng = np.random.default_rng(seed)
    R, N = 7, 5
    overlaps = [[[int(rng.integers(R)), int(rng.integers(N))] for _ in range(int(rng.integers(2, 5)))]
                for _ in range(6)]
    problem = Problem.build(2, np.ones((R, N), bool), overlaps)
    ids = [f"c{r}" for r in range(R)]
    tally = Tally(ids, N, problem)
    x = rng.integers(0, 9, size=(R, N)).astype(float)
    for r in range(R):
        for j in range(N):
            tally.observe(ids[r], j, x[r, j])
    assert tally.reward() == (0.0, 0.0)
    for _ in range(60):
        r, j, value = int(rng.integers(R)), int(rng.integers(N)), bool(rng.random() < 0.7)
        tally.confirm(ids[r], j, value)
        assert tally.reward() == (evaluate(problem, tally.deployed, x) if tally.deployed.any() else (0.0, 0.0))
    assert np.array_equal(tally._p.reshape(R, N), penalties(problem, tally.deployed))
