"""The coordinator's stage clock: the waits (for the carriers to join, for a stage's
observations, for the last Confirms, for the Byes), the stage loop and the progress line.

Two clocks (docs/fleet.md, "Simulated time and wall time"): on the ``sim`` clock a live carrier
that makes progress is waited for and only a failure (its token gone, or nothing from it for
``silence_timeout_s``: :func:`mission.peers.last_heard`) ends a wait; on the ``wall`` clock the
timeouts are deadlines. :class:`StageClock` is a part of :class:`coordinator.node.Coordinator`.
"""
from __future__ import annotations

import time

from mission import events as ev
from mission.timers import silent
from mission.timeouts import DEFAULTS
from wire import keys
from wire.messages import REVISION, End


class _OfState:
    """``fn(state)`` of the coordinator's current state, computed again only when the state is a
    new object. A wait tests its condition after every inbox drain, and most drains apply no
    event (Progress and Poses arrive every wall second from every carrier, in drains of one or
    two); the conditions are set differences over R carriers (``MissionState.waiting``). The state is
    immutable (mission.state), so the value is the one ``fn`` would give."""

    def __init__(self, owner, fn):
        self._owner, self._fn = owner, fn
        self._state = self._value = None

    def __call__(self):
        state = self._owner.state
        if state is not self._state:
            self._state, self._value = state, self._fn(state)
        return self._value


def _by_progress(state, cids) -> tuple[frozenset, frozenset]:
    """``cids`` as (those that send Progress, those of revision < 3 that send none)."""
    mute = state.without_progress(cids)
    return frozenset(cids).difference(mute), mute


