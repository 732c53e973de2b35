"""MCTS-SSAP and MCTS-Random, fast: array trees searched by numba kernels.

The algorithm is the paper's (see :mod:`planner.mcts.reference` for the plain version and
docs/performance.md, "Planner decision time", for the comparison), in one of two tree layouts (``layout=``):

* ``"joint"`` — the reference's tree: a node is one stage, its children are the joint actions
  of the carriers with a choice there (forced carriers fixed), ``2^k`` for ``k`` such carriers,
  expanded one untried action per visit in a random order that is never listed (the ``i``-th
  expanded child is ``(a * i + b) mod 2^k`` with ``a`` odd and ``a``, ``b`` drawn per node);
  a node's children occupy one contiguous block of ids reserved at its first expansion
  (:func:`planner.mcts.kernel.search_joint`). Refused beyond ``JOINT_LIMIT`` carriers
  with a choice.
* ``"binary"`` — **each tree level is one carrier's binary choice**. A stage is up to R
  consecutive levels, carriers in index order; carriers with no choice at a stage (∅ stage, no
  passenger left, or forced to deploy) get no level and their action is applied while walking.
  A path through the levels of one stage spells one feasible joint action, so the tree reaches
  exactly the joint actions the joint-action tree reaches; UCT statistics are shared between
  joint actions with a common prefix, and each iteration expands one binary node
  (:func:`planner.mcts.kernel.search_binary`). At most ``iterations + 1`` nodes, whatever R
  (an expanded node reserves a ``[stay, deploy]`` block of 2 ids).
* ``"auto"`` (default) — joint for problems of at most ``JOINT_MAX_CARRIERS`` carriers, binary
  beyond. With the paper's nearly greedy exploration constant the binary levels lose quality
  against the joint tree once the fleet has several carriers (docs/performance.md, "Planner
  decision time"); beyond that size the joint tree cannot try each root action even a few times
  in the default budget.

Per iteration (the step functions of :mod:`planner.mcts.kernel`): UCT selection with constant ``c``
on normalised rewards, expansion of one untried binary child (uniformly random when both are
untried), lazy sampling of future observations from the prior (only where a rollout decision or
the evaluation reads them; open-loop), the SSAP rollout per carrier on the conflict-discounted
observation ``x / (1 + conflicts with chosen deployments)`` or the uniformly random feasible
rollout, evaluation of the whole trajectory with the exact penalty rule, backup.

The executed action is the **most visited** root child (joint layout; ties: higher mean, then
expansion order), or follows the most visited child at each binary level of the root stage
(binary layout; ties: higher mean, then "stay"; a level never expanded, only with budgets below
~R iterations, falls back to the SSAP rule on the conflict-discounted observation).

Priors: the kernels sample the compiled problem's sampler (:mod:`planner.compiled`): exact
inverse CDF over a discrete prior's support (table priors on their own points), a continuous
prior by ``CONTINUOUS_ATOMS`` equiprobable atoms at its quantiles.

Randomness: one uint64 drawn from the decision's Generator seeds the kernel's splitmix64 stream
once per decision, so a decision is a deterministic function of the view and the Generator (in
iteration mode; in ``plan_ms`` mode the number of iterations depends on the clock).
"""
from __future__ import annotations

import functools
import time

import numpy as np

from planner import coverage as cov
from planner import ssap
from planner.compiled import compile_problem
from planner.coverage_plan import plan_for
from planner.mcts import kernel as _k
from planner.problem import Problem, StageView, make_view, point_weights, warm_up_problem
from planner.settings import DEFAULT_EXPLORATION, DEFAULT_ITERATIONS, DEFAULT_SAMPLES, LAYOUTS, check_budget

#: Rollout policies.
ROLLOUTS = {"ssap": _k.ROLLOUT_SSAP, "random": _k.ROLLOUT_RANDOM}
#: Time-budget mode: the first kernel call runs this many iterations to measure the rate.
FIRST_CHUNK = 16
#: Time-budget mode: a kernel call runs at most this many times the previous call's iterations
#: (an iteration costs more as the tree deepens, so the rate is re-measured often).
CHUNK_GROWTH = 4
#: Time-budget mode: a kernel call aims at most at this fraction of the remaining time ...
CHUNK_OF_REMAINING = 0.5
#: ... and at most at this fraction of the whole budget.
CHUNK_OF_BUDGET = 0.2
#: Time-budget mode: stop when less than this fraction of the budget remains.
STOP_FRACTION = 0.01
#: Node capacity of the first allocation in time-budget mode (grown geometrically).
INITIAL_CAPACITY = 4096
#: ``layout="auto"`` uses the joint-action tree when at most this many carriers can still have a
#: choice (2^8 = 256 root actions: 10,000 iterations try each about 40 times), the binary
#: levels beyond (where the joint tree cannot even try each root action once).
JOINT_MAX_CARRIERS = 8
#: The joint layout reserves 2^k node ids per expanded node (k carriers with a choice): it is
#: refused beyond this many (the binary layout has no such limit).
JOINT_LIMIT = 16


