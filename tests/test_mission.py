"""The mission state machines without sockets: tables of events in, state and effects out.

Mission: carriers a (2 passengers, scheduled at stages 0..2) and b (1 passenger, stages 1..2),
3 stages 5 s apart, fingerprint "fp". Recovery is checked as the same fold: fold live events,
persist what they say to record, reload mission.db, fold again: equal state, equal summary.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mission.ballot import Ballot
from mission import carrier as mc
from mission import peers as mission_peers
from mission import events as ev
from mission import state as ms

SPEC = ms.MissionSpec.build(("a", "b"), [[True, True, True], [False, True, True]], (2, 1), (0.0, 5.0, 10.0), "fp")


def hello(cid, fp="fp", at=1.0, next_stage=0):
    return ev.Hello(cid, 100, "host", 2, next_stage, fp, at)


def obs(cid, j, x, t=None, at=2.0):
    return ev.Observation(cid, j, SPEC.stage_times[j] if t is None else t, x, (1.0, 2.0), 2, ((0.5, 2.0),), at)


def live(cid, alive=True, at=1.0):
    return ev.LivelinessChanged(cid, alive, at)


def decide(j, deploy=(), at=3.0):
    return ev.Decided(j, tuple(deploy), 1.5, at)


def confirm(cid, j, deployed, status, at=4.0):
    return ev.Confirmed(cid, j, deployed, status, (1.0, 2.0), 1, at)


READY = [ev.Opened(0.0), live("a"), live("b"), hello("a"), hello("b")]


def run(events):
    """Fold ``events``; the state and the effects of the last one."""
    state, effects = ms.initial(SPEC), ()
    for e in events:
        state, effects = ms.step(state, e)
    return state, effects


def rejected(effects):
    return [e.reason for e in effects if isinstance(e, ms.Reject)]


def recorded(effects):
    return [e.event for e in effects if isinstance(e, ms.Record)]


# --------------------------------------------------------------------------- observations
OBSERVATION_CASES = [
    # id, events before, the event, rejection reason (None = accepted), (carrier, stage) -> x after
    ("accepted", READY, obs("a", 0, 3), None, {("a", 0): 3}),
    ("duplicate", READY + [obs("a", 0, 3)], obs("a", 0, 9), "duplicate", {("a", 0): 3}),
    ("identical-repeat", READY + [obs("a", 0, 3)], obs("a", 0, 3, at=2.5), "", {("a", 0): 3}),
    ("stale", READY + [decide(0)], obs("a", 0, 3), "stale-stage", {}),
    ("identical-repeat-after-decision", READY + [obs("a", 0, 3), decide(0)], obs("a", 0, 3, at=2.5), "",
     {("a", 0): 3}),
    ("different-after-decision", READY + [obs("a", 0, 3), decide(0)], obs("a", 0, 4), "stale-stage", {("a", 0): 3}),
    ("future", READY, obs("a", 1, 99), "future-stage", {}),
    ("future-then-real", READY + [obs("a", 1, 99), obs("a", 0, 3), decide(0)], obs("a", 1, 4), None,
     {("a", 0): 3, ("a", 1): 4}),
    ("unscheduled-empty-after-decision", READY + [decide(0)], obs("b", 0, None), "", {}),
    ("wrong-time", READY, obs("a", 0, 3, t=0.5), "out-of-range", {}),
    ("stage-out-of-range", READY, ev.Observation("a", 3, 15.0, 1, (0.0, 0.0), 2), "out-of-range", {}),
    ("unknown-carrier", READY, ev.Observation("z", 0, 0.0, 1, (0.0, 0.0), 1), "unknown-carrier", {}),
    ("no-hello", [ev.Opened(0.0), live("a")], obs("a", 0, 3), "no-hello", {}),
    ("refused-hello", [ev.Opened(0.0), live("a"), hello("a", fp="other")], obs("a", 0, 3), "world-mismatch", {}),
]


@pytest.mark.parametrize("before,event,reason,after", [c[1:] for c in OBSERVATION_CASES],
                         ids=[c[0] for c in OBSERVATION_CASES])
def test_observation_rules(before, event, reason, after):
    state, _ = run(before)
    new, effects = ms.step(state, event)
    if reason is None:
        assert rejected(effects) == [] and recorded(effects) == [event]
    elif reason == "":
        assert effects == () and new is state  # expected and harmless: neither kept nor counted
    else:
        assert rejected(effects) == [reason] and new is state
    assert new.reported == after


def test_a_value_sent_before_its_stage_never_decides_anything():
    """The hole: x = 99 for stage 1 sent while stage 0 is collected must not be the stage-1 value."""
    state, _ = run(READY + [obs("a", 1, 99), obs("a", 0, 3), decide(0), obs("a", 1, 4), obs("b", 1, 2)])
    assert state.observations()[0, 1] == 4


# --------------------------------------------------------------------------- the stage clock
CLOCK_CASES = [
    # id, events, stage, expected carriers, waiting carriers
    ("all-expected", READY, 1, {"a", "b"}, {"a", "b"}),
    ("unscheduled-not-expected", READY, 0, {"a"}, {"a"}),
    ("accepted-observation", READY + [obs("a", 0, 3)], 0, {"a"}, set()),
    ("crash", READY + [live("a", False)], 1, {"b"}, {"b"}),
    ("rejoin", READY + [live("a", False), live("a"), hello("a", at=5.0)], 1, {"a", "b"}, {"a", "b"}),
    ("no-hello-not-expected", [ev.Opened(0.0), live("a"), live("b"), hello("b")], 1, {"b"}, {"b"}),
    ("refused-not-expected", [ev.Opened(0.0), live("a"), live("b"), hello("a", fp="x"), hello("b")], 1, {"b"}, {"b"}),
    ("restart-forgets-liveliness", READY + [ev.Opened(9.0)], 1, set(), set()),
]


@pytest.mark.parametrize("events,j,expected,waiting", [c[1:] for c in CLOCK_CASES], ids=[c[0] for c in CLOCK_CASES])
def test_stage_clock_predicates(events, j, expected, waiting):
    state, _ = run(events)
    assert state.expected(j) == expected and state.waiting(j) == waiting
    assert state.stage_complete(j) == (not waiting)


def test_who_is_waited_for_is_remembered_in_the_state():
    """One home for who a wait is still for: ``waited_for`` / ``confirms_awaited`` split it by
    Progress [P-10.4] and are remembered in the state (the same state answers with the same
    object); ``expected`` is handed on to the states made from it while live, accepted and
    accounts are the same objects; two coordinators' states (two lineages) keep their own."""
    loud = ev.Hello("a", 100, "host", 2, 0, "fp", 1.0, ms.PROGRESS_REVISION)
    quiet = ev.Hello("b", 100, "host", 2, 0, "fp", 1.0, ms.PROGRESS_REVISION - 1)  # sends no Progress
    state, _ = run([ev.Opened(0.0), live("a"), live("b"), loud, quiet])
    assert state.waited_for(1) == ({"a"}, {"b"}) and state.waited_for(1) is state.waited_for(1)
    assert state.confirms_awaited(0) == ({"a"}, {"b"})
    after, _ = ms.step(state, obs("a", 0, 3))
    assert after.waited_for(0) == (frozenset(), frozenset()) and state.waited_for(0) == ({"a"}, frozenset())
    assert after.expected(1) is state.expected(1)
    other, _ = run(READY)
    assert other.expected(1) == {"a", "b"} and after.expected(1) is state.expected(1)
    gone, _ = ms.step(after, live("b", False))
    assert gone.waited_for(1) == ({"a"}, frozenset()) and gone.expected(1) == {"a"}


