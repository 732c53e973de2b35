"""The carrier's lifecycle machine (mission/carrier_life.py) as a table: one row per transition
of its phase table (docs/architecture.md, "The carrier's lifecycle"), each citing its rule of
docs/protocol.md. Times are seconds on one clock; the machine reads no clock."""
from __future__ import annotations

import dataclasses
import math

import pytest

from mission import carrier as mc
from mission import carrier_life as cl
from mission import timers as tm
from mission.peers import PeerBook
from mission.timeouts import DEFAULTS

P = cl.Phase
WAITS = dataclasses.replace(DEFAULTS, decision_s=30.0, coordinator_s=30.0, end_s=10.0, peer_s=5.0, join_s=20.0,
                            hello_s=10.0, state_query_s=2.0, progress_s=1.0)
SIM, WALL = mc.Timers("sim", 9.0, 0.0), mc.Timers("wall", 9.0, 0.0)


def machine(stage: int = 0, pending: int | None = None, **changes) -> mc.Handshake:
    m = mc.initial("a", (True,) * 4, (0.0, 5.0, 10.0, 15.0), 2)
    m, _ = mc.step(m, mc.Joined(0))
    m = dataclasses.replace(m, stage=stage, pending=pending)
    return dataclasses.replace(m, **changes)


def view(m=None, present=True, absent_since=0.0, timers=SIM, **more) -> cl.View:
    book = PeerBook(("a", "b"), [[True] * 4, [True] * 4])
    return cl.View(m if m is not None else machine(), present, absent_since, timers, book=book, **more)


def life(mode="hybrid", **changes) -> cl.Life:
    return dataclasses.replace(cl.initial(mode, WAITS), **changes)


def kinds(effects) -> list:
    return [type(e).__name__ for e in effects]


def test_start_asks_state_or_joins_alone():
    """[P-5.2] a carrier starts by asking the coordinator's State; [P-8.5] a decentralised one
    goes on from its own log."""
    new, effects = cl.step(life(), cl.Start(100.0), view())
    assert new.phase is P.JOINING and new.asked == 100.0 and kinds(effects) == ["Query"]
    new, effects = cl.step(life("decentralised"), cl.Start(100.0), view())
    assert new.phase is P.GATHERING and kinds(effects) == ["JoinAlone"]


@pytest.mark.parametrize("mode, now, asked, failed, phase, expected", [
    pytest.param("hybrid", 101.0, 100.0, None, P.JOINING, ["Wait"], id="[P-5.2] a query out: its reply waited for"),
    pytest.param("hybrid", 102.0, 100.0, None, P.JOINING, ["Wait"], id="[P-5.2] none in 2 s: asked again 0.2 s later"),
    pytest.param("hybrid", 102.2, None, 102.0, P.JOINING, ["Query"], id="[P-5.2] 0.2 s after a query without reply"),
    pytest.param("hybrid", 130.0, None, 129.0, P.GATHERING, ["Note", "JoinAlone"],
                 id="[P-5.5] 4 hybrid: none in the coordinator timeout, alone"),
    pytest.param("coordinated", 130.0, None, 129.0, P.DONE, ["Note", "Finish"],
                 id="[P-5.5] 4 coordinated: none in the coordinator timeout, exit"),
])
def test_joining(mode, now, asked, failed, phase, expected):
    new, effects = cl.step(life(mode, phase=P.JOINING, opened=100.0, asked=asked, failed=failed), cl.Tick(now), view())
    assert new.phase is phase and kinds(effects) == expected
    if phase is P.DONE:
        assert effects[-1] == cl.Finish("coordinator-lost")
    if expected == ["Wait"]:
        assert effects[-1] == tm.Wait(102.0 if now < 102.0 else 102.2)


def test_an_answer_starts_the_stages():
    new, _ = cl.step(life(phase=P.JOINING, asked=100.0), cl.Answered(100.5), view())
    assert new.phase is P.STARTED
    new, effects = cl.step(new, cl.Tick(100.5), view(machine(stage=2)))
    assert new.phase is P.WORK and new.stage == 2 and new.at_once and effects == ()
    ended = machine(ended=True)
    new, _ = cl.step(dataclasses.replace(new, phase=P.STARTED), cl.Tick(101.0), view(ended))
    assert new.phase is P.END


