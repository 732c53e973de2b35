"""The planner's on-disk numba cache (planner/jitcache.py): never reused across a change of the
planner's sources, shared by every copy of the same sources on a machine, and filled by one
process per kernel.

numba checks a cached function against its own file only; a kernel that inlines a rule of
planner/kernels.py (or reads a constant of planner/ssap.py) would keep yesterday's rule after that
file changed. planner.jitcache.cache_follows_sources stamps every cached function with a digest of
all planner sources, and keys the cache by that digest rather than by the files' paths.
"""
from __future__ import annotations

import importlib
import os
import pkgutil
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import planner
from planner.jitcache import sources_digest

ROOT = Path(__file__).resolve().parents[1]


def _cached_dispatchers():
    for info in pkgutil.walk_packages(planner.__path__, "planner."):
        module = importlib.import_module(info.name)
        for name, obj in vars(module).items():
            cache_file = getattr(getattr(obj, "_cache", None), "_cache_file", None)
            if cache_file is not None and obj.py_func.__module__ == info.name:
                yield f"{info.name}.{name}", cache_file


def test_every_cached_planner_function_is_stamped_with_the_sources_digest():
    found = dict(_cached_dispatchers())
    assert "planner.mcts.kernel.search_joint" in found and "planner.kernels.deploys" in found
    for name, cache_file in found.items():
        stamp = cache_file._source_stamp
        assert stamp[:2] == ("planner-sources", sources_digest()), name


_PROBE = """
import numpy as np
from planner import jitcache
jitcache.report_compiles(lambda line: print("report:", line, flush=True))
from planner.mcts import kernel
# points 1, 2 with probability 1/2 each; guide[m] = first index with cdf > m / 8
print(kernel.quantiles(np.array([0.25]), np.array([1.0, 2.0]), np.array([0.5, 1.0]),
                       np.array([0, 0, 0, 0, 1, 1, 1, 1], dtype=np.int64))[0])
"""


@pytest.mark.slow
def test_a_change_to_an_inlined_rule_recompiles_the_kernels_that_inline_it(tmp_path):
    """mcts.kernel.quantiles inlines planner.kernels.quantile: after editing only kernels.py, the
    next process must run the edited rule, not the cached kernel."""
    shutil.copytree(ROOT / "planner", tmp_path / "planner", ignore=shutil.ignore_patterns("__pycache__"))
    env = {**os.environ, "PYTHONPATH": str(tmp_path), "NUMBA_CACHE_DIR": str(tmp_path / "numba-cache")}

    def probe() -> str:
        out = subprocess.run([sys.executable, "-c", _PROBE], cwd=tmp_path, env=env, capture_output=True,
                             text=True, timeout=120)
        assert out.returncode == 0, out.stderr
        return out.stdout.strip().splitlines()[-1]

    assert probe() == "1.0"
    assert any((tmp_path / "numba-cache").rglob("*.nbi"))  # the kernel was cached
    kernels = tmp_path / "planner" / "kernels.py"
    text = kernels.read_text()
    assert text.count("    return points[i]\n") == 1
    kernels.write_text(text.replace("    return points[i]\n", "    return points[i] + 100.0\n"))
    assert probe() == "101.0"


def _copy_planner(dest: Path) -> Path:
    shutil.copytree(ROOT / "planner", dest / "planner", ignore=shutil.ignore_patterns("__pycache__"))
    return dest


def _env(tree: Path, cache_home: Path) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    return {**env, "PYTHONPATH": str(tree), "XDG_CACHE_HOME": str(cache_home)}


def _start_probe(tree: Path, cache_home: Path) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", _PROBE], cwd=tree, env=_env(tree, cache_home),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _finish(proc: subprocess.Popen) -> list[str]:
    out, err = proc.communicate(timeout=180)
    assert proc.returncode == 0, err
    lines = out.strip().splitlines()
    assert lines[-1] == "1.0"
    return [line for line in lines if line.startswith("report: ")]


@pytest.mark.slow
def test_two_copies_of_the_same_planner_share_the_user_cache(tmp_path):
    """A second checkout or venv of the same sources, elsewhere on the machine, loads what the
    first compiled: the cache is under the user's cache folder, keyed by versions and digest."""
    cache_home = tmp_path / "cache"
    first = _finish(_start_probe(_copy_planner(tmp_path / "a"), cache_home))
    assert "report: compiling planner.mcts.kernel.quantiles" in first
    assert any(line.startswith("report: compiled planner.mcts.kernel.quantiles in ") for line in first)
    kept = list((cache_home / "marsupial-fleet" / "numba").glob("numba-*/planner/mcts/kernel/*quantiles*.nbi"))
    assert len(kept) == 1, kept
    assert _finish(_start_probe(_copy_planner(tmp_path / "b"), cache_home)) == []  # loaded, not compiled


@pytest.mark.slow
def test_processes_starting_together_compile_a_kernel_once(tmp_path):
    """Three processes wanting the same kernel at once on a new machine: one compiles it, the
    others wait for its lock and load it."""
    tree, cache_home = _copy_planner(tmp_path), tmp_path / "cache"
    reports = [_finish(proc) for proc in [_start_probe(tree, cache_home) for _ in range(3)]]
    compiled = [r for r in reports if "report: compiling planner.mcts.kernel.quantiles" in r]
    assert len(compiled) == 1, reports
    assert all(r == [] or r[0].startswith("report: waiting for another process compiling planner.mcts.kernel.")
               for r in reports if r not in compiled), reports


#: Missions flown after the install step (``python -m planner.cli.compile``): the default planner
#: in both layouts, closed-loop, the on-board planner and a coverage mission's planner.
AFTER_INSTALL = """
import numpy as np
import world
from planner import clairvoyant, jitcache
from planner.online import run_online
from planner.registry import make_planner
lines = []
jitcache.report_compiles(lines.append)
six = world.load_scenario("scenarios/six_carriers.yaml")
problem, x = world.build_problem(six), world.observe_all(six)
for name, options in (("mcts-ssap", {}), ("mcts-ssap", {"layout": "binary"}), ("closed-loop", {}),
                      ("dec-closed-loop", {})):
    run_online(problem, x, make_planner(name, **options), six.seed)
clairvoyant.solve(problem, np.where(problem.valid, x, np.nan))  # the summary's bound
world.offline_mission(world.load_scenario("scenarios/six_carriers_coverage.yaml"))
print("\\n".join(line for line in lines if line.startswith("compiling")))
"""


@pytest.mark.slow
def test_after_the_install_step_a_mission_compiles_nothing(tmp_path):
    """docs/performance.md's promise: after ``python -m planner.cli.compile`` on a new machine, a
    mission compiles no kernel. A kernel called with arrays of another writability, or with a
    literal where the install step passed a variable, would be compiled again (numba types both
    apart): each is seconds of CPU before a first decision."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    install = subprocess.run([sys.executable, "-m", "planner.cli.compile", "--jobs", "2"], cwd=ROOT, env=env,
                             capture_output=True, text=True, timeout=900)
    assert install.returncode == 0, install.stderr
    # its processes (one per planner, two at a time here) compile each kernel once between them
    compiling = [line for line in install.stdout.splitlines() if line.startswith("compiling planner.")]
    assert compiling and len(compiling) == len(set(compiling)), install.stdout
    assert f"{len(compiling)} compiled" in install.stdout.splitlines()[-1], install.stdout
    run = subprocess.run([sys.executable, "-c", AFTER_INSTALL], cwd=ROOT, env=env, capture_output=True, text=True,
                         timeout=900)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == "", "compiled after the install step:\n" + run.stdout
