"""The example plug-in package (examples/greedy-planner) as a user installs it: pip builds and
installs it (offline, without build isolation, into a temporary target directory, so the
project's venv is left as it was), and the installed entry point ``greedy`` passes the
conformance kit, runs in ``solve`` by its name and by ``greedy_planner:GreedyPlanner``, and flies
a real mission with the launcher."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fleet_helpers import deployed_matrix, offline

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "greedy-planner"
TINY = ROOT / "scenarios" / "tiny.yaml"


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Path:
    """The example installed by pip into a target directory (built from a copy, so that no build
    files land in the clone)."""
    work = tmp_path_factory.mktemp("greedy")
    source = work / "src"
    shutil.copytree(EXAMPLE, source)
    target = work / "site"
    proc = subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation",
                           "--no-index", "--target", str(target), str(source)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    [info] = target.glob("marsupial_fleet_greedy_planner-*.dist-info")
    assert "greedy = greedy_planner:GreedyPlanner" in (info / "entry_points.txt").read_text()
    return target


def _env(target: Path | None) -> dict:
    paths = ([str(target)] if target is not None else []) + [str(ROOT)]
    return dict(os.environ, PYTHONPATH=os.pathsep.join(paths))


def _run(args, target, cwd=ROOT, timeout=300):
    return subprocess.run([sys.executable, *args], cwd=cwd, env=_env(target), capture_output=True, text=True,
                          timeout=timeout)


@pytest.mark.slow
def test_the_installed_plugin_passes_the_conformance_kit(installed, tmp_path):
    report = tmp_path / "report.json"
    proc = _run(["-m", "planner.conformance", "greedy", "--option", "q=0.8", "--json", str(report)], installed)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert proc.stdout.splitlines()[-1] == "planner 'greedy': conformant (7 checks)"
    checks = {c["name"]: c["outcome"] for c in json.loads(report.read_text())["checks"]}
    assert checks["feasible"] == checks["deterministic"] == checks["options"] == "pass"
    bad = _run(["-m", "planner.conformance", "greedy", "--option", "q=1.5"], installed)
    assert bad.returncode == 2 and "q: expected a number > 0 and <= 1 (an option of planner 'greedy')" in bad.stderr


def test_solve_runs_it_by_entry_point_name_and_by_dotted_path(installed, tmp_path):
    instance = tmp_path / "instance.json"
    instance.write_text(json.dumps({"carriers": 3, "passengers": 2, "stages": 6,
                                    "overlaps": [[[0, 1], [1, 2]], [[2, 3], [0, 4]]],
                                    "observations": [[1, 6, 2, 0, 7, 1], [4, 1, 5, 6, 0, 2], [0, 0, 9, 2, 1, 1]]}))
    flags = ["--no-clairvoyant", "--no-upper-bound", "--planner-option", "q=0.8"]
    outputs = []
    for name in ("greedy", "greedy_planner:GreedyPlanner"):
        proc = _run(["-m", "planner.cli.solve", str(instance), "--planner", name, *flags], installed)
        assert proc.returncode == 0, proc.stderr
        out = json.loads(proc.stdout)
        assert out["planner"] == name and "online_optimum" in out
        outputs.append(out["deployments"])
    # Poisson(3)'s 0.8 quantile is 4: deploy above it, and when forced.
    assert outputs[0] == outputs[1] == [[1, 4], [2, 3], [2, 5]]
    missing = _run(["-m", "planner.cli.solve", str(instance), "--planner", "greedy"], None)
    assert missing.returncode == 2 and missing.stderr.count("\n") == 1 and "expected one of" in missing.stderr


@pytest.mark.slow
def test_a_fleet_mission_flies_with_it(installed, tmp_path, monkeypatch):
    """The launcher on scenarios/tiny.yaml with --planner greedy: real processes (the coordinator
    builds the plug-in from its entry point; a few seconds, so not marked slow), the same
    deployments as the offline loop."""
    out = tmp_path / "run"
    proc = _run(["run_fleet.py", str(TINY), "--out", str(out), "--planner", "greedy", "--no-map"], installed,
                timeout=240)
    assert proc.returncode == 0, (proc.stdout + proc.stderr)[-3000:]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["planner"] == "greedy"
    import world

    scenario = world.load_scenario(TINY)
    from planner import registry

    monkeypatch.syspath_prepend(str(installed))
    monkeypatch.setattr(registry, "_PLUGINS", {})  # the plug-in loaded here is forgotten afterwards
    reference, _ = offline(scenario, planner="greedy")
    np.testing.assert_array_equal(deployed_matrix(summary, scenario), reference.deployed)
    assert summary["total_reward"] == pytest.approx(reference.reward)
