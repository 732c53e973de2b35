"""V* under the coverage reward (issue 35): the exact online optimum of a tiny coverage instance.

The fleet decides stage by stage knowing every count its observations revealed (an observation at
a point reveals the counts of the regions its disc covers, :func:`planner.coverage.revealed`);
V* is the best expected coverage any such policy earns, over counts drawn from the region priors,
with the forced-deployment rule (a carrier deploys when its valid stages left equal its
passengers left). Scheduled validity only (no surprise ∅); no passenger values.

The recursion (memoised over stages):

* **Groups.** Regions first revealed at stage j and explored by the same points at stages >= j are
  always revealed and covered together, so only their summed count matters: one *group* (its
  distribution the convolution of its regions' priors; Poisson regions add their means).
* **State** entering stage j: the passengers left and, for each revealed group not covered yet
  that a later point explores, its count, keyed by those later points (groups with the same key
  merge). A covered group is worth nothing more; a group no later point explores is dropped.
* **Stage j**: the expectation over the new groups' counts of the best action (every subset of the
  carriers that may deploy, containing those that must): the counts of the groups it covers plus
  the value of the next state.

**Truncation.** Each new group's count is capped at the smallest K with P(S > K) <= ``tail``, the
tail's mass put on K. Capping lowers every policy's value and adds no information that matters
(the excess is independent of everything else), so the capped optimum V_K satisfies
``V_K <= V* <= V_K + sum over groups E[(S - K)^+]``; :attr:`CoverageOptimum.truncation_error` is
that sum (normalised), exact for the instance.

Limits: :data:`MAX_OUTCOMES` joint outcomes of one stage's new groups times its actions (checked
before anything is solved, from the sizes) and :data:`MAX_NODES` evaluated (state, outcome) pairs
(checked as it goes): :class:`TooLarge` with a one-line message beyond either.
"""
from __future__ import annotations

import itertools
import math
import weakref
from dataclasses import dataclass

import numpy as np

from planner import priors as priors_mod
from planner.problem import Problem, valid_stages_left

#: Default tail mass cut from each group's count distribution.
TAIL = 1e-4
#: Largest (joint outcomes of one stage's new groups) x (its actions).
MAX_OUTCOMES = 200_000
#: Largest number of (state, outcome) evaluations of one solve.
MAX_NODES = 2_000_000
#: What ``solve`` computes unasked: a coarser tail and a node limit of a few seconds here
#: (examples/coverage_tiny.json: 87,624 nodes, 2 s, truncation error 0.0067).
AUTO_TAIL = 1e-2
AUTO_NODES = 150_000


class TooLarge(ValueError):
    """The instance is beyond V*'s limits. ``str(err)`` is one line."""


@dataclass(frozen=True)
class CoverageOptimum:
    """V* of a coverage instance.

    Attributes:
        expected_reward: V_K / scale, the optimum over the truncated counts (a lower bound on V*).
        truncation_error: normalised bound on V* - V_K (module docstring); 0 when no group was cut.
        nodes: (state, outcome) evaluations.
    """

    expected_reward: float
    truncation_error: float
    nodes: int


