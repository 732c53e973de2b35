"""Fidelity under the coverage reward (issue 35): a fault-free fleet of real processes over real
Zenoh makes exactly the offline planner's decisions (``planner.online.run_online`` over
``world.observe_all`` and the realised region counts ``world.observe_counts``) on a coverage
mission — scenarios/six_carriers_coverage.yaml on a saturated host, and a generated street grid
(tools.scale's grid family, a seed and size the coverage code was not developed on) flown under
``reward: coverage`` in 4 carrier processes, and a 256-carrier grid in 8. Identical observations,
decisions, covered features and reward; every carrier sent its region counts (mission.db)."""
from __future__ import annotations

import os

import numpy as np
import pytest

import world
from mission import events as ev
from storage.missiondb import load_events
from tools.scale import grid_scenario
from test_fidelity import _assert_offline_decisions, _fly, _write, saturated_host

from fleet_helpers import ROOT, offline

COVERAGE = ROOT / "scenarios" / "six_carriers_coverage.yaml"


def _assert_coverage(summary, scenario, out):
    reference = _assert_offline_decisions(summary, scenario)
    _, x = offline(scenario)
    assert summary["reward"] == "coverage"
    assert summary["coverage"]["covered_features"] == reference.features == summary["total_features"]
    counted = {(e.carrier, e.stage): e.counts for e in load_events(out / "mission.db") if isinstance(e, ev.Observation)}
    for r, cid in enumerate(scenario.carrier_ids):
        for j in np.flatnonzero(scenario.valid()[r]):
            assert sum(counted[(cid, int(j))]) == x[r, j]  # [P-6.14]: the counts behind every x


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_six_carriers_coverage_on_a_saturated_host(tmp_path):
    with saturated_host() as busy:
        summary, _ = _fly(COVERAGE, tmp_path / "run")
    _assert_coverage(summary, world.load_scenario(COVERAGE), tmp_path / "run")
    assert len(busy.procs) >= 2 * (os.cpu_count() or 1)


@pytest.mark.slow
@pytest.mark.timeout(1500)
def test_a_generated_street_grid_under_coverage_in_4_processes(tmp_path):
    mapping = dict(grid_scenario(64, seed=7), reward="coverage")
    mapping["name"] = "grid_64_coverage"
    path = _write(tmp_path, mapping)
    scenario = world.load_scenario(path)
    assert world.build_problem(scenario).coverage.n_regions > 64
    summary, _ = _fly(path, tmp_path / "run", "--carrier-processes", "4", "--no-record")
    _assert_coverage(summary, scenario, tmp_path / "run")


@pytest.mark.slow
@pytest.mark.timeout(1500)
def test_a_256_carrier_street_grid_under_coverage_in_8_processes(tmp_path):
    """The world's regions at fleet scale (8,281 regions) and 256 carriers sending their counts."""
    mapping = dict(grid_scenario(256, seed=11), reward="coverage")
    mapping["name"] = "grid_256_coverage"
    path = _write(tmp_path, mapping)
    summary, _ = _fly(path, tmp_path / "run", "--carrier-processes", "8", "--no-record")
    _assert_coverage(summary, world.load_scenario(path), tmp_path / "run")
