"""The clairvoyant bound: the offline optimum with every observation known in advance.

No online planner can beat it on the same instance, so experiments report online rewards as a
fraction of it.

The offline problem: carrier r deploys at exactly ``k_r = min(D_r, its valid stages)`` of its valid
stages (valid = scheduled and observed, i.e. not NaN), and the total ``sum x / p`` under the penalty
rule of :func:`planner.problem.penalties` is maximised.

Exact method (branch and bound, compiled with numba):

* **Per-carrier options.** A valid point with no valid conflicting point is *free*: its reward is
  ``x`` whatever the others do. When all observations are >= 0, some optimum uses, besides a set T
  of the carrier's overlapped points, its ``k_r - |T|`` largest free points, and no point of T has a
  smaller ``x`` than an unused free point (swapping such a point for the free one never lowers the
  total: the free point earns at least as much and removing a deployment only lowers penalties).
  A carrier's options are the sets T with that property. (With a negative observation anywhere,
  all ``C(valid, k_r)`` subsets are options.)
* **Depth-first search over carriers**, options in decreasing order of their conflict-free value.
  Bound at a node: the selected points' rewards with the penalties among themselves (adding
  deployments only raises penalties, so only lowers these) plus, for every carrier not yet
  decided, its ``k_r`` largest ``x / (1 + conflicts with the selected points)`` (again, later
  choices only lower them). Negative observations enter the bound as 0 (``x / p <= 0``).
* **Limits.** More than :data:`MAX_OPTIONS` options for a carrier, or more than ``max_nodes``
  search nodes, stops the exact search; the result is then the *conflict-free upper bound* (each
  carrier's ``k_r`` largest observations, negatives counted as 0) with ``exact=False``, and
  ``deployed`` holds the conflict-free choice, whose real penalised reward is lower than the
  reported bound.
"""
from __future__ import annotations

if __name__ == "__main__":  # a forward, first: this file's body runs once, under its own name
    from planner.cli.measure import clairvoyant_times

    raise SystemExit(clairvoyant_times())

import math
from itertools import combinations
from typing import NamedTuple

import numba
import numpy as np

from planner.compiled import compile_problem
from planner.jitcache import cache_follows_sources
from planner.problem import ClairvoyantResult, Problem, evaluate, warm_up_problem  # noqa: F401 (its home was here)

#: Largest number of options one carrier may have for the exact search.
MAX_OPTIONS = 200_000
#: Default search-node limit (one node = one carrier's option tried on top of a partial plan).
MAX_NODES = 2_000_000
#: Flat points a node visits per second here (a node visits every one of the R * N points; 300,000
#: nodes of a 256-carrier, 12-stage street grid took 1.6 s). Only :func:`node_limit` reads it.
POINT_VISITS_PER_S = 5e8


def _valid_points(problem: Problem, x: np.ndarray) -> np.ndarray:
    return problem.valid & ~np.isnan(x)


def conflict_free_bound(problem: Problem, x: np.ndarray) -> ClairvoyantResult:
    """Each carrier's ``k_r`` largest observations, penalties ignored (negatives counted as 0).

    An upper bound on the offline optimum; ``deployed`` is that choice (ties: earlier stage).
    """
    x = np.asarray(x, dtype=float)
    valid = _valid_points(problem, x)
    deployed = np.zeros(valid.shape, dtype=bool)
    total = 0.0
    wts = _sorted_weights(problem)
    for r in range(problem.n_carriers):
        stages = np.flatnonzero(valid[r])
        k = min(int(problem.passengers[r]), len(stages))
        top = stages[np.argsort(-x[r, stages], kind="stable")[:k]]
        deployed[r, top] = True
        if wts is None:
            total += float(np.maximum(x[r, top], 0.0).sum())
        else:  # top is by decreasing x: the heaviest passenger to the largest value
            total += float(np.dot(wts[r, :k], np.maximum(x[r, top], 0.0)))
    return ClairvoyantResult(deployed, total / problem.scale, total, exact=False,
                             released=_assign(problem, deployed, x))


def _sorted_weights(problem: Problem) -> np.ndarray | None:
    """float64 ``[R, max D]``: each carrier's passenger weights, largest first (None without values)."""
    if problem.weights is None:
        return None
    return np.ascontiguousarray(-np.sort(-problem.weights, axis=1))


def _assign(problem: Problem, deployed: np.ndarray, x: np.ndarray) -> np.ndarray:
    from planner.passengers import best_assignment

    return best_assignment(problem, deployed, x)