@pytest.mark.parametrize("gathered, now, phase, expected", [
    pytest.param(False, 110.0, P.GATHERING, ["Wait"], id="[P-8.5] a peer without a token: waited for"),
    pytest.param(False, 120.0, P.STARTED, ["Gathered"], id="[P-8.5] at most the join timeout"),
    pytest.param(True, 101.0, P.STARTED, ["Gathered"], id="[P-8.5] every peer's token: at once"),
])
def test_gathering(gathered, now, phase, expected):
    new, effects = cl.step(life(phase=P.GATHERING, opened=100.0), cl.Tick(now), view(gathered=gathered))
    assert new.phase is phase and kinds(effects) == expected


@pytest.mark.parametrize("mode, present, resync", [
    pytest.param("hybrid", True, True, id="[P-5.12] hybrid: its token came back during the wait, resync at once"),
    pytest.param("hybrid", False, False, id="[P-5.12] hybrid: still absent, alone"),
    pytest.param("decentralised", True, False, id="decentralised: no coordinator to resync with"),
])
def test_a_coordinator_back_when_the_gathering_ends_is_resynchronised_with(mode, present, resync):
    """Found by the simulator (docs/fleet.md, "Findings"): a hybrid carrier whose State query timed
    out just as the coordinator's token came back went on alone and never said Hello. The machine
    names the resynchronisation in its Gathered; both drivers carry it out."""
    if mode == "hybrid":  # its last State query went unanswered: it goes on alone
        joined, effects = cl.step(life(mode, phase=P.JOINING, opened=100.0, failed=129.0), cl.Tick(130.0),
                                  view(present=False))
    else:
        joined, effects = cl.step(life(mode), cl.Start(130.0), view(present=False))
    assert joined.phase is P.GATHERING and kinds(effects)[-1] == "JoinAlone"
    new, effects = cl.step(joined, cl.Tick(131.0), view(present=present, gathered=True))
    assert new.phase is P.STARTED and effects == (cl.Gathered(resync=resync),)


def test_work_drives_then_observes_or_passes():
    """A stage: the body driven to t_j (not paced at the first stage after a join or behind),
    Progress while it drives (sim clock, [P-10.6]); there, Observe, or Pass when the stage was
    decided without this carrier."""
    w = life(phase=P.WORK, stage=1, at_once=False)
    new, effects = cl.step(w, cl.Tick(100.0), view(machine(stage=1)))
    assert effects == (cl.Drive(1, True),) and new.driving
    new, effects = cl.step(new, cl.Tick(100.0), view(machine(stage=1)))
    assert kinds(effects) == ["SendProgress", "Wait"] and effects[-1] == tm.Wait(101.0)
    new2, effects = cl.step(new, cl.Tick(100.5), view(machine(stage=1)))
    assert kinds(effects) == ["Wait"]
    after, effects = cl.step(new, cl.Arrived(1, 100.5), view(machine(stage=1)))
    assert after.phase is P.WAIT and effects == (cl.Observe(1),) and after.wait == tm.DecisionWait.opened(100.5)
    behind = machine(stage=1, latest_decided=1)
    after, effects = cl.step(new, cl.Arrived(1, 100.5), view(behind))
    assert after.phase is P.WORK and after.stage == 2 and after.at_once and effects == (cl.Pass(1),)
    new, effects = cl.step(dataclasses.replace(w, at_once=True), cl.Tick(100.0), view(machine(stage=1)))
    assert effects == (cl.Drive(1, False),)


def waiting(**changes) -> cl.Life:
    return life(phase=P.WAIT, stage=0, wait=tm.DecisionWait.opened(100.0), **changes)


