"""A carrier's lifecycle as a pure machine: the phase is state, time is an input, every wait is a
rule of :mod:`mission.timers` and the waiting itself is an effect (:class:`mission.timers.Wait`).

``step(life, event, view) -> (life, effects)``, etcd raft's shape: the carrier process
(carriers/node.py) and the deterministic simulator (mission/simulate/carrier.py) are drivers that
read their clock and network, feed :class:`Tick` and the few lifecycle events below, and carry out
the effects in order; neither compares two times of its own. The stage handshake (what a Decision
does, at most once per stage) is :mod:`mission.carrier`'s machine, which the driver steps when an
effect here says so (:class:`Observe`, :class:`Pass`, :class:`DecideOnBoard`, :class:`MoveOn`);
this machine reads it through :class:`View` and never changes it.

Phases (docs/architecture.md, "The carrier's lifecycle"):

==========  =====================================================  ==============================
phase       what it waits for (rule)                               leaves to
==========  =====================================================  ==============================
joining     a State reply ([P-5.2] :func:`~mission.timers.state_query`)  started (answered), gathering
                                                                   (hybrid, none in time), done
gathering   the peers' tokens ([P-8.5] :func:`~mission.timers.join_wait`) started
started     nothing (the handshake machine joined)                 work, end
work        its body at t_j (:class:`Drive`, :class:`Arrived`)     wait, work (behind: passed)
wait        the Decision of j ([P-10.8] :func:`~mission.timers.decision_wait`)  work, alone, done
alone       its peers' Observations of j ([P-8.4] :func:`~mission.timers.peer_wait`)  work
end         End ([P-9.5] :func:`~mission.timers.end_wait`)         done
done        nothing                                                -
==========  =====================================================  ==============================

In every phase but done, a Hello without an answer is said again ([P-5.14]
:func:`~mission.timers.hello_again`).
"""
from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field
from typing import Any

from . import carrier as mc
from . import timers as tm
from .evolve import evolve
from .timeouts import STATE_RETRY_S, Timeouts
from .modes import Mode


class Phase(str, enum.Enum):
    JOINING = "joining"
    GATHERING = "gathering"
    STARTED = "started"
    WORK = "work"
    WAIT = "wait"
    ALONE = "alone"
    END = "end"
    DONE = "done"


# --------------------------------------------------------------------------- events

@dataclass(frozen=True)
class Start:
    """The process started (or restarted on its log) at ``now``."""

    now: float


@dataclass(frozen=True)
class Tick:
    """The driver's look at its clock: ``now`` (s)."""

    now: float


@dataclass(frozen=True)
class Answered:
    """A State answered the join and the driver joined from it (the handshake machine is flying,
    or ended): the stages begin."""

    now: float


@dataclass(frozen=True)
class Arrived:
    """The body reached t_j of the stage it was driving to (:class:`Drive`)."""

    stage: int
    now: float


@dataclass(frozen=True)
class Stopped:
    """A stop request (SIGINT/SIGTERM): say Bye and end."""

    now: float


# --------------------------------------------------------------------------- effects

@dataclass(frozen=True)
class Query:
    """Ask the coordinator's State to join ([P-5.2]); its reply is the driver's to take (the join
    from State, then :class:`Answered`); none within ``state_query_s``: this machine asks again."""


@dataclass(frozen=True)
class AskState:
    """Sim clock, a long wait for the Decision of ``stage``: ask State ([P-10.8]) and take what it
    says (:class:`mission.carrier.Collecting` or :class:`mission.carrier.Resync`)."""

    stage: int


@dataclass(frozen=True)
class JoinAlone:
    """No coordinator to join from (decentralised, or none answered: hybrid): go on from the
    durable log (its deployments replayed) and listen to the peers; then :class:`Gathered`."""


@dataclass(frozen=True)
class Gathered:
    """The wait for the peers' tokens is over (some may have none): the handshake machine joins at
    the stage after the last its log resolved (:class:`mission.carrier.Joined`). ``resync``: a
    hybrid carrier whose coordinator's token came while no State answered (its State query timed
    out as the token came back): the coordinator is back, resynchronise from its State at once
    ([P-5.12]; without it the carrier, its return already seen, went on alone and never said
    Hello)."""

    resync: bool = False


