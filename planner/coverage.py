"""The coverage reward (issue 35): deployments valued by the features they cover together.

The paper charges overlapping deployments a 1/p penalty; under ``reward: coverage`` a passenger
released by carrier r at stage j explores a fixed set of *regions* (the cells of the arrangement
of the candidate discs), and a set of deployments is worth the features in the union of the
regions it explores, each region counted once.

Pure numpy (scipy only through the region priors given to it); imports nothing of the package,
so :mod:`planner.problem` can hold a :class:`Coverage` without a cycle.

Rules:

* **Value.** ``value = sum over regions m of counts[m] * best[m]`` where ``best[m]`` is the
  largest weight among the deployed passengers whose disc covers m (0 when none does). Without
  passenger values every weight is 1 and this is the sum of the counts over the union of the
  covered regions. With passenger values (types) a region explored by several passengers is worth
  the best of them once: exploring it again with a lighter passenger adds nothing, with a heavier
  one adds the difference.
* **Marginal gain** of one more deployment with weight w at flat point a:
  ``sum over m in covers(a) of counts[m] * max(0, w - best[m])``; it reads only the regions the
  point touches (the CSR lists :attr:`Coverage.ptr` / :attr:`Coverage.idx`), so adding a
  deployment costs time proportional to its regions, not to all regions.
* **Observations.** A carrier's observation at a valid stage is the sum of the counts of the
  regions its disc covers (:func:`observations`), so ``x[r, j]`` keeps its meaning for every
  planner that reads observations.
* **Prior.** Counts of distinct regions are independent, region m's from its own prior
  (Poisson(mean) from the instance's ``{"mean": mu}``): :func:`sample_counts`. An observation
  reveals the counts of the regions its disc covers (:func:`revealed`); a planner's future keeps
  those and draws the rest from their priors (:func:`sample_counts_given`), which is exact since
  distinct regions are independent.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np


class PoissonPriors(Sequence):
    """Poisson(mean) priors of M regions, each a :class:`planner.priors.Poisson` made only when
    asked for (then kept): the Poisson paths read the means alone."""

    def __init__(self, means):
        self.means = np.array(means, dtype=float)
        self.means.setflags(write=False)
        self._frozen: dict[int, Any] = {}

    def __len__(self) -> int:
        return len(self.means)

    def __getitem__(self, m):
        if isinstance(m, slice):
            return [self[i] for i in range(len(self))[m]]
        m = range(len(self))[m]  # IndexError past the end, as a tuple's
        frozen = self._frozen.get(m)
        if frozen is None:
            from planner.priors import Poisson

            frozen = self._frozen.setdefault(m, Poisson(float(self.means[m])))
        return frozen


@dataclass(frozen=True, eq=False)
class Coverage:
    """The regions and which decision points explore them (everything known in advance).

    Attributes:
        priors: one frozen scipy.stats distribution per region (M of them), the prior of its
            feature count (:class:`PoissonPriors`: frozen when asked for).
        means: float ``[M]``: each region's prior mean count.
        ptr: int64 ``[R*N + 1]`` and idx: int64 ``[ptr[-1]]``: CSR lists; the regions explored
            by a passenger released at flat point ``a = r * N + j`` are ``idx[ptr[a]:ptr[a+1]]``
            (empty at an invalid stage). Each list is sorted and duplicate-free.
        poisson: whether every region prior is Poisson (drawn in one vectorised call).
    """

    priors: Sequence[Any]
    means: np.ndarray
    ptr: np.ndarray
    idx: np.ndarray
    poisson: bool

    @staticmethod
    def build(covers: Sequence[Sequence[Sequence[int] | None]], priors: Sequence[Any]) -> "Coverage":
        """From ``covers[r][j]`` (region indices, or None at an invalid stage) and the region priors
        (frozen scipy.stats distributions, or :class:`PoissonPriors`).

        Raises:
            ValueError: a region index outside ``0..M-1``.
        """
        n_regions = len(priors)
        lists = [sorted(set(int(m) for m in (cell or ()))) for row in covers for cell in row]
        for a, regions in enumerate(lists):
            if regions and not (0 <= regions[0] and regions[-1] < n_regions):
                raise ValueError(f"point {a}: region indices must lie in 0..{n_regions - 1}, got {regions}")
        ptr = np.zeros(len(lists) + 1, dtype=np.int64)
        ptr[1:] = np.cumsum([len(regions) for regions in lists])
        idx = np.array([m for regions in lists for m in regions], dtype=np.int64)
        if isinstance(priors, PoissonPriors):
            means, poisson = priors.means, True
        else:
            priors = tuple(priors)
            means = np.array([float(p.mean()) for p in priors])
            poisson = all(getattr(p.dist, "name", "") == "poisson" for p in priors)
        for arr in (ptr, idx, means):
            arr.setflags(write=False)
        return Coverage(priors, means, ptr, idx, poisson)

    @property
    def n_regions(self) -> int:
        return len(self.priors)

    def regions(self, point: int) -> np.ndarray:
        """int64: the regions explored from flat point ``point``."""
        return self.idx[self.ptr[point]:self.ptr[point + 1]]

    def overlaps(self, n_stages: int) -> list[list[list[int]]]:
        """The penalty model's view of the same geometry: one overlap group of ``[carrier, stage]``
        pairs per region explored from two or more points (what a planner that plans with the 1/p
        penalty treats as conflicting)."""
        points = np.repeat(np.arange(len(self.ptr) - 1), np.diff(self.ptr))
        order = np.argsort(self.idx, kind="stable")
        groups = []
        for region_points in np.split(points[order], np.cumsum(np.bincount(self.idx, minlength=self.n_regions))[:-1]):
            if len(region_points) >= 2:
                groups.append([[int(a) // n_stages, int(a) % n_stages] for a in region_points])
        return groups


def best_weights(coverage: Coverage, deployed: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """float ``[M]``: each region's largest weight among the deployed passengers covering it (0
    when none does). ``deployed``: bool ``[R, N]``; ``weights``: float ``[R, N]`` weight of the
    passenger released at each point (:func:`planner.problem.point_weights`), None = all 1."""
    best = np.zeros(coverage.n_regions)
    flat = np.asarray(deployed, dtype=bool).reshape(-1)
    w = None if weights is None else np.asarray(weights, dtype=float).reshape(-1)
    for a in np.flatnonzero(flat):
        regions = coverage.regions(a)
        best[regions] = np.maximum(best[regions], 1.0 if w is None else w[a])
    return best


def value(coverage: Coverage, deployed: np.ndarray, counts: np.ndarray, weights: np.ndarray | None = None) -> float:
    """The coverage value of a set of deployments: ``sum counts[m] * best[m]`` (module docstring).

    Args:
        deployed: bool ``[R, N]``.
        counts: float ``[M]``: the feature count of every region.
        weights: float ``[R, N]`` passenger weight per point, or None (every passenger weighs 1).
    """
    return float(np.dot(np.asarray(counts, dtype=float), best_weights(coverage, deployed, weights)))


def marginal_gain(coverage: Coverage, best: np.ndarray, point: int, counts: np.ndarray, weight: float = 1.0) -> float:
    """The value added by one more deployment of weight ``weight`` at flat point ``point`` on top
    of the regions' current ``best`` weights (:func:`best_weights`); reads only its regions."""
    regions = coverage.regions(point)
    return float(np.dot(counts[regions], np.maximum(weight - best[regions], 0.0)))


