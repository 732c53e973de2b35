"""The coordinator's stage clock: the driver of its lifecycle machine
(:mod:`mission.coordinator_life`: the carriers' join, the stages, the last Confirms, End and the
Byes, each wait a rule of :mod:`mission.timers` called by the machine) and the progress line.

Two clocks (docs/fleet.md, "Simulated time and wall time"): on the ``sim`` clock a live carrier
that makes progress is waited for and only a failure (its token gone, or nothing from it for
``silence_timeout_s``: :func:`mission.peers.last_heard`) ends a wait; on the ``wall`` clock the
timeouts are deadlines. :class:`StageClock` is a collaborator of
:class:`coordinator.node.Coordinator`, given its settings when built; it drives the coordinator
through a narrow interface (:class:`Clocked`), handed at each call.
"""
from __future__ import annotations

import dataclasses
import threading
import time
from typing import Callable, Protocol

from mission import coordinator_life as cl
from mission import events as ev
from mission import state as ms
from mission import timers as tm
from mission.timeouts import DEFAULTS, Timeouts
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


def waits_of(config) -> Timeouts:
    """The waits of :mod:`mission.coordinator_life` a coordinator of ``config`` times by."""
    return dataclasses.replace(DEFAULTS, join_s=float(config.join_timeout_s), stage_s=float(config.stage_timeout_s),
                               confirm_s=float(config.confirm_timeout_s), silence_s=float(config.silence_timeout_s),
                               bye_s=float(config.bye_timeout_s), bye_grace_s=float(config.bye_grace_s),
                               end_repeat_s=float(config.end_repeat_s), rejoin_s=config.rejoin_timeout_s)


class StageClock:
    """The driver of the coordinator's lifecycle machine (``life``): :meth:`serve` feeds it the
    clock and carries out its effects on the coordinator.

    Args:
        config: the coordinator's ``CoordinatorConfig`` (its clock, pace and timeouts); spec: the
        :class:`mission.state.MissionSpec`; stage_interval: the mission time between stages (s);
        mission: the mission id; epochs: its ``coordinator.epochs.Epochs`` (the epoch End states);
        stop: its stop request; clock: its clock (s); log: a callable taking one line.
    """

    def __init__(self, config, spec: ms.MissionSpec, stage_interval: float, mission: str, epochs,
                 stop: threading.Event, clock: Callable[[], float], log):
        self.config, self.spec, self.mission = config, spec, mission
        self.epochs, self._stop, self.clock, self.log = epochs, stop, clock, log
        self.life = cl.initial(waits_of(config), config.clock, config.realtime, stage_interval)
        self.end_message: End | None = None

    def serve(self, c: Clocked) -> None:
        """The mission's phases once it is served: the carriers' join, the stages from the first
        undecided one, the last Confirms and End (not when deposed: the newer coordinator ends the
        mission); a resumed complete mission only tells late carriers it is over."""
        self.step(c, cl.Opened(self.clock()))
        self.fly(c)

    def fly(self, c: Clocked, until=None) -> None:
        """Its lifecycle until it is done or deposed (or ``until(life)`` holds). A stop request ends
        the stages with End ``stopped``; the end wait runs to its end. A rule's inputs are the
        mission state, the time and when carriers were heard, and hearing one only delays a wait's
        end: so a :class:`mission.timers.Wait` stands until its ``until`` or a new state (most
        drains apply no event: Progress, Poses, about a thousand a second at R = 1,024)."""
        wake, seen, stopped = None, None, False
        while self.life.phase not in (cl.Phase.DONE, cl.Phase.DEPOSED) and not (until and until(self.life)):
            now = self.clock()
            if self.epochs.deposed_by is not None:  # deposed: the newer coordinator ends the mission
                self.step(c, cl.Deposed())
                break
            if self._stop.is_set() and not stopped:
                stopped, wake = True, None
                self.step(c, cl.Stopped(now))
            if wake is None or c.state is not seen or now >= wake:
                seen, wake = c.state, self.step(c, cl.Tick(now))
                if wake is None:
                    continue
            c.pump(max(0.0, min(POLL_S, wake - now)))

    def step(self, c: Clocked, event) -> float | None:
        """Step the lifecycle and carry out its effects: the time to wait until, None when it is to
        be stepped again at once."""
        self.life, effects = cl.step(self.life, event, cl.View(c.state, c.inbound.heard))
        until = None
        for effect in effects:
            if isinstance(effect, tm.Wait):
                until = effect.until
            else:
                self.run(c, effect)
        return until

    def run(self, c: Clocked, effect) -> None:
        """Carry out one effect of the lifecycle machine."""
        if isinstance(effect, cl.Decide):
            planning_ms = c.decide(effect.stage)  # records, then publishes
            if planning_ms is None:
                self.step(c, cl.Deposed())
                return
            self.step(c, cl.Decided(effect.stage, self.clock(), planning_ms))
            c.pump(0.0)
        elif isinstance(effect, cl.StageLine):
            self._progress(c.state, effect.stage, effect.waited_ms)
        elif isinstance(effect, cl.RecordEnd):
            c.apply(ev.Ended(effect.reason, time.time()))
            # With its epoch (revision 4: a carrier ignores a deposed coordinator's End), in the
            # revision every carrier that said Hello reads, as the Decisions are.
            self.end_message = End(self.mission, c.state.next_stage, c.state.end_reason or effect.reason,
                                   self.epochs.epoch, self.epochs.ident)
        elif isinstance(effect, cl.PublishEnd) and self.end_message is not None:
            c.put_end(self.end_message)
        elif isinstance(effect, cl.Note):
            self.log(effect.line)

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
