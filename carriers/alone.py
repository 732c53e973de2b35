"""A carrier deciding a stage on board (no Decision in time, or no coordinator): the wait for
its peers' observations of the stage, then the on-board planner on what it heard.

:class:`Alone` is a part of :class:`carriers.node.Carrier`.
"""
from __future__ import annotations

from mission import carrier as mc
from mission import timers as tm

#: How often a carrier deciding alone looks for the peers' observations it waits for (s).
PEER_POLL_S = 0.02


class Alone:
    """The carrier's on-board decision of a stage."""

    def _decide_alone(self, j: int) -> None:
        """Decide stage j on board: wait for the other live carriers' observations of j — a
        decision arriving meanwhile still wins — then run the on-board planner on what the
        carrier heard. Wall clock: at most ``peer_timeout_s``. Sim clock: while some peer it
        waits for is heard from (its Progress while it simulates): until nothing came from any
        of them for ``silence_timeout_s`` (:func:`mission.timers.peer_wait`, [P-8.4])."""
        from planner.decentralised import LocalDecision
        from planner.problem import stage_rng

        self._listen(wait=True)
        if not self._alone:
            self._alone = True
            self.log(f"deciding on board from stage {j} (dec-closed-loop, {len(self.presence.peers_live - {self.cid})} "
                     f"other carrier(s) reachable)")
        opened = self.clock()
        while not self._stop.is_set() and not self.machine.resolved(j) and not self.machine.ended:
            now = self.clock()
            waiting = self.book.waiting(j, self.presence.peers_live - {self.cid})
            rule = tm.peer_wait(self.timers.clock, waiting, self.presence.heard, opened, now,
                                self.config.peer_timeout_s, self.timers.silence_timeout_s)
            if isinstance(rule, tm.GoOn):
                break
            self._repeat_observation(j, now)
            self._pump(min(rule.until - now, PEER_POLL_S))  # peers' messages do not wake the carrier
        if self._stop.is_set() or self.machine.resolved(j) or self.machine.ended:
            return
        problem, planner = self.onboard.get()
        local = self.book.local_view(problem, self.cid, j, self.scenario.seed)
        deploy = LocalDecision.of(planner.decide_local(local, stage_rng(self.scenario.seed, j))).deploy
        self.apply(mc.DecidedOwn(j, bool(deploy), self._position()))

    def _repeat_observation(self, j: int, now: float) -> None:
        """Sim clock, waiting for peers: its observation of j goes out again every third of the
        silence timeout (an identical repeat is absorbed), for peers waiting for it as it waits for
        theirs while one of them was lost (found by mission.simulate: two carriers heard from
        forever, each waiting for the other's lost observation)."""
        if self.timers.clock == "sim" and tm.due(self._repeated_at, now, self.timers.silence_timeout_s / 3):
            self._repeated_at = now
            self._execute(mc.ResendObservation(j))
