"""Closed-loop rollout planner (``closed-loop``): search over the current stage only.

The paper's MCTS tree is open-loop: below the root its actions are fixed whatever the sampled
observations turn out to be, so with no conflicts it trails plain SSAP, which is optimal there.
This planner keeps the search at the current stage and lets a policy *react* to every sampled
future below it (a one-step rollout algorithm, i.e. policy improvement over its base policy):

1. **Decomposition.** Carriers are linked when any of their still-relevant decision points
   (past deployments, and scheduled stages >= j of carriers with passengers left) share an
   overlap. Connected components of that graph cannot influence each other's reward, so each is
   decided on its own. A component without any conflict is decided by plain SSAP, which is
   exactly optimal for it (so with no overlaps this planner *is* SSAP).
2. **Blocks.** A component of more than ``BLOCK`` carriers (a street grid joins most of a large
   fleet into one) is split into connected blocks of at most ``BLOCK`` carriers, grown
   breadth-first, searched one after another from the conflict-aware SSAP action of the whole
   component; a block's rollouts also simulate its halo (its direct neighbours) at their
   current actions, including what earlier blocks chose. A flip mostly changes its own and its
   neighbours' rewards, so scoring it over the whole component only adds noise and cost: with
   blocks the cost per carrier stops growing with the component (quadratic to linear in R;
   docs/performance.md, "Decision time against R").
3. **Candidates.** For a block with ``k`` free carriers (may deploy, not forced) every one of
   the ``2^k`` joint actions is a candidate when ``k <= ENUMERATE_MAX``; otherwise a coordinate
   ascent from the base policy's action evaluates all single-carrier flips per round.
4. **Evaluation with common random numbers.** Every candidate is scored on the *same* sampled
   futures. A rollout applies the candidate at stage j, then the base policy: at each later
   stage, in carrier order, a carrier with ``d`` passengers and ``n`` valid stages left deploys
   at point ``q`` iff it is forced or the *marginal* gain of deploying,
   ``x / (1 + c) - sum_k x_k (1/p_k - 1/(p_k + 1))`` over the ``c`` already chosen deployments
   ``k`` sharing an overlap, minus the externality ``ext[q]`` exceeds the threshold
   ``thr[q, d]`` (:func:`conflict_values`, computed once per decision: the carrier's value of
   waiting with the conflicts its later points will meet, and what deploying at ``q`` takes from
   the neighbours' later points). Without conflicts ahead ``thr[q, d]`` is DLR's ``a[n, n - d]``
   and ``ext[q] = 0``; with ``rule_rounds = 0`` it is so everywhere, the conflict-aware SSAP rule
   closed-loop used before (docs/results.md). With passenger values the same thresholds decide
   which passenger goes (:func:`_weighted_choice`).
5. **Control variate.** Alongside, the same sampled future is run through plain independent SSAP,
   whose expected raw total is known exactly (:func:`planner.ssap.expected_value`). The
   estimate of a candidate is ``mean(aware - plain) + exact(plain)``: unbiased, with far less
   variance, and exact when nothing conflicts.

``closed-loop-gated`` (:class:`GatedClosedLoopPlanner`) is this planner with two changes in what
it does with the estimates and the base action: a candidate is chosen over the base (or current)
action only when its estimated gain clears :data:`GATE` standard errors of the paired difference,
and the base action decides a stage's free carriers by margin (:func:`base_action`).

Budget: ``iterations`` full-fleet rollouts per decision (the MCTS meaning of an iteration), i.e.
``iterations * R`` single-carrier trajectories split over the blocks that need a search; or
``plan_ms`` milliseconds. Feasibility (at most one deployment per stage, at most D, none at ∅,
forced deployments) holds in the executed action and in every rollout. Stateless across stages.
"""
from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np
from numba import njit

from planner import ssap
from planner.compiled import compile_problem
from planner.joint import ENUMERATE_MAX, SAMPLES_MAX, SAMPLES_MIN, every_combination, sampled_mean
from planner.jitcache import cache_follows_sources
from planner.kernels import cut, deploys, rank
from planner.problem import Problem, StageView, make_view, point_weights
from planner.settings import check_budget

#: Largest number of carriers searched together. A larger conflict component is split into
#: connected blocks of at most this many carriers, searched one after another; each block's
#: rollouts also simulate its neighbours (its halo) at their current actions. This keeps the
#: search linear in the component's size (see :func:`_blocks`).
BLOCK = 32
#: Alternations of :func:`conflict_values` behind the rollouts' base policy (0: DLR's thresholds
#: without externalities, the conflict-aware SSAP rule).
RULE_ROUNDS = 6
#: ``closed-loop-gated``'s gate: the standard errors a candidate's estimated gain over the base
#: action (or, in the coordinate ascent, over the current action) must clear to be chosen; a
#: candidate is ranked by its estimate minus ``GATE`` standard errors of its paired difference
#: from candidate 0 on the same sampled futures. ``closed-loop`` has no gate (0: the largest
#: estimate), and there the largest of many noisy estimates is largely noise (the winner's
#: curse): its search gained nothing over its own base action at R = 32 (docs/planner.md,
#: "closed-loop-gated").
GATE = 2.0


# ----------------------------------------------------------------------------- numba kernels


@njit(cache=True)
def marginal_gain(q, xq, sel, p, xv, nbr_ptr, nbr_idx):
    """Change of the total reward if flat point ``q`` with value ``xq`` joins the selection."""
    c = 0
    loss = 0.0
    for e in range(nbr_ptr[q], nbr_ptr[q + 1]):
        k = nbr_idx[e]
        if sel[k]:
            c += 1
            pk = p[k]
            loss += xv[k] / (pk * (pk + 1.0))  # x/p - x/(p+1)
    return xq / (1.0 + c) - loss


