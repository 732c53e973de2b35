"""The coordinator's stage clock: the mission's phases after it is served (the carriers' join,
the stages, the last Confirms, End and the Byes), each wait a driver of a rule of
:mod:`mission.timers`, and the progress line.

Two clocks (docs/fleet.md, "Simulated time and wall time"): on the ``sim`` clock a live carrier
that makes progress is waited for and only a failure (its token gone, or nothing from it for
``silence_timeout_s``: :func:`mission.peers.last_heard`) ends a wait; on the ``wall`` clock the
timeouts are deadlines. :class:`StageClock` is a collaborator of
:class:`coordinator.node.Coordinator`, given its settings when built; it drives the coordinator
through a narrow interface (:class:`Clocked`), handed at each call.
"""
from __future__ import annotations

import threading
import time
from typing import Callable, Protocol, cast

from mission import events as ev
from mission import state as ms
from mission import timers as tm
from mission.timeouts import resumed_join
from wire.messages import End


#: Longest the coordinator waits for inbox items before it looks at its clock again (s).
POLL_S = 0.05


class Clocked(Protocol):
    """What the stage clock drives of a coordinator (:class:`coordinator.node.Coordinator`).

    Attributes:
        state: its :class:`mission.state.MissionState` (read: :meth:`apply` changes it).
        heard: carrier id -> when it was last heard (the clock's s) [P-10.5].
    """

    state: ms.MissionState
    heard: dict[str, float]

    def pump(self, timeout_s: float) -> None:
        """Wait up to ``timeout_s`` for inbox items and take them."""

    def apply(self, event) -> None:
        """Step its mission state with ``event``, persist, carry out the effects."""

    def decide(self, j: int) -> float | None:
        """Plan stage j, record and publish its Decision: the planning ms (None: deposed)."""

    def put_end(self, end: End) -> None:
        """Publish End."""


