"""The fleet's timer rules as pure functions of what is known and of the time (docs/protocol.md,
"Time", [P-10.n]; docs/architecture.md, "Time as an input").

Nothing here reads a clock. A driver (a carrier or coordinator process, or the deterministic
simulator, :mod:`mission.simulate`) passes the time an event happened at, or the time of a
tick, and carries out the effect returned: :class:`Wait` (nothing to do before ``until``; the
driver sleeps or schedules a tick then, or acts on the next message heard earlier), or the action
the rule calls for. Each rule is a row of tests/test_timers.py.

Times are seconds on the caller's clock (a process's monotonic clock, a simulated host's clock);
only differences of two times of one clock are taken.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from .peers import last_heard
from .modes import Mode


# --------------------------------------------------------------------------- effects

@dataclass(frozen=True)
class Wait:
    """Nothing to do before ``until`` (``math.inf``: until something is heard)."""

    until: float = math.inf


def drive(steps, handle):
    """Carry out what a generator of requests asks (a collaborator's waits and events, e.g. the
    operator's hold or a carrier's join path): each request handled by ``handle(request)``, whose
    result is sent back to it; what the generator returns. The generator holds no driver and calls
    nothing back: the driver owns the I/O."""
    reply = None
    while True:
        try:
            request = steps.send(reply)
        except StopIteration as done:
            return done.value
        reply = handle(request)


@dataclass(frozen=True)
class GoOn:
    """The wait is over. ``stalled``: those waited for taken as stalled (nothing from them for the
    silence timeout, sim clock); ``late``: those past a deadline (wall clock, or a carrier that
    sends no Progress)."""

    stalled: frozenset = frozenset()
    late: frozenset = frozenset()


@dataclass(frozen=True)
class AskState:
    """Sim clock, a long wait for a Decision: ask the coordinator's State (a Decision lost in a
    reconnection is recovered) and go on waiting ([P-10.8])."""


@dataclass(frozen=True)
class DecideAlone:
    """Decide the stage on board ([P-8.1]): no coordinator to wait for, or (wall clock) none in
    time."""


@dataclass(frozen=True)
class MoveOn:
    """A coordinated carrier on the wall clock: no Decision in time, go on without deploying."""


@dataclass(frozen=True)
class GiveUp:
    """End this participant's mission: ``reason`` (``coordinator-lost``)."""

    reason: str


@dataclass(frozen=True)
class TakeOver:
    """A standby coordinator: the primary is gone; open the mission with a new epoch."""


@dataclass(frozen=True)
class Attempt:
    """Try (again) now: open the session, or query State ([P-5.2])."""


# --------------------------------------------------------------------------- silence

def silent(heard, among, opened: float, now: float, silence_s: float) -> bool:
    """Nothing came from any of ``among`` for ``silence_s`` since the wait opened at ``opened``
    ([P-10.3], [P-10.5]); the O(|among|) look is skipped until that much time has passed since then."""
    return now - opened >= silence_s and now - last_heard(heard, among, opened) >= silence_s


# --------------------------------------------------------------------------- coordinator

def stage_wait(clock: str, loud, mute, heard, opened: float, now: float, stage_s: float,
               silence_s: float) -> Wait | GoOn:
    """The coordinator's wait for a stage's Observations, opened at ``opened`` ([P-10.3], [P-10.4]).

    ``loud``: the carriers still waited for that send Progress; ``mute``: those of a revision
    before Progress. Wall clock: the stage timeout is a deadline for all. Sim clock: a live
    carrier that makes progress is waited for as long as it takes; the loud ones end the wait by
    their silence, the mute ones by the stage timeout (their silence says nothing)."""
    loud, mute = frozenset(loud), frozenset(mute)
    if not loud and not mute:
        return GoOn()
    if clock == "wall":
        return GoOn(late=loud | mute) if now - opened >= stage_s else Wait(opened + stage_s)
    loud_done = not loud or silent(heard, loud, opened, now, silence_s)
    mute_done = not mute or now - opened >= stage_s
    if loud_done and mute_done:
        return GoOn(stalled=loud, late=mute)
    until = []
    if not loud_done:
        until.append(last_heard(heard, loud, opened) + silence_s)
    if not mute_done:
        until.append(opened + stage_s)
    return Wait(min(until))


def join_wait(clock: str, all_joined: bool, opened: float, last_join: float, now: float,
              join_s: float) -> Wait | GoOn:
    """Before stage 0: wait for every carrier's token and Hello ([P-5.11]). Wall clock: at most
    ``join_s`` from ``opened``; sim clock: ``join_s`` from the last carrier that joined
    (``last_join``), so a fleet starting slowly on a busy host is waited for while it arrives."""
    if all_joined:
        return GoOn()
    since = opened if clock == "wall" else max(opened, last_join)
    return GoOn() if now - since >= join_s else Wait(since + join_s)