def add(coverage: Coverage, best: np.ndarray, point: int, weight: float = 1.0) -> None:
    """Record a deployment of weight ``weight`` at flat point ``point`` in ``best`` (in place)."""
    regions = coverage.regions(point)
    best[regions] = np.maximum(best[regions], weight)


def observations(coverage: Coverage, counts: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """float ``[R, N]``: each valid point's observation, the sum of its regions' counts; NaN elsewhere."""
    counts = np.asarray(counts, dtype=float)
    sums = np.add.reduceat(np.append(counts[coverage.idx], 0.0), coverage.ptr[:-1]) if len(coverage.idx) else None
    x = np.zeros(valid.size) if sums is None else np.where(np.diff(coverage.ptr) > 0, sums, 0.0)
    return np.where(valid, x.reshape(valid.shape), np.nan)


def sample_counts(coverage: Coverage, rng: np.random.Generator) -> np.ndarray:
    """float ``[M]``: independent draws of every region's count from its prior."""
    if coverage.poisson:
        return rng.poisson(coverage.means).astype(float)
    return np.array([float(p.rvs(random_state=rng)) for p in coverage.priors])


def revealed(coverage: Coverage, x: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """float ``[M]``: the counts an observer knows, NaN for the others.

    An observation at point a reveals the count of every region a's disc covers (issue 35: a
    carrier observes region counts; ``x[r, j]`` is their sum). ``x``: float ``[R, N]``, NaN where
    nothing was observed (∅, or a stage not reached yet); ``counts``: float ``[M]`` the realised
    counts (only the revealed entries are read).
    """
    seen = np.flatnonzero(~np.isnan(np.asarray(x, dtype=float)).reshape(-1))
    mask = np.zeros(coverage.n_regions, dtype=bool)
    if len(seen):
        starts, stops = coverage.ptr[seen], coverage.ptr[seen + 1]
        lengths = stops - starts
        if lengths.sum():
            offsets = np.repeat(starts - np.cumsum(lengths) + lengths, lengths) + np.arange(lengths.sum())
            mask[coverage.idx[offsets]] = True
    return np.where(mask, np.asarray(counts, dtype=float), np.nan)


def sample_counts_given(coverage: Coverage, known: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """float ``[M]``: a future consistent with what is known: the revealed counts as they are
    (``known``, NaN where unrevealed: :func:`revealed`), the others drawn from their priors.
    Exact: the counts of distinct regions are independent, so what was revealed says nothing of
    the rest. The prior draw is made for every region (then overwritten), so the stream consumed
    does not depend on what was revealed."""
    counts = sample_counts(coverage, rng)
    known = np.asarray(known, dtype=float)
    return np.where(np.isnan(known), counts, known)
