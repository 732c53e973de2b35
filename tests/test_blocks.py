"""Large conflict components are searched in blocks (closed-loop, dec-closed-loop): the split, and
that blocks change nothing for components that fit in one."""
import numpy as np
import pytest

from mission.peers import PeerBook
from planner.closedloop import BLOCK, ClosedLoopPlanner, _blocks
from planner.decentralised import DecClosedLoopPlanner, local_views
from planner.problem import Problem, enforce, make_view, stage_rng
from planner.online import run_online


def chain(n_carriers: int, n_stages: int = 6, passengers: int = 2) -> Problem:
    """Carrier r overlaps carrier r + 1 at every stage: one component, a path graph."""
    valid = np.ones((n_carriers, n_stages), dtype=bool)
    overlaps = [[[r, t], [r + 1, t]] for r in range(n_carriers - 1) for t in range(n_stages)]
    return Problem.build(passengers, valid, overlaps)


def path_adjacency(n: int) -> np.ndarray:
    adj = np.zeros((n, n), dtype=bool)
    idx = np.arange(n - 1)
    adj[idx, idx + 1] = adj[idx + 1, idx] = True
    return adj


@pytest.mark.parametrize("n, size", [(10, 4), (33, 32), (64, 8), (7, 3)])
def test_blocks_partition_the_component_and_add_their_neighbours(n, size):
    adj = path_adjacency(n)
    comp = np.arange(n)
    parts = _blocks(comp, adj, size)
    blocks = [b for b, _ in parts]
    assert sorted(np.concatenate(blocks).tolist()) == list(range(n))  # disjoint and covering
    for block, members in parts:
        assert 1 <= len(block) <= size
        assert (np.diff(block) == 1).all()  # grown breadth-first on a path: contiguous
        halo = set(members.tolist()) - set(block.tolist())
        assert halo == {int(s) for s in np.flatnonzero(adj[block].any(axis=0))} - set(block.tolist())
        assert (np.diff(members) > 0).all()


def test_a_component_that_fits_is_one_block_without_halo():
    adj = path_adjacency(12)
    comp = np.arange(12)
    assert [(b.tolist(), m.tolist()) for b, m in _blocks(comp, adj, 12)] == [(comp.tolist(), comp.tolist())]
    assert len(_blocks(comp, adj, 0)) == 1  # 0: whole components


def test_blocks_change_nothing_when_the_component_fits():
    problem = chain(10)
    x = np.random.default_rng(5).poisson(3.0, problem.valid.shape).astype(float)

    def mission(planner):
        return run_online(problem, x, planner, 3).deployed

    whole = mission(ClosedLoopPlanner(iterations=400, block=0))
    np.testing.assert_array_equal(mission(ClosedLoopPlanner(iterations=400, block=10)), whole)
    np.testing.assert_array_equal(mission(ClosedLoopPlanner(iterations=400)), whole)  # BLOCK > 10


def test_blocked_search_is_feasible_deterministic_and_beats_ignoring_conflicts():
    """24 carriers on a chain in blocks of 4: every decision is feasible (enforce changes
    nothing), the same seed gives the same mission, and it does at least as well as plain SSAP,
    which ignores the conflicts, over a few observation draws."""
    from planner.registry import make_planner

    problem = chain(24, n_stages=6, passengers=2)
    gains = []
    for k in range(4):
        x = np.random.default_rng(100 + k).poisson(3.0, problem.valid.shape).astype(float)
        planner = ClosedLoopPlanner(iterations=300, block=4)
        n = problem.n_stages
        dep = np.zeros_like(problem.valid)
        for j in range(n):
            view = make_view(problem, j, np.where(np.arange(n)[None, :] <= j, x, np.nan), dep)
            d = planner.decide(view, stage_rng(3, j))
            np.testing.assert_array_equal(enforce(view, d), d)
            dep[:, j] = d
        again = run_online(problem, x, ClosedLoopPlanner(iterations=300, block=4), 3)
        np.testing.assert_array_equal(again.deployed, dep)
        gains.append(again.reward - run_online(problem, x, make_planner("ssap"), 3).reward)
    assert np.mean(gains) > 0, gains


def test_on_board_decision_in_a_large_component_is_the_decision_of_its_block_alone():
    """dec-closed-loop deciding alone in a 40-carrier chain with blocks of 8 searches carrier 20's
    block (16..23, grown breadth-first) and halo (15, 24) only: it decides, with the same scores,
    exactly as carrier 5 of a 10-carrier chain made of carriers 15..24 searched whole."""
    j = 1
    x = np.random.default_rng(9).poisson(3.0, (40, 5)).astype(float)

    def local(problem, xs, r, unknown):
        ids = [f"c{b}" for b in range(problem.n_carriers)]
        book = PeerBook(ids, problem.valid)
        for b in range(problem.n_carriers):
            for t in range(j + 1):
                if (b, t) != (unknown, j):  # one carrier's latest word missing: a partial view
                    book.observation(ids[b], t, float(xs[b, t]))
        view = book.local_view(problem, ids[r], j, 0)
        assert not view.complete
        return view

    big = DecClosedLoopPlanner(iterations=2000, block=8)
    small = DecClosedLoopPlanner(iterations=2000, block=0)
    for seed in range(3):
        a = big.partial_scores(local(chain(40, 5), x, 20, unknown=15), np.random.default_rng(seed))
        b = small.partial_scores(local(chain(10, 5), x[15:25], 5, unknown=0), np.random.default_rng(seed))
        np.testing.assert_array_equal(a[0], b[0])  # the same candidates over the same 10 carriers
        np.testing.assert_allclose(a[1], b[1], rtol=1e-12)
        assert a[2] == b[2] == 5
    whole = small.partial_scores(local(chain(40, 5), x, 20, unknown=15), np.random.default_rng(0))
    assert whole[0].shape[1] == 40  # without blocks: the whole component


def test_dec_closed_loop_with_full_information_is_closed_loop_with_blocks():
    problem = chain(40, n_stages=5, passengers=2)
    x = np.random.default_rng(4).poisson(3.0, problem.valid.shape).astype(float)
    view = make_view(problem, 0, np.where(np.arange(5)[None, :] <= 0, x, np.nan), np.zeros_like(problem.valid))
    central = ClosedLoopPlanner(iterations=300, block=8).decide(view, np.random.default_rng(2))
    dec = DecClosedLoopPlanner(iterations=300, block=8)
    got = [dec.decide_local(lv, np.random.default_rng(2)).deploy for lv in local_views(view)]
    np.testing.assert_array_equal(got, enforce(view, central))
    assert BLOCK >= 8