def test_the_clock_predicates_follow_every_event():
    """expected(j) is remembered for its inputs (mission.state._Expected): after each event of a
    mission with a crash, a rejoin, a Hello from a later stage and an account, every stage's
    expected, waiting and unconfirmed equal a count from scratch, asked of the new state and the
    one before it in turns."""
    def scratch(st, j):
        exp = frozenset(cid for r, cid in enumerate(SPEC.carriers) if SPEC.valid[r][j] and cid in st.live
                        and cid in st.accepted and not st.passed(cid, j))
        return (exp, frozenset(c for c in exp if (c, j) not in st.reported),
                frozenset(c for c in st.live if (c, j) not in st.confirms
                          and not (c in st.accepted and st.accepted[c].next_stage > j)))

    own = ev.Accounted("b", 1, 5.0, 2, False, (1.0, 2.0), 1, 6.0)
    events = READY + [obs("a", 0, 3), decide(0, ("a",)), confirm("a", 0, True, "deployed"), live("b", False),
                      obs("a", 1, 1), live("b"), hello("b", at=5.0, next_stage=1), own, decide(1),
                      confirm("a", 1, False, "idle"), obs("a", 2, 0), obs("b", 2, 4), decide(2)]
    for j in range(SPEC.n_stages):  # one stage asked through a whole mission, as a wait does
        state = ms.initial(SPEC)
        for e in events:
            previous, (state, _) = state, ms.step(state, e)
            for st in (state, previous, state):
                assert (st.expected(j), st.waiting(j), st.unconfirmed(j)) == scratch(st, j), (e, j)
                assert set().union(*st.waited_for(j)) == st.waiting(j)
                assert set().union(*st.confirms_awaited(j)) == st.unconfirmed(j)


def test_a_carrier_that_joined_after_the_last_stage_is_not_waited_for_its_confirm():
    """[P-10.3] b's Hello names a stage past the last one: it has nothing to confirm, and the wait
    for the last stage's Confirms is for a alone (it waited out b's end wait: 10 s)."""
    last = SPEC.n_stages - 1
    events = READY[:-1] + [obs("a", 0, 3), decide(0), obs("a", 1, 1), decide(1), obs("a", 2, 0), decide(2),
                           hello("b", at=20.0, next_stage=SPEC.n_stages)]
    state, _ = run(events)  # READY without b's Hello of stage 0
    assert "b" in state.live and state.accepted["b"].next_stage == SPEC.n_stages
    assert state.unconfirmed(last) == {"a"}