@njit(cache=True)
def select_point(q, xq, sel, p, xv, nbr_ptr, nbr_idx, log, nlog):
    """Add ``q`` to the selection, logging every change (``-(k+1)``: p[k] incremented; ``q``: selected)."""
    c = 0
    for e in range(nbr_ptr[q], nbr_ptr[q + 1]):
        k = nbr_idx[e]
        if sel[k]:
            p[k] += 1
            log[nlog] = -(k + 1)
            nlog += 1
            c += 1
    sel[q] = True
    p[q] = 1 + c
    xv[q] = xq
    log[nlog] = q
    nlog += 1
    return nlog


@njit(cache=True)
def undo_selection(sel, p, log, nlog):
    for i in range(nlog - 1, -1, -1):
        v = log[i]
        if v < 0:
            p[-v - 1] -= 1
        else:
            sel[v] = False


class Selection(NamedTuple):
    """Selection state over flat points ``[R*N]``: chosen, penalty ``p`` (1 + chosen points sharing
    an overlap), value (the observation, weighted with passenger values). The kernels restore it."""

    sel: np.ndarray
    p: np.ndarray
    xv: np.ndarray


class Net(NamedTuple):
    """What the kernels read of the problem: validity bool ``[R, N]``, valid stages left int64
    ``[R, N + 1]``, DLR thresholds ``[N + 2, N + 2]`` (raw units), CSR of "shares an overlap"."""

    valid: np.ndarray
    nleft: np.ndarray
    table: np.ndarray
    nbr_ptr: np.ndarray
    nbr_idx: np.ndarray


class Rule(NamedTuple):
    """The rollout base policy's rule (:func:`conflict_values`): float ``[R*N, D + 1]`` threshold of
    each flat point for each number of passengers left and float ``[R*N]`` externality; a carrier
    deploys iff forced or ``gain - ext[q] > cut(thr[q, d])``."""

    thr: np.ndarray
    ext: np.ndarray


class Candidates(NamedTuple):
    """Candidate joint actions bool ``[K, m]`` of a component's ``m`` carriers ``members`` (int64,
    in decision order), their observations now float ``[m]`` and passengers left before the
    current stage int64 ``[m]``."""

    actions: np.ndarray
    members: np.ndarray
    xnow: np.ndarray
    left0: np.ndarray


class _Stage(NamedTuple):
    """One decision of the planner: the view, the compiled problem, the shared :class:`Selection`,
    validity ``[R, N]``, valid stages left ``[R, N + 1]``, passengers left ``[R]``, the
    observations now ``[R]`` and the base policy's :class:`Rule`."""

    view: object
    prep: object
    selection: Selection
    valid: np.ndarray
    nleft: np.ndarray
    left: np.ndarray
    xnow: np.ndarray
    rule: Rule


# The rollout after the current stage (the loop over t below) is written out here and in
# planner.decentralised._evaluate_imputed rather than shared, because one inlined numba function
# for both made the decisions measurably slower (`python -m tools.rollout_bench`; the figures:
# docs/planner.md, "closed-loop"). The two loops differ in their rule anyway (closed-loop's
# reads the base policy's thresholds and externalities). The anytime sampling loop around the
# kernels is shared (sampled_mean).
@njit(cache=True)
def _evaluate(cand, stage, n_stages, net, selection, samples, out, control_variate, rule):
    """Per-sample control-variate values of every candidate.

    Args:
        cand: :class:`Candidates` of one component.
        stage, n_stages: the current stage and N.
        net: :class:`Net`.
        selection: :class:`Selection` of the past deployments, restored on return.
        samples: float ``[S, N - stage - 1, m]`` sampled future observations.
        out: float ``[K, S]`` receives ``aware_total - plain_future`` per candidate and sample
            (raw units; constant offsets common to all candidates left out), or ``aware_total``
            alone when ``control_variate`` is False.
        rule: :class:`Rule` of the base policy.
    """
    actions, members, xnow, left0 = cand
    valid, nleft, table, nbr_ptr, nbr_idx = net
    sel, p, xv = selection
    thr, ext = rule
    n_cand = actions.shape[0]
    m = members.shape[0]
    n_samples = samples.shape[0]
    left = np.empty(m, np.int64)
    lefti = np.empty(m, np.int64)
    log = np.empty(sel.shape[0] + nbr_idx.shape[0] + 1, np.int64)
    for k in range(n_cand):
        for s in range(n_samples):
            nlog = np.int64(0)  # not a literal 0 (one compilation of undo_selection)
            total = 0.0
            plain = 0.0
            for i in range(m):
                left[i] = left0[i]
                if actions[k, i]:
                    q = members[i] * n_stages + stage
                    total += marginal_gain(q, xnow[i], sel, p, xv, nbr_ptr, nbr_idx)
                    nlog = select_point(q, xnow[i], sel, p, xv, nbr_ptr, nbr_idx, log, nlog)
                    left[i] -= 1
                lefti[i] = left[i]
            for t in range(stage + 1, n_stages):
                for i in range(m):
                    r = members[i]
                    if not valid[r, t]:
                        continue
                    n = nleft[r, t]
                    xs = samples[s, t - stage - 1, i]
                    d = left[i]
                    if d > 0:
                        q = r * n_stages + t
                        g = marginal_gain(q, xs, sel, p, xv, nbr_ptr, nbr_idx)
                        if n <= d or g - ext[q] > cut(thr[q, d]):
                            total += g
                            nlog = select_point(q, xs, sel, p, xv, nbr_ptr, nbr_idx, log, nlog)
                            left[i] = d - 1
                    d = lefti[i]
                    if d > 0 and deploys(table, xs, n, d):
                        plain += xs
                        lefti[i] = d - 1
            undo_selection(sel, p, log, nlog)
            out[k, s] = total - plain if control_variate else total


