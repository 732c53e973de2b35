"""``dec-mcts``: Dec-MCTS (Best, Cliff, Patten, Mettu, Fitch, IJRR 2019) with SSAP rollouts.

Each carrier grows its own tree over its own action sequence and exchanges intents:

* **Tree.** Nodes are this carrier's choices at its remaining valid stages (stay / deploy; only
  feasible actions: no deployment without a passenger, none skipped when forced). Selection is
  D-UCT (discounted UCT: visit counts and value sums decay by ``GAMMA`` per iteration, because
  the others' sampled plans are non-stationary), with the paper's exploration constant on
  normalised rewards; one child is expanded per iteration (a random untried one).
* **Rollout.** Below the tree the carrier's own future follows the paper's rollout policy (SSAP
  thresholds on observations sampled from the prior, discounted ``x / (1 + c)`` for the ``c``
  deployments already chosen that share an overlap). Every other carrier ``b`` follows, from its
  last known deployment on, a sequence drawn from the latest intent received from it; without an
  intent, its known default policy (the same SSAP rollout). Observations the carrier has not
  received are drawn from the prior.
* **Reward.** The global objective: the exact penalty rule over the whole trajectory (known
  past, tree, rollouts), normalised.
* **Intent.** After the search: up to ``INTENT_SIZE`` distinct sequences (each node's best
  rollout sequence, nodes by discounted visits), with a distribution ``q`` optimised by
  ``GRADIENT_STEPS`` annealed steps of the paper's gradient descent
  ``q_i <- q_i - alpha q_i ((E_q[f] - E[f | x_i]) / beta + H(q) + ln q_i)``, where
  ``E[f | x_i]`` is estimated on ``INTENT_SAMPLES`` rollouts with the others drawn from their
  intents. The intent is published after the stage's decision (the comms model delivers it).
* **Decision.** The most visited feasible root action.

Budget: ``iterations`` tree iterations per carrier per stage (default the registry's 10,000), or
``plan_ms`` milliseconds per carrier per stage (the intent's optimisation comes on top).
A carrier whose conflict component has no overlap uses SSAP (optimal there; so with no overlaps
``dec-mcts`` is SSAP). Random numbers: a splitmix64 stream seeded from the carrier's copy of the
stage stream and its index (deterministic for a seed). Stages must number at most 62 (own
sequences are 64-bit masks).
"""
from __future__ import annotations

import math
import time
from typing import NamedTuple

import numpy as np
from numba import njit

from planner import ssap
from planner.compiled import compile_problem
from planner.decentralised import Intent, LocalDecision, LocalView
from planner.jitcache import cache_follows_sources
from planner.kernels import deploys, forced
from planner.mcts.kernel import _random, _sample, weigh
from planner.problem import Problem, fill_releases, point_weights, valid_stages_left, warm_up_problem
from planner.settings import DEFAULT_EXPLORATION, check_budget

#: D-UCT discount per iteration.
GAMMA = 0.999
#: Sequences in a published intent.
INTENT_SIZE = 4
#: Rollouts per candidate sequence when optimising the intent's distribution.
INTENT_SAMPLES = 64
#: Annealed gradient steps of the intent's distribution; step size; initial temperature.
GRADIENT_STEPS = 10
GRADIENT_ALPHA = 0.1
BETA0 = 1.0
#: Most stages a dec-mcts instance may have.
MAX_STAGES = 62
NO_CHILD = -1
#: Iterations between clock checks with a time budget.
CHUNK = 256


# ----------------------------------------------------------------------------- named structures
# The kernels' arguments (NamedTuples of arrays, read by numba as tuples), as in planner.mcts.kernel.


class Model(NamedTuple):
    """The compiled problem as the kernels read it (:class:`planner.compiled.CompiledProblem`)."""

    table: np.ndarray   # float64 [N + 2, N + 2] DLR thresholds (raw units)
    points: np.ndarray  # float64 [K] sampler support points
    cdf: np.ndarray     # float64 [K] cumulative probabilities
    guide: np.ndarray   # int64 [G] guide table of the inverse CDF
    indptr: np.ndarray  # int64 [R*N + 1] CSR of "shares an overlap"
    nbr: np.ndarray     # int64 [nnz]
    scale: float        # rewards are divided by it


