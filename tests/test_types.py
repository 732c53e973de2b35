"""Passenger types (issue 13): the generalised DLR rule against a brute-force dynamic programme
over (stages left, set of passengers left), the equal-weight reduction to today's SSAP, and
weighted problems through the planners, the clairvoyant bound and the instance format."""
from __future__ import annotations

import itertools
from functools import lru_cache

import numpy as np
import pytest
from scipy import integrate, stats

from planner import priors, ssap
from planner.problem import Problem

WEIGHTS = (1.0, 0.6, 0.6, 0.25)  # a scout, two rovers of one type, a small probe: ties included


class _Discrete:
    """Expectations over a discrete prior by its (truncated) support."""

    def __init__(self, prior):
        self.points, self.mass = priors.support(prior)
        self.points = np.asarray(self.points, dtype=float)

    def expect_max(self, lines):
        """E[max_k (c_k + w_k X)] for lines (c_k, w_k)."""
        c = np.array([line[0] for line in lines])[:, None]
        w = np.array([line[1] for line in lines])[:, None]
        return float(np.dot(self.mass, (c + w * self.points[None, :]).max(axis=0)))

    def grid(self):
        return self.points[self.mass > 1e-9]


class _Continuous:
    """Expectations over a continuous prior by adaptive quadrature between the lines' crossings."""

    def __init__(self, prior):
        self.prior = prior

    def expect_max(self, lines):
        lo, hi = self.prior.support()
        cross = sorted({(c2 - c1) / (w1 - w2) for (c1, w1), (c2, w2) in itertools.combinations(lines, 2)
                        if w1 != w2 and lo < (c2 - c1) / (w1 - w2) < hi})
        edges = [lo] + cross + [hi]
        total = 0.0
        for a, b in zip(edges[:-1], edges[1:]):
            total += integrate.quad(lambda v: max(c + w * v for c, w in lines) * self.prior.pdf(v), a, b,
                                    epsabs=1e-12, epsrel=1e-12, limit=200)[0]
        return total

    def grid(self):
        return self.prior.ppf(np.linspace(0.005, 0.995, 60))


def _options(n, left, weights):
    """The feasible choices at a stage: release passenger i of ``left``, or none unless forced."""
    opts = [(i, left - {i}) for i in sorted(left)]
    if n > len(left):
        opts.append((None, left))
    return opts


def _brute_force(dist, weights, n_max):
    """V(n, S): optimal expected sum of w x over n stages with passengers S left (forced rule)."""

    @lru_cache(maxsize=None)
    def value(n, left):
        if n == 0 or not left:
            return 0.0
        lines = [(value(n - 1, rest), 0.0 if i is None else weights[i]) for i, rest in _options(n, left, weights)]
        return dist.expect_max(lines)

    return value


PRIORS = {
    "poisson3": (stats.poisson(3.0), _Discrete, 1e-9, 8),
    "table": (priors.build_prior({"kind": "table", "values": [0, 1, 2.5, 4, 9],
                                  "probabilities": [0.3, 0.25, 0.2, 0.15, 0.1]}), _Discrete, 1e-9, 8),
    "gamma": (stats.gamma(2.0, scale=1.5), _Continuous, 1e-6, 6),
}


@pytest.mark.parametrize("prior_name", list(PRIORS))
def test_generalised_rule_matches_brute_force(prior_name):
    prior, kind, tol, n_max = PRIORS[prior_name]
    dist = kind(prior)
    weights = WEIGHTS
    value = _brute_force(dist, weights, n_max)
    table = ssap.thresholds(prior, n_max)
    everyone = frozenset(range(len(weights)))
    checked_unique = 0
    for n in range(1, n_max + 1):
        for size in range(0, len(weights) + 1):
            for left in map(frozenset, itertools.combinations(sorted(everyone), size)):
                w_left = np.array([weights[i] for i in sorted(left)])
                # The optimal expected value: the k-th weight times the k-th slot value.
                assert ssap.weighted_value(table, n, w_left) == pytest.approx(value(n, left), abs=tol, rel=tol)
                if not left:
                    continue
                for x in dist.grid():
                    scores = {i: (0.0 if i is None else weights[i] * x) + value(n - 1, rest)
                              for i, rest in _options(n, left, weights)}
                    best = max(scores.values())
                    if ssap.deploys(table, x, n, len(left)):
                        pos = ssap.release(table, x, n, w_left)
                        mine = sorted(left)[pos]
                    else:
                        mine = None
                    assert scores[mine] >= best - 10 * tol, (n, sorted(left), x, mine, scores)
                    ranked = sorted(scores.values(), reverse=True)
                    if len(ranked) == 1 or ranked[0] - ranked[1] > 1e-6:
                        # A unique optimum: the same decision, passenger included (up to equal weights).
                        winner = max(scores, key=scores.get)
                        same = mine == winner or (mine is not None and winner is not None
                                                  and weights[mine] == weights[winner])
                        assert same, (n, sorted(left), x, mine, winner)
                        checked_unique += 1
    assert checked_unique > 100


