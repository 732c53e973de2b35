"""Import boundaries: planner/ uses numpy/scipy/numba only (every module of it, no exclusions);
world/ never imports coordinator/ or carriers/. Checked twice: by importing in a fresh interpreter, and statically over every import
statement (so a lazy import inside a function cannot slip through)."""
from __future__ import annotations

import ast
import json
import pkgutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

#: Top-level packages the planner may import besides the standard library and itself.
CORE_ALLOWED = {"numpy", "scipy", "numba", "planner"}
#: Must never be loaded by importing any planner module. (yaml is absent on purpose: numba itself
#: loads it to read its optional config file; the static check below still keeps planner/ from
#: importing it.)
CORE_FORBIDDEN = ("zenoh", "pymunk", "msgpack", "sqlite3", "_sqlite3", "matplotlib", "world", "wire",
                  "coordinator", "carriers", "mission", "experiments")
#: Stdlib modules the planner must not import either (process concerns).
CORE_FORBIDDEN_STDLIB = {"sqlite3", "socket", "multiprocessing", "threading"}
#: Must never be loaded by importing world/.
WORLD_FORBIDDEN = ("coordinator", "carriers")


def _modules(package: str, excluded: set[str] = frozenset()) -> list[str]:
    path = REPO / package
    if not path.is_dir():
        return []
    return sorted(f"{package}.{m.name}" for m in pkgutil.walk_packages([str(path)])
                  if m.name.split(".")[0] not in excluded)


def _loaded_after_import(modules: list[str]) -> list[str]:
    code = (
        "import importlib, json, sys\n"
        f"for name in {modules!r}:\n"
        "    importlib.import_module(name)\n"
        "print(json.dumps(sorted(sys.modules)))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.splitlines()[-1])


def _offending(loaded: list[str], forbidden: tuple[str, ...]) -> list[str]:
    return [name for name in loaded if any(name == f or name.startswith(f + ".") for f in forbidden)]


def _imports(path: Path) -> list[tuple[int, str]]:
    """(line, absolute module name) of every import statement in a file, function bodies included."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.append((node.lineno, node.module))
        elif isinstance(node, ast.ImportFrom) and node.level > 0:
            out.append((node.lineno, path.parent.name + "." + (node.module or "")))
    return out


def _planner_modules() -> list[str]:
    """Every module of planner/, subpackages included (from the files: nothing is skipped)."""
    out = []
    for path in sorted((REPO / "planner").rglob("*.py")):
        parts = path.relative_to(REPO).with_suffix("").parts
        out.append(".".join(parts[:-1] if parts[-1] == "__init__" else parts))
    return out


def test_planner_modules_exist():
    core = _planner_modules()
    for name in ("limits", "priors", "problem", "compiled", "ssap", "policies", "registry", "closedloop",
                 "clairvoyant", "instance", "solve", "bench", "kernels", "mcts.fast", "mcts.kernel",
                 "mcts.reference"):
        assert f"planner.{name}" in core


@pytest.mark.parametrize("module", _planner_modules())
def test_planner_module_imports_no_process_library_in_a_fresh_interpreter(module):
    loaded = _loaded_after_import([module])
    assert module in loaded
    assert _offending(loaded, CORE_FORBIDDEN) == []


def test_planner_package_and_limits_are_light():
    """Carriers import planner.limits: it must not load numpy, scipy or numba."""
    loaded = _loaded_after_import(["planner", "planner.limits", "planner.registry"])
    assert _offending(loaded, ("numpy", "scipy", "numba")) == []


@pytest.mark.parametrize("path", sorted((REPO / "planner").rglob("*.py")), ids=lambda p: str(p.relative_to(REPO)))
def test_planner_import_statements(path):
    bad = []
    for line, module in _imports(path):
        top = module.split(".")[0]
        if top == "__future__" or (top in sys.stdlib_module_names and top not in CORE_FORBIDDEN_STDLIB):
            continue
        if top not in CORE_ALLOWED:
            bad.append(f"{path.name}:{line}: {module}")
    assert bad == []


def test_world_never_imports_coordinator_or_carriers():
    world = _modules("world")
    if (REPO / "world" / "__init__.py").exists():
        world = ["world", *world]
    loaded = _loaded_after_import(world)
    assert _offending(loaded, WORLD_FORBIDDEN) == []
    bad = [f"{path.relative_to(REPO)}:{line}: {module}" for path in sorted((REPO / "world").rglob("*.py"))
           for line, module in _imports(path) if module.split(".")[0] in WORLD_FORBIDDEN]
    assert bad == []


def test_priors_table_is_pure():
    """planner/priors.py is shared by the planner and world/, so it may use only numpy and scipy."""
    path = REPO / "planner" / "priors.py"
    bad = [f"{line}: {module}" for line, module in _imports(path)
           if module.split(".")[0] not in sys.stdlib_module_names | {"__future__", "numpy", "scipy"}]
    assert bad == []
