"""The stage's hold for the operator: the one place where a coordinator's decision waits for a
person and applies the constraints they set.

At stage j, once the observations are in: the planner recommends (:func:`planner.online.stage_step`),
the page shows the recommendation, its reasons (:func:`planner.advice.advise`) and a countdown;
the coordinator goes on taking the carriers' messages while the hold waits, and applies the
operator's actions the hold hands it (the hold is a generator of waits and events: it holds no
coordinator and calls nothing back, :meth:`OperatorHold.decide`). A veto or a force is a mission event; the planner then decides the rest of the stage
again under every constraint set so far, on the same random stream, with its usual budget. The
hold ends when the operator approves, when the wait runs out (:func:`mission.operator_rules.hold_wait`:
``--operator-timeout``, or with ``--operator-required`` the stage's own wait), or on a stop
request; the decision then is the last one the planner made, with what the operator changed
and the planner's estimate of what that gained (:func:`planner.advice.override_gain`).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Generator

import numpy as np

from mission import operator_rules
from mission import state as ms
from mission import timers as tm
from planner.advice import advise, override_gain
from mission.decide import operator_constraints, planning_inputs
from planner.problem import make_view, stage_rng

@dataclass(frozen=True)
class Apply:
    """What the hold asks of its coordinator: apply this mission event (an operator's action)
    and send back the mission state after it."""

    event: object


@dataclass(frozen=True)
class OperatorSettings:
    """Operator mode (run_fleet.py's ``--operator`` flags).

    Attributes:
        port: the console's TCP port (0: any free one).
        timeout_s: the hold's wait (s); 0: the console only watches.
        required: wait for the operator up to ``stage_wait_s`` instead of ``timeout_s``.
        stage_wait_s: the stage's own wait (the coordinator's stage timeout), s.
        bind: the address the page is served on (127.0.0.1 by default).
        tls: (certificate file, key file) to serve it over HTTPS, or None.
    """

    port: int
    timeout_s: float
    required: bool = False
    stage_wait_s: float = 30.0
    bind: str = "127.0.0.1"
    tls: tuple[str, str] | None = None

    @property
    def wait_s(self) -> float:
        return self.stage_wait_s if self.required else self.timeout_s


@dataclass(frozen=True)
class Outcome:
    """The stage's decision after the hold: the fields of :class:`mission.events.Decided`."""

    deploy: tuple[str, ...]
    planning_ms: float
    passengers: tuple[int, ...]
    recommended: tuple[str, ...] | None
    forced: tuple[str, ...]
    vetoed: tuple[str, ...]
    hold: str
    gain: float | None


class OperatorHold:
    """The hold of each stage (see the module docstring).

    Args:
        settings: :class:`OperatorSettings`; desk: the :class:`console.desk.Desk`; plan:
        ``plan(j, state, constraints) -> StageStep``, the coordinator's planner step
        (:func:`coordinator.planning.plan_step`); problem: the planning problem; ids: the carrier
        ids; seed: the mission's root seed (the estimate's stream); clock: the coordinator's
        clock (s); stop: its stop request; log: a callable taking one line.
    """

    def __init__(self, settings: OperatorSettings, desk, plan, problem, ids, seed: int, clock, stop, log):
        self.settings, self.desk, self.plan, self.problem, self.ids = settings, desk, plan, problem, tuple(ids)
        self.seed, self.clock, self._stop, self.log = seed, clock, stop, log

    def stage_view(self, j: int, st: ms.MissionState):
        """The planner's view of stage j in mission state ``st`` (what the reasons are computed on)."""
        return make_view(self.problem, j, *planning_inputs(self.problem, st, j))

    def decide(self, j: int, st: ms.MissionState) -> Generator[tm.Wait | Apply, ms.MissionState, Outcome]:
        """Stage j's hold, from mission state ``st``: a generator of what it asks of its
        coordinator, a :class:`mission.timers.Wait` (take the inbox until then, or for its
        poll at most: the desk is looked at again after it) or an :class:`Apply` (an operator's action), each answered with the
        mission state then; it returns the stage's :class:`Outcome`."""
        ids = self.ids
        first = self.plan(j, st, None)
        recommended = first.deploy.copy()
        step, planning_ms = first, first.decision_ms
        forced, vetoed, approved = operator_rules.constraints(st.operator_actions.get(j, ()))
        if forced or vetoed:  # a resumed coordinator: the actions taken before it stopped
            step = self.plan(j, st, operator_constraints(ids, forced, vetoed))
            planning_ms += step.decision_ms
        opened = self.clock()
        wait_s = self.settings.wait_s
        self._show(j, st, step, recommended, (forced, vetoed), opened, wait_s, "holding")
        while not self._stop.is_set():
            rule = operator_rules.hold_wait(opened, self.clock(), wait_s, approved)
            if not isinstance(rule, tm.Wait):
                break
            st = yield rule
            changed = False
            for e, ticket in self.desk.drain():
                refused = operator_rules.refusal(st, e)
                if refused is not None:
                    self.desk.answer(ticket, e, False, *refused)
                    continue
                st = yield Apply(e)
                self.desk.answer(ticket, e, True)
                changed = True
            if changed:
                now_forced, now_vetoed, approved = operator_rules.constraints(st.operator_actions.get(j, ()))
                if (now_forced, now_vetoed) != (forced, vetoed):
                    forced, vetoed = now_forced, now_vetoed
                    step = self.plan(j, st, operator_constraints(ids, forced, vetoed))
                    planning_ms += step.decision_ms
                    for r, why in step.dropped.items():
                        self.log(f"coordinator: stage {j}: the operator's constraint on {ids[r]} cannot apply ({why})")
                self._show(j, st, step, recommended, (forced, vetoed), opened, wait_s, "holding")
        kept = {ids[r] for r in step.dropped}
        forced = tuple(cid for cid in forced if cid not in kept)
        vetoed = tuple(cid for cid in vetoed if cid not in kept)
        hold = "watching" if wait_s <= 0 else "approved" if approved else "timeout"
        gain = None
        if forced or vetoed:
            gain = override_gain(self.stage_view(j, st), recommended, step.deploy, stage_rng(self.seed + 1, j))
            self.log(f"coordinator: stage {j}: operator constraints forced {', '.join(forced) or '-'}, vetoed "
                     f"{', '.join(vetoed) or '-'}; recommended {_names(ids, recommended)}, decided "
                     f"{_names(ids, step.deploy)}; the planner estimates "
                     f"{'n/a' if gain is None else f'{gain:+.3f}'} reward")
        elif hold == "timeout":
            self.log(f"coordinator: stage {j}: no answer from the operator in {wait_s:g} s; the recommendation stands")
        self.desk.show(None)  # decided: the page shows the mission so far until the next hold
        rs = sorted(np.flatnonzero(step.deploy), key=lambda r: ids[r])
        rec = tuple(sorted(ids[r] for r in np.flatnonzero(recommended)))
        deploy = tuple(ids[r] for r in rs)
        return Outcome(deploy, planning_ms, tuple(int(step.passengers[r]) for r in rs),
                       rec if rec != tuple(sorted(deploy)) else None, forced, vetoed, hold,
                       None if gain is None or math.isnan(gain) else float(gain))

    def _show(self, j, st: ms.MissionState, step, recommended, constraints, opened, wait_s, status) -> None:
        view = self.stage_view(j, st)
        ids = self.ids
        self.desk.show({
            "stage": j, "status": status, "deploy": step.deploy.tolist(), "recommended": recommended.tolist(),
            "advice": [dict(a, carrier=ids[r], conflicts=[ids[q] for q in a["conflicts"]])
                       for r, a in enumerate(advise(view, step.deploy))], "forced": list(constraints[0]), "vetoed": list(constraints[1]),
            # The page counts down on wall time: the deadline as seconds since the epoch.
            "deadline": time.time() + (opened + wait_s - self.clock()) if wait_s > 0 else None, "wait_s": wait_s,
            "required": self.settings.required, "dropped": {ids[r]: why for r, why in step.dropped.items()}})


def _names(ids, deploy) -> str:
    return " ".join(ids[r] for r in np.flatnonzero(deploy)) or "-"
