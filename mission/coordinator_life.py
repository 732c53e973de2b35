"""A coordinator's lifecycle as a pure machine: the phase is state, time is an input, every wait
is a rule of :mod:`mission.timers` and the waiting itself is an effect
(:class:`mission.timers.Wait`).

``step(life, event, view) -> (life, effects)``, etcd raft's shape, as :mod:`mission.carrier_life`
is for a carrier. The coordinator process (coordinator/node.py) and the deterministic simulator
(mission/simulate/coordinator.py) are its drivers: they feed :class:`Tick` and the lifecycle
events below and carry out the effects; the mission rules themselves (what an event does to the
mission) are :mod:`mission.state`'s machine, which this one reads through :class:`View`.

Phases (docs/architecture.md, "The coordinator's lifecycle"):

=========  =======================================================  ============================
phase      what it waits for (rule)                                 leaves to
=========  =======================================================  ============================
standby    the primary's token gone ([P-7.x] ``standby``)            (driver opens: join)
join       every carrier live with a Hello ([P-5.11] ``join_wait``)  stage, confirm
stage      the pace ([P-10.7] ``pace``), a live carrier ([P-6.5]     stage j+1 (Decide, Decided),
           ``hold``), the Observations of j ([P-10.3] ``stage_wait``) confirm, deposed
confirm    the last stage's Confirms ([P-10.3] ``stage_wait``)       end
end        the Byes, End repeated ([P-9.1] ``end_due``, ``bye_wait``)  done
done       nothing                                                  -
deposed    nothing (a newer ballot decides)                         -
=========  =======================================================  ============================

A stop request ends join, stage and confirm with End ``stopped``; the end wait runs to its end.
"""
from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import Any

from . import timers as tm
from .evolve import evolve
from .timeouts import Timeouts, resumed_join


class Phase(str, enum.Enum):
    STANDBY = "standby"
    JOIN = "join"
    STAGE = "stage"
    CONFIRM = "confirm"
    END = "end"
    DONE = "done"
    DEPOSED = "deposed"


# --------------------------------------------------------------------------- events

@dataclass(frozen=True)
class Opened:
    """The mission was opened at ``now`` (a fresh start, a restart or a takeover: the record folded
    into the :class:`View`'s state)."""

    now: float


@dataclass(frozen=True)
class Tick:
    now: float


@dataclass(frozen=True)
class Decided:
    """The Decision of ``stage`` was recorded and published at ``now`` (``planning_ms`` planning)."""

    stage: int
    now: float
    planning_ms: float = 0.0


@dataclass(frozen=True)
class Deposed:
    """A coordinator of a newer ballot decides: this one stops without End."""


@dataclass(frozen=True)
class Stopped:
    """A stop request at ``now``."""

    now: float


# --------------------------------------------------------------------------- effects

@dataclass(frozen=True)
class TakeOver:
    """A standby: the primary is gone; open the mission (then :class:`Opened`)."""


@dataclass(frozen=True)
class Decide:
    """Plan ``stage``, record and publish its Decision (then :class:`Decided`, or :class:`Deposed`)."""

    stage: int


@dataclass(frozen=True)
class StageLine:
    """The progress line of ``stage``: its Decision went out ``waited_ms`` of waiting after its
    stage opened."""

    stage: int
    waited_ms: float


@dataclass(frozen=True)
class RecordEnd:
    """Step the mission with :class:`mission.events.Ended` (``reason``)."""

    reason: str


@dataclass(frozen=True)
class PublishEnd:
    """Publish End (again: for carriers that missed it)."""


@dataclass(frozen=True)
class Finish:
    """The mission is over for this coordinator."""


@dataclass(frozen=True)
class Note:
    line: str


# --------------------------------------------------------------------------- what it reads

@dataclass(frozen=True)
class View:
    """What the driver knows at the step, read and never changed by this machine.

    Attributes:
        state: the :class:`mission.state.MissionState`.
        heard: carrier id -> when it was last heard (s) [P-10.5].
        primary_present: a standby: the primary's token is present; primary_lost: when its loss
            was noticed (None: not lost).
    """

    state: Any
    heard: Any = None
    primary_present: bool = True
    primary_lost: float | None = None


# --------------------------------------------------------------------------- state

