"""MCTS-SSAP and MCTS-Random, fast (planner.mcts.fast) and reference (planner.mcts.reference):
feasibility, causality, determinism, the kernel's sampler, fast-vs-reference parity, the optimum
when the future is deterministic, and the paper's ordering MCTS-SSAP > SSAP > Random."""
from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy import stats

from planner.mcts import kernel as kernel
from planner.instance import random_instance
from planner.compiled import compile_problem
from planner.mcts.fast import MCTSPlanner
from planner.mcts.reference import ReferenceMCTSPlanner, feasible_joint_actions
from planner.policies import RandomPlanner, SSAPPlanner
from planner.problem import Problem, evaluate, make_view
from planner.online import run_online
from planner.ssap import table_for

PLANNERS = {
    "fast-ssap": lambda: MCTSPlanner("ssap", iterations=60),
    "fast-random": lambda: MCTSPlanner("random", iterations=60),
    "fast-ssap-samples": lambda: MCTSPlanner("ssap", iterations=30, samples=3),
    "fast-ssap-binary": lambda: MCTSPlanner("ssap", iterations=60, layout="binary"),
    "fast-random-binary": lambda: MCTSPlanner("random", iterations=60, layout="binary"),
    "reference-ssap": lambda: ReferenceMCTSPlanner("ssap", iterations=30),
    "reference-random": lambda: ReferenceMCTSPlanner("random", iterations=30),
}


@pytest.fixture(params=sorted(PLANNERS), ids=sorted(PLANNERS))
def planner(request):
    p = PLANNERS[request.param]()
    if hasattr(p, "warm_up"):
        p.warm_up()
    return p


def _instances(seed: int, count: int):
    """Varied small instances: per-carrier D (zeros too), ∅ stages, self-conflicts, D > stages."""
    rng = np.random.default_rng(seed)
    for _ in range(count):
        carriers = int(rng.integers(1, 6))
        stages = int(rng.integers(1, 9))
        passengers = rng.integers(0, 5, size=carriers).tolist()
        yield random_instance(rng, carriers=carriers, passengers=passengers, stages=stages,
                              overlaps=int(rng.integers(0, 10)), mean=float(rng.uniform(0.5, 5)),
                              invalid_fraction=float(rng.choice([0.0, 0.2, 0.5])))


def test_feasibility_every_passenger_deployed(planner):
    for k, (problem, x) in enumerate(_instances(11, 20)):
        result = run_online(problem, x, planner, seed=k)  # enforce() checks each stage's rules
        valid = ~np.isnan(x)
        assert not (result.deployed & ~valid).any()
        expected = np.minimum(problem.passengers, valid.sum(axis=1))
        assert result.deployed.sum(axis=1).tolist() == expected.tolist()


def test_feasibility_with_online_surprises(planner):
    rng = np.random.default_rng(5)
    for k, (problem, x) in enumerate(_instances(12, 15)):
        x = x.copy()
        x[rng.random(x.shape) < 0.2] = np.nan  # carriers that did not report: ∅ online
        result = run_online(problem, x, planner, seed=k)
        assert not (result.deployed & np.isnan(x)).any()
        assert (result.deployed.sum(axis=1) <= problem.passengers).all()


def test_causality_and_determinism(planner):
    rng = np.random.default_rng(7)
    for k, (problem, x) in enumerate(_instances(13, 10)):
        first = run_online(problem, x, planner, seed=k)
        again = run_online(problem, x, planner, seed=k)
        assert np.array_equal(first.deployed, again.deployed) and first.reward == again.reward
        j = int(rng.integers(problem.n_stages))
        changed = x.copy()
        later = rng.poisson(4.0, size=x.shape).astype(float)
        changed[:, j + 1:] = np.where(np.isnan(x[:, j + 1:]), np.nan, later[:, j + 1:])
        other = run_online(problem, changed, planner, seed=k)
        assert np.array_equal(first.deployed[:, : j + 1], other.deployed[:, : j + 1])


def test_fast_planner_depends_on_the_seed():
    problem, x = random_instance(np.random.default_rng(3), carriers=4, passengers=3, stages=10, overlaps=20)
    planner = MCTSPlanner("random", iterations=50)
    runs = {run_online(problem, x, planner, seed=s).deployed.tobytes() for s in range(8)}
    assert len(runs) > 1  # the seed reaches the kernel's random stream