def test_no_carrier_is_taken_to_deploy_more_passengers_than_it_has():
    """[P-6.15] b carries one passenger and confirmed its release at stage 1: an Own or a
    Confirm of another deployment (a lying or broken carrier) is refused ``out-of-range`` and
    the planner's view keeps b within its one passenger."""
    base = READY + [decide(0), obs("b", 1, 3), decide(1, ("b",)), confirm("b", 1, True, "deployed")]
    state, _ = run(base)
    lie = ev.Accounted("b", 2, 10.0, 9, True, (1.0, 2.0), 0, 6.0)
    after, effects = ms.step(state, lie)
    assert after is state and [(e.reason) for e in effects if isinstance(e, ms.Reject)] == ["out-of-range"]
    state, _ = run(base + [obs("b", 2, 4), decide(2, ("b",))])
    after, effects = ms.step(state, confirm("b", 2, True, "deployed"))
    assert [e.reason for e in effects if isinstance(e, ms.Reject)] == ["out-of-range"]
    assert after.deployed()[SPEC.index("b")].sum() <= 1
    # Not deploying is always believed; a carrier with a passenger left is believed.
    assert not [e for e in ms.step(state, confirm("b", 2, False, "idle"))[1] if isinstance(e, ms.Reject)]
    state, _ = run(READY + [decide(0, ("a",)), confirm("a", 0, True, "deployed")])
    assert not [e for e in ms.step(state, ev.Accounted("a", 1, 5.0, 2, True, (1.0, 2.0), 0, 6.0))[1]
                if isinstance(e, ms.Reject)]


def test_missing_carrier_is_empty_and_recorded_with_the_decision():
    state, effects = run(READY + [decide(0, ())])
    assert (("a", 0) in state.missing) and state.missing_stages("a") == [0]
    assert [type(e) for e in effects] == [ms.Record, ms.Publish]  # stored before published
    assert effects[0].missing == ("a",)
    assert state.next_stage == 1 and state.observations()[0, 0] != state.observations()[0, 0]  # NaN


def test_a_stage_is_decided_once_and_in_order():
    state, _ = run(READY + [decide(0)])
    with pytest.raises(ValueError):
        ms.step(state, decide(0))
    with pytest.raises(ValueError):
        ms.step(state, decide(2))


def test_join_waits_for_tokens_and_hellos():
    assert not run([ev.Opened(0.0), live("a"), live("b"), hello("a")])[0].all_joined()
    assert run(READY)[0].all_joined()
    assert run([ev.Opened(0.0), live("a"), hello("a"), hello("b", fp="x")])[0].all_joined()


# --------------------------------------------------------------------------- Hello
def test_refused_hello_gets_an_explicit_refusal():
    state, effects = run([ev.Opened(0.0), live("a"), hello("a", fp="other")])
    assert "a" not in state.accepted and state.refused == {"a": "other"}
    refusals = [e for e in effects if isinstance(e, ms.Refuse)]
    assert refusals == [ms.Refuse("a", "other", "world-mismatch", refusals[0].detail)]
    assert rejected(effects) == ["world-mismatch"]


def test_a_later_bad_hello_never_undoes_an_accepted_one():
    state, effects = run(READY + [hello("a", fp="other", at=7.0)])
    assert state.accepted["a"] == ms.CarrierInfo(100, "host", 0) and "a" not in state.refused
    assert any(isinstance(e, ms.Refuse) for e in effects) and recorded(effects) == []
    assert state.expected(1) == {"a", "b"}
    state, _ = ms.step(state, obs("a", 0, 3))
    assert state.reported[("a", 0)] == 3  # its observations still count


def test_a_good_hello_after_a_refusal_is_accepted():
    state, _ = run([ev.Opened(0.0), live("a"), hello("a", fp="other"), hello("a")])
    assert "a" in state.accepted and state.refused == {}


# --------------------------------------------------------------------------- Confirm
CONFIRM_CASES = [
    # id, events before, the event, rejection reason (None = accepted, "" = absorbed)
    ("accepted", READY + [obs("a", 0, 3), decide(0, ["a"])], confirm("a", 0, True, "deployed"), None),
    ("undecided", READY, confirm("a", 0, False, "idle"), "stale-stage"),
    ("out-of-range", READY, confirm("a", 3, False, "idle"), "out-of-range"),
    ("no-hello", [ev.Opened(0.0), live("a")], confirm("a", 0, False, "idle"), "no-hello"),
    ("repeat-same", READY + [decide(0, ()), confirm("a", 0, False, "idle")], confirm("a", 0, False, "late"), ""),
    ("already", READY + [decide(0, ()), confirm("a", 0, False, "idle")], confirm("a", 0, True, "already"), ""),
    ("contradiction", READY + [decide(0, ()), confirm("a", 0, False, "idle")], confirm("a", 0, True, "deployed"),
     "duplicate"),
]


@pytest.mark.parametrize("before,event,reason", [c[1:] for c in CONFIRM_CASES], ids=[c[0] for c in CONFIRM_CASES])
def test_confirm_rules(before, event, reason):
    state, _ = run(before)
    new, effects = ms.step(state, event)
    if reason is None:
        assert rejected(effects) == [] and recorded(effects) == [event]
    elif reason == "":
        assert effects == () and new is state
    else:
        assert rejected(effects) == [reason] and new is state


def test_late_confirm_refutes_the_deployment():
    state, _ = run(READY + [obs("a", 0, 3), decide(0, ["a"]), ev.Published(0, 3.5)])
    assert state.deployed()[0, 0] and state.passengers_left()[0] == 1
    state, effects = ms.step(state, confirm("a", 0, False, "late", at=3.6))
    assert not state.deployed()[0, 0] and state.passengers_left()[0] == 2
    assert state.confirms[("a", 0)].latency_ms == pytest.approx(100.0)
    assert any(isinstance(e, ms.Log) and "did not deploy" in e.line for e in effects)


