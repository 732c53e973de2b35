"""Sequential Stochastic Assignment (Derman, Lieberman & Ross 1972) thresholds for one carrier.

A carrier with ``n`` valid stages remaining (the current one included) and ``d`` passengers left
deploys at the current stage iff its observation ``x`` exceeds ``a[n, n - d]``, where

    a[n, 0] = -inf,   a[n, n] = +inf,
    a[n + 1, i] = E[ min(max(X, a[n, i - 1]), a[n, i]) ]   for i = 1..n.

``a[n + 1, 1..n]`` are also the expected values of the slots: the optimal expected total of a
carrier with ``n`` stages and ``d`` passengers is the sum of the ``d`` largest of ``a[n + 1, 1..n]``.
Exact for discrete priors: Poisson by a closed form in its CDF, others by a finite sum over the
support (truncated where the tail mass is below 1e-15); continuous priors use adaptive quadrature
of tail integrals.

Same table, same decisions, on every machine: sums are correctly rounded (:func:`math.fsum`, not
a BLAS dot product, whose kernel and use of fused multiply-add depend on the CPU), and a value
within :data:`TIE` of a threshold counts as equal to it (:func:`cut`), so an observation that
equals a threshold in exact arithmetic (3 against the mean of the uniform prior on 0..6) stays,
whatever the last bits of either.
"""
from __future__ import annotations

import math

import numpy as np
import scipy  # scipy.integrate is loaded on first use

from planner.priors import Poisson, is_discrete, support

#: Relative tie margin of the threshold rule: ``x`` exceeds a threshold ``t`` iff
#: ``x > t + TIE * max(1, |t|)`` (:func:`cut`). Far above the rounding error of a threshold (a few
#: units in the last place, ~1e-15 relative) and of a discounted observation ``x / (1 + c)``, far
#: below any real gap between a discrete prior's values and its thresholds.
TIE = 1e-9


def cut(t: float) -> float:
    """The value an observation must exceed to be above the threshold ``t``: ``t`` raised by the
    tie margin (``t + TIE * max(1, |t|)``; infinite ``t`` unchanged), so that values equal to
    ``t`` up to rounding stay below it. :func:`planner.kernels.cut` is its numba twin."""
    return t + TIE * max(1.0, abs(t)) if math.isfinite(t) else t


def _is_plain_poisson(prior) -> bool:
    kwds = prior.kwds
    return (getattr(prior.dist, "name", None) == "poisson" and kwds.get("loc", 0) == 0
            and len(prior.args) + ("mu" in kwds) == 1)


def _poisson_clipped_mean(lam: float):
    """Closed form for X ~ Poisson(lam), no truncation. With A = floor(a), B = floor(b) and F the
    CDF: E[min(max(X, a), b)] = a F(A) + sum_{k=A+1..B} k p(k) + b (1 - F(B)), and
    sum_{k=m..n} k p(k) = lam (F(n - 1) - F(m - 2)) because k p(k) = lam p(k - 1)."""
    cdf = Poisson(lam).cdf

    def clipped_mean(a: float, b: float) -> float:
        total = 0.0
        lower = 0.0  # F(A - 1): mass below the clipped middle's shifted range
        upper = 1.0  # F(B - 1)
        if np.isfinite(a):
            fa = float(cdf(np.floor(a)))
            total += a * fa
            lower = float(cdf(np.floor(a) - 1))
        if np.isfinite(b):
            total += b * float(Poisson(lam).sf(np.floor(b)))
            upper = float(cdf(np.floor(b) - 1))
        return total + lam * max(upper - lower, 0.0)

    return clipped_mean


def _pointwise(prior, name: str):
    """``prior.cdf`` (``name`` "cdf") or ``prior.sf`` at one point, for quadrature: the frozen
    distribution's own arithmetic, ``(x - loc) / scale`` and then its family's ``_cdf``/``_sf`` on
    one-element arrays inside the open support, 0 or 1 outside it (the same bits), without the
    public method's argument handling: about 60 µs of the 65 µs a call costs, and quadrature calls
    it thousands of times per threshold table. The public method where the family's own is not
    reachable. tests/test_ssap.py holds the two equal bit for bit for every continuous prior kind."""
    public = getattr(prior, name)
    try:
        dist = prior.dist
        shapes, loc, scale = dist._parse_args(*prior.args, **prior.kwds)
        shapes = tuple(np.atleast_1d(np.asarray(a, dtype=float)) for a in shapes)
        support_lo, support_hi = (float(v) for v in dist._get_support(*shapes))
        method = getattr(dist, "_" + name)
        loc, scale = float(loc), float(scale)
    except (AttributeError, TypeError, ValueError):
        return public
    if not (scale > 0 and bool(np.all(dist._argcheck(*shapes)))):
        return public
    below, above = (0.0, 1.0) if name == "cdf" else (1.0, 0.0)

    def at(x: float) -> float:
        z = (x - loc) / scale
        if z != z:
            return public(x)
        if z <= support_lo:
            return below
        if z >= support_hi:
            return above
        return float(method(np.array([z]), *shapes)[0])

    return at