@pytest.mark.parametrize("mode, timers, present, now, phase, expected", [
    pytest.param("hybrid", SIM, True, 110.0, P.WAIT, ["SendProgress", "Wait"],
                 id="[P-10.8] present: waiting, Progress a third of the silence apart"),
    pytest.param("hybrid", SIM, True, 130.0, P.WAIT, ["SendProgress", "AskState"],
                 id="[P-10.8] sim: the decision timeout, State asked"),
    pytest.param("hybrid", WALL, True, 130.0, P.ALONE, ["Note", "Note", "Listen"],
                 id="[P-8.1] wall, hybrid: none in time, alone"),
    pytest.param("coordinated", WALL, True, 130.0, P.WORK, ["Note", "MoveOn"],
                 id="[P-8.1] wall, coordinated: none in time, on without deploying"),
    pytest.param("hybrid", SIM, False, 101.0, P.ALONE, ["Note", "Listen"], id="[P-8.1] hybrid, absent: alone"),
    pytest.param("decentralised", SIM, True, 100.0, P.ALONE, ["Note", "Listen"], id="[P-8.1] decentralised: alone"),
    pytest.param("coordinated", SIM, False, 110.0, P.WAIT, ["Wait"], id="[P-8.1] coordinated, absent: holds"),
    pytest.param("coordinated", SIM, False, 131.0, P.DONE, ["Note", "Finish"],
                 id="[P-8.1] coordinated, absent for the coordinator timeout: exits"),
])
def test_waiting_for_a_decision(mode, timers, present, now, phase, expected):
    new, effects = cl.step(dataclasses.replace(waiting(), mode=mode), cl.Tick(now),
                           view(machine(pending=0), present=present, absent_since=100.0, timers=timers))
    assert new.phase is phase and kinds(effects) == expected
    if phase is P.WAIT and not present:
        assert effects[-1] == tm.Wait(130.0)


@pytest.mark.parametrize("mode, since, now, phase, expected", [
    pytest.param("hybrid", None, 120.0, P.WAIT, ["SendProgress", "Wait"],
                 id="[P-7.2] outranked: waited for the decision timeout (a current Decision may follow)"),
    pytest.param("hybrid", 120.0, 150.0, P.ALONE, ["Note", "Listen"],
                 id="[P-7.2] hybrid, outranked for the decision timeout: absent since the rejection, alone"),
    pytest.param("coordinated", 120.0, 150.0, P.DONE, ["Note", "Finish"],
                 id="[P-7.2] coordinated, outranked for the decision timeout: absent for the coordinator timeout, exits"),
])
def test_an_outranked_coordinator_is_absent(mode, since, now, phase, expected):
    """The handshake machine rejected the live coordinator's Decision ``deposed`` (a lower
    ballot: a primary restarted on a stale disk after a standby's takeover): its token says
    present; unless a current Decision or State comes within the decision timeout of the
    rejection (:func:`mission.timers.outranked`), the carrier takes it as absent since then."""
    outranked = machine(pending=0, outranked=True)
    new, effects = cl.step(waiting(mode=mode, outranked_at=since), cl.Tick(now), view(outranked, present=True))
    assert new.phase is phase and kinds(effects) == expected
    assert new.outranked_at == (120.0 if since is None else since)
    if phase is P.WAIT:
        assert effects[-1].until <= 150.0  # looked at again by the end of the grace
    # A current Decision or State heard since: present again, the mark cleared, waiting on.
    back, effects = cl.step(waiting(mode=mode, outranked_at=120.0), cl.Tick(125.0), view(machine(pending=0)))
    assert back.phase is P.WAIT and back.outranked_at is None and kinds(effects)[-1] == "Wait"


def test_a_resolved_stage_or_end_leaves_the_wait():
    decided = machine(pending=0, latest_decided=0)
    decided, _ = mc.step(machine(pending=0), mc.DecisionHeard(0, 0.0, (), (0.0, 0.0)))
    new, effects = cl.step(waiting(), cl.Tick(101.0), view(decided))
    assert new.phase is P.WORK and new.stage == 1 and effects == (cl.MoveOn(0, True),)
    new, effects = cl.step(waiting(), cl.Tick(101.0), view(machine(pending=0, ended=True)))
    assert new.phase is P.END and effects == (cl.MoveOn(0),) and new.end_present


