"""Seeded random coverage worlds for ``python -m experiments coverage`` (issue 35 item 6).

Stand-ins, until branch cov-planners lands, for ``planner.instance.random_coverage_instance`` and
``planner.instance.penalty_twin`` as that branch defines them (commit 83109a7): the same
signatures, the same draws in the same order, so the same seed gives the same world, and
swapping the import in :mod:`experiments.coverage` for the shared functions leaves every
committed row of the experiment unchanged (``python -m experiments check`` tells). Delete this
module then.

The world (combinatorial, no geometry): every valid decision point's disc has ``own`` regions
nobody else explores, each Poisson(``mean / own``), so a point that shares nothing observes
Poisson(``mean``) as in the paper; ``overlaps`` shared regions (the overlap level), each explored
by 2 or 3 distinct valid points (the first uniform among the valid points, the others uniform
among the valid points within ``reach`` stages of it, or all valid points when ``reach`` is None),
each Poisson(``mean / own``) too (a lens about the size of one own cell). Draw order: validity,
shared regions, counts.
"""
from __future__ import annotations

import numpy as np


def point_prior_spec(coverage, valid: np.ndarray) -> dict:
    """The pooled prior of a coverage problem's observations: Poisson of the mean, over the valid
    points, of the sum of a point's region means (Poisson(3) when no point explores any)."""
    sums = np.diff(np.concatenate([[0.0], np.cumsum(coverage.means[coverage.idx])])[coverage.ptr])
    point_mean = float(sums[np.asarray(valid).ravel()].mean()) if np.any(valid) else 0.0
    return {"kind": "poisson", "mean": point_mean if point_mean > 0 else 3.0}


def random_coverage_instance(rng: np.random.Generator, carriers: int = 4, passengers: int | list[int] = 3,
                             stages: int = 10, overlaps: int = 20, mean: float = 3.0, own: int = 2,
                             reach: int | None = None, invalid_fraction: float = 0.0, weights=None):
    """``(Instance(problem, x), counts)``: a random coverage world (module docstring);
    ``problem.overlaps`` its penalty view (one group per shared region), ``counts`` float ``[M]``."""
    from planner import coverage as cov
    from planner import priors
    from planner.instance import Instance
    from planner.problem import Problem

    if own < 1:
        raise ValueError(f"own must be >= 1 (regions of a point's own disc), got {own}")
    valid = rng.random((carriers, stages)) >= invalid_fraction
    points = np.flatnonzero(valid.ravel())
    covers: list[list[int]] = [[] for _ in range(carriers * stages)]
    for i, a in enumerate(points):
        covers[a] = list(range(i * own, (i + 1) * own))
    n_own = own * len(points)
    shared = overlaps if len(points) >= 2 else 0
    for k in range(shared):
        first = int(rng.choice(points))
        near = points if reach is None else points[np.abs(points % stages - first % stages) <= reach]
        near = near[near != first]
        size = min(int(rng.integers(2, 4)) - 1, len(near))
        for a in [first, *rng.choice(near, size=size, replace=False).tolist()] if size else [first]:
            covers[a].append(n_own + k)
    region_prior = priors.build_prior({"kind": "poisson", "mean": mean / own})
    grid = [[covers[r * stages + j] if valid[r, j] else None for j in range(stages)] for r in range(carriers)]
    coverage = cov.Coverage.build(grid, [region_prior] * (n_own + shared))
    problem = Problem.build(passengers, valid, coverage.overlaps(stages),
                            priors.build_prior(point_prior_spec(coverage, valid)), weights=weights, coverage=coverage)
    counts = cov.sample_counts(coverage, rng)
    return Instance(problem, cov.observations(coverage, counts, valid)), counts


def penalty_twin(problem):
    """The penalty model's problem of a coverage world: the same passengers, schedule, prior (so
    the same scale) and passenger values, one overlap group per shared region, the 1/p reward."""
    from planner.problem import Problem

    return Problem(problem.passengers, problem.valid, problem.overlaps, problem.prior, problem.scale,
                   problem.conflict, problem.weights)