@njit(cache=True)
def _conflicts(q, sel, p, xv, nbr_ptr, nbr_idx):
    """(c, loss): the chosen points sharing an overlap with flat point ``q``, and what their rewards
    lose if ``q`` joins (``marginal_gain`` is ``x / (1 + c) - loss``)."""
    c = 0
    loss = 0.0
    for e in range(nbr_ptr[q], nbr_ptr[q + 1]):
        k = nbr_idx[e]
        if sel[k]:
            c += 1
            pk = p[k]
            loss += xv[k] / (pk * (pk + 1.0))
    return c, loss


@njit(cache=True)
def _drop(ws, i, pos, d):
    """Remove the passenger at rank position ``pos`` from member i's sorted weights ``ws[i, :d]``."""
    for k in range(pos, d - 1):
        ws[i, k] = ws[i, k + 1]
    ws[i, d - 1] = 0.0


@njit(cache=True)
def _weighted_choice(thr, q, y, loss, n, d, ws, i):
    """The base policy's rule with passenger values, for member i at flat point ``q`` with
    ``d >= 1`` passengers of sorted weights ``ws[i, :d]`` (``ws[i, d] == 0``), ``n`` valid stages
    left, conflict-adjusted observation ``y = x / (1 + c)`` and ``loss`` (the conflict loss plus
    the externality ``ext[q]``). Returns the rank position (0-based) of the passenger to release,
    or -1 to wait.

    With ``thr[q, k]`` the marginal value of the k-th passenger later (:func:`conflict_values`;
    DLR's ``a[n, n - k]`` where no conflict lies ahead), the best passenger to release at y is the
    rank of y's interval among them, capped at d (the loss is the same for every passenger); it
    goes iff forced or its gain ``w y - loss`` exceeds what the release costs the future,
    ``V(S) - V(S without it) = sum_{k >= i} (w_k - w_{k+1}) thr[q, k]`` over the ranks
    ``k <= min(d, n - 1)``. Equal weights give the unweighted rule ``y - loss > thr[q, d]``."""
    top = d if d < n - 1 else n - 1
    i_rank = 1
    for k in range(1, top + 1):
        if k < d and y <= cut(thr[q, k]):
            i_rank += 1
    if n <= d:
        return i_rank - 1
    cost = 0.0
    for k in range(i_rank, top + 1):
        cost += (ws[i, k - 1] - ws[i, k]) * thr[q, k]
    return i_rank - 1 if ws[i, i_rank - 1] * y - loss > cost else -1


@njit(cache=True)
def _evaluate_weighted(cand, stage, n_stages, net, selection, samples, out, control_variate, ws0, pos_now, rule):
    """:func:`_evaluate` for a problem with passenger values (``selection.xv`` holds weighted values).

    Args (besides :func:`_evaluate`'s):
        ws0: float ``[m, max D + 1]`` weights of each member's passengers aboard, largest first,
            0.0-padded.
        pos_now: int64 ``[m]`` rank position of the passenger a deployment now releases
            (:func:`planner.passengers.choose`).
        rule: :class:`Rule` of the base policy.
    """
    actions, members, xnow, left0 = cand
    valid, nleft, table, nbr_ptr, nbr_idx = net
    sel, p, xv = selection
    n_cand = actions.shape[0]
    m = members.shape[0]
    n_samples = samples.shape[0]
    left = np.empty(m, np.int64)
    lefti = np.empty(m, np.int64)
    thr, ext = rule
    ws = np.empty_like(ws0)
    wp = np.empty_like(ws0)
    log = np.empty(sel.shape[0] + nbr_idx.shape[0] + 1, np.int64)
    for k in range(n_cand):
        for s in range(n_samples):
            nlog = np.int64(0)  # not a literal 0 (one compilation of undo_selection)
            total = 0.0
            plain = 0.0
            ws[:, :] = ws0
            for i in range(m):
                left[i] = left0[i]
                if actions[k, i]:
                    q = members[i] * n_stages + stage
                    v = ws[i, pos_now[i]] * xnow[i]
                    total += marginal_gain(q, v, sel, p, xv, nbr_ptr, nbr_idx)
                    nlog = select_point(q, v, sel, p, xv, nbr_ptr, nbr_idx, log, nlog)
                    _drop(ws, i, pos_now[i], left[i])
                    left[i] -= 1
                lefti[i] = left[i]
            wp[:, :] = ws
            for t in range(stage + 1, n_stages):
                for i in range(m):
                    r = members[i]
                    if not valid[r, t]:
                        continue
                    n = nleft[r, t]
                    xs = samples[s, t - stage - 1, i]
                    d = left[i]
                    if d > 0:
                        q = r * n_stages + t
                        c, loss = _conflicts(q, sel, p, xv, nbr_ptr, nbr_idx)
                        y = xs / (1.0 + c)
                        pos = _weighted_choice(thr, q, y, loss + ext[q], n, d, ws, i)
                        if pos >= 0:
                            w = ws[i, pos]
                            total += w * y - loss
                            nlog = select_point(q, w * xs, sel, p, xv, nbr_ptr, nbr_idx, log, nlog)
                            _drop(ws, i, pos, d)
                            left[i] = d - 1
                    d = lefti[i]
                    if d > 0 and deploys(table, xs, n, d):
                        pos = rank(table, xs, n)
                        pos = (pos if pos < d else d) - 1
                        plain += wp[i, pos] * xs
                        _drop(wp, i, pos, d)
                        lefti[i] = d - 1
            undo_selection(sel, p, log, nlog)
            out[k, s] = total - plain if control_variate else total


