"""The timer rules of mission.timers as tables: one row per case, each citing its rule of
docs/protocol.md ("Time"). Times are seconds on one clock; every rule is a pure function."""
from __future__ import annotations

import math

import pytest

from mission import timers as tm
from mission.timeouts import DEFAULTS, STATE_RETRY_S

INF = math.inf
F = frozenset


def rows(table):
    """pytest params named by each row's first item (its case)."""
    return [pytest.param(*row[1:], id=row[0]) for row in table]


# --------------------------------------------------------------------------- silence [P-10.3]

@pytest.mark.parametrize("heard, opened, now, expected", rows([
    ("nothing heard, before the timeout since opening", {}, 10.0, 39.9, False),
    ("nothing heard, the timeout since opening", {}, 10.0, 40.0, True),
    ("heard before opening counts from opening", {"a": 5.0}, 10.0, 40.0, True),
    ("heard after opening: from then", {"a": 15.0}, 10.0, 44.9, False),
    ("heard after opening: the timeout since then", {"a": 15.0}, 10.0, 45.0, True),
    ("the latest of several", {"a": 15.0, "b": 20.0}, 10.0, 49.0, False),
]))
def test_silent(heard, opened, now, expected):
    among = {"a", "b"} if "b" in heard else {"a"}
    assert tm.silent(heard, among, opened, now, 30.0) is expected


# --------------------------------------------------------------------------- the coordinator's stage wait [P-10.3], [P-10.4]

@pytest.mark.parametrize("clock, loud, mute, heard, now, stage_s, expected", rows([
    ("[P-10.3] nobody waited for: go on", "sim", (), (), {}, 0.0, 5.0, tm.GoOn()),
    ("[P-10.3] wall: before the stage timeout", "wall", ("a",), (), {}, 4.0, 5.0, tm.Wait(5.0)),
    ("[P-10.3] wall: the stage timeout, late", "wall", ("a",), ("b",), {}, 5.0, 5.0, tm.GoOn(late=F({"a", "b"}))),
    ("[P-10.3] wall: heard from does not extend", "wall", ("a",), (), {"a": 4.9}, 5.0, 5.0, tm.GoOn(late=F({"a"}))),
    ("[P-10.3] sim: a slow carrier is waited for past the stage timeout", "sim", ("a",), (), {"a": 20.0}, 45.0, 5.0,
     tm.Wait(50.0)),
    ("[P-10.3] sim: silent for the silence timeout, stalled", "sim", ("a",), (), {"a": 20.0}, 50.0, 5.0,
     tm.GoOn(stalled=F({"a"}))),
    ("[P-10.3] sim: silent since opening", "sim", ("a",), (), {}, 30.0, 5.0, tm.GoOn(stalled=F({"a"}))),
    ("[P-10.4] sim: a mute carrier, only the stage timeout", "sim", (), ("m",), {}, 5.0, 5.0, tm.GoOn(late=F({"m"}))),
    ("[P-10.4] sim: a mute carrier before the stage timeout", "sim", (), ("m",), {}, 4.0, 5.0, tm.Wait(5.0)),
    ("[P-10.4] sim: mute late, loud still heard: wait for the loud", "sim", ("a",), ("m",), {"a": 10.0}, 6.0, 5.0,
     tm.Wait(40.0)),
    ("[P-10.4] sim: loud silent, mute before its timeout", "sim", ("a",), ("m",), {}, 30.0, 60.0, tm.Wait(60.0)),
    ("[P-10.4] sim: both over", "sim", ("a",), ("m",), {}, 60.0, 60.0, tm.GoOn(stalled=F({"a"}), late=F({"m"}))),
    # the last stage's Confirms: the same wait, the confirm timeout as its stage_s [P-10.3]
    ("[P-10.3] confirms, wall: the confirm timeout", "wall", ("a",), (), {}, DEFAULTS.confirm_s, DEFAULTS.confirm_s,
     tm.GoOn(late=F({"a"}))),
    ("[P-10.3] confirms, wall: before it", "wall", ("a",), (), {}, 2.0, DEFAULTS.confirm_s, tm.Wait(DEFAULTS.confirm_s)),
    ("[P-10.3] confirms, sim: an unconfirmed carrier heard from", "sim", ("a",), (), {"a": 10.0}, 35.0,
     DEFAULTS.confirm_s, tm.Wait(40.0)),
]))
def test_stage_wait(clock, loud, mute, heard, now, stage_s, expected):
    assert tm.stage_wait(clock, loud, mute, heard, 0.0, now, stage_s, 30.0) == expected


