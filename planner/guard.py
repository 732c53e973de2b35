"""What a planner may return, checked wherever a planner decides: the conformance kit, the
offline loop (``solve``) and the coordinator (docs/planner.md, "Writing a planner plug-in").

A plug-in is someone else's code: a decision that raises, breaks a rule or comes back later than
its budget is a :class:`PlannerFault` naming the rule (one of the kit's reasons: ``raises``,
``infeasible``, ``deploys-twice``, ``beyond-passengers``, ``over-budget``), never an exception of
the plug-in's own that takes its caller down. Pure: numpy only.
"""
from __future__ import annotations

import time
from typing import Any

import numpy as np

#: A decision under ``plan_ms`` may take this many times the budget ...
BUDGET_FACTOR = 4.0
#: ... plus this much (timer and scheduler noise on a loaded host), milliseconds.
BUDGET_SLACK_MS = 30.0


def budget_limit_ms(plan_ms: float) -> float:
    """The longest a decision under a ``plan_ms`` budget may take, milliseconds."""
    return BUDGET_FACTOR * float(plan_ms) + BUDGET_SLACK_MS


class Violation(Exception):
    """A planner broke a rule: ``reason`` of :data:`REASONS`, ``detail`` one line."""

    def __init__(self, reason: str, detail: str):
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail



class PlannerFault(AssertionError):
    """A planner broke rule ``rule`` (a reason of :class:`Violation`) deciding ``stage``;
    ``detail`` is one line. An AssertionError, as the feasibility check always raised."""

    def __init__(self, rule: str, stage: int, detail: str):
        super().__init__(f"{rule}: {detail}")
        self.rule, self.stage, self.detail = rule, int(stage), detail

    def line(self, planner: str) -> str:
        """One line naming the planner and the rule it broke."""
        return f"planner {planner!r} broke rule {self.rule} at stage {self.stage}: {self.detail}"


def classify(decision: Any, view) -> np.ndarray:
    """A central decision checked against the rules of its view: bool ``[R]``.

    Raises:
        Violation: ``deploys-twice``, ``beyond-passengers`` or ``infeasible`` (which carriers).
    """
    n_carriers = view.problem.n_carriers
    try:
        raw = np.asarray(decision)
    except Exception:  # an object numpy cannot read
        raise Violation("infeasible", f"stage {view.stage}: a decision numpy cannot read ({type(decision).__name__})")
    if raw.shape != (n_carriers,):
        raise Violation("infeasible", f"stage {view.stage}: decision shape {raw.shape}, expected ({n_carriers},)")
    if raw.dtype != bool:
        if not np.issubdtype(raw.dtype, np.number) or not np.isfinite(raw.astype(float)).all():
            raise Violation("infeasible", f"stage {view.stage}: decision of dtype {raw.dtype}, expected bool")
        values = raw.astype(float)
        twice = np.flatnonzero(values >= 2)
        if len(twice):
            raise Violation("deploys-twice", f"stage {view.stage}: carriers {twice.tolist()} deploy "
                                             f"{values[twice].tolist()} times at one stage")
        if ((values != 0) & (values != 1)).any():
            raise Violation("infeasible", f"stage {view.stage}: decision values {values.tolist()}, expected 0 or 1")
    deploy = raw.astype(bool)
    empty = np.flatnonzero(deploy & (view.passengers_left <= 0))
    if len(empty):
        raise Violation("beyond-passengers", f"stage {view.stage}: carriers {empty.tolist()} deploy with no "
                                             f"passenger left")
    bad = np.flatnonzero(deploy & ~view.can_deploy)
    if len(bad):
        raise Violation("infeasible", f"stage {view.stage}: carriers {bad.tolist()} deploy at an empty (∅) stage")
    missing = np.flatnonzero(view.must_deploy & ~deploy)
    if len(missing):
        raise Violation("infeasible", f"stage {view.stage}: carriers {missing.tolist()} must deploy (as many "
                                      f"valid stages left as passengers) and do not")
    return deploy



def checked_decision(planner, view, rng, budget_ms: float | None = None) -> tuple[np.ndarray, float]:
    """``planner.decide(view, rng)`` checked: (bool ``[R]``, its wall time in ms).

    Raises:
        PlannerFault: it raised (``raises``), broke a rule (:func:`classify`), or, with a
            ``budget_ms`` (a ``plan_ms``), took longer than :func:`budget_limit_ms` of it.
    """
    start = time.perf_counter()
    try:
        decision = planner.decide(view, rng)
    except Violation as err:  # a checked planner (the conformance kit's recorder)
        raise PlannerFault(err.reason, view.stage, err.detail) from None
    except Exception as err:
        raise PlannerFault("raises", view.stage, f"{type(err).__name__}: {' '.join(str(err).split())[:200]}") from err
    ms = (time.perf_counter() - start) * 1e3
    try:
        deploy = classify(decision, view)
    except Violation as err:
        raise PlannerFault(err.reason, view.stage, err.detail) from None
    if budget_ms is not None and ms > budget_limit_ms(budget_ms):
        raise PlannerFault("over-budget", view.stage, f"the decision took {ms:.0f} ms, more than {BUDGET_FACTOR:g} x "
                                                     f"plan_ms={budget_ms:g} + {BUDGET_SLACK_MS:g} ms")
    return deploy, ms
