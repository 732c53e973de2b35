"""Coverage missions in the fleet (issue 35; docs/protocol.md [P-6.14]): carriers send the region
counts behind their observations (wire revision 5), the coordinator folds and stores them and
plans with the revealed ones, so the fleet decides as the offline planner does; a carrier of an
earlier revision is refused from a coverage mission with a reason it reads, and flies a penalty
mission as before."""
from __future__ import annotations

import dataclasses
import json
import sqlite3

import numpy as np
import pytest
import yaml

import world
from fleet_helpers import ROOT, InProcessFleet, deployed_matrix, offline
from mission import coverage as mcov
from mission import events as ev
from mission import state as ms
from storage.missiondb import MissionStore, load_events

COVERAGE = ROOT / "scenarios" / "six_carriers_coverage.yaml"
TINY = ROOT / "scenarios" / "tiny.yaml"


def _tiny(tmp_path, reward):
    data = yaml.safe_load(TINY.read_text())
    data.update(name=f"tiny_{reward}", reward=reward, planner={"name": "closed-loop"})
    path = tmp_path / f"tiny_{reward}.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return world.load_scenario(path)


@pytest.fixture(scope="module")
def coverage_spec():
    s = world.load_scenario(COVERAGE)
    problem = world.build_problem(s)
    spec = ms.MissionSpec.build(s.carrier_ids, problem.valid, problem.passengers, s.stage_times(), "fp",
                                **mcov.spec_options(problem))
    return s, problem, spec


def _ready(spec, revision=5):
    state = ms.initial(spec)
    for cid in spec.carriers:
        state, _ = ms.step(state, ev.LivelinessChanged(cid, True, 1.0))
        state, _ = ms.step(state, ev.Hello(cid, 1, "h", 3, 0, "fp", 1.0, revision))
    return state


def test_a_coverage_mission_refuses_an_earlier_revision_and_a_penalty_one_does_not(coverage_spec):
    """[P-6.14]: the Hello of a revision 4 carrier is refused ``version`` with the revision needed."""
    _, problem, spec = coverage_spec
    assert spec.min_revision == 5
    state, effects = ms.step(ms.initial(spec), ev.Hello("c1", 1, "h", 3, 0, "fp", 1.0, 4))
    refuse = [e for e in effects if isinstance(e, ms.Refuse)]
    assert [(r.reason, r.revision) for r in refuse] == [("version", 4)] and "revision 5" in refuse[0].detail
    assert "c1" in state.refused and "c1" not in state.accepted
    penalty = ms.MissionSpec.build(spec.carriers, problem.valid, problem.passengers, spec.stage_times, "fp")
    state, effects = ms.step(ms.initial(penalty), ev.Hello("c1", 1, "h", 3, 0, "fp", 1.0, 4))
    assert "c1" in state.accepted and not [e for e in effects if isinstance(e, ms.Refuse)]


def test_observations_carry_one_count_per_region_and_are_folded(coverage_spec):
    """[P-6.14]: counts of the wrong length, or none, are ``out-of-range``; the accepted ones are
    the revealed counts the planner sees (NaN elsewhere), as planner.coverage.revealed gives them."""
    s, problem, spec = coverage_spec
    state = _ready(spec)
    counts = world.observe_counts(s)
    x = world.observe_all(s)
    r = int(np.flatnonzero(problem.valid[:, 0])[0])
    cid, regions = s.carrier_ids[r], problem.coverage.regions(r * s.stages)
    good = tuple(int(c) for c in counts[regions])
    base = ev.Observation(cid, 0, 0.0, int(x[r, 0]), (1.0, 2.0), 3)
    for bad in (None, good + (0,)):
        _, effects = ms.step(state, dataclasses.replace(base, counts=bad))
        assert [e.reason for e in effects if isinstance(e, ms.Reject)] == ["out-of-range"]
    state, effects = ms.step(state, dataclasses.replace(base, counts=good))
    assert any(isinstance(e, ms.Record) for e in effects)
    known = mcov.planning_counts(state, problem)
    np.testing.assert_array_equal(np.flatnonzero(~np.isnan(known)), regions)
    np.testing.assert_array_equal(known[regions], counts[regions])
    seen = np.full(x.shape, np.nan)
    seen[r, 0] = x[r, 0]
    from planner.coverage import revealed

    np.testing.assert_array_equal(known, revealed(problem.coverage, seen, counts))
    # repeated identically: absorbed; with other counts: a duplicate
    assert ms.step(state, dataclasses.replace(base, counts=good, at=3.0))[1] == ()
    other = tuple(reversed(good)) if len(good) > 1 and good != tuple(reversed(good)) else None
    if other is not None:
        assert [e.reason for e in ms.step(state, dataclasses.replace(base, counts=other))[1]] == ["duplicate"]


