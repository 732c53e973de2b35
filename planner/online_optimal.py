"""The exact Bayes-optimal online policy for small instances, and the exact value of other policies.

Every quality figure elsewhere is a fraction of the clairvoyant bound, which knows the future.
``V*``, the expected reward of the best *online* policy, separates the price of not knowing the
future (clairvoyant minus ``V*``) from what a planner leaves on the table (``V*`` minus its value).

Method: expectimax over stages with memoisation.

* **State before stage j**: ``(j, passengers left per carrier, open points)``. An *open* point is a
  past deployment ``p`` whose reward can still change: some scheduled-valid point at a stage >= j
  of a carrier with passengers left conflicts with it. An open point is stored as
  ``(flat index, x, conflicting deployments so far)``: its final reward is ``x / (1 + final
  count)``. A deployment that can gain no more conflicts is *closed*: its reward ``x / (1 +
  count)`` is banked the moment it closes and it leaves the state.
* **Recursion**: ``V(s) = E_x[ max_a ( banked(s, x, a) + V(s') ) ]``, the expectation over the joint
  observation of the carriers that can deploy at stage j (the others' observations earn nothing),
  the maximum over the feasible joint actions (per carrier at most one deployment, forced when its
  valid stages left, the current one included, are no more than its passengers left). ``V`` of the
  empty start state is ``V*`` (raw units; divided by ``problem.scale`` like
  :func:`planner.problem.evaluate`).
* **Other policies** by the same recursion with the maximum replaced by the policy's action
  weights: ``ssap`` (each carrier's DLR thresholds) and ``random`` (each carrier deploys with
  probability d / n).

Discretisation. Discrete priors are enumerated over their support, the unbounded tails cut where
the tail mass is below :data:`TAIL_MASS` (1e-9 in total) and the rest renormalised; table priors use
their own points. Continuous priors are replaced by :data:`CONTINUOUS_ATOMS` equiprobable atoms, the
conditional means of the prior on its K quantile bins (the mean is kept); the value is then the
exact value of that discretised problem, reported with ``exact=False``.

Limits. Work grows like (states) x (joint outcomes K^m) x (joint actions 2^m) for m carriers that
can deploy at a stage. Before solving, :func:`estimate` first bounds the work from below in
O(R·N) (carriers that must still hold a passenger at a stage decide there in every state), so a
large fleet is refused before any joint action is enumerated; then it enumerates the reachable state structures
(passengers left and open points with their counts, without their x values) and counts states and
work; an instance beyond :data:`MAX_STATES` states or :data:`MAX_WORK` operations is refused with
:class:`TooLarge` (a ValueError, one line) before anything large is allocated.

Pure: numpy and scipy only.
"""
from __future__ import annotations

import itertools
import math
import weakref
from dataclasses import dataclass

import numpy as np

from planner import priors, ssap
from planner.problem import Problem, StageView

#: Total tail mass cut from an unbounded discrete prior (then renormalised).
TAIL_MASS = 1e-9
#: Equiprobable atoms standing in for a continuous prior.
CONTINUOUS_ATOMS = 12
#: Most memoised states an exact solve may create (about 0.4 kB each: ~200 MB at the limit).
MAX_STATES = 500_000
#: Most elementary operations (states x joint outcomes x joint actions) an exact solve may do
#: (20 to 50 s at the limit on one core: 2e7 to 5e7 a second).
MAX_WORK = 1e9
#: Work limit under which ``python -m coordinator.solve`` adds the online optimum by itself
#: (up to several seconds).
AUTO_WORK = 1.5e8

POLICIES = ("optimal", "ssap", "random")


class TooLarge(ValueError):
    """The instance is beyond the exact solver's size limits. ``str(err)`` is one line."""


# ----------------------------------------------------------------------------- discretisation

@dataclass(frozen=True)
class Atoms:
    """The prior as finitely many points.

    Attributes:
        points: float ``[K]`` observation values.
        probs: float ``[K]`` probabilities (sum 1).
        exact: True for a discrete prior (only a tail below :data:`TAIL_MASS` cut), False for a
            continuous prior replaced by equiprobable atoms.
    """

    points: np.ndarray
    probs: np.ndarray
    exact: bool