def read_only(a: np.ndarray) -> np.ndarray:
    """``a`` read-only (itself if it is, else a read-only view). numba types a read-only array
    apart from a writable one and compiles a kernel once per combination it is called with:
    every per-problem input the kernels only read is passed read-only, so that each kernel is
    compiled once (a problem's cached arrays are read-only, a prior's table or a placeholder may
    not be; mixing them compiled ``search_joint`` three times, 8 s of CPU each on a new machine)."""
    if not a.flags.writeable:
        return a
    view = a.view()
    view.setflags(write=False)
    return view


def _model(problem: Problem, cover: _k.Cover | None = None) -> _k.Model:
    """The compiled problem as the kernels read it (``cover``: the coverage reward's arrays, None
    for the penalty rule); its arrays read-only (:func:`read_only`)."""
    cp = compile_problem(problem)
    s = cp.sampler
    return _k.Model(*map(read_only, (cp.table, cp.ucut, s.points, s.cdf, s.guide, cp.indptr, cp.nbr)),
                    float(cp.scale), _NO_COVER if cover is None else cover)


def _cover(on: bool, *arrays, past_value: float) -> _k.Cover:
    """A :class:`~planner.mcts.kernel.Cover`: its per-problem arrays (all but the last three, which
    the kernels write) read-only (:func:`read_only`)."""
    return _k.Cover(on, *map(read_only, arrays[:-3]), *arrays[-3:], past_value)


_I0, _F0 = np.zeros(1, dtype=np.int64), np.zeros(1)
#: The penalty rule's placeholder (same types as a real one: one compiled kernel serves both).
_NO_COVER = _cover(False, _I0, _I0, _I0, _F0, _F0, np.zeros(1, dtype=np.uint8), _I0, _F0, _F0, _I0, _I0, _F0,
                   np.zeros((2, 1), dtype=np.int64), np.zeros(1, dtype=np.int64), past_value=0.0)


def cover_state(view: StageView) -> _k.Cover:
    """The coverage reward of one decision as the kernels read it: the problem's CSR lists and
    per-point thresholds (:func:`planner.coverage_plan.plan_for`), the counts the view reveals,
    the regions its past deployments cover and their (revealed) value."""
    return cover_arrays(view.problem, view.counts, view.deployed)


def cover_arrays(problem: Problem, known: np.ndarray, deployed: np.ndarray) -> _k.Cover:
    """:func:`cover_state` from the revealed region counts ``known`` (float ``[M]``, NaN
    unrevealed) and the past deployments ``deployed`` (bool ``[R, N]``)."""
    plan = plan_for(problem)
    cnt = plan.plan_counts(known)
    revealed = ~np.isnan(cnt)
    covered = np.zeros(len(cnt), dtype=np.int64)  # -1: covered by the past (the kernels' ticks start at 1)
    for a in np.flatnonzero(np.asarray(deployed).reshape(-1)).tolist():
        covered[plan.pidx[plan.pptr[a]:plan.pptr[a + 1]]] = -1
    past_value = float(cnt[(covered < 0) & revealed].sum())
    stamp = np.where(revealed, -1, 0).astype(np.int64)  # -1: revealed; 0: no sample drew it yet
    return _cover(True, plan.pptr, plan.pidx, plan.tptr, plan.thr, plan.ucut, plan.solo, plan.rptr, plan.rpoints,
                  plan.rcdf, plan.gptr, plan.guide, np.ascontiguousarray(np.nan_to_num(cnt, nan=0.0)),
                  np.ascontiguousarray(np.stack([covered, stamp])), np.zeros(1, dtype=np.int64), past_value=past_value)


@functools.lru_cache(maxsize=1)
def _uct_tables() -> _k.UCTTables:
    return _k.UCTTables(*_k.uct_tables())


def _stats(capacity: int) -> _k.Stats:
    return _k.Stats(np.zeros(capacity, dtype=np.int64), np.zeros(capacity), np.zeros(capacity), np.zeros(capacity))