class Root(NamedTuple):
    """What carrier ``r`` knows when it decides stage ``j``."""

    r: int                   # the deciding carrier
    j: int                   # the stage
    own_stages: np.ndarray   # int64 [S] its valid stages from j on
    valid: np.ndarray        # bool [R, N] validity as it knows it
    nleft: np.ndarray        # int64 [R, N + 1] valid stages left
    xobs: np.ndarray         # float64 [R, N] observations it has (NaN: unknown)
    record: np.ndarray       # int64 [R] per carrier, the first stage whose deployment it does not know
    left_rec: np.ndarray     # int64 [R] passengers left at ``record``
    known_pts: np.ndarray    # int64 [P] flat points known deployed
    known_x: np.ndarray      # float64 [P] their (weighted) observations
    ws0: np.ndarray          # float64 [R, max D + 1] weights aboard, largest first (a placeholder without values)
    weighted: bool           # passenger values


class Intents(NamedTuple):
    """The others' latest intents: codes int64 ``[R, K]`` (stage masks), cumulative
    probabilities float64 ``[R, K]``, count per carrier int64 ``[R]`` (0: none heard)."""

    code: np.ndarray
    cum: np.ndarray
    count: np.ndarray


class Scratch(NamedTuple):
    """Work arrays of one decision and its random stream."""

    state: np.ndarray   # uint64 [1] splitmix64 counter
    left: np.ndarray    # int64 [R] passengers left along the trajectory
    mark: np.ndarray    # int8 [R*N] selected points
    xval: np.ndarray    # float64 [R*N] their observations
    pts: np.ndarray     # int64 [R*N] selected points, in order
    plan: np.ndarray    # int64 [R] the sequence drawn for each other carrier (-1: none)
    path: np.ndarray    # int64 [N + 2] node ids of the tree path
    ws: np.ndarray      # float64 like Root.ws0, along the trajectory


class Tree(NamedTuple):
    """The carrier's tree, ``[C]`` arrays (children ``[C, 2]``): children, position in the own
    stages, passengers left, discounted visits, discounted value sums, last update, best rollout
    value and its own sequence."""

    child: np.ndarray
    pos: np.ndarray
    dleft: np.ndarray
    n_eff: np.ndarray
    w: np.ndarray
    last: np.ndarray
    bestv: np.ndarray
    bestm: np.ndarray