def discretise(prior, atoms: int = CONTINUOUS_ATOMS, tail: float = TAIL_MASS) -> Atoms:
    """The prior as :class:`Atoms` (see the module docstring for the rule)."""
    if priors.is_discrete(prior):
        lo, hi = prior.support()
        unbounded = (not np.isfinite(lo)) + (not np.isfinite(hi))
        # The whole tail budget on one unbounded side, half on each of two.
        points, probs = priors.support(prior, tail=tail / max(unbounded, 1))
        keep = probs > 0
        points, probs = points[keep], probs[keep]
        return Atoms(points, probs / probs.sum(), True)
    edges = prior.ppf(np.linspace(0.0, 1.0, atoms + 1))
    points = np.array([prior.expect(lambda v: v, lb=edges[k], ub=edges[k + 1], conditional=True)
                       for k in range(atoms)], dtype=float)
    return Atoms(points, np.full(atoms, 1.0 / atoms), False)


# ----------------------------------------------------------------------------- compiled problem

@dataclass(frozen=True, eq=False)
class _Compiled:
    """What the recursion needs of a problem, as plain Python structures.

    Attributes:
        n_carriers, n_stages: R and N.
        valid: tuple of R tuples of N bools (the schedule).
        stages_left: ``stages_left[r][j]`` valid stages of r at stages >= j (``[R][N + 1]``).
        neighbours: ``neighbours[p]`` frozenset of flat points conflicting with flat point p.
        future: ``future[p][j]`` bitmask of carriers with a valid point at a stage >= j
            conflicting with p (``[R*N][N + 1]``).
        passengers: tuple of D_r.
    """

    n_carriers: int
    n_stages: int
    valid: tuple
    stages_left: tuple
    neighbours: tuple
    future: tuple
    passengers: tuple


def _compile(problem: Problem) -> _Compiled:
    n_carriers, n_stages = problem.valid.shape
    valid = problem.valid
    stages_left = tuple(tuple(int(valid[r, j:].sum()) for j in range(n_stages + 1)) for r in range(n_carriers))
    neighbours = tuple(frozenset(np.flatnonzero(row).tolist()) for row in problem.conflict)
    future = []
    for p in range(n_carriers * n_stages):
        masks = [0] * (n_stages + 1)
        for q in neighbours[p]:
            r, j = divmod(q, n_stages)
            if valid[r, j]:
                for k in range(j + 1):
                    masks[k] |= 1 << r
        future.append(tuple(masks))
    return _Compiled(n_carriers, n_stages, tuple(tuple(bool(v) for v in row) for row in valid), stages_left,
                     neighbours, tuple(future), tuple(int(d) for d in problem.passengers))


def _alive(left: tuple) -> int:
    """Bitmask of carriers with passengers left."""
    mask = 0
    for r, d in enumerate(left):
        if d > 0:
            mask |= 1 << r
    return mask


def _actions(m: int, must: list[bool]) -> list[tuple[int, ...]]:
    """Feasible joint actions of ``m`` deciding carriers: tuples of their local indices, forced
    carriers always in. Order: by bitmask (no deployment first), which fixes tie-breaking."""
    forced = sum(1 << i for i in range(m) if must[i])
    return [tuple(i for i in range(m) if bits >> i & 1) for bits in range(1 << m) if bits & forced == forced]


# ----------------------------------------------------------------------------- size estimate

@dataclass(frozen=True)
class SizeEstimate:
    """Reachable state space of the exact recursion.

    Attributes:
        atoms: K, points per observation.
        states: memoised states a full solve creates (an upper bound).
        work: sum over states of joint outcomes x joint actions.
    """

    atoms: int
    states: int
    work: float