def _grown(arrays: tuple, new: int, fill=0) -> list:
    """Each array extended to ``new`` entries (``fill`` in the new ones)."""
    return [np.concatenate([a, np.full(new - a.shape[0], fill, dtype=a.dtype)]) for a in arrays]


class _NodeStats:
    """The per-node statistics both layouts share (``self.stats``, a kernel ``Stats``)."""

    stats: _k.Stats

    @property
    def visits(self) -> np.ndarray:
        """int64 ``[cap]`` iterations through each node."""
        return self.stats.visits

    @property
    def value(self) -> np.ndarray:
        """float64 ``[cap]`` sum of the normalised rewards of those iterations."""
        return self.stats.value


class _Tree(_NodeStats):
    """Node arrays of the binary layout (:class:`planner.mcts.kernel.BinaryTree`), grown
    geometrically; an expanded node reserves a block of 2 ids ``[stay, deploy]``."""

    def __init__(self, capacity: int):
        self.base = np.full(capacity, _k.UNEXPANDED, dtype=np.int64)
        self.point = np.zeros(capacity, dtype=np.int64)
        self.stats = _stats(capacity)
        self.counter = np.ones(1, dtype=np.int64)  # the root exists

    def reserve(self, more: int) -> None:
        """Make room for ``more`` new ids."""
        need = int(self.counter[0]) + more
        cap = self.point.shape[0]
        if need <= cap:
            return
        new = max(need, 2 * cap)
        (self.base,) = _grown((self.base,), new, _k.UNEXPANDED)
        (self.point,) = _grown((self.point,), new)
        self.stats = _k.Stats(*_grown(tuple(self.stats), new))

    def arrays(self) -> _k.BinaryTree:
        return _k.BinaryTree(self.base, self.point, self.counter, self.stats)

    def created(self) -> int:
        """Nodes created (reserved block entries never expanded have no visit)."""
        n = int(self.counter[0])
        return 1 + int(np.count_nonzero(self.stats.visits[1:n]))


class _JointTree(_NodeStats):
    """Node arrays of the joint-action layout (:class:`planner.mcts.kernel.JointTree`), grown
    geometrically; ids are reserved a child block (``2^k`` ids) at a time."""

    def __init__(self, capacity: int):
        self.base = np.zeros(capacity, dtype=np.int64)
        self.expanded = np.zeros(capacity, dtype=np.int64)
        self.mult = np.zeros(capacity, dtype=np.uint64)
        self.offset = np.zeros(capacity, dtype=np.uint64)
        self.stats = _stats(capacity)
        self.counter = np.ones(1, dtype=np.int64)  # the root exists

    def touch(self) -> None:
        """Write every entry once, so that the first decision does not take the page faults of
        fresh (lazily zeroed) memory inside its search."""
        for a in (self.base, self.expanded, self.mult, self.offset, *self.stats):
            a.fill(0)

    def created(self) -> int:
        """Nodes created: the root and, level by level, the first ``expanded`` ids of each created
        node's block (the other reserved ids hold whatever an earlier decision left there)."""
        total = 1
        level = np.zeros(1, dtype=np.int64)
        while level.size:
            n = self.expanded[level]
            level, n = level[n > 0], n[n > 0]
            count = int(n.sum())
            total += count
            # ids base[v] + 0 .. base[v] + n[v] - 1 of every node v of the level, concatenated
            level = np.repeat(self.base[level] - (np.cumsum(n) - n), n) + np.arange(count)
        return total

    def reset(self) -> None:
        """An empty tree (the root only). Other entries are garbage until the kernel writes them:
        it reads a node's fields only after creating it (see search_joint)."""
        self.counter[0] = 1
        self.expanded[0] = 0
        self.stats.visits[0] = 0
        self.stats.value[0] = 0.0

    def grow(self) -> None:
        """Double the capacity."""
        new = 2 * self.base.shape[0]
        self.base, self.expanded, self.mult, self.offset = _grown(
            (self.base, self.expanded, self.mult, self.offset), new)
        self.stats = _k.Stats(*_grown(tuple(self.stats), new))

    def arrays(self) -> _k.JointTree:
        return _k.JointTree(self.base, self.expanded, self.mult, self.offset, self.counter, self.stats)