@pytest.mark.parametrize("prior_name", list(PRIORS))
def test_equal_weights_reduce_to_ssap(prior_name):
    prior, _, _, n_max = PRIORS[prior_name]
    table = ssap.thresholds(prior, n_max)
    for n in range(1, n_max + 1):
        for d in range(1, n_max + 2):
            assert ssap.weighted_value(table, n, np.full(d, 2.0)) == pytest.approx(
                2.0 * ssap.expected_value(table, n, d), rel=1e-12)
            assert ssap.weighted_value(table, n, np.ones(d)) == pytest.approx(ssap.expected_value(table, n, d),
                                                                               rel=1e-12)
            # With equal weights the rank rule releases the lowest index (index order).
            assert ssap.release(table, 1e9, n, np.ones(d)) == 0
            assert ssap.release(table, -1e9, n, np.ones(d)) == 0


def test_rank_twin_matches_python():
    from planner.kernels import rank

    table = ssap.thresholds(stats.poisson(3.0), 12)
    for n in range(1, 13):
        for x in np.arange(-1.0, 12.0, 0.5):
            assert rank(table, x, n) == ssap.rank(table, x, n)


# ----------------------------------------------------------------------------- the clairvoyant bound


def _weighted_brute_force(problem: Problem, x: np.ndarray) -> float:
    """Largest raw total over every offline plan and every assignment of passengers to its points."""
    from planner.problem import evaluate

    valid = problem.valid & ~np.isnan(x)
    per_carrier = []
    for r in range(problem.n_carriers):
        stages = np.flatnonzero(valid[r])
        k = min(int(problem.passengers[r]), len(stages))
        plans = []
        for chosen in itertools.combinations(stages, k):
            for who in itertools.permutations(range(int(problem.passengers[r])), k):
                plans.append((chosen, who))
        per_carrier.append(plans)
    best = -np.inf
    for plan in itertools.product(*per_carrier):
        deployed = np.zeros(valid.shape, dtype=bool)
        released = np.full(valid.shape, -1, dtype=np.int64)
        for r, (stages, who) in enumerate(plan):
            deployed[r, list(stages)] = True
            released[r, list(stages)] = who
        best = max(best, evaluate(problem, deployed, x, released)[1])
    return best


def _weighted_instances(seed: int, count: int, prior):
    rng = np.random.default_rng(seed)
    for _ in range(count):
        carriers, stages = int(rng.integers(1, 4)), int(rng.integers(1, 6))
        valid = rng.random((carriers, stages)) > 0.2
        overlaps = [[[int(rng.integers(carriers)), int(rng.integers(stages))] for _ in range(int(rng.integers(2, 4)))]
                    for _ in range(int(rng.integers(0, 6)))]
        passengers = rng.integers(0, 4, size=carriers)
        weights = [np.round(rng.uniform(0.2, 1.5, size=d), 2).tolist() for d in passengers]
        problem = Problem.build(passengers, valid, overlaps, prior, normalize="none", weights=weights)
        x = problem.prior.rvs(size=valid.shape, random_state=rng).astype(float)
        yield problem, np.where(valid, x, np.nan)