def estimate(problem: Problem, atoms: Atoms | None = None, max_states: int = MAX_STATES,
             max_work: float = MAX_WORK) -> SizeEstimate:
    """Count the reachable states and work by enumerating state structures (no x values).

    Stops as soon as a limit is passed and raises :class:`TooLarge`, so it is quick on big
    instances too.
    """
    if problem.weights is not None:
        raise TooLarge("online-optimal: expected an instance without passenger values (the exact recursion "
                       "has none), found passenger_values")
    atoms = discretise(problem.prior) if atoms is None else atoms
    k = len(atoms.points)
    n_carriers, n_stages = problem.valid.shape

    def refuse(what: str) -> TooLarge:
        return TooLarge(
            f"online-optimal: instance too large for the exact solver ({what}; limits {max_states:,} states, "
            f"{max_work:.0e} operations; R={n_carriers}, N={n_stages}, {k} points per observation)")

    # O(R·N) first, before anything of size (R·N)^2: a carrier that cannot have deployed all its
    # passengers before stage j (at most one per valid stage) decides at j in every reachable
    # state, so stage j costs at least K^(such carriers) operations. A large fleet is refused
    # here, before any joint action is enumerated.
    valid = np.asarray(problem.valid, dtype=bool)
    before = np.cumsum(valid, axis=1) - valid  # valid stages before j
    deciders = (valid & (np.asarray(problem.passengers)[:, None] > before)).sum(axis=0)
    floor = 0.0
    for j, m in enumerate(deciders.tolist()):
        floor += math.inf if m * math.log(max(k, 1)) > math.log(max_work) else float(k) ** m
        if floor > max_work:
            raise refuse(f"more than {max_work:.0e} operations: {m} carriers decide at stage {j}")
    comp = _compile(problem)
    layer = {(comp.passengers, ()): 1}  # structure -> 1; a structure stands for K^open states
    states = 0
    work = 0.0
    for j in range(n_stages):
        nxt = {}
        for left, opened in layer:
            n_open = len(opened)
            count = k ** n_open
            can = [r for r in range(n_carriers) if comp.valid[r][j] and left[r] > 0]
            must = [comp.stages_left[r][j] <= left[r] for r in can]
            states += count
            # 2^(free deciders) joint actions: counted before they are enumerated.
            work += float(count) * float(k) ** len(can) * 2.0 ** (len(can) - sum(must))
            if states > max_states:
                raise refuse(f"more than {max_states:,} states")
            if work > max_work:
                raise refuse(f"more than {max_work:.0e} operations")
            for action in _actions(len(can), must):
                left2, opened2, _ = _transition(comp, j, left, opened, [can[i] for i in action])
                nxt[(left2, tuple(sorted((e[0], e[1]) for e in opened2)))] = 1
        layer = nxt
    states += sum(k ** len(o) for _, o in layer)
    return SizeEstimate(k, states, work)


def _transition(comp: _Compiled, j: int, left: tuple, opened, deploying: list[int]):
    """Apply the deployments of carriers ``deploying`` at stage j.

    ``opened`` holds ``(p, c, *rest)`` tuples (rest: the x value, if any). Returns ``(left', still
    open, closing)``: still-open and closing entries as ``(p, c, *rest)`` with updated counts; new
    points come with ``rest`` = ``("new", carrier)``.
    """
    n_stages = comp.n_stages
    new = [r * n_stages + j for r in deploying]
    new_set = set(new)
    updated = [(e[0], e[1] + len(comp.neighbours[e[0]] & new_set), *e[2:]) for e in opened]
    old_points = {e[0] for e in opened}
    for r, q in zip(deploying, new):
        c = len(comp.neighbours[q] & old_points) + len(comp.neighbours[q] & new_set)
        updated.append((q, c, "new", r))
    left2 = tuple(d - 1 if r in deploying else d for r, d in enumerate(left))
    alive = _alive(left2)
    still, closing = [], []
    for e in updated:
        (still if comp.future[e[0]][j + 1] & alive else closing).append(e)
    return left2, still, closing


# ----------------------------------------------------------------------------- the recursion

