"""closed-loop under the coverage reward (issue 35): one-stage search, reacting rollouts.

The penalty planner's structure (:mod:`planner.closedloop`): only the current stage's joint action
is searched (every combination of the carriers with a choice up to ``ENUMERATE_MAX`` of them,
coordinate ascent over single flips beyond), and each candidate is scored on common sampled
futures in which a base policy reacts to every sample. Under coverage:

* **Futures.** A future keeps the counts the view reveals and draws the others from their priors
  (:func:`planner.coverage.sample_counts_given`, batched: :func:`draw_counts`); every candidate
  reads the same futures (common random numbers), so only differences matter.
* **Base policy** (the rollouts after the current stage, and the starting action at it): a
  carrier deploys iff forced or the deployment's *marginal coverage* over the deployments already
  chosen (past, the candidate's, and the rollout's so far) exceeds its point's DLR threshold
  (:mod:`planner.coverage_plan`): the coverage form of the conflict-aware SSAP rule
  (``rule_rounds = 0``). The conflict-value rule and the plain-SSAP control variate of the
  penalty planner have no coverage form yet, so neither is used.
* **Score.** The candidate's marginal coverage at the current stage plus the rollout's, on each
  future (the past's coverage is common to all candidates and left out).

The rollout is the MCTS kernels' (:func:`planner.mcts.kernel.rollout_cover`) on fully drawn
counts, so it draws nothing itself.
"""
from __future__ import annotations

import time

import numpy as np
from numba import njit

from planner import coverage as cov
from planner.coverage_plan import plan_for
from planner.joint import ENUMERATE_MAX, SAMPLES_MAX, SAMPLES_MIN, every_combination, sampled_mean
from planner.jitcache import cache_follows_sources
from planner.mcts import kernel as _k
from planner.mcts.fast import cover_state
from planner.problem import StageView


def draw_counts(problem, known: np.ndarray, rng: np.random.Generator, batch: int) -> np.ndarray:
    """float ``[batch, P]``: ``batch`` futures of the planning regions' counts
    (:class:`planner.coverage_plan.CoveragePlan`), each the revealed ``known`` (float ``[P]``,
    NaN elsewhere) with the others drawn from their priors (as
    :func:`planner.coverage.sample_counts_given`; one vectorised call when all are Poisson)."""
    plan = plan_for(problem)
    if plan.poisson:  # a sum of independent Poisson counts is Poisson of the summed means
        draws = rng.poisson(plan.pmeans, size=(batch, len(plan.pmeans))).astype(float)
    else:
        draws = plan.plan_counts(np.column_stack([np.asarray(prior.rvs(size=batch, random_state=rng), dtype=float)
                                                  for prior in problem.coverage.priors]))  # one call per region
    return np.where(np.isnan(known)[None, :], draws, known[None, :])


@njit(cache=True)
def score_actions(actions, counts, root, scratch, cover, out):
    """``out[c, s]``: the raw coverage that joint action ``actions[c]`` (bool ``[K, R]``) at stage
    ``root.j0`` and the base policy after it add over the past, on future ``counts[s]``."""
    n_carriers, n_stages = root.valid.shape
    left, mark, pts, state = scratch.left, scratch.mark, scratch.pts, scratch.state
    for s in range(counts.shape[0]):
        for m in range(counts.shape[1]):  # every count known: the rollout draws nothing
            cover.cnt[m] = counts[s, m]
            cover.marks[_k.STAMP, m] = -1
        for c in range(actions.shape[0]):
            cover.tick[0] += 1  # a new trajectory: nothing of the previous one is covered
            n = np.int64(0)  # not a literal 0: rollout_cover would be compiled for Literal[int](0) as well
            total = 0.0
            for r in range(n_carriers):
                left[r] = root.d0[r]
                if actions[c, r]:
                    a = r * n_stages + root.j0
                    total += _k.cover_gain(a, cover, state)
                    _k.cover_add(a, cover)
                    mark[a] = 1
                    pts[n] = a
                    n += 1
                    left[r] -= 1
            n, more = _k.rollout_cover(n_carriers, n, root, _k.ROLLOUT_SSAP, scratch, cover)
            out[c, s] = total + more
            for i in range(n):
                mark[pts[i]] = 0


