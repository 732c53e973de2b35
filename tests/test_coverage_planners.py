"""Planners under the coverage reward (issue 35): the random coverage instances, feasibility,
determinism by seed, and the value of planning with coverage."""
import numpy as np
import pytest

from planner import coverage as cov
from planner.instance import random_coverage_instance


def test_random_coverage_instances_are_seeded_and_consistent():
    kwargs = dict(carriers=3, passengers=2, stages=6, overlaps=8, mean=3.0, own=2, reach=1, invalid_fraction=0.2)
    (problem, x), counts = random_coverage_instance(np.random.default_rng(5), **kwargs)
    (_, x2), counts2 = random_coverage_instance(np.random.default_rng(5), **kwargs)
    assert np.array_equal(x, x2, equal_nan=True) and np.array_equal(counts, counts2)
    assert problem.reward == "coverage" and problem.coverage.n_regions == len(counts)
    assert np.array_equal(x, cov.observations(problem.coverage, counts, problem.valid), equal_nan=True)
    own = 2 * int(problem.valid.sum())
    for a in range(problem.valid.size):
        regions = problem.coverage.regions(a)
        assert (len(regions) == 0) == (not problem.valid.flat[a])  # invalid points explore nothing
    shared = [m for m in range(own, problem.coverage.n_regions)
              if sum(m in problem.coverage.regions(a) for a in range(problem.valid.size)) >= 2]
    assert len(problem.overlaps) == len(shared) >= 1
    for group in problem.overlaps:  # reach=1: a shared region's points lie within 1 stage of each other
        stages = [j for _, j in group.tolist()]
        assert max(stages) - min(stages) <= 2
