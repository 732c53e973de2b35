"""The coordinator's lifecycle machine (mission/coordinator_life.py) as a table: one row per
transition of its phase table (docs/architecture.md, "The coordinator's lifecycle"), each citing
its rule of docs/protocol.md. Times are seconds on one clock; the machine reads no clock."""
from __future__ import annotations

import dataclasses

import pytest

from mission import coordinator_life as cl
from mission import events as ev
from mission import state as ms
from mission import timers as tm
from mission.timeouts import DEFAULTS

P = cl.Phase
WAITS = dataclasses.replace(DEFAULTS, join_s=20.0, stage_s=5.0, confirm_s=3.0, silence_s=30.0, bye_s=2.0,
                            bye_grace_s=0.5, end_repeat_s=0.5, standby_poll_s=0.25)
SPEC = ms.MissionSpec.build(("a", "b"), [[True, True], [True, True]], [1, 1], (0.0, 5.0), "f")


def state(*events) -> ms.MissionState:
    st = ms.initial(SPEC)
    for e in events:
        st, _ = ms.step(st, e)
    return st


def joined(*cids, at=0.0):
    out = []
    for cid in cids:
        out += [ev.LivelinessChanged(cid, True, at), ev.Hello(cid, 1, "h", 1, 0, "f", at, 4)]
    return out


def life(clock="sim", **changes) -> cl.Life:
    return dataclasses.replace(cl.initial(WAITS, clock, 0.0, 5.0), **changes)


def kinds(effects) -> list:
    return [type(e).__name__ for e in effects]


def test_opened_joins_or_ends_a_complete_mission():
    new, effects = cl.step(life(), cl.Opened(100.0), cl.View(state(*joined("a"))))
    assert new.phase is P.JOIN and new.opened == 100.0 and new.joined == 1 and effects == ()
    done = state(ev.Ended("complete", 0.0))
    new, effects = cl.step(life(), cl.Opened(100.0), cl.View(done))
    assert new.phase is P.END and effects == (cl.RecordEnd("complete"),)


@pytest.mark.parametrize("clock, events, last_join, now, phase, expected", [
    pytest.param("sim", joined("a"), 100.0, 110.0, P.JOIN, ["Wait"], id="[P-5.11] waiting for b"),
    pytest.param("sim", joined("a"), 105.0, 120.0, P.JOIN, ["Wait"], id="[P-5.11] sim: from the last that joined"),
    pytest.param("wall", joined("a"), 105.0, 120.0, P.STAGE, ["Note"], id="[P-5.11] wall: from the start"),
    pytest.param("sim", joined("a"), 100.0, 120.0, P.STAGE, ["Note"], id="[P-5.11] the join timeout: without b"),
    pytest.param("sim", joined("a", "b"), 100.0, 100.5, P.STAGE, [], id="[P-5.11] everyone: at once"),
])
def test_the_join_wait(clock, events, last_join, now, phase, expected):
    st = state(*events)
    new, effects = cl.step(life(clock, phase=P.JOIN, opened=100.0, joined=1, last_join=last_join), cl.Tick(now),
                           cl.View(st, {}))
    assert new.phase is phase and kinds(effects) == expected
    if phase is P.STAGE:
        assert new.stage == 0 and new.opened is None


def test_a_joining_carrier_restarts_the_sim_join_wait():
    st = state(*joined("a"))
    new, _ = cl.step(life(phase=P.JOIN, opened=100.0, joined=0, last_join=100.0), cl.Tick(110.0), cl.View(st, {}))
    assert new.joined == 1 and new.last_join == 110.0


@pytest.mark.parametrize("clock, heard, now, expected", [
    pytest.param("sim", {"a": 110.0, "b": 110.0}, 120.0, ["Wait"], id="[P-10.3] sim: heard from, waited for"),
    pytest.param("sim", {"a": 110.0, "b": 110.0}, 140.0, ["Note", "Decide"], id="[P-10.3] sim: silent, stalled"),
    pytest.param("wall", {"a": 104.0, "b": 104.0}, 105.0, ["Decide"], id="[P-10.3] wall: the stage timeout"),
])
def test_the_stage_wait(clock, heard, now, expected):
    st = state(*joined("a", "b"))
    new, effects = cl.step(life(clock, phase=P.STAGE, stage=0, opened=100.0), cl.Tick(now), cl.View(st, heard))
    assert kinds(effects) == expected
    if expected[-1] == "Decide":
        assert new.deciding and effects[-1] == cl.Decide(0)
        new, effects = cl.step(new, cl.Tick(now + 1.0), cl.View(st, heard))
        assert effects == (tm.Wait(),)  # the decision is out: nothing until it is done


