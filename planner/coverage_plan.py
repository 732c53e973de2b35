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
* **Planning regions.** What the kernels draw futures of: a point's private regions (explored
  by no other point) summed into one region, each shared region one; each with its prior as an
  inverse-CDF table with a guide (CSR). Exact: values add over regions and a point's private
  regions are revealed together (:class:`CoveragePlan`).

The marginal coverage of one deployment on revealed counts is :func:`planner.coverage.marginal_gain`.
"""
from __future__ import annotations

import math
import weakref
from dataclasses import dataclass

import numpy as np

from planner import priors, ssap
from planner.compiled import GUIDE_FACTOR
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
    return sum_support(coverage, coverage.regions(point))


def sum_support(coverage, regions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The prior of the sum of the counts of ``regions`` (:func:`point_support`'s rule)."""
    regions = np.asarray(regions, dtype=np.int64)
    if len(regions) == 0:
        return np.zeros(1), np.ones(1)
    if coverage.poisson:
        points, mass = priors.poisson_support(float(coverage.means[regions].sum()))
        keep = mass > 0
        return points[keep], mass[keep]
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
        owner: ``[M]``: the *planning region* of each region. A region explored by one point only
            (a private one) is read by that point alone and revealed with its other private
            regions, so a point's private regions are one planning region (their sum, prior the
            convolution); a shared region is a planning region of its own. Values are additive
            over regions, so coverage over planning regions is the coverage over regions.
        pptr, pidx: the CSR point -> planning regions lists (a point's aggregate first).
        pmeans: ``[P]`` each planning region's prior mean; poisson: all Poisson.
        rptr, rpoints, rcdf: planning region m's support and CDF (last entry 1.0) are
            ``rpoints[rptr[m]:rptr[m + 1]]``, ``rcdf[...]``; gptr, guide: its guide table
            (:class:`planner.compiled.Sampler`'s, indices from ``rptr[m]``) is
            ``guide[gptr[m]:gptr[m + 1]]``.
        solo: uint8 ``[R*N]``: the point explores only its own aggregate (no shared region);
            ucut: like ``thr``: the point prior's CDF at each threshold, so an unrevealed solo
            point's observation ``quantile(u)`` exceeds the threshold iff ``u >= ucut``.
    """

    ptr: np.ndarray
    idx: np.ndarray
    tptr: np.ndarray
    thr: np.ndarray
    owner: np.ndarray
    pptr: np.ndarray
    pidx: np.ndarray
    pmeans: np.ndarray
    rptr: np.ndarray
    rpoints: np.ndarray
    rcdf: np.ndarray
    gptr: np.ndarray
    guide: np.ndarray
    solo: np.ndarray
    ucut: np.ndarray
    poisson: bool

    def plan_counts(self, counts: np.ndarray) -> np.ndarray:
        """float ``[..., P]``: planning-region counts of region counts ``[..., M]`` (NaN where a
        region is unrevealed: a point's private regions are revealed together)."""
        counts = np.asarray(counts, dtype=float)
        out = np.zeros(counts.shape[:-1] + (len(self.pmeans),))
        np.add.at(out, (..., self.owner), counts)
        return out

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
    owner, pptr, pidx, members = _planning_regions(coverage, n_carriers * n_stages)
    supports = [sum_support(coverage, regions) for regions in members]
    rptr = np.zeros(len(supports) + 1, dtype=np.int64)
    rptr[1:] = np.cumsum([len(p) for p, _ in supports])
    rpoints = np.concatenate([p for p, _ in supports])
    rcdf = np.concatenate([np.cumsum(m) / math.fsum(m.tolist()) for _, m in supports])
    rcdf[rptr[1:] - 1] = 1.0  # a uniform in [0, 1) always finds a point
    guides = [np.searchsorted(rcdf[lo:hi], np.arange(GUIDE_FACTOR * (hi - lo)) / (GUIDE_FACTOR * (hi - lo)),
                              side="right") for lo, hi in zip(rptr[:-1].tolist(), rptr[1:].tolist())]
    gptr = np.zeros(len(guides) + 1, dtype=np.int64)
    gptr[1:] = np.cumsum([len(g) for g in guides])
    guide = np.concatenate(guides).astype(np.int64)
    pmeans = np.array([float(coverage.means[regions].sum()) for regions in members])
    solo = np.zeros(n_carriers * n_stages, dtype=np.uint8)
    ucut = np.ones(len(thr))
    for a in range(n_carriers * n_stages):
        lo, hi = pptr[a], pptr[a + 1]
        if hi - lo == 1 and len(members[pidx[lo]]) == len(coverage.regions(a)):  # its aggregate only
            solo[a] = 1
            m = pidx[lo]
            points, cdf = rpoints[rptr[m]:rptr[m + 1]], rcdf[rptr[m]:rptr[m + 1]]
            at = np.searchsorted(points, thr[tptr[a]:tptr[a + 1]], side="right") - 1
            ucut[tptr[a]:tptr[a + 1]] = np.where(at >= 0, cdf[np.clip(at, 0, None)], 0.0)
    arrays = (np.ascontiguousarray(coverage.ptr, dtype=np.int64), np.ascontiguousarray(coverage.idx, dtype=np.int64),
              tptr, np.ascontiguousarray(thr, dtype=np.float64), owner, pptr, pidx, pmeans, rptr,
              np.ascontiguousarray(rpoints, dtype=np.float64), np.ascontiguousarray(rcdf, dtype=np.float64), gptr,
              guide, solo,
              np.ascontiguousarray(ucut, dtype=np.float64))
    for arr in arrays:
        arr.setflags(write=False)
    return CoveragePlan(*arrays, bool(coverage.poisson))


def _planning_regions(coverage, n_points: int):
    """(owner ``[M]``, pptr, pidx, members): a point's private regions (explored by it alone)
    become one planning region, each shared region stays one (:class:`CoveragePlan`);
    ``members[p]`` the regions of planning region p (a region nobody explores is one too)."""
    degree = np.bincount(coverage.idx, minlength=coverage.n_regions)
    owner = np.full(coverage.n_regions, -1, dtype=np.int64)
    members: list[list[int]] = []
    lists: list[list[int]] = []
    for a in range(n_points):
        private = [m for m in coverage.regions(a).tolist() if degree[m] == 1]
        if private:
            owner[private] = len(members)
            members.append(private)
        lists.append([len(members) - 1] if private else [])
    for m in np.flatnonzero(degree != 1).tolist():
        owner[m] = len(members)
        members.append([m])
    for a in range(n_points):
        lists[a] += sorted({int(owner[m]) for m in coverage.regions(a).tolist() if degree[m] >= 2})
    pptr = np.zeros(n_points + 1, dtype=np.int64)
    pptr[1:] = np.cumsum([len(x) for x in lists])
    pidx = np.array([p for x in lists for p in x], dtype=np.int64)
    return owner, pptr, pidx, [np.array(m, dtype=np.int64) for m in members]


_PLANS: "weakref.WeakKeyDictionary[Problem, CoveragePlan]" = weakref.WeakKeyDictionary()


def plan_for(problem: Problem) -> CoveragePlan:
    """The coverage problem's :class:`CoveragePlan`, built on first call and cached with it."""
    plan = _PLANS.get(problem)
    if plan is None:
        if problem.coverage is None:
            raise ValueError("plan_for needs a coverage problem (reward: coverage)")
        plan = _PLANS[problem] = _build(problem)
    return plan
