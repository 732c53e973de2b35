"""The operator's rules (docs/fleet.md, "The operator console"): which actions a mission takes,
what constraints they put on a stage's decision, and what summary.json says of them.

An action (:class:`mission.events.OperatorAction`) is about the stage being decided
(``next_stage``); for the same carrier at the same stage the latest action stands (a veto after
a force replaces it). Checked here without the planner: the mission's schedule and passengers
say whether a carrier could be forced (scheduled, not ∅, a passenger left) or vetoed (its
scheduled stages left exceed its passengers left); the planner checks again when it decides
(:func:`planner.constraints.usable`) and drops what no longer applies.
"""
from __future__ import annotations

import math

from . import events as ev


def refusal(state, e: ev.OperatorAction) -> tuple[str, str] | None:
    """Why ``e`` is refused in ``state`` (a :class:`mission.state.MissionState`), as (reason code,
    detail), or None when it is taken. The reasons are docs/protocol.md's ([P-12.4])."""
    spec, j = state.spec, e.stage
    if e.action not in ev.OPERATOR_ACTIONS:
        return "out-of-range", f"action {e.action!r}: expected one of {', '.join(ev.OPERATOR_ACTIONS)}"
    if state.ended:
        return "stale-stage", f"the mission has ended; stage {j} is not being decided"
    if j < state.next_stage:
        return "stale-stage", f"stage {j} is already decided (deploy: {', '.join(state.decisions[j].deploy) or '-'})"
    if j > state.next_stage or j >= spec.n_stages:
        return "future-stage", f"stage {j} is not being decided; stage {state.next_stage} is"
    if e.action == "approve":
        return None if e.carrier is None else ("out-of-range", "approve names no carrier")
    if e.carrier is None or not spec.has(e.carrier):
        return "unknown-carrier", f"carrier {e.carrier!r} is not in the scenario"
    r = spec.index(e.carrier)
    if not spec.valid[r][j]:
        return "not-scheduled", f"carrier {e.carrier} is not scheduled at stage {j}"
    left = int(state.passengers_left()[r])
    stages = sum(spec.valid[r][j:]) - (1 if _void(state, r, j) else 0)
    if e.action == "force":
        if left <= 0:
            return "cannot-force", f"carrier {e.carrier} has no passenger left"
        if _void(state, r, j):
            return "cannot-force", f"carrier {e.carrier} is ∅ at stage {j}"
    elif stages <= left:
        return "must-deploy", (f"carrier {e.carrier} must deploy at stage {j}: {left} passenger(s) left for "
                               f"{stages} stage(s)")
    return None


def _void(state, r: int, j: int) -> bool:
    cid = state.spec.carriers[r]
    return (cid, j) in state.reported and math.isnan(state.observation(r, j))


def constraints(actions) -> tuple[tuple[str, ...], tuple[str, ...], bool]:
    """(forced ids, vetoed ids, approved) from a stage's accepted actions, in order: the latest
    action per carrier stands."""
    last: dict[str, str] = {}
    approved = False
    for a in actions:
        if a.action == "approve":
            approved = True
        else:
            last[a.carrier] = a.action
    forced = tuple(sorted(c for c, a in last.items() if a == "force"))
    vetoed = tuple(sorted(c for c, a in last.items() if a == "veto"))
    return forced, vetoed, approved


def summary_block(state) -> dict | None:
    """summary.json's ``operator`` block (None for a mission decided without operator mode):
    counts of approvals, vetoes, forces and timeouts over the decided stages, and per overridden
    stage the planner's recommendation, the decision and its estimate of the gain (negative: a
    cost) in normalised reward."""
    decisions = state.decisions
    if not any(d.hold for d in decisions.values()) and not state.operator_actions:
        return None
    counts = {"approvals": 0, "vetoes": 0, "forces": 0, "timeouts": 0, "watched": 0}
    overrides = []
    for j in sorted(decisions):
        d = decisions[j]
        counts["approvals"] += d.hold == "approved"
        counts["timeouts"] += d.hold == "timeout"
        counts["watched"] += d.hold == "watching"
        counts["vetoes"] += len(d.vetoed)
        counts["forces"] += len(d.forced)
        if d.forced or d.vetoed:
            overrides.append({"stage": j, "forced": list(d.forced), "vetoed": list(d.vetoed),
                              "recommended": list(d.recommended if d.recommended is not None else d.deploy),
                              "decided": list(d.deploy), "estimated_gain": d.gain})
    gains = [o["estimated_gain"] for o in overrides if o["estimated_gain"] is not None]
    actions = [{"stage": a.stage, "action": a.action, "carrier": a.carrier, "operator": a.operator}
               for j in sorted(state.operator_actions) for a in state.operator_actions[j]]
    return {**counts, "overrides": overrides, "estimated_gain_total": float(sum(gains)) if gains else 0.0,
            "actions": actions,
            "meaning": "estimated_gain: the planner's estimate, when it decided, of the normalised reward the "
                       "operator's decision gains over its own recommendation (negative: a cost)"}


#: How a stage's hold for the operator ended (``Decided.hold``): the operator approved, the
#: wait ran out (the recommendation, or the decision under the constraints taken, stands), or
#: the console only watches (``--operator-timeout 0``).
HOLDS = ("approved", "timeout", "watching")


def hold_wait(opened: float, now: float, wait_s: float, approved: bool):
    """The stage's wait for the operator ([P-12.3]): over when the operator approved or ``wait_s``
    seconds have passed since the recommendation was shown (``wait_s`` 0: the console watches,
    no wait), else a :class:`mission.timers.Wait` until then."""
    from .timers import GoOn, Wait

    if approved or wait_s <= 0 or now >= opened + wait_s:
        return GoOn()
    return Wait(opened + wait_s)
