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

Speed. Conflict components (carriers linked by chains of overlaps) are solved separately and
their values added. A memo entry is a state *structure* (the state without the open points' x
values) holding a numpy tensor over those x values, so the expectation over the deciders' atoms
and the maximum over joint actions are array operations, not a Python call per state.

Limits: a work budget, counted. The solvers count their real work as they go (:class:`_Work`:
tensor elements and transitions charged before each memo entry is computed, memoised values after
it is stored) and stop with :class:`TooLarge` (a ValueError, one line) when the work passes the
limit (:data:`MAX_SECONDS` of modelled CPU time at the counted rates
:data:`COUNTED_SECONDS_PER_ELEMENT`, :data:`COUNTED_SECONDS_PER_TRANSITION`, fitted to measured
solves on the development machine) or the memo :data:`MAX_STATES` values. The count is a function
of the instance and the calls made, never of a clock: the same instance is solved or refused the
same way on every machine and at every load. Before any work, :func:`admit` refuses in O(R·N·D²)
what is beyond the limits for certain or as good as certain: :func:`estimate`'s floor (carriers
that decide at a stage in every reachable state: a lower bound) above the limit, or its upper
bound on the elements and transitions, at its own pessimistic rates (:data:`SECONDS_PER_ELEMENT`,
:data:`SECONDS_PER_TRANSITION`), above :data:`ESTIMATE_SLACK` times the limits, more than the
largest estimate / counted ratio measured. ``solve``'s automatic field takes what the estimate at
the counted rates puts within :data:`AUTO_SECONDS` (:func:`auto_admit`) and solves it under
:data:`MAX_SECONDS`, a margin that an admitted solve does not exhaust (cheap: refused in
O(R·N·D²), never a solve it has to abandon).