class _Solver:
    """Memoised expectimax (``policy="optimal"``) or policy evaluation (``"ssap"``, ``"random"``).

    Values are raw (sum of x / p); callers divide by ``problem.scale``.
    """

    def __init__(self, problem: Problem, policy: str, atoms: Atoms):
        if policy not in POLICIES:
            raise ValueError(f"policy must be one of {', '.join(POLICIES)}, got {policy!r}")
        self.problem = problem
        self.policy = policy
        self.atoms = atoms
        self.comp = _compile(problem)
        self.table = ssap.table_for(problem) if policy == "ssap" else None
        self.memo: dict = {}
        self._prob_tensors: dict[int, np.ndarray] = {}
        self._ssap_deploy: dict[tuple[int, int], np.ndarray] = {}

    def _prob_tensor(self, m: int) -> np.ndarray:
        tensor = self._prob_tensors.get(m)
        if tensor is None:
            tensor = np.ones(())
            for _ in range(m):
                tensor = np.multiply.outer(tensor, self.atoms.probs)
            self._prob_tensors[m] = tensor
        return tensor

    def value(self, j: int, left: tuple, opened: tuple) -> float:
        """Expected raw reward still to come (open points' final rewards included) from the state
        before stage ``j``; ``opened`` is a sorted tuple of ``(p, x, count)``."""
        key = (j, left, opened)
        cached = self.memo.get(key)
        if cached is not None:
            return cached
        comp = self.comp
        if j == comp.n_stages:
            result = sum(x / (1 + c) for _, x, c in opened)
        else:
            can = [r for r in range(comp.n_carriers) if comp.valid[r][j] and left[r] > 0]
            must = [comp.stages_left[r][j] <= left[r] for r in can]
            xs = [self.atoms.points] * len(can)
            values = self.action_values(j, left, opened, can, must, xs)
            if self.policy == "optimal":
                best = np.max(np.stack([v for _, v in values]), axis=0)
            else:
                best = sum(self._weights(j, left, can, must, action) * v for action, v in values)
            result = float(np.sum(best * self._prob_tensor(len(can))))
        self.memo[key] = result
        return result

    def _weights(self, j: int, left: tuple, can: list[int], must: list[bool], action: tuple[int, ...]):
        """Probability of ``action`` under the policy, as a tensor over the deciders' atoms."""
        m = len(can)
        weight = np.ones(())
        for i, r in enumerate(can):
            n = self.comp.stages_left[r][j]
            if self.policy == "ssap":
                key = (n, left[r])
                deploy = self._ssap_deploy.get(key)
                if deploy is None:
                    deploy = np.array([ssap.decide(self.table, float(x), n, left[r]) for x in self.atoms.points], float)
                    self._ssap_deploy[key] = deploy
            else:
                deploy = np.full(len(self.atoms.points), 1.0 if must[i] else min(1.0, left[r] / n))
            factor = deploy if i in action else 1.0 - deploy
            weight = np.multiply.outer(weight, factor)
        return weight.reshape((len(self.atoms.points),) * m)

    def action_values(self, j: int, left: tuple, opened: tuple, can: list[int], must: list[bool],
                      xs: list[np.ndarray]) -> list[tuple[tuple[int, ...], np.ndarray]]:
        """For every feasible joint action (local indices into ``can``), the banked reward plus the
        continuation value, as a tensor over the deciders' observations ``xs`` (one 1-D array per
        carrier of ``can``; shape ``[len(xs[0]), ..., len(xs[m-1])]``)."""
        m = len(can)
        shape = tuple(len(v) for v in xs)
        out = []
        for action in _actions(m, must):
            deploying = [can[i] for i in action]
            left2, still, closing = _transition(self.comp, j, left, [(p, c, x) for p, x, c in opened], deploying)
            local = {r: i for i, r in enumerate(can)}
            total = np.zeros(shape)
            for e in closing:
                if e[2] == "new":
                    i = local[e[3]]
                    axis_shape = [1] * m
                    axis_shape[i] = shape[i]
                    total = total + (xs[i] / (1 + e[1])).reshape(axis_shape)
                else:
                    total = total + e[2] / (1 + e[1])
            kept = [(e[0], e[2], e[1]) for e in still if e[2] != "new"]
            fresh = [(e[0], local[e[3]], e[1]) for e in still if e[2] == "new"]
            if not fresh:
                total = total + self.value(j + 1, left2, tuple(sorted(kept)))
            else:
                axes = [i for _, i, _ in fresh]
                cont = np.empty(tuple(shape[i] for i in axes))
                for idx in itertools.product(*(range(shape[i]) for i in axes)):
                    points = kept + [(q, float(xs[i][k]), c) for (q, i, c), k in zip(fresh, idx)]
                    cont[idx] = self.value(j + 1, left2, tuple(sorted(points)))
                axis_shape = [1] * m
                for i in axes:
                    axis_shape[i] = shape[i]
                # ``axes`` are increasing (deployments are listed in carrier order), so a reshape
                # puts every continuation value on its carriers' axes.
                total = total + cont.reshape(axis_shape)
            out.append((action, np.broadcast_to(total, shape)))
        return out