def test_stopped_mission_resumes_complete_one_stays_ended():
    stopped, _ = run(READY + [ev.Ended("stopped", 5.0), ev.Opened(6.0)])
    assert not stopped.ended and stopped.resumed
    complete, _ = run(READY + [ev.Ended("complete", 5.0), ev.Opened(6.0)])
    assert complete.ended and complete.end_reason == "complete"


# --------------------------------------------------------------------------- recovery = the same fold
def _mission_events():
    return [
        live("a", at=1.0), live("b", at=1.1), hello("a", at=1.2), hello("b", at=1.3, next_stage=0),
        obs("a", 0, 6, at=2.0), obs("z", 0, 1, at=2.05), decide(0, ["a"], at=2.1), ev.Published(0, 2.2),
        confirm("a", 0, True, "deployed", at=2.3), obs("a", 1, 1, at=3.0), obs("b", 1, 4, at=3.1),
        confirm("a", 0, True, "already", at=3.15), decide(1, ["b"], at=3.2), ev.Published(1, 3.3),
        confirm("a", 1, False, "idle", at=3.4), confirm("b", 1, True, "deployed", at=3.45),
        live("a", False, at=3.5), obs("b", 2, 2, at=4.0), decide(2, [], at=4.1), ev.Published(2, 4.2),
        confirm("b", 2, False, "idle", at=4.3), ev.Ended("complete", 4.4),
        ev.Bye("b", (1,), (("duplicate", 1),), "end", 4.5),
    ]


def test_recovery_is_the_same_fold(tmp_path):
    from planner.problem import Problem
    from storage.missiondb import MissionStore, load_events
    from mission.summary import RunInfo, summary
    import numpy as np
    from scipy import stats

    store = MissionStore(tmp_path / "mission.db", {"mission": "m"})
    live_state = ms.fold(SPEC, store.mission_events())  # the store's own "open"
    for e in _mission_events():
        live_state, effects = ms.step(live_state, e)
        for effect in effects:
            if isinstance(effect, ms.Record):
                store.record(effect, live_state)
    store.close()
    replayed = ms.fold(SPEC, load_events(tmp_path / "mission.db"))
    assert replayed == live_state
    assert replayed.decided().tolist() == [[True, False, False], [False, True, False]]
    assert replayed.confirmed_deployments().sum() == 2 and replayed.live == {"b"}

    problem = Problem.build(np.array(SPEC.passengers), np.array(SPEC.valid), [], stats.poisson(3.0))
    run_info = RunInfo("m", "m.yaml", "m", "ssap", {}, 7, 1, "h", 1.0, {})
    assert summary(replayed, problem, run_info) == summary(live_state, problem, run_info)
    assert summary(live_state, problem, run_info)["latency_ms"]["count"] == 4  # deployed/idle with a publication


# --------------------------------------------------------------------------- the carrier's side
P0 = (1.0, 2.0)


def carrier(*events, passengers=2, valid=(True, True, True)):
    state = mc.initial("a", valid, (0.0, 5.0, 10.0), passengers)
    effects = ()
    for e in events:
        state, effects = mc.step(state, e)
    return state, effects


def confirms(effects):
    return [(e.stage, e.status, e.deployed) for e in effects if isinstance(e, mc.SendConfirm)]


def heard(j, deploy=("a",), t=None):
    return mc.DecisionHeard(j, (0.0, 5.0, 10.0)[j] if t is None else t, tuple(deploy), P0)


JOINED = [mc.Joined(0)]

CARRIER_CASES = [
    # id, events before, the event, confirms sent [(stage, status, deployed)], rejection reason
    ("deployed", JOINED + [mc.Observed(0)], heard(0), [(0, "deployed", True)], None),
    ("idle", JOINED + [mc.Observed(0)], heard(0, ()), [(0, "idle", False)], None),
    ("duplicate-already", JOINED + [mc.Observed(0), heard(0)], heard(0, ()), [(0, "already", True)], None),
    ("late-after-timeout", JOINED + [mc.Observed(0), mc.MovedOn(0), mc.Observed(1)], heard(0),
     [(0, "late", False)], None),
    ("before-join-selected", [mc.Joined(2)], heard(0), [(0, "late", False)], None),
    ("before-join-not-selected", [mc.Joined(2)], heard(1, ()), [(1, "idle", False)], None),
    ("future-held", JOINED + [mc.Observed(0)], heard(1), [], None),
    ("future-repeat-held", JOINED + [mc.Observed(0), heard(1)], heard(1), [], None),
    ("future-repeat-answered", JOINED + [mc.Observed(0), heard(1), heard(1), heard(0), mc.MovedOn(0)],
     mc.Passed(1, P0), [(1, "deployed", True), (1, "already", True)], None),
    ("out-of-range", JOINED, mc.DecisionHeard(3, 15.0, ("a",), P0), [], "out-of-range"),
    ("wrong-time", JOINED + [mc.Observed(0)], heard(0, t=1.0), [], "out-of-range"),
]


@pytest.mark.parametrize("before,event,sent,reason", [c[1:] for c in CARRIER_CASES], ids=[c[0] for c in CARRIER_CASES])
def test_carrier_decision_rules(before, event, sent, reason):
    state, _ = carrier(*before)
    new, effects = mc.step(state, event)
    assert confirms(effects) == sent
    assert [e.reason for e in effects if isinstance(e, mc.Reject)] == ([reason] if reason else [])