class MCTSPlanner:
    """The paper's MCTS planner, fast (see the module docstring).

    Args:
        rollout: ``"ssap"`` (MCTS-SSAP) or ``"random"`` (MCTS-Random).
        iterations: iterations per decision (ignored when ``plan_ms`` is given).
        plan_ms: wall-clock budget per decision, milliseconds (anytime mode; at least one
            iteration runs).
        exploration: UCT constant ``c`` on normalised rewards.
        samples: Monte Carlo rollouts per iteration (their mean is backed up).
        layout: tree layout, ``"auto"`` (default), ``"joint"`` or ``"binary"`` (see the module
            docstring; ``"auto"`` is joint when the problem has at most JOINT_MAX_CARRIERS
            carriers, binary beyond, so the layout is fixed per problem).
    """

    def __init__(self, rollout: str = "ssap", iterations: int = DEFAULT_ITERATIONS, plan_ms: float | None = None,
                 exploration: float = DEFAULT_EXPLORATION, samples: int = DEFAULT_SAMPLES, layout: str = LAYOUTS[0]):
        if layout not in LAYOUTS:
            raise ValueError(f"layout must be one of {LAYOUTS}, got {layout!r}")
        if rollout not in ROLLOUTS:
            raise ValueError(f"rollout must be one of {tuple(ROLLOUTS)}, got {rollout!r}")
        iterations, plan_ms = check_budget(iterations, plan_ms)
        if int(samples) < 1:
            raise ValueError(f"samples must be >= 1, got {samples}")
        if not exploration >= 0:
            raise ValueError(f"exploration must be >= 0, got {exploration}")
        self.rollout = rollout
        self.iterations = iterations
        self.plan_ms = plan_ms
        self.exploration = float(exploration)
        self.samples = int(samples)
        self.layout = layout
        self.name = f"mcts-{rollout}"
        self.last_iterations = 0  # iterations run by the latest decision (for benchmarks)
        self.last_nodes = 0  # tree nodes of the latest decision
        self.last_reserved = 0  # node ids allocated by the latest decision (joint: whole child blocks)
        self.last_layout = None  # layout used by the latest decision
        self._joint_tree = None  # joint-layout node arrays, reused by the next decision

    def release(self) -> None:
        """Drop the node arrays kept for the next decision (the next one allocates afresh)."""
        self._joint_tree = None

    def _joint_capacity(self, k_max: int) -> int:
        """Node ids a joint-layout decision allocates first with at most ``k_max`` carriers with a
        choice (``plan_ms`` mode grows them as it goes)."""
        max_block = 1 << k_max
        budget_nodes = self.iterations if self.plan_ms is None else INITIAL_CAPACITY
        return 1 + max_block + min(16 * budget_nodes, budget_nodes * max_block)

    def layout_for(self, problem: Problem) -> str:
        """The layout used on ``problem`` ("joint" or "binary")."""
        if self.layout != "auto":
            return self.layout
        return "joint" if problem.valid.shape[0] <= JOINT_MAX_CARRIERS else "binary"

    def warm_up(self, problem: Problem | None = None) -> None:
        """Load (or compile, the first time ever) the numba kernels with a tiny decision.

        Call before timing decisions; compiled code is cached on disk across runs.
        """
        given = problem is not None
        if problem is None:
            problem = warm_up_problem()
        x = np.where(problem.valid, 1.0, np.nan)
        counts = None if problem.coverage is None else np.ones(problem.coverage.n_regions)
        view = make_view(problem, 0, x, np.zeros(problem.valid.shape, dtype=bool), counts=counts)
        saved = (self.iterations, self.plan_ms)
        layout = self.layout
        self.iterations, self.plan_ms = 2, None
        try:
            if not (view.can_deploy & ~view.must_deploy).any():
                tiny = _tiny_view_args()
                view = make_view(*tiny)
                if self.layout == "auto" and self.layout_for(problem) != self.layout_for(tiny[0]):
                    self.layout = self.layout_for(problem)  # load the kernel the problem will use
            self.decide(view, np.random.default_rng(0))
        finally:
            self.iterations, self.plan_ms = saved
            self.layout = layout
        if given and self.layout_for(problem) == "joint":
            # The node arrays of the problem's decisions (the largest at stage 0: the carriers that
            # can still choose only decrease), allocated and written now rather than in the first
            # decision: about 10 MB at R = 6, whose page faults cost that decision about 10 ms.
            k_max = int(np.count_nonzero((problem.passengers > 0) & problem.valid.any(axis=1)))
            if k_max <= JOINT_LIMIT:
                want = self._joint_capacity(k_max)
                if self._joint_tree is None or self._joint_tree.base.shape[0] < want:
                    self._joint_tree = _JointTree(want)
                    self._joint_tree.touch()

    def decide(self, view: StageView, rng: np.random.Generator) -> np.ndarray:
        """bool ``[R]``: carriers deploying at ``view.stage``."""
        start = time.perf_counter()
        problem = view.problem
        n_carriers, n_stages = problem.valid.shape
        j0 = view.stage
        can, must = view.can_deploy, view.must_deploy
        choice = can & ~must
        if not choice.any():  # a single feasible joint action: nothing to plan
            self.last_iterations = 0
            self.last_nodes = 0
            return must.copy()
        layout = self.layout_for(problem)
        self.last_layout = layout
        state = rng.integers(2 ** 64, dtype=np.uint64, size=1)  # the kernel's random stream

        valid = np.ascontiguousarray(view.valid, dtype=np.uint8)
        vs_left = view.stages_left_table
        d0 = np.ascontiguousarray(view.passengers_left, dtype=np.int64)
        known = np.ascontiguousarray(view.observations, dtype=np.float64)  # NaN after the root stage
        past = np.flatnonzero(view.deployed.reshape(-1)).astype(np.int64)
        mark = np.zeros(n_carriers * n_stages, dtype=np.uint8)
        mark[past] = 1
        xval = np.zeros(n_carriers * n_stages, dtype=np.float64)
        xval[past] = known.reshape(-1)[past]
        weighted = problem.weights is not None
        if weighted and problem.coverage is not None:
            raise ValueError(f"{self.name}: passenger values under the coverage reward are not supported")
        if weighted:  # passenger values: past deployments with their passengers' weights
            # In units of the mean passenger value, so the exploration constant keeps its meaning.
            unit = float(problem.weights[problem.weights > 0].mean())
            xval[past] *= point_weights(problem, view.past_releases).reshape(-1)[past] / unit
            ws0 = np.zeros((n_carriers, problem.weights.shape[1] + 1))
            for r in range(n_carriers):
                w = np.sort(problem.weights[r, view.aboard[r]])[::-1] / unit
                ws0[r, : len(w)] = w
        else:
            ws0 = np.zeros((1, 1))
        root = _k.Root(j0, d0, valid, vs_left, known, known.reshape(-1), past, ws0, weighted)
        scratch = _k.Scratch(
            state,
            np.zeros(n_carriers, dtype=np.int64),  # left
            np.zeros(n_carriers, dtype=np.int64),  # left_tree
            mark,
            xval,
            np.zeros(n_carriers * n_stages, dtype=np.int64),  # pts
            np.zeros((n_stages - j0) * n_carriers + 2, dtype=np.int64),  # path
            np.zeros(n_carriers, dtype=np.int64),  # choice
            np.zeros_like(ws0),  # ws
            np.zeros(n_carriers, dtype=np.int64),  # dleft
        )
        cover = None if problem.coverage is None else cover_state(view)
        fixed = (root, _model(problem, cover), _k.Settings(ROLLOUTS[self.rollout], self.exploration, self.samples),
                 _uct_tables(), scratch)
        if layout == "joint":
            # Upper bound of the choice carriers at any node: carriers with a passenger left and a
            # valid stage from j0 on.
            k_max = int(np.count_nonzero((d0 > 0) & (vs_left[:, j0] > 0)))
            if k_max > JOINT_LIMIT:
                raise ValueError(f"layout 'joint' supports at most {JOINT_LIMIT} carriers with a choice, "
                                 f"found {k_max}")
            max_block = 1 << k_max
            want = self._joint_capacity(k_max)
            tree = self._joint_tree
            if tree is None or tree.base.shape[0] < want:
                # Kept across decisions: a fresh multi-megabyte tree per decision cost page faults.
                tree = self._joint_tree = _JointTree(want)
            tree.reset()

            def run(n_iter: int) -> None:
                while n_iter > 0:
                    ran = _k.search_joint(n_iter, tree.arrays(), *fixed, max_block)
                    n_iter -= ran
                    if n_iter > 0:
                        tree.grow()
        else:
            first = int(np.flatnonzero(choice)[0])  # the root is the first carrier with a choice
            tree = _Tree(2 * self.iterations + 1 if self.plan_ms is None else INITIAL_CAPACITY)
            tree.point[_k.ROOT] = first

            def run(n_iter: int) -> None:
                tree.reserve(2 * n_iter)  # a block of 2 ids per expansion
                _k.search_binary(n_iter, tree.arrays(), *fixed)

        if self.plan_ms is None:
            run(self.iterations)
            done = self.iterations
        else:
            budget = self.plan_ms / 1e3
            deadline = start + budget
            chunk = FIRST_CHUNK
            done = 0
            while True:
                t0 = time.perf_counter()
                run(chunk)
                done += chunk
                now = time.perf_counter()
                remaining = deadline - now
                per_iteration = (now - t0) / chunk  # the latest rate: iterations slow down as the tree grows
                if remaining < max(STOP_FRACTION * budget, per_iteration):
                    break
                target = min(CHUNK_OF_REMAINING * remaining, CHUNK_OF_BUDGET * budget)
                chunk = int(min(CHUNK_GROWTH * chunk, max(1.0, target / per_iteration)))
        self.last_iterations = done
        if layout == "joint":
            self.last_nodes = tree.created()  # created, not reserved
            self.last_reserved = int(tree.counter[0])
            return self._extract_joint(tree, choice, must)
        self.last_nodes = tree.created()
        self.last_reserved = int(tree.counter[0])
        return self._extract(view, tree, choice, must)

    @staticmethod
    def _extract_joint(tree: _JointTree, choice: np.ndarray, must: np.ndarray) -> np.ndarray:
        """The most visited root child's joint action (ties: higher mean, then expansion order)."""
        root = _k.ROOT
        carriers = np.flatnonzero(choice)
        n_act = 1 << len(carriers)
        expanded = int(tree.expanded[root])
        b0 = int(tree.base[root])
        best, key = 0, None
        visits, value = tree.stats.visits, tree.stats.value
        for slot in range(expanded):
            v = int(visits[b0 + slot])
            k = (v, float(value[b0 + slot]) / v)
            if key is None or k > key:
                best, key = slot, k
        # The action of a slot: (mult * slot + offset) mod 2^64 mod 2^k (2^k divides 2^64).
        act = (int(tree.mult[root]) * best + int(tree.offset[root])) % n_act
        decision = must.copy()
        for i, r in enumerate(carriers.tolist()):
            decision[r] = bool(act >> i & 1)
        return decision

    def _extract(self, view: StageView, tree: _Tree, choice: np.ndarray, must: np.ndarray) -> np.ndarray:
        """Follow the most visited child through the root stage's binary levels."""
        problem = view.problem
        n_stages = problem.n_stages
        j0 = view.stage
        decision = must.copy()
        node = _k.ROOT
        passengers_left, stages_left = view.passengers_left, view.stages_left
        table = compile_problem(problem).table
        for r in np.flatnonzero(choice).tolist():
            # Invariant: at the root stage the choice carriers are fixed, one level each.
            assert node == _k.UNEXPANDED or tree.point[node] == r
            first = int(tree.base[node]) if node != _k.UNEXPANDED else _k.UNEXPANDED
            if first != _k.UNEXPANDED:  # a block exists: at least one of [stay, deploy] was created
                visits, value = tree.stats.visits, tree.stats.value
                best, key = _k.UNEXPANDED, None
                for b in (0, 1):
                    c = first + b
                    if visits[c] == 0:  # never created
                        continue
                    k = (visits[c], value[c] / visits[c])
                    if key is None or k > key:
                        best, key = b, k
                deploy = best == 1
                node = first + best
            else:  # never expanded: the rollout's rule on the conflict-discounted observation
                selected = view.deployed.copy()
                selected[:, j0] = decision
                a = r * n_stages + j0
                if problem.coverage is not None:  # ... or on the marginal coverage
                    n, d = int(stages_left[r]), int(passengers_left[r])
                    gain = cov.marginal_gain(problem.coverage, cov.best_weights(problem.coverage, selected), a,
                                             np.nan_to_num(view.counts, nan=0.0))
                    decision[r] = self.rollout == "ssap" and plan_for(problem).deploys(a, gain, n, d)
                    node = _k.UNEXPANDED
                    continue
                conflicts = int(np.count_nonzero(compile_problem(problem).conflict[a] & selected.reshape(-1)))
                n, d = int(stages_left[r]), int(passengers_left[r])
                if self.rollout == "ssap":
                    deploy = ssap.deploys(table, view.observations[r, j0] / (1 + conflicts), n, d)
                else:
                    deploy = False
                node = _k.UNEXPANDED
            decision[r] = deploy
        return decision


def _tiny_view_args():
    problem = warm_up_problem()
    x = np.ones((2, 3))
    return problem, 0, x, np.zeros((2, 3), dtype=bool)