def _clipped_mean_factory(prior):
    """A function (a, b) -> E[min(max(X, a), b)] for a <= b (either may be infinite)."""
    if _is_plain_poisson(prior):
        return _poisson_clipped_mean(float(prior.args[0] if prior.args else prior.kwds["mu"]))
    if is_discrete(prior):
        points, mass = support(prior)

        def clipped_mean(a: float, b: float) -> float:
            # Correctly rounded: the same bits whatever the CPU (np.dot's BLAS kernel is not).
            return math.fsum((mass * np.clip(points, a, b)).tolist())

        return clipped_mean

    lo, hi = prior.support()
    mean = float(prior.mean())
    cdf, sf = _pointwise(prior, "cdf"), _pointwise(prior, "sf")

    def integral(f, u: float, v: float) -> float:
        return float(scipy.integrate.quad(f, u, v, epsabs=1e-11, epsrel=1e-11, limit=200)[0])

    # E[min(max(X, a), b)] through tail integrals: E[max(X, a)] = E[X] + ∫_lo^a F,
    # E[min(X, b)] = E[X] - ∫_b^hi S, and for finite a <= b: max(a, lo) + ∫_max(a,lo)^min(b,hi) S.
    def clipped_mean(a: float, b: float) -> float:
        if not np.isfinite(a) and not np.isfinite(b):
            return mean
        if not np.isfinite(a):
            return mean if b >= hi else mean - integral(sf, b, hi)
        if not np.isfinite(b):
            return mean if a <= lo else mean + integral(cdf, lo, a)
        if a >= hi:
            return float(a)
        if b <= lo:
            return float(b)
        lower, upper = max(a, lo), min(b, hi)
        return lower + integral(sf, lower, upper)

    return clipped_mean


def clipped_mean(prior):
    """A function ``(a, b) -> E[min(max(X, a), b)]`` for ``a <= b`` (either may be infinite), exact
    for ``prior`` as the thresholds are (closed form, finite sum or quadrature)."""
    return _clipped_mean_factory(prior)


def thresholds(prior, n_max: int) -> np.ndarray:
    """DLR threshold table.

    Args:
        prior: frozen scipy.stats distribution of an observation.
        n_max: largest number of remaining stages needed.

    Returns:
        float ``[n_max + 2, n_max + 2]`` table ``a`` with ``a[n, i]`` for ``0 <= i <= n <= n_max + 1``
        (NaN above the diagonal). Row ``n_max + 1`` holds the slot values for ``n_max`` stages.
    """
    size = n_max + 2
    a = np.full((size, size), np.nan)
    clipped_mean = _clipped_mean_factory(prior)
    for n in range(1, size):
        a[n, 0] = -np.inf
        a[n, n] = np.inf
        if n >= 2:
            for i in range(1, n):
                a[n, i] = clipped_mean(a[n - 1, i - 1], a[n - 1, i])
    return a


def deploys(table: np.ndarray, x: float, n: int, d: int) -> bool:
    """The threshold rule: with ``n`` valid stages left (current included) and ``d >= 1``
    passengers left, deploy iff forced (``n <= d``) or ``x`` exceeds ``table[n, n - d]`` (``x >
    cut(table[n, n - d])``: ties, up to the margin :data:`TIE`, stay). The one definition in
    Python; :func:`planner.kernels.deploys` is its numba twin."""
    return n <= d or x > cut(table[n, n - d])


def rank(table: np.ndarray, x: float, n: int) -> int:
    """The interval of ``x`` among the thresholds of ``n`` valid stages left (DLR's generalised
    rule): 1 + the number of ``table[n, 1..n-1]`` that ``x`` does not exceed (``x <= cut(t)``, the
    complement of :func:`deploys`' test), in ``1..n``. Rank 1 is above every threshold. With ``d`` passengers the threshold rule deploys iff ``rank <= d`` (or forced);
    :func:`planner.kernels.rank` is its numba twin."""
    count = 0
    for i in range(1, n):
        if x <= cut(table[n, i]):
            count += 1
    return 1 + count


