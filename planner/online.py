"""The online loop: one stage step, and ``run_online`` running it stage by stage.

:func:`stage_step` is the one definition of "decide stage j": the causal view of the stage
(:func:`planner.problem.make_view`), the planner's decision on the stage's random stream
(:func:`planner.problem.stage_rng`), the feasibility check (:func:`planner.problem.enforce`) and
the passenger each deploying carrier releases (:func:`planner.passengers.release`). The offline
loop (:func:`run_online`) and the fleet's coordinator both call it, so the fleet decides exactly
like the offline planner.

This module sits above the planners' modules: it routes a decentralised planner to
:func:`planner.decentralised.run_comms` (perfect links), and nothing of ``planner/`` imports it.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from planner.constraints import Constraints, apply, constrain, usable
from planner.guard import checked_decision
from planner.passengers import release
from planner.problem import OnlineResult, Planner, Problem, StageView, evaluate, make_view, stage_rng, start_online


@dataclass(frozen=True, eq=False)
class StageStep:
    """One stage's decision.

    Attributes:
        deploy: bool ``[R]``: carriers deploying at the stage (checked by ``enforce``).
        passengers: int64 ``[R]``: the passenger index each deploying carrier releases, -1 for
            the others (index order without passenger values).
        decision_ms: wall time of the planner's ``decide`` call, milliseconds.
        dropped: carrier index -> the reason code of each constraint that could not apply.
    """

    deploy: np.ndarray
    passengers: np.ndarray
    decision_ms: float
    dropped: dict = field(default_factory=dict)


def stage_step(problem: Problem, x: np.ndarray, deployed: np.ndarray, planner: Planner, seed: int,
               stage: int, released: np.ndarray | None = None, counts: np.ndarray | None = None,
               budget_ms: float | None = None, constraints: Constraints | None = None) -> StageStep:
    """Decide stage ``stage`` of a mission with root seed ``seed``.

    Args:
        problem: the instance.
        x: float ``[R, N]``: the observations so far (NaN = ∅); only stages ``<= stage`` are read.
        deployed: bool ``[R, N]``: the deployments so far; only stages ``< stage`` are read.
        planner: any :class:`planner.problem.Planner` (already warmed up by the caller if it
            times decisions).
        seed: the mission's root seed (the planner draws from ``stage_rng(seed, stage)``).
        stage: the stage j being decided.
        released: int64 ``[R, N]`` or None: the passenger each past deployment released (read
            only for a problem with passenger values; None means index order).
        counts: float ``[M]``: the realised region counts of a coverage problem (required there;
            the view keeps only those the observations up to ``stage`` reveal), else None.
        budget_ms: the planner's ``plan_ms`` budget, when it has one: a decision later than
            :func:`planner.guard.budget_limit_ms` of it is a fault.
        constraints: carriers an operator forces or vetoes at the stage
            (:mod:`planner.constraints`): the planner decides the rest of the stage on the
            constrained view, with the same random stream; a constraint that cannot apply (a
            force of a carrier that cannot deploy, a veto of one that must) is dropped and
            reported in ``StageStep.dropped`` (carrier index -> reason code).

    Raises:
        ValueError: ``stage`` outside the problem's stages, or a coverage problem without counts.
        planner.guard.PlannerFault: the planner raised, broke a rule or ran past its budget
            (an AssertionError).
    """
    view = make_view(problem, stage, x, deployed, released, counts)
    dropped: dict = {}
    if constraints:
        constraints, dropped = usable(view, constraints)
    decider = _Constrained(planner, constraints) if constraints else planner
    deploy, decision_ms = checked_decision(decider, view, stage_rng(seed, stage), budget_ms)
    return StageStep(deploy, release(planner, view, deploy), decision_ms, dropped)


class _Constrained:
    """``planner`` deciding the rest of a stage on the view ``constraints`` leave it
    (:func:`planner.constraints.constrain`), the constraints applied to its decision."""

    def __init__(self, planner: Planner, constraints: Constraints):
        self.planner, self.constraints = planner, constraints

    def decide(self, view: StageView, rng: np.random.Generator) -> np.ndarray:
        return apply(self.planner.decide(constrain(view, self.constraints), rng), self.constraints)


def run_online(problem: Problem, x: np.ndarray, planner: Planner, seed: int,
               counts: np.ndarray | None = None, budget_ms: float | None = None) -> OnlineResult:
    """Run ``planner`` stage by stage over realised observations ``x`` (NaN = ∅).

    Stage j is :func:`stage_step` (random stream ``stage_rng(seed, j)``). A NaN at a scheduled
    stage is an online surprise: the planner learns it only at that stage. If the planner has a
    ``warm_up(problem)`` method (e.g. to compile numba code) it is called once before the first
    timed decision, so ``decision_ms`` never includes compilation. A decentralised planner
    (``decentralised = True``, ``decide_local``) runs under perfect communication
    (:func:`planner.decentralised.run_comms`). ``counts``: the realised region counts of a
    coverage problem (``x`` is then their sums, :func:`planner.coverage.observations`).
    """
    if callable(getattr(planner, "decide_local", None)) and getattr(planner, "decentralised", False):
        # Imported here: the decentralised module loads numba kernels that a centralised run never needs.
        from planner.decentralised import run_comms  # every carrier decides; links are perfect here

        return run_comms(problem, x, planner, seed, counts=counts)
    x, released = start_online(problem, x, planner)
    deployed = np.zeros(problem.valid.shape, dtype=bool)
    times = []
    for j in range(problem.n_stages):
        step = stage_step(problem, x, deployed, planner, seed, j, released, counts, budget_ms)
        times.append(step.decision_ms)
        deployed[:, j] = step.deploy
        if released is not None:
            released[:, j] = step.passengers
    reward, features = evaluate(problem, deployed, x, released, counts=counts)
    return OnlineResult(deployed, reward, features, tuple(times), released)
