"""Passenger types through the fleet (issue 13 part A): a scenario listing typed passengers, a
real coordinator and real carriers on loopback Zenoh; Decisions name the passenger, Confirms
report it, summary.json and map.png say which type went where, and the mission equals the
offline planner's run with the passenger values."""
from __future__ import annotations

import numpy as np
import pytest
import yaml

import world
from fleet_helpers import ROOT, InProcessFleet, db_rows, deployed_matrix, offline


@pytest.fixture(scope="module")
def typed(tmp_path_factory):
    data = yaml.safe_load((ROOT / "scenarios" / "tiny.yaml").read_text())
    data["passenger_types"] = {"scout": 1.0, "rover": 0.4}
    data["carriers"][0]["passengers"] = ["rover", "scout"]
    data["carriers"][1]["passengers"] = [{"type": "scout"}]
    data["planner"] = {"name": "closed-loop", "iterations": 200}
    path = tmp_path_factory.mktemp("typed") / "tiny_types.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return world.load_scenario(path)


def test_typed_mission_matches_the_offline_planner(typed, tmp_path):
    fleet = InProcessFleet(typed, tmp_path, render=True)
    fleet.start_coordinator()
    for cid in typed.carrier_ids:
        fleet.start_carrier(cid)
    summary = fleet.join()
    reference, x = offline(typed)
    assert reference.released is not None and (reference.released >= 0).any()
    np.testing.assert_array_equal(deployed_matrix(summary, typed), reference.deployed)
    assert summary["total_reward"] == pytest.approx(reference.reward)
    for r, carrier in enumerate(summary["carriers"]):
        got = [d["passenger"] for d in carrier["deployments"]]
        assert got == [int(reference.released[r, d["stage"]]) for d in carrier["deployments"]]
        assert sorted(got) == list(range(typed.carriers[r].passengers))  # each passenger once
        for d in carrier["deployments"]:
            assert d["type"] == typed.passenger_type(r, d["passenger"])
            assert d["value"] == typed.passenger_values()[r][d["passenger"]]
    # The carriers' Confirms named what they released (stored in mission.db).
    named = {(c, j): p for c, j, p in db_rows(
        tmp_path / "mission.db",
        "SELECT carrier, stage, json_extract(payload, '$.passenger') FROM events WHERE kind = 'confirm'")}
    for r, cid in enumerate(typed.carrier_ids):
        for j in np.flatnonzero(reference.deployed[r]):
            assert named[(cid, int(j))] == int(reference.released[r, j])
    assert (tmp_path / "map.png").stat().st_size > 0
    # The report rebuilds summary.json from mission.db and the carriers' logs: the same passengers.
    import json

    from coordinator.report import run_report

    run_report(typed, tmp_path, render=False, log=lambda line: None)
    again = json.loads((tmp_path / "summary.json").read_text())
    assert again["total_reward"] == pytest.approx(summary["total_reward"])
    for before, after in zip(summary["carriers"], again["carriers"]):
        assert [(d["stage"], d["passenger"], d["type"]) for d in before["deployments"]] == \
            [(d["stage"], d["passenger"], d["type"]) for d in after["deployments"]]
