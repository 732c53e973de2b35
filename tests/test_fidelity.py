"""Fidelity: a fault-free fleet run makes exactly the decisions of the offline online loop
(``planner.online``'s ``run_online`` over ``world.observe_all``) on the same scenario and seed,
however loaded the host is (docs/fleet.md, "Simulated time and wall time").

Real processes over real Zenoh on loopback, the host saturated by busy processes the tests start
themselves (twice as many as cores, at normal priority, while the launcher runs its carriers
niced): six_carriers; a physics-heavy family generated from a seed (long stages: seconds of
carrier CPU per stage, so that under load a stage takes longer than a wall-clock stage
timeout, cut to 1 s there so that this holds on a fast host too); a 256-carrier street grid in
8 carrier processes. Every test asserts identical observations, decisions and reward, not a
fraction. The families and seeds here are not the ones
the sim clock was developed on (long-streets seed 1, 32 carriers).
"""
from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
import yaml

import world
from tools.scale import BusyHost, grid_scenario, long_streets_scenario

from fleet_helpers import ROOT, deployed_matrix, offline

RUN_FLEET = str(ROOT / "run_fleet.py")
SIX = ROOT / "scenarios" / "six_carriers.yaml"


def saturated_host(per_core: int = 2):
    """``per_core`` busy processes per core (pure CPU, normal priority) while the block runs."""
    return BusyHost(per_core * (os.cpu_count() or 1))


def _fly(scenario_path, out, *flags, timeout_s=1500):
    proc = subprocess.run([sys.executable, RUN_FLEET, str(scenario_path), "--out", str(out), "--no-map", *flags],
                          capture_output=True, text=True, timeout=timeout_s, cwd=out.parent)
    assert proc.returncode == 0, (proc.stdout[-3000:], proc.stderr[-3000:])
    return json.loads((out / "summary.json").read_text()), proc.stdout


def _assert_offline_decisions(summary, scenario):
    reference, x = offline(scenario)
    np.testing.assert_array_equal(np.array(summary["observations"], dtype=float), x)
    np.testing.assert_array_equal(deployed_matrix(summary, scenario), reference.deployed)
    assert summary["total_reward"] == reference.reward
    assert summary["stages_decided"] == scenario.stages
    assert all(not c["own_stages"] for c in summary["carriers"])  # nobody decided alone
    return reference


def _write(tmp_path, mapping):
    path = tmp_path / f"{mapping['name']}.yaml"
    path.write_text(yaml.safe_dump(mapping, sort_keys=False))
    return path


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_six_carriers_on_a_saturated_host(tmp_path):
    with saturated_host() as busy:
        summary, _ = _fly(SIX, tmp_path / "run")
    _assert_offline_decisions(summary, world.load_scenario(SIX))
    assert len(busy.procs) >= 2 * (os.cpu_count() or 1)


@pytest.mark.slow
@pytest.mark.timeout(1500)
def test_a_physics_heavy_family_on_a_saturated_host(tmp_path):
    """16 carriers, 600 s of driving per carrier and stage (about 200,000 physics steps of the
    fleet per stage), with the wall clock's deadlines cut to 1 s: on the wall clock such stages
    would come out ∅; on the sim clock they are waited for, whatever the host's speed."""
    path = _write(tmp_path, long_streets_scenario(16, seed=5, stages=6, stage_interval=600.0))
    scenario = world.load_scenario(path)
    with saturated_host():
        summary, stdout = _fly(path, tmp_path / "run", "--carrier-processes", "4",
                               "--stage-timeout", "1", "--peer-timeout", "1")
    _assert_offline_decisions(summary, scenario)
    # The stages really were long: at least one took longer than the (wall-clock) stage timeout.
    waits = [float(line.split("| wait")[1].split("ms")[0]) for line in stdout.splitlines() if "| wait" in line]
    assert max(waits) > 1000.0, waits


@pytest.mark.slow
@pytest.mark.timeout(1500)
def test_a_256_carrier_street_grid_in_8_processes(tmp_path):
    path = _write(tmp_path, grid_scenario(256, seed=3))
    summary, _ = _fly(path, tmp_path / "run", "--carrier-processes", "8", "--no-record")
    _assert_offline_decisions(summary, world.load_scenario(path))