@dataclass(frozen=True)
class Drive:
    """Drive the body to t of ``stage`` (paced when ``paced`` and the mission is paced); the
    driver tells :class:`Arrived` when it is there."""

    stage: int
    paced: bool


@dataclass(frozen=True)
class Observe:
    """Sense at ``stage``, step the handshake machine with :class:`mission.carrier.Observed` and
    publish the Observation."""

    stage: int


@dataclass(frozen=True)
class Pass:
    """``stage`` was decided without this carrier (it is behind): step the handshake machine with
    :class:`mission.carrier.Passed` and go on at once."""

    stage: int


@dataclass(frozen=True)
class Listen:
    """Deciding alone from now on: subscribe to the peers' messages and tokens."""


@dataclass(frozen=True)
class DecideOnBoard:
    """Run the on-board planner on what the carrier heard and step the handshake machine with
    :class:`mission.carrier.DecidedOwn` for ``stage``."""

    stage: int


@dataclass(frozen=True)
class MoveOn:
    """``stage`` is over for this carrier: step the handshake machine with
    :class:`mission.carrier.MovedOn`. ``answered``: a Decision resolved it (a spell of deciding
    alone ends)."""

    stage: int
    answered: bool = False


@dataclass(frozen=True)
class SendProgress:
    """Sim clock: publish Progress for ``stage`` ([P-10.6])."""

    stage: int


@dataclass(frozen=True)
class RepeatObservation:
    """Sim clock, deciding alone: publish the Observation of ``stage`` again for the peers that
    wait for it as it waits for theirs (an identical repeat is absorbed)."""

    stage: int


@dataclass(frozen=True)
class SayHelloAgain:
    """The latest Hello had no answer: step the handshake machine with
    :class:`mission.carrier.HelloUnanswered` ([P-5.14])."""


@dataclass(frozen=True)
class Finish:
    """End this carrier's mission: say Bye with ``reason`` (a key of carriers/exits.py)."""

    reason: str


@dataclass(frozen=True)
class Note:
    """A line for the carrier's log."""

    line: str


# --------------------------------------------------------------------------- what it reads

@dataclass(frozen=True)
class Hello:
    """The coordinator's answer to the latest Hello, as :func:`mission.timers.hello_again` reads it:
    ``unanswered`` (one went out without an answer yet), ``answers`` (the coordinator answers
    Hellos: revision 3 or later), ``at`` (when it went out), ``tries`` (said again since)."""

    unanswered: bool = False
    answers: bool = True
    at: float = 0.0
    tries: int = 0


@dataclass(frozen=True)
class View:
    """What the driver knows at the step, read and never changed by this machine.

    Attributes:
        machine: the handshake machine (:class:`mission.carrier.Handshake`).
        present: the coordinator's token is present (or it answered since it vanished).
        absent_since: since when it is absent (s, the driver's clock).
        timers: what the carrier times its waits by (:class:`mission.carrier.Timers`).
        peers_live: the peers whose token is present; heard: peer id -> when something last came.
        book: the :class:`mission.peers.PeerBook` (whose Observation of j is still awaited).
        gathered: every peer listened to has a token (joining alone).
        hello: :class:`Hello`.
    """

    machine: mc.Handshake
    present: bool
    absent_since: float
    timers: mc.Timers
    peers_live: frozenset = frozenset()
    heard: Any = field(default_factory=dict)
    book: Any = None
    gathered: bool = True
    hello: Hello = Hello()


# --------------------------------------------------------------------------- state