# --------------------------------------------------------------------------- join [P-5.11], [P-8.5]

@pytest.mark.parametrize("clock, all_joined, last_join, now, expected", rows([
    ("everyone joined", "wall", True, 0.0, 1.0, tm.GoOn()),
    ("wall: within the join timeout", "wall", False, 15.0, 19.0, tm.Wait(20.0)),
    ("wall: a late joiner does not slide it", "wall", False, 15.0, 20.0, tm.GoOn()),
    ("sim: slides from the last joiner", "sim", False, 15.0, 20.0, tm.Wait(35.0)),
    ("sim: the join timeout after the last joiner", "sim", False, 15.0, 35.0, tm.GoOn()),
    ("sim: nobody joined since opening", "sim", False, -1.0, 20.0, tm.GoOn()),
]))
def test_join_wait(clock, all_joined, last_join, now, expected):
    assert tm.join_wait(clock, all_joined, 0.0, last_join, now, 20.0) == expected


# --------------------------------------------------------------------------- Bye [P-9.1]

@pytest.mark.parametrize("all_bye, missing, grace_from, now, expected", rows([
    ("no Bye yet", False, True, None, 1.0, tm.Wait(2.0)),
    ("the Bye wait is over", False, True, None, 2.0, tm.GoOn()),
    ("every carrier said Bye", True, False, 0.5, 0.6, tm.GoOn()),
    ("a vanished token without Bye: grace", True, True, 0.5, 0.7, tm.Wait(1.0)),
    ("the grace is over", True, True, 0.5, 1.0, tm.GoOn()),
    ("the grace ends within the Bye wait", True, True, 1.8, 1.9, tm.Wait(2.0)),
]))
def test_bye_wait(all_bye, missing, grace_from, now, expected):
    assert tm.bye_wait(all_bye, missing, 0.0, grace_from, now, 2.0, 0.5) == expected


def test_end_is_repeated_when_due():
    """[P-9.1] End every 0.5 s; [P-10.6] Progress every interval; an interval <= 0: never."""
    assert [tm.due(last, now, 0.5) for last, now in ((None, 0.0), (0.0, 0.4), (0.0, 0.5), (1.0, 1.6))] == [
        True, False, True, True]
    assert not tm.due(None, 5.0, 0.0) and not tm.due(0.0, 5.0, -1.0)


@pytest.mark.parametrize("last, now, expected", rows([
    ("[P-9.1] End goes out at once", None, 0.0, True),
    ("[P-9.1] not again before the repeat interval", 0.0, 0.4, False),
    ("[P-9.1] again every 0.5 s", 1.0, 1.5, True),
    ("[P-9.1] not once the Bye wait is over", 1.5, 2.0, False),
]))
def test_end_due(last, now, expected):
    assert tm.end_due(last, 0.0, now, 0.5, 2.0) is expected


# --------------------------------------------------------------------------- standby [P-7.6]

@pytest.mark.parametrize("present, lost_at, now, expected", rows([
    ("the primary is there: look again", True, None, 1.0, tm.Wait(1.25)),
    ("not noticed gone yet", False, None, 1.0, tm.Wait(1.25)),
    ("its token gone: take over", False, 0.9, 1.0, tm.TakeOver()),
]))
def test_standby(present, lost_at, now, expected):
    assert tm.standby(present, lost_at, now, 0.25) == expected


# --------------------------------------------------------------------------- the carrier's Decision wait [P-10.8], [P-8.1]

