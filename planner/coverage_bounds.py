"""Bounds under the coverage reward (issue 35): the clairvoyant by integer programming and the
information-relaxation upper bound adapted to coverage.

The clairvoyant knows every region count and picks the best feasible set of deployments: carrier
r deploys at exactly ``k_r = min(D_r, its feasible stages)`` of its feasible stages (valid and
observed, as :mod:`planner.clairvoyant`; the forced-deployment rule of the online planners), and
the set is worth :func:`planner.coverage.value`. The model (HiGHS through :mod:`planner.highs`):

* a 0/1 column per feasible point (per point and passenger with passenger values: ``y[a, i]``,
  each point releases at most one passenger, each passenger is released at most once); carrier
  rows ``sum y = k_r``;
* per region m with ``counts[m] > 0`` and each distinct weight level ``w_1 < ... < w_L`` of the
  passengers that could explore it, ``u[m, l] <= sum of the columns exploring m with weight >=
  w_l`` (``u`` continuous in [0, 1]); objective ``sum counts[m] * (w_l - w_{l-1}) * u[m, l]``:
  at an integer ``y`` that is ``counts[m]`` times the best weight exploring m (the documented
  rule of :mod:`planner.coverage`), without passenger values ``counts[m]`` once.

Size and precision (:func:`model_size`, O(R*N + the covers' entries), before anything is built):
within :data:`ILP_COLUMNS` columns and :data:`ILP_NONZEROS` nonzeros the integer program is
solved (``exact`` when HiGHS proves optimality within :data:`ILP_TIME_LIMIT_S`; otherwise its
dual bound, ``exact=False`` and the ``gap``); within :data:`LP_COLUMNS` / :data:`LP_NONZEROS` the
LP relaxation is the bound; beyond, the union bound (every region some feasible point explores,
at the best weight that could explore it). ``gap`` = (bound - best feasible value found) / bound,
the best of HiGHS's incumbent and a lazy greedy.

The upper bound on every online policy (Brown, Smith and Sun): ``E[max_y (value(y) - z(y))]``
over counts drawn from the region priors, with ``z`` the carriers' DLR values-to-go minus their
conditional means (:func:`penalty_terms`, zero mean for every non-anticipative policy) or no
penalty at all (the clairvoyant mean); the inner maximum is this module's model with each carrier
as the flow network of :func:`planner.duality.carrier_flow`, as a MIP (its dual bound) or an LP.
docs/planner.md, "Coverage bounds".
"""
from __future__ import annotations

if __name__ == "__main__":  # a forward, first: this file's body runs once, under its own name
    from planner.cli.measure import coverage_bound_times

    raise SystemExit(coverage_bound_times())

import heapq
import math
import weakref
from dataclasses import dataclass

import numpy as np

from planner import coverage as cov
from planner.problem import ClairvoyantResult, Problem, evaluate, in_order, valid_stages_left

#: Largest integer program solved (columns, nonzeros of the constraint matrix).
ILP_COLUMNS = 20_000
ILP_NONZEROS = 200_000
#: Largest LP relaxation solved; beyond it the union bound.
LP_COLUMNS = 400_000
LP_NONZEROS = 4_000_000
#: HiGHS time limits, seconds: past the first the MIP's dual bound is reported (exact=False).
ILP_TIME_LIMIT_S = 10.0
LP_TIME_LIMIT_S = 60.0


class TooLarge(ValueError):
    """A model beyond its size budget (decided from the sizes alone). ``str(err)`` is one line."""


def _check(problem: Problem) -> cov.Coverage:
    if problem.coverage is None:
        raise ValueError("coverage bounds: expected a coverage problem (reward: coverage), found the penalty reward")
    return problem.coverage


def feasible_points(problem: Problem, x: np.ndarray) -> np.ndarray:
    """bool ``[R, N]``: valid and observed (x not NaN)."""
    return problem.valid & ~np.isnan(np.asarray(x, dtype=float))


def quotas(problem: Problem, feasible: np.ndarray) -> np.ndarray:
    """int64 ``[R]``: ``k_r = min(D_r, feasible stages)`` (the forced-deployment rule)."""
    return np.minimum(problem.passengers, feasible.sum(axis=1)).astype(np.int64)


@dataclass(frozen=True)
class Size:
    columns: int
    nonzeros: int

    def fits(self, columns: int, nonzeros: int) -> bool:
        return self.columns <= columns and self.nonzeros <= nonzeros