def test_a_rejected_decision_does_not_raise_the_epoch():
    state, _ = carrier(*JOINED)
    for bad in (mc.DecisionHeard(3, 15.0, ("a",), P0, epoch=5), mc.DecisionHeard(0, 1.0, ("a",), P0, epoch=5)):
        new, effects = mc.step(state, bad)
        assert new.epoch == state.epoch and [e.reason for e in effects if isinstance(e, mc.Reject)] == ["out-of-range"]
    new, _ = mc.step(state, mc.DecisionHeard(0, 0.0, ("a",), P0, epoch=5))
    assert new.epoch == 5


def test_carrier_deploys_once_and_never_beyond_its_passengers():
    state, effects = carrier(*JOINED, mc.Observed(0), heard(0), passengers=1)
    kinds = [type(e) for e in effects]
    assert kinds[:2] == [mc.LogOutcome, mc.Deploy] and state.passengers_left == 0  # on record before it acts
    state, _ = mc.step(state, mc.MovedOn(0))
    state, _ = mc.step(state, mc.Observed(1))
    state, effects = mc.step(state, heard(1))
    assert confirms(effects) == [(1, "refused", False)] and not any(isinstance(e, mc.Deploy) for e in effects)
    assert state.deployments() == (0,)


def test_carrier_unscheduled_stage_is_refused():
    _, effects = carrier(*JOINED, mc.Observed(0), heard(0), valid=(False, True, True))
    assert confirms(effects) == [(0, "refused", False)]


def test_carrier_behind_answers_the_held_decision_on_passing():
    state, _ = carrier(*JOINED, mc.Observed(0), heard(0, ()), mc.MovedOn(0), heard(1))
    assert state.behind(1)
    state, effects = mc.step(state, mc.Passed(1, P0))
    assert confirms(effects) == [(1, "deployed", True)] and state.stage == 2


def test_carrier_resends_its_observation_when_the_coordinator_catches_up():
    """It gave up waiting for stage 0 and observed stage 1 (rejected as future-stage); the late
    decision of stage 0 tells it stage 1 is now being collected: it sends the observation again."""
    state, effects = carrier(*JOINED, mc.Observed(0), mc.MovedOn(0), mc.Observed(1), heard(0, ()))
    assert confirms(effects) == [(0, "idle", False)] and mc.ResendObservation(1) in effects


def test_carrier_that_decided_alone_resends_its_observation_when_the_coordinator_catches_up():
    """Cut off, it decided stage 0 on its own and went on to stage 1; the coordinator, back, was
    still at stage 0 (the Observation of 1 was rejected as future-stage). Its Decision of 0
    (answered ``already`` with the own outcome) tells the carrier that 1 is being collected now:
    the Observation goes out again, or the coordinator would wait for it while the carrier waits
    for the Decision (found by tests/test_no_spof.py on the sim clock)."""
    state, effects = carrier(*JOINED, mc.Observed(0), mc.DecidedOwn(0, True, P0), mc.MovedOn(0), mc.Observed(1),
                             heard(0, ()))
    assert confirms(effects) == [(0, "already", True)] and mc.ResendObservation(1) in effects
    # Nothing is resent for a stage it is not waiting at, nor once the coordinator is past it.
    _, effects = carrier(*JOINED, mc.Observed(0), mc.DecidedOwn(0, True, P0), heard(0, ()))
    assert not any(isinstance(e, mc.ResendObservation) for e in effects)
    _, effects = mc.step(state, heard(1, ()))
    assert not any(isinstance(e, mc.ResendObservation) for e in effects)


def test_carrier_resends_its_observation_while_state_says_its_stage_is_collected():
    """Sim clock: every --decision-timeout a waiting carrier asks State; if the coordinator still
    collects the carrier's stage it may never have had its Observation: sent again. Not for a
    deposed coordinator's State, another stage, or a stage already answered."""
    state, _ = carrier(*JOINED, mc.Observed(0), heard(0, ()), mc.MovedOn(0), mc.Observed(1))
    assert mc.step(state, mc.Collecting(1))[1] == (mc.ResendObservation(1),)
    assert mc.step(state, mc.Collecting(0))[1] == ()
    assert mc.step(dataclasses.replace(state, epoch=3), mc.Collecting(1, epoch=2))[1] == ()
    answered, _ = mc.step(state, heard(1))
    assert mc.step(answered, mc.Collecting(1))[1] == ()


def test_carrier_resync_after_the_coordinator_returns():
    state, _ = carrier(*JOINED, mc.Observed(0), heard(0, ()), mc.MovedOn(0), mc.Observed(1))
    seen = mc.StateSeen(next_stage=1, deployments=(), last_decision=(0, 0.0, ()), ended=False)
    state, effects = mc.step(state, mc.Resync(seen, P0))
    kinds = [type(e) for e in effects]
    assert mc.SendHello in kinds and mc.ResendObservation(1) in effects
    assert confirms(effects) == [(0, "already", False)]
    # A deployment on record it never received is answered late (the passenger is on board).
    state2, effects = mc.step(state, mc.Resync(mc.StateSeen(2, (1,), None, False), P0))
    assert (1, "late", False) in confirms(effects) and state2.passengers_left == 2



