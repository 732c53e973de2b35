"""The fleet in one process: real Zenoh sessions on loopback (one per node), real worlds, real
planner; coordinator and carriers as threads."""
from __future__ import annotations

import time

import msgpack
import numpy as np
import pytest

import world
from coordinator.node import Coordinator, CoordinatorConfig
from wire import keys
from wire.messages import MAX_PAYLOAD_BYTES, Decision, Observation, encode
from wire.transport import Node
from wire.zconfig import free_port, make_config

from fleet_helpers import TINY, InProcessFleet, db_rows, deployed_matrix, offline


@pytest.fixture(scope="module")
def tiny():
    return world.load_scenario(TINY)


def test_whole_mission_matches_the_offline_planner(tiny, tmp_path):
    fleet = InProcessFleet(tiny, tmp_path)
    fleet.start_coordinator()
    for cid in tiny.carrier_ids:
        fleet.start_carrier(cid)
    summary = fleet.join()
    reference, x = offline(tiny)

    assert summary["ended"] and summary["stages_decided"] == tiny.stages
    assert all(fleet.results[cid] == "end" for cid in tiny.carrier_ids)
    np.testing.assert_array_equal(np.array(summary["observations"], dtype=float), x)
    np.testing.assert_array_equal(deployed_matrix(summary, tiny), reference.deployed)
    assert summary["total_reward"] == pytest.approx(reference.reward)
    assert summary["total_features"] == pytest.approx(reference.features)
    assert summary["clairvoyant"]["reward"] >= summary["total_reward"] - 1e-9
    assert summary["latency_ms"]["count"] == tiny.n_carriers * tiny.stages
    assert summary["rejected"]["coordinator"] == {}
    for carrier, spec in zip(summary["carriers"], tiny.carriers):
        assert len(carrier["deployments"]) == spec.passengers  # every passenger is deployed
        assert carrier["pid"] is not None and carrier["host"]
    # Everything is in mission.db, and each decision was committed before its confirmations.
    db = tmp_path / "mission.db"
    assert db_rows(db, "SELECT COUNT(*) FROM decisions")[0][0] == tiny.stages
    order = dict(db_rows(db, "SELECT stage, seq FROM decisions"))
    for cid, stage, seq in db_rows(db, "SELECT carrier, stage, seq FROM confirmations"):
        assert seq > order[stage]
    for cid, stage, seq in db_rows(db, "SELECT carrier, stage, seq FROM observations"):
        assert seq < order[stage]


def test_staggered_start_catches_up_from_the_mission_state(tiny, tmp_path):
    # 5 x real time: a stage per wall second. Carrier b starts after stage 0 is decided.
    fleet = InProcessFleet(tiny, tmp_path, realtime=5.0, join_timeout_s=0.5)
    fleet.start_coordinator()
    fleet.start_carrier("a", realtime=5.0)
    deadline = time.monotonic() + 30
    while fleet.coordinator.state.next_stage < 1 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert fleet.coordinator.state.next_stage >= 1
    fleet.start_carrier("b", realtime=5.0)
    summary = fleet.join()
    reference, x = offline(tiny)

    assert summary["ended"] and fleet.results["b"] == "end"
    hello = db_rows(tmp_path / "mission.db", "SELECT stage FROM events WHERE kind='hello' AND carrier='b'")
    joined = hello[0][0]
    assert joined >= 1  # b learnt from the state that stage 0 was decided already
    obs = np.array(summary["observations"], dtype=float)
    rb = tiny.carrier_index("b")
    # From the stage after it joined on, b's observations are the world's own.
    np.testing.assert_array_equal(obs[rb, joined + 1:], x[rb, joined + 1:])
    assert np.isnan(obs[rb, :joined]).all()
    b = summary["carriers"][rb]
    assert len(b["deployments"]) == tiny.carriers[rb].passengers
    assert len({d["stage"] for d in b["deployments"]}) == len(b["deployments"])


def test_bad_messages_are_rejected_counted_and_change_nothing(tiny, tmp_path):
    fleet = InProcessFleet(tiny, tmp_path)
    fleet.start_coordinator()
    deadline = time.monotonic() + 60
    while fleet.coordinator.node is None and time.monotonic() < deadline:  # planner warm-up first
        time.sleep(0.05)
    intruder = Node(make_config("client", [], [fleet.endpoint]), open_timeout_s=30)
    m = fleet.coordinator.setup.mission
    while not intruder.query(keys.state_key(m)) and time.monotonic() < deadline:
        time.sleep(0.05)  # the state queryable is declared after the subscribers
    obs_key = keys.carrier_key(m, "a", "obs")
    good = Observation(m, "a", 3, 15.0, 99, (0.0, 0.0), 2, ())
    raw = msgpack.unpackb(encode(good))
    try:
        intruder.put_raw(obs_key, b"\x00garbage")
        intruder.put_raw(obs_key, msgpack.packb({**raw, "v": 9}))
        intruder.put_raw(obs_key, msgpack.packb({**raw, "stage": "3"}))
        intruder.put_raw(obs_key, msgpack.packb({**raw, "mission": "other"}))
        intruder.put_raw(obs_key, msgpack.packb({**raw, "carrier": "b"}))
        intruder.put_raw(keys.carrier_key(m, "zz", "obs"), msgpack.packb({**raw, "carrier": "zz"}))
        intruder.put_raw(obs_key, b"\x01" * (MAX_PAYLOAD_BYTES + 6 * 1024))
        intruder.put_raw(keys.decision_key(m), msgpack.packb({**msgpack.unpackb(encode(
            Decision(m, 0, 0.0, ("a",), 1.0))), "deploy": "a"}))
        time.sleep(0.3)
        for cid in tiny.carrier_ids:
            fleet.start_carrier(cid)
        summary = fleet.join()
    finally:
        intruder.close()
    reference, _ = offline(tiny)
    np.testing.assert_array_equal(deployed_matrix(summary, tiny), reference.deployed)
    rejected = summary["rejected"]["coordinator"]
    for reason in ("malformed", "version", "wrong-type", "wrong-mission", "key-mismatch", "unknown-carrier",
                   "oversized"):
        assert rejected.get(reason) == 1, (reason, rejected)
    # Each carrier saw the malformed decision once (if it had subscribed by then) and carried on.
    for cid in tiny.carrier_ids:
        assert set(summary["rejected"]["carriers"][cid]) <= {"wrong-type"}