def release(table: np.ndarray, x: float, n: int, weights: np.ndarray) -> int:
    """Which passenger a deployment at observation ``x`` with ``n`` valid stages left releases
    (Derman, Lieberman & Ross 1972, the generalised assignment): the passenger of weight rank
    ``min(rank(x), d)`` among the ``d`` still aboard (largest weight = rank 1; among equal weights
    the lowest index, so equal weights release in index order). The rank is above ``d`` only when a planner deploys where plain SSAP would not
    (a conflict-aware choice): then the lightest passenger goes.

    Args:
        weights: float ``[d]`` weights of the passengers aboard, in passenger order.

    Returns:
        The position in ``weights`` of the passenger to release.
    """
    weights = np.asarray(weights, dtype=float)
    target = np.sort(weights)[::-1][min(rank(table, x, n), len(weights)) - 1]
    return int(np.flatnonzero(weights == target)[0])


def decide(table: np.ndarray, x: float, stages_left: int, passengers_left: int) -> bool:
    """Deploy now? Nothing to deploy or no stage left: no; otherwise :func:`deploys`."""
    if passengers_left <= 0 or stages_left <= 0:
        return False
    return bool(deploys(table, x, stages_left, passengers_left))


def expected_value(table: np.ndarray, stages_left: int, passengers_left: int) -> float:
    """Optimal expected total of one carrier (raw units) with the given stages and passengers."""
    d = min(passengers_left, stages_left)
    if d <= 0:
        return 0.0
    slots = table[stages_left + 1, 1 : stages_left + 1]
    return math.fsum(slots[stages_left - d :].tolist())


def weighted_value(table: np.ndarray, stages_left: int, weights: np.ndarray) -> float:
    """Optimal expected total ``sum w x`` of one carrier with passengers of the given weights: the
    k-th largest weight times the k-th largest slot value ``table[n + 1, n + 1 - k]``, for
    ``k <= min(d, n)`` (DLR). Equal weights 1 give :func:`expected_value`."""
    n = stages_left
    w = np.sort(np.asarray(weights, dtype=float))[::-1][: max(n, 0)]
    if len(w) == 0:
        return 0.0
    slots = table[n + 1, n + 1 - np.arange(1, len(w) + 1)]
    return math.fsum((w * slots).tolist())


def prior_key(prior) -> object:
    """A hashable key equal for equal frozen distributions (same family, parameters, table).

    Falls back to the distribution object itself (identity) when its parameters are unhashable.
    """
    dist = prior.dist
    key = (type(dist).__name__, getattr(dist, "name", None), tuple(prior.args), tuple(sorted(prior.kwds.items())))
    if hasattr(dist, "xk"):
        key += (tuple(np.asarray(dist.xk).tolist()), tuple(np.asarray(dist.pk).tolist()))
    try:
        hash(key)
    except TypeError:
        return prior
    return key


#: Threshold tables by (prior key, n_max); cleared when it grows past _TABLES_MAX entries.
_TABLES: dict = {}
_TABLES_MAX = 1024


def table_for_prior(prior, n_stages: int) -> np.ndarray:
    """Threshold table (read-only) with rows up to ``n_stages + 1``.

    Cached per (prior family and parameters, number of stages), so the thousands of instances of
    an experiment that share a prior compute it once.
    """
    key = (prior_key(prior), n_stages)
    table = _TABLES.get(key)
    if table is None:
        if len(_TABLES) >= _TABLES_MAX:
            _TABLES.clear()
        table = thresholds(prior, n_stages)
        table.setflags(write=False)
        _TABLES[key] = table
    return table


def table_for(problem) -> np.ndarray:
    """Threshold table (read-only) of a :class:`planner.problem.Problem` (see :func:`table_for_prior`)."""
    return table_for_prior(problem.prior, problem.n_stages)


def alone(problem, x: np.ndarray, deployed: np.ndarray, r: int, first: int) -> np.ndarray:
    """bool ``[R, N]``: ``deployed`` with carrier r's deployments from stage ``first`` on replaced
    by what its own SSAP policy does on its observations ``x[r]`` (NaN = ∅), the others' and its
    earlier ones unchanged: what a carrier deciding alone by SSAP from ``first`` would have done
    (the yardstick of a carrier cut off, docs/planner.md)."""
    from planner.problem import valid_stages_left

    valid = problem.valid[r] & ~np.isnan(x[r])
    left = valid_stages_left(valid[None, :])[0]
    table = table_for(problem)
    out = np.array(deployed, dtype=bool, copy=True)
    out[r, first:] = False
    d = int(problem.passengers[r] - out[r].sum())
    for j in np.flatnonzero(valid[first:]) + first:
        if d > 0 and (left[j] <= d or decide(table, float(x[r, j]), int(left[j]), d)):
            out[r, j] = True
            d -= 1
    return out