def _distribution(coverage, regions: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """(values, probabilities) of the summed count of ``regions`` (priors' supports cut at
    :data:`planner.priors.TAIL`; Poisson regions as one Poisson)."""
    poisson = [m for m in regions if getattr(coverage.priors[m].dist, "name", "") == "poisson"]
    parts = [priors_mod.support(priors_mod.Poisson(float(coverage.means[poisson].sum())))] if poisson else []
    parts += [priors_mod.support(coverage.priors[m]) for m in regions if m not in poisson]
    values, probs = np.zeros(1), np.ones(1)
    for v, p in parts:
        sums = (values[:, None] + v[None, :]).ravel()
        mass = (probs[:, None] * p[None, :]).ravel()
        values, inverse = np.unique(sums, return_inverse=True)
        probs = np.bincount(inverse, weights=mass)
    return values, probs


def _truncate(values: np.ndarray, probs: np.ndarray, tail: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Cap at the smallest value K with P(S > K) <= tail (its tail's mass on K); returns the capped
    (values, probabilities) and E[(S - K)^+] (over the support given)."""
    above = 1.0 - np.cumsum(probs)
    cut = int(np.argmax(above <= tail)) if (above <= tail).any() else len(values) - 1
    error = float(np.dot(np.maximum(values - values[cut], 0.0), probs))
    capped = probs[: cut + 1].copy()
    capped[-1] += float(probs[cut + 1:].sum())
    keep = capped > 0
    return values[: cut + 1][keep], capped[keep], error


@dataclass(frozen=True)
class _Stage:
    points: tuple[int, ...]                 # carriers valid at this stage
    groups: tuple[frozenset, ...]           # each new group's key: later points (stages > j) exploring it
    covers: tuple[frozenset, ...]           # each new group's points at this stage (carriers)
    outcomes: tuple[tuple, ...]             # per new group: (values, probabilities)


def _explorers(problem: Problem) -> dict[int, set[int]]:
    """region -> the valid flat points exploring it."""
    explorers: dict[int, set[int]] = {}
    for a in np.flatnonzero(problem.valid.reshape(-1)):
        for m in problem.coverage.regions(int(a)).tolist():
            explorers.setdefault(m, set()).add(int(a))
    return explorers


def _stages(problem: Problem, tail: float, explorers: dict[int, set[int]]) -> tuple[list[_Stage], float]:
    coverage = problem.coverage
    n_stages = problem.n_stages
    revealed: set[int] = set()
    stages, error = [], 0.0
    for j in range(n_stages):
        carriers = tuple(int(r) for r in np.flatnonzero(problem.valid[:, j]))
        new: dict[frozenset, list[int]] = {}
        for r in carriers:
            for m in coverage.regions(r * n_stages + j).tolist():
                if m not in revealed:
                    revealed.add(m)
                    key = frozenset(a for a in explorers[m] if a % n_stages >= j)
                    new.setdefault(key, []).append(m)
        # Every group has two values at least: refuse before any distribution is built.
        _check_size(j, 2 ** len(new) * 2 ** len(carriers))
        keys, covers, outcomes = [], [], []
        for key, regions in sorted(new.items(), key=lambda kv: sorted(kv[0])):
            values, probs, cut = _truncate(*_distribution(coverage, regions), tail)
            error += cut
            keys.append(frozenset(a for a in key if a % n_stages > j))
            covers.append(frozenset(a // n_stages for a in key if a % n_stages == j))
            outcomes.append((values, probs))
        _check_size(j, math.prod(len(v) for v, _ in outcomes) * 2 ** len(carriers))
        stages.append(_Stage(carriers, tuple(keys), tuple(covers), tuple(outcomes)))
    return stages, error


def _check_size(stage: int, pairs: int) -> None:
    if pairs > MAX_OUTCOMES:
        raise TooLarge(f"coverage V*: stage {stage} has {pairs:.3g} (outcome, action) pairs or more, "
                       f"beyond {MAX_OUTCOMES:,}")


class _Recursion:
    """The memoised recursion of one problem (module docstring): V* from any stage and state, and
    the value of each action at a stage (what the ``online-optimal`` planner takes the best of)."""

    def __init__(self, problem: Problem, tail: float):
        if problem.coverage is None:
            raise ValueError("coverage V*: expected a coverage problem (reward: coverage)")
        if problem.weights is not None:
            raise TooLarge("coverage V*: passenger values are not modelled (the recursion treats passengers as alike)")
        self.problem, self.tail = problem, tail
        self.explorers = _explorers(problem)
        self.stages, self.error = _stages(problem, tail, self.explorers)
        self.left_table = valid_stages_left(problem.valid)
        self.memo: dict = {}
        self.splits: dict = {}
        self.nodes = 0
        self.max_nodes = MAX_NODES

    def value(self, j: int, left: tuple, state: frozenset) -> float:
        """Expected best coverage from stage j; ``state``: {(later points, carriers at j, count)},
        one entry per distinct later-points key (a set: canonical without sorting)."""
        if j == self.problem.n_stages:
            return 0.0
        key = (j, left, state)
        found = self.memo.get(key)
        if found is not None:
            return found
        st = self.stages[j]
        can = [r for r in st.points if left[r] > 0]
        must = [r for r in can if self.left_table[r, j] <= left[r]]
        total = 0.0
        for combo in itertools.product(*[range(len(v)) for v, _ in st.outcomes]):
            self.nodes += 1
            if self.nodes > self.max_nodes:
                raise TooLarge(f"coverage V*: more than {self.max_nodes:,} (state, outcome) evaluations")
            p = math.prod(float(st.outcomes[g][1][i]) for g, i in enumerate(combo))
            groups = list(state) + [(k, st.covers[g], float(st.outcomes[g][0][i])) for g, (k, i) in
                                    enumerate(zip(st.groups, combo))]
            total += p * max(v for _, v in self.action_values(j, left, groups, can, must))
        self.memo[key] = total
        return total

    def action_values(self, j: int, left: tuple, groups: list, can: list, must: list) -> list:
        """``[(action, value)]`` at stage j for every subset of ``can`` holding ``must`` (in
        subset-size order, then ``itertools.combinations``' order): the counts of the groups the
        action covers plus V* of the next state. ``groups``: (later points, carriers at j, count)."""
        free = [r for r in can if r not in must]
        out = []
        for k in range(len(free) + 1):
            for c in itertools.combinations(free, k):
                action = frozenset(must) | frozenset(c)
                gain, nxt = 0.0, {}
                for later, now, count in groups:
                    if now & action:
                        gain += count
                    elif later:
                        nxt[later] = nxt.get(later, 0.0) + count
                left2 = tuple(d - (r in action) for r, d in enumerate(left))
                state2 = frozenset((*self._split(later, j + 1), count) for later, count in nxt.items())
                out.append((action, gain + self.value(j + 1, left2, state2)))
        return out

    def _split(self, later: frozenset, j: int) -> tuple[frozenset, frozenset]:
        """A group's later points as (points after stage j, carriers at stage j); cached."""
        found = self.splits.get((later, j))
        if found is None:
            n_stages = self.problem.n_stages
            found = self.splits[(later, j)] = (frozenset(a for a in later if a % n_stages > j),
                                               frozenset(a // n_stages for a in later if a % n_stages == j))
        return found

    def groups_of(self, view) -> list:
        """The revealed counts of ``view`` (a :class:`planner.problem.StageView`) that can still add
        coverage, as the recursion's groups entering its stage: each revealed region no past
        deployment covers and some valid point at the stage or later explores, keyed by those
        points (split into later points and carriers at the stage; equal keys merged)."""
        problem, j = self.problem, view.stage
        coverage, n_stages = problem.coverage, problem.n_stages
        covered = np.zeros(coverage.n_regions, dtype=bool)
        for a in np.flatnonzero(view.deployed.reshape(-1)):
            covered[coverage.regions(int(a))] = True
        merged: dict = {}
        for m in np.flatnonzero(~np.isnan(view.counts) & ~covered).tolist():
            key = frozenset(a for a in self.explorers.get(m, ()) if a % n_stages >= j)
            if key:
                merged[key] = merged.get(key, 0.0) + float(view.counts[m])
        return [(*self._split(key, j), count) for key, count in merged.items()]


def online_value(problem: Problem, tail: float = TAIL, max_nodes: int = MAX_NODES) -> CoverageOptimum:
    """V* of a coverage ``problem`` (module docstring). Raises :class:`TooLarge` (one line)."""
    solver = _Recursion(problem, tail)
    solver.max_nodes = max_nodes
    start = tuple(int(d) for d in problem.passengers)
    raw = solver.value(0, start, frozenset())
    return CoverageOptimum(raw / problem.scale, solver.error / problem.scale, solver.nodes)


def decide(problem: Problem, view, tail: float = AUTO_TAIL, max_nodes: int = MAX_NODES) -> np.ndarray:
    """The ``online-optimal`` decision of a coverage stage view: the feasible joint action of the
    best value (banked coverage now plus V* of the next state); the first in the recursion's action
    order on ties within 1e-12 relative. The recursion is memoised per problem, so a mission's
    stages share one solve. Scheduled validity after the stage (surprises at the stage itself
    decide who may deploy). The continuation values use the coarser :data:`AUTO_TAIL` by default: a
    decision compares actions on the same truncated futures. Raises :class:`TooLarge`."""
    solver = recursion(problem, tail, max_nodes)
    can = np.flatnonzero(view.can_deploy).tolist()
    must = np.flatnonzero(view.must_deploy).tolist()
    left = tuple(int(d) for d in view.passengers_left)
    best_action, best = None, 0.0
    for action, v in solver.action_values(view.stage, left, solver.groups_of(view), can, must):
        if best_action is None or v > best + 1e-12 * max(1.0, abs(best)):
            best_action, best = action, v
    out = np.zeros(problem.n_carriers, dtype=bool)
    out[sorted(best_action)] = True
    return out


def recursion(problem: Problem, tail: float = TAIL, max_nodes: int = MAX_NODES) -> _Recursion:
    """The problem's memoised recursion, built on first use (its memo serves every stage of the
    problem's missions); a refusal drops it, so the next call is refused the same way."""
    solver = _SOLVERS.get(problem)
    if solver is None or (solver.max_nodes, solver.tail) != (max_nodes, tail):
        solver = _Recursion(problem, tail)
        solver.max_nodes = max_nodes
        _SOLVERS[problem] = solver
    return solver


#: One recursion per coverage problem and its limits.
_SOLVERS: "weakref.WeakKeyDictionary[Problem, _Recursion]" = weakref.WeakKeyDictionary()


def warm_up(problem: Problem) -> None:
    """Solve the whole recursion (V* from the start) before a mission's first timed decision.
    Raises :class:`TooLarge` (and drops the partial memo)."""
    solver = recursion(problem, AUTO_TAIL)
    try:
        solver.value(0, tuple(int(d) for d in problem.passengers), frozenset())
    except TooLarge:
        _SOLVERS.pop(problem, None)
        raise