@dataclass(frozen=True)
class Life:
    """A carrier's lifecycle (see the module's phase table).

    Attributes:
        mode: ``hybrid``, ``decentralised`` or ``coordinated``; waits: its :class:`Timeouts`.
        phase: :class:`Phase`; stage: the stage of work/wait/alone.
        opened: when the phase (joining: the first query; gathering, alone, end) opened (s).
        asked: when the outstanding State query went out (joining; None: none outstanding).
        failed: when the latest query of the join went unanswered (None: none did yet).
        driving: work: :class:`Drive` went out for ``stage``; at_once: the next stage is not paced.
        wait: wait: :class:`mission.timers.DecisionWait`.
        end_present: end: the coordinator was present when the wait for End opened.
        progress_at: when Progress last went out; repeated_at: when the Observation was last
            repeated to the peers (alone); deciding: in a spell of deciding alone.
        reason: done: why it ended.
        outranked_at: when the handshake machine found the live coordinator outranked
            (:attr:`mission.carrier.Handshake.outranked`; None: it is not): absent since then.
    """

    mode: str
    waits: Timeouts
    phase: Phase = Phase.DONE
    stage: int = 0
    opened: float = 0.0
    asked: float | None = None
    failed: float | None = None
    driving: bool = False
    at_once: bool = True
    wait: tm.DecisionWait = tm.DecisionWait(0.0, 0.0)
    end_present: bool = False
    progress_at: float | None = None
    repeated_at: float | None = None
    deciding: bool = False
    reason: str | None = None
    outranked_at: float | None = None


def initial(mode: str, waits: Timeouts) -> Life:
    return Life(mode, waits)


# --------------------------------------------------------------------------- step

def step(life: Life, event, view: View) -> tuple[Life, tuple]:
    """One event (:class:`Start`, :class:`Tick`, :class:`Answered`, :class:`Arrived`,
    :class:`Stopped`) at its time: the new life and the effects, in order. The last effect is a
    :class:`mission.timers.Wait` when there is nothing to do before its ``until``; without one the
    driver steps again at once (something changed)."""
    if isinstance(event, Start):
        return _start(life, event.now)
    if life.phase is Phase.DONE:
        return life, (tm.Wait(),)
    if isinstance(event, Stopped):
        return _finish(life, "stopped")
    if isinstance(event, Answered):
        return evolve(life, phase=Phase.STARTED, asked=None), ()
    if isinstance(event, Arrived):
        return _arrived(life, event, view)
    if isinstance(event, Tick):
        life, effects = _PHASES[life.phase](life, event.now, view)
        if not effects or not isinstance(effects[-1], tm.Wait):
            return life, effects
        again = _hello_again(life, event.now, view)
        if isinstance(again, tm.Attempt):
            return life, (*effects[:-1], SayHelloAgain())
        until = min(effects[-1].until, again.until)
        return life, (*effects[:-1], tm.Wait(until))
    raise TypeError(f"not a carrier lifecycle event: {event!r}")


def _start(life: Life, now: float):
    life = evolve(Life(life.mode, life.waits), opened=now)
    if life.mode == Mode.DECENTRALISED:
        return evolve(life, phase=Phase.GATHERING), (JoinAlone(),)
    return evolve(life, phase=Phase.JOINING, asked=now), (Query(),)


def _finish(life: Life, reason: str, *notes) -> tuple[Life, tuple]:
    return evolve(life, phase=Phase.DONE, reason=reason), (*notes, Finish(reason))


def _hello_again(life: Life, now: float, view: View):
    if life.phase in (Phase.JOINING, Phase.GATHERING):
        return tm.Wait()
    h = view.hello
    return tm.hello_again(h.unanswered, h.answers, view.present, h.at, h.tries, now, life.waits.hello_s)


def _joining(life: Life, now: float, view: View):
    w = life.waits
    failed = life.failed
    if life.asked is not None:  # a query is out: its reply, or none within state_query_s
        until = life.asked + w.state_query_s
        if now < until:
            return life, (tm.Wait(until),)
        failed = until
        life = evolve(life, asked=None, failed=failed)
    rule = tm.state_query(life.mode, life.opened, failed, now, w.coordinator_s, STATE_RETRY_S)
    if isinstance(rule, tm.AskState):
        return evolve(life, asked=now), (Query(),)
    if isinstance(rule, tm.DecideAlone):
        note = Note(f"no coordinator answered within {w.coordinator_s:.0f} s; going on without it")
        return evolve(life, phase=Phase.GATHERING, opened=now), (note, JoinAlone())
    if isinstance(rule, tm.GiveUp):
        return _finish(life, rule.reason, Note(f"no coordinator answered within {w.coordinator_s:.0f} s"))
    return life, (rule,)