def test_plan_ms_mode_runs_iterations_and_stays_feasible():
    problem, x = random_instance(np.random.default_rng(4), carriers=6, passengers=3, stages=10, overlaps=10)
    # 50 ms: several chunks even on a core shared with two other processes (with 5 ms a worker of
    # the default suite's three on two cores was once preempted through the whole budget)
    planner = MCTSPlanner("ssap", plan_ms=50.0)
    planner.warm_up(problem)
    view = make_view(problem, 0, x, np.zeros(problem.valid.shape, dtype=bool))
    decision = planner.decide(view, np.random.default_rng(0))
    assert planner.last_iterations > kernel_first_chunk()
    assert decision.shape == (6,) and not (decision & ~view.can_deploy).any()
    assert planner.last_nodes <= planner.last_iterations + 1


def test_plan_ms_mode_joint_layout_grows_its_tree():
    problem, x = random_instance(np.random.default_rng(4), carriers=6, passengers=3, stages=10, overlaps=10)
    planner = MCTSPlanner("ssap", plan_ms=60.0, layout="joint")
    planner.warm_up(problem)
    view = make_view(problem, 0, x, np.zeros(problem.valid.shape, dtype=bool))
    decision = planner.decide(view, np.random.default_rng(0))
    assert planner.last_layout == "joint"
    assert planner.last_reserved > 1 + 64 + 16 * 4096 or planner.last_iterations < 4096  # grown when needed
    assert planner.last_nodes <= planner.last_iterations + 1
    assert not (decision & ~view.can_deploy).any() and not (view.must_deploy & ~decision).any()


def test_layout_choice_and_validation():
    small, _ = random_instance(np.random.default_rng(1), carriers=8, passengers=3, stages=10, overlaps=10)
    large, _ = random_instance(np.random.default_rng(1), carriers=9, passengers=3, stages=10, overlaps=10)
    assert MCTSPlanner().layout_for(small) == "joint" and MCTSPlanner().layout_for(large) == "binary"
    assert MCTSPlanner(layout="binary").layout_for(small) == "binary"
    with pytest.raises(ValueError, match="layout"):
        MCTSPlanner(layout="tree")
    wide, x = random_instance(np.random.default_rng(2), carriers=20, passengers=3, stages=10, overlaps=5)
    view = make_view(wide, 0, x, np.zeros(wide.valid.shape, dtype=bool))
    with pytest.raises(ValueError, match="at most 16"):
        MCTSPlanner(iterations=10, layout="joint").decide(view, np.random.default_rng(0))


def test_joint_layout_expands_every_root_action_once_in_a_seeded_order():
    """With 2^k iterations at a root of k choice carriers, the root's children are exactly the 2^k
    joint actions (a permutation: none repeated, none missing), and the order depends on the seed."""
    problem = Problem.build(3, np.ones((4, 6), dtype=bool), [[(0, 0), (1, 0)], [(2, 1), (3, 1)]])
    x = np.full((4, 6), 2.0)
    view = make_view(problem, 0, x, np.zeros((4, 6), dtype=bool))
    orders = set()
    for seed in range(4):
        planner = MCTSPlanner("ssap", iterations=16, layout="joint")
        planner.decide(view, np.random.default_rng(seed))
        tree = planner._joint_tree
        assert tree.expanded[0] == 16 and (tree.visits[tree.base[0]:tree.base[0] + 16] == 1).all()
        order = tuple((int(tree.mult[0]) * i + int(tree.offset[0])) % 16 for i in range(16))
        assert sorted(order) == list(range(16))
        orders.add(order)
    assert len(orders) > 1