class StageClock:
    """The coordinator's waits and its stage loop: each wait is a driver of a rule of
    :mod:`mission.timers`, evaluated at the time the loop last looked at its clock.

    Args:
        config: the coordinator's ``CoordinatorConfig`` (its clock, pace and timeouts); spec: the
        :class:`mission.state.MissionSpec`; stage_interval: the mission time between stages (s);
        mission: the mission id; epochs: its ``coordinator.epochs.Epochs`` (the epoch End states;
        deposed: no End); stop: its stop request; clock: its clock (s); log: a callable taking one
        line.
    """

    def __init__(self, config, spec: ms.MissionSpec, stage_interval: float, mission: str, epochs,
                 stop: threading.Event, clock: Callable[[], float], log):
        self.config, self.spec, self.stage_interval, self.mission = config, spec, stage_interval, mission
        self.epochs, self._stop, self.clock, self.log = epochs, stop, clock, log

    def serve(self, c: Clocked) -> None:
        """The mission's phases once it is served: the carriers' join, the stages from the first
        undecided one, the last Confirms and End (not when deposed: the newer coordinator ends the
        mission); a resumed complete mission only tells late carriers it is over."""
        if c.state.ended:
            self.end(c, cast(str, c.state.end_reason))  # an ended state has its reason
            return
        self._wait_for_carriers(c)
        self._stages(c)
        if not self._stop.is_set():
            self._wait_confirms(c, self.spec.n_stages - 1)
        if self.epochs.deposed_by is None:  # deposed: the newer coordinator ends the mission
            self.end(c, "stopped" if self._stop.is_set() else "complete")

    def _drive(self, c: Clocked, rule):
        """Handle inbound items until ``rule(now)`` says anything but wait, or a stop request;
        returns what it said (None: stopped). A rule's inputs are the mission state, the time and
        when carriers were heard, and hearing one only delays a wait's end: so a
        :class:`mission.timers.Wait` stands until its ``until`` or a new state (most drains apply
        no event: Progress, Poses, about a thousand a second at R = 1,024)."""
        effect, seen = None, None
        while not self._stop.is_set():
            now = self.clock()
            if effect is None or c.state is not seen or now >= effect.until:
                seen, effect = c.state, rule(now)
                if not isinstance(effect, tm.Wait):
                    return effect
            c.pump(min(POLL_S, effect.until - now))
        return None

    def wait_stage(self, c: Clocked, j: int, opened: float) -> None:
        """Until every expected carrier's Observation of j is in, or a stop request, by
        :func:`mission.timers.stage_wait` ([P-10.3], [P-10.4]). Wall clock: at most
        ``stage_timeout_s``. Sim clock: as long as some carrier still waited for is making
        progress: one that nothing came from for ``silence_timeout_s`` (since the stage opened) is
        stalled and not waited for any more; a dead or cut-off one leaves ``expected`` by itself
        when its token vanishes."""
        clock, silence = self.config.clock, self.config.silence_timeout_s
        done = self._drive(c, lambda now: tm.stage_wait(clock, *c.state.waited_for(j), c.heard, opened, now,
                                                        self.config.stage_timeout_s, silence))
        if done is None or clock == "wall":
            return
        stalled, mute = sorted(done.stalled), sorted(done.late)
        if stalled:
            self.log(f"coordinator: stage {j}: nothing from {', '.join(stalled[:8])}"
                     f"{' ...' if len(stalled) > 8 else ''} for {silence:.0f} s (stalled); ∅ for them")
        if mute:
            self.log(f"coordinator: stage {j}: no Observation from {', '.join(mute[:8])}"
                     f"{' ...' if len(mute) > 8 else ''} within the stage timeout "
                     f"({self.config.stage_timeout_s:.0f} s: revision < 3, no Progress); ∅ for them")

    def _wait_confirms(self, c: Clocked, j: int) -> None:
        """After the last decision: wait for its Confirms from the live carriers, by the stage's
        rule with the confirm timeout ([P-10.3]). Wall clock: at most ``confirm_timeout_s``; sim
        clock: until nothing came from any carrier still unconfirmed for ``silence_timeout_s``."""
        opened = self.clock()
        self._drive(c, lambda now: tm.stage_wait(self.config.clock, *c.state.confirms_awaited(j), c.heard, opened,
                                                 now, self.config.confirm_timeout_s, self.config.silence_timeout_s))

    def _wait_for_carriers(self, c: Clocked) -> None:
        """Before the first stage: wait until every carrier is live with an accepted Hello, by
        :func:`mission.timers.join_wait` ([P-5.11]): the join timeout (on resume at most the stage
        timeout, since some carriers may be gone); on the sim clock it runs from the last carrier
        that joined: a fleet whose processes start slowly on a busy host is waited for while it
        keeps arriving."""
        wait_s = self.config.join_timeout_s
        if c.state.resumed:
            wait_s = resumed_join(wait_s, self.config.stage_timeout_s, self.config.rejoin_timeout_s)

        def count() -> int:
            return sum(1 for cid in c.state.live if cid in c.state.accepted)

        opened = self.clock()
        joined = [count(), opened]  # the most carriers joined so far, and when that many first were

        def rule(now: float):
            if count() > joined[0]:
                joined[:] = [count(), now]
            return tm.join_wait(self.config.clock, c.state.all_joined(), opened, joined[1], now, wait_s)

        self._drive(c, rule)
        missing = sorted(cid for cid in self.spec.carriers if not (cid in c.state.live and cid in c.state.accepted))
        if missing and not self._stop.is_set():
            self.log(f"coordinator: starting without carrier(s) {', '.join(missing)} (not live with a Hello "
                     f"after {wait_s:.0f} s); they can join late")

    def _progress(self, st: ms.MissionState, j: int, waited_ms: float) -> None:
        d = st.decisions[j]
        obs = []
        for r, cid in enumerate(self.spec.carriers):
            if self.spec.valid[r][j]:
                value = st.reported.get((cid, j))
                obs.append(f"{cid}={'∅' if value is None else value}")
        # Confirmations of the previous stage's deployments. Stage numbers count from 0 everywhere
        # (the wire, summary.json, map.png and this line): stage j of 0..N-1.
        confirmed = sorted(cid for (cid, jj), conf in st.confirms.items() if jj == j - 1 and conf.deployed)
        self.log(
            f"stage {j:>3} of 0..{self.spec.n_stages - 1} t={self.spec.stage_times[j]:7.1f} s | "
            f"obs {' '.join(obs) or '-'} | deploy {' '.join(d.deploy) or '-'} | plan {d.planning_ms:7.1f} ms | "
            f"wait {waited_ms:6.0f} ms"
            + (f" | deployed@{j - 1}: {' '.join(confirmed) or '-'}" if j > 0 else "")
        )

    def _stages(self, c: Clocked) -> None:
        last_published = None
        for j in range(c.state.next_stage, self.spec.n_stages):
            if self._stop.is_set():
                return
            if last_published is not None and not c.state.behind(j):
                # Paced like the carriers: Δt / realtime after the previous decision went out
                # (not when the carriers are past j already: then it catches up at once).
                self._drive(c, lambda now: tm.pace(last_published, self.stage_interval, self.config.realtime, now))
            if j > 0 and not c.state.live:
                # Nobody to decide for (cut off, or every carrier gone): deciding now would only
                # record empty stages the carriers decide themselves. Hold until one is back (its
                # Hello says where it is), at most the join timeout [P-6.5].
                self.log(f"coordinator: no carrier is live; holding stage {j} (at most {self.config.join_timeout_s:.0f} s)")
                held = self.clock()
                self._drive(c, lambda now: tm.hold(bool(c.state.live), held, now, self.config.join_timeout_s))
            opened = self.clock()
            self.wait_stage(c, j, opened)
            if self._stop.is_set():
                return
            planning_ms = c.decide(j)  # records, then publishes
            if planning_ms is None:  # deposed
                return
            last_published = self.clock()
            self._progress(c.state, j, (last_published - opened) * 1e3 - planning_ms)
            c.pump(0.0)

    def end(self, c: Clocked, reason: str) -> None:
        """Record End (once), publish it every ``end_repeat_s`` and wait for the live carriers'
        Byes, at most ``bye_timeout_s`` (:func:`mission.timers.end_due`, :func:`mission.timers.bye_wait`,
        [P-9.1]). Runs to its end even when a stop was requested."""
        c.apply(ev.Ended(reason, time.time()))
        # With its epoch (revision 4: a carrier ignores a deposed coordinator's End), in the
        # revision every carrier that said Hello reads, as the Decisions are.
        end = End(self.mission, c.state.next_stage, c.state.end_reason or reason, self.epochs.epoch)
        ended_at, last_put, grace = self.clock(), None, None
        while True:
            now = self.clock()
            if tm.end_due(last_put, ended_at, now, self.config.end_repeat_s, self.config.bye_timeout_s):
                # Repeated for carriers that missed it.
                c.put_end(end)
                last_put = self.clock()
            if grace is None and c.state.all_said_bye():
                grace = now  # one whose token vanished first may have its Bye on the way
            rule = tm.bye_wait(c.state.all_said_bye(), c.state.bye_missing(), ended_at, grace, now,
                               self.config.bye_timeout_s, self.config.bye_grace_s)
            if isinstance(rule, tm.GoOn):
                break
            c.pump(min(POLL_S, rule.until - now))
        self.log(f"coordinator: mission {c.state.end_reason} after {c.state.next_stage} stage(s)")