def _gathering(life: Life, now: float, view: View):
    rule = tm.join_wait("wall", view.gathered, life.opened, life.opened, now, life.waits.join_s)
    if isinstance(rule, tm.Wait):
        return life, (rule,)
    return evolve(life, phase=Phase.STARTED), (Gathered(resync=life.mode == Mode.HYBRID and view.present),)


def _started(life: Life, now: float, view: View):
    m = view.machine
    if m.ended or m.stage >= m.n_stages:
        return _to_end(life, now, view)
    return evolve(life, phase=Phase.WORK, stage=m.stage, driving=False, at_once=True), ()


def _to_end(life: Life, now: float, view: View):
    return evolve(life, phase=Phase.END, opened=now, end_present=view.present), ()


def _stage_ended(life: Life, now: float, view: View):
    """End came while the carrier was at a stage: it leaves the stage and waits for nothing more."""
    life, _ = _to_end(life, now, view)
    return life, (MoveOn(life.stage),)


def _progress(life: Life, now: float, view: View, every_s: float) -> tuple[Life, tuple]:
    """Progress when due on the sim clock ([P-10.6]), and when the next one is due."""
    if view.timers.clock != "sim" or every_s <= 0:
        return life, ()
    if tm.due(life.progress_at, now, every_s):
        return evolve(life, progress_at=now), (SendProgress(life.stage),)
    return life, ()


def _next_progress(life: Life, view: View, every_s: float) -> float:
    if view.timers.clock != "sim" or every_s <= 0 or life.progress_at is None:
        return math.inf
    return life.progress_at + every_s


def _work(life: Life, now: float, view: View):
    m = view.machine
    if m.ended:
        return _to_end(life, now, view)
    j = life.stage
    if j >= m.n_stages:
        return _to_end(life, now, view)
    if not life.driving:
        paced = not (life.at_once or m.behind(j))
        return evolve(life, driving=True), (Drive(j, paced),)
    life, sent = _progress(life, now, view, life.waits.progress_s)
    return life, (*sent, tm.Wait(_next_progress(life, view, life.waits.progress_s)))


def _arrived(life: Life, e: Arrived, view: View):
    m = view.machine
    if life.phase is not Phase.WORK or e.stage != life.stage:
        return life, ()
    if m.ended:
        return _to_end(life, e.now, view)
    j = e.stage
    if m.behind(j):
        # decided without its Observation (cut off, or too slow): nothing to publish, go on at once
        return evolve(life, stage=j + 1, driving=False, at_once=True), (Pass(j),)
    return (evolve(life, phase=Phase.WAIT, driving=False, at_once=False,
                   wait=tm.DecisionWait.opened(e.now)), (Observe(j),))


def _resolved(life: Life, now: float, view: View):
    """The stage needs nothing more of this carrier: leave it (End: wait for nothing more)."""
    m, j = view.machine, life.stage
    answered = m.resolved(j)
    life = evolve(life, phase=Phase.WORK, stage=j + 1, driving=False,
                  deciding=life.deciding and not answered)
    return life, (MoveOn(j, answered),)


def _deciding_coordinator(life: Life, now: float, view: View) -> tuple[Life, View, float]:
    """A coordinator whose Decisions the handshake machine rejects as deposed (a lower ballot:
    it restarted on a stale disk after a standby's takeover) decides nothing for this carrier:
    unless a current Decision or State comes within the decision timeout of the first rejection
    (:func:`mission.timers.outranked`), it is absent since that rejection, whatever its token
    says (docs/protocol.md [P-7.2]). Also when to look again (inf: nothing to wait for)."""
    if not (view.machine.outranked and view.present):
        return (evolve(life, outranked_at=None) if life.outranked_at is not None else life), view, math.inf
    since = now if life.outranked_at is None else life.outranked_at
    life = evolve(life, outranked_at=since)
    rule = tm.outranked(since, now, life.waits.decision_s)
    if isinstance(rule, tm.Wait):
        return life, view, rule.until
    return life, evolve(view, present=False, absent_since=since), math.inf


