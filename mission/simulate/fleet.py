"""What the simulator needs of a scenario: :class:`Fleet` (built from a scenario file by
:mod:`launcher.simulate`), with the planners' steps memoised on their exact inputs."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .. import events as ev
from .. import state as ms
from ..timeouts import DEFAULTS, Timeouts
from ..modes import Mode

@dataclass(frozen=True)
class Fleet:
    """What the simulator needs of a scenario (all numbers; :mod:`launcher.simulate` builds it).

    Attributes:
        ids: carrier ids in scenario order; passengers: ``[R]``; valid: bool ``[R, N]``;
        stage_times: ``[N]`` s; x: float ``[R, N]``, what each carrier senses (NaN: invalid);
        problem: the planner core's instance; planner: the coordinator's planner (stateless);
        onboard: the on-board planner (``decide_local``); seed: the scenario's root seed;
        fingerprint: the world fingerprint every Hello carries; mode: the carriers' mode.
        links: the link model between the participants (:class:`world.fleet_links.FleetLinks`:
            ``spec``, ``between(src, dst, stages, alive)``, ``size(kind)``); None or a ``perfect``
            spec: the network as without one (mission/simulate/links.py).
        timeouts: the fleet's waits (:func:`mission.timeouts.over_links` of the link model's
            latency bound: the defaults on perfect and radio links).
        operator: a simulated operator's schedule: ``(stage, action, carrier)`` entries
            (``approve`` with carrier None, ``veto``, ``force``) taken at that stage before it is
            decided, as the console's actions are (docs/fleet.md, "The operator console").
    """

    ids: tuple
    passengers: tuple
    valid: np.ndarray
    stage_times: tuple
    x: np.ndarray
    problem: object
    planner: object
    onboard: object
    seed: int
    fingerprint: str = "sim"
    mode: str = Mode.HYBRID
    decisions: dict = field(default_factory=dict, compare=False, repr=False)  # the planner's memo
    links: object = field(default=None, compare=False, repr=False)
    timeouts: Timeouts = field(default=DEFAULTS, compare=False)
    operator: tuple = ()

    @property
    def n_stages(self) -> int:
        return len(self.stage_times)

    def spec(self) -> ms.MissionSpec:
        return ms.MissionSpec.build(self.ids, self.valid, self.passengers, self.stage_times, self.fingerprint)

    def decide(self, state: ms.MissionState, j: int) -> tuple[tuple, tuple]:
        """(deploying ids, sorted; the passenger each releases): the coordinator's stage step on
        the mission's view, under the operator's constraints of stage j in ``state``. Planners
        are stateless, so the step is a function of its inputs and is memoised on them (the
        campaign's missions share most of their stages)."""
        from ..decide import operator_constraints, planning_inputs, stage_decision
        from ..operator_rules import constraints

        x, deployed, released, counts = planning_inputs(self.problem, state, j)
        forced, vetoed, _ = constraints(state.operator_actions.get(j, ()))
        key = (j, np.nan_to_num(x[:, : j + 1], nan=-1.0).tobytes(), deployed[:, :j].tobytes(),
               None if released is None else released[:, :j].tobytes(),
               None if counts is None else np.nan_to_num(counts, nan=-1.0).tobytes(), forced, vetoed)
        hit = self.decisions.get(key)
        if hit is None:
            # no budget: the simulated planner's time is not the real one's (its faults of rule are)
            step = stage_decision(self.problem, state, j, self.planner, self.seed,
                                  operator_constraints(self.ids, forced, vetoed))
            rs = sorted(np.flatnonzero(step.deploy), key=lambda r: self.ids[r])
            hit = self.decisions[key] = (tuple(self.ids[r] for r in rs), tuple(int(step.passengers[r]) for r in rs))
        return hit

    def operator_actions(self, state: ms.MissionState, j: int, at: float) -> list:
        """The simulated operator's actions on stage j (:attr:`operator`), unless ``state``
        already holds actions of j (a resumed coordinator replayed them from its disk)."""
        if state.operator_actions.get(j):
            return []
        return [ev.OperatorAction(j, action, carrier, "simulated", at)
                for stage, action, carrier in self.operator if stage == j]

    def operator_decided(self, state: ms.MissionState, j: int, deploy, passengers, at: float) -> ev.Decided:
        """Stage j's Decided with what the operator changed (plain without a simulated operator)."""
        if not self.operator:
            return ev.Decided(j, deploy, 0.0, at, passengers)
        from ..operator_rules import constraints

        forced, vetoed, approved = constraints(state.operator_actions.get(j, ()))
        forced = tuple(c for c in forced if c in deploy)
        vetoed = tuple(c for c in vetoed if c not in deploy)
        return ev.Decided(j, deploy, 0.0, at, passengers, None, forced, vetoed, "approved" if approved else "timeout")

    def listened_by(self) -> dict:
        """carrier id -> the ids that listen to it (:func:`mission.peers.listened`: each carrier
        deciding on board listens to its conflict component), computed once."""
        key = ("listened",)
        if key not in self.decisions:
            from ..peers import listened

            out = {cid: [] for cid in self.ids}
            for r, cid in enumerate(self.ids):
                for b in listened(self.problem, r):
                    out[self.ids[b]].append(cid)
            self.decisions[key] = {cid: tuple(v) for cid, v in out.items()}
        return self.decisions[key]

    def decide_local(self, local) -> bool:
        """A carrier's on-board decision of its stage on its local view (memoised on the view)."""
        from planner.decentralised import LocalDecision
        from planner.problem import stage_rng

        key = ("local", local.carrier, local.stage, np.nan_to_num(local.observations, nan=-1.0).tobytes(),
               local.deployed.tobytes(),
               local.seen.tobytes(), local.record.tobytes())
        hit = self.decisions.get(key)
        if hit is None:
            hit = self.decisions[key] = bool(LocalDecision.of(self.onboard.decide_local(
                local, stage_rng(self.seed, local.stage))).deploy)
        return hit

    def offline(self) -> dict:
        """The offline planner's decisions (stage -> deploying ids) with every observation known:
        what a fault-free mission must decide (computed once per fleet)."""
        if ("offline",) not in self.decisions:
            self.decisions[("offline",)] = self._offline()
        return self.decisions[("offline",)]

    def _offline(self) -> dict:
        state = ms.initial(self.spec())
        for cid in self.ids:
            state = ms.step(state, ev.LivelinessChanged(cid, True))[0]
            state = ms.step(state, ev.Hello(cid, 0, "sim", self.passengers[self.ids.index(cid)], 0, self.fingerprint,
                                            revision=4))[0]
        out = {}
        for j in range(self.n_stages):
            for r, cid in enumerate(self.ids):
                if self.valid[r, j]:
                    xv = None if np.isnan(self.x[r, j]) else int(self.x[r, j])
                    state = ms.step(state, ev.Observation(cid, j, self.stage_times[j], xv, (0.0, 0.0), 0))[0]
            for action in self.operator_actions(state, j, 0.0):
                state = ms.step(state, action)[0]
            deploy, passengers = self.decide(state, j)
            state = ms.step(state, self.operator_decided(state, j, deploy, passengers, 0.0))[0]
            out[j] = deploy
        return out