def test_carrier_ignores_a_deposed_coordinators_decisions():
    """Epochs (docs/protocol.md, "Epochs"): once epoch 2 was heard (State at join, a Decision, a
    Resync), a Decision of epoch 1 is rejected as ``deposed``, unanswered and without effect; a
    State of a lower epoch teaches nothing; equal and higher epochs are handled as usual."""
    state, _ = carrier(mc.Joined(0, epoch=2), mc.Observed(0))
    assert state.epoch == 2
    new, effects = mc.step(state, mc.DecisionHeard(0, 0.0, ("a",), P0, epoch=1))
    # nothing changes but the note that the live coordinator is outranked (mission.carrier_life
    # takes it as absent until a current Decision or State comes)
    assert new == dataclasses.replace(state, outranked=True) and confirms(effects) == []
    assert [e.reason for e in effects if isinstance(e, mc.Reject)] == ["deposed"]
    new, effects = mc.step(state, mc.DecisionHeard(0, 0.0, ("a",), P0, epoch=3))
    assert confirms(effects) == [(0, "deployed", True)] and new.epoch == 3
    _, effects = mc.step(new, mc.DecisionHeard(0, 0.0, ("a",), P0, epoch=2))
    assert confirms(effects) == [] and [e.reason for e in effects if isinstance(e, mc.Reject)] == ["deposed"]
    # A stale State (epoch 1) after epoch 3: its next_stage and last decision are not taken.
    stale = mc.StateSeen(next_stage=2, deployments=(1,), last_decision=(1, 5.0, ("a",)), ended=True, epoch=1)
    back, effects = mc.step(new, mc.Resync(stale, P0))
    assert back.state_next == new.state_next and not back.ended and 1 not in back.handled
    # A Decision without an epoch (an earlier coordinator) is epoch 1: fine while nothing higher was heard.
    fresh, _ = carrier(*JOINED, mc.Observed(0))
    _, effects = mc.step(fresh, heard(0))
    assert confirms(effects) == [(0, "deployed", True)]


def test_a_ballot_ranks_two_coordinators_of_one_epoch():
    """Ballots (docs/protocol.md [P-7.2], revision 6): (epoch, coordinator id), compared in that
    order; an unstated id (a coordinator of revision 5 or earlier, or a broadcast in revision 5)
    ranks neither above nor below a stated one of its epoch."""
    assert Ballot(2, "coordinator").below(Ballot(2, "standby"))
    assert not Ballot(2, "standby").below(Ballot(2, "coordinator"))
    assert Ballot(2, "standby").below(Ballot(3, "coordinator")) and Ballot(1).below(Ballot(2, "a"))
    assert not Ballot(2).below(Ballot(2, "standby")) and not Ballot(2, "standby").below(Ballot(2))
    assert Ballot(2).highest(Ballot(2, "standby")) == Ballot(2, "standby") == Ballot(2, "standby").highest(Ballot(2))
    # The standby took epoch 2 and decided stage 0; the primary restarted on its staler disk
    # with epoch 2 again: its Decisions and End are rejected, and the carrier takes the live
    # coordinator as outranked until a current Decision or State comes.
    state, _ = carrier(mc.Joined(0, epoch=2, coordinator="standby"), mc.Observed(0))
    state, effects = mc.step(state, mc.DecisionHeard(0, 0.0, ("a",), P0, 2, "standby"))
    assert confirms(effects) == [(0, "deployed", True)] and state.ballot == Ballot(2, "standby")
    stale, effects = mc.step(state, mc.DecisionHeard(1, 5.0, ("a",), P0, 2, "coordinator"))
    assert confirms(effects) == [] and [e.reason for e in effects if isinstance(e, mc.Reject)] == ["deposed"]
    assert stale.outranked and 1 not in stale.buffered
    ended, effects = mc.step(stale, mc.EndHeard(2, "coordinator"))
    assert not ended.ended and [e.reason for e in effects if isinstance(e, mc.Reject)] == ["deposed"]
    back, effects = mc.step(stale, mc.DecisionHeard(1, 5.0, (), P0, 3, "coordinator"))
    assert not back.outranked and back.ballot == Ballot(3, "coordinator")
    # A revision 5 broadcast (no id) of the same epoch is current, as before ballots.
    same, effects = mc.step(state, mc.DecisionHeard(1, 5.0, (), P0, 2))
    assert not same.outranked and same.ballot == Ballot(2, "standby")


# --------------------------------------------------------------------------- passengers, epochs, presence
@pytest.mark.parametrize("named, released, count, expected", [
    (None, (), 3, 0),          # a stage decided on board names none: the lowest index on board
    (2, (), 3, 2),             # the named passenger, still on board
    (2, (2,), 3, 0),           # named, but released already: the lowest on board
    (1, (0, 1), 3, 2),
    (5, (), 3, 0),             # an index the carrier does not have
    (None, (0, 1, 2), 3, 0),   # none left (the machine refuses it before): 0
], ids=["none", "named", "named-gone", "lowest-left", "out-of-range", "none-left"])
def test_passenger_for(named, released, count, expected):
    assert mc.passenger_for(named, released, count) == expected


@pytest.mark.parametrize("heard, epoch, current", [(0, 1, True), (2, 2, True), (2, 3, True), (2, 1, False)],
                         ids=["nothing-heard", "equal", "newer", "deposed"])
def test_current_epoch(heard, epoch, current):
    state = dataclasses.replace(mc.initial("a", [True], [0.0], 1), epoch=heard)
    assert mc.current(state, epoch) is current