@pytest.mark.parametrize("prior", [stats.poisson(3.0), stats.norm(0.5, 2.0)], ids=["poisson", "normal-negatives"])
def test_weighted_clairvoyant_matches_brute_force(prior):
    from planner import clairvoyant
    from planner.problem import evaluate

    checked = 0
    for problem, x in _weighted_instances(7, 60, prior):
        result = clairvoyant.solve(problem, x)
        assert result.exact
        assert result.features == pytest.approx(_weighted_brute_force(problem, x), abs=1e-9)
        assert evaluate(problem, result.deployed, x, result.released)[1] == pytest.approx(result.features)
        checked += problem.passengers.sum() > 1
    assert checked > 20


def test_weighted_clairvoyant_stays_exact_at_the_papers_size():
    from planner import clairvoyant
    from planner.instance import random_instance

    rng = np.random.default_rng(3)
    for _ in range(20):
        problem, x = random_instance(rng, carriers=4, passengers=3, stages=10, overlaps=20,
                                     weights=[[1.0, 0.6, 0.6]] * 4)
        result = clairvoyant.solve(problem, x)
        assert result.exact
        # Never below the type-blind optimum with its passengers in index order.
        blind = clairvoyant.solve(Problem.build(3, problem.valid, problem.overlaps, problem.prior), x)
        from planner.problem import evaluate

        assert result.features >= evaluate(problem, blind.deployed, x)[1] - 1e-9


# ----------------------------------------------------------------------------- planners


TYPED_PLANNERS = ["random", "ssap", "mcts-random", "mcts-ssap", "closed-loop", "dec-mcts", "dec-closed-loop"]


def _typed_instance(seed, carriers=3, stages=8, overlaps=8):
    from planner.instance import random_instance

    rng = np.random.default_rng(seed)
    return random_instance(rng, carriers=carriers, passengers=3, stages=stages, overlaps=overlaps,
                           weights=[[1.0, 0.6, 0.6], [0.3, 1.0, 0.6], [1.0, 1.0, 0.2]][:carriers])


@pytest.mark.parametrize("name", TYPED_PLANNERS)
def test_every_planner_releases_each_passenger_once_and_deterministically(name):
    from planner.problem import evaluate
    from planner.online import run_online
    from planner.registry import make_planner

    for seed in range(3):
        problem, x = _typed_instance(seed)
        options = {} if name in ("random", "ssap") else {"iterations": 60}
        result = run_online(problem, x, make_planner(name, **options), seed=seed)
        again = run_online(problem, x, make_planner(name, **options), seed=seed)
        assert (result.released == again.released).all() and result.reward == again.reward
        assert ((result.released >= 0) == result.deployed).all()
        for r in range(problem.n_carriers):
            got = result.released[r][result.deployed[r]]
            assert len(set(got.tolist())) == len(got) and (got < problem.passengers[r]).all()
        assert result.reward == pytest.approx(evaluate(problem, result.deployed, x, result.released)[0])


def test_ssap_releases_by_the_rank_rule_and_keeps_its_deployments():
    """SSAP's deployments do not depend on the values (DLR's thresholds do not); which passenger
    goes does: each release is the rank of the observation's interval among those aboard."""
    from planner.passengers import unweighted
    from planner.online import run_online
    from planner.registry import make_planner

    differs = 0
    for seed in range(6):
        problem, x = _typed_instance(seed)
        typed = run_online(problem, x, make_planner("ssap"), seed=0)
        plain = run_online(unweighted(problem), x, make_planner("ssap"), seed=0)
        assert (typed.deployed == plain.deployed).all()
        differs += int((typed.released != plain.released).any())
        table = ssap.table_for(problem)
        n_left = problem.valid[:, ::-1].cumsum(axis=1)[:, ::-1]
        for r in range(problem.n_carriers):
            aboard = list(range(int(problem.passengers[r])))
            for j in np.flatnonzero(typed.deployed[r]):
                w = problem.weights[r, aboard]
                expect = aboard[ssap.release(table, x[r, j], int(n_left[r, j]), w)]
                assert typed.released[r, j] == expect
                aboard.remove(expect)
    assert differs > 0


def test_without_values_everything_is_unweighted():
    """A problem without passenger values releases in index order and no planner reads weights."""
    from planner.instance import random_instance
    from planner.problem import in_order
    from planner.online import run_online
    from planner.registry import make_planner

    problem, x = random_instance(np.random.default_rng(1), carriers=3, passengers=3, stages=8, overlaps=8)
    result = run_online(problem, x, make_planner("closed-loop", iterations=60), seed=2)
    assert (result.released == in_order(result.deployed)).all()