def bye_wait(all_live_said_bye: bool, bye_missing: bool, ended_at: float, grace_from: float | None,
             now: float, bye_s: float, grace_s: float) -> Wait | GoOn:
    """After End: wait for the live carriers' Byes, at most ``bye_s`` from ``ended_at``; once
    every live carrier said Bye, a carrier whose token vanished without one gets ``grace_s`` more
    from ``grace_from`` (when that happened): its Bye and its token's end travel apart
    ([P-9.1])."""
    if now - ended_at >= bye_s:
        return GoOn()
    if all_live_said_bye and (not bye_missing or (grace_from is not None and now - grace_from >= grace_s)):
        return GoOn()
    if all_live_said_bye and grace_from is not None:
        return Wait(min(ended_at + bye_s, grace_from + grace_s))
    return Wait(ended_at + bye_s)


def end_due(last: float | None, ended_at: float, now: float, repeat_s: float, bye_s: float) -> bool:
    """End goes out again ([P-9.1]): first at once, then every ``repeat_s`` while the Bye wait
    opened at ``ended_at`` lasts (``bye_s``)."""
    return last is None or (now - ended_at < bye_s and due(last, now, repeat_s))


def standby(primary_present: bool, lost_at: float | None, now: float, poll_s: float) -> Wait | TakeOver:
    """A standby coordinator: take over once the primary's token has been gone at one look
    (``lost_at``: when its loss was noticed); looks again every ``poll_s``."""
    if primary_present or lost_at is None:
        return Wait(now + poll_s)
    return TakeOver()


# --------------------------------------------------------------------------- carrier

def decision_wait(clock: str, mode: str, present: bool, waited_s: float, absent_s: float,
                  decision_s: float, coordinator_s: float):
    """A carrier's wait for a stage's Decision ([P-10.8], [P-8.1]).

    Args:
        clock: ``sim`` or ``wall``; mode: ``coordinated``, ``hybrid`` or ``decentralised``.
        present: the coordinator's token is present.
        waited_s: how long it waited while the coordinator was present, since it opened the wait
            (sim clock: or last asked State): :class:`DecisionWait`.
        absent_s: how long the coordinator has been absent (0 while present).

    Returns :class:`DecideAlone` (decentralised; hybrid without a coordinator; wall clock, none
    in time), :class:`MoveOn` (coordinated, wall clock, none in time), :class:`AskState` (sim
    clock, ``decision_s`` waited: ask again, wait on), :class:`GiveUp` (the coordinator absent
    for ``coordinator_s``, coordinated) or :class:`Wait`."""
    if mode == Mode.DECENTRALISED:
        return DecideAlone()
    if present:
        if waited_s < decision_s:
            return Wait()
        if clock == "sim":
            return AskState()
        return MoveOn() if mode == Mode.COORDINATED else DecideAlone()
    if mode == Mode.HYBRID:
        return DecideAlone()
    if absent_s >= coordinator_s:
        return GiveUp("coordinator-lost")
    return Wait()


def outranked(rejected_at: float, now: float, grace_s: float) -> Wait | GoOn:
    """A live coordinator whose Decision (or End) the carrier rejected as deposed ([P-7.2]: a lower
    ballot) is waited for ``grace_s`` more (the decision timeout: a current coordinator's Decision
    may follow the stale one, two coordinators live across a healed split); :class:`GoOn` once it
    has not been heard for that long: absent since the rejection."""
    if now - rejected_at < grace_s:
        return Wait(rejected_at + grace_s)
    return GoOn()


@dataclass(frozen=True)
class DecisionWait:
    """What a carrier's wait for a Decision has counted ([P-10.8]): ``waited_s``, the time the
    coordinator's token was present since the wait opened or State was last asked, up to
    ``last`` (when it last looked). An interval counts as present when the token is present at
    its end (the carrier notes a vanished token as it happens: the interval it was present in
    ends then). Wall clock: the sum runs across absences; sim clock: it starts again at each
    State query (:meth:`asked`)."""

    waited_s: float
    last: float

    @classmethod
    def opened(cls, now: float) -> "DecisionWait":
        return cls(0.0, now)

    def tick(self, now: float, present: bool) -> "DecisionWait":
        return DecisionWait(self.waited_s + (now - self.last if present else 0.0), now)

    def asked(self) -> "DecisionWait":
        return DecisionWait(0.0, self.last)