def model_size(problem: Problem, feasible: np.ndarray, flow: bool = False) -> Size:
    """An upper estimate of the model's columns and nonzeros, O(R*N + the covers' entries).
    ``flow``: each carrier as its flow network (the upper bound's model)."""
    coverage = _check(problem)
    flat = feasible.reshape(-1)
    lens = np.diff(coverage.ptr)[flat]
    carrier = np.repeat(np.arange(problem.n_carriers), problem.n_stages)[flat]
    d = problem.passengers.astype(np.int64)[carrier]
    units = 2 * (d + 1) if flow else (d if problem.weights is not None else np.ones_like(d))
    levels = 1 if problem.weights is None else max(1, len(np.unique(problem.weights[problem.weights > 0])))
    regions = min(coverage.n_regions, int(lens.sum()))
    columns = int(units.sum()) + regions * levels
    nonzeros = int(3 * units.sum() + levels * (np.dot(lens, units) + regions))
    return Size(columns, nonzeros)


# ----------------------------------------------------------------------------- the model


@dataclass
class _Units:
    """The model's deployment columns: flat point, passenger (-1 = any) and weight of each."""

    point: list
    passenger: list
    weight: list
    column: list

    def add(self, point: int, passenger: int, weight: float, column: int) -> None:
        self.point.append(point)
        self.passenger.append(passenger)
        self.weight.append(weight)
        self.column.append(column)


def _build(problem: Problem, feasible: np.ndarray, counts: np.ndarray, integer: bool, phi: np.ndarray | None = None):
    """The model of the module docstring; ``phi``: carriers as flow networks with these penalty
    terms (:func:`planner.duality.carrier_flow`). Returns (model, units)."""
    from planner.duality import carrier_flow
    from planner.highs import Model

    coverage = problem.coverage
    model, units = Model(), _Units([], [], [], [])
    ks = quotas(problem, feasible)
    n_stages = problem.n_stages
    for r in np.flatnonzero(ks > 0):
        stages = np.flatnonzero(feasible[r])
        if phi is not None:
            for a, arcs in carrier_flow(model, problem, int(r), stages, int(ks[r]), phi, integer).items():
                for c in arcs:
                    units.add(a, -1, 1.0, c)
            continue
        if problem.weights is None:
            cols = [model.var(0.0, is_int=integer) for _ in stages]
            for j, c in zip(stages, cols):
                units.add(int(r) * n_stages + int(j), -1, 1.0, c)
            model.row(ks[r], ks[r], cols, [1.0] * len(cols))
            continue
        d = int(problem.passengers[r])
        grid = [[model.var(0.0, is_int=integer) for _ in range(d)] for _ in stages]
        for j, row in zip(stages, grid):
            model.row(-np.inf, 1.0, row, [1.0] * d)  # one passenger per point
            for i, c in enumerate(row):
                units.add(int(r) * n_stages + int(j), i, float(problem.weights[r, i]), c)
        for i in range(d):
            model.row(-np.inf, 1.0, [row[i] for row in grid], [1.0] * len(grid))  # released once
        flat = [c for row in grid for c in row]
        model.row(ks[r], ks[r], flat, [1.0] * len(flat))
    by_region: dict[int, list[int]] = {}
    for u, a in enumerate(units.point):
        for m in coverage.regions(a).tolist():
            if counts[m] > 0:
                by_region.setdefault(m, []).append(u)
    for m, us in sorted(by_region.items()):
        levels = sorted(set(units.weight[u] for u in us))
        below = 0.0
        for w in levels:
            z = model.var(float(counts[m]) * (w - below))
            over = [units.column[u] for u in us if units.weight[u] >= w]
            model.row(-np.inf, 0.0, [z] + over, [1.0] + [-1.0] * len(over))
            below = w
    return model, units


