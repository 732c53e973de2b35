"""An upper bound on the expected reward of every online policy, much tighter than clairvoyance:
the information-relaxation (duality) bound of Brown, Smith and Sun (Operations Research, 2010).

``U = E_x[max_y (R(y, x) - z(y, x))]``, with a penalty ``z`` of mean zero for every
non-anticipative policy built from the carriers' single-carrier DLR values-to-go (or adaptive: a
conflicted point's share shrinks with the other carriers' earlier deployments in its overlaps);
its inner maximum split into the conflict graph's components, each solved ``exact``, by HiGHS
(``mip``, its dual bound), as the LP relaxation (``lp``) or by the ``separable`` fallback, or
``mixed`` (``exact`` where a component fits, ``mip`` elsewhere), every one a valid upper bound. The derivation, the
model, the methods' limits, the time budget and the API: docs/planner.md, "An upper bound on every
online policy".

Pure: numpy only at import; HiGHS is driven through :mod:`planner.highs` (imported when a model is
solved).
"""
from __future__ import annotations

import math
import time
import weakref
from dataclasses import dataclass
from itertools import combinations

import numpy as np

from planner.compiled import compile_problem
from planner.problem import Problem, sample_observations, valid_stages_left

#: Methods of the inner maximisation (see the module docstring); ``mixed`` picks one per component.
METHODS = ("exact", "mip", "lp", "separable", "mixed")
#: Largest number of stage-set combinations of one component that ``exact`` enumerates.
MAX_COMBINATIONS = 200_000
#: Default samples (observation matrices) of the Monte Carlo mean.
DEFAULT_SAMPLES = 200
#: Default wall-time budget of :func:`upper_bound`, seconds.
DEFAULT_BUDGET_S = 3.0
#: Time limit of one HiGHS branch and bound (``mip``), seconds: beyond it its dual bound is used.
MIP_TIME_LIMIT_S = 1.0
#: Time limit of one HiGHS LP, seconds: beyond it the part falls back to the separable bound.
LP_TIME_LIMIT_S = 60.0
#: Largest HiGHS model (columns) the ``auto`` method solves as a MIP rather than an LP.
MIP_COLUMNS = 2_000


class BoundTooLarge(ValueError):
    """The bound would not fit its time budget. ``str(err)`` is one line."""


# ----------------------------------------------------------------------------- the penalty


def penalty_terms(problem: Problem, x: np.ndarray, scale: float = 1.0,
                  discount: np.ndarray | None = None) -> np.ndarray:
    """float ``[R, N, Dmax + 1]``: ``phi[r, j, d]``, the penalty term of carrier r at stage j with
    d passengers left before j, ``scale * (g(x[r, j]) - E[g(X)])`` at valid stages (0 at invalid
    ones and for ``d = 0``); raw units. ``scale = 0`` is the zero penalty (clairvoyance).

    ``g`` is the carrier's one-stage Bellman value ``max(rho x + V(j+1, d-1), V(j+1, d))`` (deploy
    forced when its valid stages left equal ``d``) of the single-carrier values
    :func:`carrier_values` under the per-point ``discount`` rho (None: rho = 1, the DLR values, and
    ``E[g(X)]`` is the DLR slot value S(n, d)). Any rho gives a term of mean zero given the past.

    ``x``: float ``[R, N]`` observations (NaN = ∅; every scheduled stage must be observed).
    """
    n_carriers, n_stages = problem.valid.shape
    dmax = int(problem.passengers.max(initial=0))
    out = np.zeros((n_carriers, n_stages, dmax + 1))
    if scale == 0.0 or dmax == 0:
        return out
    left = valid_stages_left(problem.valid)[:, :n_stages]  # n at each (r, j)
    r_idx, j_idx = np.nonzero(problem.valid)
    n = left[r_idx, j_idx]
    xv = np.asarray(x, dtype=float)[r_idx, j_idx]
    if discount is None:
        slot = compile_problem(problem).slot_value  # [N + 1, N + 1], S(n, d), d clipped to n

        def after(dd):  # V(j + 1, dd): the DLR value of n - 1 stages
            return slot[n - 1, np.minimum(dd, n - 1)]

        now = [slot[n, np.minimum(d, n)] for d in range(dmax + 1)]
        rho = np.ones_like(xv)
    else:
        values = carrier_values(problem, discount)  # [R, N + 1, Dmax + 1]

        def after(dd):
            return values[r_idx, j_idx + 1, np.minimum(dd, dmax)]

        now = [values[r_idx, j_idx, d] for d in range(dmax + 1)]
        rho = np.asarray(discount, dtype=float)[r_idx, j_idx]
    for d in range(1, dmax + 1):
        dd = np.minimum(d, n)
        deploy = rho * xv + after(dd - 1)
        stay = after(dd)
        value = np.where(n <= d, deploy, np.maximum(deploy, stay))
        out[r_idx, j_idx, d] = scale * (value - now[d])
    return out


def _expected_max(prior):
    """A function ``c -> E[max(X, c)]`` (float array in, float array out) exact for the prior: a sum
    over the support (discrete; tail mass below ``priors.TAIL`` dropped) or tail integrals
    (continuous, :mod:`planner.ssap`'s quadrature)."""
    from planner import priors, ssap

    if priors.is_discrete(prior):
        points, mass = priors.support(prior)

        def expected(c):
            c = np.asarray(c, dtype=float)
            return (mass[None, :] * np.maximum(points[None, :], c.reshape(-1, 1))).sum(axis=1).reshape(c.shape)

        return expected
    clipped = ssap.clipped_mean(prior)

    def expected(c):
        c = np.asarray(c, dtype=float)
        return np.array([clipped(v, np.inf) for v in c.ravel().tolist()]).reshape(c.shape)

    return expected


_VALUES: "weakref.WeakKeyDictionary[Problem, dict]" = weakref.WeakKeyDictionary()