def test_joint_layout_node_count_and_arrays_do_not_depend_on_earlier_decisions():
    """A decision on the node arrays an earlier, larger one left behind reports the nodes it
    created, as a fresh planner does; warm_up(problem) allocates the arrays its decisions use."""
    problem, x = random_instance(np.random.default_rng(4), carriers=6, passengers=3, stages=10, overlaps=10)
    view = make_view(problem, 0, x, np.zeros(problem.valid.shape, dtype=bool))
    used = MCTSPlanner("ssap", iterations=3000, layout="joint")
    used.warm_up(problem)
    arrays = used._joint_tree
    used.decide(view, np.random.default_rng(1))
    assert used._joint_tree is arrays  # sized by warm_up: the decision allocated nothing
    used.iterations = 40
    fresh = MCTSPlanner("ssap", iterations=40, layout="joint")
    assert np.array_equal(used.decide(view, np.random.default_rng(2)), fresh.decide(view, np.random.default_rng(2)))
    assert used.last_nodes == fresh.last_nodes <= 41
    assert used.last_reserved == fresh.last_reserved


def kernel_first_chunk() -> int:
    from planner.mcts.fast import FIRST_CHUNK

    return FIRST_CHUNK


def test_large_fleet_tree_is_bounded_by_iterations():
    problem, x = random_instance(np.random.default_rng(6), carriers=32, passengers=3, stages=10, overlaps=10)
    planner = MCTSPlanner("ssap", iterations=500)
    view = make_view(problem, 0, x, np.zeros(problem.valid.shape, dtype=bool))
    decision = planner.decide(view, np.random.default_rng(1))
    assert decision.shape == (32,)
    assert planner.last_nodes <= 501  # one node per iteration at most: 2^32 actions never built


@pytest.mark.parametrize("prior", [stats.poisson(3.0), stats.binom(8, 0.3), stats.gamma(2.0, scale=1.5)],
                         ids=["poisson", "binom", "gamma"])
def test_kernel_sampler_matches_the_prior(prior):
    problem = Problem.build(1, np.ones((1, 2), dtype=bool), prior=prior)
    sampler = compile_problem(problem).sampler
    points, cdf, guide = sampler.points, sampler.cdf, sampler.guide
    draws = kernel.sample_many(np.array([12345], dtype=np.uint64), points, cdf, guide, 200_000)
    assert abs(draws.mean() - prior.mean()) < 5 * prior.std() / np.sqrt(len(draws))
    if hasattr(prior.dist, "pmf"):
        for v in range(int(points[0]), int(points[0]) + 6):
            freq = np.mean(draws == v)
            p = prior.pmf(v)
            assert abs(freq - p) < 5 * np.sqrt(p * (1 - p) / len(draws)) + 1e-12
    else:
        for q in (0.1, 0.5, 0.9):
            assert abs(np.mean(draws <= prior.ppf(q)) - q) < 0.005


def test_threshold_cdf_decides_like_the_threshold():
    for prior in (stats.poisson(3.0), stats.gamma(2.0, scale=1.5)):
        problem = Problem.build(3, np.ones((1, 10), dtype=bool), prior=prior)
        sampler = compile_problem(problem).sampler
        points, cdf, guide = sampler.points, sampler.cdf, sampler.guide
        table, ucut = table_for(problem), compile_problem(problem).ucut
        us = np.linspace(0, 1, 2001, endpoint=False)
        xs = kernel.quantiles(us, points, cdf, guide)
        for n in range(2, 11):
            for i in range(1, n):
                assert np.array_equal(us >= ucut[n, i], xs > table[n, i]), (n, i)


def test_feasible_joint_actions_contain_forced_and_only_allowed():
    can = np.array([True, True, False, True])
    must = np.array([False, True, False, False])
    actions = feasible_joint_actions(can, must)
    assert len(actions) == 4 and len(set(actions)) == 4
    for a in actions:
        assert a & 0b0010 and not a & 0b0100


# ----------------------------------------------------------------------------- quality


def test_fast_matches_reference_quality():
    """Fast planner (default layout: joint at this size) vs the reference: same mean reward within noise.

    Paired over instances and seeds; the tolerance (3 standard errors of the paired difference)
    is required to be well below the gap between MCTS-SSAP and random deployments, so the test
    can tell a broken planner from a matching one.
    """
    fast = MCTSPlanner("ssap", iterations=200)
    fast.warm_up()
    ref = ReferenceMCTSPlanner("ssap", iterations=200)
    f, r, rnd = [], [], []
    for k in range(16):
        problem, x = random_instance(np.random.default_rng(500 + k), carriers=3, passengers=2, stages=6,
                                     overlaps=6)
        f.append(run_online(problem, x, fast, seed=k).reward)
        r.append(run_online(problem, x, ref, seed=k).reward)
        rnd.append(run_online(problem, x, RandomPlanner(), seed=k).reward)
    f, r, rnd = map(np.asarray, (f, r, rnd))
    diff = f - r
    tolerance = 3 * diff.std(ddof=1) / np.sqrt(len(diff)) + 1e-9
    assert abs(diff.mean()) <= tolerance, (f.mean(), r.mean(), tolerance)
    assert tolerance < 0.5 * (r.mean() - rnd.mean()), (tolerance, r.mean(), rnd.mean())