@pytest.mark.parametrize("clock, mode, present, waited, absent, expected", rows([
    ("[P-8.5] decentralised decides alone", "sim", "decentralised", False, 0.0, 0.0, tm.DecideAlone()),
    ("[P-10.8] sim, present: wait", "sim", "hybrid", True, 29.0, 0.0, tm.Wait()),
    ("[P-10.8] sim, present, the decision timeout: ask State", "sim", "hybrid", True, 30.0, 0.0, tm.AskState()),
    ("[P-10.8] sim, coordinated: ask State too", "sim", "coordinated", True, 30.0, 0.0, tm.AskState()),
    ("[P-8.1] wall, hybrid, the decision timeout: decide alone", "wall", "hybrid", True, 30.0, 0.0, tm.DecideAlone()),
    ("[P-8.1] wall, coordinated, the decision timeout: move on", "wall", "coordinated", True, 30.0, 0.0, tm.MoveOn()),
    ("[P-8.1] hybrid, absent: decide alone at once", "sim", "hybrid", False, 0.0, 0.0, tm.DecideAlone()),
    ("[P-8.1] coordinated, absent: hold", "wall", "coordinated", False, 10.0, 29.0, tm.Wait()),
    ("[P-8.1] coordinated, absent the coordinator timeout: exit", "sim", "coordinated", False, 10.0, 30.0,
     tm.GiveUp("coordinator-lost")),
]))
def test_decision_wait(clock, mode, present, waited, absent, expected):
    assert tm.decision_wait(clock, mode, present, waited, absent, 30.0, 30.0) == expected


@pytest.mark.parametrize("looks, expected", rows([
    ("present throughout", ((10.0, True), (20.0, True)), 20.0),
    ("[P-10.8] the time while absent does not count", ((10.0, True), (15.0, False), (20.0, True)), 15.0),
    ("[P-10.8] wall: the sum runs across absences", ((10.0, True), (15.0, False), (25.0, True), (40.0, True)),
     35.0),
    ("[P-10.8] sim: a State query starts it again", ((10.0, True), (30.0, True), ("asked",), (45.0, True)), 15.0),
    ("absent from the start", ((10.0, False), (20.0, False)), 0.0),
]))
def test_decision_wait_counts_the_time_present(looks, expected):
    wait = tm.DecisionWait.opened(0.0)
    for look in looks:
        wait = wait.asked() if look == ("asked",) else wait.tick(*look)
    assert wait.waited_s == expected


def test_a_long_decision_wait_on_the_sim_clock_asks_state_every_decision_timeout():
    """[P-10.8] the counter and the rule together: State asked at 30 s and 60 s of presence, the
    absence between not counted."""
    wait, asked = tm.DecisionWait.opened(0.0), []
    for now, present in ((10.0, True), (30.0, True), (40.0, True), (50.0, False), (55.0, True), (70.0, True)):
        wait = wait.tick(now, present)
        if isinstance(tm.decision_wait("sim", "hybrid", present, wait.waited_s, 0.0, 30.0, 30.0), tm.AskState):
            asked.append(now)
            wait = wait.asked()
    assert asked == [30.0, 70.0]


# --------------------------------------------------------------------------- deciding alone [P-8.4]

@pytest.mark.parametrize("clock, waiting, heard, now, expected", rows([
    ("every peer heard: decide", "sim", (), {}, 0.1, tm.GoOn()),
    ("wall: within the peer timeout", "wall", ("b",), {}, 4.0, tm.Wait(5.0)),
    ("wall: the peer timeout", "wall", ("b",), {"b": 4.9}, 5.0, tm.GoOn(late=F({"b"}))),
    ("sim: a peer heard from is waited for", "sim", ("b",), {"b": 20.0}, 40.0, tm.Wait(50.0)),
    ("sim: silent for the silence timeout", "sim", ("b",), {"b": 20.0}, 50.0, tm.GoOn(stalled=F({"b"}))),
    ("sim: the last heard of several", "sim", ("b", "c"), {"b": 20.0, "c": 25.0}, 50.0, tm.Wait(55.0)),
]))
def test_peer_wait(clock, waiting, heard, now, expected):
    assert tm.peer_wait(clock, waiting, heard, 0.0, now, 5.0, 30.0) == expected


