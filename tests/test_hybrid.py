"""Carriers that decide without the coordinator: the pure parts (the coordinator's merge of the
carriers' own accounts, the carrier's own decisions, the peer book) and a decentralised fleet in
this process (real Zenoh sessions on loopback) against the centralised planner.

Mission of the pure tests (tests/test_mission.py's): carriers a (2 passengers, stages 0..2) and b
(1 passenger, stages 1..2), 3 stages 5 s apart.
"""
from __future__ import annotations

import threading

import numpy as np
import pytest

from mission import carrier as mc
from mission import events as ev
from mission import state as ms
from mission.peers import PeerBook
from test_mission import P0, READY, SPEC, carrier, confirm, confirms, decide, heard, hello, obs, rejected, run


def own(cid, j, x, deployed, at=5.0, left=1):
    return ev.Accounted(cid, j, SPEC.stage_times[j], x, deployed, (3.0, 4.0), left, at)


# --------------------------------------------------------------------------- the coordinator's merge

def test_an_account_is_the_truth_over_the_decision_and_is_counted_once():
    # Stage 0 was decided for a; a never received it and decided stage 0 itself, not deploying.
    state, _ = run(READY + [obs("a", 0, 3), decide(0, ("a",))])
    assert state.deployed()[0, 0]  # a decision nobody answered is taken as done ...
    state, effects = ms.step(state, own("a", 0, 3, False))
    assert recorded(effects) and not rejected(effects)
    assert not state.deployed()[0, 0]  # ... until the carrier's own account says otherwise
    assert state.passengers_left()[0] == 2
    # Its answer to the decision, arriving later, agrees with its account: on record, absorbed.
    state, effects = ms.step(state, confirm("a", 0, False, "already"))
    assert not rejected(effects) and not state.confirmed_deployments()[0, 0]
    # A contradicting Confirm or a second, different account is a duplicate; the first stands.
    _, effects = ms.step(state, ev.Confirmed("b", 0, True, "already", P0, 0, 4.5))
    assert rejected(ms.step(state, own("a", 0, 3, True))[1]) == ["duplicate"]
    assert ms.step(state, own("a", 0, 3, False)) == (state, ())  # identical repeat: nothing new


def recorded(effects):
    return [e.event for e in effects if isinstance(e, ms.Record)]


def test_a_carrier_past_a_stage_is_neither_waited_for_nor_planned_there():
    state, _ = run(READY + [obs("a", 0, 3), decide(0)])
    assert state.expected(1) == {"a", "b"}
    # b decided stage 1 itself (the coordinator had not got there) and deployed.
    state, effects = ms.step(state, own("b", 1, 4, True, left=0))
    assert not rejected(effects)
    assert state.expected(1) == {"a"}
    x = state.planning_observations(1)
    assert np.isnan(x[1, 1])  # b is ∅ for the planner at stage 1: it decided that stage
    assert state.observation(1, 1) == 4  # but its x is on record for the reward
    state, _ = ms.step(state, obs("a", 1, 2))
    assert state.stage_complete(1)
    state, _ = ms.step(state, decide(1))
    assert state.deployed()[1, 1] and state.passengers_left()[1] == 0  # later plans see it gone
    assert state.confirmed_deployments()[1, 1] and state.deployment_position("b", 1) == (3.0, 4.0)
    # A Hello saying a carrier goes on from stage 2 takes it off stage 1 as well.
    fresh, _ = run(READY + [obs("a", 0, 3), decide(0), hello("a", next_stage=2)])
    assert fresh.expected(1) == {"b"}


@pytest.mark.parametrize("event,reason", [
    (own("b", 0, None, True), "out-of-range"),         # b is not scheduled at stage 0
    (ev.Accounted("a", 0, 1.0, 3, False, P0, 2), "out-of-range"),  # t is not t_0
    (ev.Accounted("z", 0, 0.0, 3, False, P0, 2), "unknown-carrier"),
])
def test_bad_accounts_are_rejected(event, reason):
    state, _ = run(READY)
    assert rejected(ms.step(state, event)[1]) == [reason]