def test_a_decided_stage_opens_the_next_paced_or_the_confirms():
    st = state(*joined("a", "b"), ev.Observation("a", 0, 0.0, 1, (0.0, 0.0), 1, (), 1.0),
               ev.Observation("b", 0, 0.0, 1, (0.0, 0.0), 1, (), 1.0), ev.Decided(0, (), 0.0, 1.0))
    deciding = life(phase=P.STAGE, stage=0, opened=100.0, deciding=True)
    new, effects = cl.step(deciding, cl.Decided(0, 101.0, 200.0), cl.View(st, {}))
    assert effects == (cl.StageLine(0, 800.0),) and new.phase is P.STAGE and new.stage == 1
    assert new.published == 101.0 and new.opened is None and not new.deciding
    paced = dataclasses.replace(new, realtime=2.0)
    _, effects = cl.step(paced, cl.Tick(101.5), cl.View(st, {}))
    assert effects == (tm.Wait(103.5),)  # [P-10.7] Δt / realtime after the previous Decision
    new, _ = cl.step(new, cl.Tick(101.5), cl.View(st, {}))
    assert new.opened == 101.5
    last = state(*joined("a", "b"), ev.Decided(0, (), 0.0, 1.0), ev.Decided(1, (), 0.0, 1.0))
    new, _ = cl.step(life(phase=P.STAGE, stage=1, opened=100.0, deciding=True), cl.Decided(1, 102.0), cl.View(last))
    assert new.phase is P.CONFIRM and new.opened == 102.0


def test_a_stage_is_held_while_no_carrier_is_live():
    """[P-6.5] a stage j > 0 is held while no carrier is live, at most the join timeout."""
    st = state(*joined("a"), ev.Decided(0, (), 0.0, 1.0), ev.LivelinessChanged("a", False, 2.0))
    new, effects = cl.step(life(phase=P.STAGE, stage=1), cl.Tick(100.0), cl.View(st, {}))
    assert kinds(effects) == ["Note", "Wait"] and effects[-1] == tm.Wait(120.0) and new.held_at == 100.0
    new, effects = cl.step(new, cl.Tick(110.0), cl.View(st, {}))
    assert effects == (tm.Wait(120.0),)
    new, effects = cl.step(new, cl.Tick(120.0), cl.View(st, {}))
    assert new.opened == 120.0


@pytest.mark.parametrize("heard, now, phase", [
    pytest.param({"a": 100.0}, 110.0, P.CONFIRM, id="[P-10.3] the last Confirms: a heard from"),
    pytest.param({"a": 100.0}, 130.0, P.END, id="[P-10.3] the last Confirms: a silent"),
])
def test_the_confirm_wait(heard, now, phase):
    st = state(*joined("a"), ev.Decided(0, (), 0.0, 1.0), ev.Decided(1, (), 0.0, 1.0))
    new, effects = cl.step(life(phase=P.CONFIRM, opened=100.0), cl.Tick(now), cl.View(st, heard))
    assert new.phase is phase
    if phase is P.END:
        assert effects == (cl.RecordEnd("complete"),) and new.ended_at == now


def test_the_end_wait_repeats_end_and_waits_for_the_byes():
    """[P-9.1] End at once, then every end_repeat_s while the Bye wait lasts; a carrier whose
    token vanished without a Bye gets the grace."""
    st = state(*joined("a"), ev.Ended("complete", 1.0))
    new, effects = cl.step(life(phase=P.END, ended_at=100.0), cl.Tick(100.0), cl.View(st, {}))
    assert effects == (cl.PublishEnd(), tm.Wait(100.5))
    new, effects = cl.step(new, cl.Tick(100.5), cl.View(st, {}))
    assert effects == (cl.PublishEnd(), tm.Wait(101.0))
    new, effects = cl.step(new, cl.Tick(102.0), cl.View(st, {}))
    assert new.phase is P.DONE and kinds(effects)[-2:] == ["Note", "Finish"]
    bye = state(*joined("a"), ev.Ended("complete", 1.0), ev.Bye("a", (), (), "end", 2.0))
    new, effects = cl.step(life(phase=P.END, ended_at=100.0, last_end=100.0), cl.Tick(100.1), cl.View(bye, {}))
    assert new.phase is P.DONE


def test_a_stop_request_ends_with_end_stopped_and_deposition_without():
    for phase in (P.JOIN, P.STAGE, P.CONFIRM):
        new, effects = cl.step(life(phase=phase), cl.Stopped(5.0), cl.View(state()))
        assert new.phase is P.END and effects == (cl.RecordEnd("stopped"),)
    new, effects = cl.step(life(phase=P.END), cl.Stopped(5.0), cl.View(state()))
    assert new.phase is P.END and effects == ()  # the end wait runs to its end
    new, effects = cl.step(life(phase=P.STAGE, deciding=True), cl.Deposed(), cl.View(state()))
    assert new.phase is P.DEPOSED and effects == ()
    assert cl.step(new, cl.Tick(6.0), cl.View(state())) == (new, (tm.Wait(),))


def test_a_standby_takes_over_when_the_primary_is_gone():
    standby = cl.initial(WAITS, standby=True)
    _, effects = cl.step(standby, cl.Tick(10.0), cl.View(state(), primary_present=True))
    assert effects == (tm.Wait(10.25),)
    new, effects = cl.step(standby, cl.Tick(10.0), cl.View(state(), primary_present=False, primary_lost=9.0))
    assert effects == (cl.TakeOver(),)
