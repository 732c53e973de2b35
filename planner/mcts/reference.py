"""MCTS-SSAP and MCTS-Random, the paper's algorithm written plainly (the quality baseline).

This is the unoptimised algorithm: a tree of Python objects whose edges are *joint* actions
(subsets of carriers deploying at one stage). It exists to be read and to be compared with the
fast planner in :mod:`planner.mcts.fast`, which must match its decision quality.

One decision at stage ``j`` (the root):

1. **Selection.** From the root, while every feasible joint action of the node has a child,
   descend to the child maximising UCT ``Q + c * sqrt(ln N_parent / N_child)`` where ``Q`` is
   the mean normalised total reward of the child's iterations and ``c`` the exploration constant
   (0.05·√2 by default).
2. **Expansion.** At the first node with an untried joint action, pick one untried action
   uniformly at random and add its child (one new node per iteration).
3. **Simulation.** Sample the future observations (stages > j) from the prior, then roll out
   from the stage after the last tree action to the end: per carrier and stage, in carrier
   order, the SSAP rule on the observation discounted for conflicts with deployments already in
   the trajectory (``x / (1 + c)`` with ``c`` the number of chosen deployments sharing an overlap,
   against the carrier's threshold ``table[n, n - d]``), or a uniformly random feasible rollout
   (deploy with probability ``d / n``: a uniform ``d``-subset of the remaining valid stages).
4. **Evaluation.** The full trajectory (real past deployments + tree actions + rollout) is scored
   by :func:`planner.problem.evaluate` (the exact penalty rule), normalised by the prior's
   scale. With ``samples > 1`` steps 3-4 repeat with fresh observations and the mean is used.
5. **Backup.** Every node on the path gets one more visit and the reward.

Open-loop: nodes branch on actions only; the same node collects iterations with different
sampled observations. Feasibility holds at every depth: a joint action never includes a carrier
that is at an ∅ stage or has no passenger left, and always includes a carrier whose remaining
valid stages equal its passengers left.

The executed action is the **most visited** root child (ties: higher mean, then expansion
order). The most visited child is the robust choice of MCTS: with the small exploration
constant the mean of a rarely visited child is noisy, while visits only accumulate on children
that kept a high mean. When a stage leaves no choice (a single feasible joint action) the planner
returns it without searching.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from planner import ssap
from planner.compiled import compile_problem
from planner.problem import StageView, evaluate
from planner.settings import DEFAULT_EXPLORATION, DEFAULT_ITERATIONS, DEFAULT_SAMPLES
#: Rollout policies.
ROLLOUTS = ("ssap", "random")


def feasible_joint_actions(can: np.ndarray, must: np.ndarray) -> list[int]:
    """All feasible joint actions of one stage as bitmasks (bit ``r`` set = carrier ``r`` deploys).

    Args:
        can: bool ``[R]``, carriers allowed to deploy.
        must: bool ``[R]``, carriers forced to deploy (a subset of ``can``).

    Returns:
        ``2 ** (number of optional carriers)`` bitmasks, each containing every forced carrier.
    """
    forced = sum(1 << int(r) for r in np.flatnonzero(must))
    optional = [int(r) for r in np.flatnonzero(can & ~must)]
    actions = []
    for subset in range(1 << len(optional)):
        mask = forced
        for bit, r in enumerate(optional):
            if subset >> bit & 1:
                mask |= 1 << r
        actions.append(mask)
    return actions


@dataclass(eq=False)
class _Node:
    """A tree node: the decision of ``stage`` after the path's actions.

    Invariant: ``children`` and ``untried`` partition the node's feasible joint actions.
    """

    stage: int
    passengers_left: np.ndarray  # int64 [R], before this stage's decision
    untried: list[int]
    children: dict[int, "_Node"] = field(default_factory=dict)
    visits: int = 0
    value: float = 0.0  # sum of normalised rewards of the iterations through this node


class _Search:
    """State of one decision: the view, derived arrays and the tree."""

    def __init__(self, view: StageView, rollout: str, exploration: float, samples: int,
                 rng: np.random.Generator):
        problem = view.problem
        self.problem = problem
        self.rollout = rollout
        self.exploration = exploration
        self.samples = samples
        self.rng = rng
        self.stage = view.stage
        self.n_carriers, self.n_stages = problem.valid.shape
        self.valid = view.valid
        self.compiled = compile_problem(problem)
        # valid stages from k (inclusive) to the end, per carrier: int64 [R, N + 1]
        self.stages_left = view.stages_left_table
        self.table = self.compiled.table
        self.known = view.observations  # NaN after the current stage
        self.past = view.deployed
        self.root = self._make_node(self.stage, view.passengers_left.copy())

    def _can_must(self, stage: int, passengers_left: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        can = self.valid[:, stage] & (passengers_left > 0)
        must = can & (self.stages_left[:, stage] <= passengers_left)
        return can, must

    def _make_node(self, stage: int, passengers_left: np.ndarray) -> _Node:
        if stage >= self.n_stages:
            return _Node(stage, passengers_left, [])
        return _Node(stage, passengers_left, feasible_joint_actions(*self._can_must(stage, passengers_left)))

    def _apply(self, deployed: np.ndarray, stage: int, passengers_left: np.ndarray, action: int) -> np.ndarray:
        """Mark the action's deployments; return the passengers left after it."""
        left = passengers_left.copy()
        for r in range(self.n_carriers):
            if action >> r & 1:
                deployed[r, stage] = True
                left[r] -= 1
        return left

    def _uct_child(self, node: _Node) -> tuple[int, _Node]:
        log_parent = math.log(node.visits)
        best, best_score = None, -math.inf
        for action, child in node.children.items():
            score = child.value / child.visits + self.exploration * math.sqrt(log_parent / child.visits)
            if score > best_score:
                best, best_score = (action, child), score
        return best

    def _sample_future(self) -> np.ndarray:
        """Known observations up to the root stage, prior samples after it; NaN at ∅ stages."""
        x = self.known.copy()
        j = self.stage
        if j + 1 < self.n_stages:
            draw = self.compiled.sampler.sample(self.rng, (self.n_carriers, self.n_stages - j - 1))
            x[:, j + 1:] = np.where(self.valid[:, j + 1:], draw, np.nan)
        return x

    def _rollout(self, x: np.ndarray, deployed: np.ndarray, start: int, passengers_left: np.ndarray) -> None:
        """Complete ``deployed`` from stage ``start`` on with the rollout policy (in place)."""
        left = passengers_left.copy()
        flat = deployed.reshape(-1)  # a view: conflicts see deployments as they are chosen
        for k in range(start, self.n_stages):
            for r in range(self.n_carriers):
                if not self.valid[r, k] or left[r] <= 0:
                    continue
                n, d = int(self.stages_left[r, k]), int(left[r])
                if n <= d:  # forced: no draw (the random rollout draws only for a choice)
                    go = True
                elif self.rollout == "ssap":
                    conflicts = int(np.count_nonzero(self.compiled.conflict[r * self.n_stages + k] & flat))
                    go = ssap.deploys(self.table, x[r, k] / (1 + conflicts), n, d)
                else:
                    go = self.rng.random() < d / n
                if go:
                    deployed[r, k] = True
                    left[r] -= 1

    def iterate(self) -> None:
        """One selection-expansion-simulation-backup iteration."""
        node = self.root
        path = [node]
        deployed = self.past.copy()
        while node.stage < self.n_stages:
            if node.untried:
                action = node.untried.pop(int(self.rng.integers(len(node.untried))))
                left = self._apply(deployed, node.stage, node.passengers_left, action)
                child = self._make_node(node.stage + 1, left)
                node.children[action] = child
                node = child
                path.append(node)
                break
            action, child = self._uct_child(node)
            self._apply(deployed, node.stage, node.passengers_left, action)
            node = child
            path.append(node)
        total = 0.0
        for _ in range(self.samples):
            x = self._sample_future()
            trajectory = deployed.copy()
            self._rollout(x, trajectory, node.stage, node.passengers_left)
            total += evaluate(self.problem, trajectory, x)[0]
        reward = total / self.samples
        for visited in path:
            visited.visits += 1
            visited.value += reward

    def best_action(self) -> int:
        """Most visited root child (ties: higher mean, then expansion order)."""
        best, key = None, None
        for action, child in self.root.children.items():
            k = (child.visits, child.value / child.visits)
            if key is None or k > key:
                best, key = action, k
        return best