def hello_again(unanswered: bool, answers: bool, present: bool, sent: float, tries: int, now: float,
                retry_s: float) -> Wait | Attempt:
    """A carrier's latest Hello, sent at ``sent``, has no answer ([P-5.14]): say it again (:class:`Attempt`)
    ``retry_s * 2**tries`` after it went out (``tries``: the Hellos said again since the last one a
    join or a Resync sent), so the interval doubles and a mission of any length says it a few
    times at most. Nothing to wait for when it was answered (``unanswered`` False), when the
    coordinator sends no answers (``answers`` False: its State announced revision 1 or 2), or while
    its token is absent (``present`` False: its return is a Resync, which says Hello anyway)."""
    if not (unanswered and answers and present):
        return Wait()
    due_at = sent + retry_s * 2 ** tries
    return Attempt() if now >= due_at else Wait(due_at)


def peer_wait(clock: str, waiting, heard, opened: float, now: float, peer_s: float,
              silence_s: float) -> Wait | GoOn:
    """A carrier deciding stage j alone waits for the Observations of j of its live peers
    (``waiting``: those not heard yet) from ``opened`` ([P-8.4]): wall clock, at most ``peer_s``;
    sim clock, while any of them is heard from (until the silence timeout passed since the wait
    opened and since the last message of any of them). The coordinator's stage wait with every
    peer sending Progress."""
    return stage_wait(clock, waiting, (), heard, opened, now, peer_s, silence_s)


def end_wait(ended: bool, present: bool, opened: float, now: float, end_s: float) -> Wait | GoOn:
    """A carrier past its last stage waits for End ([P-9.5]): at most ``end_s`` from ``opened``
    when the coordinator's token was present then (``present``), not at all when it was absent."""
    if ended or not present or now - opened >= end_s:
        return GoOn()
    return Wait(opened + end_s)


def retry(first: float, failed: float | None, now: float, timeout_s: float,
          retry_s: float) -> Attempt | Wait | GiveUp:
    """Something tried until it works, at most ``timeout_s`` from the first try at ``first``:
    again ``retry_s`` after the last failure (``failed``; None: not tried yet), then
    :class:`GiveUp` (``timeout``). Opening a session, querying State ([P-5.2])."""
    if now - first >= timeout_s:
        return GiveUp("timeout")
    if failed is None or now - failed >= retry_s:
        return Attempt()
    return Wait(min(failed + retry_s, first + timeout_s))


def state_query(mode: str, first: float, failed: float | None, now: float, coordinator_s: float,
                retry_s: float) -> AskState | Wait | DecideAlone | GiveUp:
    """A joining carrier's State query ([P-5.2], [P-5.5] 4): asked again ``retry_s`` after one got
    no reply, until the coordinator timeout passed since the first; then a hybrid carrier goes
    on from its own log (:class:`DecideAlone`) and a coordinated one exits (``coordinator-lost``)."""
    rule = retry(first, failed, now, coordinator_s, retry_s)
    if isinstance(rule, Attempt):
        return AskState()
    if isinstance(rule, GiveUp):
        return DecideAlone() if mode == Mode.HYBRID else GiveUp("coordinator-lost")
    return rule


def pace(since: float, sim_s: float, realtime: float, now: float) -> Wait | GoOn:
    """A paced mission (``realtime`` F > 0): ``sim_s`` simulated seconds after the wall time
    ``since`` are due at ``since + sim_s / F`` (a carrier's physics, the coordinator's next stage
    after its last Decision); unpaced (F <= 0) at once."""
    if realtime <= 0:
        return GoOn()
    until = since + sim_s / realtime
    return GoOn() if now >= until else Wait(until)


def hold(live: bool, opened: float, now: float, join_s: float) -> Wait | GoOn:
    """The coordinator holds a stage j > 0 while no carrier is live ([P-6.5]): until one is, at
    most ``join_s`` from ``opened``."""
    if live or now - opened >= join_s:
        return GoOn()
    return Wait(opened + join_s)


def lapses(silent_from: float, until: float, lease_s: float) -> bool:
    """A session silent from ``silent_from`` to ``until`` (a stopped or frozen process) lapses:
    silent for longer than its Zenoh lease, its liveliness token vanishes a lease after it fell
    silent (and a process that runs again has it back). The simulated network's model of the
    lease (:mod:`mission.simulate.injector`)."""
    return until - silent_from > lease_s


def due(last: float | None, now: float, interval_s: float) -> bool:
    """A periodic message (Progress [P-10.6], Pose, End's repetition [P-9.1]) is due: never sent, or ``interval_s``
    since the last one (an interval of 0 or less: never periodic)."""
    return interval_s > 0 and (last is None or now - last >= interval_s)
