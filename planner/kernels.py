"""Numba twins of planner rules, shared by the MCTS and closed-loop kernels, and the rule that
ties the planner's on-disk numba cache to its sources (:func:`cache_follows_sources`).

Each function here is the compiled counterpart of exactly one Python definition; nothing else
in the kernels restates these rules.
"""
from __future__ import annotations

import functools
import hashlib
import math
from pathlib import Path

from numba import njit

from planner.ssap import TIE

#: The planner package's directory (whose sources :func:`sources_digest` hashes).
PACKAGE = Path(__file__).resolve().parent


@functools.lru_cache(maxsize=1)
def sources_digest() -> str:
    """SHA-256 (hex) of every ``.py`` file of the planner package (relative path and content)."""
    h = hashlib.sha256()
    for path in sorted(PACKAGE.rglob("*.py")):
        h.update(path.relative_to(PACKAGE).as_posix().encode() + b"\0" + path.read_bytes() + b"\0")
    return h.hexdigest()


def cache_follows_sources(namespace: dict) -> None:
    """Make the on-disk cache of every ``cache=True`` function defined in a module (``namespace``
    is its ``globals()``; call at its end) valid only for today's planner sources.

    numba checks a cached function against its own file's time stamp only: code it compiled in
    from another file (a rule of this module inlined into a kernel, a constant such as
    ``planner.ssap.TIE``) stays as cached when that file changes, and a stale cache then decides
    by yesterday's rule. The index of each function is therefore stamped with
    :func:`sources_digest` as well, so any change to a planner source recompiles the planner's
    kernels on first use (relies on numba's ``Cache._cache_file._source_stamp``; numba is pinned
    in constraints.txt, and tests/test_numba_cache.py checks the mechanism)."""
    module = namespace["__name__"]
    for obj in list(namespace.values()):
        cache_file = getattr(getattr(obj, "_cache", None), "_cache_file", None)
        if cache_file is None or getattr(getattr(obj, "py_func", None), "__module__", None) != module:
            continue  # not a cached dispatcher, or one another module defines (and stamps)
        stamp = cache_file._source_stamp
        if not (isinstance(stamp, tuple) and len(stamp) == 3 and stamp[0] == "planner-sources"):
            cache_file._source_stamp = ("planner-sources", sources_digest(), stamp)


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