class ReferenceMCTSPlanner:
    """The paper's MCTS planner, plain Python (see the module docstring).

    Args:
        rollout: ``"ssap"`` (MCTS-SSAP) or ``"random"`` (MCTS-Random).
        iterations: iterations per decision (ignored when ``plan_ms`` is given).
        plan_ms: wall-clock budget per decision, milliseconds (anytime mode).
        exploration: UCT constant ``c`` on normalised rewards.
        samples: Monte Carlo rollouts per iteration (their mean is backed up).
    """

    def __init__(self, rollout: str = "ssap", iterations: int = DEFAULT_ITERATIONS, plan_ms: float | None = None,
                 exploration: float = DEFAULT_EXPLORATION, samples: int = DEFAULT_SAMPLES):
        if rollout not in ROLLOUTS:
            raise ValueError(f"rollout must be one of {ROLLOUTS}, got {rollout!r}")
        if iterations < 1 or samples < 1:
            raise ValueError("iterations and samples must be >= 1")
        self.rollout = rollout
        self.iterations = int(iterations)
        self.plan_ms = plan_ms
        self.exploration = float(exploration)
        self.samples = int(samples)
        self.name = f"mcts-{rollout}-reference"
        self.last_iterations = 0  # iterations run by the latest decision (for benchmarks)

    def decide(self, view: StageView, rng: np.random.Generator) -> np.ndarray:
        """bool ``[R]``: the most visited root joint action after the budget."""
        search = _Search(view, self.rollout, self.exploration, self.samples, rng)
        root = search.root
        if len(root.untried) == 1:  # a single feasible joint action: nothing to plan
            self.last_iterations = 0
            return _bits(root.untried[0], search.n_carriers)
        done = 0
        if self.plan_ms is None:
            for done in range(1, self.iterations + 1):
                search.iterate()
        else:
            deadline = time.perf_counter() + self.plan_ms / 1e3
            while True:
                search.iterate()
                done += 1
                if time.perf_counter() >= deadline:
                    break
        self.last_iterations = done
        return _bits(search.best_action(), search.n_carriers)


def _bits(mask: int, n_carriers: int) -> np.ndarray:
    return np.array([bool(mask >> r & 1) for r in range(n_carriers)])
