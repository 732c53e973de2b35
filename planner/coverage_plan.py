"""What the planners derive from a coverage problem (issue 35), built once per problem.

``plan_for(problem)`` returns the problem's :class:`CoveragePlan` (cached with the problem object):

* **Point priors.** A point's observation ``x`` is the sum of its regions' counts, which are
  independent, so its prior is their convolution: Poisson(sum of the means) when every region is
  Poisson, the convolution of the regions' supports otherwise (:func:`point_support`). Points
  differ (a point with a shared lens explores more), so SSAP's thresholds are per point.
* **Per-point DLR thresholds.** DLR's rule holds for independent, not identically distributed
  observations (Derman, Lieberman & Ross 1972): for carrier r with scheduled valid stages
  ``s_1 < ... < s_K``, the thresholds at ``s_k`` (``n = K - k + 1`` stages left) are
  ``T_k[0] = -inf``, ``T_k[n] = +inf`` and ``T_k[i] = E[min(max(X_{s_{k+1}}, T_{k+1}[i-1]),
  T_{k+1}[i])]``: each stage's thresholds read the priors of the stages after it only. They depend
  on the schedule, not on what was observed, so they are computed once; a carrier with ``d``
  passengers deploys at ``s_k`` iff forced or its value exceeds ``cut(T_k[n - d])``
  (:func:`planner.ssap.cut`). Sums are correctly rounded (:func:`math.fsum`), as in
  :mod:`planner.ssap`.
* **Region samplers.** Each region's prior as an inverse-CDF table (CSR ``rptr``/``rpoints``/
  ``rcdf``) for the kernels that draw futures.
"""
from __future__ import annotations

import math
import weakref
from dataclasses import dataclass

import numpy as np

from planner import priors, ssap
from planner.problem import Problem

#: Point-prior mass below this is dropped from a convolution's tails (as ``priors.TAIL``).
TAIL = priors.TAIL


def _region_support(prior) -> tuple[np.ndarray, np.ndarray]:
    points, mass = priors.support(prior)
    keep = mass > 0
    return points[keep], mass[keep]


def point_support(coverage, point: int) -> tuple[np.ndarray, np.ndarray]:
    """The prior of flat point ``point``'s observation (the sum of its regions' independent
    counts) as support points float ``[K]`` ascending and their masses float ``[K]``: Poisson of
    the summed means when every region is Poisson, else the convolution of the region supports."""
    regions = coverage.regions(point)
    if len(regions) == 0:
        return np.zeros(1), np.ones(1)
    if coverage.poisson:
        return _region_support(priors.build_prior({"kind": "poisson", "mean": float(coverage.means[regions].sum())}))
    points, mass = np.zeros(1), np.ones(1)
    for m in regions.tolist():
        rp, rm = _region_support(coverage.priors[m])
        sums, inverse = np.unique(np.add.outer(points, rp).ravel(), return_inverse=True)
        merged = np.bincount(inverse, weights=np.multiply.outer(mass, rm).ravel(), minlength=len(sums))
        keep = merged > TAIL * 1e-3
        points, mass = sums[keep], merged[keep]
    return points, mass


