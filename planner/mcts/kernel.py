"""Numba kernels of the fast MCTS planner (:mod:`planner.mcts.fast`), both tree layouts.

One iteration is the paper's five steps, each one named function shared by both layouts:

==========================  ===================================================================
step                        function
==========================  ===================================================================
UCT selection               :func:`uct_select` (argmax of ``mean + c sqrt(ln N_parent / N_child)``
                            over a node's child block, ties to the lowest index)
expansion                   :func:`expand` (creates one child; which one is the layout's
                            choice: a random untried action, see the searches)
rollout                     :func:`simulate` samples the unknown observations and runs
                            :func:`rollout` (SSAP on conflict-discounted observations, or
                            uniformly random feasible), ``samples`` times
evaluation (penalty rule)   :func:`evaluate` (the whole trajectory: past + tree + rollout)
coverage reward             :func:`simulate_cover` / :func:`rollout_cover`: the same steps, every
                            deployment valued by its marginal coverage (:class:`Cover`)
backup                      :func:`backup` (visits, value sums, means along the path)
==========================  ===================================================================

:func:`search_binary` and :func:`search_joint` walk their tree with these steps.

Arguments are named structures (NamedTuples of arrays, read by numba as tuples):
:class:`Model` (the compiled problem, per problem), :class:`Root` (the decision's state),
:class:`Settings`, :class:`UCTTables`, :class:`Scratch` (work arrays and the random stream) and
the tree (:class:`BinaryTree` or :class:`JointTree`, both with :class:`Stats`).

Trees are preallocated arrays. A node's children occupy one contiguous *block* of node ids,
reserved at its first expansion, so UCT scans contiguous statistics:

* binary layout — node ``i`` is one carrier's binary choice at one stage; its block is
  ``[stay, deploy]`` at ``base[i]`` (indexed by the action), ``point[i]`` is the sequence
  position of the choice. Carriers without a choice (∅ stage, no passenger left, or forced) get
  no level: their action is applied while walking (:func:`_advance`).
* joint layout — see the block comment above :func:`search_joint`.

Decision points are visited in *sequence order* ``q = (k - j0) * R + r`` (stage ``k`` from the
root stage ``j0``, carrier ``r``), flat point ``a = r * N + k``.

Random numbers come from a splitmix64 stream (a 64-bit counter in ``Scratch.state[0]``, seeded
once per decision from the caller's numpy Generator): a draw is a few integer operations, far
cheaper than numba's ``np.random``, which matters at tens of draws per iteration.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from planner.jitcache import cache_follows_sources
from planner.kernels import deploys, deploys_u, forced, rank
from planner.kernels import quantile as _quantile

#: Index of the root node.
ROOT = 0
#: ``base`` of a node without children yet.
UNEXPANDED = -1
#: Rollout policies (``Settings.rollout``).
ROLLOUT_SSAP = 0
ROLLOUT_RANDOM = 1
#: Size of the lookup tables of 1/n, 1/sqrt(n) and sqrt(ln n) used by UCT for visit counts n.
UCT_TABLE = 1 << 16

#: splitmix64 constants (Steele, Lea & Flood 2014).
_GAMMA = np.uint64(0x9E3779B97F4A7C15)
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)
_S30 = np.uint64(30)
_S27 = np.uint64(27)
_S31 = np.uint64(31)
_S11 = np.uint64(11)
_TO_UNIT = 1.0 / 9007199254740992.0  # 2**-53


# ----------------------------------------------------------------------------- named structures

#: The rows of :attr:`Cover.marks`.
COVERED, STAMP = 0, 1


class Cover(NamedTuple):
    """The coverage reward as the kernels read it (``on`` False: the penalty rule, and the arrays
    are placeholders), over the *planning regions* of :class:`planner.coverage_plan.CoveragePlan`
    (a point's private regions summed into one). Per problem: the CSR lists, thresholds and
    priors; per decision: the revealed counts, the regions the past covers and the per-sample
    counts, drawn lazily (a region's count is drawn the first time a sample reads it)."""

    on: bool
    ptr: np.ndarray         # int64 [R*N + 1] point -> planning regions (CSR)
    idx: np.ndarray         # int64 [nnz]
    tptr: np.ndarray        # int64 [R*N + 1] point -> thresholds with the tie margin (CSR)
    thr: np.ndarray         # float64
    ucut: np.ndarray        # float64 like thr: the point prior's CDF at each threshold
    solo: np.ndarray        # uint8 [R*N] the point explores its own aggregate only
    rptr: np.ndarray        # int64 [P + 1] planning region -> inverse-CDF table (CSR)
    rpoints: np.ndarray     # float64
    rcdf: np.ndarray        # float64
    gptr: np.ndarray        # int64 [P + 1] planning region -> guide table (CSR)
    guide: np.ndarray       # int64 first index (from rptr[m]) with rcdf > k / len
    cnt: np.ndarray         # float64 [P] counts: revealed (stamp -1) or this sample's (stamp == tick)
    marks: np.ndarray       # int64 [2, P] row COVERED: -1 covered by the past, == tick by the current
                            # trajectory; row STAMP: -1 revealed, == tick drawn for the current sample
    tick: np.ndarray        # int64 [1] the current sample's id (>= 1)
    past_value: float       # raw coverage of the deployments before the root stage


class Model(NamedTuple):
    """The compiled problem as the kernels read it (:class:`planner.compiled.CompiledProblem`)."""

    table: np.ndarray   # float64 [N + 2, N + 2] DLR thresholds (raw units)
    ucut: np.ndarray    # float64 [N + 2, N + 2] sampler CDF at the thresholds
    points: np.ndarray  # float64 [K] sampler support points (atoms for a continuous prior)
    cdf: np.ndarray     # float64 [K] cumulative probabilities, last == 1
    guide: np.ndarray   # int64 [G] guide table of the inverse CDF
    indptr: np.ndarray  # int64 [R*N + 1] CSR of "shares an overlap"
    nbr: np.ndarray     # int64 [nnz]
    scale: float        # rewards are divided by it (normalised rewards)
    cover: Cover        # the coverage reward (cover.on), else placeholders


class Root(NamedTuple):
    """The state of one decision at root stage ``j0``."""

    j0: int                 # root stage
    d0: np.ndarray          # int64 [R] passengers left before the root stage
    valid: np.ndarray       # uint8 [R, N] validity: realised up to j0, scheduled after
    vs_left: np.ndarray     # int64 [R, N + 1] valid stages from k (inclusive) to the end
    known: np.ndarray       # float64 [R, N] observations up to j0, NaN after it
    known_flat: np.ndarray  # float64 [R*N] the same, flat
    past: np.ndarray        # int64 [P] flat points deployed before j0
    ws0: np.ndarray         # float64 [R, max D + 1] weights of the passengers aboard, largest first
                            # (passenger values; a [1, 1] placeholder without them)
    weighted: bool          # passenger values: trajectories are scored with the released weights


class Settings(NamedTuple):
    """Search settings."""

    rollout: int        # ROLLOUT_SSAP or ROLLOUT_RANDOM
    exploration: float  # UCT constant c on normalised rewards
    samples: int        # rollouts per iteration (their mean is backed up)


class UCTTables(NamedTuple):
    """1/n, 1/sqrt(n), sqrt(ln n) for n < UCT_TABLE (entry 0 unused), float64 [UCT_TABLE] each."""

    inv: np.ndarray
    inv_sqrt: np.ndarray
    sqrt_log: np.ndarray


class Scratch(NamedTuple):
    """Work arrays of one decision. ``mark``/``xval`` hold the past on entry and on exit."""

    state: np.ndarray      # uint64 [1] splitmix64 counter (advanced in place)
    left: np.ndarray       # int64 [R] passengers left along the current trajectory
    left_tree: np.ndarray  # int64 [R] passengers left after the tree path
    mark: np.ndarray       # uint8 [R*N] selected points of the current trajectory
    xval: np.ndarray       # float64 [R*N] observation of each selected point
    pts: np.ndarray        # int64 [R*N] selected points after the past, in order
    path: np.ndarray       # int64 [(N - j0) * R + 2] node ids of the current tree path
    choice: np.ndarray     # int64 [R] carriers with a choice at the current stage (joint layout)
    ws: np.ndarray         # float64 like Root.ws0: weights aboard along the trajectory (passenger values)
    dleft: np.ndarray      # int64 [R] passengers aboard along the trajectory (passenger values)


class Stats(NamedTuple):
    """Node statistics, float/int ``[cap]``: iterations through the node, sum of their normalised
    rewards, and ``value / visits`` and ``1 / sqrt(visits)`` kept by :func:`backup` for UCT."""

    visits: np.ndarray
    value: np.ndarray
    mean: np.ndarray
    isq: np.ndarray


class BinaryTree(NamedTuple):
    """Binary layout: ``base[i]`` first id of node i's ``[stay, deploy]`` block (or UNEXPANDED);
    ``point[i]`` sequence position of its choice; ``counter[0]`` ids reserved. A block entry
    exists iff its ``visits > 0`` (a child is backed up in the iteration that creates it)."""

    base: np.ndarray
    point: np.ndarray
    counter: np.ndarray
    stats: Stats


class JointTree(NamedTuple):
    """Joint layout (see the block comment above :func:`search_joint`)."""

    base: np.ndarray
    expanded: np.ndarray
    mult: np.ndarray
    offset: np.ndarray
    counter: np.ndarray
    stats: Stats


# ----------------------------------------------------------------------------- low level


@njit(cache=True, inline="always")
def _unit(z):
    """Uniform float in [0, 1) from the splitmix64 counter value z."""
    z = (z ^ (z >> _S30)) * _MIX1
    z = (z ^ (z >> _S27)) * _MIX2
    z = z ^ (z >> _S31)
    return np.float64(z >> _S11) * _TO_UNIT


@njit(cache=True, inline="always")
def _random(state):
    """Uniform float in [0, 1) from the splitmix64 stream whose counter is ``state[0]``."""
    z = state[0] + _GAMMA
    state[0] = z
    return _unit(z)


@njit(cache=True, inline="always")
def _sample(state, points, cdf, guide):
    """One draw of the prior."""
    return _quantile(_random(state), points, cdf, guide)


@njit(cache=True, inline="always")
def _conflicts(a, mark, indptr, nbr):
    """Number of marked (selected) points sharing an overlap with flat point a."""
    c = 0
    for e in range(indptr[a], indptr[a + 1]):
        c += mark[nbr[e]]
    return c


@njit(cache=True)
def _advance(q, n, j0, left, valid, vs_left, mark, pts):
    """Walk from position q, applying forced deployments, to the next choice position.

    Returns (position of the next choice or Q, number of points in ``pts``).
    """
    n_carriers, n_stages = valid.shape
    k = j0 + q // n_carriers
    r = q % n_carriers
    while k < n_stages:
        while r < n_carriers:
            if valid[r, k] and left[r] > 0:
                if not forced(vs_left[r, k], left[r]):
                    return (k - j0) * n_carriers + r, n
                a = r * n_stages + k
                mark[a] = 1
                pts[n] = a
                n += 1
                left[r] -= 1
            r += 1
        r = 0
        k += 1
    return (n_stages - j0) * n_carriers, n


@njit(cache=True)
def rollout(q, n, root, model, policy, scratch):
    """Complete the trajectory from position q with the rollout policy; returns len(pts).

    SSAP: a carrier deploys by the threshold rule on its observation discounted for conflicts
    with the deployments already chosen, ``x / (1 + c)``; random: with probability ``d / n``.
    A sampled observation x = quantile(u) exceeds the threshold t iff u >= P(X <= t) =
    ``ucut[ns, ns - d]``, so a conflict-free SSAP decision reads u alone and the quantile is
    looked up only for deployments (the same draws and decisions as sampling x first).
    ``policy``: ROLLOUT_SSAP or ROLLOUT_RANDOM; ``n`` points are in ``scratch.pts`` on entry.
    """
    j0, valid, vs_left, known = root.j0, root.valid, root.vs_left, root.known
    table, ucut, points, cdf, guide = model.table, model.ucut, model.points, model.cdf, model.guide
    indptr, nbr = model.indptr, model.nbr
    state, left, mark, xval, pts = scratch.state, scratch.left, scratch.mark, scratch.xval, scratch.pts
    n_carriers, n_stages = valid.shape
    z = state[0]  # the stream's counter, kept in a register and stored back at the end
    k = j0 + q // n_carriers
    r = q % n_carriers
    while k < n_stages:
        while r < n_carriers:
            d = left[r]
            if d > 0 and valid[r, k]:
                ns = vs_left[r, k]
                a = r * n_stages + k
                x = 0.0
                if k == j0:  # only when the tree stopped inside the root stage
                    x = known[r, k]
                    if forced(ns, d):
                        go = True
                    elif policy == ROLLOUT_SSAP:
                        go = deploys(table, x / (1.0 + _conflicts(a, mark, indptr, nbr)), ns, d)
                    else:
                        z += _GAMMA
                        go = _unit(z) * ns < d
                else:
                    z += _GAMMA
                    u = _unit(z)
                    if forced(ns, d):
                        go = True
                    elif policy == ROLLOUT_SSAP:
                        if indptr[a] == indptr[a + 1]:  # no overlap: x > t iff u >= ucut
                            go = deploys_u(ucut, u, ns, d)
                        else:
                            x = _quantile(u, points, cdf, guide)
                            go = deploys(table, x / (1.0 + _conflicts(a, mark, indptr, nbr)), ns, d)
                    else:
                        # deploy with probability d / ns: a uniform d-subset of the remaining valid stages
                        go = u * ns < d
                        if go:
                            z += _GAMMA
                            u = _unit(z)
                    if go:
                        x = _quantile(u, points, cdf, guide)
                if go:
                    mark[a] = 1
                    xval[a] = x
                    pts[n] = a
                    n += 1
                    left[r] = d - 1
            r += 1
        r = 0
        k += 1
    state[0] = z
    return n


@njit(cache=True)
def evaluate(n, past, pts, mark, xval, indptr, nbr):
    """Raw total of the trajectory (past + pts[:n]) under the exact penalty rule: every selected
    point earns ``x / (1 + selected points sharing an overlap with it)``."""
    total = 0.0
    for i in range(past.shape[0]):
        a = past[i]
        total += xval[a] / (1.0 + _conflicts(a, mark, indptr, nbr))
    for i in range(n):
        a = pts[i]
        total += xval[a] / (1.0 + _conflicts(a, mark, indptr, nbr))
    return total


@njit(cache=True)
def weigh(n, pts, xval, n_stages, vs_left, table, d0, ws0, ws, dleft):
    """Passenger values: turn the raw observations of the trajectory's deployments ``pts[:n]``
    (in stage order) into weighted values ``w x``, each carrier releasing, at each of its
    deployments, the passenger of rank ``min(rank(x), d)`` among those aboard (the DLR rule of
    :func:`planner.passengers.choose`), starting from the root's passengers ``ws0``."""
    for r in range(d0.shape[0]):
        dleft[r] = d0[r]
        for i in range(ws0.shape[1]):
            ws[r, i] = ws0[r, i]
    for i in range(n):
        a = pts[i]
        r = a // n_stages
        k = a % n_stages
        d = dleft[r]
        if d <= 0:
            continue
        pos = rank(table, xval[a], vs_left[r, k])
        pos = (pos if pos < d else d) - 1
        xval[a] *= ws[r, pos]
        for m in range(pos, d - 1):
            ws[r, m] = ws[r, m + 1]
        ws[r, d - 1] = 0.0
        dleft[r] = d - 1


# ----------------------------------------------------------------------------- the coverage reward


@njit(cache=True, inline="always")
def _region_draw(m, u, rptr, rpoints, rcdf, gptr, guide):
    """Planning region m's count at uniform u (:func:`planner.kernels.quantile` on its CSR rows)."""
    g0 = gptr[m]
    i = rptr[m] + guide[g0 + int(u * (gptr[m + 1] - g0))]
    while rcdf[i] <= u:
        i += 1
    return rpoints[i]


@njit(cache=True, inline="always")
def _gain(a, ptr, idx, marks, cnt, tick, rptr, rpoints, rcdf, gptr, guide, state):
    """Marginal coverage of a deployment at flat point a over the current trajectory: the counts
    of its regions no deployment of the trajectory covers yet (reads only a's regions). A region's
    count is the revealed one, or drawn from its prior the first time sample ``tick`` reads it.
    Arrays are :class:`Cover`'s, passed unpacked (no reference counting in the loops)."""
    g = 0.0
    for e in range(ptr[a], ptr[a + 1]):
        m = idx[e]
        cv = marks[COVERED, m]
        if cv == tick or cv < 0:  # covered by the past or the current trajectory
            continue
        st = marks[STAMP, m]
        if st != tick and st >= 0:
            cnt[m] = _region_draw(m, _random(state), rptr, rpoints, rcdf, gptr, guide)
            marks[STAMP, m] = tick
        g += cnt[m]
    return g


@njit(cache=True, inline="always")
def _cover_add(a, ptr, idx, marks, tick):
    """Mark the regions of a deployment at flat point a covered in trajectory ``tick`` (a new
    tick uncovers them all at once: nothing to clear; the past's -1 stays)."""
    for e in range(ptr[a], ptr[a + 1]):
        m = idx[e]
        if marks[COVERED, m] >= 0:
            marks[COVERED, m] = tick


@njit(cache=True)
def cover_gain(a, cover, state):
    """:func:`_gain` of flat point a with the arrays of ``cover`` (sample ``cover.tick[0]``)."""
    return _gain(a, cover.ptr, cover.idx, cover.marks, cover.cnt, cover.tick[0], cover.rptr, cover.rpoints,
                 cover.rcdf, cover.gptr, cover.guide, state)


@njit(cache=True)
def cover_add(a, cover):
    """:func:`_cover_add` with the arrays of ``cover`` (trajectory ``cover.tick[0]``)."""
    _cover_add(a, cover.ptr, cover.idx, cover.marks, cover.tick[0])


@njit(cache=True)
def rollout_cover(q, n, root, policy, scratch, cover):
    """:func:`rollout` under the coverage reward; returns (len(pts), raw gain of the rollout).

    SSAP: a carrier deploys iff forced or the deployment's marginal coverage over the trajectory
    so far (past + tree + rollout) exceeds the point's threshold (the analogue of the penalty
    rollout's ``x / (1 + c)``); random: with probability ``d / n``. Every deployment adds its
    marginal coverage, so the sum is the trajectory's coverage beyond the tree path's.
    """
    j0, valid, vs_left = root.j0, root.valid, root.vs_left
    state, left, mark, pts = scratch.state, scratch.left, scratch.mark, scratch.pts
    ptr, idx, tptr, thr, rptr, rpoints, rcdf = cover.ptr, cover.idx, cover.tptr, cover.thr, cover.rptr, \
        cover.rpoints, cover.rcdf
    cnt, marks, solo, ucut = cover.cnt, cover.marks, cover.solo, cover.ucut
    gptr, guide = cover.gptr, cover.guide
    tick = cover.tick[0]
    n_carriers, n_stages = valid.shape
    total = 0.0
    k = j0 + q // n_carriers
    r = q % n_carriers
    while k < n_stages:
        while r < n_carriers:
            d = left[r]
            if d > 0 and valid[r, k]:
                ns = vs_left[r, k]
                a = r * n_stages + k
                g = -1.0  # not computed yet
                if forced(ns, d):
                    go = True
                elif policy == ROLLOUT_SSAP:
                    if solo[a] and marks[STAMP, idx[ptr[a]]] >= 0:
                        m = idx[ptr[a]]
                        # Its own unrevealed aggregate only (read by no other point, so never
                        # marked covered): x > t iff u >= ucut, the count looked up only to deploy.
                        u = _random(state)
                        if u >= ucut[tptr[a] + ns - d]:
                            total += _region_draw(m, u, rptr, rpoints, rcdf, gptr, guide)
                            mark[a] = 1
                            pts[n] = a
                            n += 1
                            left[r] = d - 1
                        r += 1
                        continue
                    else:
                        g = _gain(a, ptr, idx, marks, cnt, tick, rptr, rpoints, rcdf, gptr, guide, state)
                        go = g > thr[tptr[a] + ns - d]
                else:
                    go = _random(state) * ns < d
                if go:
                    if g < 0.0:
                        g = _gain(a, ptr, idx, marks, cnt, tick, rptr, rpoints, rcdf, gptr, guide, state)
                    total += g
                    _cover_add(a, ptr, idx, marks, tick)
                    mark[a] = 1
                    pts[n] = a
                    n += 1
                    left[r] = d - 1
            r += 1
        r = 0
        k += 1
    return n, total


@njit(cache=True, inline="always")
def simulate_cover(q, n_tree, root, model, settings, scratch):
    """:func:`simulate` under the coverage reward: per sample, a future of the unrevealed region
    counts (drawn lazily), the tree path's deployments and the rollout each adding their marginal
    coverage; the trajectory is worth the past's coverage plus those gains (past + tree + rollout).
    On exit the marks of the path and rollout are cleared (each sample is a new ``tick``: what
    it covered is uncovered by the next)."""
    left, left_tree, mark, pts, state = scratch.left, scratch.left_tree, scratch.mark, scratch.pts, scratch.state
    cover = model.cover
    ptr, idx, marks, cnt = cover.ptr, cover.idx, cover.marks, cover.cnt
    rptr, rpoints, rcdf, tick, gptr, guide = cover.rptr, cover.rpoints, cover.rcdf, cover.tick, cover.gptr, cover.guide
    n_carriers = left.shape[0]
    for r in range(n_carriers):
        left_tree[r] = left[r]
    total = 0.0
    for _s in range(settings.samples):
        tick[0] += 1
        gain = 0.0
        for i in range(n_tree):
            a = pts[i]
            gain += _gain(a, ptr, idx, marks, cnt, tick[0], rptr, rpoints, rcdf, gptr, guide, state)
            _cover_add(a, ptr, idx, marks, tick[0])
        for r in range(n_carriers):
            left[r] = left_tree[r]
        n, more = rollout_cover(q, n_tree, root, settings.rollout, scratch, cover)
        total += cover.past_value + gain + more
        for i in range(n_tree, n):
            mark[pts[i]] = 0
    for i in range(n_tree):
        mark[pts[i]] = 0
    return total / (settings.samples * model.scale)


@njit(cache=True, inline="always")
def simulate(q, n_tree, root, model, settings, scratch):
    """Mean normalised reward of ``settings.samples`` rollouts below a tree path.

    On entry ``pts[:n_tree]`` are the path's deployments (marked in ``mark``), ``left`` the
    passengers left after them and ``q`` the decision slot where the rollout starts. Observations
    of the path's points are sampled afresh per sample where unknown (after the root stage).
    On exit every mark of the path and rollout is cleared; ``left`` is clobbered.
    """
    if model.cover.on:
        return simulate_cover(q, n_tree, root, model, settings, scratch)
    left, left_tree, mark, xval, pts = scratch.left, scratch.left_tree, scratch.mark, scratch.xval, scratch.pts
    state = scratch.state
    j0, d0, valid, vs_left, known, known_flat, past, ws0, weighted = root
    table, ucut, points, cdf, guide, indptr, nbr, scale, _ = model
    policy, _, samples = settings
    n_carriers = left.shape[0]
    for r in range(n_carriers):
        left_tree[r] = left[r]
    total = 0.0
    for _s in range(samples):
        for i in range(n_tree):
            a = pts[i]
            x = known_flat[a]  # NaN after the root stage: sampled
            xval[a] = _sample(state, points, cdf, guide) if np.isnan(x) else x
        for r in range(n_carriers):
            left[r] = left_tree[r]
        n = rollout(q, n_tree, root, model, policy, scratch)
        if weighted:
            weigh(n, pts, xval, known.shape[1], vs_left, table, d0, ws0, scratch.ws, scratch.dleft)
        total += evaluate(n, past, pts, mark, xval, indptr, nbr)
        for i in range(n_tree, n):
            mark[pts[i]] = 0
    for i in range(n_tree):
        mark[pts[i]] = 0
    return total / (samples * scale)


@njit(cache=True, inline="always")
def uct_select(visits, mean, isq, first, count, parent, exploration, sqrt_log):
    """UCT selection: the index ``i`` in ``0..count-1`` of the child ``first + i`` maximising
    ``mean + c * sqrt(ln visits[parent] / visits[child])`` (ties: the lowest index). Every child
    of the block must have been visited. Arrays are :class:`Stats`' and :class:`UCTTables`'."""
    nv = visits[parent]
    ex = exploration * (sqrt_log[nv] if nv < UCT_TABLE else math.sqrt(math.log(nv)))
    best = 0
    best_s = -np.inf
    for i in range(count):  # contiguous: the child block
        s = mean[first + i] + ex * isq[first + i]
        if s > best_s:
            best_s = s
            best = i
    return best


@njit(cache=True, inline="always")
def expand(visits, value, child):
    """Expansion: create node ``child`` with no visit (its first :func:`backup` writes its mean)."""
    visits[child] = 0
    value[child] = 0.0


@njit(cache=True, inline="always")
def backup(visits, value, mean, isq, path, plen, reward, inv, inv_sqrt):
    """Backup: one more visit and ``reward`` for every node of ``path[:plen]``, with the mean and
    ``1 / sqrt(visits)`` that :func:`uct_select` reads."""
    for i in range(plen):
        m = path[i]
        v = visits[m] + 1
        visits[m] = v
        value[m] += reward
        if v < UCT_TABLE:
            mean[m] = value[m] * inv[v]
            isq[m] = inv_sqrt[v]
        else:
            mean[m] = value[m] / v
            isq[m] = 1.0 / math.sqrt(v)


@njit(cache=True)
def uct_tables():
    """(1/n, 1/sqrt(n), sqrt(ln n)) for n < UCT_TABLE (entry 0 unused)."""
    inv = np.zeros(UCT_TABLE)
    inv_sqrt = np.zeros(UCT_TABLE)
    sqrt_log = np.zeros(UCT_TABLE)
    for n in range(1, UCT_TABLE):
        inv[n] = 1.0 / n
        inv_sqrt[n] = 1.0 / math.sqrt(n)
        sqrt_log[n] = math.sqrt(math.log(n))
    return inv, inv_sqrt, sqrt_log


@njit(cache=True)
def search_binary(n_iter, tree, root, model, settings, uct, scratch):
    """Run ``n_iter`` MCTS iterations on the binary tree (continuing from ``tree.counter[0]`` ids);
    the tree must have room for ``2 * n_iter`` more ids.

    Selection walks the levels: UCT between the two children once both exist, otherwise the
    node is expanded with an untried action (uniformly random when both are untried).
    """
    # Arrays unpacked once (no reference counting inside the loops).
    valid, vs_left, j0, d0 = root.valid, root.vs_left, root.j0, root.d0
    visits, value, mean, isq = tree.stats
    inv, inv_sqrt, sqrt_log = uct
    base, point = tree.base, tree.point
    left, mark, pts, path, state = scratch.left, scratch.mark, scratch.pts, scratch.path, scratch.state
    exploration = settings.exploration
    n_carriers, n_stages = valid.shape
    end = (n_stages - j0) * n_carriers
    n_nodes = tree.counter[0]
    for _ in range(n_iter):
        for r in range(n_carriers):
            left[r] = d0[r]
        node = ROOT
        path[0] = ROOT
        plen = 1
        q, n = _advance(np.int64(0), np.int64(0), j0, left, valid, vs_left, mark, pts)  # not literal 0s: one compilation
        # Invariant: q == point[node] and the path's actions are applied to left/mark/pts.
        while q < end:
            first = base[node]
            if first == UNEXPANDED:
                b = 1 if _random(state) < 0.5 else 0
                grow = True
            elif visits[first] > 0 and visits[first + 1] > 0:
                b = uct_select(visits, mean, isq, first, 2, node, exploration, sqrt_log)
                grow = False
            else:
                b = 0 if visits[first] == 0 else 1
                grow = True
            if b == 1:
                r = q % n_carriers
                a = r * n_stages + j0 + q // n_carriers
                mark[a] = 1
                pts[n] = a
                n += 1
                left[r] -= 1
            q, n = _advance(q + 1, n, j0, left, valid, vs_left, mark, pts)
            if grow:
                if first == UNEXPANDED:
                    first = n_nodes
                    n_nodes += 2
                    base[node] = first
                    visits[first] = 0  # both entries untried
                    visits[first + 1] = 0
                child = first + b
                expand(visits, value, child)
                base[child] = UNEXPANDED
                point[child] = q
                path[plen] = child
                plen += 1
                break
            node = first + b
            path[plen] = node
            plen += 1
        reward = simulate(q, n, root, model, settings, scratch)
        backup(visits, value, mean, isq, path, plen, reward, inv, inv_sqrt)
    tree.counter[0] = n_nodes


@njit(cache=True)
def sample_many(state, points, cdf, guide, count):
    """``count`` draws of the prior from the stream ``state`` (for tests and diagnostics)."""
    out = np.empty(count)
    for i in range(count):
        out[i] = _sample(state, points, cdf, guide)
    return out


@njit(cache=True)
def quantiles(us, points, cdf, guide):
    """The kernel's inverse CDF at each u of ``us`` (for tests and diagnostics)."""
    out = np.empty(us.shape[0])
    for i in range(us.shape[0]):
        out[i] = _quantile(us[i], points, cdf, guide)
    return out


# ---------------------------------------------------------------------------------------------
# Joint-action layout: the reference's tree (planner.mcts.reference), on arrays.
#
# A node is one stage's decision after its path's actions. Its children are the joint actions of
# the carriers that have a choice at that stage (forced carriers deploy, carriers at ∅ stages or
# without passengers stay), ``2^k`` of them for ``k`` choice carriers; a node with no choice has
# one child (the forced action), exactly like the reference. The children of a node occupy one
# contiguous block of node ids ``base[node] + slot``, reserved at its first expansion, so UCT
# scans contiguous ``visits``/``value`` entries. The ``slot``-th expanded child is the joint
# action ``(mult[node] * slot + offset[node]) mod 2^k`` (bit i = the i-th choice carrier
# deploys): an odd ``mult`` makes this a permutation of the 2^k actions, drawn per node from the
# random stream, so the untried actions are expanded in a random order without listing them.
#
# Tree arrays (JointTree; capacity ``cap`` node ids, ``counter[0]`` reserved):
#   base[i]      first id of node i's child block (valid once expanded[i] > 0);
#   expanded[i]  children expanded so far (slots 0..expanded[i]-1 exist);
#   mult[i], offset[i]   uint64 parameters of node i's expansion order;
#   stats        visits, value sums, means and 1 / sqrt(visits) (Stats).
# ---------------------------------------------------------------------------------------------

_ONE = np.uint64(1)


@njit(cache=True, inline="always")
def _bits64(state):
    """Next 64 random bits of the splitmix64 stream whose counter is ``state[0]``."""
    z = state[0] + _GAMMA
    state[0] = z
    z = (z ^ (z >> _S30)) * _MIX1
    z = (z ^ (z >> _S27)) * _MIX2
    return z ^ (z >> _S31)


@njit(cache=True)
def search_joint(n_iter, tree, root, model, settings, uct, scratch, max_block):
    """Run up to ``n_iter`` MCTS iterations on the joint-action tree (see the block comment).

    Stops early, before an iteration, when fewer than ``max_block`` (>= 2^k of any node) free
    node ids remain; returns the number of iterations run (the caller grows the arrays and calls
    again: the result does not depend on where the calls split the iterations).
    """
    # Arrays unpacked once (no reference counting inside the loops).
    valid, vs_left, j0 = root.valid, root.vs_left, root.j0
    visits, value, mean, isq = tree.stats
    inv, inv_sqrt, sqrt_log = uct
    left, mark, pts, path, state, choice = (scratch.left, scratch.mark, scratch.pts, scratch.path,
                                            scratch.state, scratch.choice)
    base, expanded, mult, offset = tree.base, tree.expanded, tree.mult, tree.offset
    d0 = root.d0
    exploration = settings.exploration
    n_carriers, n_stages = valid.shape
    cap = visits.shape[0]
    n_nodes = tree.counter[0]
    done = 0
    while done < n_iter:
        if n_nodes + max_block > cap:
            break
        for r in range(n_carriers):
            left[r] = d0[r]
        node = ROOT
        path[0] = ROOT
        plen = 1
        n = np.int64(0)  # not a literal 0: rollout would be compiled for Literal[int](0) as well
        k = j0
        # Invariant: the path's joint actions (stages j0..k-1) are applied to left/mark/pts.
        while k < n_stages:
            nc = 0
            for r in range(n_carriers):
                if valid[r, k] and left[r] > 0:
                    if not forced(vs_left[r, k], left[r]):
                        choice[nc] = r
                        nc += 1
                    else:
                        a = r * n_stages + k
                        mark[a] = 1
                        pts[n] = a
                        n += 1
                        left[r] -= 1
            n_act = np.int64(1) << nc
            e = expanded[node]
            if e < n_act:  # expansion: the e-th action of the node's order
                if e == 0:
                    base[node] = n_nodes
                    n_nodes += n_act
                    mult[node] = _bits64(state) | _ONE
                    offset[node] = _bits64(state)
                slot = e
                child = base[node] + e
                expanded[node] = e + 1
                expanded[child] = 0
                expand(visits, value, child)
                grow = True
            else:
                slot = uct_select(visits, mean, isq, base[node], n_act, node, exploration, sqrt_log)
                child = base[node] + slot
                grow = False
            act = (mult[node] * np.uint64(slot) + offset[node]) & np.uint64(n_act - 1)
            for i in range(nc):
                if (act >> np.uint64(i)) & _ONE:
                    r = choice[i]
                    a = r * n_stages + k
                    mark[a] = 1
                    pts[n] = a
                    n += 1
                    left[r] -= 1
            node = child
            path[plen] = node
            plen += 1
            k += 1
            if grow:
                break
        q = (k - j0) * n_carriers
        reward = simulate(q, n, root, model, settings, scratch)
        backup(visits, value, mean, isq, path, plen, reward, inv, inv_sqrt)
        done += 1
    tree.counter[0] = n_nodes
    return done


cache_follows_sources(globals())  # the on-disk cache follows every planner source
