"""The project as a user installs it: a wheel built from the clone, installed into a fresh virtual
environment (dependencies from the package index under constraints.txt), and marsupial-fleet run
from an empty directory outside the clone, where nothing of the clone is on the module path."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _run(argv, cwd, timeout=900, env=None):
    proc = subprocess.run([str(a) for a in argv], cwd=cwd, capture_output=True, text=True, timeout=timeout, env=env)
    assert proc.returncode == 0, (argv, proc.stdout[-2000:], proc.stderr[-4000:])
    return proc


@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_an_installed_wheel_runs_a_bundled_scenario_from_an_empty_directory(tmp_path):
    dist, venv, empty, src = tmp_path / "dist", tmp_path / "venv", tmp_path / "empty", tmp_path / "src"
    empty.mkdir()
    # Built from a copy of the clone's files (tracked, or new and not ignored), as from a fresh
    # checkout: a build/ folder left in the clone would put files deleted since into the wheel.
    files = _run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"], cwd=ROOT).stdout
    for name in filter(None, files.split("\0")):
        if (ROOT / name).is_file():
            (src / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / name, src / name)
    _run([sys.executable, "-m", "pip", "wheel", ".", "--no-deps", "-w", dist, "-q"], cwd=src)
    [wheel] = list(dist.glob("marsupial_fleet-*.whl"))
    _run([sys.executable, "-m", "venv", venv], cwd=tmp_path)
    python, command = venv / "bin" / "python", venv / "bin" / "marsupial-fleet"
    _run([python, "-m", "pip", "install", "-q", wheel, "-c", ROOT / "constraints.txt"], cwd=tmp_path)
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env["PATH"] = f"{venv / 'bin'}{os.pathsep}{env.get('PATH', '')}"

    # The packages come from the venv, not the clone; every bundled scenario loads there.
    shown = _run([python, "-c", "import launcher, scenarios, world\n"
                                "print(launcher.__file__)\n"
                                "for n in scenarios.bundled_names(): world.load_scenario(scenarios.bundled_path(n))\n"
                                "print(','.join(scenarios.bundled_names()))"], cwd=empty, env=env)
    where, names = shown.stdout.split()
    assert where.startswith(str(venv)) and "six_carriers" in names.split(",")

    helped = _run([command, "--help"], cwd=empty, env=env).stdout
    assert all(name in helped for name in ("run", "solve", "world", "experiments", "record", "conformance"))

    ran = _run([command, "run", "six_carriers"], cwd=empty, env=env)
    assert ran.stdout.startswith("marsupial-fleet: network tcp/127.0.0.1:"), ran.stdout[:500]
    [summary_path] = list((empty / "runs").glob("six_carriers-*/summary.json"))  # under the current directory
    summary = json.loads(summary_path.read_text())
    assert [c["id"] for c in summary["carriers"]] == ["c1", "c2", "c3", "c4", "c5", "c6"]
    assert summary["stages_decided"] == summary["stages"]
    assert not list(venv.glob("lib/python*/site-packages/runs"))

    instance = empty / "instance.json"
    _run([python, "-c", "import json, sys, numpy as np\n"
                        "from planner.instance import instance_dict, random_instance\n"
                        "i = random_instance(np.random.default_rng(1), carriers=3, passengers=2, stages=6, overlaps=2)\n"
                        "open(sys.argv[1], 'w').write(json.dumps(instance_dict(i)))", instance], cwd=empty, env=env)
    solved = _run([command, "solve", instance, "--planner", "closed-loop"], cwd=empty, env=env)
    assert "reward" in solved.stdout
