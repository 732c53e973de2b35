"""Constraints on one stage's decision: carriers an operator forces to deploy or vetoes there.

A constraint changes what the planner sees of the stage, never the planner: a vetoed carrier is
∅ at the stage (it cannot deploy there, and its stages left count one fewer), a forced carrier
has already deployed there (its release is part of the past the planner plans around: its
reward and its conflicts with the others' choices count, and it has one passenger fewer). Every
planner therefore decides the rest of the stage under the constraint with its usual budget and
plans the later stages knowing it (docs/planner.md, "Operator constraints").
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from planner.problem import StageView

#: Why a constraint cannot apply at a stage (the reason codes docs/protocol.md lists).
CANNOT_FORCE = "cannot-force"
CANNOT_VETO = "must-deploy"


@dataclass(frozen=True)
class Constraints:
    """An operator's constraints on one stage's decision.

    Attributes:
        forced: carrier indices r that deploy at the stage.
        vetoed: carrier indices r that do not deploy at the stage.
    """

    forced: frozenset = frozenset()
    vetoed: frozenset = frozenset()

    def __post_init__(self):
        object.__setattr__(self, "forced", frozenset(int(r) for r in self.forced))
        object.__setattr__(self, "vetoed", frozenset(int(r) for r in self.vetoed))
        both = self.forced & self.vetoed
        if both:
            raise ValueError(f"carriers {sorted(both)} both forced and vetoed")

    def __bool__(self) -> bool:
        return bool(self.forced or self.vetoed)

    def masks(self, n_carriers: int) -> tuple[np.ndarray, np.ndarray]:
        """(forced, vetoed) as bool ``[R]``."""
        forced = np.zeros(n_carriers, dtype=bool)
        vetoed = np.zeros(n_carriers, dtype=bool)
        forced[list(self.forced)] = True
        vetoed[list(self.vetoed)] = True
        return forced, vetoed


def why_not(view: StageView, r: int, kind: str) -> str | None:
    """Why carrier r cannot be forced (``kind`` "force") or vetoed ("veto") at the view's stage,
    as a reason code, or None when it can: a force needs a carrier that can deploy there (valid,
    not ∅, a passenger left); a veto a carrier that need not deploy there (its valid stages left
    exceed its passengers left: vetoing it would strand a passenger)."""
    if kind == "force":
        return None if bool(view.can_deploy[r]) else CANNOT_FORCE
    if kind == "veto":
        return CANNOT_VETO if bool(view.must_deploy[r]) else None
    raise ValueError(f"constraint kind must be 'force' or 'veto', found {kind!r}")


def usable(view: StageView, constraints: Constraints) -> tuple[Constraints, dict[int, str]]:
    """The constraints that apply at the view's stage, and the reason code of each dropped one
    (carrier r -> reason): an operator may have asked before the stage's observations arrived."""
    dropped = {r: why_not(view, r, "force") for r in constraints.forced}
    dropped.update({r: why_not(view, r, "veto") for r in constraints.vetoed})
    dropped = {r: why for r, why in dropped.items() if why is not None}
    return Constraints(constraints.forced - set(dropped), constraints.vetoed - set(dropped)), dropped


def constrain(view: StageView, constraints: Constraints) -> StageView:
    """The view a planner decides the rest of the stage on (see the module docstring). Every
    constraint must apply (:func:`usable`)."""
    if not constraints:
        return view
    j = view.stage
    valid = view.valid.copy()
    deployed = view.deployed.copy()
    for r in constraints.vetoed:
        valid[r, j] = False
    for r in constraints.forced:
        valid[r, j] = False
        deployed[r, j] = True
    released = view.released
    if released is not None:
        released = released.copy()
        aboard = view.aboard
        for r in constraints.forced:  # the lowest passenger aboard, as a carrier releases without a name
            left = np.flatnonzero(aboard[r])
            released[r, j] = int(left[0]) if len(left) else -1
    return dataclasses.replace(view, valid=valid, deployed=deployed, released=released)


def apply(decision: np.ndarray, constraints: Constraints) -> np.ndarray:
    """bool ``[R]``: ``decision`` with the forced carriers deploying and the vetoed ones not."""
    out = np.asarray(decision, dtype=bool).copy()
    out[list(constraints.forced)] = True
    out[list(constraints.vetoed)] = False
    return out