def _carrier_options(
    x_r: np.ndarray, stages: np.ndarray, overlapped: np.ndarray, k: int, dominance: bool
) -> list[tuple[int, ...]] | None:
    """Candidate stage sets of one carrier (see the module docstring); None when too many."""
    over = [int(j) for j in stages if overlapped[j]]
    free = sorted((int(j) for j in stages if not overlapped[j]), key=lambda j: (-x_r[j], j))
    if not dominance:
        over, free = [int(j) for j in stages], []
    lo = max(0, k - len(free))
    hi = min(k, len(over))
    if sum(math.comb(len(over), t) for t in range(lo, hi + 1)) > MAX_OPTIONS:
        return None
    options = []
    for t in range(lo, hi + 1):
        rest = free[: k - t]
        unused_best = x_r[free[k - t]] if k - t < len(free) else -np.inf
        for chosen in combinations(over, t):
            if dominance and t and min(x_r[j] for j in chosen) < unused_best:
                continue
            options.append(tuple(sorted(chosen + tuple(rest))))
    return options


@numba.njit(cache=True)
def _topk_sum(values: np.ndarray, k: int) -> float:
    """Sum of the k largest entries of a small 1-D array (k <= len(values))."""
    if k <= 0:
        return 0.0
    buf = np.full(k, -np.inf)
    for v in values:
        if v > buf[k - 1]:
            i = k - 1
            while i > 0 and buf[i - 1] < v:
                buf[i] = buf[i - 1]
                i -= 1
            buf[i] = v
    return buf.sum()


@numba.njit(cache=True)
def _topk_wsum(values: np.ndarray, k: int, w: np.ndarray, dcount: int) -> float:
    """The best assignment of a carrier's passengers to the k largest entries of a small 1-D
    array: ``w[:dcount]`` are its passengers' weights, largest first (k <= dcount); positive
    values go to the heaviest passengers in order, negative ones to the lightest (the most
    negative to the lightest), as :func:`planner.passengers.best_assignment`."""
    if k <= 0:
        return 0.0
    buf = np.full(k, -np.inf)
    for v in values:
        if v > buf[k - 1]:
            i = k - 1
            while i > 0 and buf[i - 1] < v:
                buf[i] = buf[i - 1]
                i -= 1
            buf[i] = v
    total = 0.0
    for i in range(k):
        total += (w[i] if buf[i] >= 0.0 else w[dcount - k + i]) * buf[i]
    return total


class Points(NamedTuple):
    """The flat decision points ``[M]``: observations (0 at invalid points; never selected),
    validity, and the CSR rows of the valid-conflict graph (``nbr_ptr`` int ``[M + 1]``,
    ``nbr_idx`` int ``[E]``)."""

    xs: np.ndarray
    valid: np.ndarray
    nbr_ptr: np.ndarray
    nbr_idx: np.ndarray


class Options(NamedTuple):
    """Each carrier's deployment options: ``order`` int ``[R]`` (carrier searched at each level);
    options of carrier r are ``opt_ptr[r]:opt_ptr[r + 1]`` (int ``[R + 1]``), each with its flat
    points ``opt_pts`` int ``[O, kmax]`` (first ``ks[r]`` used) and its conflict-free value
    ``opt_ub`` float ``[O]`` (negatives as 0); ``ks`` int ``[R]`` deployments per carrier."""

    order: np.ndarray
    opt_ptr: np.ndarray
    opt_pts: np.ndarray
    opt_ub: np.ndarray
    ks: np.ndarray


class Values(NamedTuple):
    """Passenger values: weights float ``[R, max D]`` largest first and passengers per carrier
    int ``[R]`` (read when ``weighted``: a carrier's points earn sorted-matched weights)."""

    wts: np.ndarray
    dcount: np.ndarray
    weighted: bool