def test_mission_db_keeps_the_counts_and_reads_rows_without_them(tmp_path, coverage_spec):
    s, problem, spec = coverage_spec
    state = _ready(spec)
    store = MissionStore(tmp_path / "mission.db", {"mission": "m"})
    e = ev.Observation(s.carrier_ids[0], 0, 0.0, 3, (1.0, 2.0), 3, (), 2.0, (1, 2))
    store.record(ms.Record(e, 0), state)
    old = ev.Observation(s.carrier_ids[1], 0, 0.0, 2, (1.0, 2.0), 3, (), 2.0)  # a penalty row: no key
    store.record(ms.Record(old, 0), state)
    store.flush()
    store.close()
    payloads = [json.loads(p) for (p,) in sqlite3.connect(tmp_path / "mission.db").execute(
        "SELECT payload FROM events WHERE kind = 'observation' ORDER BY seq")]
    assert payloads[0]["counts"] == [1, 2] and "counts" not in payloads[1]
    events = [x for x in load_events(tmp_path / "mission.db") if isinstance(x, ev.Observation)]
    assert [x.counts for x in events] == [(1, 2), None]


def test_a_coverage_mission_flies_as_the_offline_planner_decides(tmp_path):
    """six_carriers_coverage, every carrier of today's revision: identical observations,
    decisions and covered features; summary.json says the reward model."""
    s = world.load_scenario(COVERAGE)
    reference, x = offline(s)
    fleet = InProcessFleet(s, tmp_path / "run", join_timeout_s=30.0, stage_timeout_s=15.0)
    fleet.start_coordinator()
    for cid in s.carrier_ids:
        fleet.start_carrier(cid)
    summary = fleet.join(300)
    np.testing.assert_array_equal(np.array(summary["observations"], dtype=float), x)
    np.testing.assert_array_equal(deployed_matrix(summary, s), reference.deployed)
    assert summary["reward"] == "coverage" and summary["total_reward"] == reference.reward
    assert summary["coverage"]["covered_features"] == reference.features == summary["total_features"]
    assert summary["coverage"]["regions_revealed"] == summary["coverage"]["regions"]
    assert summary["rejected"]["coordinator"] == {}
    if summary["clairvoyant"] is not None:  # written once the bound is computed (maximum coverage)
        from planner import clairvoyant
        from world.regions import region_counts

        best = clairvoyant.solve(world.build_problem(s), x, counts=region_counts(s))
        assert summary["clairvoyant"]["features"] == pytest.approx(best.features)
        assert summary["clairvoyant"]["method"] == "ilp" and summary["clairvoyant"]["exact"]
        assert best.features >= reference.features
    stored = [e for e in load_events(tmp_path / "run" / "mission.db") if isinstance(e, ev.Observation) and e.counts]
    assert sum(sum(e.counts) for e in stored) == np.nansum(x)


@pytest.fixture
def revision4(monkeypatch):
    """Today's carriers speaking revision 4 (as a carrier written from that page would)."""
    import carriers.joining
    import carriers.who

    monkeypatch.setattr(carriers.who, "REVISION", 4)
    monkeypatch.setattr(carriers.joining, "REVISION", 4)


def test_a_revision4_carrier_is_refused_from_a_coverage_mission_with_the_reason(tmp_path, revision4):
    """[P-6.14]: it reads Refusal ``version`` and its detail, and stops; the mission goes on."""
    s = _tiny(tmp_path, "coverage")
    fleet = InProcessFleet(s, tmp_path / "run", join_timeout_s=1.0, stage_timeout_s=1.0)
    fleet.start_coordinator()
    fleet.start_carrier("a")
    summary = fleet.join(120)
    assert fleet.results["a"] == "refused"
    assert any("refused our Hello (version" in line and "revision 5" in line for line in fleet.log.lines), fleet.log.lines
    assert summary["ended"] and summary["carriers"][0]["deployments"] == []


def test_a_revision4_carrier_flies_a_penalty_mission_as_before(tmp_path, revision4):
    s = _tiny(tmp_path, "penalty")
    reference, x = offline(s)
    fleet = InProcessFleet(s, tmp_path / "run", join_timeout_s=30.0, stage_timeout_s=15.0)
    fleet.start_coordinator()
    for cid in s.carrier_ids:
        fleet.start_carrier(cid)
    summary = fleet.join(120)
    np.testing.assert_array_equal(deployed_matrix(summary, s), reference.deployed)
    assert summary["reward"] == "penalty" and "coverage" not in summary
    assert summary["rejected"]["coordinator"] == {}
    hellos = [e for e in load_events(tmp_path / "run" / "mission.db") if isinstance(e, ev.Hello)]
    assert hellos and {e.revision for e in hellos} == {4}
