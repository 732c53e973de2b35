"""A carrier deciding a stage on board (no Decision in time, or no coordinator): the on-board
planner on what it heard. The wait for its peers' observations before it is the carrier's
lifecycle's (:mod:`mission.carrier_life`, phase ``alone``)."""
from __future__ import annotations

from mission.peers import PeerBook


class Alone:
    """The carrier's on-board decision of a stage (its lifecycle's
    :class:`mission.carrier_life.DecideOnBoard`, once the wait for its peers' observations is
    over: :func:`mission.timers.peer_wait`, [P-8.4])."""

    def __init__(self, cid: str, book: PeerBook, onboard, seed: int, log):
        self.cid, self.book, self.onboard, self.seed, self.log = cid, book, onboard, seed, log

    def deploy(self, j: int) -> bool:
        """The on-board planner's choice at stage j on what the carrier heard (deploy or not)."""
        from planner.decentralised import LocalDecision
        from planner.problem import stage_rng

        problem, planner = self.onboard.get()
        local = self.book.local_view(problem, self.cid, j, self.seed)
        return bool(LocalDecision.of(planner.decide_local(local, stage_rng(self.seed, j))).deploy)
