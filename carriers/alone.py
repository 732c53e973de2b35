"""A carrier deciding a stage on board (no Decision in time, or no coordinator): the wait for
its peers' observations of the stage, then the on-board planner on what it heard.

:class:`Alone` is a collaborator of :class:`carriers.node.Carrier`: it owns its spell of deciding
alone and its repeats, and is handed the carrier's clock, presence, timers and inbox pump for each
stage (a test or a ROS 2 body may replace them on the carrier after it is built).
"""
from __future__ import annotations

from mission import carrier as mc
from mission import timers as tm
from mission.peers import PeerBook

#: How often a carrier deciding alone looks for the peers' observations it waits for (s).
PEER_POLL_S = 0.02


class Alone:
    """The carrier's on-board decision of a stage.

    Attributes:
        deciding: the carrier is deciding stages itself (logged once per spell; a Decision that
            resolves a stage ends the spell, :meth:`answered`).
        repeated_at: when it last repeated its observation to the peers it waits for.
    """

    def __init__(self, cid: str, book: PeerBook, onboard, seed: int, peer_timeout_s: float, log):
        self.cid, self.book, self.onboard, self.seed, self.log = cid, book, onboard, seed, log
        self.peer_timeout_s = peer_timeout_s
        self.deciding = False
        self.repeated_at: float | None = None

    def answered(self) -> None:
        """A Decision resolved the stage: the next stage decided alone starts a new spell."""
        self.deciding = False

    def decide(self, j: int, clock, presence, timers, settled, pump, resend) -> bool | None:
        """Decide stage j on board: wait for the other live carriers' observations of j — a
        decision arriving meanwhile still wins — then run the on-board planner on what the
        carrier heard. Wall clock: at most ``peer_timeout_s``. Sim clock: while some peer it
        waits for is heard from (its Progress while it simulates): until nothing came from any
        of them for ``silence_timeout_s`` (:func:`mission.timers.peer_wait`, [P-8.4]).

        Handed: ``clock()`` the carrier's clock; ``presence`` its
        :class:`mission.peers.Presence`; ``timers()`` its :class:`mission.carrier.Timers` now
        (they follow the coordinator's Accepted); ``settled()`` true once the stage needs no
        decision of its own (resolved, End, a stop request); ``pump(s)`` waits for and handles
        its messages; ``resend()`` sends its observation of j again. Returns whether the carrier
        deploys at j (None: settled meanwhile, nothing to decide)."""
        if not self.deciding:
            self.deciding = True
            self.log(f"deciding on board from stage {j} (dec-closed-loop, {len(presence.peers_live - {self.cid})} "
                     f"other carrier(s) reachable)")
        opened = clock()
        while not settled():
            now, now_timers = clock(), timers()
            waiting = self.book.waiting(j, presence.peers_live - {self.cid})
            rule = tm.peer_wait(now_timers.clock, waiting, presence.heard, opened, now, self.peer_timeout_s,
                                now_timers.silence_timeout_s)
            if isinstance(rule, tm.GoOn):
                break
            self._repeat_observation(now_timers, now, resend)
            pump(min(rule.until - now, PEER_POLL_S))  # peers' messages do not wake the carrier
        return None if settled() else self.deploy(j)

    def deploy(self, j: int) -> bool:
        """The on-board planner's choice at stage j on what the carrier heard (deploy or not)."""
        from planner.decentralised import LocalDecision
        from planner.problem import stage_rng

        problem, planner = self.onboard.get()
        local = self.book.local_view(problem, self.cid, j, self.seed)
        return bool(LocalDecision.of(planner.decide_local(local, stage_rng(self.seed, j))).deploy)

    def _repeat_observation(self, timers: mc.Timers, now: float, resend) -> None:
        """Sim clock, waiting for peers: its observation of j goes out again every third of the
        silence timeout (an identical repeat is absorbed), for peers waiting for it as it waits for
        theirs while one of them was lost (found by mission.simulate: two carriers heard from
        forever, each waiting for the other's lost observation)."""
        if timers.clock == "sim" and tm.due(self.repeated_at, now, timers.silence_timeout_s / 3):
            self.repeated_at = now
            resend()