def test_an_account_before_a_hello_is_rejected():
    state, _ = run([ev.Opened(0.0), ev.LivelinessChanged("a", True, 1.0)])
    assert rejected(ms.step(state, own("a", 0, 3, True))[1]) == ["no-hello"]


# --------------------------------------------------------------------------- the carrier's own decisions

def test_own_decision_is_logged_before_the_deployment_and_announced_after_it():
    state, _ = carrier(*[mc.Joined(0)], mc.Observed(0, 7, P0))
    state, effects = mc.step(state, mc.DecidedOwn(0, True, P0))
    kinds = [type(e) for e in effects]
    assert kinds.index(mc.LogOutcome) < kinds.index(mc.Deploy) < kinds.index(mc.SendOwn)
    sent = next(e for e in effects if isinstance(e, mc.SendOwn))
    assert (sent.stage, sent.x, sent.deployed, sent.passengers_left) == (0, 7, True, 1)
    # A coordinator's decision of that stage arriving later changes nothing: "already".
    state2, effects = mc.step(state, heard(0, ()))
    assert confirms(effects) == [(0, "already", True)] and state2.passengers_left == 1
    # A second own decision of the same stage does nothing.
    assert mc.step(state, mc.DecidedOwn(0, True, P0)) == (state, ())


def test_own_decision_never_deploys_without_a_passenger_or_off_schedule():
    state, _ = carrier(mc.Joined(0), mc.Observed(0, 5, P0), passengers=0)
    state, effects = mc.step(state, mc.DecidedOwn(0, True, P0))
    assert not any(isinstance(e, mc.Deploy) for e in effects) and not state.handled[0].deployed
    state, _ = carrier(mc.Joined(0), mc.Observed(0, 5, P0), valid=(False, True, True))
    state, effects = mc.step(state, mc.DecidedOwn(0, True, P0))
    assert not any(isinstance(e, mc.Deploy) for e in effects)
    assert next(e for e in effects if isinstance(e, mc.SendOwn)).x is None  # not scheduled: ∅


def test_resync_repeats_own_decisions_as_own_and_answers_as_already():
    state, _ = carrier(mc.Joined(0), mc.Observed(0, 2, P0), heard(0, ()), mc.MovedOn(0),
                       mc.Observed(1, 6, P0), mc.DecidedOwn(1, True, P0), mc.MovedOn(1), mc.Observed(2, 1, P0))
    _, effects = mc.step(state, mc.Resync(None, P0))
    assert confirms(effects) == [(0, "already", False)]
    owns = [(e.stage, e.x, e.deployed) for e in effects if isinstance(e, mc.SendOwn)]
    assert owns == [(1, 6, True)]


# --------------------------------------------------------------------------- the peer book

def test_peer_book_view_reveals_the_region_counts_of_its_prefix_only():
    """Under the coverage reward a view knows the counts behind the observations it holds."""
    from planner.problem import Problem
    from planner.coverage import Coverage
    from planner.priors import build_prior

    valid = np.ones((2, 2), dtype=bool)
    covers = [[[0], [1, 2]], [[2, 3], [4]]]
    coverage = Coverage.build(covers, [build_prior({"kind": "poisson", "mean": 1.0})] * 5)
    problem = Problem.build(1, valid, coverage.overlaps(2), coverage=coverage)
    book = PeerBook(("a", "b"), valid)
    book.observation("a", 0, 3, (3,))
    book.observation("a", 1, 5, (1, 4))
    book.observation("b", 1, 2, (2,))  # b's stage 0 was never heard: its stage 1 is beyond the prefix
    view = book.local_view(problem, "a", 1, seed=0)
    assert view.counts[:3].tolist() == [3.0, 1.0, 4.0] and np.isnan(view.counts[3:]).all()
    book.observation("b", 0, 6, (4, 2))  # the heard counts of a shared region agree (region 2)
    assert book.local_view(problem, "a", 1, seed=0).counts.tolist() == [3.0, 1.0, 4.0, 2.0, 2.0]
    assert PeerBook(("a", "b"), valid).local_view(Problem.build(1, valid, []), "a", 0, seed=0).counts is None