def _brute_force_optimum(problem: Problem, x: np.ndarray) -> float:
    """Best normalised reward over every full deployment (each carrier uses min(D, valid) stages)."""
    valid = ~np.isnan(x)
    options = []
    for r in range(problem.n_carriers):
        stages = np.flatnonzero(valid[r])
        options.append(list(itertools.combinations(stages, min(int(problem.passengers[r]), len(stages)))))
    best = -np.inf
    for choice in itertools.product(*options):
        deployed = np.zeros(problem.valid.shape, dtype=bool)
        for r, stages in enumerate(choice):
            deployed[r, list(stages)] = True
        best = max(best, evaluate(problem, deployed, x)[0])
    return best


@pytest.mark.parametrize("planner_cls", [MCTSPlanner, ReferenceMCTSPlanner], ids=["fast", "reference"])
def test_mcts_ssap_finds_the_optimum_when_the_future_is_known(planner_cls):
    """A point-mass prior makes every future observation certain, so open-loop = closed-loop and
    the online MCTS-SSAP must reach the offline optimum (only stage 0's values vary).

    UCT backs up means, not maxima: with the default constant (0.05·√2, nearly greedy on rewards
    of order 1) a child whose subtree holds the optimum behind poor rollouts can stay unvisited
    (seen on the first instance here, by both implementations). A larger constant makes the
    search explore enough to be exact on these tiny trees."""
    try:
        from planner.clairvoyant import solve as clairvoyant_solve
    except ImportError:  # pragma: no cover - the module belongs to the planner core
        clairvoyant_solve = None
    rng = np.random.default_rng(21)
    level = 2
    prior = stats.randint(level, level + 1)  # P(X = 2) = 1
    planner = planner_cls("ssap", iterations=1500, exploration=2.0)
    for k in range(6 if planner_cls is MCTSPlanner else 3):
        carriers, stages = 2 + k % 2, 5
        valid = rng.random((carriers, stages)) > 0.15
        groups = [[(int(rng.integers(carriers)), int(rng.integers(stages))) for _ in range(3)] for _ in range(4)]
        problem = Problem.build(rng.integers(1, 3, size=carriers).tolist(), valid, groups, prior)
        x = np.where(valid, float(level), np.nan)
        x[:, 0] = np.where(valid[:, 0], rng.integers(0, 6, size=carriers), np.nan)
        best = _brute_force_optimum(problem, x)
        if clairvoyant_solve is not None:
            assert clairvoyant_solve(problem, x).reward == pytest.approx(best)
        result = run_online(problem, x, planner, seed=k)
        assert result.reward == pytest.approx(best), (k, result.deployed.astype(int).tolist())


def test_paper_ordering_mcts_ssap_beats_ssap_beats_random():
    """30 seeded instances, R = 4, D = 3, N = 10, 20 overlaps, 2,000 iterations per stage."""
    mcts = MCTSPlanner("ssap", iterations=2000)
    mcts.warm_up()
    totals = {"mcts-ssap": [], "ssap": [], "random": []}
    for k in range(30):
        problem, x = random_instance(np.random.default_rng(900 + k), carriers=4, passengers=3, stages=10,
                                     overlaps=20)
        totals["mcts-ssap"].append(run_online(problem, x, mcts, seed=k).reward)
        totals["ssap"].append(run_online(problem, x, SSAPPlanner(), seed=k).reward)
        totals["random"].append(run_online(problem, x, RandomPlanner(), seed=k).reward)
    means = {name: float(np.mean(v)) for name, v in totals.items()}
    assert means["mcts-ssap"] > means["ssap"] > means["random"], means