@njit(cache=True)
def _trajectory(own_mask, stop, root, model, scratch):
    """Build one full trajectory and return (normalised reward, own deployment mask).

    Own decisions at stages ``< stop`` come from ``own_mask``; later ones, and those of carriers
    without a plan (``plan[b] < 0``), from the conflict-discounted SSAP rollout; carriers with a
    plan deploy at its stages (and when forced). Unknown observations are drawn from the prior.
    """
    r, valid, nleft, xobs, record, left_rec = root.r, root.valid, root.nleft, root.xobs, root.record, root.left_rec
    known_pts, known_x = root.known_pts, root.known_x
    table, points, cdf, guide, indptr, nbr = model.table, model.points, model.cdf, model.guide, model.indptr, model.nbr
    state, left, mark, xval, pts, plan = scratch.state, scratch.left, scratch.mark, scratch.xval, scratch.pts, scratch.plan
    n_carriers, n_stages = valid.shape
    npts = 0
    for e in range(known_pts.shape[0]):
        a = known_pts[e]
        mark[a] = 1
        xval[a] = known_x[e]
        pts[npts] = a
        npts += 1
    tmin = n_stages
    for b in range(n_carriers):
        left[b] = left_rec[b]
        if record[b] < tmin:
            tmin = record[b]
    mine = np.int64(0)
    for t in range(tmin, n_stages):
        for b in range(n_carriers):
            if t < record[b]:
                continue
            d = left[b]
            if d <= 0 or not valid[b, t]:
                continue
            n = nleft[b, t]
            a = b * n_stages + t
            x = xobs[b, t]
            if x != x:
                x = _sample(state, points, cdf, guide)
            if b == r and t < stop:
                go = ((own_mask >> t) & 1) == 1
            elif b != r and plan[b] >= 0:
                go = forced(n, d) or ((plan[b] >> t) & 1) == 1
            else:
                c = 0
                for e in range(indptr[a], indptr[a + 1]):
                    c += mark[nbr[e]]
                go = deploys(table, x / (1.0 + c), n, d)
            if go:
                mark[a] = 1
                xval[a] = x
                pts[npts] = a
                npts += 1
                left[b] = d - 1
                if b == r:
                    mine |= np.int64(1) << t
    if root.weighted:
        n_known = known_pts.shape[0]
        weigh(npts - n_known, pts[n_known:], xval, n_stages, nleft, table, left_rec, root.ws0, scratch.ws, left)
    total = 0.0
    for e in range(npts):
        a = pts[e]
        c = 0
        for f in range(indptr[a], indptr[a + 1]):
            c += mark[nbr[f]]
        total += xval[a] / (1.0 + c)
    for e in range(npts):
        mark[pts[e]] = 0
    return total / model.scale, mine


@njit(cache=True)
def _draw_plans(state, intents, plan):
    """``plan[b]``: a sequence drawn from carrier b's intent (-1 without one)."""
    icode, icum, ik = intents
    for b in range(ik.shape[0]):
        plan[b] = -1
        if ik[b] > 0:
            u = _random(state)
            i = 0
            while i < ik[b] - 1 and icum[b, i] <= u:
                i += 1
            plan[b] = icode[b, i]


@njit(cache=True)
def _search(it0, n_iter, created, c_uct, gamma, root, intents, model, tree, scratch):
    """Run iterations ``it0 .. it0 + n_iter - 1`` from the root (node 0) of ``tree`` with
    ``created`` nodes (capacity >= created + n_iter); returns the nodes created. ``c_uct``: the
    D-UCT constant; ``gamma``: the discount per iteration."""
    r, own_stages, valid, nleft = root.r, root.own_stages, root.valid, root.nleft
    child, pos, dleft, n_eff, w, last, bestv, bestm = tree
    state, path = scratch.state, scratch.path
    n_own = own_stages.shape[0]
    for it in range(it0, it0 + n_iter):
        _draw_plans(state, intents, scratch.plan)
        node = 0
        depth = 0
        path[0] = 0
        own_mask = np.int64(0)
        stop = valid.shape[1]
        while True:
            p = pos[node]
            d = dleft[node]
            if p >= n_own or d <= 0:
                break
            t = own_stages[p]
            n = nleft[r, t]
            can_stay = n > d
            # Expand an untried feasible action, if any.
            untried0 = can_stay and child[node, 0] == NO_CHILD
            untried1 = child[node, 1] == NO_CHILD
            if untried0 or untried1:
                if untried0 and untried1:
                    a = 1 if _random(state) < 0.5 else 0
                else:
                    a = 0 if untried0 else 1
                nid = created
                created += 1
                child[node, a] = nid
                pos[nid] = p + 1
                dleft[nid] = d - a
                if a == 1:
                    own_mask |= np.int64(1) << t
                depth += 1
                path[depth] = nid
                stop = own_stages[p + 1] if p + 1 < n_own else valid.shape[1]
                break
            # D-UCT over the feasible children.
            total = 0.0
            for a in range(2):
                cid = child[node, a]
                if cid != NO_CHILD and (a == 1 or can_stay):
                    total += n_eff[cid] * gamma ** (it - last[cid])
            best = -1
            best_score = -1e300
            for a in range(2):
                cid = child[node, a]
                if cid == NO_CHILD or (a == 0 and not can_stay):
                    continue
                ne = n_eff[cid] * gamma ** (it - last[cid])
                score = w[cid] / n_eff[cid] + c_uct * math.sqrt(math.log(max(total, 1.0)) / max(ne, 1e-12))
                if score > best_score:
                    best_score = score
                    best = a
            if best == 1:
                own_mask |= np.int64(1) << t
            node = child[node, best]
            depth += 1
            path[depth] = node
            stop = own_stages[p + 1] if p + 1 < n_own else valid.shape[1]
        value, mine = _trajectory(own_mask, stop, root, model, scratch)
        for k in range(depth + 1):
            v = path[k]
            decay = gamma ** (it - last[v])
            n_eff[v] = n_eff[v] * decay + 1.0
            w[v] = w[v] * decay + value
            last[v] = it
            if value > bestv[v]:
                bestv[v] = value
                bestm[v] = mine
    return created