@numba.njit(cache=True)
def _branch_and_bound(points, options, values, n_stages, incumbent, max_nodes):
    """Best plan by branch and bound over the carriers' options (:class:`Points`,
    :class:`Options`, :class:`Values`), pruning bounds ``<= incumbent`` (the value of a known
    feasible plan), at most ``max_nodes`` nodes.

    Returns (best value, best option per carrier (-1 = incumbent kept), nodes, finished)."""
    xs, valid, nbr_ptr, nbr_idx = points
    order, opt_ptr, opt_pts, opt_ub, ks = options
    wts, dcount, weighted = values
    n_carriers = len(order)
    n_points = len(xs)
    pos = np.maximum(xs, 0.0)
    cnt = np.zeros(n_points, dtype=np.int64)       # selected points conflicting with each point
    selected = np.zeros(n_points, dtype=np.bool_)
    idx = np.full(n_carriers, -1, dtype=np.int64)  # option index (global) tried at each level
    added = np.zeros(n_carriers, dtype=np.bool_)
    best = incumbent
    best_opts = np.full(n_carriers, -1, dtype=np.int64)
    nodes = 0
    tol = 1e-9 * max(1.0, abs(incumbent))
    # Upper bound of the points already selected; rest bound of the carriers below a level.
    fixed_ub = np.zeros(n_carriers + 1)
    rest_ub = np.zeros(n_carriers + 1)

    row = np.empty(n_stages)
    # Entering level 0: nothing selected; the carriers below are bounded by their best option.
    for lv in range(1, n_carriers):
        r = order[lv]
        if opt_ptr[r + 1] > opt_ptr[r]:
            rest_ub[0] += opt_ub[opt_ptr[r]]
    level = 0
    while level >= 0:
        r = order[level]
        if added[level]:
            o = idx[level]
            for q in range(ks[r]):
                b = opt_pts[o, q]
                selected[b] = False
                for e in range(nbr_ptr[b], nbr_ptr[b + 1]):
                    cnt[nbr_idx[e]] -= 1
            added[level] = False
        if idx[level] < 0:
            idx[level] = opt_ptr[r]
        else:
            idx[level] += 1
        o = idx[level]
        # Options are sorted by conflict-free value: once one cannot beat the best, none can.
        if o >= opt_ptr[r + 1] or fixed_ub[level] + opt_ub[o] + rest_ub[level] <= best + tol:
            idx[level] = -1
            level -= 1
            continue
        nodes += 1
        if nodes > max_nodes:
            return best, best_opts, nodes, False
        for q in range(ks[r]):
            b = opt_pts[o, q]
            selected[b] = True
            for e in range(nbr_ptr[b], nbr_ptr[b + 1]):
                cnt[nbr_idx[e]] += 1
        added[level] = True
        # Value of the selected points among themselves (exact at a leaf, a bound otherwise).
        value = 0.0
        bound = 0.0
        if weighted:
            # Per decided carrier, the heaviest passenger to its largest x / p (both sums only
            # fall as penalties grow, so the bound stays an upper bound).
            for lv in range(level + 1):
                c = order[lv]
                oc = idx[lv]
                for q in range(ks[c]):
                    b = opt_pts[oc, q]
                    row[q] = xs[b] / (1.0 + cnt[b])
                value += _topk_wsum(row[: ks[c]], ks[c], wts[c], dcount[c])
                for q in range(ks[c]):
                    row[q] = row[q] if row[q] > 0.0 else 0.0
                bound += _topk_wsum(row[: ks[c]], ks[c], wts[c], dcount[c])
        else:
            for a in range(n_points):
                if selected[a]:
                    v = xs[a] / (1.0 + cnt[a])
                    value += v
                    bound += v if v > 0.0 else 0.0
        if level == n_carriers - 1:
            if value > best + tol:
                best = value
                for lv in range(n_carriers):
                    best_opts[lv] = idx[lv]
            continue
        # Bound of the carriers below: their k largest x / (1 + conflicts with the selection).
        rest = 0.0
        rest_next = 0.0
        for lv in range(level + 1, n_carriers):
            c = order[lv]
            if ks[c] == 0:
                continue
            for j in range(n_stages):
                a = c * n_stages + j
                row[j] = pos[a] / (1.0 + cnt[a]) if valid[a] else -1.0
            s = _topk_wsum(row, ks[c], wts[c], dcount[c]) if weighted else _topk_sum(row, ks[c])
            rest += s
            if lv > level + 1:
                rest_next += s
        if bound + rest <= best + tol:
            continue
        level += 1
        fixed_ub[level] = bound
        rest_ub[level] = rest_next
        idx[level] = -1
    return best, best_opts, nodes, True


def node_limit(problem: Problem, seconds: float) -> int:
    """The node limit that keeps the search within about ``seconds`` on this project's reference
    host (:data:`POINT_VISITS_PER_S`), at most :data:`MAX_NODES`. A limit of nodes, not of time:
    the result depends on the instance only, never on the host's speed or load."""
    return max(1, min(MAX_NODES, int(seconds * POINT_VISITS_PER_S / max(1, problem.valid.size))))