# --------------------------------------------------------------------------- End after the last stage [P-9.5]

@pytest.mark.parametrize("ended, present, now, expected", rows([
    ("End heard", True, True, 1.0, tm.GoOn()),
    ("the coordinator present: wait", False, True, 9.0, tm.Wait(10.0)),
    ("the end timeout", False, True, 10.0, tm.GoOn()),
    ("no coordinator: no wait", False, False, 0.0, tm.GoOn()),
]))
def test_end_wait(ended, present, now, expected):
    assert tm.end_wait(ended, present, 0.0, now, 10.0) == expected


# --------------------------------------------------------------------------- retries [P-5.2]

@pytest.mark.parametrize("failed, now, expected", rows([
    ("not tried yet", None, 0.0, tm.Attempt()),
    ("failed: wait the retry interval", 2.0, 2.1, tm.Wait(2.2)),
    ("the retry interval passed", 2.0, 2.2, tm.Attempt()),
    ("the retry falls after the timeout: wait to it", 29.9, 29.95, tm.Wait(30.0)),
    ("the timeout since the first try", 29.0, 30.0, tm.GiveUp("timeout")),
]))
def test_retry(failed, now, expected):
    assert tm.retry(0.0, failed, now, 30.0, 0.2) == expected


# --------------------------------------------------------------------------- a Hello said again [P-5.14]

@pytest.mark.parametrize("unanswered, answers, present, tries, now, expected", rows([
    ("[P-5.14] answered: nothing to do", False, True, True, 0, 100.0, tm.Wait()),
    ("[P-5.14] no Hello yet: nothing to do", None, True, True, 0, 100.0, tm.Wait()),
    ("[P-5.14] unanswered, before the retry time", True, True, True, 0, 14.9, tm.Wait(15.0)),
    ("[P-5.14] unanswered for the retry time: again", True, True, True, 0, 15.0, tm.Attempt()),
    ("[P-5.14] said again once: twice the retry time", True, True, True, 1, 20.0, tm.Wait(25.0)),
    ("[P-5.14] said again twice: four times", True, True, True, 2, 44.9, tm.Wait(45.0)),
    ("[P-5.14] four times the retry time passed", True, True, True, 2, 45.0, tm.Attempt()),
    ("[P-5.14] a coordinator of revision 1 or 2 sends no answer: never again", True, False, True, 0, 1e9, tm.Wait()),
    ("[P-5.14] the coordinator's token absent: its return is a Resync", True, True, False, 0, 1e9, tm.Wait()),
]))
def test_hello_again(unanswered, answers, present, tries, now, expected):
    assert tm.hello_again(unanswered, answers, present, 5.0, tries, now, 10.0) == expected


def test_hello_again_is_bounded():
    """[P-5.14] the interval doubles: a Hello never answered is said again a logarithmic number of
    times in a mission of any length."""
    sent, tries, now, said = 0.0, 0, 0.0, 0
    while now < 1e6:
        rule = tm.hello_again(True, True, True, sent, tries, now, DEFAULTS.hello_s)
        if isinstance(rule, tm.Attempt):
            sent, tries, said = now, tries + 1, said + 1
        else:
            now = rule.until
    assert said == 16  # 10 s · (2^16 - 1) < 1e6 s < 10 s · (2^17 - 1)


@pytest.mark.parametrize("mode, failed, now, expected", rows([
    ("[P-5.2] the first query", "hybrid", None, 0.0, tm.AskState()),
    ("[P-5.2] no reply: again 0.2 s later", "coordinated", 2.0, 2.0 + STATE_RETRY_S, tm.AskState()),
    ("[P-5.2] no reply: not sooner", "coordinated", 2.0, 2.1, tm.Wait(2.0 + STATE_RETRY_S)),
    ("[P-5.5] 4: hybrid, none within the coordinator timeout: from its own log", "hybrid", 29.0, 30.0,
     tm.DecideAlone()),
    ("[P-5.5] 4: coordinated, none within the coordinator timeout: exit", "coordinated", 29.0, 30.0,
     tm.GiveUp("coordinator-lost")),
]))
def test_state_query(mode, failed, now, expected):
    assert tm.state_query(mode, 0.0, failed, now, 30.0, STATE_RETRY_S) == expected