def test_type_aware_beats_type_blind_on_average():
    """Releasing the heavy passenger at the good observations must pay on average (SSAP)."""
    from planner.passengers import TypeBlind
    from planner.online import run_online
    from planner.registry import make_planner

    aware, blind = [], []
    for seed in range(30):
        problem, x = _typed_instance(100 + seed, overlaps=0)
        aware.append(run_online(problem, x, make_planner("ssap"), seed=0).reward)
        blind.append(run_online(problem, x, TypeBlind(make_planner("ssap")), seed=0).reward)
    assert np.mean(aware) > np.mean(blind)


def test_weighted_closed_loop_is_ssap_without_conflicts():
    from planner.online import run_online
    from planner.registry import make_planner

    for seed in range(4):
        problem, x = _typed_instance(seed, overlaps=0)
        a = run_online(problem, x, make_planner("closed-loop", iterations=60), seed=seed)
        b = run_online(problem, x, make_planner("ssap"), seed=seed)
        assert (a.deployed == b.deployed).all() and (a.released == b.released).all()


def test_weighted_choice_rule_reduces_to_the_threshold_rule():
    """The conflict-aware rule with passenger values: equal weights give ``y - loss > a[n, n - d]``."""
    from planner.closedloop import _weighted_choice

    table = ssap.thresholds(stats.poisson(3.0), 10)
    rng = np.random.default_rng(0)
    for _ in range(500):
        n = int(rng.integers(1, 11))
        d = int(rng.integers(1, 4))
        ws = np.zeros((1, 5))
        ws[0, :d] = 1.0
        y, loss = float(rng.uniform(0, 8)), float(rng.uniform(0, 2)) * (rng.random() < 0.5)
        thr = np.zeros((1, 5))  # DLR's thresholds, the rule where no conflict lies ahead
        for k in range(1, min(n, 5)):
            thr[0, k] = table[n, n - k]
        got = _weighted_choice(thr, 0, y, loss, n, d, ws, 0) >= 0
        assert got == bool(ssap.deploys(table, y - loss, n, d))


def test_dec_closed_loop_is_closed_loop_with_perfect_links_and_values():
    from planner.online import run_online
    from planner.registry import make_planner

    for seed in range(3):
        problem, x = _typed_instance(seed)
        a = run_online(problem, x, make_planner("closed-loop", iterations=60), seed=seed)
        b = run_online(problem, x, make_planner("dec-closed-loop", iterations=60), seed=seed)
        assert (a.deployed == b.deployed).all() and (a.released == b.released).all()


@pytest.mark.parametrize("name", ["closed-loop", "dec-closed-loop", "dec-mcts", "ssap"])
def test_planners_with_values_under_lossy_links(name):
    from planner.comms import CommsSpec
    from planner.decentralised import run_comms
    from planner.problem import evaluate
    from planner.registry import make_planner

    problem, x = _typed_instance(5)
    result = run_comms(problem, x, make_planner(name, **({} if name == "ssap" else {"iterations": 60})), seed=3,
                       comms=CommsSpec(loss=0.5, delay=1))
    assert ((result.released >= 0) == result.deployed).all()
    for r in range(problem.n_carriers):
        got = result.released[r][result.deployed[r]]
        assert len(set(got.tolist())) == len(got)
    assert result.reward == pytest.approx(evaluate(problem, result.deployed, x, result.released)[0])


def test_weighted_closed_loop_control_variate_is_unbiased():
    """With passenger values, closed-loop's estimate with the exact weighted SSAP control variate
    ranks joint actions as the plain Monte Carlo mean of its rollouts does (same expectation)."""
    from planner.closedloop import estimate
    from planner.problem import make_view
    from planner.online import run_online
    from planner.registry import make_planner

    problem, x = _typed_instance(11, overlaps=12)
    res = run_online(problem, x, make_planner("closed-loop", iterations=60), seed=0)
    checked = 0
    for j in range(1, 5):
        view = make_view(problem, j, x, res.deployed, res.released)
        acts = np.array(list(itertools.product([False, True], repeat=problem.n_carriers)))
        acts = acts[(acts <= view.can_deploy).all(1) & (acts >= view.must_deploy).all(1)]
        if len(acts) < 2:
            continue
        cv = estimate(view, acts, 20000, np.random.default_rng(1), True)
        mc = estimate(view, acts, 20000, np.random.default_rng(2), False)
        assert np.abs((cv - cv[0]) - (mc - mc[0])).max() < 0.25
        assert np.abs(cv - cv[0]).max() > 0.25  # the actions do differ: the check can fail
        checked += 1
    assert checked >= 2


