"""A coordinator's decision of stage j on its mission state: the one step the real coordinator
(:func:`coordinator.planning.plan_step`, the operator console's holds) and the simulator's coordinator
(:meth:`mission.simulate.fleet.Fleet.decide`) both take.

It is :func:`planner.online.stage_step` on the state's view of the stage (the observations it
plans with, the deployments and passengers so far, a coverage mission's revealed region counts)
under the operator's constraints, guarded: a planner fault (:mod:`planner.guard`: it raised,
broke a rule, ran past its budget) is handed to ``on_fault`` and the stage decided by
:data:`FALLBACK_PLANNER` under the same constraints. A plug-in is someone else's code; it cannot
take the fleet down, on real processes or in the simulator.
"""
from __future__ import annotations

from typing import Callable

from planner.constraints import Constraints
from planner.guard import PlannerFault
from planner.online import StageStep, stage_step

from .coverage import planning_counts

#: The planner that decides a stage a planner failed: SSAP, the carriers' on-board rule, needs no
#: options and cannot fail.
FALLBACK_PLANNER = "ssap"


def stage_decision(problem, state, j: int, planner, seed: int, constraints: Constraints | None = None,
                   budget_ms: float | None = None,
                   on_fault: Callable[[PlannerFault], None] | None = None) -> StageStep:
    """Stage ``j``'s step on mission state ``state`` (:class:`mission.state.MissionState`) by
    ``planner`` (its decision checked, ``budget_ms`` its ``plan_ms`` budget or None), falling back
    to :data:`FALLBACK_PLANNER` on a fault, which ``on_fault`` hears first."""
    from planner.registry import make_planner  # every planner's module: loaded when needed

    x, deployed, released, counts = planning_inputs(problem, state, j)
    try:
        return stage_step(problem, x, deployed, planner, seed, j, released, counts, budget_ms, constraints)
    except PlannerFault as fault:
        if on_fault is not None:
            on_fault(fault)
        return stage_step(problem, x, deployed, make_planner(FALLBACK_PLANNER), seed, j, released, counts, None,
                          constraints)


def planning_inputs(problem, state, j: int) -> tuple:
    """(x, deployed, released, counts): what stage ``j`` is planned on in mission state ``state``
    (the arguments of :func:`planner.problem.make_view` after the problem and the stage)."""
    return (state.planning_observations(j), state.deployed(),
            state.releases() if problem.weights is not None else None, planning_counts(state, problem))


def operator_constraints(ids, forced, vetoed) -> Constraints:
    """The planner's :class:`~planner.constraints.Constraints` (carrier indices in ``ids``) of the
    operator's forced and vetoed carrier ids."""
    index = {cid: r for r, cid in enumerate(ids)}
    return Constraints(frozenset(index[c] for c in forced), frozenset(index[c] for c in vetoed))