def _chosen(problem: Problem, units: _Units, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(deployed, released) of an integer solution."""
    deployed = np.zeros(problem.valid.shape, dtype=bool)
    released = np.full(problem.valid.shape, -1, dtype=np.int64)
    for a, i, c in zip(units.point, units.passenger, units.column):
        if values[c] > 0.5:
            deployed.reshape(-1)[a] = True
            released.reshape(-1)[a] = i
    return deployed, (released if problem.weights is not None else in_order(deployed))


# ----------------------------------------------------------------------------- the clairvoyant


def greedy(problem: Problem, feasible: np.ndarray, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(deployed, released): a feasible set by lazy greedy marginal coverage, each carrier's
    heaviest remaining passenger at its next deployment (gains only fall as regions are covered
    and passengers get lighter, so a stale heap entry is an upper bound)."""
    coverage = problem.coverage
    n_stages = problem.n_stages
    ks = quotas(problem, feasible)
    order = [np.argsort(-problem.weights[r, : problem.passengers[r]], kind="stable") if problem.weights is not None
             else np.arange(problem.passengers[r]) for r in range(problem.n_carriers)]
    done = np.zeros(problem.n_carriers, dtype=np.int64)
    best = np.zeros(coverage.n_regions)
    deployed = np.zeros(problem.valid.shape, dtype=bool)
    released = np.full(problem.valid.shape, -1, dtype=np.int64)

    def weight(r: int) -> float:
        return 1.0 if problem.weights is None else float(problem.weights[r, order[r][done[r]]])

    heap = [(-cov.marginal_gain(coverage, best, int(a), counts, weight(int(a) // n_stages)), int(a))
            for a in np.flatnonzero(feasible.reshape(-1)) if ks[int(a) // n_stages] > 0]
    heapq.heapify(heap)
    while heap:
        _, a = heapq.heappop(heap)
        r = a // n_stages
        if done[r] >= ks[r]:
            continue
        gain = cov.marginal_gain(coverage, best, a, counts, weight(r))
        if heap and -heap[0][0] > gain + 1e-12:
            heapq.heappush(heap, (-gain, a))
            continue
        deployed[r, a % n_stages] = True
        released[r, a % n_stages] = order[r][done[r]]
        cov.add(coverage, best, a, weight(r))
        done[r] += 1
    return deployed, (released if problem.weights is not None else in_order(deployed))


def union_bound(problem: Problem, feasible: np.ndarray, counts: np.ndarray) -> float:
    """Raw: every region some feasible point explores, at the heaviest weight of its carrier."""
    coverage = problem.coverage
    best = np.zeros(coverage.n_regions)
    heaviest = (np.ones(problem.n_carriers) if problem.weights is None else problem.weights.max(axis=1))
    for a in np.flatnonzero(feasible.reshape(-1)):
        cov.add(coverage, best, int(a), float(heaviest[a // problem.n_stages]))
    return float(np.dot(counts, best))


def method_for(size: Size) -> str:
    """``ilp``, ``lp`` or ``union`` (the module docstring's budgets)."""
    if size.fits(ILP_COLUMNS, ILP_NONZEROS):
        return "ilp"
    return "lp" if size.fits(LP_COLUMNS, LP_NONZEROS) else "union"


def solve(problem: Problem, x: np.ndarray, counts: np.ndarray, method: str = "auto",
          time_limit_s: float = ILP_TIME_LIMIT_S) -> ClairvoyantResult:
    """The clairvoyant under coverage: the best feasible set knowing every region count.

    Args:
        x: float ``[R, N]`` observations (NaN = ∅: not feasible).
        counts: float ``[M]`` every region's realised count.
        method: ``auto`` (:func:`method_for` of :func:`model_size`), ``ilp``, ``lp`` or ``union``;
            ``ilp`` / ``lp`` beyond their budget raise :class:`TooLarge` before building.

    Returns:
        :class:`planner.problem.ClairvoyantResult`: ``features`` the optimum (``exact``) or an
        upper bound on it, ``deployed`` / ``released`` the best feasible set found, ``gap`` and
        ``method``.
    """
    _check(problem)
    counts = np.asarray(counts, dtype=float).reshape(-1)
    x = np.asarray(x, dtype=float)
    if x.shape != problem.valid.shape:
        raise ValueError(f"observations shape {x.shape} != problem shape {problem.valid.shape}")
    feasible = feasible_points(problem, x)
    size = model_size(problem, feasible)
    if method == "auto":
        method = method_for(size)
    limits = {"ilp": (ILP_COLUMNS, ILP_NONZEROS), "lp": (LP_COLUMNS, LP_NONZEROS)}
    if method in limits and not size.fits(*limits[method]):
        raise TooLarge(f"coverage clairvoyant: {method} model of about {size.columns:,} columns and "
                       f"{size.nonzeros:,} nonzeros, beyond {limits[method][0]:,} / {limits[method][1]:,}")
    deployed, released = greedy(problem, feasible, counts)
    found = evaluate(problem, deployed, x, released, counts=counts)[1]
    bound = union_bound(problem, feasible, counts)
    exact = False
    if method in limits:
        model, units = _build(problem, feasible, counts, integer=method == "ilp")
        solved = model.solve(method == "ilp", time_limit_s if method == "ilp" else LP_TIME_LIMIT_S)
        bound = min(bound, solved.bound)
        if method == "ilp" and solved.values is not None:
            d2, r2 = _chosen(problem, units, solved.values)
            v2 = evaluate(problem, d2, x, r2, counts=counts)[1]
            if v2 > found:
                deployed, released, found = d2, r2, v2
        exact = method == "ilp" and solved.optimal
    features = found if exact else max(bound, found)
    gap = 0.0 if exact or features <= 0 else (features - found) / features
    return ClairvoyantResult(deployed, features / problem.scale, features, exact, 0, released, gap, method)


# ----------------------------------------------------------------------------- the upper bound


def values_to_go(problem: Problem) -> np.ndarray:
    """float ``[R, N + 1, Dmax + 1]``: ``W[r, j, d]``, carrier r's optimal expected coverage from
    stage j on with d passengers left *were it alone and its points' regions disjoint* (each
    point's observation the sum of its regions' counts, unconditioned): the single-carrier DLR
    value of that carrier's own point distributions, by backward induction over its valid stages
    with the forced-deployment rule. Raw units; depends on the problem only."""
    coverage = _check(problem)
    n_carriers, n_stages = problem.valid.shape
    dmax = int(problem.passengers.max(initial=0))
    out = np.zeros((n_carriers, n_stages + 1, dmax + 1))
    left = valid_stages_left(problem.valid)
    for r in range(n_carriers):
        for j in range(n_stages - 1, -1, -1):
            nxt = out[r, j + 1]
            if not problem.valid[r, j]:
                out[r, j] = nxt
                continue
            regions = coverage.regions(r * n_stages + j)
            mean = float(coverage.means[regions].sum())
            for d in range(1, dmax + 1):
                if left[r, j] <= d:  # forced: deploy
                    out[r, j, d] = mean + nxt[d - 1]
                else:  # E[max(X + A, B)] = A + E[X] + E[(B - A - X)^+]
                    out[r, j, d] = nxt[d - 1] + mean + _shortfall(coverage, regions, nxt[d] - nxt[d - 1])
    return out


def penalty_terms(problem: Problem, counts: np.ndarray, values: np.ndarray | None = None) -> np.ndarray:
    """float ``[R, N, Dmax + 1]``: ``phi[r, j, d] = v(j, d, x_rj) - E[v(j, d, X_rj) | stages < j]``
    with ``v(j, d, x) = max(x + W[r, j+1, d-1], W[r, j+1, d])`` (``x + W[r, j+1, d-1]`` when
    forced) for the values-to-go ``W`` (:func:`values_to_go` when None) and x_rj the sum of the
    point's region counts (raw units; 0 at invalid stages and for d = 0).

    Zero mean for every non-anticipative policy: before stage j the observer knows the counts of
    the regions of every valid point at stages < j, so ``X_rj = K + U`` with K known and U the
    sum of the point's other region counts (independent of the past), and
    ``E[max(K + U + A, B)] = K + A + E[U] + E[(B - A - K - U)^+]`` where the last term is a finite
    sum over U's values below ``B - A - K`` (:func:`_shortfall`): exact, no truncation.
    """
    coverage = _check(problem)
    w = values_to_go(problem) if values is None else values
    n_carriers, n_stages = problem.valid.shape
    dmax = int(problem.passengers.max(initial=0))
    out = np.zeros((n_carriers, n_stages, dmax + 1))
    left = valid_stages_left(problem.valid)
    known = np.zeros(coverage.n_regions, dtype=bool)  # revealed before the current stage
    for j in range(n_stages):
        for r in np.flatnonzero(problem.valid[:, j]):
            regions = coverage.regions(int(r) * n_stages + j)
            seen = known[regions]
            x_value = float(counts[regions].sum())
            k_value = float(counts[regions[seen]].sum())
            unseen = regions[~seen]
            mu = float(coverage.means[unseen].sum())
            for d in range(1, dmax + 1):
                a_, b_ = w[r, j + 1, d - 1], w[r, j + 1, d]
                if left[r, j] <= d:  # forced: v = x + A
                    out[r, j, d] = x_value - k_value - mu
                    continue
                mean = k_value + a_ + mu + _shortfall(coverage, unseen, b_ - a_ - k_value)
                out[r, j, d] = max(x_value + a_, b_) - mean
        for r in np.flatnonzero(problem.valid[:, j]):
            known[coverage.regions(int(r) * n_stages + j)] = True
    return out


_SUPPORTS: "weakref.WeakKeyDictionary[cov.Coverage, dict]" = weakref.WeakKeyDictionary()


def _support(coverage: cov.Coverage, m: int) -> tuple[list, list]:
    """Region m's (values, probabilities) (:func:`planner.priors.support`), cached per coverage."""
    from planner.priors import support

    cache = _SUPPORTS.setdefault(coverage, {})
    if m not in cache:
        values, probs = support(coverage.priors[m])
        cache[m] = (values.tolist(), probs.tolist())
    return cache[m]


def _shortfall(coverage: cov.Coverage, regions: np.ndarray, t: float) -> float:
    """``E[(t - U)^+]`` for U the sum of the counts of ``regions`` (independent, each >= 0): only
    U's values <= t matter, and only each region's values <= t reach them. Poisson regions are
    one Poisson (means summed); any other prior is convolved over its support points <= t."""
    if t < 0:
        return 0.0
    poisson = [m for m in regions.tolist() if getattr(coverage.priors[m].dist, "name", "") == "poisson"]
    mu = float(coverage.means[poisson].sum()) if poisson else 0.0
    dist, p = {}, math.exp(-mu)  # Poisson(mu) on 0..floor(t) by p(u) = p(u - 1) * mu / u
    for u in range(int(math.floor(t)) + 1):
        dist[float(u)] = p
        p *= mu / (u + 1)
    for m in regions.tolist():
        if m in poisson:
            continue
        points, probs = _support(coverage, m)
        nxt: dict[float, float] = {}
        for u, p in dist.items():
            for v, q in zip(points, probs):
                if u + v <= t and q > 0:
                    nxt[u + v] = nxt.get(u + v, 0.0) + p * q
        dist = nxt
    return float(sum((t - u) * p for u, p in dist.items()))


def inner_maximum(problem: Problem, counts: np.ndarray, penalty: bool = True, integer: bool = True,
                  time_limit_s: float = 1.0, values: np.ndarray | None = None) -> float:
    """``max_y (value(y, counts) - z(y, counts))`` or an upper bound on it (the MIP's dual bound,
    or the LP with ``integer=False``); raw units. ``penalty=False``: z = 0 (the clairvoyant).
    ``values``: :func:`values_to_go` when the caller keeps them."""
    counts = np.asarray(counts, dtype=float)
    dmax = int(problem.passengers.max(initial=0))
    phi = penalty_terms(problem, counts, values) if penalty else np.zeros(problem.valid.shape + (dmax + 1,))
    model, _ = _build(problem, problem.valid, counts, integer, phi)
    return model.solve(integer, time_limit_s).bound


#: Cost model of one sample of :func:`upper_bound` (seconds, one core of the development machine):
#: per HiGHS model, per column and per squared column (the LP), the MIP's factor over the LP
#: (typical; one MIP is capped at :data:`planner.duality.MIP_TIME_LIMIT_S`), and per penalty
#: term (a valid point and passengers left; :func:`penalty_terms`). Measured on
#: examples/coverage_tiny.json: 3.3 ms (LP), 6.8 ms (MIP), 1.4 ms of penalty terms per sample.
_COST = {"model": 0.003, "column": 4e-5, "column2": 1.5e-9, "mip": 2.0, "term": 6e-5}


def estimate_seconds(problem: Problem, method: str, samples: int, penalty: bool = True) -> float:
    """Predicted wall time of :func:`upper_bound` (``penalty`` True or "auto": with the pilot)
    from the sizes alone (O(R*N + covers))."""
    columns = model_size(problem, problem.valid, flow=True).columns
    per = _COST["model"] + _COST["column"] * columns + _COST["column2"] * columns ** 2
    per *= _COST["mip"] if method == "mip" else 1.0
    if penalty:
        per += _COST["term"] * int(problem.valid.sum()) * int(problem.passengers.max(initial=0))
    # the pilot of penalty="auto": both inner maxima of PILOT_SAMPLES count vectors
    return per * (samples + (2 * PILOT_SAMPLES if penalty else 0))


def plan(problem: Problem, budget_s: float, samples: int, penalty: bool = True) -> tuple[str, int]:
    """``(method, samples)`` within ``budget_s`` by :func:`estimate_seconds`: ``mip`` when the flow
    model fits the integer budget (:data:`ILP_COLUMNS`, :data:`ILP_NONZEROS`) and enough samples
    fit, else ``lp``. Raises :class:`planner.duality.BoundTooLarge` (one line, no solve) when not
    even :data:`planner.duality.MIN_SAMPLES` fit."""
    from planner.duality import MIN_SAMPLES, BoundTooLarge

    size = model_size(problem, problem.valid, flow=True)
    methods = ("mip", "lp") if size.fits(ILP_COLUMNS, ILP_NONZEROS) else ("lp",)
    if size.fits(LP_COLUMNS, LP_NONZEROS):
        for method in methods:
            pilot = estimate_seconds(problem, method, 0, penalty)
            per = estimate_seconds(problem, method, 1, penalty) - pilot
            fit = min(samples, int((budget_s - pilot) // per) if per > 0 else samples)
            if fit >= MIN_SAMPLES:
                return method, fit
    raise BoundTooLarge(f"coverage upper bound: {MIN_SAMPLES} samples by lp would take about "
                        f"{estimate_seconds(problem, 'lp', MIN_SAMPLES, penalty):.3g} s, beyond the {budget_s:g} s "
                        f"budget (R={problem.n_carriers}, N={problem.n_stages}, {size.columns:,} columns)")


#: Count vectors of the pilot that picks the penalty of ``penalty="auto"``.
PILOT_SAMPLES = 8


def upper_bound(problem: Problem, rng: np.random.Generator, samples: int = 200, method: str = "mip",
                penalty: bool | str = "auto", deadline_s: float | None = None):
    """The information-relaxation bound under coverage: the mean of :func:`inner_maximum` over
    ``samples`` count vectors drawn from the region priors with ``rng``; a
    :class:`planner.duality.UpperBound` (``penalty_scale`` 1.0 with the DLR penalty, 0.0 without:
    the clairvoyant mean). ``method``: ``mip`` (each sample's dual bound within
    :data:`planner.duality.MIP_TIME_LIMIT_S`) or ``lp``. ``penalty="auto"``: the DLR penalty or
    none, whichever gives the smaller mean on :data:`PILOT_SAMPLES` count vectors drawn first
    (then discarded, so the bound's samples are independent of the choice and it stays valid;
    the DLR values come from one prior for every point and are not always the tighter).

    Raises:
        ValueError: a problem with passenger values (the DLR penalty knows no types), or fewer
            than 2 samples.
        planner.duality.BoundTooLarge: past ``deadline_s`` (the bound of all samples or nothing).
    """
    import time

    from planner.duality import MIP_TIME_LIMIT_S, BoundTooLarge, UpperBound

    _check(problem)
    if problem.weights is not None:
        raise ValueError("coverage upper bound: expected an instance without passenger values, found passenger_values")
    if samples < 2:
        raise ValueError(f"coverage upper bound: expected at least 2 samples (for a standard error), found {samples}")

    w = values_to_go(problem) if penalty else None

    def value(counts, with_penalty):
        return inner_maximum(problem, counts, with_penalty, method == "mip", MIP_TIME_LIMIT_S, w) / problem.scale

    if penalty == "auto":
        pilot = [cov.sample_counts(problem.coverage, rng) for _ in range(PILOT_SAMPLES)]
        penalty = sum(value(c, True) for c in pilot) < sum(value(c, False) for c in pilot)
    values = np.empty(samples)
    start = time.perf_counter()
    for s in range(samples):
        values[s] = value(cov.sample_counts(problem.coverage, rng), penalty)
        if deadline_s is not None and time.perf_counter() - start > deadline_s:
            raise BoundTooLarge(f"coverage upper bound: stopped after {s + 1} of {samples} samples at the "
                                f"{deadline_s:g} s deadline")
    return UpperBound(float(values.mean()), float(values.std(ddof=1) / math.sqrt(samples)), method, samples,
                      1.0 if penalty else 0.0)


def seeded_bound(problem: Problem, seed: int, budget_s: float | None = None, samples: int | None = None):
    """The bound as ``solve`` reports it: :func:`plan` within the budget of
    :func:`planner.duality.seeded_bound`, counts from ``SeedSequence(seed,
    spawn_key=planner.duality.BOUND_SPAWN_KEY)``. Raises as :func:`plan`."""
    from planner import duality

    budget_s = duality.DEFAULT_BUDGET_S if budget_s is None else budget_s
    method, count = plan(problem, budget_s, duality.DEFAULT_SAMPLES if samples is None else samples)
    rng = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=duality.BOUND_SPAWN_KEY))
    return upper_bound(problem, rng, count, method, deadline_s=duality.DEADLINE_FACTOR * budget_s)