def test_types_experiment_smoke(tmp_path):
    """``python -m experiments types --quick``: every file, paired variants, the exact weighted
    bound above every planner of its trial."""
    import csv

    from experiments.run import main

    out = tmp_path / "types"
    assert main(["types", "--quick", "--trials", "2", "--iterations", "40", "--jobs", "1", "--no-progress",
                 "--planners", "ssap,closed-loop", "--out", str(out)]) == 0
    for name in ("types_trials.csv", "types_summary.csv", "types.md"):
        assert (out / name).is_file()
    assert (out / "types.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with open(out / "types_trials.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 3 * 2 * (1 + 2 * 3)  # cases x trials x (bound + planners x variants)
    by_trial = {}
    for r in rows:
        by_trial.setdefault((r["level"], r["trial"]), []).append(r)
    for group in by_trial.values():
        assert len({r["planner_seed"] for r in group}) == 1
        bound = next(r for r in group if r["planner"] == "clairvoyant")
        assert all(float(r["reward"]) <= float(bound["reward"]) + 1e-9 for r in group)
        # SSAP's deployments do not depend on the values; type-blind ones release in listed order.
        ssap_rows = {r["variant"]: r for r in group if r["planner"] == "ssap"}
        assert ssap_rows["aware"]["deployed"] == ssap_rows["blind"]["deployed"]
        for part in ssap_rows["blind"]["released"].split("|"):
            got = [int(i) for i in part.split()]
            assert got == list(range(len(got)))


@pytest.mark.parametrize("name", ["mcts-ssap", "closed-loop", "dec-mcts"])
def test_unit_values_decide_as_without_values(name):
    """Passenger values all 1 are the unweighted problem: the same decisions (the weighted
    search paths reduce exactly), and values that differ change some decision (they are read)."""
    from planner.instance import random_instance
    from planner.online import run_online
    from planner.registry import make_planner

    changed = 0
    for seed in range(4):
        rng = np.random.default_rng(seed)
        plain, x = random_instance(rng, carriers=3, passengers=3, stages=8, overlaps=10)
        ones = Problem.build(3, plain.valid, plain.overlaps, plain.prior, weights=[[1.0] * 3] * 3)
        typed = Problem.build(3, plain.valid, plain.overlaps, plain.prior, weights=[[1.0, 0.2, 0.2]] * 3)
        a = run_online(plain, x, make_planner(name, iterations=200), seed=seed)
        b = run_online(ones, x, make_planner(name, iterations=200), seed=seed)
        c = run_online(typed, x, make_planner(name, iterations=200), seed=seed)
        assert (a.deployed == b.deployed).all() and a.reward == pytest.approx(b.reward)
        changed += int((c.deployed != a.deployed).any())
    assert changed > 0


def test_online_optimal_refuses_passenger_values():
    from planner.online_optimal import TooLarge, estimate, online_value

    problem, _ = _typed_instance(0, carriers=2, stages=4, overlaps=1)
    with pytest.raises(TooLarge, match="passenger values"):
        estimate(problem)
    with pytest.raises(TooLarge, match="passenger values"):
        online_value(problem)


def test_learned_prior_keeps_the_released_passengers():
    """learn_prior hands the inner planner the same view (passengers released included)."""
    from planner.learning import LearnedPriorPlanner
    from planner.problem import make_view
    from planner.registry import make_planner

    problem, x = _typed_instance(2)
    deployed = np.zeros(x.shape, dtype=bool)
    deployed[0, 0] = True
    released = np.full(x.shape, -1, dtype=np.int64)
    released[0, 0] = 2
    view = make_view(problem, 3, x, deployed, released)
    inner = LearnedPriorPlanner(make_planner("ssap")).view_for(view)
    assert inner.problem is not problem and (inner.released == view.released).all()
    assert inner.aboard[0].tolist() == [True, True, False]