def _wait(life: Life, now: float, view: View):
    m, w, j = view.machine, life.waits, life.stage
    if m.ended:
        return _stage_ended(life, now, view)
    if m.resolved(j):
        return _resolved(life, now, view)
    life, view, grace_until = _deciding_coordinator(life, now, view)
    wait = life.wait.tick(now, view.present)
    absent_s = 0.0 if view.present else now - view.absent_since
    rule = tm.decision_wait(view.timers.clock, life.mode, view.present, wait.waited_s, absent_s, w.decision_s,
                            w.coordinator_s)
    life = evolve(life, wait=wait)
    silence3 = view.timers.silence_timeout_s / 3
    sent: tuple = ()
    if view.present and isinstance(rule, (tm.Wait, tm.AskState)):
        # alive while the Decision is on its way, so the next stage's wait does not take this
        # carrier for a stalled one [P-10.6]
        life, sent = _progress(life, now, view, silence3)
    if isinstance(rule, tm.AskState):
        return evolve(life, wait=wait.asked()), (*sent, AskState(j))
    if isinstance(rule, (tm.MoveOn, tm.DecideAlone)):
        notes: tuple = ()
        if wait.waited_s >= w.decision_s:  # none in time (wall clock)
            notes = (Note(f"no decision for stage {j} within {w.decision_s:.0f} s; "
                          + ("going on" if isinstance(rule, tm.MoveOn) else "deciding on board")),)
        if isinstance(rule, tm.MoveOn):
            return evolve(life, phase=Phase.WORK, stage=j + 1, driving=False), (*notes, MoveOn(j))
        if not life.deciding:
            notes += (Note(f"deciding on board from stage {j} (dec-closed-loop, "
                           f"{len(view.peers_live - {m.cid})} other carrier(s) reachable)"),)
        return (evolve(life, phase=Phase.ALONE, opened=now, deciding=True, repeated_at=None),
                (*notes, Listen()))
    if isinstance(rule, tm.GiveUp):
        return _finish(life, rule.reason, Note(f"coordinator absent for {w.coordinator_s:.0f} s; exiting"))
    until = min(_next_progress(life, view, silence3) if view.present else math.inf, grace_until)
    if view.present:
        until = min(until, now + (w.decision_s - wait.waited_s))
    elif life.mode == Mode.COORDINATED:
        until = min(until, view.absent_since + w.coordinator_s)
    return life, (*sent, tm.Wait(until))


def _alone(life: Life, now: float, view: View):
    m, w, j = view.machine, life.waits, life.stage
    if m.ended:
        return _stage_ended(life, now, view)
    if m.resolved(j):
        return _resolved(life, now, view)
    waiting = view.book.waiting(j, view.peers_live - {m.cid}) if view.book is not None else ()
    silence_s = view.timers.silence_timeout_s
    rule = tm.peer_wait(view.timers.clock, waiting, view.heard, life.opened, now, w.peer_s, silence_s)
    if isinstance(rule, tm.GoOn):
        return evolve(life, phase=Phase.WORK, stage=j + 1, driving=False), (DecideOnBoard(j), MoveOn(j))
    effects: tuple = ()
    until = rule.until
    if view.timers.clock == "sim":
        # its peers may wait for its Observation as it waits for theirs, and one was lost: it goes
        # again with each Progress (found by mission.simulate: two carriers heard from forever)
        if tm.due(life.repeated_at, now, silence_s / 3):
            life = evolve(life, repeated_at=now)
            effects = (RepeatObservation(j),)
        life, sent = _progress(life, now, view, silence_s / 3)
        effects += sent
        until = min(until, life.repeated_at + silence_s / 3, _next_progress(life, view, silence_s / 3))
    return life, (*effects, tm.Wait(until))


def _end(life: Life, now: float, view: View):
    m = view.machine
    rule = tm.end_wait(m.ended, life.end_present, life.opened, now, life.waits.end_s)
    if isinstance(rule, tm.GoOn):
        return _finish(life, "end" if m.ended else "finished")
    return life, (rule,)


def _done(life: Life, now: float, view: View):
    return life, (tm.Wait(),)


_PHASES = {
    Phase.JOINING: _joining, Phase.GATHERING: _gathering, Phase.STARTED: _started, Phase.WORK: _work,
    Phase.WAIT: _wait, Phase.ALONE: _alone, Phase.END: _end, Phase.DONE: _done,
}