def test_peer_book_view_is_the_prefix_of_what_was_heard():
    from planner.problem import Problem

    valid = np.array([[True, True, True, True], [True, True, False, True], [False, True, True, True]])
    problem = Problem.build([2, 1, 1], valid, [[(0, 1), (1, 1)]])
    book = PeerBook(("a", "b", "c"), valid)
    for j, x in enumerate([3, 1, 4]):
        book.observation("a", j, x)
        book.outcome("a", j, j == 0) if j < 2 else None
    book.observation("b", 0, 5)
    book.observation("b", 1, None)  # b sensed nothing it could report at 1: ∅
    book.decision(0, ("a", "b"))    # the coordinator selected a and b at 0; a's own word stands
    book.outcome("a", 0, True)
    book.observation("c", 2, 2)     # c's stage 1 observation was never heard: its prefix stops at 1
    view = book.local_view(problem, "a", 2, seed=9)
    # b is not scheduled at 2 (known in advance), so all its stages up to 2 are known.
    assert list(view.seen) == [3, 3, 1] and list(view.record) == [2, 1, 1]
    assert view.deployed[1, 0] and not view.deployed[1, 1:].any()  # b: from the decision
    assert np.isnan(view.observations[1, 1]) and view.observations[1, 0] == 5
    assert np.isnan(view.observations[2, 1:]).all()  # beyond c's prefix: unknown
    assert not view.complete
    assert book.waiting(2, ["b", "c"]) == []  # b is not scheduled at 2, c was heard
    assert book.waiting(3, ["b", "c"]) == ["b", "c"]
    # Heard in full, the view is the coordinator's.
    book.observation("c", 1, 0)
    book.decision(1, ())  # nobody selected at 1: b's and c's actions there are known
    full = book.local_view(problem, "a", 2, seed=9)
    assert full.complete


# --------------------------------------------------------------------------- a decentralised fleet

@pytest.mark.parametrize("reward", ["penalty", "coverage"])
def test_decentralised_fleet_makes_the_centralised_closed_loop_decisions(tmp_path, reward):
    """tiny.yaml with no coordinator: two carriers (threads, each its own Zenoh session) on a zenoh
    router, every stage decided on board; the deployments equal the centralised closed-loop's
    (the planner core over the world's observations), and each carrier's log has them. Under the
    coverage reward the carriers hear each other's region counts and decide by marginal coverage."""
    import yaml

    import world
    from storage.carrierlog import log_path, read_log
    from carriers.node import CarrierConfig
    from carriers.process import run_carriers
    from fleet_helpers import TINY, offline
    from wire.zconfig import free_port, make_config, open_session, close_session

    data = yaml.safe_load(TINY.read_text())
    data.update(name=f"tiny_{reward}", reward=reward)
    (tmp_path / "tiny.yaml").write_text(yaml.safe_dump(data, sort_keys=False))
    tiny = world.load_scenario(str(tmp_path / "tiny.yaml"))
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = open_session(make_config("router", [endpoint]), 10.0)
    try:
        configs = [CarrierConfig(cid, mode="decentralised", out_dir=str(tmp_path), log=lambda line: None,
                                 join_timeout_s=10.0, planner_options=(("iterations", 2000),))
                   for cid in tiny.carrier_ids]
        reasons = {}
        thread = threading.Thread(target=lambda: reasons.update(run_carriers(
            tiny, configs, lambda: make_config("client", [], [endpoint]))))
        thread.start()
        thread.join(120)
        assert not thread.is_alive()
    finally:
        close_session(router, (), 3.0)
    assert reasons == {cid: "finished" for cid in tiny.carrier_ids}
    reference, x = offline(tiny, planner="closed-loop", iterations=2000)
    for r, cid in enumerate(tiny.carrier_ids):
        meta, entries = read_log(log_path(tmp_path, cid))
        assert meta["carrier"] == cid and [e.stage for e in entries] == list(range(tiny.stages))
        assert all(e.status == "own" for e in entries)
        assert [e.stage for e in entries if e.deployed] == list(np.flatnonzero(reference.deployed[r]))
        observed = [np.nan if e.x is None else e.x for e in entries]
        np.testing.assert_array_equal(observed, x[r])