def base_action_cover(view: StageView) -> np.ndarray:
    """bool ``[R]``: the base policy's action at ``view.stage``: carriers in index order, each
    deploying iff forced or its marginal coverage (revealed counts) over the past and the
    deployments chosen before it exceeds its point's threshold."""
    problem = view.problem
    plan = plan_for(problem)
    j = view.stage
    decision = view.must_deploy.copy()
    best = cov.best_weights(problem.coverage, view.deployed)  # 1 where covered
    counts = np.nan_to_num(view.counts, nan=0.0)  # a point observed now has its regions revealed
    for r in np.flatnonzero(view.can_deploy).tolist():
        a = r * problem.n_stages + j
        if not decision[r]:
            gain = cov.marginal_gain(problem.coverage, best, a, counts)
            decision[r] = plan.deploys(a, gain, int(view.stages_left[r]), int(view.passengers_left[r]))
        if decision[r]:
            cov.add(problem.coverage, best, a)
    return decision


def decide_cover(planner, view: StageView, rng: np.random.Generator) -> np.ndarray:
    """closed-loop's decision under the coverage reward (module docstring). ``planner``: the
    :class:`planner.closedloop.ClosedLoopPlanner` (its budget and search)."""
    problem = view.problem
    if problem.weights is not None:
        raise ValueError("closed-loop: passenger values under the coverage reward are not supported")
    n_carriers, n_stages = problem.valid.shape
    free = view.can_deploy & ~view.must_deploy
    base = base_action_cover(view)
    if not free.any():
        return base
    flip = np.flatnonzero(free)
    k = len(flip)
    n_cand = (1 << k) * 1 if k <= ENUMERATE_MAX else (k + 1) * 3
    samples = int(np.clip(planner.iterations // n_cand, SAMPLES_MIN, SAMPLES_MAX))
    cover = cover_state(view)
    known = plan_for(problem).plan_counts(view.counts)
    vs_left = view.stages_left_table
    root = _k.Root(view.stage, view.passengers_left.astype(np.int64), np.ascontiguousarray(view.valid, dtype=np.uint8),
                   vs_left, np.zeros((1, 1)), np.zeros(1), np.zeros(0, dtype=np.int64), np.zeros((1, 1)), False)
    size = n_carriers * n_stages
    scratch = _k.Scratch(np.zeros(1, dtype=np.uint64), np.zeros(n_carriers, dtype=np.int64),
                         np.zeros(n_carriers, dtype=np.int64), np.zeros(size, dtype=np.uint8), np.zeros(size),
                         np.zeros(size, dtype=np.int64), np.zeros(2, dtype=np.int64),
                         np.zeros(n_carriers, dtype=np.int64), np.zeros((1, 1)), np.zeros(n_carriers, dtype=np.int64))

    def score(actions: np.ndarray, deadline: float | None) -> np.ndarray:
        def evaluate(batch: int) -> np.ndarray:
            out = np.empty((len(actions), batch))
            score_actions(np.ascontiguousarray(actions), draw_counts(problem, known, rng, batch),
                          root, scratch, cover, out)
            return out

        return sampled_mean(len(actions), samples, deadline, evaluate)

    deadline = None if planner.plan_ms is None else time.perf_counter() + planner.plan_ms / 1e3
    if k <= ENUMERATE_MAX:
        actions = every_combination(base, flip)
        return actions[int(np.argmax(score(actions, deadline)))]
    return planner.ascend(base, flip, deadline, score)


cache_follows_sources(globals())  # the on-disk cache follows every planner source