def solve(problem: Problem, x: np.ndarray, max_nodes: int = MAX_NODES,
          counts: np.ndarray | None = None) -> ClairvoyantResult:
    """Offline optimum of ``problem`` with all observations ``x[R, N]`` (NaN = ∅) known.

    Args:
        problem: the instance.
        x: float ``[R, N]`` realised observations.
        max_nodes: search-node limit; beyond it the conflict-free upper bound is returned.
        counts: float ``[M]`` the realised region counts of a coverage problem (required there:
            its clairvoyant is :func:`planner.coverage_bounds.solve`); ignored for the penalty.

    Returns:
        :class:`ClairvoyantResult`; ``exact=False`` marks an upper bound (see module docstring).
    """
    if problem.coverage is not None:
        from planner import coverage_bounds
        from planner.problem import _region_counts

        return coverage_bounds.solve(problem, x, _region_counts(problem, counts))
    x = np.asarray(x, dtype=float)
    if x.shape != problem.valid.shape:
        raise ValueError(f"observations shape {x.shape} != problem shape {problem.valid.shape}")
    n_carriers, n_stages = problem.valid.shape
    valid = _valid_points(problem, x)
    fallback = conflict_free_bound(problem, x)
    wts = _sorted_weights(problem)
    flat_valid = valid.ravel()
    xs = np.where(flat_valid, np.nan_to_num(x.ravel(), nan=0.0), 0.0)
    # The conflict graph restricted to points that can be selected.
    conflict = compile_problem(problem).conflict
    graph = conflict & flat_valid[:, None] & flat_valid[None, :]
    overlapped = graph.any(axis=1).reshape(n_carriers, n_stages)
    dominance = bool((xs[flat_valid] >= 0).all())
    ks = np.array(
        [min(int(problem.passengers[r]), int(valid[r].sum())) for r in range(n_carriers)], dtype=np.int64
    )
    per_carrier = []
    for r in range(n_carriers):
        opts = _carrier_options(x[r], np.flatnonzero(valid[r]), overlapped[r], int(ks[r]), dominance)
        if opts is None:
            return fallback
        if wts is None:
            values = [float(np.maximum(x[r, list(o)], 0.0).sum()) for o in opts]
        else:
            values = [float(np.dot(wts[r, : len(o)], -np.sort(-np.maximum(x[r, list(o)], 0.0)))) for o in opts]
        per_carrier.append(sorted(zip(values, opts), key=lambda vo: (-vo[0], vo[1])))
    kmax = max(1, int(ks.max()))
    opt_ptr = np.zeros(n_carriers + 1, dtype=np.int64)
    opt_pts, opt_ub = [], []
    for r, opts in enumerate(per_carrier):
        opt_ptr[r + 1] = opt_ptr[r] + len(opts)
        for value, stages in opts:
            row = [r * n_stages + j for j in stages] + [0] * (kmax - len(stages))
            opt_pts.append(row)
            opt_ub.append(value)
    opt_pts = np.array(opt_pts, dtype=np.int64).reshape(-1, kmax)
    opt_ub = np.array(opt_ub, dtype=float)
    nbr_ptr = np.zeros(len(xs) + 1, dtype=np.int64)
    nbr_ptr[1:] = np.cumsum(graph.sum(axis=1))
    nbr_idx = np.flatnonzero(graph.ravel()) % len(xs)
    # Carriers with more options first: the bound tightens where the branching is widest.
    counts = np.diff(opt_ptr)
    order = np.argsort(-counts, kind="stable").astype(np.int64)
    # Incumbent: every carrier's best conflict-free option, evaluated with penalties.
    first = np.zeros(valid.shape, dtype=bool)
    for r, opts in enumerate(per_carrier):
        first[r, list(opts[0][1])] = True
    if wts is None:
        incumbent = float((xs / (1.0 + conflict[:, first.ravel()].sum(axis=1)))[first.ravel()].sum())
    else:
        incumbent = evaluate(problem, first, x, _assign(problem, first, x))[1]
    best, best_opts, nodes, finished = _branch_and_bound(
        Points(xs, flat_valid, nbr_ptr, nbr_idx), Options(order, opt_ptr, opt_pts, opt_ub, ks),
        Values(np.ones((1, 1)) if wts is None else wts, problem.passengers.astype(np.int64), wts is not None),
        n_stages, incumbent, int(max_nodes),
    )
    if not finished:
        return ClairvoyantResult(fallback.deployed, fallback.reward, fallback.features, False, int(nodes),
                                 fallback.released)
    if best_opts[0] < 0:
        deployed = first
    else:
        deployed = np.zeros(valid.shape, dtype=bool)
        for level in range(n_carriers):
            r = order[level]
            o = best_opts[level]
            deployed.reshape(-1)[opt_pts[o, : ks[r]]] = True
    released = _assign(problem, deployed, x)
    reward, features = evaluate(problem, deployed, x, released)
    return ClairvoyantResult(deployed, reward, features, True, int(nodes), released)


def warm_up() -> None:
    """Compile (or load from the numba cache) the search on a tiny instance."""
    tiny = warm_up_problem()
    solve(tiny, np.array([[1.0, 2.0, 0.0], [3.0, 0.0, 1.0]]))


cache_follows_sources(globals())  # the on-disk cache follows every planner source
