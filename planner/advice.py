"""What a planner's recommendation rests on, in numbers an operator can check.

:func:`advise` gives, per carrier at a stage, the value of deploying now (its observation over
the penalty its conflicts at this stage and in the past would give it) against the value of
waiting (the DLR threshold it is compared with: the expected value of the slot its passenger
would take later), and the conflicts the recommendation avoids (carriers whose observation
passes their threshold, so that SSAP alone would deploy them, held back by the planner).
:func:`override_gain` is the planner's estimate of what a decision other than its own gains (or
costs, when negative): both joint actions followed by every carrier's SSAP policy over the same
sampled futures, scored by the penalty rule (docs/planner.md, "Operator constraints").
"""
from __future__ import annotations

import math

import numpy as np

from planner import ssap
from planner.problem import Problem, StageView, evaluate, sample_observations

#: Largest R * N whose override gain is estimated (its rollouts are plain Python, O(R * N) each).
ESTIMATE_MAX_CELLS = 4096
#: Sampled futures per estimate (common to both joint actions).
ESTIMATE_SAMPLES = 64


def advise(view: StageView, deploy: np.ndarray) -> list[dict]:
    """Per carrier r (index order), the reasons behind ``deploy`` (bool ``[R]``) at the view's stage.

    Each entry: ``x`` (None = ∅), ``can``, ``must``, ``deploy``, ``stages_left``,
    ``passengers_left``, ``now`` (raw features deploying now would earn: x / p, p = 1 + the
    deployments of this stage's ``deploy`` and of the past sharing an overlap with it; None when
    it cannot deploy), ``wait`` (the DLR threshold it is compared with, raw features; None when it
    cannot deploy, must, or under the coverage reward), ``conflicts`` (carriers at this stage
    sharing an overlap with it), ``avoided`` (passes its threshold, not deployed).
    """
    problem = view.problem
    j, n_r, n = view.stage, problem.n_carriers, problem.n_stages
    deploy = np.asarray(deploy, dtype=bool)
    conflict = problem.conflict
    table = ssap.table_for(problem) if problem.coverage is None else None
    past = np.flatnonzero(view.deployed.reshape(-1))
    out = []
    for r in range(n_r):
        cell = r * n + j
        x = view.observations[r, j]
        can, must = bool(view.can_deploy[r]), bool(view.must_deploy[r])
        stage_conflicts = [q for q in range(n_r) if q != r and conflict[cell, q * n + j]]
        entry = {"x": None if math.isnan(x) else float(x), "can": can, "must": must, "deploy": bool(deploy[r]),
                 "stages_left": int(view.stages_left[r]), "passengers_left": int(view.passengers_left[r]),
                 "now": None, "wait": None, "conflicts": stage_conflicts, "avoided": False}
        if can:
            p = 1 + sum(1 for q in stage_conflicts if deploy[q]) + int(conflict[cell, past].sum())
            entry["now"] = float(x) / p
            if table is not None and not must:
                k = int(view.stages_left[r]) - int(view.passengers_left[r])
                entry["wait"] = float(ssap.cut(table[int(view.stages_left[r]), k]))
                entry["avoided"] = bool(x > entry["wait"]) and not deploy[r]
        out.append(entry)
    return out


def override_gain(view: StageView, recommended: np.ndarray, decided: np.ndarray, rng: np.random.Generator,
                  samples: int = ESTIMATE_SAMPLES) -> float | None:
    """The planner's estimate of the normalised reward ``decided`` gains over ``recommended`` (both
    bool ``[R]`` at the view's stage; negative: a cost): the mean over ``samples`` futures drawn
    from the prior of the difference of the two, each followed by the carriers' SSAP policies.
    None where it is not estimated: equal actions give 0; the coverage reward, passenger values,
    and missions above :data:`ESTIMATE_MAX_CELLS` give None."""
    problem = view.problem
    recommended, decided = np.asarray(recommended, dtype=bool), np.asarray(decided, dtype=bool)
    if np.array_equal(recommended, decided):
        return 0.0
    if problem.coverage is not None or problem.weights is not None or problem.valid.size > ESTIMATE_MAX_CELLS:
        return None
    j = view.stage
    gains = np.empty(samples)
    for s in range(samples):
        x = sample_observations(problem, rng)
        x[:, : j + 1] = view.observations[:, : j + 1]
        gains[s] = _rollout(problem, view, x, decided) - _rollout(problem, view, x, recommended)
    return float(gains.mean())


def _rollout(problem: Problem, view: StageView, x: np.ndarray, action: np.ndarray) -> float:
    """The normalised reward of ``action`` at the view's stage followed by every carrier's SSAP
    policy on the future ``x``."""
    deployed = view.deployed.copy()
    deployed[:, view.stage] = action
    for r in range(problem.n_carriers):
        deployed = ssap.alone(problem, x, deployed, r, view.stage + 1)
    return float(evaluate(problem, deployed, x)[0])