# --------------------------------------------------------------------------- pace and hold

@pytest.mark.parametrize("sim_s, realtime, now, expected", rows([
    ("unpaced: at once", 10.0, 0.0, 0.0, tm.GoOn()),
    ("paced: sim_s / F after since", 10.0, 2.0, 104.0, tm.Wait(105.0)),
    ("paced: due", 10.0, 2.0, 105.0, tm.GoOn()),
]))
def test_pace(sim_s, realtime, now, expected):
    assert tm.pace(100.0, sim_s, realtime, now) == expected


@pytest.mark.parametrize("live, now, expected", rows([
    ("[P-6.5] a carrier is live: go on", True, 0.0, tm.GoOn()),
    ("[P-6.5] nobody live: hold", False, 19.0, tm.Wait(20.0)),
    ("[P-6.5] nobody live for the join timeout: go on", False, 20.0, tm.GoOn()),
]))
def test_hold(live, now, expected):
    assert tm.hold(live, 0.0, now, 20.0) == expected


@pytest.mark.parametrize("now, expected", rows([
    ("[P-7.2] outranked: waited for the grace", 125.0, tm.Wait(150.0)),
    ("[P-7.2] outranked for the grace: absent", 150.0, tm.GoOn()),
]))
def test_outranked(now, expected):
    assert tm.outranked(120.0, now, 30.0) == expected


@pytest.mark.parametrize("rule, until, expected", [
    ("[network] silent for less than the lease: the session holds", 1.5, False),
    ("[network] silent for the lease exactly: it holds", 3.0, False),
    ("[network] silent past the lease: it lapses", 3.5, True),
])
def test_lapses(rule, until, expected):
    assert tm.lapses(0.0, until, 3.0) is expected


def test_no_time_difference_is_compared_outside_the_rules():
    """Every wait of a carrier, a coordinator and the simulator is a rule of mission.timers: no
    comparison of a difference of two times (``now - self.opened >= t.coordinator_s``) is left in
    carriers/, coordinator/ or mission/simulate/ (a difference with a constant, an index's ``j -
    1`` or a tolerance, is not one)."""
    import ast
    from pathlib import Path

    root = Path(tm.__file__).resolve().parents[1]
    found = []
    for folder in ("carriers", "coordinator", "mission/simulate"):
        for path in sorted((root / folder).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.Compare):
                    found += [f"{path.relative_to(root)}:{node.lineno}: {ast.unparse(node)}"
                              for side in (node.left, *node.comparators)
                              if isinstance(side, ast.BinOp) and isinstance(side.op, ast.Sub)
                              and not isinstance(side.left, ast.Constant) and not isinstance(side.right, ast.Constant)]
    assert not found, found


def test_no_rule_reads_a_clock():
    """Time is an input: mission.timers imports no clock (nor anything that reads one)."""
    import ast
    import inspect

    tree = ast.parse(inspect.getsource(tm))
    imported = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    imported |= {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module}
    assert imported <= {"__future__", "math", "dataclasses", "peers", "modes"}, imported


@pytest.mark.parametrize("module", ["mission.carrier_life", "mission.coordinator_life"])
def test_no_lifecycle_reads_a_clock(module):
    """Time is an input of the lifecycle machines too: they import no clock, nor any I/O."""
    import ast
    import importlib
    import inspect

    tree = ast.parse(inspect.getsource(importlib.import_module(module)))
    imported = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    imported |= {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module}
    assert imported <= {"__future__", "math", "dataclasses", "enum", "typing", None, "timeouts", "modes", "evolve"}, imported
