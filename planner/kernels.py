"""Numba twins of planner rules, shared by the MCTS and closed-loop kernels.

Each function here is the compiled counterpart of exactly one Python definition; nothing else
in the kernels restates these rules.
"""
from __future__ import annotations

import math

from numba import njit

from planner.jitcache import cache_follows_sources
from planner.ssap import TIE


@njit(cache=True, inline="always")
def forced(n, d):
    """A carrier with ``n`` valid stages left (current included) and ``d`` passengers left must
    deploy now: ``n <= d``."""
    return n <= d


@njit(cache=True, inline="always")
def cut(t):
    """A threshold raised by the tie margin (twin of :func:`planner.ssap.cut`)."""
    return t + TIE * max(1.0, abs(t)) if math.isfinite(t) else t


@njit(cache=True, inline="always")
def deploys(table, x, n, d):
    """The threshold rule (twin of :func:`planner.ssap.deploys`): with ``d >= 1`` passengers
    left, deploy iff forced or ``x > cut(table[n, n - d])``."""
    return n <= d or x > cut(table[n, n - d])


@njit(cache=True, inline="always")
def deploys_u(ucut, u, n, d):
    """:func:`deploys` for the draw ``x = quantile(u)`` of the compiled sampler, read from the
    uniform alone: ``x > cut(table[n, i])`` iff ``u >= ucut[n, i]`` (``ucut`` = CDF at the cuts)."""
    return n <= d or u >= ucut[n, n - d]


@njit(cache=True, inline="always")
def quantile(u, points, cdf, guide):
    """Inverse CDF with a guide table (Chen & Asau), twin of :meth:`planner.compiled.Sampler.draw`
    for discrete priors: the first point whose cumulative probability exceeds u in [0, 1).
    ``guide[m]`` is the first index with ``cdf > m / len(guide)``; ``cdf[-1] == 1``."""
    i = guide[int(u * guide.shape[0])]
    while cdf[i] <= u:
        i += 1
    return points[i]


@njit(cache=True, inline="always")
def rank(table, x, n):
    """The interval of ``x`` among ``table[n, 1..n-1]`` (twin of :func:`planner.ssap.rank`):
    1 + the number of those thresholds that ``x`` does not exceed (``x <= cut(t)``)."""
    count = 0
    for i in range(1, n):
        if x <= cut(table[n, i]):
            count += 1
    return 1 + count


cache_follows_sources(globals())
