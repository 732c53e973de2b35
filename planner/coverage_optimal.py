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
    from scipy import stats

    poisson = [m for m in regions if getattr(coverage.priors[m].dist, "name", "") == "poisson"]
    parts = [priors_mod.support(stats.poisson(float(coverage.means[poisson].sum())))] if poisson else []
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


def _stages(problem: Problem, tail: float) -> tuple[list[_Stage], float]:
    coverage = problem.coverage
    n_stages = problem.n_stages
    explorers: dict[int, set[int]] = {}  # region -> valid flat points exploring it
    for a in np.flatnonzero(problem.valid.reshape(-1)):
        for m in coverage.regions(int(a)).tolist():
            explorers.setdefault(m, set()).add(int(a))
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


def online_value(problem: Problem, tail: float = TAIL, max_nodes: int = MAX_NODES) -> CoverageOptimum:
    """V* of a coverage ``problem`` (module docstring). Raises :class:`TooLarge` (one line)."""
    if problem.coverage is None:
        raise ValueError("coverage V*: expected a coverage problem (reward: coverage)")
    if problem.weights is not None:
        raise TooLarge("coverage V*: passenger values are not modelled (the recursion treats passengers as alike)")
    stages, error = _stages(problem, tail)
    n_stages = problem.n_stages
    left_table = valid_stages_left(problem.valid)
    memo: dict = {}
    nodes = [0]

    def value(j: int, left: tuple, state: frozenset) -> float:
        """Expected best coverage from stage j; ``state``: {(later points, carriers at j, count)},
        one entry per distinct later-points key (a set: canonical without sorting)."""
        if j == n_stages:
            return 0.0
        key = (j, left, state)
        found = memo.get(key)
        if found is not None:
            return found
        st = stages[j]
        can = [r for r in st.points if left[r] > 0]
        must = [r for r in can if left_table[r, j] <= left[r]]
        free = [r for r in can if r not in must]
        actions = [frozenset(must) | frozenset(c) for k in range(len(free) + 1)
                   for c in itertools.combinations(free, k)]
        total = 0.0
        for combo in itertools.product(*[range(len(v)) for v, _ in st.outcomes]):
            nodes[0] += 1
            if nodes[0] > max_nodes:
                raise TooLarge(f"coverage V*: more than {max_nodes:,} (state, outcome) evaluations")
            p = math.prod(float(st.outcomes[g][1][i]) for g, i in enumerate(combo))
            groups = list(state) + [(k, st.covers[g], float(st.outcomes[g][0][i])) for g, (k, i) in
                                    enumerate(zip(st.groups, combo))]
            best = -np.inf
            for action in actions:
                gain, nxt = 0.0, {}
                for later, now, count in groups:
                    if now & action:
                        gain += count
                    elif later:
                        nxt[later] = nxt.get(later, 0.0) + count
                left2 = tuple(d - (r in action) for r, d in enumerate(left))
                state2 = frozenset((*split(later, j + 1), count) for later, count in nxt.items())
                best = max(best, gain + value(j + 1, left2, state2))
            total += p * best
        memo[key] = total
        return total

    splits: dict = {}

    def split(later: frozenset, j: int) -> tuple[frozenset, frozenset]:
        """A group's later points as (points after stage j, carriers at stage j); cached."""
        found = splits.get((later, j))
        if found is None:
            found = splits[(later, j)] = (frozenset(a for a in later if a % n_stages > j),
                                          frozenset(a // n_stages for a in later if a % n_stages == j))
        return found

    start = tuple(int(d) for d in problem.passengers)
    raw = value(0, start, frozenset())
    return CoverageOptimum(raw / problem.scale, error / problem.scale, nodes[0])