@dataclass(frozen=True)
class Life:
    """A coordinator's lifecycle (see the module's phase table).

    Attributes:
        waits: its :class:`Timeouts` (``join_s``, ``stage_s``, ``confirm_s``, ``silence_s``,
            ``bye_s``, ``bye_grace_s``, ``end_repeat_s``, ``rejoin_s``, ``standby_poll_s``).
        clock: ``sim`` or ``wall``; realtime: the pace (0: unpaced); stage_interval: Δt (s).
        phase: :class:`Phase`; stage: the stage it collects.
        opened: when the phase's wait opened (stage: its Observations' wait; None: not yet).
        joined: the most carriers live with a Hello so far; last_join: when that many first were.
        published: when the latest Decision went out (None: none yet by this process).
        held_at: when it started holding the stage for want of a live carrier (None: not held).
        deciding: :class:`Decide` is out for ``stage``.
        ended_at, last_end, grace: the end wait: End recorded, last published, every live
            carrier said Bye (None: not yet).
        reason: why the mission ended.
    """

    waits: Timeouts
    clock: str = "sim"
    realtime: float = 0.0
    stage_interval: float = 0.0
    phase: Phase = Phase.DONE
    stage: int = 0
    opened: float | None = None
    joined: int = 0
    last_join: float = 0.0
    published: float | None = None
    held_at: float | None = None
    deciding: bool = False
    ended_at: float = 0.0
    last_end: float | None = None
    grace: float | None = None
    reason: str | None = None


def initial(waits: Timeouts, clock: str = "sim", realtime: float = 0.0, stage_interval: float = 0.0,
            standby: bool = False) -> Life:
    return Life(waits, clock, float(realtime), float(stage_interval), Phase.STANDBY if standby else Phase.DONE)


def _joined(state) -> int:
    return sum(1 for cid in state.live if cid in state.accepted)


# --------------------------------------------------------------------------- step

def step(life: Life, event, view: View) -> tuple[Life, tuple]:
    """One event (:class:`Opened`, :class:`Tick`, :class:`Decided`, :class:`Deposed`,
    :class:`Stopped`): the new life and the effects in order. A step that ends with a
    :class:`mission.timers.Wait` has nothing more to do before its ``until``; one without is to be
    stepped again at once."""
    if isinstance(event, Opened):
        return _opened(life, event.now, view)
    if life.phase in (Phase.DONE, Phase.DEPOSED):
        return life, (tm.Wait(),)
    if isinstance(event, Deposed):
        return evolve(life, phase=Phase.DEPOSED, deciding=False), ()
    if isinstance(event, Stopped):
        if life.phase in (Phase.JOIN, Phase.STAGE, Phase.CONFIRM):
            return _to_end(life, event.now, "stopped")
        return life, ()
    if isinstance(event, Decided):
        return _decided(life, event, view)
    if isinstance(event, Tick):
        return _PHASES[life.phase](life, event.now, view)
    raise TypeError(f"not a coordinator lifecycle event: {event!r}")


def _opened(life: Life, now: float, view: View):
    st = view.state
    life = evolve(initial(life.waits, life.clock, life.realtime, life.stage_interval),
                  phase=Phase.JOIN, opened=now, joined=_joined(st), last_join=now)
    if st.ended:  # a complete mission is final: it only tells late carriers it is over
        return _to_end(life, now, st.end_reason or "complete")
    return life, ()


def _to_end(life: Life, now: float, reason: str):
    return (evolve(life, phase=Phase.END, ended_at=now, last_end=None, grace=None, reason=reason,
                   deciding=False), (RecordEnd(reason),))


def _standby(life: Life, now: float, view: View):
    rule = tm.standby(view.primary_present, view.primary_lost, now, life.waits.standby_poll_s)
    if isinstance(rule, tm.TakeOver):
        return evolve(life, phase=Phase.DONE), (TakeOver(),)
    return life, (rule,)


def _join(life: Life, now: float, view: View):
    st, w = view.state, life.waits
    count = _joined(st)
    if count > life.joined:  # the wait runs from when the count last grew: a Hello said again does not restart it
        life = evolve(life, joined=count, last_join=now)
    wait_s = resumed_join(w.join_s, w.stage_s, w.rejoin_s) if st.resumed else w.join_s
    rule = tm.join_wait(life.clock, st.all_joined(), life.opened, life.last_join, now, wait_s)
    if isinstance(rule, tm.Wait):
        return life, (rule,)
    missing = sorted(cid for cid in st.spec.carriers if not (cid in st.live and cid in st.accepted))
    notes = (Note(f"coordinator: starting without carrier(s) {', '.join(missing)} (not live with a Hello "
                  f"after {wait_s:.0f} s); they can join late"),) if missing else ()
    return _next_stage(life, now, view, notes)


