"""Planner defaults and choice lists: the one home of every value the planners, the registry and
the command lines share.

This module sits below every planner and below :mod:`planner.registry` (which builds the option
table from these values and imports the planners to build them), and imports nothing of the
package, so a planner reading its default never reaches back up to the registry.
"""
from __future__ import annotations

import math

#: Default MCTS / closed-loop / Dec-MCTS budget: iterations (full-fleet rollouts) per decision.
DEFAULT_ITERATIONS = 10_000
#: Default UCT exploration constant on normalised rewards (the paper's 0.05·√2).
DEFAULT_EXPLORATION = 0.05 * math.sqrt(2.0)
#: Default planner of a scenario (and of ``python -m coordinator.solve``).
DEFAULT_PLANNER = "mcts-ssap"
#: MCTS tree layouts (see planner.mcts.fast); the first is the default.
LAYOUTS = ("auto", "joint", "binary")
#: Default Monte Carlo rollouts per MCTS iteration.
DEFAULT_SAMPLES = 1
#: The planner a carrier runs on board when it decides a stage itself (and the one the report names
#: for stages the carriers decided alone).
ONBOARD_PLANNER = "dec-closed-loop"


def check_budget(iterations: int | None, plan_ms: float | None) -> tuple[int, float | None]:
    """A search planner's budget, checked: ``(iterations, plan_ms)`` with ``iterations`` None read
    as :data:`DEFAULT_ITERATIONS` and ``plan_ms`` (milliseconds per decision) None for "not set".

    Raises:
        ValueError: iterations below 1 or plan_ms not > 0, naming the option.
    """
    if iterations is not None and int(iterations) < 1:
        raise ValueError(f"iterations must be >= 1, got {iterations}")
    if plan_ms is not None and not float(plan_ms) > 0:
        raise ValueError(f"plan_ms must be > 0, got {plan_ms}")
    return (DEFAULT_ITERATIONS if iterations is None else int(iterations)), (None if plan_ms is None else float(plan_ms))