Pure: numpy and scipy only.
"""
from __future__ import annotations

if __name__ == "__main__":  # a forward, first: this file's body runs once, under its own name
    from planner.cli.measure import optimal_table

    raise SystemExit(optimal_table())

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
#: Most memoised values (one float each, tensors over open points' x) an exact solve may store
#: (2 GB at the limit), counted as they are stored.
MAX_STATES = 2.5e8
#: Work budget of an exact solve (``online-optimal``, ``online_value``): modelled CPU seconds of the
#: work it counts (:class:`_Work`), fitted to one core of the development machine; what a plain
#: memoised expectimax solves within a minute, the solver takes (``python -m
#: tools.online_optimal_bench --admission K`` checks it).
MAX_SECONDS = 60.0
#: Counted seconds (:func:`estimate`'s ``counted_seconds``) within which ``solve`` adds the online
#: optimum by itself (:func:`auto_admit`); the admitted solve runs under :data:`MAX_SECONDS`.
AUTO_SECONDS = 10.0
#: The automatic V*'s margin: :data:`MAX_SECONDS` / :data:`AUTO_SECONDS`, above the largest counted
#: work / counted estimate measured (``tests/test_online_optimal.py`` checks a seeded sweep).
AUTO_MARGIN = MAX_SECONDS / AUTO_SECONDS
#: The estimate's cost of one tensor element of one joint action (add, add, maximum, expectation)
#: and of one state transition (Python bookkeeping and numpy call overhead), seconds: pessimistic
#: (``python -m tools.online_optimal_bench --estimates 40``: measured 0.04 to 0.6 of the estimate).
SECONDS_PER_ELEMENT = 4e-8
SECONDS_PER_TRANSITION = 1e-4
#: Fixed cost of a solve (the prior's atoms, the compiled component, the first tables), seconds.
SECONDS_FIXED = 5e-3
#: The same two costs for the work a solve counts as it goes (:class:`_Work`): fitted to the
#: measured CPU time of real solves (``python -m tools.online_optimal_bench --estimates 40``
#: prints measured / counted: 0.42 to 1.81, median 0.84, on 33 instances), so that the counted
#: limit is the time limit on this machine. The estimate's rates above are pessimistic (measured
#: 0.04 to 0.58 of its seconds).
COUNTED_SECONDS_PER_ELEMENT = 4e-9
COUNTED_SECONDS_PER_TRANSITION = 3e-5
#: The early refusal (:func:`admit`) refuses an instance whose estimate is above this many times
#: the limits without solving it: more than the largest estimate / counted seconds measured (17.3
#: on the same 33 instances; the floor's refusal at this slack is a proof, see :func:`admit`).
ESTIMATE_SLACK = 50.0
#: Largest tensor (elements) a state's solve builds at once; beyond, it is solved one atom of its
#: first open point at a time.
CHUNK = 1 << 21

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


# ----------------------------------------------------------------------------- components

@dataclass(frozen=True, eq=False)
class _Compiled:
    """What the recursion needs of one conflict component, as plain Python structures (carriers
    renumbered ``0..R_c-1``, flat points ``r * N + j``).

    Attributes:
        carriers: int ``[R_c]`` the component's carriers in the problem (ascending).
        n_carriers, n_stages: R_c and N.
        valid: tuple of R_c tuples of N bools (the schedule).
        stages_left: ``stages_left[r][j]`` valid stages of r at stages >= j (``[R_c][N + 1]``).
        neighbours: ``neighbours[p]`` frozenset of flat points conflicting with flat point p.
        future: ``future[p][j]`` bitmask of carriers with a valid point at a stage >= j
            conflicting with p (``[R_c*N][N + 1]``).
        passengers: tuple of D_r.
    """

    carriers: np.ndarray
    n_carriers: int
    n_stages: int
    valid: tuple
    stages_left: tuple
    neighbours: tuple
    future: tuple
    passengers: tuple


def _components(problem: Problem) -> list[np.ndarray]:
    """The carriers that can ever deploy (a passenger and a valid stage), split into conflict
    components: two carriers are in one component when a chain of overlaps links deployable
    points of theirs. Carriers of different components never change each other's rewards, so
    ``V*`` (and any per-carrier policy's value) is the sum over components. O(R·N + overlap
    members)."""
    valid = np.asarray(problem.valid, dtype=bool)
    deployable = valid & (np.asarray(problem.passengers)[:, None] > 0)
    parent = list(range(valid.shape[0]))

    def root(r: int) -> int:
        while parent[r] != r:
            parent[r] = parent[parent[r]]
            r = parent[r]
        return r

    for group in problem.overlaps:
        members = {(int(r), int(j)) for r, j in group if deployable[r, j]}
        if len(members) > 1:
            first = root(next(iter(members))[0])
            for r, _ in members:
                parent[root(r)] = first
    out: dict[int, list[int]] = {}
    for r in np.flatnonzero(deployable.any(axis=1)).tolist():
        out.setdefault(root(r), []).append(r)
    return [np.array(rs) for rs in sorted(out.values())]


def _horizon(problem: Problem) -> np.ndarray:
    """int ``[R, N]``: the last stage of a deployable point conflicting with ``(r, j)`` (another
    point: a point listed twice does not conflict with itself), -1 for none. O(overlap members)."""
    valid = np.asarray(problem.valid, dtype=bool)
    deployable = valid & (np.asarray(problem.passengers)[:, None] > 0)
    out = np.full(valid.shape, -1, dtype=np.int64)
    for group in problem.overlaps:
        points = sorted({(int(r), int(j)) for r, j in group}, key=lambda q: q[1])
        live = [j for r, j in points if deployable[r, j]]
        if not live:
            continue
        top, second = live[-1], (live[-2] if len(live) > 1 else -1)
        for r, j in points:
            other = second if (deployable[r, j] and j == top and live.count(top) == 1) else top
            out[r, j] = max(out[r, j], other)
    return out


def _compile(problem: Problem, carriers: np.ndarray) -> _Compiled:
    n_stages = problem.valid.shape[1]
    valid = problem.valid[carriers]
    n_carriers = len(carriers)
    points = (carriers[:, None] * n_stages + np.arange(n_stages)[None, :]).ravel()
    conflict = problem.conflict[np.ix_(points, points)]
    stages_left = tuple(tuple(int(valid[r, j:].sum()) for j in range(n_stages + 1)) for r in range(n_carriers))
    neighbours = tuple(frozenset(np.flatnonzero(row).tolist()) for row in conflict)
    future = []
    for p in range(n_carriers * n_stages):
        masks = [0] * (n_stages + 1)
        for q in neighbours[p]:
            r, j = divmod(q, n_stages)
            if valid[r, j]:
                for k in range(j + 1):
                    masks[k] |= 1 << r
        future.append(tuple(masks))
    return _Compiled(carriers, n_carriers, n_stages, tuple(tuple(bool(v) for v in row) for row in valid),
                     stages_left, neighbours, tuple(future), tuple(int(d) for d in problem.passengers[carriers]))


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
    """What an exact solve costs, estimated in O(R·N·D²) (never by enumerating states).

    Attributes:
        atoms: K, points per observation.
        states: memoised values a full solve stores (one float each; an upper bound).
        work: tensor elements the solve computes (sum over state structures and joint actions of
            ``K^(open points + deciders)``).
        seconds: estimated wall time of the solve on one core of the development machine
            (``SECONDS_FIXED + work * SECONDS_PER_ELEMENT + transitions *
            SECONDS_PER_TRANSITION``).
        components: conflict components solved separately.
        transitions: state transitions (structure x joint action) the solve makes (an upper bound).
        counted_seconds: ``work`` and ``transitions`` at the counted rates
            (:data:`COUNTED_SECONDS_PER_ELEMENT`, :data:`COUNTED_SECONDS_PER_TRANSITION`): an upper
            bound on the work a full solve counts (:class:`_Work`), so a limit at or above it is never
            reached.
    """

    atoms: int
    states: float
    work: float
    seconds: float
    components: int
    transitions: float = 0.0
    counted_seconds: float = 0.0


def _carrier_stage_sums(d: int, a: int, b: int, k: int, decides: bool, forced_at: int, skips: int):
    """For one carrier before one stage: sums over its possible (deployed so far t, open points
    s among ``a`` openable earlier valid points and ``b`` others) of (structures, states, work,
    transitions). ``decides``: the stage is valid; it is forced with ``left <= forced_at``;
    ``skips``: how many valid stages it can pass without deploying (the forced rule), so
    ``t >= a + b - skips``."""
    structures = states = work = transitions = 0.0
    for t in range(max(0, a + b - skips), min(d, a + b) + 1):
        left = d - t
        deciding = decides and left > 0
        actions = 1 if (not deciding or forced_at <= left) else 2
        for s in range(max(0, t - b), min(t, a) + 1):
            try:
                ways = float(math.comb(a, s))
                size = ways * float(k) ** s
            except OverflowError:
                ways = size = math.inf
            structures += ways
            states += size
            work += size * (k if deciding else 1) * actions
            transitions += ways * actions
    return structures, states, work, transitions


def estimate(problem: Problem, atoms: Atoms | None = None, max_seconds: float = MAX_SECONDS,
             max_states: float = MAX_STATES, slack: float = 1.0, counted: bool = False) -> SizeEstimate:
    """Estimate the exact solve's states, work and time, and refuse it when too large.

    O(R·N·D²) after the conflict components (O(R·N + overlap members)): per component and stage
    the reachable state structures are bounded by the product over its carriers of their
    (passengers left, open earlier points) combinations; a carrier's earlier point is counted
    open only if a deployable point conflicts with it at this stage or later. First, a lower
    bound: a carrier that cannot have released all its passengers before stage j decides there in
    every reachable state, so a component with m such carriers costs at least ``K^m`` there; a
    large fleet is refused by that bound alone.

    ``counted``: judge the floor and the time at the counted rates (``counted_seconds``, what the
    solve's own limit counts) instead of the estimate's pessimistic ones (``seconds``).

    Raises:
        TooLarge: the floor or the estimated time is above ``slack * max_seconds``, or the states
            above ``slack * max_states``.
    """
    if problem.coverage is not None:
        # Its state would hold every revealed count that a later point can still add: the joint
        # expectation over a stage's newly revealed regions is beyond even tiny instances here.
        raise TooLarge("online-optimal: expected a penalty instance (the exact recursion over region counts of "
                       "reward: coverage is not implemented), found reward: coverage")
    if problem.weights is not None:
        raise TooLarge("online-optimal: expected an instance without passenger values (the exact recursion "
                       "has none), found passenger_values")
    atoms = discretise(problem.prior) if atoms is None else atoms
    k = len(atoms.points)
    n_carriers, n_stages = problem.valid.shape
    per_element, per_transition = ((COUNTED_SECONDS_PER_ELEMENT, COUNTED_SECONDS_PER_TRANSITION) if counted
                                   else (SECONDS_PER_ELEMENT, SECONDS_PER_TRANSITION))
    max_work = max_seconds / per_element

    def refuse(what: str) -> TooLarge:
        return TooLarge(
            f"online-optimal: instance too large for the exact solver ({what}; limits {max_seconds:g} s, "
            f"{max_states:.2g} states; R={n_carriers}, N={n_stages}, {k} points per observation)")

    valid = np.asarray(problem.valid, dtype=bool)
    passengers = np.asarray(problem.passengers, dtype=np.int64)
    components = _components(problem)
    before = np.cumsum(valid, axis=1) - valid  # valid stages before j
    holding = valid & (passengers[:, None] > before)  # decides at j in every reachable state
    for carriers in components:
        for j, m in enumerate(holding[carriers].sum(axis=0).tolist()):
            if m * math.log(max(k, 2)) > math.log(slack * max_work):
                raise refuse(f"more than {max_seconds:g} s: {m} carriers decide at stage {j}")
    horizon = _horizon(problem)
    stages_left = valid[:, ::-1].cumsum(axis=1)[:, ::-1]
    states = work = transitions = 0.0
    for carriers in components:
        for j in range(n_stages + 1):
            stage = np.ones(4)
            for r in carriers.tolist():
                earlier = valid[r, :j]
                a = int((earlier & (horizon[r, :j] >= j)).sum())
                decides = j < n_stages and bool(valid[r, j])
                forced_at = int(stages_left[r, j]) if j < n_stages else 0
                stage *= _carrier_stage_sums(int(passengers[r]), a, int(earlier.sum()) - a, k, decides, forced_at,
                                             max(0, int(stages_left[r, 0]) - int(passengers[r])))
            states += stage[1]
            work += stage[2]
            transitions += stage[3]
        seconds = _seconds(work, transitions, per_element, per_transition)
        beyond = f", beyond {slack:g} x the limit" if slack != 1.0 else ""
        if seconds > slack * max_seconds:
            raise refuse(f"about {seconds:.3g} s estimated{beyond}")
        if states > slack * max_states:
            raise refuse(f"about {states:.3g} states estimated{beyond}")
    return SizeEstimate(k, states, work, _seconds(work, transitions), len(components), transitions,
                        _seconds(work, transitions, COUNTED_SECONDS_PER_ELEMENT, COUNTED_SECONDS_PER_TRANSITION))


def admit(problem: Problem, atoms: Atoms | None = None, max_seconds: float = MAX_SECONDS,
          max_states: float = MAX_STATES) -> SizeEstimate:
    """The early refusal of an exact solve, O(R·N·D²): :class:`TooLarge` when the instance is
    beyond the limits for certain or as good as certain: :func:`estimate`'s floor (a lower bound
    on the elements) or its estimate (an upper bound) above :data:`ESTIMATE_SLACK` times the
    limits. At the counted rate the floor is then above ``ESTIMATE_SLACK * COUNTED_SECONDS_PER_ELEMENT
    / SECONDS_PER_ELEMENT`` (5) times ``max_seconds``: a proof; the estimate's slack is more than
    the largest estimate / counted ratio measured. Every other instance is solved, and refused
    only if its counted work passes the limits."""
    return estimate(problem, atoms, max_seconds, max_states, ESTIMATE_SLACK)


def auto_admit(problem: Problem, atoms: Atoms | None = None) -> SizeEstimate:
    """The admission of the automatic V* (``solve``'s ``online_optimum``), O(R·N·D²): :class:`TooLarge`
    unless :func:`estimate` at the counted rates puts the solve within :data:`AUTO_SECONDS`. The
    admitted instance is then solved under the solver's own budget, :data:`MAX_SECONDS`: a solve
    counts at most :data:`AUTO_MARGIN` times its counted estimate, so an admitted solve is not
    abandoned, and an instance the pessimistic rates would refuse but the solver finishes quickly
    gets its V*."""
    return estimate(problem, atoms, AUTO_SECONDS, MAX_STATES, counted=True)


def known_value(problem: Problem, policy: str = "optimal") -> "OnlineValue | None":
    """The exact value of ``policy`` on this ``problem`` object when it is solved already (e.g. by
    the ``online-optimal`` planner's :meth:`OnlineOptimalPlanner.warm_up`): read from the memo,
    no new work; None when it is not."""
    if policy not in _SOLVERS.get(problem, {}):
        return None
    return online_value(problem, policy, max_seconds=math.inf, max_states=math.inf)


# ----------------------------------------------------------------------------- counted work

def _seconds(elements: float, transitions: float, per_element: float = SECONDS_PER_ELEMENT,
             per_transition: float = SECONDS_PER_TRANSITION) -> float:
    """Modelled seconds of a solve that computes ``elements`` tensor elements over ``transitions``
    state transitions (structure x joint action): the estimate's rates by default, the counted
    work's (:data:`COUNTED_SECONDS_PER_ELEMENT`, :data:`COUNTED_SECONDS_PER_TRANSITION`) for
    :class:`_Work`."""
    return SECONDS_FIXED + elements * per_element + transitions * per_transition


class _Work:
    """The work of one problem's solvers, counted as they compute (one shared counter for its
    conflict components): tensor elements and transitions charged before each memo entry is
    computed, memoised values after. A function of the instance and the calls made, never of the
    clock, so a refusal is the same on every machine and at every load.

    ``allow(seconds, states)`` opens a call's allowance: at most ``seconds`` more modelled seconds
    of work (:attr:`seconds`) and at most ``states`` memoised values in all; :meth:`charge`
    and :meth:`store` raise :class:`TooLarge` beyond them.
    """

    def __init__(self, what: str):
        self.what = what  # the instance, for the refusal's line
        self.elements = 0
        self.transitions = 0
        self.states = 0
        self._limit = math.inf
        self._budget = math.inf
        self._max_states = math.inf

    @property
    def seconds(self) -> float:
        """Modelled CPU seconds of the work so far: the counted rates, fitted to the measured time."""
        return _seconds(self.elements, self.transitions, COUNTED_SECONDS_PER_ELEMENT, COUNTED_SECONDS_PER_TRANSITION)

    def allow(self, seconds: float, states: float) -> None:
        self._budget = seconds
        # The first call's allowance includes the fixed cost (counted from zero work).
        self._limit = (self.seconds if self.elements or self.transitions else 0.0) + seconds
        self._max_states = states

    def charge(self, elements: int, transitions: int) -> None:
        self.elements += elements
        self.transitions += transitions
        if self.seconds > self._limit:
            raise TooLarge(f"online-optimal: instance too large for the exact solver (stopped after "
                           f"{self._budget:g} s of counted work, the limit; {self.what})")

    def store(self, size: int) -> None:
        self.states += size
        if self.states > self._max_states:
            raise TooLarge(f"online-optimal: instance too large for the exact solver (stopped at "
                           f"{self._max_states:.2g} memoised values, the limit; {self.what})")


def _transition(comp: _Compiled, j: int, left: tuple, opened, deploying: list[int]):
    """Apply the deployments of carriers ``deploying`` at stage j.

    ``opened`` holds ``(p, c, *rest)`` tuples. Returns ``(left', still open, closing)``: still-open
    and closing entries as ``(p, c, *rest)`` with updated counts; new points come with ``rest`` =
    ``("new", carrier)``.
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
    """Memoised expectimax (``policy="optimal"``) or policy evaluation (``"ssap"``, ``"random"``)
    over one conflict component, vectorised over observations.

    A memo entry is keyed by a state *structure* ``(j, passengers left, open points)``, an open
    point being ``(p, count, given)``; its value is a tensor with one axis per open point (in the
    order of p) over that point's possible x: the prior's atoms (``given`` None) or one observed
    value (``given`` = x, what a planner's decision sees). Values are raw (sum of x / p); callers
    divide by ``problem.scale``.
    """

    def __init__(self, problem: Problem, comp: _Compiled, policy: str, atoms: Atoms, work: "_Work"):
        self.policy = policy
        self.atoms = atoms
        self.comp = comp
        self.work = work
        self.table = ssap.table_for(problem) if policy == "ssap" else None
        self.memo: dict = {}
        self._atom_index = {float(x): i for i, x in enumerate(atoms.points)}
        self._ssap_deploy: dict[tuple, np.ndarray] = {}

    def grid(self, given) -> np.ndarray:
        """The x values of an axis: the atoms, or the one given value."""
        return self.atoms.points if given is None else np.array([float(given)])

    def value(self, j: int, left: tuple, opened: tuple) -> np.ndarray:
        """Expected raw reward still to come (open points' final rewards included) from the state
        structure before stage ``j``, as a tensor over the open points' x (see the class)."""
        key = (j, left, opened)
        cached = self.memo.get(key)
        if cached is not None:
            return cached
        # A given x that is an atom reads the atoms' tensor at that atom.
        pick = [self._atom_index.get(g) if g is not None else None for _, _, g in opened]
        if any(i is not None for i in pick):
            full = self.value(j, left, tuple((p, c, None if i is not None else g)
                                             for (p, c, g), i in zip(opened, pick)))
            return full[tuple(slice(None) if i is None else slice(i, i + 1) for i in pick)]
        shape = tuple(len(self.grid(g)) for *_, g in opened)
        if opened and math.prod(shape) * len(self.atoms.points) > CHUNK:
            # One slice of the first open point's atoms at a time: transient tensors stay small.
            p, c, _ = opened[0]
            result = np.concatenate([self._compute(j, left, ((p, c, float(x)),) + opened[1:])
                                     for x in self.atoms.points], axis=0)
        else:
            result = self._compute(j, left, opened)
        self.work.store(result.size)
        self.memo[key] = result
        return result

    def _compute(self, j: int, left: tuple, opened: tuple) -> np.ndarray:
        """:meth:`value` without the memo."""
        comp = self.comp
        if j == comp.n_stages:
            self.work.charge(math.prod(len(self.grid(g)) for *_, g in opened), 1)
            result = np.zeros((1,) * len(opened))
            for axis, (_, c, g) in enumerate(opened):
                result = result + _along(self.grid(g) / (1 + c), axis, len(opened))
        else:
            can = [r for r in range(comp.n_carriers) if comp.valid[r][j] and left[r] > 0]
            must = [comp.stages_left[r][j] <= left[r] for r in can]
            shape = tuple(len(self.grid(g)) for *_, g in opened) + (len(self.atoms.points),) * len(can)
            actions = 1 << sum(not f for f in must)
            self.work.charge(math.prod(shape) * actions, actions)
            best = None
            for action, v in self.action_values(j, left, opened, can, must, [None] * len(can)):
                if self.policy != "optimal":
                    v = self._weights(j, left, can, must, action, len(opened)) * v
                if best is None:
                    # ``v`` is a fresh array (action_values adds): written in place below.
                    best = v if v.shape == shape else np.array(np.broadcast_to(v, shape))
                elif self.policy == "optimal":
                    np.maximum(best, v, out=best)
                else:
                    best += v
            for _ in can:  # the expectation over the deciders' observations (the last axes)
                best = best @ self.atoms.probs
            result = best
        return result

    def _weights(self, j: int, left: tuple, can: list[int], must: list[bool], action: tuple[int, ...], n_open: int):
        """Probability of ``action`` under the policy, as a tensor over the deciders' atoms (axes
        after the ``n_open`` open points' axes)."""
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
        return weight.reshape((1,) * n_open + (len(self.atoms.points),) * m)

    def action_values(self, j: int, left: tuple, opened: tuple, can: list[int], must: list[bool],
                      given: list) -> list[tuple[tuple[int, ...], np.ndarray]]:
        """For every feasible joint action (local indices into ``can``), the banked reward plus the
        continuation value, as a tensor over the open points' x (first axes) and the deciders' x
        (``given[i]`` None: the atoms; else that value), broadcastable to the full shape."""
        n_open, m = len(opened), len(can)
        dims = n_open + m
        grids = [self.grid(g) for *_, g in opened] + [self.grid(g) for g in given]
        givens = [g for *_, g in opened] + list(given)
        local = {r: i for i, r in enumerate(can)}
        out = []
        for action in _actions(m, must):
            deploying = [can[i] for i in action]
            entries = [(p, c, axis) for axis, (p, c, _) in enumerate(opened)]
            left2, still, closing = _transition(self.comp, j, left, entries, deploying)
            total = np.zeros((1,) * dims)
            for e in closing:
                axis = n_open + local[e[3]] if e[2] == "new" else e[2]
                total = total + _along(grids[axis] / (1 + e[1]), axis, dims)
            kept = sorted((e[0], e[1], n_open + local[e[3]] if e[2] == "new" else e[2]) for e in still)
            cont = self.value(j + 1, left2, tuple((p, c, givens[axis]) for p, c, axis in kept))
            axes = [axis for *_, axis in kept]
            # Each continuation axis onto its source axis (open point or decider), in axis order.
            cont = np.transpose(cont, np.argsort(axes)) if axes else cont
            shape = [1] * dims
            for axis, size in zip(sorted(axes), cont.shape):
                shape[axis] = size
            out.append((action, total + cont.reshape(shape)))
        return out


def _along(values: np.ndarray, axis: int, dims: int) -> np.ndarray:
    """``values`` [n] as a tensor of ``dims`` axes varying along ``axis``."""
    shape = [1] * dims
    shape[axis] = len(values)
    return values.reshape(shape)


# ----------------------------------------------------------------------------- public API

@dataclass(frozen=True)
class OnlineValue:
    """Exact expected reward of a policy on a problem.

    Attributes:
        expected_reward: normalised (raw / problem.scale), the units of ``evaluate``.
        exact: True for a discrete prior (tail below :data:`TAIL_MASS` cut); False when the prior
            is continuous and the value is that of its :data:`CONTINUOUS_ATOMS`-point stand-in.
        atoms: K, points per observation.
        states: memoised values the solve stored (tensor elements over every component).
        counted_seconds: the work its solvers counted so far (:class:`_Work`), in modelled CPU
            seconds of the development machine.
    """

    expected_reward: float
    exact: bool
    atoms: int
    states: int
    counted_seconds: float = 0.0


#: Solvers per problem (identity) and policy: one per conflict component, and their shared
#: :class:`_Work`; entries go with their problem.
_SOLVERS: "weakref.WeakKeyDictionary[Problem, dict]" = weakref.WeakKeyDictionary()


def _solvers(problem: Problem, policy: str) -> tuple[list[_Solver], _Work]:
    """The solvers of ``(problem, policy)`` and their shared work counter, built on first use."""
    per_problem = _SOLVERS.setdefault(problem, {})
    entry = per_problem.get(policy)
    if entry is None:
        atoms = discretise(problem.prior)
        n_carriers, n_stages = problem.valid.shape
        work = _Work(f"R={n_carriers}, N={n_stages}, {len(atoms.points)} points per observation")
        entry = ([_Solver(problem, _compile(problem, carriers), policy, atoms, work)
                  for carriers in _components(problem)], work)
        per_problem[policy] = entry
    return entry


def _solving(problem: Problem, policy: str, max_seconds: float, max_states: float, fn):
    """``fn(solvers)`` under a fresh allowance of ``max_seconds`` counted seconds and at most
    ``max_states`` memoised values; a refusal drops the partial memo (the next call starts over
    and is refused the same way)."""
    if policy not in POLICIES:
        raise ValueError(f"policy must be one of {', '.join(POLICIES)}, got {policy!r}")
    if policy not in _SOLVERS.get(problem, {}):
        admit(problem, None, max_seconds, max_states)  # raises TooLarge far beyond the limits
    solvers, work = _solvers(problem, policy)
    work.allow(max_seconds, max_states)
    try:
        return fn(solvers)
    except TooLarge:
        _SOLVERS[problem].pop(policy, None)
        raise
    finally:
        work.allow(math.inf, math.inf)


def online_value(problem: Problem, policy: str = "optimal", max_seconds: float = MAX_SECONDS,
                 max_states: float = MAX_STATES) -> OnlineValue:
    """Exact expected reward of ``policy`` ("optimal" = ``V*``, "ssap" or "random") on ``problem``
    under its schedule (no online surprises): the sum over conflict components.

    Raises:
        TooLarge: beyond the limits: at once by :func:`admit`, or when the counted work passes
            ``max_seconds`` or the memo ``max_states`` values (see :class:`_Work`).
    """
    def solve(solvers):
        return math.fsum(float(s.value(0, s.comp.passengers, ())) for s in solvers)

    raw = _solving(problem, policy, max_seconds, max_states, solve)
    solvers, work = _solvers(problem, policy)
    atoms = discretise(problem.prior) if not solvers else solvers[0].atoms
    return OnlineValue(raw / problem.scale, atoms.exact, len(atoms.points), work.states, work.seconds)


class OnlineOptimalPlanner:
    """The Bayes-optimal online policy (``online-optimal``) for instances within the limits.

    At stage j it rebuilds the state from the view (passengers left, open past deployments with
    their x and conflict counts), scores every feasible joint action by its banked reward plus the
    exact continuation value, and takes the best, conflict component by component (ties within
    1e-12 relative: the first in bitmask order of the component's carriers, which for exact ties
    is the first in bitmask order of the whole fleet). Deterministic; the random stream is unused.
    Online surprises are handled: the current stage's realised validity decides who can deploy,
    later stages follow the schedule. Under the coverage reward the recursion is
    :mod:`planner.coverage_optimal`'s, over the revealed region counts (tiny instances only).

    Raises (from ``warm_up`` or ``decide``):
        TooLarge: the instance is beyond the limits.
    """

    name = "online-optimal"

    def __init__(self, max_seconds: float = MAX_SECONDS, max_states: float = MAX_STATES):
        self.max_seconds = max_seconds
        self.max_states = max_states

    def warm_up(self, problem: Problem) -> None:
        """Check the size and solve the whole recursion before the first timed decision."""
        if problem.coverage is not None:
            from planner import coverage_optimal

            _coverage(coverage_optimal.warm_up, problem)
            return
        online_value(problem, "optimal", self.max_seconds, self.max_states)

    def decide(self, view: StageView, rng: np.random.Generator) -> np.ndarray:
        problem = view.problem
        if problem.coverage is not None:  # the recursion over revealed region counts
            from planner import coverage_optimal

            return _coverage(coverage_optimal.decide, problem, view)

        def decide(solvers):
            return [r for solver in solvers for r in _component_decision(solver, view)]

        out = np.zeros(problem.n_carriers, dtype=bool)
        out[np.array(_solving(problem, "optimal", self.max_seconds, self.max_states, decide), dtype=np.int64)] = True
        return out


def _coverage(fn, *args):
    """``fn(*args)`` of :mod:`planner.coverage_optimal`, its refusal as this module's TooLarge."""
    from planner import coverage_optimal

    try:
        return fn(*args)
    except coverage_optimal.TooLarge as err:
        raise TooLarge(f"online-optimal: {err}") from None


def _component_decision(solver: _Solver, view: StageView) -> list[int]:
    """The carriers (problem indices) of one component that deploy at the view's stage."""
    comp = solver.comp
    carriers = comp.carriers
    n_stages = comp.n_stages
    j = view.stage
    left = tuple(int(d) for d in view.passengers_left[carriers])
    alive = _alive(left)
    deployed = np.flatnonzero(view.deployed[carriers].ravel())
    chosen = set(deployed.tolist())
    x = view.observations[carriers]
    opened = tuple(sorted(
        (int(p), len(comp.neighbours[p] & chosen), float(x[p // n_stages, p % n_stages]))
        for p in deployed if comp.future[p][j] & alive))
    can = np.flatnonzero(view.can_deploy[carriers]).tolist()
    must = [bool(view.must_deploy[carriers[r]]) for r in can]
    values = solver.action_values(j, left, opened, can, must, [float(x[r, j]) for r in can])
    best_action, best = None, -np.inf
    for action, v in values:
        score = float(v.reshape(-1)[0])
        if score > best + 1e-12 * max(1.0, abs(best)) or best_action is None:
            best_action, best = action, score
    return [int(carriers[can[i]]) for i in best_action]