@pytest.mark.parametrize("events, taken, unanswered, refused", [
    ([], [], None, None),
    ([("sent",)], [], True, None),
    ([("sent",), ("accepted", "fp")], [True], False, None),
    ([("sent",), ("refused", "fp")], [True], False, "R"),
    ([("sent",), ("refused", "other")], [False], True, None),             # about someone else's Hello
    ([("sent",), ("accepted", "fp"), ("refused", "fp")], [True, False], False, None),  # after the answer
    ([("sent",), ("refused", "fp"), ("sent",), ("accepted", "fp")], [True, True], False, None),
    ([("refused", "fp")], [False], None, None),                            # no Hello sent
], ids=["none", "sent", "accepted", "refused", "other-fingerprint", "after-answer", "new-hello", "no-hello"])
def test_hello_answer(events, taken, unanswered, refused):
    answer = mc.HelloAnswer("fp")
    got = []
    for e in events:
        if e[0] == "sent":
            answer.sent()
        else:
            got.append(answer.answered(e[1], "R" if e[0] == "refused" else None))
    assert got == taken and answer.unanswered == unanswered and answer.refused == refused
    assert answer.said_hello == (unanswered is not None)


def test_releases_follow_the_current_decisions_naming():
    """The first naming of a current Decision counts; a deposed coordinator's is ignored; a
    released passenger is not released again."""
    releases = mc.Releases(3)
    state = dataclasses.replace(mc.initial("a", [True] * 4, [0.0, 1.0, 2.0, 3.0], 3), epoch=2)
    releases.name(state, 0, 1, 2)      # epoch 1 < 2: deposed, ignored
    releases.name(state, 0, 2, 1)
    releases.name(state, 0, 3, 2)      # a repeat for stage 0: the first naming stays
    releases.name(state, 1, 2, None)   # names none
    releases.name(state, 2, 2, 1)      # names one released already
    assert [releases.release(j) for j in (0, 1, 2)] == [1, 0, 2]
    assert releases.at(0) == 1 and releases.at(3) is None


@pytest.mark.parametrize("events, present, seen, absent_since, returned", [
    ([], False, False, 10.0, []),
    ([("alive",)], True, True, 10.0, [False]),
    ([("alive",), ("gone", 12.0)], False, True, 12.0, [False]),
    ([("alive",), ("gone", 12.0), ("alive",)], True, True, 12.0, [False, True]),
    ([("answered",)], True, True, 10.0, []),
    ([("alive",), ("gone", 12.0), ("answered",)], False, True, 12.0, [False]),
], ids=["start", "token", "token-gone", "came-back", "answered-at-join", "answered-after-seen"])
def test_presence_of_the_coordinator(events, present, seen, absent_since, returned):
    presence = mission_peers.Presence(10.0)
    came_back = []
    for e in events:
        if e[0] == "alive":
            came_back.append(presence.coordinator_alive())
        elif e[0] == "gone":
            presence.coordinator_gone(e[1])
        else:
            presence.coordinator_answered()
    assert (presence.coordinator_present, presence.coordinator_seen, presence.absent_since) == (
        present, seen, absent_since)
    assert came_back == returned
    assert presence.absent_for(20.0) == (0.0 if present else 20.0 - absent_since)


@pytest.mark.parametrize("heard, among, since, expected", [
    ({}, ["b"], 5.0, 5.0),                      # nothing heard: the wait's opening
    ({"b": 3.0}, ["b"], 5.0, 5.0),              # heard before the wait opened
    ({"b": 7.0, "c": 9.0}, ["b", "c"], 5.0, 9.0),
    ({"b": 7.0, "c": 9.0}, ["b"], 5.0, 7.0),    # only those waited for count
    ({"b": 7.0}, [], 5.0, 5.0),
], ids=["none", "before", "latest", "among-only", "nobody"])
def test_last_heard(heard, among, since, expected):
    assert mission_peers.last_heard(heard, among, since) == expected
    presence = mission_peers.Presence(0.0)
    for cid, at in heard.items():
        presence.heard_from(cid, at)
    assert presence.last_heard(among, since) == expected


def test_presence_of_peers():
    presence = mission_peers.Presence(0.0)
    presence.peer("b", True)
    presence.peer("c", True)
    presence.peer("b", False)
    presence.peer("d", False)
    assert presence.peers_live == {"c"}


# --------------------------------------------------------------------------- purity
FORBIDDEN = ("zenoh", "pymunk", "msgpack", "sqlite3", "world", "wire", "carriers", "coordinator.node",
             "storage.missiondb", "matplotlib")


def test_mission_imports_no_process_library():
    """Statically (every import statement, function bodies included) and in a fresh interpreter."""
    import ast
    import json
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    for path in (root / "mission").glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module] if isinstance(node, ast.ImportFrom) and node.level == 0 else [])
            for name in names:
                assert not any(name == f or name.startswith(f + ".") for f in FORBIDDEN), (path.name, name)
    code = ("import importlib, json, sys\n"
            "for m in ('mission', 'mission.events', 'mission.state', 'mission.carrier', 'mission.summary',"
            " 'mission.timeouts'):\n    importlib.import_module(m)\n"
            "print(json.dumps(sorted(sys.modules)))\n")
    proc = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    loaded = json.loads(proc.stdout.splitlines()[-1])
    assert [m for m in loaded if any(m == f or m.startswith(f + ".") for f in FORBIDDEN)] == []


def test_after_end_a_carrier_gone_without_its_bye_is_still_owed_one():
    """A carrier's Bye and the end of its token arrive on different subscriptions, in either
    order: once its token is gone it no longer counts as live (all_said_bye), but its Bye is
    still missing (bye_missing), which the coordinator waits a grace for."""
    state, _ = run(READY + [ev.Bye("a", (), (), "end", 3.0), live("b", False, 3.1)])
    assert state.all_said_bye() and state.bye_missing()
    state, _ = ms.step(state, ev.Bye("b", (), (), "end", 3.2))
    assert state.all_said_bye() and not state.bye_missing()


