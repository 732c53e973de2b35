"""The compiled problem: every array a planner derives from a :class:`~planner.problem.Problem`,
built once per problem and shared by SSAP, both MCTS layouts, the reference MCTS, closed-loop and
the clairvoyant bound.

``compile_problem(problem)`` returns the problem's :class:`CompiledProblem` (cached per problem
object, dropped with it). Its parts:

* ``sampler`` — the prior as an inverse-CDF :class:`Sampler`: exact for every discrete prior
  (integer supports truncated where the tail mass is below ``priors.TAIL``; table priors on their
  own, possibly non-integer, points); a continuous prior is represented inside the numba kernels
  by ``CONTINUOUS_ATOMS`` equiprobable atoms at its quantiles ``(i + 1/2) / CONTINUOUS_ATOMS``,
  and sampled exactly (``prior.ppf(u)``) by Python code (:meth:`Sampler.draw`);
* ``table`` / ``ucut`` — the DLR threshold table (:func:`planner.ssap.table_for`) and the
  sampler's CDF at every threshold, so a kernel decides ``x > t`` from the uniform alone;
* ``slot_value`` — the optimal single-carrier SSAP value ``[n, d]``;
* ``conflict`` / ``indptr`` / ``nbr`` — "shares an overlap" as the dense matrix
  (``problem.conflict``, the same array) and its CSR lists.

Thresholds are built on first use (continuous priors need quadrature), so a caller that needs
only the conflict graph (the clairvoyant bound) does not pay for them.
"""
from __future__ import annotations

import math
import weakref
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from planner import priors, ssap
from planner.problem import Problem

#: Equiprobable atoms standing for a continuous prior inside the numba kernels.
CONTINUOUS_ATOMS = 4096
#: Guide-table entries per support point (inverse-CDF sampling takes ~1 comparison on average).
GUIDE_FACTOR = 4


@dataclass(frozen=True, eq=False)
class Sampler:
    """A prior as arrays for inverse-CDF sampling (Chen & Asau guide table).

    Attributes:
        points: float64 ``[K]`` support points, ascending (atoms for a continuous prior).
        cdf: float64 ``[K]`` cumulative probabilities, last entry exactly 1.0 (so a uniform
            ``u`` in [0, 1) always finds a point).
        guide: int64 ``[GUIDE_FACTOR * K]``; ``guide[m]`` is the first index with
            ``cdf > m / len(guide)`` (where the kernels' scan starts).
        prior: the frozen scipy.stats distribution.
        discrete: whether ``points`` is the exact support (else atoms of a continuous prior).
    """

    points: np.ndarray
    cdf: np.ndarray
    guide: np.ndarray
    prior: object = field(repr=False)
    discrete: bool

    @staticmethod
    def build(prior) -> "Sampler":
        if priors.is_discrete(prior):
            points, mass = priors.support(prior)
            cdf = np.cumsum(mass) / math.fsum(mass.tolist())  # correctly rounded: no CPU-dependent bits
        else:
            u = (np.arange(CONTINUOUS_ATOMS) + 0.5) / CONTINUOUS_ATOMS
            points = prior.ppf(u)
            cdf = (np.arange(CONTINUOUS_ATOMS) + 1.0) / CONTINUOUS_ATOMS
        points = np.ascontiguousarray(points, dtype=np.float64)
        cdf = np.ascontiguousarray(cdf, dtype=np.float64)
        cdf[-1] = 1.0
        n_guide = GUIDE_FACTOR * len(cdf)
        guide = np.searchsorted(cdf, np.arange(n_guide) / n_guide, side="right").astype(np.int64)
        for arr in (points, cdf, guide):
            arr.setflags(write=False)
        return Sampler(points, cdf, guide, prior, priors.is_discrete(prior))

    def draw(self, u: np.ndarray) -> np.ndarray:
        """The prior's quantile at each uniform of ``u`` (any shape, values in [0, 1)): the first
        support point whose cumulative probability exceeds ``u`` (the same point the kernels'
        guided scan finds), or ``prior.ppf(u)`` for a continuous prior. float64, shape of ``u``."""
        u = np.asarray(u, dtype=np.float64)
        if not self.discrete:
            return np.asarray(self.prior.ppf(u), dtype=np.float64)
        return self.points[np.searchsorted(self.cdf, u, side="right")]

    def sample(self, rng: np.random.Generator, shape) -> np.ndarray:
        """float64 ``shape`` draws of the prior: :meth:`draw` of ``rng.random(shape)``."""
        return self.draw(rng.random(shape))