@njit(cache=True)
def _values_given(masks, n_samples, root, intents, model, scratch, out):
    """``out[i]``: mean reward with this carrier following ``masks[i]`` (others from intents)."""
    n_stages = root.valid.shape[1]
    for i in range(masks.shape[0]):
        acc = 0.0
        for s in range(n_samples):
            _draw_plans(scratch.state, intents, scratch.plan)
            v, _ = _trajectory(masks[i], n_stages, root, model, scratch)
            acc += v
        out[i] = acc / n_samples


def _tree(capacity: int, d_root: int) -> Tree:
    """Preallocated tree arrays for ``capacity`` nodes: children ``[C, 2]``, position, passengers
    left, discounted visits, discounted value sums, last update, best rollout value and its own
    sequence (root: position 0, ``d_root`` passengers)."""
    child = np.full((capacity, 2), NO_CHILD, dtype=np.int64)
    dleft = np.zeros(capacity, np.int64)
    dleft[0] = d_root
    return Tree(child, np.zeros(capacity, np.int64), dleft, np.zeros(capacity), np.zeros(capacity),
                np.zeros(capacity, np.int64), np.full(capacity, -np.inf), np.zeros(capacity, np.int64))


def _grown(tree: Tree, capacity: int) -> Tree:
    """The tree's arrays with room for ``capacity`` nodes (new entries as :func:`_tree`'s)."""
    fresh = _tree(capacity, 0)
    out = []
    for old, new in zip(tree, fresh):
        new[: len(old)] = old
        out.append(new)
    return Tree(*out)


def optimise_distribution(values: np.ndarray, steps: int = GRADIENT_STEPS, alpha: float = GRADIENT_ALPHA,
                          beta0: float = BETA0) -> np.ndarray:
    """Dec-MCTS's annealed gradient descent on this carrier's distribution over its candidate
    sequences, given ``values[i]`` = E[f | x_i] (others fixed): from uniform,
    ``q_i <- q_i - alpha q_i ((E_q f - E[f | x_i]) / beta + H(q) + ln q_i)``, renormalised, with
    ``beta`` annealed linearly from ``beta0`` to ``beta0 / steps``."""
    k = len(values)
    q = np.full(k, 1.0 / k)
    for step in range(steps):
        beta = beta0 * (steps - step) / steps
        expected = float(q @ values)
        entropy = -float(np.sum(q * np.log(q)))
        q = q - alpha * q * ((expected - values) / beta + entropy + np.log(q))
        q = np.clip(q, 1e-6, None)
        q /= q.sum()
    return q


def _refuse_coverage(problem: Problem) -> None:
    """dec-mcts plans with the penalty rule only (its kernel scores trajectories by x / p)."""
    if problem.coverage is not None:
        raise ValueError("dec-mcts: the coverage reward is not supported (it plans with the 1/p penalty); "
                         "use dec-closed-loop")