# ----------------------------------------------------------------------------- whom a carrier listens to
# A chain 0-1-2-3 of overlap groups and a separate pair 4-5; (component_max, carrier) -> listened.
LISTENED_CASES = [
    (64, 0, [1, 2, 3]),       # its whole component
    (64, 4, [5]),
    (2, 0, [1]),              # the component (4) is larger than 2: its direct neighbours only
    (2, 1, [0, 2]),
    (2, 4, [5]),              # a component of 2 is heard whole
]


@pytest.mark.parametrize("component_max,r,expected", LISTENED_CASES)
def test_listened_is_the_component_or_the_neighbours(component_max, r, expected):
    from mission.peers import conflict_adjacency, listened
    from planner.problem import Problem

    problem = Problem.build(2, [[True] * 3] * 6,
                            [[[0, 0], [1, 0]], [[1, 1], [2, 1]], [[2, 2], [3, 2]], [[4, 0], [5, 1]]])
    assert listened(problem, r, component_max) == expected
    # the process's shared conflict graph gives the same answer as the carrier's own
    assert listened(problem, r, component_max, adjacency=conflict_adjacency(problem)) == expected


def test_pair_map_is_a_mapping_that_set_never_changes():
    # mission.state.PairMap: the (carrier, stage) maps of the state; set() shares the other
    # stages' entries and leaves the map it was called on as it was.
    from mission.state import PairMap

    rng = np.random.default_rng(3)
    plain: dict = {}
    pm = PairMap()
    history = []
    for _ in range(200):
        key = (f"c{int(rng.integers(6))}", int(rng.integers(4)))
        value = int(rng.integers(100))
        history.append((pm, dict(plain)))
        pm = pm.set(key, value)
        plain[key] = value
        assert pm == plain and plain == pm and len(pm) == len(plain)
        assert pm[key] == value and key in pm and pm.get(("zz", 0)) is None and ("zz", 0) not in pm
    for old, snapshot in history:
        assert old == snapshot  # nothing changed the earlier maps
    assert PairMap(plain) == pm and set(pm) == set(plain) and dict(pm.items()) == plain
    with pytest.raises(KeyError):
        pm[("zz", 9)]
    assert "c1" not in pm and 5 not in pm


def test_a_decision_left_no_room_by_later_reports_is_not_taken_as_done():
    """Carrier a (2 passengers) was named at stages 0 and 2 with no answer, and reports deploying
    at stage 1: it has room for one of the two guesses only, the earlier one."""
    events = READY + [obs("a", 0, 3), decide(0, ["a"]), obs("a", 1, 3, at=7.0), obs("b", 1, 1, at=7.0),
                      decide(1, [], at=7.5), obs("a", 2, 3, at=12.0), obs("b", 2, 1, at=12.0),
                      decide(2, ["a"], at=12.5), confirm("a", 1, True, "already", at=13.0)]
    state, _ = run(events)
    assert state.decided()[0].tolist() == [True, False, True]
    assert state.deployed()[0].tolist() == [True, True, False]
    assert state.passengers_left().tolist() == [0, 1]
    assert state.releases()[0, 2] == -1


@pytest.mark.parametrize("listed, deployed", [((), False), ((0,), True)])
def test_a_bye_settles_the_decisions_its_carrier_did_not_answer(listed, deployed):
    """Carrier a was named at stage 0 and never answered; its Bye lists its deployments."""
    state, _ = run(READY + [obs("a", 0, 3), decide(0, ["a"])])
    assert state.deployed()[0, 0] and state.deployments_of("a") == [0]
    state, _ = ms.step(state, ev.Bye("a", listed, (), "end", 20.0))
    assert state.deployed()[0, 0] == deployed and state.deployments_of("a") == list(listed)
    assert state.passengers_left()[0] == 2 - len(listed)


def test_summary_names_and_defines_its_fields():
    """A deployment's ``features_over_p`` is its x / p (``features``, kept), summing to
    ``total_features``; ``wall_time_s`` comes with its definition; a plug-in's defaults are in
    the recorded options, so the run can be reproduced from its summary."""
    import numpy as np
    from scipy import stats

    from mission.summary import RunInfo, WALL_TIME_MEANING, summary
    from planner.problem import Problem
    from planner.registry import used_options

    state, _ = run(_mission_events())
    problem = Problem.build(np.array(SPEC.passengers), np.array(SPEC.valid), [[(0, 0), (1, 1)]], stats.poisson(3.0))
    out = summary(state, problem, RunInfo("m", "m.yaml", "m", "ssap", {}, 7, 1, "h", 1.0, {}), bound=False)
    deps = [d for c in out["carriers"] for d in c["deployments"]]
    assert deps and all(d["features_over_p"] == d["features"] for d in deps)
    assert sum(d["features_over_p"] for d in deps) == pytest.approx(out["total_features"])
    assert out["wall_time_meaning"] == WALL_TIME_MEANING and "coordinator" in WALL_TIME_MEANING
    assert used_options("planner_plugins:Threshold", {}) == {"cut": 3.0}
    assert used_options("planner_plugins:Threshold", {"cut": 5}) == {"cut": 5.0}