@dataclass(frozen=True, eq=False)
class CompiledProblem:
    """What every planner reads of one problem (see the module docstring).

    Attributes:
        n_carriers, n_stages: R and N.
        scale: rewards are divided by it for planning.
        sampler: the prior, for sampling.
        conflict: bool ``[R*N, R*N]`` flat points sharing an overlap (``problem.conflict``).
        indptr: int64 ``[R*N + 1]``; ``nbr[indptr[a]:indptr[a + 1]]`` are the points sharing an
            overlap with flat point ``a`` (CSR of ``conflict``), int64 ``[nnz]``.
    """

    n_carriers: int
    n_stages: int
    scale: float
    sampler: Sampler
    conflict: np.ndarray = field(repr=False)
    indptr: np.ndarray = field(repr=False)
    nbr: np.ndarray = field(repr=False)
    prior: object = field(repr=False)

    @cached_property
    def nbr_rows(self) -> np.ndarray:
        """int64 ``[nnz]``: the flat point whose list each entry of :attr:`nbr` is in (the CSR's row
        indices), read-only."""
        out = np.repeat(np.arange(len(self.indptr) - 1, dtype=np.int64), np.diff(self.indptr))
        out.setflags(write=False)
        return out

    def links(self, open_: np.ndarray, past: np.ndarray) -> np.ndarray:
        """bool ``[R, R]``: carriers joined by a conflict between two relevant flat points of which
        at least one is ``open_`` (the other open or ``past``); O(nnz), from the CSR lists (a
        dense ``[R*N, R*N]`` mask grows as (R·N)²)."""
        rows, cols = self.nbr_rows, self.nbr
        relevant = open_ | past
        keep = (open_[rows] & relevant[cols]) | (relevant[rows] & open_[cols])
        out = np.zeros((self.n_carriers, self.n_carriers), dtype=bool)
        out[rows[keep] // self.n_stages, cols[keep] // self.n_stages] = True
        return out

    def penalties(self, selected: np.ndarray) -> np.ndarray:
        """int64 ``[R*N]``: 1 + the number of ``selected`` flat points sharing an overlap with each
        point (the penalty p a deployment there would have), from the CSR lists."""
        counts = np.bincount(self.nbr_rows, weights=selected[self.nbr], minlength=len(self.indptr) - 1)
        return (1 + counts).astype(np.int64)

    @cached_property
    def table(self) -> np.ndarray:
        """float64 ``[N + 2, N + 2]`` DLR thresholds ``a[n, i]`` (raw units), read-only."""
        return np.ascontiguousarray(ssap.table_for_prior(self.prior, self.n_stages), dtype=np.float64)

    @cached_property
    def ucut(self) -> np.ndarray:
        """float64 ``[N + 2, N + 2]``: P(X <= cut(table[n, i])) under the sampler's distribution
        (:func:`planner.ssap.cut`: the threshold with its tie margin), so a draw with uniform u
        exceeds the threshold iff ``u >= ucut[n, i]`` (1.0 where no support point exceeds it;
        NaN-threshold entries included, never read)."""
        points, cdf = self.sampler.points, self.sampler.cdf
        cuts = np.array([[ssap.cut(t) for t in row] for row in np.nan_to_num(self.table, nan=np.inf).tolist()])
        idx = np.searchsorted(points, cuts, side="right") - 1
        out = np.ascontiguousarray(np.where(idx >= 0, cdf[np.clip(idx, 0, None)], 0.0), dtype=np.float64)
        out.setflags(write=False)
        return out

    @cached_property
    def tails(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The sampler's atoms float64 ``[K]`` with their suffix sums ``[K + 1]``: ``tail_mass[i]``
        = P(X >= points[i]) and ``tail_first[i]`` = E[X; X >= points[i]] (0 at ``i = K``), so
        P(X > c) and E[(X - c)^+] take one binary search (closed-loop's base policy)."""
        points = self.sampler.points
        mass = np.diff(self.sampler.cdf, prepend=0.0)
        tail_mass = np.append(np.cumsum(mass[::-1])[::-1], 0.0)
        tail_first = np.append(np.cumsum((mass * points)[::-1])[::-1], 0.0)
        for arr in (tail_mass, tail_first):
            arr.setflags(write=False)
        return points, tail_mass, tail_first

    @cached_property
    def slot_value(self) -> np.ndarray:
        """float64 ``[N + 1, N + 1]``: ``slot_value[n, d]`` the optimal expected raw total of one
        carrier with ``n`` valid stages and ``d`` passengers left (:func:`ssap.expected_value`)."""
        n_stages = self.n_stages
        out = np.zeros((n_stages + 1, n_stages + 1))
        for n in range(n_stages + 1):
            for d in range(n_stages + 1):
                out[n, d] = ssap.expected_value(self.table, n, d)
        out.setflags(write=False)
        return out


_COMPILED: "weakref.WeakKeyDictionary[Problem, CompiledProblem]" = weakref.WeakKeyDictionary()


def compile_problem(problem: Problem) -> CompiledProblem:
    """The problem's compiled form, built on first call and cached with the problem object."""
    compiled = _COMPILED.get(problem)
    if compiled is None:
        conflict = problem.conflict
        rows, cols = np.nonzero(conflict)
        indptr = np.zeros(conflict.shape[0] + 1, dtype=np.int64)
        np.add.at(indptr, rows + 1, 1)
        indptr = np.cumsum(indptr)
        nbr = cols.astype(np.int64)
        for arr in (indptr, nbr):
            arr.setflags(write=False)
        compiled = CompiledProblem(problem.n_carriers, problem.n_stages, problem.scale,
                                   Sampler.build(problem.prior), conflict, indptr, nbr, problem.prior)
        _COMPILED[problem] = compiled
    return compiled