def carrier_values(problem: Problem, discount: np.ndarray) -> np.ndarray:
    """float ``[R, N + 1, Dmax + 1]``: ``V[r, j, d]``, the optimal expected total (raw units) of
    carrier r alone from stage j on with d passengers left (clipped to its valid stages left) when
    a deployment at (r, j') earns ``discount[r, j'] * x``; ``V[r, N, :] = 0``. The DLR recurrence
    with a point-dependent reward: ``V(j, d) = E[max(rho X + V(j+1, d-1), V(j+1, d))]``, the deploy
    forced when the stages left equal d. ``discount``: float ``[R, N]``, positive at valid points."""
    rho_all = np.ascontiguousarray(discount, dtype=float)
    if rho_all.shape != problem.valid.shape or not (rho_all[problem.valid] > 0).all():
        raise ValueError("discount: expected a positive [R, N] array at every scheduled point")
    cache = _VALUES.setdefault(problem, {})
    key = rho_all.tobytes()
    if key not in cache:
        cache[key] = _carrier_values(problem, rho_all)
        cache[key].setflags(write=False)
    return cache[key]


def _carrier_values(problem: Problem, rho_all: np.ndarray) -> np.ndarray:
    n_carriers, n_stages = problem.valid.shape
    dmax = int(problem.passengers.max(initial=0))
    left = valid_stages_left(problem.valid)
    expected_max = _expected_max(problem.prior)
    mean = float(problem.prior.mean())
    values = np.zeros((n_carriers, n_stages + 1, dmax + 1))
    for j in range(n_stages - 1, -1, -1):
        values[:, j] = values[:, j + 1]
        rows = np.flatnonzero(problem.valid[:, j])
        if len(rows) == 0:
            continue
        n, rho, nxt = left[rows, j], rho_all[rows, j], values[rows, j + 1]
        for d in range(1, dmax + 1):
            dd = np.minimum(d, n)
            a = nxt[np.arange(len(rows)), dd - 1]
            b = nxt[np.arange(len(rows)), np.minimum(dd, dmax)]
            forced = dd >= n
            free = np.flatnonzero(~forced)
            out = rho * mean + a
            if len(free):
                out[free] = a[free] + rho[free] * expected_max((b[free] - a[free]) / rho[free])
            values[rows, j, d] = out
    return values


#: Strengths ``c`` of :func:`conflict_discount` tried by :func:`upper_bound` (``strength="auto"``);
#: 0 is the DLR penalty.
STRENGTHS = (0.0, 0.25, 0.5)