@njit(cache=True, inline="always")
def _tail(points, tail_mass, tail_first, c):
    """(P(X > c), E[(X - c)^+]) under the sampler's atoms ``points`` (ascending), with suffix sums
    ``tail_mass[i] = sum_{l >= i} mass[l]`` and ``tail_first[i] = sum_{l >= i} mass[l] points[l]``."""
    lo = 0
    hi = points.shape[0]
    while lo < hi:  # first atom above c
        mid = (lo + hi) // 2
        if points[mid] > c:
            hi = mid
        else:
            lo = mid + 1
    return tail_mass[lo], tail_first[lo] - c * tail_mass[lo]


@njit(cache=True)
def conflict_values(stage, n_stages, net, left, past, prior, rounds, rule):
    """The rollout base policy's thresholds and externalities with the conflicts to come.

    Plain DLR thresholds value a carrier's later points as if nobody else could take them. Here a
    later point ``q`` is *available* with probability ``alpha[q]`` (none of the open points
    sharing an overlap with it and deciding before it — earlier stage, or same stage and a lower
    carrier index — deploys; they deploy independently with their probabilities ``pi``; a past
    deployment sharing an overlap makes it unavailable), and worth 0 when unavailable (half of
    its value, minus half of the blocker's). A deployment at ``q`` also takes from each open point
    ``k`` deciding after it and sharing an overlap what that point's availability is worth to its
    carrier: ``ext[q] = sum_k alpha[k] / (1 - pi[q]) * (W_k(available) - W_k(unavailable))``.
    Per carrier, ``W[t, d]`` (the value of ``d`` passengers from stage ``t`` on, externalities
    charged) follows the backward recursion of a single carrier with stage-dependent
    observations; ``pi`` and the passengers-left distribution follow forward in stage order.
    ``rounds`` alternations of the two passes, from the plain DLR policy (``alpha = 1``, ``ext =
    0``). Where a carrier's later points are all free of both (``alpha = 1``, ``ext = 0``) its
    threshold is exactly DLR's, ``table[n, n - d]``, so without conflicts the rule is SSAP's.

    Args:
        stage, n_stages: the current stage j and N.
        net: :class:`Net`.
        left: int64 ``[R]`` passengers left at stage j; past: bool ``[R*N]`` past deployments.
        prior: ``(slot_value, points, tail_mass, tail_first)``: DLR values float ``[N + 1, N + 1]``,
            the prior's atoms and their suffix sums (``CompiledProblem.tails``, :func:`_tail`).
        rounds: alternations of the backward and forward passes.
        rule: :class:`Rule` receiving ``thr`` (float ``[R*N, D + 1]``, the threshold of each point
            for ``d`` passengers left, read where not forced, ``d < n``) and ``ext`` (float
            ``[R*N]``).
    The rollout rule: deploy iff forced or ``gain - ext[q] > cut(thr[q, d])``.
    """
    valid, nleft, table, nbr_ptr, nbr_idx = net
    slot_value, points, tail_mass, tail_first = prior
    thr, ext = rule
    n_carriers = valid.shape[0]
    n_points = n_carriers * n_stages
    d_max = thr.shape[1] - 1
    mu = tail_first[0]
    alpha = np.ones(n_points)
    pi = np.zeros(n_points)
    ext[:] = 0.0
    value = np.zeros((n_carriers, n_stages + 1, d_max + 1))
    dist = np.zeros((n_carriers, n_stages + 1, d_max + 1))
    new_ext = np.zeros(n_points)
    for rnd in range(rounds + 1):
        # Backward: values and thresholds from alpha and ext.
        for r in range(n_carriers):
            if left[r] <= 0:
                continue
            clean = True
            value[r, n_stages, :] = 0.0
            for t in range(n_stages - 1, stage - 1, -1):
                if not valid[r, t]:
                    for d in range(d_max + 1):  # element by element: a slice copy compiles a shape check
                        value[r, t, d] = value[r, t + 1, d]
                    continue
                n = nleft[r, t]
                q = r * n_stages + t
                top = d_max if d_max < n else n
                for d in range(1, top + 1):
                    if d < n:
                        thr[q, d] = table[n, n - d] if clean else value[r, t + 1, d] - value[r, t + 1, d - 1]
                clean = clean and alpha[q] == 1.0 and ext[q] == 0.0
                value[r, t, 0] = 0.0
                for d in range(1, top + 1):
                    if clean:
                        value[r, t, d] = slot_value[n, d]
                        continue
                    a = alpha[q]
                    w1 = value[r, t + 1, d - 1]
                    if d >= n:
                        value[r, t, d] = a * mu - ext[q] + w1
                    else:
                        w0 = value[r, t + 1, d]
                        c = w0 - w1 + ext[q]
                        _, h = _tail(points, tail_mass, tail_first, c)
                        value[r, t, d] = w0 + a * h + (1.0 - a) * max(-c, 0.0)
        if rnd == rounds:
            break
        # Forward in decision order: availability, deployment probabilities, passengers left.
        for r in range(n_carriers):
            dist[r, stage, :] = 0.0
            dist[r, stage, min(max(left[r], 0), d_max)] = 1.0
        for t in range(stage, n_stages):
            for r in range(n_carriers):
                q = r * n_stages + t
                for d in range(d_max + 1):
                    dist[r, t + 1, d] = dist[r, t, d]
                pi[q] = 0.0
                if not valid[r, t] or left[r] <= 0:
                    continue
                a = 1.0
                for e in range(nbr_ptr[q], nbr_ptr[q + 1]):
                    k = nbr_idx[e]
                    if past[k]:
                        a = 0.0
                        break
                    tk = k % n_stages
                    if tk < t or (tk == t and k // n_stages < r):
                        a *= 1.0 - pi[k]
                alpha[q] = a
                n = nleft[r, t]
                dist[r, t + 1, :] = 0.0
                total = 0.0
                for d in range(d_max + 1):
                    mass = dist[r, t, d]
                    if mass == 0.0:
                        continue
                    if d == 0:
                        dist[r, t + 1, 0] += mass
                        continue
                    if n <= d:
                        go = 1.0
                    else:
                        bar = cut(thr[q, d])
                        above, _ = _tail(points, tail_mass, tail_first, bar + ext[q])
                        go = a * above + ((1.0 - a) if -ext[q] > bar else 0.0)
                    total += mass * go
                    dist[r, t + 1, d - 1] += mass * go
                    dist[r, t + 1, d] += mass * (1.0 - go)
                pi[q] = total
        # Externalities: what a deployment at q takes from the open points deciding after it.
        for r in range(n_carriers):
            if left[r] <= 0:
                continue
            for t in range(stage, n_stages):
                q = r * n_stages + t
                new_ext[q] = 0.0
                if not valid[r, t]:
                    continue
                s = 0.0
                for e in range(nbr_ptr[q], nbr_ptr[q + 1]):
                    k = nbr_idx[e]
                    rk = k // n_stages
                    tk = k % n_stages
                    if left[rk] <= 0 or not valid[rk, tk] or tk < stage or past[k]:
                        continue
                    if not (tk > t or (tk == t and rk > r)):
                        continue
                    ak = alpha[k] / max(1.0 - pi[q], 1e-3)
                    if ak > 1.0:
                        ak = 1.0
                    nk = nleft[rk, tk]
                    worth = 0.0
                    for d in range(1, d_max + 1):
                        mass = dist[rk, tk, d]
                        if mass == 0.0:
                            continue
                        if nk <= d:
                            worth += mass * mu
                        else:
                            c = value[rk, tk + 1, d] - value[rk, tk + 1, d - 1] + ext[k]
                            _, h = _tail(points, tail_mass, tail_first, c)
                            worth += mass * (h - max(-c, 0.0))
                    s += ak * worth
                new_ext[q] = s
        for q in range(n_points):
            if rnd == 0:
                ext[q] = new_ext[q]
            else:  # damped: two points that share an overlap would otherwise swap roles each round
                ext[q] = 0.5 * (ext[q] + new_ext[q])
    return alpha, pi


# ----------------------------------------------------------------------------- helpers


def conflict_components(adjacency: np.ndarray) -> list[np.ndarray]:
    """Connected components (sorted carrier indices) of a symmetric bool ``[R, R]`` graph."""
    n = adjacency.shape[0]
    label = np.full(n, -1)
    comps = []
    for start in range(n):
        if label[start] >= 0:
            continue
        stack = [start]
        label[start] = len(comps)
        members = []
        while stack:
            r = stack.pop()
            members.append(r)
            for s in np.flatnonzero(adjacency[r] & (label < 0)):
                label[s] = len(comps)
                stack.append(s)
        comps.append(np.array(sorted(members), dtype=np.int64))
    return comps


def grow_block(seed: int, adjacency: np.ndarray, allowed: np.ndarray, size: int) -> np.ndarray:
    """Up to ``size`` carriers reached breadth-first from ``seed`` through ``allowed`` carriers
    (bool ``[R]``), nearest first (ties in index order); sorted."""
    taken = np.zeros(len(allowed), dtype=bool)
    taken[seed] = True
    order = [seed]
    head = 0
    while head < len(order) and len(order) < size:
        nxt = np.flatnonzero(adjacency[order[head]] & allowed & ~taken)[: size - len(order)]
        taken[nxt] = True
        order.extend(int(s) for s in nxt)
        head += 1
    return np.array(sorted(order), dtype=np.int64)


def block_halo(block: np.ndarray, adjacency: np.ndarray, within: np.ndarray) -> np.ndarray:
    """``block`` and its direct neighbours among ``within`` (bool ``[R]``), sorted."""
    near = adjacency[block].any(axis=0) & within
    near[block] = True
    return np.flatnonzero(near).astype(np.int64)


def _blocks(comp: np.ndarray, adjacency: np.ndarray, size: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Split a connected component into blocks of at most ``size`` carriers.

    Blocks are grown breadth-first from the lowest carrier not yet in a block, so each is
    connected where the graph allows it. Returns ``(block, members)`` pairs: ``members`` is the
    block with its halo (its direct neighbours in ``comp``), in index order. A component of at
    most ``size`` carriers (or ``size <= 0``) is one block without a halo.
    """
    if size <= 0 or len(comp) <= size:
        return [(comp, comp)]
    n = adjacency.shape[0]
    within = np.zeros(n, dtype=bool)
    within[comp] = True
    left = within.copy()
    out = []
    for seed in comp:
        if not left[seed]:
            continue
        block = grow_block(int(seed), adjacency, left, size)
        left[block] = False
        out.append((block, block_halo(block, adjacency, within)))
    return out


# ----------------------------------------------------------------------------- the planner


class ClosedLoopPlanner:
    """One-stage search with conflict-aware SSAP rollouts that react to each sampled future.

    Args:
        iterations: full-fleet rollouts per decision (default 10,000; ignored with ``plan_ms``).
        plan_ms: time budget per decision, milliseconds (anytime; not bit-reproducible).
        block: :data:`BLOCK`.
        rule_rounds: :data:`RULE_ROUNDS` (0: the previous base policy, DLR's thresholds).
        gate: standard errors of its paired gap to the base (or current) action a candidate's
            estimate is lowered by before the search takes the largest (0, closed-loop's: the
            largest estimate; :data:`GATE`, closed-loop-gated's).
        by_margin: the base action decides the free carriers of a stage in decreasing order of
            their margin over the rule's threshold (closed-loop-gated) or in index order (False,
            closed-loop); see :func:`base_action`.
    """

    name = "closed-loop"

    def __init__(self, iterations: int | None = None, plan_ms: float | None = None, block: int = BLOCK,
                 rule_rounds: int = RULE_ROUNDS, gate: float = 0.0, by_margin: bool = False, **_ignored):
        self.iterations, self.plan_ms = check_budget(iterations, plan_ms)
        self.block = int(block)
        self.rule_rounds = int(rule_rounds)
        self.gate = float(gate)
        self.by_margin = bool(by_margin)

    def warm_up(self, problem: Problem) -> None:
        """Compile the kernels (cached on disk) and prepare the problem's constants."""
        # Not planner.problem.warm_up_problem(): on that instance a kernel of the first real
        # decision stays unloaded, so the first decision would pay for loading it.
        tiny = Problem.build(2, np.ones((2, 4), dtype=bool), [[[0, 1], [1, 1]], [[0, 2], [1, 3]]])
        x = np.full((2, 4), 3.0)
        ClosedLoopPlanner(iterations=8).decide(make_view(tiny, 0, x, np.zeros((2, 4), bool)),
                                               np.random.default_rng(0))
        if problem.coverage is not None:  # the coverage kernel, on the problem itself
            counts = np.ones(problem.coverage.n_regions)
            ClosedLoopPlanner(iterations=8).decide(make_view(problem, 0, np.where(problem.valid, 1.0, np.nan),
                                                             np.zeros(problem.valid.shape, bool), counts=counts),
                                                   np.random.default_rng(0))
            return
        compile_problem(problem).slot_value

    # The decision -----------------------------------------------------------------------------

    def decide(self, view: StageView, rng: np.random.Generator) -> np.ndarray:
        problem = view.problem
        n_carriers = problem.n_carriers
        j = view.stage
        can = view.can_deploy
        must = view.must_deploy
        free = can & ~must
        decision = must.copy()
        if not free.any():
            return decision
        if problem.coverage is not None:
            from planner.closedloop_cover import decide_cover  # the coverage form (its own numba kernel)

            return decide_cover(self, view, rng)
        prep = compile_problem(problem)
        valid = np.ascontiguousarray(view.valid)
        left = view.passengers_left.astype(np.int64)
        nleft = view.stages_left_table
        xnow = np.nan_to_num(view.observations[:, j], nan=0.0)

        # Relevant points: past deployments, and scheduled points from j on of carriers with
        # passengers left. Carriers are linked when a conflict joins two relevant points of
        # which at least one is still open (past-past conflicts are settled).
        past = view.deployed.ravel()
        open_ = (valid & (left > 0)[:, None]).copy()
        open_[:, :j] = False
        open_ = open_.ravel()
        adjacency = prep.links(open_, past)
        linked = adjacency.copy()
        np.fill_diagonal(linked, True)

        comps = conflict_components(linked)
        search = []
        for comp in comps:
            if not free[comp].any():
                continue
            if not adjacency[np.ix_(comp, comp)].any():
                # No conflict can touch these carriers: independent SSAP is optimal.
                for r in comp[free[comp]]:
                    decision[r] = ssap.decide(prep.table, float(xnow[r]), int(nleft[r, j]), int(left[r]))
                continue
            search.append(comp)
        if not search:
            return decision

        # Shared selection state: past deployments with their current penalties.
        sel = past.copy()
        p = prep.penalties(sel)
        xv = np.nan_to_num(np.where(view.deployed, _past_values(view), 0.0), nan=0.0).ravel()
        state = Selection(sel, p, xv)
        rule = base_rule(view, prep, valid, nleft, left, past, self.rule_rounds)
        ctx = _Stage(view, prep, state, valid, nleft, left, xnow, rule)

        plans = []
        for comp in search:
            typed = None if problem.weights is None else _typed_state(view, comp, prep.table)
            decision[comp] = base_action(comp, view.stage, prep, state, nleft, left, xnow, must, free, typed, rule,
                                         by_margin=self.by_margin)
            for block, members in _blocks(comp, adjacency, self.block):
                flip = np.flatnonzero(np.isin(members, block[free[block]]))
                k = len(flip)
                if k == 0:
                    continue
                rounds = 1 if k <= ENUMERATE_MAX else 3
                n_cand = (1 << k) if k <= ENUMERATE_MAX else k + 1
                plans.append((members, flip, n_cand * rounds))
        weight = sum(len(members) * w for members, _, w in plans)
        samples = int(np.clip(self.iterations * n_carriers // max(weight, 1), SAMPLES_MIN, SAMPLES_MAX))
        deadline = None if self.plan_ms is None else time.perf_counter() + self.plan_ms / 1e3
        for members, flip, w in plans:
            share = len(members) * w / weight
            block_deadline = None
            if deadline is not None:
                block_deadline = time.perf_counter() + share * max(deadline - time.perf_counter(), 0.0)
            action = self._search(members, decision[members], flip, samples, block_deadline, ctx, rng)
            decision[members[flip]] = action[flip]
        return decision

    # Search of one block ----------------------------------------------------------------------

    def _search(self, members, base, flip, samples, deadline, ctx, rng):
        """The best joint action of ``members`` found from ``base`` by changing only the carriers at
        positions ``flip``: all ``2^k`` combinations when ``k <= ENUMERATE_MAX``, else coordinate
        ascent over single flips (3 rounds, or until the deadline). ``ctx``: the :class:`_Stage`."""
        k = len(flip)
        def score(actions, score_deadline):
            return self._score(actions, members, samples, score_deadline, ctx, rng)

        if k <= ENUMERATE_MAX:
            actions = every_combination(base, flip)
            return actions[int(np.argmax(score(actions, deadline)))]
        return self.ascend(base, flip, deadline, score)

    @staticmethod
    def ascend(base, flip, deadline, score):
        """Coordinate ascent over single flips of the positions ``flip`` of the joint action
        ``base`` (3 rounds, or until ``deadline``); ``score(actions, deadline)`` estimates each
        candidate of a round (the first candidate is the current action)."""
        k = len(flip)
        current = base
        for _ in range(3 if deadline is None else 1 << 30):
            actions = np.repeat(current[None, :], k + 1, axis=0)
            for a, i in enumerate(flip, start=1):
                actions[a, i] = not actions[a, i]
            round_deadline = None
            if deadline is not None:
                if time.perf_counter() >= deadline:
                    break
                round_deadline = time.perf_counter() + (deadline - time.perf_counter()) / 2
            best = int(np.argmax(score(actions, round_deadline)))
            if best == 0:
                break
            current = actions[best]
        return current

    def _score(self, actions, comp, samples, deadline, ctx, rng, control_variate=True):
        """Estimated value (raw units, up to a constant common to all candidates) of each candidate
        joint action of the carriers ``comp`` (``ctx``: the :class:`_Stage`).

        With ``control_variate`` (the default) the estimate is ``mean(aware - plain) + exact(plain)``;
        without, the plain Monte Carlo mean of the aware rollouts (for tests: same expectation).
        With ``control_variate`` and ``self.gate > 0`` each candidate's estimate is lowered by
        ``gate`` standard errors of its paired difference from ``actions[0]`` (the base or current
        action, which keeps its estimate): the score the search maximises (:data:`GATE`).
        """
        view, prep, selection, valid, nleft, left, xnow, rule = ctx
        problem = view.problem
        j = view.stage
        n_stages = problem.n_stages
        horizon = n_stages - j - 1
        comp_left = left[comp]
        typed = None if problem.weights is None else _typed_state(view, comp, prep.table)
        cand = Candidates(actions, comp, xnow[comp], comp_left)
        net = Net(valid, nleft, prep.table, prep.indptr, prep.nbr)

        def evaluate(batch):
            draws = prep.sampler.sample(rng, (batch, horizon, len(comp)))
            out = np.empty((len(actions), batch))
            if typed is None:
                _evaluate(cand, j, n_stages, net, selection, draws, out, control_variate, rule)
            else:
                _evaluate_weighted(cand, j, n_stages, net, selection, draws, out, control_variate, typed[0], typed[1],
                                   rule)
            return out

        if not control_variate:
            return sampled_mean(len(actions), samples, deadline, evaluate)
        gated = self.gate > 0.0 and len(actions) > 1
        if gated:
            mean, gap_se = sampled_mean(len(actions), samples, deadline, evaluate, spread=True)
            mean = mean - self.gate * gap_se
        else:
            mean = sampled_mean(len(actions), samples, deadline, evaluate)
        if typed is not None:
            _, _, stay, go = typed
            return mean + np.where(actions, go[None, :], stay[None, :]).sum(axis=1)
        # Exact expected future of plain SSAP after each candidate's action.
        n_after = nleft[comp, j + 1]
        d_after = np.minimum(comp_left[None, :] - actions.astype(np.int64), n_stages)
        exact = prep.slot_value[n_after[None, :], d_after].sum(axis=1)
        return mean + exact


class GatedClosedLoopPlanner(ClosedLoopPlanner):
    """``closed-loop-gated``: closed-loop whose search takes a candidate over the base (or current)
    action only when its estimated gain clears :data:`GATE` standard errors of the paired
    difference, and whose base action lets a stage's free carriers decide in decreasing order of
    their margin over the rule's threshold (docs/planner.md, "closed-loop-gated"). The same
    rollouts, candidates, blocks and budget as closed-loop."""

    name = "closed-loop-gated"

    def __init__(self, iterations: int | None = None, plan_ms: float | None = None, block: int = BLOCK,
                 rule_rounds: int = RULE_ROUNDS, gate: float = GATE, by_margin: bool = True, **_ignored):
        super().__init__(iterations, plan_ms, block, rule_rounds, gate, by_margin)


def _dlr_rule(prep, q: int, n: int) -> Rule:
    """A :class:`Rule` whose row ``q`` holds DLR's thresholds of ``n`` valid stages left (the
    previous rule, for :func:`base_action` without a rule)."""
    thr = np.zeros((q + 1, prep.n_stages + 2))
    for k in range(1, n):
        thr[q, k] = prep.table[n, n - k]
    return Rule(thr, np.zeros(q + 1))


def base_rule(view: StageView, prep, valid: np.ndarray, nleft: np.ndarray, left: np.ndarray, past: np.ndarray,
              rounds: int) -> Rule:
    """The base policy's :class:`Rule` at ``view.stage`` (:func:`conflict_values` with ``rounds``
    alternations; 0 gives DLR's thresholds and no externality, the conflict-aware SSAP rule)."""
    n_stages = view.problem.n_stages
    d_max = max(int(view.problem.passengers.max()), 1)
    thr = np.zeros((view.problem.n_carriers * n_stages, d_max + 1))
    ext = np.zeros(view.problem.n_carriers * n_stages)
    rule = Rule(thr, ext)
    conflict_values(view.stage, n_stages, Net(valid, nleft, prep.table, prep.indptr, prep.nbr), left,
                    np.ascontiguousarray(past, dtype=np.bool_), (prep.slot_value, *prep.tails), int(rounds), rule)
    return rule


def _past_values(view: StageView) -> np.ndarray:
    """Observations at past stages (the values of past deployments), float ``[R, N]``; times the
    released passenger's weight for a problem with passenger values."""
    out = np.zeros(view.observations.shape)
    out[:, : view.stage] = np.nan_to_num(view.observations[:, : view.stage], nan=0.0)
    if view.problem.weights is not None:
        out *= point_weights(view.problem, view.past_releases)
    return out


def base_action(comp: np.ndarray, stage: int, prep, state, nleft: np.ndarray, left: np.ndarray, xnow: np.ndarray,
                must: np.ndarray, free: np.ndarray, typed=None, rule: Rule | None = None,
                by_margin: bool = False) -> np.ndarray:
    """The base policy's action of the carriers ``comp`` at ``stage``, given the chosen points
    ``state = (sel, p, xv)``: bool ``[len(comp)]``. ``typed`` is :func:`_typed_state` of the view
    for a problem with passenger values (None: the unweighted rule). ``rule``: the base policy's
    :class:`Rule` (None: DLR's thresholds without externalities, the previous conflict-aware SSAP
    rule, which dec-closed-loop's partial-information path uses).

    The carriers decide one after another, each against the deployments chosen before it (the
    marginal gain): in index order, or with ``by_margin`` and a ``rule`` the forced carriers first
    and then the free ones in decreasing order of their margin ``w x - ext[q] - thr[q, d]`` (its
    value now, the released passenger's weight ``w`` with passenger values, over what it would
    need alone; ties in index order), so a carrier barely over its threshold no longer takes an
    overlap from a neighbour far over its own just because its index is lower."""
    sel, p, xv = state
    n_stages = prep.n_stages
    j = stage
    action = must[comp].copy()
    chosen = sel.copy()
    pp = p.copy()
    vv = xv.copy()
    log = np.empty(len(sel) + len(prep.nbr) + 1, dtype=np.int64)
    order = range(len(comp))
    if by_margin and rule is not None:
        margin = np.full(len(comp), np.inf)  # forced (and idle) carriers first, in index order
        for i, r in enumerate(comp):
            if free[r]:
                q = int(r) * n_stages + j
                value = float(xnow[r]) if typed is None else float(xnow[r]) * typed[0][i, typed[1][i]]
                margin[i] = value - rule.ext[q] - rule.thr[q, int(left[r])]
        order = np.argsort(-margin, kind="stable")
    for i in order:
        r = comp[i]
        q = int(r) * n_stages + j
        value = float(xnow[r])
        if typed is not None:
            ws, pos = typed[0], typed[1]
            value *= ws[i, pos[i]]
        if free[r]:
            n, d = int(nleft[r, j]), int(left[r])
            if typed is None:
                gain = marginal_gain(q, value, chosen, pp, vv, prep.indptr, prep.nbr)
                if rule is None:
                    action[i] = ssap.deploys(prep.table, gain, n, d)
                else:
                    action[i] = n <= d or gain - rule.ext[q] > ssap.cut(rule.thr[q, d])
            else:
                c, loss = _conflicts(q, chosen, pp, vv, prep.indptr, prep.nbr)
                y = float(xnow[r]) / (1.0 + c)
                thr, ext = rule if rule is not None else _dlr_rule(prep, q, n)
                action[i] = _weighted_choice(thr, q, y, loss + ext[q], n, d, ws, i) >= 0
        if action[i]:
            select_point(q, value, chosen, pp, vv, prep.indptr, prep.nbr, log, 0)
    return action


def _typed_state(view: StageView, comp: np.ndarray, table: np.ndarray):
    """Per member of ``comp``: (sorted weights aboard ``[m, max D + 1]``, rank position of the
    passenger a deployment now releases ``[m]``, the exact plain-SSAP future value after staying
    and after deploying now ``[m]`` each)."""
    from planner.passengers import choose

    problem = view.problem
    j = view.stage
    aboard = view.aboard
    released = choose(view, np.ones(problem.n_carriers, dtype=bool))
    ws = np.zeros((len(comp), problem.weights.shape[1] + 1))
    pos = np.zeros(len(comp), dtype=np.int64)
    stay = np.zeros(len(comp))
    go = np.zeros(len(comp))
    n_after = view.stages_left_table[:, j + 1]
    for i, r in enumerate(comp):
        w = problem.weights[r, aboard[r]]
        order = np.argsort(-w, kind="stable")
        ws[i, : len(w)] = w[order]
        stay[i] = ssap.weighted_value(table, int(n_after[r]), w)
        if released[r] >= 0:
            k = int(np.flatnonzero(np.flatnonzero(aboard[r]) == released[r])[0])  # its position in w
            pos[i] = int(np.flatnonzero(order == k)[0])
            go[i] = ssap.weighted_value(table, int(n_after[r]), np.delete(w, k))
    return ws, pos, stay, go



def estimate(view: StageView, actions: np.ndarray, samples: int, rng: np.random.Generator,
             control_variate: bool = True) -> np.ndarray:
    """Estimated raw value of joint actions at ``view.stage``, all carriers taken as one group.

    Args:
        view: the stage's causal view.
        actions: bool ``[K, R]`` feasible joint actions.
        samples: sampled futures, common to all actions.
        rng: the random stream.
        control_variate: use the exact plain-SSAP control variate (the planner's estimator) or
            the plain Monte Carlo mean of the conflict-aware rollouts.

    Returns:
        float ``[K]``: estimates, up to a constant common to all actions (only differences mean
        something). Both estimators have the same expectation.
    """
    problem = view.problem
    n_carriers = problem.n_carriers
    prep = compile_problem(problem)
    valid = np.ascontiguousarray(view.valid)
    left = view.passengers_left.astype(np.int64)
    nleft = view.stages_left_table
    xnow = np.nan_to_num(view.observations[:, view.stage], nan=0.0)
    sel = view.deployed.ravel().copy()
    p = prep.penalties(sel)
    xv = np.where(view.deployed, _past_values(view), 0.0).ravel()
    planner = ClosedLoopPlanner(gate=0.0)  # the estimates themselves, not the search's gated scores
    rule = base_rule(view, prep, valid, nleft, left, sel, planner.rule_rounds)
    ctx = _Stage(view, prep, Selection(sel, p, xv), valid, nleft, left, xnow, rule)
    return planner._score(np.asarray(actions, dtype=bool), np.arange(n_carriers, dtype=np.int64),
                                      int(samples), None, ctx, rng, control_variate)


cache_follows_sources(globals())  # the on-disk cache follows every planner source