def _next_stage(life: Life, now: float, view: View, effects: tuple = ()):
    st = view.state
    if st.next_stage >= st.spec.n_stages:
        return evolve(life, phase=Phase.CONFIRM, opened=now, deciding=False), effects
    return (evolve(life, phase=Phase.STAGE, stage=st.next_stage, opened=None, held_at=None,
                   deciding=False), effects)


def _stage(life: Life, now: float, view: View):
    st, w, j = view.state, life.waits, life.stage
    if life.deciding:
        return life, (tm.Wait(),)
    if life.opened is None:
        if life.published is not None and not st.behind(j):
            # paced like the carriers: Δt / realtime after the previous Decision went out (not when
            # the carriers are past j already: then it catches up at once)
            rule = tm.pace(life.published, life.stage_interval, life.realtime, now)
            if isinstance(rule, tm.Wait):
                return life, (rule,)
        notes: tuple = ()
        if j > 0 and not st.live:
            # nobody to decide for (cut off, or every carrier gone): hold until one is back (its
            # Hello says where it is), at most the join timeout [P-6.5]
            if life.held_at is None:
                life = evolve(life, held_at=now)
                notes = (Note(f"coordinator: no carrier is live; holding stage {j} (at most {w.join_s:.0f} s)"),)
            rule = tm.hold(False, life.held_at, now, w.join_s)
            if isinstance(rule, tm.Wait):
                return life, (*notes, rule)
        life = evolve(life, opened=now)
        if notes:
            return life, notes
    rule = tm.stage_wait(life.clock, *st.waited_for(j), view.heard, life.opened, now, w.stage_s, w.silence_s)
    if isinstance(rule, tm.Wait):
        return life, (rule,)
    return evolve(life, deciding=True), (*_stage_notes(life, j, rule), Decide(j))


def _stage_notes(life: Life, j: int, done: tm.GoOn) -> tuple:
    if life.clock == "wall":
        return ()
    notes = []
    stalled, mute = sorted(done.stalled), sorted(done.late)
    if stalled:
        notes.append(Note(f"coordinator: stage {j}: nothing from {', '.join(stalled[:8])}"
                          f"{' ...' if len(stalled) > 8 else ''} for {life.waits.silence_s:.0f} s (stalled); "
                          "∅ for them"))
    if mute:
        notes.append(Note(f"coordinator: stage {j}: no Observation from {', '.join(mute[:8])}"
                          f"{' ...' if len(mute) > 8 else ''} within the stage timeout "
                          f"({life.waits.stage_s:.0f} s: revision < 3, no Progress); ∅ for them"))
    return tuple(notes)


def _decided(life: Life, e: Decided, view: View):
    if life.phase is not Phase.STAGE or e.stage != life.stage:
        return life, ()
    opened = life.opened if life.opened is not None else e.now
    line = StageLine(e.stage, (e.now - opened) * 1e3 - e.planning_ms)
    life = evolve(life, published=e.now)
    return _next_stage(life, e.now, view, (line,))


def _confirm(life: Life, now: float, view: View):
    st, w = view.state, life.waits
    last = st.spec.n_stages - 1
    rule = tm.stage_wait(life.clock, *st.confirms_awaited(last), view.heard, life.opened, now, w.confirm_s,
                         w.silence_s)
    if isinstance(rule, tm.Wait):
        return life, (rule,)
    return _to_end(life, now, "complete")


def _end(life: Life, now: float, view: View):
    st, w = view.state, life.waits
    effects: tuple = ()
    if tm.end_due(life.last_end, life.ended_at, now, w.end_repeat_s, w.bye_s):
        life = evolve(life, last_end=now)
        effects = (PublishEnd(),)
    if life.grace is None and st.all_said_bye():
        life = evolve(life, grace=now)  # one whose token vanished first may have its Bye on the way
    rule = tm.bye_wait(st.all_said_bye(), st.bye_missing(), life.ended_at, life.grace, now, w.bye_s, w.bye_grace_s)
    if isinstance(rule, tm.GoOn):
        line = f"coordinator: mission {st.end_reason or life.reason} after {st.next_stage} stage(s)"
        return evolve(life, phase=Phase.DONE), (*effects, Note(line), Finish())
    again = life.last_end + w.end_repeat_s if life.last_end is not None else math.inf
    return life, (*effects, tm.Wait(min(rule.until, again)))


def _idle(life: Life, now: float, view: View):
    return life, (tm.Wait(),)


_PHASES = {
    Phase.STANDBY: _standby, Phase.JOIN: _join, Phase.STAGE: _stage, Phase.CONFIRM: _confirm, Phase.END: _end,
    Phase.DONE: _idle, Phase.DEPOSED: _idle,
}