def conflict_discount(problem: Problem, strength: float, adaptive: bool = False) -> np.ndarray:
    """float ``[R, N]``: ``1 / (1 + strength * m)`` at each point, ``m`` the expected number of
    conflicting deployments of the other valid points (each carrier deploying at a uniformly
    random ``min(D_r, valid stages)`` of its valid stages); 1 at invalid points. A guess of the
    share of ``x`` a deployment keeps; any positive array keeps the penalty's mean zero.
    ``adaptive``: the discount of the adaptive penalty, whose count ``k`` replaces the guess for
    the other carriers' points at earlier stages: ``m`` leaves those out."""
    n_carriers, n_stages = problem.valid.shape
    total = problem.valid.sum(axis=1)
    rate = np.minimum(problem.passengers, total) / np.maximum(total, 1)  # [R]
    pi = (problem.valid * rate[:, None]).ravel().astype(float)
    comp = compile_problem(problem)
    rows, cols = comp.nbr_rows, comp.nbr
    if adaptive:
        keep = (rows // n_stages == cols // n_stages) | (cols % n_stages >= rows % n_stages)
        rows, cols = rows[keep], cols[keep]
    m = np.zeros(n_carriers * n_stages)
    np.add.at(m, rows, pi[cols])
    return (1.0 / (1.0 + strength * m)).reshape(n_carriers, n_stages)


# ----------------------------------------------------------------------------- inner maximum


@dataclass(frozen=True)
class _Component:
    """Carriers joined by conflicts among valid points, with their valid stages and counts."""

    carriers: tuple[int, ...]
    stages: tuple[np.ndarray, ...]  # valid stages of each carrier, ascending
    ks: tuple[int, ...]             # deployments of each carrier: min(D_r, valid stages)

    def combinations(self) -> float:
        return math.prod(float(math.comb(len(s), k)) for s, k in zip(self.stages, self.ks))


_COMPONENTS: "weakref.WeakKeyDictionary[Problem, list]" = weakref.WeakKeyDictionary()


def _components(problem: Problem) -> list[_Component]:
    """Connected components of the carriers linked by a conflict between two scheduled-valid
    points (a carrier with no such conflict is a component of its own); cached per problem."""
    found = _COMPONENTS.get(problem)
    if found is None:
        found = _COMPONENTS[problem] = _find_components(problem, problem.valid)
    return found


def _find_components(problem: Problem, valid: np.ndarray) -> list[_Component]:
    n_carriers, n_stages = valid.shape
    flat_valid = valid.ravel()
    comp = compile_problem(problem)
    rows, cols = comp.nbr_rows, comp.nbr
    keep = flat_valid[rows] & flat_valid[cols]
    parent = list(range(n_carriers))

    def find(a):
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    for a, b in zip((rows[keep] // n_stages).tolist(), (cols[keep] // n_stages).tolist()):
        ra, rb = find(a), find(b)
        if ra != rb:
            parent[max(ra, rb)] = min(ra, rb)
    groups: dict[int, list[int]] = {}
    for r in range(n_carriers):
        groups.setdefault(find(r), []).append(r)
    out = []
    for members in groups.values():
        stages = tuple(np.flatnonzero(valid[r]) for r in members)
        ks = tuple(min(int(problem.passengers[r]), len(s)) for r, s in zip(members, stages))
        out.append(_Component(tuple(members), stages, ks))
    return out


@dataclass(frozen=True, eq=False)
class _Enumeration:
    """Every combination of one component's stage sets, as arrays (built once per problem).

    Attributes:
        flat: int64 ``[P]`` the component's valid flat points.
        conflict: float ``[P, P]`` their conflict matrix.
        sel: float ``[C, P]`` 1 where combination c deploys at point p.
        options: per carrier ``(stages [n], left [O, n] passengers left before each stage,
            choice [C] the carrier's option in each combination)``.
        dleft: int16 ``[C, P]`` passengers left before point p's stage in combination c.
    """

    flat: np.ndarray
    conflict: np.ndarray
    sel: np.ndarray
    options: tuple
    dleft: np.ndarray


_ENUMERATIONS: "weakref.WeakKeyDictionary[Problem, dict]" = weakref.WeakKeyDictionary()


def _flat_points(problem: Problem, part: _Component) -> np.ndarray:
    """int64 ``[P]``: the component's valid flat points, carrier by carrier, stages ascending (the
    order of :class:`_Enumeration` and :class:`_Adaptive`)."""
    return np.concatenate([r * problem.n_stages + s for r, s in zip(part.carriers, part.stages)])


def _enumeration(problem: Problem, part: _Component) -> _Enumeration:
    cache = _ENUMERATIONS.setdefault(problem, {})
    found = cache.get(part.carriers)
    if found is not None:
        return found
    flat = _flat_points(problem, part)
    offsets = np.concatenate(([0], np.cumsum([len(s) for s in part.stages])))
    masks = []
    for stages, k in zip(part.stages, part.ks):
        opts = list(combinations(range(len(stages)), k))
        mask = np.zeros((len(opts), len(stages)), dtype=bool)
        for o_idx, o in enumerate(opts):
            mask[o_idx, list(o)] = True
        masks.append(mask)
    grids = np.meshgrid(*[np.arange(len(m)) for m in masks], indexing="ij")
    choices = [g.ravel() for g in grids]
    sel = np.zeros((len(choices[0]), len(flat)))
    dleft = np.zeros(sel.shape, dtype=np.int16)
    options = []
    for i, (r, stages, mask, choice) in enumerate(zip(part.carriers, part.stages, masks, choices)):
        sel[:, offsets[i]:offsets[i + 1]] = mask[choice]
        before = np.concatenate((np.zeros((len(mask), 1), dtype=np.int64), np.cumsum(mask, axis=1)[:, :-1]), axis=1)
        options.append((stages, int(problem.passengers[r]) - before, choice))
        dleft[:, offsets[i]:offsets[i + 1]] = options[-1][1][choice]
    out = _Enumeration(flat, problem.conflict[np.ix_(flat, flat)].astype(float), sel, tuple(options), dleft)
    cache[part.carriers] = out
    return out


def _exact_component(problem: Problem, x: np.ndarray, phi: np.ndarray, part: _Component,
                     adaptive: "_Adaptive | None" = None, scale: float = 1.0) -> float:
    """Maximum of (reward - penalty) over every combination of the component's stage sets, raw;
    with ``adaptive`` (:func:`_adaptive`, of the discount ``phi`` was built with) the penalty is
    the adaptive one (:func:`adaptive_terms`)."""
    en = _enumeration(problem, part)
    xs = np.asarray(x, dtype=float).ravel()[en.flat]
    value = (en.sel * xs[None, :] / (1.0 + en.sel @ en.conflict)).sum(axis=1)
    for r, (stages, left, choice) in zip(part.carriers, en.options):
        value -= phi[r, stages[None, :], left].sum(axis=1)[choice]
    if adaptive is not None and len(adaptive.points):
        terms = scale * adaptive.terms(xs[adaptive.points])  # [L, Dmax + 1, K + 1]
        late = np.arange(len(adaptive.points))[None, :]
        d = en.dleft[:, adaptive.points]
        k = (en.sel @ adaptive.earlier).astype(np.int64)  # [C, L] earlier conflicting deployments
        value -= (terms[late, d, k] - terms[late, d, 0]).sum(axis=1)
    return float(value.max())


# ----------------------------------------------------------------------------- the adaptive penalty


@dataclass(frozen=True, eq=False)
class _Adaptive:
    """The adaptive penalty's tables for one component and discount (built once per problem).

    ``points``: int ``[L]`` positions (in the component's enumeration) of its *late* points, those
    that share an overlap with a point of another carrier at an earlier stage; ``earlier``: float
    ``[P, L]``, 1 where enumeration point a is such an earlier point of late point l. Per late point,
    passengers left d and earlier deployments k: ``rho [L, K + 1]`` the share ``rho_a / (1 + k)``,
    ``deploy``/``stay`` ``[L, Dmax + 1]`` the values after the stage (``V(j+1, d-1)``,
    ``V(j+1, d)``), ``forced`` ``[L, Dmax + 1]``, ``mean [L, Dmax + 1, K + 1]`` the expectation of
    the one-stage value (``E[g(X)]``); d = 0 earns no term.
    """

    points: np.ndarray
    earlier: np.ndarray
    rho: np.ndarray
    deploy: np.ndarray
    stay: np.ndarray
    forced: np.ndarray
    mean: np.ndarray

    def terms(self, x: np.ndarray) -> np.ndarray:
        """float ``[L, Dmax + 1, K + 1]``: ``g(x) - E[g(X)]`` at each late point's observation ``x [L]``."""
        deploy = self.rho[:, None, :] * x[:, None, None] + self.deploy[:, :, None]
        value = np.where(self.forced[:, :, None], deploy, np.maximum(deploy, self.stay[:, :, None]))
        out = value - self.mean
        out[:, 0, :] = 0.0
        return out


_ADAPTIVE: "weakref.WeakKeyDictionary[Problem, dict]" = weakref.WeakKeyDictionary()


def _adaptive(problem: Problem, part: _Component, discount: np.ndarray | None) -> _Adaptive:
    rho_all = np.ones(problem.valid.shape) if discount is None else np.asarray(discount, dtype=float)
    cache = _ADAPTIVE.setdefault(problem, {})
    key = (part.carriers, rho_all.tobytes())
    if key in cache:
        return cache[key]
    n_stages = problem.n_stages
    flat = _flat_points(problem, part)  # the enumeration's point order, without enumerating
    carrier, stage = flat // n_stages, flat % n_stages
    conflict = problem.conflict[np.ix_(flat, flat)]
    earlier = conflict & (stage[:, None] < stage[None, :]) & (carrier[:, None] != carrier[None, :])
    points = np.flatnonzero(earlier.any(axis=0))
    earlier = earlier[:, points].astype(float)
    dmax = int(problem.passengers.max(initial=0))
    kmax = int(earlier.sum(axis=0).max(initial=0))
    values = carrier_values(problem, rho_all)
    left = valid_stages_left(problem.valid)
    r, j = carrier[points], stage[points]
    n = left[r, j][:, None]
    d = np.arange(dmax + 1)[None, :]
    dd = np.minimum(d, n)
    deploy = values[r[:, None], j[:, None] + 1, np.clip(dd - 1, 0, dmax)]
    stay = values[r[:, None], j[:, None] + 1, np.minimum(dd, dmax)]
    forced = n <= d
    rho = rho_all[r, j][:, None] / (1.0 + np.arange(kmax + 1)[None, :])
    expected_max = _expected_max(problem.prior)
    rho3 = np.broadcast_to(rho[:, None, :], (len(points), dmax + 1, kmax + 1))
    a3 = np.broadcast_to(deploy[:, :, None], rho3.shape)
    b3 = np.broadcast_to(stay[:, :, None], rho3.shape)
    free_mean = a3 + rho3 * expected_max((b3 - a3) / rho3)
    mean = np.where(forced[:, :, None], rho3 * float(problem.prior.mean()) + a3, free_mean)
    out = cache[key] = _Adaptive(points, earlier, rho, deploy, stay, forced, mean)
    return out


def adaptive_terms(problem: Problem, x: np.ndarray, deployed: np.ndarray, discount: np.ndarray | None = None,
                   scale: float = 1.0) -> np.ndarray:
    """float ``[R, N, Dmax + 1]``: the adaptive penalty's terms along one deployment set ``deployed``
    (bool ``[R, N]``): at each valid point a the term of :func:`penalty_terms` with the share
    ``rho_a / (1 + k_a)`` in place of ``rho_a``, ``k_a`` the points of *other* carriers deployed
    at stages before a's that share an overlap with a (known before a's observation, so the term
    keeps its mean zero given the past). The penalty of ``deployed`` is the sum of the terms at each
    carrier's (stage, passengers left before it); the exact inner maximum subtracts the same terms.
    The reference implementation the enumeration is tested against (not used by the bound)."""
    n_carriers, n_stages = problem.valid.shape
    base = penalty_terms(problem, x, scale, discount)
    rho_all = np.ones(problem.valid.shape) if discount is None else np.asarray(discount, dtype=float)
    flat = np.asarray(deployed, bool).ravel()
    out = base.copy()
    dmax = base.shape[2] - 1
    if dmax == 0 or scale == 0.0:
        return out
    values = carrier_values(problem, rho_all)
    left = valid_stages_left(problem.valid)
    expected_max = None
    means = _REFERENCE_MEANS.setdefault(problem, {}).setdefault(rho_all.tobytes(), {})  # (r, j, d, k) -> E[g(X)]
    comp = compile_problem(problem)
    for a in np.flatnonzero(problem.valid.ravel()):
        r, j = divmod(int(a), n_stages)
        nbrs = comp.nbr[comp.indptr[a]:comp.indptr[a + 1]]
        k = int(sum(flat[b] and b % n_stages < j and b // n_stages != r for b in nbrs.tolist()))
        if k == 0:
            continue
        rho, n = rho_all[r, j] / (1.0 + k), int(left[r, j])
        for d in range(1, dmax + 1):
            dd = min(d, n)
            deploy, stay = values[r, j + 1, dd - 1], values[r, j + 1, min(dd, dmax)]
            if n <= d:
                out[r, j, d] = scale * rho * (float(x[r, j]) - float(problem.prior.mean()))
            else:
                if (r, j, d, k) not in means:
                    expected_max = expected_max or _expected_max(problem.prior)
                    means[r, j, d, k] = deploy + rho * float(expected_max(np.array([(stay - deploy) / rho]))[0])
                out[r, j, d] = scale * (max(rho * float(x[r, j]) + deploy, stay) - means[r, j, d, k])
    return out


_REFERENCE_MEANS: "weakref.WeakKeyDictionary[Problem, dict]" = weakref.WeakKeyDictionary()


def _alone_value(problem: Problem, x: np.ndarray, phi: np.ndarray, r: int, stages: np.ndarray, k: int) -> float:
    """Maximum of (reward - penalty) of a carrier without valid conflicts: a DP over its stages."""
    d0 = int(problem.passengers[r])
    if k == 0 or len(stages) == 0:
        return 0.0
    end = d0 - k
    best = {d0: 0.0}  # passengers left -> best value so far
    n = len(stages)
    for t, j in enumerate(stages):
        nxt: dict[int, float] = {}
        for d, val in best.items():
            base = val - phi[r, j, d]
            if d - end <= n - t - 1:  # may stay
                nxt[d] = max(nxt.get(d, -np.inf), base)
            if d - 1 >= end:
                nxt[d - 1] = max(nxt.get(d - 1, -np.inf), base + float(x[r, j]))
        best = nxt
    return best[end]


def _separable_value(problem: Problem, x: np.ndarray, phi: np.ndarray, parts: list[_Component]) -> float:
    """An upper bound on the inner maximum that ignores how carriers' deployments interact: each
    point earns at most ``x`` (``x >= 0``) or ``x / (1 + M)`` (``x < 0``, ``M`` its valid conflicting
    points), then every carrier's best stage set by :func:`_alone_value`; raw units."""
    flat_valid = problem.valid.ravel()
    comp = compile_problem(problem)
    rows, cols = comp.nbr_rows, comp.nbr
    keep = flat_valid[rows] & flat_valid[cols]
    many = np.bincount(rows[keep], minlength=len(flat_valid)).reshape(problem.valid.shape)
    best = np.where(x >= 0, x, x / (1.0 + many))
    return sum(_alone_value(problem, best, phi, r, s, k)
               for part in parts for r, s, k in zip(part.carriers, part.stages, part.ks))


def inner_maximum(problem: Problem, x: np.ndarray, method: str = "exact", penalty_scale: float = 1.0,
                  mip_time_limit_s: float = MIP_TIME_LIMIT_S, discount: np.ndarray | None = None,
                  adaptive: bool = False, mip_max_nodes: int | None = None) -> float:
    """``max_y (R(y, x) - z(y, x))`` for one observation matrix, or an upper bound on it; raw units.

    Args:
        x: float ``[R, N]``, an observation at every scheduled stage.
        method: ``exact`` (enumeration; :class:`BoundTooLarge` for a component beyond
            :data:`MAX_COMBINATIONS`), ``mip`` (the smaller of the HiGHS dual bound, exact when the
            search finishes within ``mip_time_limit_s``, and the LP), ``lp`` (the linear
            relaxation), ``separable`` (interactions ignored; the fallback of an LP HiGHS cannot
            finish within :data:`LP_TIME_LIMIT_S`) or ``mixed`` (per component: ``exact`` within
            :data:`MAX_COMBINATIONS`, else ``mip``).
        penalty_scale: 1.0 for the DLR penalty, 0.0 for none (the clairvoyant optimum).
        discount: float ``[R, N]``, the penalty's per-point discount (:func:`penalty_terms`;
            None: the DLR values).
        adaptive: the adaptive penalty (:func:`adaptive_terms`: a conflicted point's share shrinks
            with the other carriers' earlier deployments in its overlaps), under every method
            (HiGHS: :func:`_adaptive_rows`; ``separable``: :func:`_separable_phi`).
        mip_max_nodes: the HiGHS branch and bound (``mip``, ``mixed``) stops after this many
            nodes and gives its dual bound (1: the root node's; None: no limit). Valid like a
            search stopped by ``mip_time_limit_s``, and the same on every machine as long as that
            limit is not reached first.
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    x = np.asarray(x, dtype=float)
    if np.isnan(x[problem.valid]).any():
        raise ValueError("the bound needs an observation at every scheduled stage (found NaN at a valid stage)")
    x = np.where(problem.valid, x, 0.0)
    phi = penalty_terms(problem, x, penalty_scale, discount)
    parts = _components(problem)
    adaptive = bool(adaptive) and penalty_scale != 0.0

    def tables(part):  # the adaptive penalty's tables of a multi-carrier component, or None
        return _adaptive(problem, part, discount) if adaptive else None

    if method == "separable":  # each component's adaptive lower terms on its own points, then one pass
        for part in parts:
            phi = _separable_phi(problem, x, phi, part, tables(part), penalty_scale)
        return _separable_value(problem, x, phi, parts)
    # Components are independent given x (the penalty and, with the adaptive penalty, its counts
    # k are per component), so the sum of per-component upper bounds bounds the whole maximum.
    total = 0.0
    for part in parts:
        how = method
        if method == "mixed":
            how = "exact" if part.combinations() <= MAX_COMBINATIONS else "mip"
        if len(part.carriers) == 1:
            total += _alone_value(problem, x, phi, part.carriers[0], part.stages[0], part.ks[0])
        elif how == "exact":
            if part.combinations() > MAX_COMBINATIONS:
                raise BoundTooLarge(f"upper bound: a component of {len(part.carriers)} carriers has "
                                    f"{part.combinations():.3g} stage-set combinations (exact limit {MAX_COMBINATIONS:,})")
            total += _exact_component(problem, x, phi, part, tables(part), penalty_scale)
        else:
            value = _highs_value(problem, x, phi, part, False, LP_TIME_LIMIT_S, tables(part), penalty_scale)
            if how == "mip":
                value = min(value, _highs_value(problem, x, phi, part, True, mip_time_limit_s, tables(part),
                                                penalty_scale, mip_max_nodes))
            if not np.isfinite(value):  # HiGHS did not finish: the interaction-free bound of this part
                value = _separable_value(problem, x, _separable_phi(problem, x, phi, part, tables(part),
                                                                    penalty_scale), [part])
            total += value
    return total


def _separable_phi(problem: Problem, x: np.ndarray, phi: np.ndarray, part: _Component,
                   adaptive: "_Adaptive | None", scale: float) -> np.ndarray:
    """``phi``, or with ``adaptive`` a lower bound on the adaptive penalty's term at each late
    point of ``part`` (the fixed term plus the smallest adaptive correction over k), so that
    :func:`_separable_value` of it stays >= the component's inner maximum under the adaptive penalty."""
    if adaptive is None or not len(adaptive.points):
        return phi
    flat = _flat_points(problem, part)[adaptive.points]
    terms = scale * adaptive.terms(np.asarray(x, dtype=float).ravel()[flat])  # [L, Dmax + 1, K + 1]
    kmax = adaptive.earlier.sum(axis=0).astype(np.int64)  # [L] the counts each late point can reach
    reach = np.arange(terms.shape[2])[None, None, :] <= kmax[:, None, None]
    low = np.where(reach, terms - terms[:, :, :1], np.inf).min(axis=2)  # [L, Dmax + 1], <= 0
    out = phi.copy()
    r, j = np.divmod(flat, problem.n_stages)
    out[r, j, :] += low
    return out


# ----------------------------------------------------------------------------- the HiGHS model


def carrier_flow(model, problem: Problem, r: int, stages: np.ndarray, k: int, phi: np.ndarray,
                 integer: bool, nodes: dict | None = None) -> dict[int, list[int]]:
    """Carrier r's deployments as a unit flow through its (stage, passengers left) network in
    ``model`` (a :class:`planner.highs.Model`): one arc per move (stay, or deploy: one passenger
    fewer) from each reachable node, each costing ``-phi[r, j, d]``; the carrier deploys exactly
    ``k`` times. Returns ``{flat point: [its deploy arcs]}`` (a point is deployed at when one of
    its arcs carries the flow). ``nodes``: filled with ``{(flat point, d): [the arcs out of node
    (its stage, d passengers left)]}`` (the flow passes one node per stage)."""
    n_stages = problem.n_stages
    d0 = int(problem.passengers[r])
    end, n = d0 - k, len(stages)
    inflow: dict[tuple[int, int], list[int]] = {}
    deploy_arcs: dict[int, list[int]] = {}
    for t, j in enumerate(stages):
        a = r * n_stages + int(j)
        for d in range(end, d0 + 1):
            if d0 - d > t or d - end > n - t:
                continue  # node (t, d) unreachable
            out = []
            cost = -float(phi[r, j, d])
            if d - end <= n - t - 1:
                out.append(model.var(cost, is_int=integer))
                inflow.setdefault((t + 1, d), []).append(out[-1])
            if d - 1 >= end:
                out.append(model.var(cost, is_int=integer))
                inflow.setdefault((t + 1, d - 1), []).append(out[-1])
                deploy_arcs.setdefault(a, []).append(out[-1])
            if nodes is not None:
                nodes[(a, d)] = out
            if t == 0:
                model.row(1.0, 1.0, out, [1.0] * len(out))
            else:
                ins = inflow.get((t, d), [])
                model.row(0.0, 0.0, out + ins, [1.0] * len(out) + [-1.0] * len(ins))
    return deploy_arcs


def _highs_value(problem: Problem, x: np.ndarray, phi: np.ndarray, part: _Component, integer: bool,
                 time_limit_s: float, adaptive: "_Adaptive | None" = None, scale: float = 1.0,
                 max_nodes: int | None = None) -> float:
    """The component's model (module docstring) solved by HiGHS: the MIP's dual bound
    (``integer``) or the LP optimum; raw units. Both are >= the component's inner maximum. With
    ``adaptive`` (:func:`_adaptive`, of the discount ``phi`` was built with) the penalty is the
    adaptive one (:func:`_adaptive_rows`)."""
    from planner.highs import Model

    n_stages = problem.n_stages
    model = Model()
    var = model.var
    flat_points = np.concatenate([r * n_stages + s for r, s in zip(part.carriers, part.stages)])
    in_part = np.zeros(problem.n_carriers * n_stages, dtype=bool)
    in_part[flat_points] = True
    comp = compile_problem(problem)
    xs = np.asarray(x, dtype=float).ravel()
    deploy_arcs: dict[int, list[int]] = {}
    nodes: dict[tuple[int, int], list[int]] | None = {} if adaptive is not None else None
    for r, stages, k in zip(part.carriers, part.stages, part.ks):
        deploy_arcs.update(carrier_flow(model, problem, r, stages, k, phi, integer, nodes))
    if adaptive is not None and len(adaptive.points):
        _adaptive_rows(model, problem, x, part, adaptive, scale, nodes, deploy_arcs, integer)
    cols_cost = model.cost
    y = {}
    for a, arcs in deploy_arcs.items():
        nbrs = comp.nbr[comp.indptr[a]:comp.indptr[a + 1]]
        nbrs = nbrs[in_part[nbrs]]
        if len(nbrs) == 0:
            for arc in arcs:
                cols_cost[arc] += float(xs[a])
            continue
        y[a] = var(0.0)
        model.row(0.0, 0.0, [y[a]] + arcs, [1.0] + [-1.0] * len(arcs))
    q = {}
    for a in y:
        for b in comp.nbr[comp.indptr[a]:comp.indptr[a + 1]].tolist():
            if b in y and a < b:
                q[(a, b)] = v = var(0.0)
                model.row(-1.0, np.inf, [v, y[a], y[b]], [1.0, -1.0, -1.0])
                model.row(-np.inf, 0.0, [v, y[a]], [1.0, -1.0])
                model.row(-np.inf, 0.0, [v, y[b]], [1.0, -1.0])
    for a, ya in y.items():
        pairs = [q[(min(a, b), max(a, b))] for b in comp.nbr[comp.indptr[a]:comp.indptr[a + 1]].tolist() if b in y]
        xa = float(xs[a])
        if xa == 0.0:
            continue
        ws = [var(xa / (1.0 + m), is_int=integer) for m in range(len(pairs) + 1)]
        model.row(0.0, 0.0, ws + [ya], [1.0] * len(ws) + [-1.0])
        lo, hi = (0.0, np.inf) if xa > 0 else (-np.inf, 0.0)
        model.row(lo, hi, ws + pairs, list(range(len(ws))) + [-1.0] * len(pairs))
    # The MIP's dual bound (+inf when stopped before the root LP); the LP's optimum, +inf when not
    # solved in time (the caller then falls back to the separable bound).
    return model.solve(integer, time_limit_s, max_nodes).bound


def _adaptive_rows(model, problem: Problem, x: np.ndarray, part: _Component, adaptive: "_Adaptive", scale: float,
                   nodes: dict, deploy_arcs: dict, integer: bool) -> None:
    """The adaptive penalty in the flow model: at each late point l (carrier r's stage j) binary
    ``u[l, d, k]`` = "r is at node (j, d) and k earlier conflicting points of other carriers are
    deployed at", with ``Σ_k u[l, d, k]`` = the flow through node (j, d) and
    ``Σ_{d,k} k u[l, d, k]`` = the deploy arcs at those earlier points; ``u[l, d, k]`` earns
    ``-(term(d, k) - term(d, 0))``, the adaptive term in place of the fixed one the arcs already
    pay. At integer flows the u are forced (one node, one k): the exact adaptive penalty; every
    true deployment set is feasible, so the LP and the MIP's dual bound stay >= the maximum."""
    flat = _flat_points(problem, part)
    xs = np.asarray(x, dtype=float).ravel()[flat]
    terms = scale * adaptive.terms(xs[adaptive.points])  # [L, Dmax + 1, K + 1]
    for late, point in enumerate(adaptive.points.tolist()):
        a = int(flat[point])
        earlier_arcs = [arc for b in flat[adaptive.earlier[:, late] > 0].tolist() for arc in deploy_arcs.get(b, [])]
        kmax = int(adaptive.earlier[:, late].sum())
        count_cols, count_coefs = [], []
        for d in range(terms.shape[1]):
            out = nodes.get((a, d))
            if out is None:
                continue  # node unreachable
            us = [model.var(-float(terms[late, d, k] - terms[late, d, 0]), is_int=integer) for k in range(kmax + 1)]
            model.row(0.0, 0.0, us + out, [1.0] * len(us) + [-1.0] * len(out))
            count_cols += us[1:]
            count_coefs += list(range(1, kmax + 1))
        model.row(0.0, 0.0, count_cols + earlier_arcs, [float(c) for c in count_coefs] + [-1.0] * len(earlier_arcs))
        if kmax > 1:
            # Valid at integer points, tightening the LP: "k >= 1" is at most the count and at
            # least each earlier deployment.
            ones = [1.0] * len(count_cols)
            model.row(-np.inf, 0.0, count_cols + earlier_arcs, ones + [-1.0] * len(earlier_arcs))
            for b in flat[adaptive.earlier[:, late] > 0].tolist():
                arcs = deploy_arcs.get(b, [])
                if arcs:
                    model.row(0.0, np.inf, count_cols + arcs, ones + [-1.0] * len(arcs))


# ----------------------------------------------------------------------------- the bound


@dataclass(frozen=True)
class UpperBound:
    """A Monte Carlo estimate of the information-relaxation bound.

    Attributes:
        expected_reward: the mean of the inner maxima over ``samples`` observation matrices drawn
            from the prior, normalised (raw / ``problem.scale``) like ``online_optimum``.
        stderr: its standard error (sample standard deviation / sqrt(samples)), same units.
        method: how the inner maxima were bounded: ``exact``, ``mip``, ``lp`` or ``separable``
            (components of one carrier are always solved exactly).
        samples: observation matrices drawn.
        penalty_scale: 1.0 (the DLR penalty) or 0.0 (none: the clairvoyant bound's mean).
        strength: the penalty's conflict discount (:func:`conflict_discount`; 0: the DLR values).
        pilot_samples: observation matrices drawn first to choose ``strength`` among
            :data:`STRENGTHS`, then discarded (0: no choice made).
        adaptive: the penalty is the adaptive one (:func:`adaptive_terms`).
    """

    expected_reward: float
    stderr: float
    method: str
    samples: int
    penalty_scale: float = 1.0
    strength: float = 0.0
    pilot_samples: int = 0
    adaptive: bool = False


def auto_method(problem: Problem) -> str:
    """``exact`` when every component has at most :data:`MAX_COMBINATIONS` stage-set combinations,
    else ``mip`` when the HiGHS models have at most :data:`MIP_COLUMNS` columns, else ``lp``.
    O(R*N + conflicts)."""
    parts = _components(problem)
    if all(p.combinations() <= MAX_COMBINATIONS for p in parts):
        return "exact"
    return "mip" if _lp_columns(problem, parts) <= MIP_COLUMNS else "lp"


#: Cost model of one sample (seconds on one core of the development machine under the usual
#: load): per enumerated combination and point (``exact``); per LP column (``lp``; HiGHS is
#: superlinear, hence the quadratic term) plus ``model`` per HiGHS model; ``mip`` times the LP
#: (typical; one branch and bound is capped at :data:`MIP_TIME_LIMIT_S`); per decision point
#: (``separable``). ``exact`` covers the adaptive penalty too (it takes 1.4 to 2 times the fixed
#: penalty's time, well within the figure's margin over today's measured time per combination).
_COST = {"exact": 2e-7, "lp": 4e-5, "lp2": 1.5e-9, "model": 0.01, "mip": 6.0, "separable": 2e-6}


def _lp_columns(problem: Problem, parts: list[_Component]) -> int:
    """Columns of the HiGHS models of the multi-carrier components (arcs, y, q and w variables)."""
    comp = compile_problem(problem)
    flat_valid = problem.valid.ravel()
    rows, cols = comp.nbr_rows, comp.nbr
    keep = flat_valid[rows] & flat_valid[cols]
    pairs = int(keep.sum())  # ordered pairs: q columns once per pair, w columns once per entry
    columns = 0
    for part in parts:
        if len(part.carriers) > 1:
            columns += sum(2 * len(s) * (k + 1) for s, k in zip(part.stages, part.ks))
    return columns + int(1.5 * pairs) + 3 * int(flat_valid.sum())


def estimate_seconds(problem: Problem, method: str, samples: int) -> float:
    """Predicted wall time of :func:`upper_bound` (``samples`` samples, ``method``), from the
    instance's sizes alone (O(R*N + conflicts), no solve), by the cost model :data:`_COST`."""
    parts = _components(problem)
    points = int(problem.valid.sum())
    per = _COST["separable"] * max(points, 1)

    def enumerated(some):
        return sum(_COST["exact"] * p.combinations() * sum(len(s) for s in p.stages)
                   for p in some if len(p.carriers) > 1)

    def highs(some, mip):
        columns = _lp_columns(problem, some)
        models = sum(len(p.carriers) > 1 for p in some)
        lp = _COST["lp"] * columns + _COST["lp2"] * columns ** 2 + _COST["model"] * models
        return lp * (_COST["mip"] if mip else 1.0)

    if method == "exact":
        per += enumerated(parts)
    elif method in ("lp", "mip"):
        per += highs(parts, method == "mip")
    elif method == "mixed":
        big = [p for p in parts if p.combinations() > MAX_COMBINATIONS]
        per += enumerated([p for p in parts if p.combinations() <= MAX_COMBINATIONS])
        per += highs(big, True) if big else 0.0
    return per * samples


def check_budget(problem: Problem, method: str, samples: int, budget_s: float) -> None:
    """Raise :class:`BoundTooLarge` (one line) when :func:`estimate_seconds` exceeds ``budget_s``."""
    need = estimate_seconds(problem, method, samples)
    if need > budget_s:
        raise BoundTooLarge(f"upper bound: {samples} samples by {method} would take about {need:.3g} s, beyond the "
                            f"{budget_s:g} s budget (R={problem.n_carriers}, N={problem.n_stages})")


def choose_strength(problem: Problem, rng: np.random.Generator, method: str, pilot: int | None = None,
                    adaptive: bool = False, mip_time_limit_s: float = MIP_TIME_LIMIT_S,
                    mip_max_nodes: int | None = None) -> float:
    """The strength of :data:`STRENGTHS` whose penalty (``adaptive`` or not, :func:`inner_maximum`)
    gives the smallest mean inner maximum on ``pilot`` observation matrices drawn from ``rng`` (the
    same matrices for every strength), ties to the first; 0.0 without conflicts. The caller discards
    these matrices: the bound's own samples are then independent of the choice, so its mean stays
    an unbiased estimate of a valid bound (the smallest of several means of the *same* samples
    would be biased low). ``pilot`` None: :func:`pilot_samples` of ``method``."""
    pilot = pilot_samples(method) if pilot is None else pilot
    if len(compile_problem(problem).nbr) == 0 or pilot < 1:
        return 0.0
    xs = [sample_observations(problem, rng) for _ in range(pilot)]
    means = [sum(inner_maximum(problem, x, method, discount=conflict_discount(problem, c, adaptive),
                               adaptive=adaptive, mip_time_limit_s=mip_time_limit_s, mip_max_nodes=mip_max_nodes)
                     for x in xs) for c in STRENGTHS]
    return float(STRENGTHS[int(np.argmin(means))])


#: Observation matrices of the pilot that chooses the penalty's strength (``strength="auto"``):
#: ``EXACT_PILOT_SAMPLES`` with ``exact`` inner maxima (cheap, and a larger pilot picks the
#: better strength more often), ``PILOT_SAMPLES`` otherwise.
PILOT_SAMPLES = 8
EXACT_PILOT_SAMPLES = 32


def pilot_samples(method: str) -> int:
    """The default pilot of ``method`` (:data:`EXACT_PILOT_SAMPLES` or :data:`PILOT_SAMPLES`)."""
    return EXACT_PILOT_SAMPLES if method == "exact" else PILOT_SAMPLES


def upper_bound(problem: Problem, rng: np.random.Generator, samples: int = DEFAULT_SAMPLES,
                method: str = "auto", penalty_scale: float = 1.0, deadline_s: float | None = None,
                strength: float | str = "auto", pilot: int | None = None,
                adaptive: bool | str = "auto", mip_time_limit_s: float = MIP_TIME_LIMIT_S,
                pilot_method: str | None = None, mip_max_nodes: int | None = None) -> UpperBound:
    """The information-relaxation bound of ``problem``: the mean of :func:`inner_maximum` over
    ``samples`` observation matrices drawn from the prior with ``rng`` (scheduled stages only).

    Args:
        method: ``auto`` (:func:`auto_method`) or one of :data:`METHODS`.
        strength: the penalty's conflict discount (:func:`conflict_discount`), or ``auto``: the
            best of :data:`STRENGTHS` on ``pilot`` (default :func:`pilot_samples`) matrices drawn
            first from ``rng`` and discarded (:func:`choose_strength`; no pilot when
            ``penalty_scale`` is 0 or nothing conflicts).
        pilot_method: the inner maxima of that pilot (None: ``method``). A cheaper method only
            changes which strength is chosen, never the validity: the pilot's matrices are
            discarded and every strength gives a valid bound.
        adaptive: the adaptive penalty (:func:`adaptive_terms`), or ``auto``: adaptive when the
            method is ``exact`` or ``mixed`` and the penalty is on (``penalty_scale`` not 0). (The
            LP relaxation of the adaptive model is looser than the fixed penalty's LP, and its MIP
            is several times slower than the fixed one's: ``lp`` and ``mip`` keep the fixed
            penalty unless asked.)
        mip_time_limit_s: time limit of one HiGHS branch and bound (``mip``, ``mixed``), seconds;
            a search stopped by it gives its dual bound, valid but timing-dependent.
        mip_max_nodes: nodes of one HiGHS branch and bound (:func:`inner_maximum`; None: no limit).
        deadline_s: stop with :class:`BoundTooLarge` once this much wall time has passed (checked
            after each sample; None: no limit). The result never depends on timing: it is the
            bound of all ``samples`` or nothing.

    Raises:
        ValueError: a problem with passenger values (the penalty knows no passenger types), fewer
            than 2 samples, or an unknown method.
    """
    if problem.weights is not None:
        raise ValueError("upper bound: expected an instance without passenger values, found passenger_values")
    if samples < 2:
        raise ValueError(f"upper bound: expected at least 2 samples (for a standard error), found {samples}")
    method = auto_method(problem) if method == "auto" else method
    if adaptive == "auto":
        adaptive = method in ("exact", "mixed") and penalty_scale != 0.0
    adaptive = bool(adaptive) and penalty_scale != 0.0
    start = time.perf_counter()
    pilot_count = 0
    if strength == "auto":
        pilot_method = method if pilot_method is None else pilot_method
        pilot_count = 0 if penalty_scale == 0.0 or len(compile_problem(problem).nbr) == 0 else (
            pilot_samples(pilot_method) if pilot is None else pilot)
        strength = (choose_strength(problem, rng, pilot_method, pilot_count, adaptive, mip_time_limit_s, mip_max_nodes)
                    if pilot_count else 0.0)
    strength = float(strength)
    discount = conflict_discount(problem, strength, adaptive) if strength and penalty_scale else None
    values = np.empty(samples)
    for s in range(samples):
        x = sample_observations(problem, rng)
        values[s] = inner_maximum(problem, x, method, penalty_scale, mip_time_limit_s, discount,
                                  adaptive, mip_max_nodes) / problem.scale
        if deadline_s is not None and time.perf_counter() - start > deadline_s:
            raise BoundTooLarge(f"upper bound: stopped after {s + 1} of {samples} samples at the {deadline_s:g} s deadline")
    return UpperBound(float(values.mean()), float(values.std(ddof=1) / math.sqrt(samples)), method, samples,
                      penalty_scale, strength if discount is not None else 0.0, pilot_count, adaptive)


#: Fewest samples :func:`plan` accepts (fewer would make the standard error meaningless).
MIN_SAMPLES = 20
#: The bound's observation stream of a root seed: ``SeedSequence(seed, spawn_key=BOUND_SPAWN_KEY)``.
BOUND_SPAWN_KEY = (3000,)
#: :func:`seeded_bound` gives up (no bound) past this multiple of its budget (a host far slower
#: than the cost model).
DEADLINE_FACTOR = 3.0


def plan(problem: Problem, budget_s: float = DEFAULT_BUDGET_S, samples: int = DEFAULT_SAMPLES) -> tuple[str, int]:
    """``(method, samples)`` for a bound within ``budget_s`` by :func:`estimate_seconds` (sizes
    alone, so the choice is the same on a fast and a loaded machine): :func:`auto_method` or, if
    that does not fit, ``lp``; as many samples as fit, at most ``samples``, after the pilot that
    chooses the penalty's strength (:data:`STRENGTHS` times :func:`pilot_samples` inner maxima).

    Raises:
        BoundTooLarge: not even :data:`MIN_SAMPLES` samples fit (one line; quick: no solve).
        ValueError: a problem with passenger values.
    """
    if problem.weights is not None:
        raise ValueError("upper bound: expected an instance without passenger values, found passenger_values")
    first = auto_method(problem)
    conflicts = len(compile_problem(problem).nbr) > 0
    for method in dict.fromkeys((first, "mip" if first == "exact" else first, "lp")):
        pilot = len(STRENGTHS) * pilot_samples(method) if conflicts else 0
        per = estimate_seconds(problem, method, 1)
        fit = min(samples, int(budget_s // per) - pilot if per > 0 else samples)
        if fit >= MIN_SAMPLES:
            return method, fit
    raise BoundTooLarge(f"upper bound: {MIN_SAMPLES} samples by lp after the {pilot}-sample pilot would take about "
                        f"{estimate_seconds(problem, 'lp', MIN_SAMPLES + pilot):.3g} s, beyond the {budget_s:g} s budget "
                        f"(R={problem.n_carriers}, N={problem.n_stages})")


def seeded_bound(problem: Problem, seed: int, budget_s: float = DEFAULT_BUDGET_S,
                 samples: int = DEFAULT_SAMPLES) -> UpperBound:
    """The bound as ``python -m coordinator.solve`` reports it: :func:`plan` within ``budget_s``,
    observations from ``SeedSequence(seed, spawn_key=BOUND_SPAWN_KEY)``. Raises as :func:`plan`."""
    method, count = plan(problem, budget_s, samples)
    rng = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=BOUND_SPAWN_KEY))
    return upper_bound(problem, rng, count, method, deadline_s=DEADLINE_FACTOR * budget_s)