@pytest.mark.parametrize("timers, heard, now, expected", [
    pytest.param(WALL, {}, 104.0, ["Wait"], id="[P-8.4] wall: the peer waited for"),
    pytest.param(WALL, {}, 105.0, ["DecideOnBoard", "MoveOn"], id="[P-8.4] wall: at most the peer timeout"),
    pytest.param(SIM, {"b": 100.0}, 100.0, ["RepeatObservation", "SendProgress", "Wait"],
                 id="[P-8.4] sim: waiting, its Observation repeated"),
    pytest.param(SIM, {"b": 100.0}, 109.0, ["DecideOnBoard", "MoveOn"], id="[P-8.4] sim: the peer silent"),
])
def test_deciding_alone(timers, heard, now, expected):
    v = view(machine(stage=1, pending=1), present=False, timers=timers, peers_live=frozenset({"b"}), heard=heard)
    new, effects = cl.step(life(phase=P.ALONE, stage=1, opened=100.0), cl.Tick(now), v)
    assert kinds(effects) == expected
    if expected[0] == "DecideOnBoard":
        assert new.phase is P.WORK and new.stage == 2 and effects[0] == cl.DecideOnBoard(1)


@pytest.mark.parametrize("ended, present, now, expected", [
    pytest.param(False, True, 105.0, tm.Wait(110.0), id="[P-9.5] present: End waited for"),
    pytest.param(False, True, 110.0, cl.Finish("finished"), id="[P-9.5] at most the end timeout"),
    pytest.param(False, False, 100.0, cl.Finish("finished"), id="[P-9.5] absent: not waited for"),
    pytest.param(True, True, 100.0, cl.Finish("end"), id="[P-9.5] End came"),
])
def test_the_end_wait(ended, present, now, expected):
    new, effects = cl.step(life(phase=P.END, opened=100.0, end_present=present), cl.Tick(now),
                           view(machine(ended=ended)))
    assert effects[-1] == expected
    assert (new.phase is P.DONE) == isinstance(expected, cl.Finish)


@pytest.mark.parametrize("hello, present, now, expected", [
    pytest.param(cl.Hello(True, True, 100.0, 0), True, 110.0, cl.SayHelloAgain(), id="[P-5.14] unanswered: again"),
    pytest.param(cl.Hello(True, True, 100.0, 1), True, 110.0, tm.Wait(120.0), id="[P-5.14] the interval doubles"),
    pytest.param(cl.Hello(True, False, 100.0, 0), True, 110.0, tm.Wait(math.inf), id="[P-5.14] revision 2: never"),
    pytest.param(cl.Hello(True, True, 100.0, 0), False, 110.0, tm.Wait(math.inf), id="[P-5.14] absent: never"),
    pytest.param(cl.Hello(False, True, 100.0, 0), True, 110.0, tm.Wait(math.inf), id="[P-5.14] answered"),
])
def test_a_hello_said_again(hello, present, now, expected):
    """In every phase but joining, gathering and done (here: driving on the wall clock)."""
    driving = life(phase=P.WORK, stage=1, driving=True)
    _, effects = cl.step(driving, cl.Tick(now), view(machine(stage=1), present=present, timers=WALL, hello=hello))
    assert effects == (expected,)
    _, effects = cl.step(life(phase=P.GATHERING, opened=now), cl.Tick(now), view(present=present, hello=hello,
                                                                                  gathered=False))
    assert effects == (tm.Wait(now + 20.0),)


def test_a_stop_request_ends_every_phase():
    for phase in (P.JOINING, P.GATHERING, P.WORK, P.WAIT, P.ALONE, P.END):
        new, effects = cl.step(life(phase=phase), cl.Stopped(1.0), view())
        assert new.phase is P.DONE and effects == (cl.Finish("stopped"),)
    new, effects = cl.step(life(phase=P.DONE), cl.Tick(1.0), view())
    assert effects == (tm.Wait(),)
