"""Numba kernels of the fast MCTS planner (:mod:`planner.mcts.fast`).

The tree is a set of preallocated arrays; node ``i`` is the decision of one carrier at one stage
(a binary choice: deploy or not), so a stage is up to R consecutive binary levels and the 2^R
joint actions are never enumerated. Carriers without a choice (∅ stage, no passenger left, or
forced) get no level: their deterministic action is applied while walking between levels.

Decision points are visited in *sequence order* ``q = (k - j0) * R + r`` (stage ``k`` from the
root stage ``j0``, carrier ``r``), flat point ``a = r * N + k``.

Tree arrays (capacity ``cap`` nodes, ``n_nodes = counter[0]`` in use):

* ``child[i, b]``: node reached by action ``b`` (0 = stay, 1 = deploy) at node ``i``, or
  ``UNEXPANDED``;
* ``visits[i]``, ``value[i]``: iterations through node ``i`` and the sum of their normalised
  rewards;
* ``point[i]``: sequence position of the node's choice, ``Q`` (= ``TERMINAL``) when no choice
  is left after the path.

Random numbers come from a splitmix64 stream (a 64-bit counter in ``state[0]``, seeded once
per decision from the caller's numpy Generator): about 1 ns per draw, against about 20 ns for
numba's ``np.random``, which matters at tens of draws per iteration.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from planner.kernels import deploys, deploys_u, forced
from planner.kernels import quantile as _quantile

#: Index of the root node.
ROOT = 0
#: ``child`` entry of an action not tried yet.
UNEXPANDED = -1
#: Rollout policies (the ``rollout`` argument of :func:`search`).
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
def _observe(state, r, k, j0, known, points, cdf, guide):
    """The observation of carrier r at stage k: known at the root stage, sampled after it."""
    if k == j0:
        return known[r, k]
    return _sample(state, points, cdf, guide)


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
def _rollout(state, q, n, j0, left, valid, vs_left, known, table, ucut, points, cdf, guide, rollout,
             mark, xval, pts, indptr, nbr):
    """Complete the trajectory from position q with the rollout policy; returns len(pts).

    A sampled observation x = quantile(u) exceeds the threshold t iff u >= P(X <= t) =
    ``ucut[ns, ns - d]``, so a conflict-free SSAP decision reads u alone and the quantile is
    looked up only for deployments (the same draws and decisions as sampling x first).
    """
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
                    elif rollout == ROLLOUT_SSAP:
                        go = deploys(table, x / (1.0 + _conflicts(a, mark, indptr, nbr)), ns, d)
                    else:
                        z += _GAMMA
                        go = _unit(z) * ns < d
                else:
                    z += _GAMMA
                    u = _unit(z)
                    if forced(ns, d):
                        go = True
                    elif rollout == ROLLOUT_SSAP:
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
def _evaluate(n, past, pts, mark, xval, indptr, nbr):
    """Raw total of the trajectory (past + pts[:n]) under the exact penalty rule."""
    total = 0.0
    for i in range(past.shape[0]):
        a = past[i]
        total += xval[a] / (1.0 + _conflicts(a, mark, indptr, nbr))
    for i in range(n):
        a = pts[i]
        total += xval[a] / (1.0 + _conflicts(a, mark, indptr, nbr))
    return total


@njit(cache=True)
def _simulate(state, q, n_tree, n_carriers, samples, scale, j0, left, left_tree, valid, vs_left, known,
              known_flat, table, ucut, points, cdf, guide, rollout, mark, xval, pts, past, indptr, nbr):
    """Mean normalised reward of ``samples`` rollouts below a tree path.

    On entry ``pts[:n_tree]`` are the path's deployments (marked in ``mark``), ``left`` the
    passengers left after them and ``q`` the decision slot where the rollout starts. Observations
    of the path's points are sampled afresh per sample where unknown (after the root stage).
    On exit every mark is cleared; ``left`` is clobbered.
    """
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
        n = _rollout(state, q, n_tree, j0, left, valid, vs_left, known, table, ucut, points, cdf, guide,
                     rollout, mark, xval, pts, indptr, nbr)
        total += _evaluate(n, past, pts, mark, xval, indptr, nbr)
        for i in range(n_tree, n):
            mark[pts[i]] = 0
    for i in range(n_tree):
        mark[pts[i]] = 0
    return total / (samples * scale)


@njit(cache=True, inline="always")
def _uct(node, c0, c1, visits, value, exploration, inv, inv_sqrt, sqrt_log):
    """The UCT choice (0 or 1, ties to 0) between the two visited children of ``node``:
    argmax of ``value/visits + c * sqrt(ln visits[node] / visits[child])``."""
    n, n0, n1 = visits[node], visits[c0], visits[c1]
    if n < UCT_TABLE:  # then n0, n1 < n are in the tables too
        e = exploration * sqrt_log[n]
        s0 = value[c0] * inv[n0] + e * inv_sqrt[n0]
        s1 = value[c1] * inv[n1] + e * inv_sqrt[n1]
    else:
        log_parent = math.log(n)
        s0 = value[c0] / n0 + exploration * math.sqrt(log_parent / n0)
        s1 = value[c1] / n1 + exploration * math.sqrt(log_parent / n1)
    return 0 if s0 >= s1 else 1


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
def search(n_iter, child, visits, value, point, counter, state,
           j0, d0, valid, vs_left, known, past, indptr, nbr, table, ucut, points, cdf, guide,
           rollout, exploration, samples, scale, inv, inv_sqrt, sqrt_log,
           left, left_tree, mark, xval, pts, path):
    """Run ``n_iter`` MCTS iterations on the tree arrays (continuing from ``counter[0]`` nodes).

    Args:
        n_iter: iterations to run; the tree must have room for ``n_iter`` more nodes.
        child, visits, value, point, counter: the tree (see the module docstring).
        state: uint64 ``[1]`` random stream counter (advanced in place).
        j0: root stage.
        d0: int64 ``[R]`` passengers left before the root stage.
        valid: uint8 ``[R, N]`` validity (realised up to j0, scheduled after).
        vs_left: int64 ``[R, N + 1]`` valid stages from k (inclusive) to the end.
        known: float64 ``[R, N]`` observations up to j0, NaN after it (read at stage j0 only).
        past: int64 ``[P]`` flat points deployed before j0 (marked in ``mark``, x in ``xval``).
        indptr, nbr: CSR lists of the points sharing an overlap with each flat point.
        table: float64 ``[N + 2, N + 2]`` SSAP thresholds.
        ucut: float64 ``[N + 2, N + 2]`` prior CDF at the thresholds (see :func:`_rollout`).
        points, cdf, guide: the prior as support points, cumulative probabilities (last > 1)
            and guide table (see :func:`_sample`).
        rollout: ROLLOUT_SSAP or ROLLOUT_RANDOM.
        exploration: UCT constant on normalised rewards.
        samples: rollouts per iteration.
        scale: normalisation of rewards.
        inv, inv_sqrt, sqrt_log: :func:`uct_tables`.
        left, left_tree, mark, xval, pts, path: scratch (mark/xval hold the past on entry and exit).
    """
    n_carriers, n_stages = valid.shape
    end = (n_stages - j0) * n_carriers
    n_nodes = counter[0]
    known_flat = known.reshape(known.size)
    for _ in range(n_iter):
        for r in range(n_carriers):
            left[r] = d0[r]
        node = ROOT
        path[0] = ROOT
        plen = 1
        q, n = _advance(0, 0, j0, left, valid, vs_left, mark, pts)
        # Invariant: q == point[node] and the path's actions are applied to left/mark/pts.
        while q < end:
            c0 = child[node, 0]
            c1 = child[node, 1]
            if c0 != UNEXPANDED and c1 != UNEXPANDED:
                b = _uct(node, c0, c1, visits, value, exploration, inv, inv_sqrt, sqrt_log)
                expand = False
            else:
                if c0 == UNEXPANDED and c1 == UNEXPANDED:
                    b = 1 if _random(state) < 0.5 else 0
                else:
                    b = 0 if c0 == UNEXPANDED else 1
                expand = True
            if b == 1:
                r = q % n_carriers
                a = r * n_stages + j0 + q // n_carriers
                mark[a] = 1
                pts[n] = a
                n += 1
                left[r] -= 1
            q, n = _advance(q + 1, n, j0, left, valid, vs_left, mark, pts)
            if expand:
                new = n_nodes
                n_nodes += 1
                child[new, 0] = UNEXPANDED
                child[new, 1] = UNEXPANDED
                visits[new] = 0
                value[new] = 0.0
                point[new] = q
                child[node, b] = new
                path[plen] = new
                plen += 1
                break
            node = child[node, b]
            path[plen] = node
            plen += 1
        reward = _simulate(state, q, n, n_carriers, samples, scale, j0, left, left_tree, valid, vs_left, known,
                           known_flat, table, ucut, points, cdf, guide, rollout, mark, xval, pts, past, indptr, nbr)
        for i in range(plen):
            visits[path[i]] += 1
            value[path[i]] += reward
    counter[0] = n_nodes


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
# Tree arrays (capacity ``cap`` node ids, ``counter[0]`` reserved):
#   base[i]      first id of node i's child block (valid once expanded[i] > 0);
#   expanded[i]  children expanded so far (slots 0..expanded[i]-1 exist);
#   mult[i], offset[i]   uint64 parameters of node i's expansion order;
#   visits[i], value[i]  iterations through node i and the sum of their normalised rewards;
#   mean[i], isq[i]      value[i] / visits[i] and 1 / sqrt(visits[i]), kept by the backup so that
#                        the UCT scan reads two contiguous arrays.
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
def search_joint(n_iter, base, expanded, mult, offset, visits, value, mean, isq, counter, state,
                 j0, d0, valid, vs_left, known, past, indptr, nbr, table, ucut, points, cdf, guide,
                 rollout, exploration, samples, scale, inv, inv_sqrt, sqrt_log,
                 left, left_tree, mark, xval, pts, path, choice, max_block):
    """Run up to ``n_iter`` MCTS iterations on the joint-action tree (see the block comment).

    Stops early, before an iteration, when fewer than ``max_block`` (>= 2^k of any node) free
    node ids remain; returns the number of iterations run (the caller grows the arrays and calls
    again: the result does not depend on where the calls split the iterations).

    Arguments are those of :func:`search` except the tree (``base, expanded, mult, offset,
    visits, value, mean, isq, counter``), ``choice`` (int64 ``[R]`` scratch) and ``max_block``.
    """
    n_carriers, n_stages = valid.shape
    cap = visits.shape[0]
    n_nodes = counter[0]
    known_flat = known.reshape(known.size)
    done = 0
    while done < n_iter:
        if n_nodes + max_block > cap:
            break
        for r in range(n_carriers):
            left[r] = d0[r]
        node = ROOT
        path[0] = ROOT
        plen = 1
        n = 0
        k = j0
        # Invariant: the path's joint actions (stages j0..k-1) are applied to left/mark/pts.
        while k < n_stages:
            nc = 0
            for r in range(n_carriers):
                if valid[r, k] and left[r] > 0:
                    if not forced(vs_left[r, k], left[r]):
                        choice[nc] = r
                        nc += 1
                    else:  # forced
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
                visits[child] = 0
                value[child] = 0.0
                expand = True
            else:  # UCT among the node's children (ties to the earliest expanded)
                b0 = base[node]
                nv = visits[node]
                ex = exploration * (sqrt_log[nv] if nv < UCT_TABLE else math.sqrt(math.log(nv)))
                best = 0
                best_s = -np.inf
                for i in range(n_act):  # contiguous: the child block
                    s = mean[b0 + i] + ex * isq[b0 + i]
                    if s > best_s:
                        best_s = s
                        best = i
                slot = best
                child = b0 + best
                expand = False
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
            if expand:
                break
        q = (k - j0) * n_carriers
        reward = _simulate(state, q, n, n_carriers, samples, scale, j0, left, left_tree, valid, vs_left, known,
                           known_flat, table, ucut, points, cdf, guide, rollout, mark, xval, pts, past, indptr, nbr)
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
        done += 1
    counter[0] = n_nodes
    return done

