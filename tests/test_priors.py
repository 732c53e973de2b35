"""planner.priors.Poisson: scipy.stats.poisson's numbers, to the bit, without importing
scipy.stats (a fleet process's prior)."""
import pickle
import subprocess
import sys

import numpy as np
import pytest
import scipy.stats

from planner.priors import Poisson, build_prior, support
from world.paths import REPO_ROOT

MEANS = [0.0, 1e-3, 0.5, 3, 3.5, 7.2, 25.0, 150.3, 2_000.0]
K = [0, 1, 2, 7, 30, 300, 5_000, -1, -0.5, 0.5, 2.5, np.nan, np.inf, -np.inf]
Q = [0.0, 1.0, 1e-15, 1 - 1e-15, 1e-300, 0.1, 0.5, 0.9, 0.999999, np.nan, -0.1, 1.1]


def same(a, b) -> bool:
    """Equal values, NaN where NaN, and the same type, dtype and shape."""
    return (type(a) is type(b) and np.shape(a) == np.shape(b) and np.asarray(a).dtype == np.asarray(b).dtype
            and np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True))


@pytest.mark.filterwarnings("ignore:invalid value encountered in subtract")  # scipy's too: pmf(inf)
@pytest.mark.parametrize("mu", MEANS)
def test_every_number_is_scipys(mu):
    ours, theirs = Poisson(mu), scipy.stats.poisson(mu)
    for method, points in (("pmf", K), ("cdf", K), ("sf", K), ("ppf", Q)):
        for arg in (*points, np.array(points, dtype=float), np.array([[1, 2], [3, 4]]), np.arange(60),
                    np.arange(60, dtype=float).reshape(6, 10) / 3):
            a, b = getattr(ours, method)(arg), getattr(theirs, method)(arg)
            assert same(a, b), (method, mu, arg, a, b)
    for method in ("support", "mean", "var", "std"):
        assert same(getattr(ours, method)(), getattr(theirs, method)()), method
    assert ours.args == theirs.args and ours.kwds == theirs.kwds and ours.dist.name == theirs.dist.name
    assert same(support(ours)[0], support(theirs)[0]) and same(support(ours)[1], support(theirs)[1])


@pytest.mark.parametrize("size", [None, (), 1, 5, (3, 4), [2, 2]])
def test_draws_are_scipys(size):
    for seed in range(4):
        for make in (np.random.default_rng, np.random.RandomState):
            a = Poisson(4.2).rvs(size=size, random_state=make(seed))
            b = scipy.stats.poisson(4.2).rvs(size=size, random_state=make(seed))
            assert same(a, b), (size, seed, make, a, b)
    assert same(Poisson(4.2).rvs(size=3, random_state=7), scipy.stats.poisson(4.2).rvs(size=3, random_state=7))


def test_the_rest_is_asked_of_scipy_and_it_pickles():
    prior = Poisson(3.5)
    assert prior.interval(0.9) == scipy.stats.poisson(3.5).interval(0.9)
    assert prior.expect(lambda v: v * v) == pytest.approx(3.5 + 3.5**2)
    with pytest.raises(AttributeError):
        prior._nothing  # noqa: B018
    copy = pickle.loads(pickle.dumps(prior))
    assert copy.args == (3.5,) and same(copy.pmf(np.arange(9)), prior.pmf(np.arange(9)))
    assert same(build_prior({"kind": "poisson", "mean": 2}).cdf(3), scipy.stats.poisson(2).cdf(3))


def test_a_fleet_process_plans_without_scipy_stats():
    """A scenario's problem and its threshold table (what each carrier's on-board planner and the
    coordinator build) import no scipy.stats: its import is the largest share of a small
    mission's CPU."""
    code = ("import sys, world\n"
            "from planner.ssap import table_for\n"
            "p = world.build_problem(world.load_scenario('scenarios/six_carriers.yaml'))\n"
            "table_for(p)\n"
            "print(sorted(m for m in sys.modules if m.startswith('scipy.stats')))\n")
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO_ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"