# ----------------------------------------------------------------------------- public API

@dataclass(frozen=True)
class OnlineValue:
    """Exact expected reward of a policy on a problem.

    Attributes:
        expected_reward: normalised (raw / problem.scale), the units of ``evaluate``.
        exact: True for a discrete prior (tail below :data:`TAIL_MASS` cut); False when the prior
            is continuous and the value is that of its :data:`CONTINUOUS_ATOMS`-point stand-in.
        atoms: K, points per observation.
        states: memoised states the solve created.
    """

    expected_reward: float
    exact: bool
    atoms: int
    states: int


#: Solvers per problem (identity) and policy; entries go with their problem.
_SOLVERS: "weakref.WeakKeyDictionary[Problem, dict]" = weakref.WeakKeyDictionary()


def _solver(problem: Problem, policy: str, max_states: int, max_work: float) -> _Solver:
    per_problem = _SOLVERS.setdefault(problem, {})
    solver = per_problem.get(policy)
    if solver is None:
        atoms = discretise(problem.prior)
        estimate(problem, atoms, max_states, max_work)  # raises TooLarge
        solver = _Solver(problem, policy, atoms)
        per_problem[policy] = solver
    return solver


def online_value(problem: Problem, policy: str = "optimal", max_states: int = MAX_STATES,
                 max_work: float = MAX_WORK) -> OnlineValue:
    """Exact expected reward of ``policy`` ("optimal" = ``V*``, "ssap" or "random") on ``problem``
    under its schedule (no online surprises).

    Raises:
        TooLarge: beyond the limits (checked before solving).
    """
    solver = _solver(problem, policy, max_states, max_work)
    raw = solver.value(0, tuple(int(d) for d in problem.passengers), ())
    return OnlineValue(raw / problem.scale, solver.atoms.exact, len(solver.atoms.points), len(solver.memo))


class OnlineOptimalPlanner:
    """The Bayes-optimal online policy (``online-optimal``) for instances within the limits.

    At stage j it rebuilds the state from the view (passengers left, open past deployments with
    their x and conflict counts), scores every feasible joint action by its banked reward plus the
    exact continuation value, and takes the best (ties: fewest deployments, then lowest carriers).
    Deterministic; the random stream is unused. Online surprises are handled: the current stage's
    realised validity decides who can deploy, later stages follow the schedule.

    Raises (from ``warm_up`` or ``decide``):
        TooLarge: the instance is beyond the limits.
    """

    name = "online-optimal"

    def __init__(self, max_states: int = MAX_STATES, max_work: float = MAX_WORK):
        self.max_states = max_states
        self.max_work = max_work

    def warm_up(self, problem: Problem) -> None:
        """Check the size and solve the whole recursion before the first timed decision."""
        online_value(problem, "optimal", self.max_states, self.max_work)

    def decide(self, view: StageView, rng: np.random.Generator) -> np.ndarray:
        problem = view.problem
        solver = _solver(problem, "optimal", self.max_states, self.max_work)
        comp = solver.comp
        j = view.stage
        left = tuple(int(d) for d in view.passengers_left)
        alive = _alive(left)
        deployed = np.flatnonzero(view.deployed.ravel())
        chosen = set(deployed.tolist())
        x_flat = view.observations.ravel()
        opened = tuple(sorted(
            (int(p), float(x_flat[p]), len(comp.neighbours[p] & chosen))
            for p in deployed if comp.future[p][j] & alive))
        can = np.flatnonzero(view.can_deploy).tolist()
        must_now = view.must_deploy
        must = [bool(must_now[r]) for r in can]
        xs = [np.array([float(view.observations[r, j])]) for r in can]
        values = solver.action_values(j, left, opened, can, must, xs)
        best_action, best = None, -np.inf
        for action, v in values:
            score = float(v.reshape(-1)[0])
            if score > best + 1e-12 * max(1.0, abs(best)) or best_action is None:
                best_action, best = action, score
        out = np.zeros(problem.n_carriers, dtype=bool)
        for i in best_action:
            out[can[i]] = True
        return out


if __name__ == "__main__":
    from planner.measure import optimal_table  # the command line lives above the core

    optimal_table()
