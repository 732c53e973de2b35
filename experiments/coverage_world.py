"""Seeded random coverage worlds for ``python -m experiments coverage`` (issue 35 item 6).

A stand-in for ``planner.instance.random_coverage_instance`` (branch cov-planners): once that
lands, :func:`random_coverage_instance` here should be replaced by it (one import in
:mod:`experiments.coverage`).

The world at overlap level k (the paper's Fig. 2: k overlap groups among R·N decision points):

* every decision point's disc has a **private region** (explored from it alone);
* each of the k overlap groups is a **lens**: one region shared by its 2 or 3 points, drawn
  exactly as :func:`planner.instance.random_instance` draws an overlap group (same stream, same
  draw order: validity, then the groups). The penalty model's view of the world
  (``Coverage.overlaps(N)``) is therefore the penalty sweep's overlap groups of the same stream;
* lens g holds a share ``s_g ~ U(SHARE)`` of a disc's expected features: Poisson(``s_g * mean``);
  a point's private region holds the rest, Poisson(``mean * max(FLOOR, 1 - sum of its lenses'
  shares)``). A point's observation (the sum of its regions' counts) is thus Poisson(``mean``), as
  in the paper, unless its lenses alone hold more than ``1 - FLOOR`` of a disc;
* the realised counts are drawn last, one Poisson per region.

The world is built as a coverage instance document (docs/planner.md, "Coverage reward") and
parsed by :func:`planner.instance.parse_instance_counts`, so the problem's point prior,
normalisation and penalty overlaps are the instance format's own rules.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

#: Range of a lens's share of a disc's expected features: discs that graze to discs that nearly coincide.
SHARE = (0.2, 0.8)
#: Smallest share of a disc's expected features its private region keeps.
FLOOR = 0.1


class CoverageInstance(NamedTuple):
    """A coverage problem, its observations ``x[R, N]`` (sums of counts, NaN = ∅) and the
    realised region counts ``[M]``."""

    problem: object
    observations: np.ndarray
    counts: np.ndarray


def coverage_document(rng: np.random.Generator, carriers: int = 4, passengers: int = 3, stages: int = 10,
                      overlaps: int = 20, mean: float = 3.0, invalid_fraction: float = 0.0) -> dict:
    """The world as a ``reward: coverage`` instance document (module docstring): regions
    ``[private of each valid point in flat order..., lens of each group...]``."""
    n_points = carriers * stages
    valid = rng.random((carriers, stages)) >= invalid_fraction
    groups = [rng.choice(n_points, size=min(int(rng.integers(2, 4)), n_points), replace=False)
              for _ in range(overlaps)]
    shares = rng.uniform(*SHARE, size=overlaps)
    flat_valid = valid.reshape(-1)
    private = {int(a): m for m, a in enumerate(np.flatnonzero(flat_valid))}
    lens_share = np.zeros(n_points)
    lenses: list[list[int]] = [[] for _ in range(n_points)]
    for g, members in enumerate(groups):
        for a in members:
            if flat_valid[a]:  # an invalid point explores nothing
                lenses[a].append(len(private) + g)
                lens_share[a] += shares[g]
    means = [mean * max(FLOOR, 1.0 - lens_share[a]) for a in private] + [mean * s for s in shares]
    counts = rng.poisson(means)
    covers = [[([private[r * stages + j], *lenses[r * stages + j]] if valid[r, j] else None)
               for j in range(stages)] for r in range(carriers)]
    return {"reward": "coverage", "carriers": carriers, "passengers": passengers, "stages": stages,
            "regions": [{"mean": float(m)} for m in means], "covers": covers,
            "counts": [int(c) for c in counts]}


def random_coverage_instance(rng: np.random.Generator, carriers: int = 4, passengers: int = 3, stages: int = 10,
                             overlaps: int = 20, mean: float = 3.0, invalid_fraction: float = 0.0) -> CoverageInstance:
    """A seeded random coverage world (module docstring); the same generator state gives the same
    world. Arguments as :func:`planner.instance.random_instance`'s."""
    from planner.instance import parse_instance_counts

    doc = coverage_document(rng, carriers, passengers, stages, overlaps, mean, invalid_fraction)
    (problem, x), counts, _ = parse_instance_counts(doc, "<random coverage world>")
    return CoverageInstance(problem, x, counts)


def penalty_problem(problem):
    """The penalty model's problem of a coverage world: the same points, passengers, prior and
    normalisation scale, overlap groups ``coverage.overlaps(N)``, no coverage."""
    from planner.problem import Problem

    if problem.coverage is None:
        raise ValueError("penalty_problem: expected a coverage problem, found a penalty one")
    return Problem.build(problem.passengers, problem.valid, problem.coverage.overlaps(problem.n_stages),
                         problem.prior, normalize=problem.scale)
