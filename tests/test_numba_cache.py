"""The planner's on-disk numba cache is never reused across a change of the planner's sources.

numba checks a cached function against its own file only; a kernel that inlines a rule of
planner/kernels.py (or reads a constant of planner/ssap.py) would keep yesterday's rule after that
file changed. planner.jitcache.cache_follows_sources stamps every cached function with a digest of
all planner sources.
"""
from __future__ import annotations

import importlib
import os
import pkgutil
import shutil
import subprocess
import sys
from pathlib import Path

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
from planner.mcts import kernel
# points 1, 2 with probability 1/2 each; guide[m] = first index with cdf > m / 8
print(kernel.quantiles(np.array([0.25]), np.array([1.0, 2.0]), np.array([0.5, 1.0]),
                       np.array([0, 0, 0, 0, 1, 1, 1, 1], dtype=np.int64))[0])
"""


def test_a_change_to_an_inlined_rule_recompiles_the_kernels_that_inline_it(tmp_path):
    """mcts.kernel.quantiles inlines planner.kernels.quantile: after editing only kernels.py, the
    next process must run the edited rule, not the cached kernel."""
    shutil.copytree(ROOT / "planner", tmp_path / "planner", ignore=shutil.ignore_patterns("__pycache__"))
    env = {**os.environ, "PYTHONPATH": str(tmp_path), "NUMBA_CACHE_DIR": str(tmp_path / "numba-cache")}

    def probe() -> str:
        out = subprocess.run([sys.executable, "-c", _PROBE], cwd=tmp_path, env=env, capture_output=True,
                             text=True, timeout=120)
        assert out.returncode == 0, out.stderr
        return out.stdout.strip()

    assert probe() == "1.0"
    assert any((tmp_path / "numba-cache").rglob("*.nbi"))  # the kernel was cached
    kernels = tmp_path / "planner" / "kernels.py"
    text = kernels.read_text()
    assert text.count("    return points[i]\n") == 1
    kernels.write_text(text.replace("    return points[i]\n", "    return points[i] + 100.0\n"))
    assert probe() == "101.0"
