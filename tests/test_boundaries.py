"""Import boundaries: the planner core uses numpy/scipy/numba only; world/ never imports coordinator/
or carriers/. Checked twice: by importing in a fresh interpreter, and statically over every import
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

#: coordinator/ modules that are process code (I/O), outside the pure planner core.
CORE_EXCLUDED = {"node", "store"}
#: Top-level packages the core may import besides the standard library and itself.
CORE_ALLOWED = {"numpy", "scipy", "numba", "coordinator", "priors"}
#: Must never be loaded by importing the core. (yaml is absent on purpose: numba itself loads it to
#: read its optional config file; the static check below still keeps the core from importing it.)
CORE_FORBIDDEN = ("zenoh", "pymunk", "msgpack", "matplotlib", "world", "wire", "carriers",
                  "coordinator.node", "coordinator.store")
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


def test_core_modules_exist():
    core = _modules("coordinator", CORE_EXCLUDED)
    for name in ("problem", "ssap", "planners", "clairvoyant", "instance", "solve"):
        assert f"coordinator.{name}" in core


def test_core_imports_no_process_libraries_in_a_fresh_interpreter():
    core = _modules("coordinator", CORE_EXCLUDED)
    loaded = _loaded_after_import(core)
    assert "planner.problem" in loaded and "numpy" in loaded
    assert _offending(loaded, CORE_FORBIDDEN) == []


@pytest.mark.parametrize("name", [m.split(".")[-1] for m in _modules("coordinator", CORE_EXCLUDED)])
def test_core_import_statements(name):
    path = REPO / "coordinator" / f"{name}.py"
    if not path.exists():
        path = REPO / "coordinator" / name / "__init__.py"
    bad = []
    for line, module in _imports(path):
        top = module.split(".")[0]
        if top in sys.stdlib_module_names or top == "__future__":
            continue
        if top not in CORE_ALLOWED or module.split(".")[:2] in (["coordinator", "node"], ["coordinator", "store"]):
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


def test_shared_priors_table_is_pure():
    """priors/ is shared by the core and world/, so it may use only numpy and scipy."""
    bad = [f"{path.relative_to(REPO)}:{line}: {module}" for path in sorted((REPO / "priors").rglob("*.py"))
           for line, module in _imports(path)
           if module.split(".")[0] not in sys.stdlib_module_names | {"__future__", "numpy", "scipy"}]
    assert bad == []