class DecMCTSPlanner:
    """Dec-MCTS with SSAP rollouts, one tree per carrier (see the module docstring).

    Args:
        iterations: tree iterations per carrier per stage.
        exploration: D-UCT constant on normalised rewards.
        plan_ms: time budget per carrier per stage, milliseconds (the tree search runs in chunks
            of :data:`CHUNK` iterations until it is spent; anytime, not bit-reproducible).
    """

    name = "dec-mcts"
    decentralised = True

    def __init__(self, iterations: int | None = None, exploration: float | None = None,
                 plan_ms: float | None = None, **_ignored):
        self.iterations, self.plan_ms = check_budget(iterations, plan_ms)
        self.exploration = DEFAULT_EXPLORATION if exploration is None else float(exploration)

    def warm_up(self, problem: Problem) -> None:
        _refuse_coverage(problem)
        tiny = warm_up_problem()
        xs = np.full((2, 3), 3.0)
        local = LocalView(tiny, 0, 0, 0, np.where([[1, 0, 0], [1, 0, 0]], xs, np.nan), np.zeros((2, 3), bool),
                          np.array([1, 1]), np.array([0, 0]), (None, None))
        self.decide_local(local, np.random.default_rng(0))
        compile_problem(problem).table

    def decide(self, view, rng):
        """Every carrier's decision with full information and no intents (for a central caller)."""
        from planner.decentralised import decide_all

        return decide_all(self, view, rng)

    def decide_local(self, local: LocalView, rng: np.random.Generator) -> LocalDecision:
        problem = local.problem
        _refuse_coverage(problem)
        R, N = problem.valid.shape
        if N > MAX_STAGES:
            raise ValueError(f"dec-mcts supports at most {MAX_STAGES} stages, got {N}")
        r, j = local.carrier, local.stage
        can, must, n_own, d_own = local.own()
        prep = compile_problem(problem)
        if not can or must:
            return LocalDecision(bool(must))
        valid = np.ascontiguousarray(local.valid)
        nleft = valid_stages_left(valid)
        record = local.record.astype(np.int64)
        # Does any overlap link this carrier's open points to a point that may still be chosen
        # or is chosen? If not, SSAP is optimal for it.
        left_rec = (problem.passengers - local.deployed.sum(axis=1)).astype(np.int64)
        stages = np.arange(N)
        open_ = valid & (left_rec > 0)[:, None] & (stages[None, :] >= record[:, None])
        flat = open_.ravel() | local.deployed.ravel()
        mine = np.zeros((R, N), dtype=bool)
        mine[r, j:] = open_[r, j:]
        if not (prep.conflict[mine.ravel()] & flat[None, :]).any():
            go = ssap.decide(prep.table, float(local.observations[r, j]), n_own, d_own)
            return LocalDecision(go)

        gen = np.random.default_rng([int(rng.integers(2 ** 63)), r])
        state = gen.integers(2 ** 64, dtype=np.uint64, size=1)
        known = np.flatnonzero(local.deployed.ravel()).astype(np.int64)
        known_x = np.nan_to_num(local.observations.ravel()[known], nan=0.0)
        ws0, weighted = self._values(local, known)
        if weighted:
            known_x = known_x * ws0[1]
            ws0 = ws0[0]
        icode, icum, ik = self._intent_arrays(local, R)
        own_stages = np.flatnonzero(valid[r, j:]).astype(np.int64) + j
        xobs = np.ascontiguousarray(local.observations)
        scratch = Scratch(state, np.zeros(R, np.int64), np.zeros(R * N, np.int8), np.zeros(R * N),
                          np.zeros(R * N, np.int64), np.zeros(R, np.int64), np.zeros(N + 2, np.int64),
                          np.zeros_like(ws0))
        root = Root(r, j, own_stages, valid, nleft, xobs, record, left_rec, known, known_x, ws0, weighted)
        model = Model(prep.table, prep.sampler.points, prep.sampler.cdf, prep.sampler.guide, prep.indptr, prep.nbr,
                      float(problem.scale))
        intents = Intents(icode, icum, ik)
        tree = _tree(self.iterations + 1 if self.plan_ms is None else CHUNK + 1, d_own)
        if self.plan_ms is None:
            done = self.iterations
            created = _search(0, done, 1, self.exploration, GAMMA, root, intents, model, tree, scratch)
        else:
            deadline = time.perf_counter() + self.plan_ms / 1e3
            done, created = 0, 1
            while True:
                if created + CHUNK >= len(tree.pos):
                    tree = _grown(tree, 2 * len(tree.pos))
                created = _search(done, CHUNK, created, self.exploration, GAMMA, root, intents, model, tree, scratch)
                done += CHUNK
                if time.perf_counter() >= deadline:
                    break
        child, pos, dleft, n_eff, w, last, bestv, bestm = tree
        it = done - 1
        eff = n_eff[:created] * GAMMA ** (it - last[:created])
        kids = child[0]
        score = [eff[c] if c != NO_CHILD else -1.0 for c in kids]
        go = bool(int(np.argmax(score)) == 1)
        # Candidate sequences: best rollout sequence of the chosen child first, then of the most
        # visited nodes.
        order = [kids[int(go)]] + [int(v) for v in np.argsort(-eff, kind="stable")]
        masks = []
        for v in order:
            if v == NO_CHILD or not np.isfinite(bestv[v]):
                continue
            mv = int(bestm[v])
            if ((mv >> j) & 1) != int(go) or mv in masks:
                continue
            masks.append(mv)
            if len(masks) == INTENT_SIZE:
                break
        if not masks:
            masks = [(1 << j) if go else 0]
        values = np.zeros(len(masks))
        _values_given(np.array(masks, dtype=np.int64), INTENT_SAMPLES, root, intents, model, scratch, values)
        q = optimise_distribution(values)
        seqs = np.zeros((len(masks), N), dtype=bool)
        for i, mv in enumerate(masks):
            seqs[i] = ((mv >> stages) & 1).astype(bool)
        seqs[:, :j] = local.deployed[r, :j]
        return LocalDecision(go, Intent(j, seqs, q))

    @staticmethod
    def _values(local: LocalView, known: np.ndarray):
        """Passenger values: ((sorted weights aboard ``[R, max D + 1]`` in mean-value units, the
        known deployments' weights ``[P]``), True), or (a placeholder, False) without values."""
        problem = local.problem
        if problem.weights is None:
            return np.zeros((1, 1)), False
        released = fill_releases(problem.passengers, local.deployed, local.released)
        unit = float(problem.weights[problem.weights > 0].mean())
        R = problem.n_carriers
        ws0 = np.zeros((R, problem.weights.shape[1] + 1))
        for b in range(R):
            aboard = np.ones(int(problem.passengers[b]), dtype=bool)
            aboard[released[b][released[b] >= 0]] = False
            w = np.sort(problem.weights[b, : len(aboard)][aboard])[::-1] / unit
            ws0[b, : len(w)] = w
        return (ws0, point_weights(problem, released).ravel()[known] / unit), True

    @staticmethod
    def _intent_arrays(local: LocalView, R: int):
        """Intents as arrays: codes int64 ``[R, K]`` (own stage masks), cumulative probabilities,
        count per carrier (0: none heard)."""
        icode = np.zeros((R, INTENT_SIZE), np.int64)
        icum = np.ones((R, INTENT_SIZE))
        ik = np.zeros(R, np.int64)
        N = local.problem.n_stages
        weights = np.int64(1) << np.arange(N, dtype=np.int64)
        for b, intent in enumerate(local.intents):
            if intent is None or b == local.carrier:
                continue
            k = min(len(intent.probs), INTENT_SIZE)
            icode[b, :k] = (intent.sequences[:k].astype(np.int64) * weights).sum(axis=1)
            icum[b, :k] = np.cumsum(intent.probs[:k]) / np.sum(intent.probs[:k])
            ik[b] = k
        return icode, icum, ik


cache_follows_sources(globals())  # the on-disk cache follows every planner source