def _clipped_means(points: np.ndarray, mass: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """``E[min(max(X, lo_i), hi_i)]`` for each pair, X on ``points`` with ``mass`` (fsum rows)."""
    clipped = np.clip(points[None, :], lo[:, None], hi[:, None]) * mass[None, :]
    return np.array([math.fsum(row) for row in clipped.tolist()])


def carrier_thresholds(supports: list[tuple[np.ndarray, np.ndarray]]) -> list[np.ndarray]:
    """The DLR thresholds of one carrier's valid stages in order (module docstring), raw (no tie
    margin): entry k is float ``[n + 1]`` for the k-th stage, ``n = K - k`` stages left after it
    plus itself. ``supports``: each stage's observation prior (:func:`point_support`)."""
    n_valid = len(supports)
    out: list[np.ndarray] = [np.empty(0)] * n_valid
    nxt = np.array([-np.inf, np.inf])
    for k in range(n_valid - 1, -1, -1):
        if k < n_valid - 1:
            points, mass = supports[k + 1]
            inner = _clipped_means(points, mass, nxt[:-1], nxt[1:])  # i = 1..n-1
            nxt = np.concatenate([[-np.inf], inner, [np.inf]])
        out[k] = nxt
    return out


@dataclass(frozen=True, eq=False)
class CoveragePlan:
    """The arrays the coverage planners read (module docstring); int64/float64, read-only.

    Attributes:
        ptr, idx: the problem's CSR point -> regions lists (:class:`planner.coverage.Coverage`).
        tptr: ``[R*N + 1]``; thr: ``[tptr[-1]]``: point a's thresholds with their tie margin
            (``cut(T[i])``, i = 0..n_a) are ``thr[tptr[a]:tptr[a + 1]]`` (empty at an invalid stage).
        rptr: ``[M + 1]``; rpoints, rcdf: region m's support and CDF (last entry 1.0) are
            ``rpoints[rptr[m]:rptr[m + 1]]``, ``rcdf[...]``.
    """

    ptr: np.ndarray
    idx: np.ndarray
    tptr: np.ndarray
    thr: np.ndarray
    rptr: np.ndarray
    rpoints: np.ndarray
    rcdf: np.ndarray

    def threshold(self, point: int, n: int, d: int) -> float:
        """The value a deployment at ``point`` with ``n`` valid stages and ``d`` passengers left
        must exceed (the tie margin included): ``cut(T[n - d])``."""
        return float(self.thr[self.tptr[point] + n - d])

    def deploys(self, point: int, value: float, n: int, d: int) -> bool:
        """The per-point threshold rule: forced (``n <= d``) or ``value`` above the threshold."""
        return n <= d or value > self.threshold(point, n, d)


def _build(problem: Problem) -> CoveragePlan:
    coverage = problem.coverage
    n_carriers, n_stages = problem.valid.shape
    rows: list[np.ndarray] = [np.empty(0)] * (n_carriers * n_stages)
    cache: dict = {}
    for r in range(n_carriers):
        stages = np.flatnonzero(problem.valid[r]).tolist()
        supports = []
        for j in stages:
            key = tuple(coverage.regions(r * n_stages + j).tolist()) if not coverage.poisson else \
                float(coverage.means[coverage.regions(r * n_stages + j)].sum())
            if key not in cache:
                cache[key] = point_support(coverage, r * n_stages + j)
            supports.append(cache[key])
        for j, t in zip(stages, carrier_thresholds(supports)):
            rows[r * n_stages + j] = np.array([ssap.cut(v) for v in t.tolist()])
    tptr = np.zeros(len(rows) + 1, dtype=np.int64)
    tptr[1:] = np.cumsum([len(t) for t in rows])
    thr = np.concatenate(rows) if tptr[-1] else np.zeros(0)
    regions = [_region_support(p) for p in coverage.priors]
    rptr = np.zeros(len(regions) + 1, dtype=np.int64)
    rptr[1:] = np.cumsum([len(p) for p, _ in regions])
    rpoints = np.concatenate([p for p, _ in regions])
    rcdf = np.concatenate([np.cumsum(m) / math.fsum(m.tolist()) for _, m in regions])
    rcdf[rptr[1:] - 1] = 1.0  # a uniform in [0, 1) always finds a point
    arrays = (np.ascontiguousarray(coverage.ptr, dtype=np.int64), np.ascontiguousarray(coverage.idx, dtype=np.int64),
              tptr, np.ascontiguousarray(thr, dtype=np.float64), rptr,
              np.ascontiguousarray(rpoints, dtype=np.float64), np.ascontiguousarray(rcdf, dtype=np.float64))
    for arr in arrays:
        arr.setflags(write=False)
    return CoveragePlan(*arrays)


_PLANS: "weakref.WeakKeyDictionary[Problem, CoveragePlan]" = weakref.WeakKeyDictionary()


def plan_for(problem: Problem) -> CoveragePlan:
    """The coverage problem's :class:`CoveragePlan`, built on first call and cached with it."""
    plan = _PLANS.get(problem)
    if plan is None:
        if problem.coverage is None:
            raise ValueError("plan_for needs a coverage problem (reward: coverage)")
        plan = _PLANS[problem] = _build(problem)
    return plan


def marginal_gains(problem: Problem, view_counts: np.ndarray, covered: np.ndarray, points: np.ndarray) -> np.ndarray:
    """float ``[len(points)]``: each point's marginal coverage over the regions already
    ``covered`` (bool ``[M]``), with the counts ``view_counts`` (NaN entries count 0)."""
    coverage = problem.coverage
    counts = np.nan_to_num(np.asarray(view_counts, dtype=float), nan=0.0)
    gain = counts * ~np.asarray(covered, dtype=bool)
    return np.array([math.fsum(gain[coverage.regions(int(a))].tolist()) for a in np.asarray(points).tolist()])


def covered_regions(problem: Problem, deployed: np.ndarray) -> np.ndarray:
    """bool ``[M]``: the regions explored by the ``deployed`` (bool ``[R, N]``) points."""
    coverage = problem.coverage
    out = np.zeros(coverage.n_regions, dtype=bool)
    for a in np.flatnonzero(np.asarray(deployed, dtype=bool).reshape(-1)).tolist():
        out[coverage.regions(a)] = True
    return out