class StageClock:
    """The coordinator's waits and its stage loop."""

    def _wait(self, seconds: float, done=lambda: False) -> None:
        """Handle inbound items for up to ``seconds`` or until ``done()`` or a stop request."""
        deadline = time.monotonic() + seconds
        while not self._stop.is_set() and not done():
            left = deadline - time.monotonic()
            if left <= 0:
                return
            self.pump(min(0.05, left))

    def _wait_stage(self, j: int, opened: float) -> None:
        """Until every expected carrier's Observation of j is in, or a stop request. Wall clock:
        at most ``stage_timeout_s``. Sim clock: as long as some carrier still waited for is
        making progress: one that nothing came from for ``silence_timeout_s`` (since the stage
        opened) is stalled and not waited for any more; a dead or cut-off one leaves
        ``expected`` by itself when its token vanishes."""
        waiting_for = _OfState(self, lambda state: state.waiting(j))
        if self.config.clock == "wall":
            self._wait(self.config.stage_timeout_s, lambda: not waiting_for())
            return
        silence = self.config.silence_timeout_s
        split = _OfState(self, lambda state: _by_progress(state, state.waiting(j)))

        def done() -> bool:
            return self._waited(split(), opened, self.config.stage_timeout_s)

        while not self._stop.is_set() and not done():
            self.pump(0.05)
        stalled, mute = (sorted(group) for group in split())
        if stalled and not self._stop.is_set():
            self.log(f"coordinator: stage {j}: nothing from {', '.join(stalled[:8])}"
                     f"{' ...' if len(stalled) > 8 else ''} for {silence:.0f} s (stalled); ∅ for them")
        if mute and not self._stop.is_set():
            self.log(f"coordinator: stage {j}: no Observation from {', '.join(mute[:8])}"
                     f"{' ...' if len(mute) > 8 else ''} within the stage timeout "
                     f"({self.config.stage_timeout_s:.0f} s: revision < 3, no Progress); ∅ for them")

    def _wait_confirms(self, j: int) -> None:
        """After the last decision: wait for its Confirms from the live carriers. Wall clock: at
        most ``confirm_timeout_s``; sim clock: until nothing came from any carrier still
        unconfirmed for ``silence_timeout_s``."""
        unconfirmed = _OfState(self, lambda state: state.unconfirmed(j))
        if self.config.clock == "wall":
            self._wait(self.config.confirm_timeout_s, lambda: not unconfirmed())
            return
        split = _OfState(self, lambda state: _by_progress(state, state.unconfirmed(j)))
        opened = time.monotonic()
        while not self._stop.is_set():
            if self._waited(split(), opened, self.config.confirm_timeout_s):
                return
            self.pump(0.05)

    def _waited(self, split, opened: float, deadline_s: float) -> bool:
        """Sim clock: the wait opened at ``opened`` for ``split`` (carriers that send Progress,
        carriers that send none) is over: the first are silent (:meth:`_silent`), and for the
        second the wall-clock ``deadline_s`` passed (docs/protocol.md, [P-10.4]: a carrier of
        revision < 3 is never taken as stalled for lack of Progress)."""
        loud, mute = split
        return ((not loud or self._silent(loud, opened))
                and (not mute or time.monotonic() - opened >= deadline_s))

    def _silent(self, waiting, opened: float) -> bool:
        """Sim clock: nothing came from any of ``waiting`` for ``silence_timeout_s``, counted from
        ``opened`` at the earliest (:func:`mission.timers.silent`: the last time heard is never before it, so the
        O(|waiting|) look is skipped until that much time has passed since the wait opened)."""
        return silent(self.heard, waiting, opened, time.monotonic(), self.config.silence_timeout_s)

    def _wait_for_carriers(self) -> None:
        """Before the first stage: wait until every carrier is live with an accepted Hello (or the
        join timeout; on resume at most the stage timeout, since some carriers may be gone). On
        the sim clock the join timeout runs from the last carrier that joined: a fleet whose
        processes start slowly on a busy host is waited for while it keeps arriving."""
        wait_s = self.config.join_timeout_s
        if self.state.resumed:
            wait_s = min(wait_s, self.config.stage_timeout_s)
        def count() -> int:
            return sum(1 for cid in self.state.live if cid in self.state.accepted)

        joined = -1
        while not self._stop.is_set() and not self.state_all_joined() and count() > joined:
            joined = count()
            self._wait(wait_s, lambda: self.state_all_joined() or (self.config.clock == "sim" and count() > joined))
            if self.config.clock == "wall":
                break
        missing = sorted(cid for cid in self.ids if not (cid in self.state.live and cid in self.state.accepted))
        if missing and not self._stop.is_set():
            self.log(f"coordinator: starting without carrier(s) {', '.join(missing)} (not live with a Hello "
                     f"after {wait_s:.0f} s); they can join late")

    def state_all_joined(self) -> bool:
        return self.state.all_joined()

    def _progress(self, j: int, waited_ms: float) -> None:
        st, d = self.state, self.state.decisions[j]
        obs = []
        for r, cid in enumerate(self.ids):
            if self.spec.valid[r][j]:
                value = st.reported.get((cid, j))
                obs.append(f"{cid}={'∅' if value is None else value}")
        # Confirmations of the previous stage's deployments (stage numbers 1-based, as printed).
        confirmed = sorted(cid for (cid, jj), c in st.confirms.items() if jj == j - 1 and c.deployed)
        self.log(
            f"stage {j + 1:>3}/{self.n_stages} t={self.spec.stage_times[j]:7.1f} s | obs {' '.join(obs) or '-'} | "
            f"deploy {' '.join(d.deploy) or '-'} | plan {d.planning_ms:7.1f} ms | "
            f"wait {waited_ms:6.0f} ms"
            + (f" | deployed@{j}: {' '.join(confirmed) or '-'}" if j > 0 else "")
        )

    def _stages(self) -> None:
        last_published = None
        for j in range(self.state.next_stage, self.n_stages):
            if self._stop.is_set():
                return
            if self.config.realtime > 0 and last_published is not None and not self.state.behind(j):
                # Paced like the carriers: Δt / realtime after the previous decision went out
                # (not when the carriers are past j already: then it catches up at once).
                self._wait(last_published + self.scenario.stage_interval / self.config.realtime - time.monotonic())
            if j > 0 and not self.state.live:
                # Nobody to decide for (cut off, or every carrier gone): deciding now would only
                # record empty stages the carriers decide themselves. Hold until one is back (its
                # Hello says where it is), at most the join timeout.
                self.log(f"coordinator: no carrier is live; holding stage {j} (at most {self.config.join_timeout_s:.0f} s)")
                self._wait(self.config.join_timeout_s, lambda: bool(self.state.live))
            opened = time.monotonic()
            self._wait_stage(j, opened)
            if self._stop.is_set():
                return
            deploy, planning_ms, passengers = self._plan(j)
            newer = self.store.newer_epoch()  # a standby took over on our disk while we were cut off
            if newer is not None:
                self._deposed(newer, "mission.db records it")
                return
            self.apply(ev.Decided(j, deploy, planning_ms, time.time(), passengers))  # records, then publishes
            last_published = time.monotonic()
            self._progress(j, (last_published - opened) * 1e3 - planning_ms)
            self.pump(0.0)

    def _end(self, reason: str) -> None:
        """Record End (once), publish it every ``end_repeat_s`` and wait for the live carriers'
        Byes, at most ``bye_timeout_s``. Runs to its end even when a stop was requested."""
        self.apply(ev.Ended(reason, time.time()))
        # With its epoch (revision 4: a carrier ignores a deposed coordinator's End), in the
        # revision every carrier that said Hello reads, as the Decisions are.
        end = End(self.mission, self.state.next_stage, self.state.end_reason or reason, self.epoch)
        deadline = time.monotonic() + self.config.bye_timeout_s
        last_put = grace = None
        while time.monotonic() < deadline:
            if last_put is None or time.monotonic() - last_put >= DEFAULTS.end_repeat_s:
                # Repeated for carriers that missed it.
                self.node.put(keys.end_key(self.mission), end, self.state.common_revision(REVISION))
                last_put = time.monotonic()
            if self.state.all_said_bye():
                # Every live carrier said Bye; one whose token vanished first may have its Bye on the way.
                grace = grace or time.monotonic() + DEFAULTS.bye_grace_s
                if not self.state.bye_missing() or time.monotonic() >= grace:
                    break
            self.pump(0.05)
        self.log(f"coordinator: mission {self.state.end_reason} after {self.state.next_stage} stage(s)")
