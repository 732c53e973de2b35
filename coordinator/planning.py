"""The coordinator's planner call: the planner warmed up (:func:`warm_up`), stage j's step on
the mission state (:func:`plan_step`, guarded and within its budget, a fault on record), the
decision of the planner alone as a mission event (:func:`planned`) and the stage's decision,
the planner's or, in operator mode, the console's (:func:`deciding`). The coordinator
(:meth:`coordinator.node.Coordinator.decide`) and the operator's console (:mod:`console.hold`,
under the operator's constraints) call them; each is given what it needs and returns what it
decided."""
from __future__ import annotations

import time

import numpy as np

from coordinator.setup import MissionSetup
from mission import events as ev
from mission import state as ms
from mission.decide import FALLBACK_PLANNER, stage_decision
from storage.missiondb import MissionStore


def warm_up(planner: tuple, problem, log) -> None:
    """The planner's ``warm_up(problem)`` if it has one; a plug-in's that raises is logged (its
    decisions are guarded one by one: :func:`plan_step`)."""
    planner, name = planner
    warm = getattr(planner, "warm_up", None)
    if callable(warm):
        try:
            warm(problem)
        except Exception as exc:
            log(f"coordinator: planner {name!r} warm_up raised {type(exc).__name__}: {exc}")


def plan_step(setup: MissionSetup, store: MissionStore, j: int, st: ms.MissionState, constraints=None):
    """Stage j's step on mission state ``st`` (:func:`mission.decide.stage_decision`: guarded,
    within the planner's ``plan_ms`` budget), under the operator's ``constraints``
    (:class:`planner.constraints.Constraints`; None: none). A planner fault is logged and
    recorded in mission.db (``planner-fault``: summary.json ``planner_faults``); the stage is
    decided by :data:`mission.decide.FALLBACK_PLANNER`."""

    def fault(f) -> None:
        setup.log(f"coordinator: {f.line(setup.planner_name)}; stage {f.stage} decided by {FALLBACK_PLANNER}")
        store.event("planner-fault", None, f.stage, rule=f.rule, detail=f.detail, planner=setup.planner_name,
                    fallback=FALLBACK_PLANNER)

    return stage_decision(setup.problem, st, j, setup.planner, setup.seed, constraints,
                          getattr(setup.planner, "plan_ms", None), fault)


def deciding(setup: MissionSetup, store: MissionStore, j: int, st: ms.MissionState, console=None):
    """Stage j's decision in mission state ``st``: the planner's alone (:func:`planned`), or, in
    operator mode, the operator's console's (``console``: ``console.run.Console``, None: none;
    its stage's hold, :meth:`console.hold.OperatorHold.decide`). A generator of what the hold
    asks its coordinator (waits, events to apply; answered with the mission state), returning
    the decision as a mission event (:class:`mission.events.Decided`)."""
    if console is None:
        return planned(setup, store, j, st)
    return (yield from console.decide(j, st))


def planned(setup: MissionSetup, store: MissionStore, j: int, st: ms.MissionState) -> ev.Decided:
    """Stage j's decision by the planner alone (deploying ids sorted, with their passengers)."""
    step = plan_step(setup, store, j, st)
    rs = sorted(np.flatnonzero(step.deploy), key=lambda r: setup.ids[r])
    return ev.Decided(j, tuple(setup.ids[r] for r in rs), step.decision_ms, time.time(),
                      tuple(int(step.passengers[r]) for r in rs))