def test_a_carrier_of_another_world_is_refused(tiny, tmp_path):
    fleet = InProcessFleet(tiny, tmp_path, join_timeout_s=0.5)
    fleet.start_coordinator()
    fleet.start_carrier("a")
    fleet.start_carrier("b", seed=tiny.seed + 1)  # another seed: other features, another world
    summary = fleet.join()
    assert fleet.results["b"] == "world-mismatch"
    assert summary["ended"]
    assert any("another world" in line for line in fleet.log.lines)
    rb = tiny.carrier_index("b")
    assert np.isnan(np.array(summary["observations"], dtype=float)[rb]).all()
    assert summary["carriers"][rb]["deployments"] == []


class _Crash(Exception):
    pass


def test_restarted_coordinator_recovers_from_mission_db(tiny, tmp_path):
    """The coordinator dies after committing stage 1's decision but before publishing it; a new
    coordinator on the same results directory replays mission.db, re-publishes that decision and
    finishes the mission exactly as the offline planner would. (Carriers that hold while the
    coordinator is away, ``coordinated``: hybrid carriers would go on without it, see
    test_hybrid.py.)"""

    fleet = InProcessFleet(tiny, tmp_path)
    crashing = fleet.coordinator

    def publish_or_crash(state, j, original=crashing.crew.effects.publish_decision):
        if j == 1:
            raise _Crash()
        return original(state, j)

    crashing.crew.effects.publish_decision = publish_or_crash
    fleet._spawn("crashed", lambda: pytest.raises(_Crash, crashing.run))
    for cid in tiny.carrier_ids:
        fleet.start_carrier(cid, mode="coordinated")
    fleet.threads[0].join(30)
    assert crashing.state.next_stage == 2 and not crashing.state.ended
    time.sleep(0.5)
    restarted = Coordinator(tiny, CoordinatorConfig(out_dir=str(tmp_path), log=fleet.log, render=False),
                            make_config("peer", [fleet.endpoint]))
    fleet.coordinator = restarted
    fleet.start_coordinator()
    summary = fleet.join()
    reference, x = offline(tiny)
    assert summary["resumed"] and summary["ended"] and summary["end_reason"] == "complete"
    assert all(fleet.results[cid] == "end" for cid in tiny.carrier_ids)
    np.testing.assert_array_equal(np.array(summary["observations"], dtype=float), x)
    np.testing.assert_array_equal(deployed_matrix(summary, tiny), reference.deployed)
    decided = [s for (s,) in db_rows(tmp_path / "mission.db", "SELECT stage FROM decisions")]
    assert sorted(decided) == list(range(tiny.stages))
    assert any("resumed from" in line for line in fleet.log.lines)


def test_restarted_carrier_rejoins_with_its_recorded_deployments(tiny, tmp_path):
    """Carrier a stops after deploying at stage 0; a new process for a (same id) learns from the
    mission state that one passenger is gone and where it is in its schedule, and finishes."""
    fleet = InProcessFleet(tiny, tmp_path, realtime=5.0)
    fleet.start_coordinator()
    first = fleet.start_carrier("a", realtime=5.0)
    fleet.start_carrier("b", realtime=5.0)
    deadline = time.monotonic() + 60
    while fleet.coordinator.state.next_stage < 2 and time.monotonic() < deadline:
        time.sleep(0.01)
    ra = tiny.carrier_index("a")
    before = int(fleet.coordinator.state.deployed()[ra].sum())
    assert before >= 1  # tiny.yaml: a deploys at stage 0 (x = 8), so there is something to replay
    first.stop()
    fleet.threads[1].join(30)
    assert fleet.results["a"] == "stopped"
    second = fleet.start_carrier("a", realtime=5.0)
    summary = fleet.join()
    assert fleet.results["a"] == "end" and summary["ended"]
    assert second.machine.stage == tiny.stages
    # The new process replayed what the log holds and never deployed a stage twice.
    replayed = sorted(j for j, c in second.machine.handled.items() if c.status == "deployed" and j < 2)
    assert len(replayed) == before
    a = summary["carriers"][ra]
    stages = [d["stage"] for d in a["deployments"]]
    assert len(stages) == len(set(stages)) <= tiny.carriers[ra].passengers
    confirmed = db_rows(tmp_path / "mission.db", "SELECT stage FROM confirmations WHERE carrier='a' AND deployed=1")
    assert len(confirmed) == len({s for (s,) in confirmed})


def test_the_map_is_drawn_from_the_runs_seed(tiny, tmp_path):
    """A run with ``--seed`` draws map.png from the features of that seed, those its carriers
    observed (not the scenario file's)."""
    coordinator = Coordinator(tiny, CoordinatorConfig(out_dir=str(tmp_path), seed=tiny.seed + 7, render=False),
                              make_config("peer", [f"tcp/127.0.0.1:{free_port()}"]))
    assert coordinator.crew.results.scenario.seed == tiny.seed + 7 == coordinator.setup.seed
