"""Import boundaries: planner/ uses numpy/scipy/numba only (every module of it, no exclusions;
highspy only inside a function body, so importing the core never loads it);
world/ never imports coordinator/ or carriers/. Checked twice: by importing in a fresh interpreter, and statically over every import
statement (so a lazy import inside a function cannot slip through).

The project's module graph, built by ``ast`` from every import statement (function bodies and
``__main__`` blocks included; planner/'s command lines are in planner/cli/, reached from the rest
of planner/ only by one-line forwards), has no cycle (every strongly connected component is one module) and follows the layers
of docs/architecture.md, read from that file."""
from __future__ import annotations

import ast
import functools
import json
import pkgutil
import re
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

#: Top-level packages the planner may import besides the standard library and itself.
CORE_ALLOWED = {"numpy", "scipy", "numba", "planner", "validation"}
#: Packages the planner may import only inside a function (never at module level): the LP solver
#: of planner/duality.py.
CORE_LAZY = {"highspy"}
#: Must never be loaded by importing any planner module. (yaml is absent on purpose: numba itself
#: loads it to read its optional config file; the static check below still keeps planner/ from
#: importing it.)
CORE_FORBIDDEN = ("zenoh", "pymunk", "msgpack", "sqlite3", "_sqlite3", "matplotlib", "world", "wire",
                  "coordinator", "carriers", "mission", "experiments", "highspy")
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
    for node in ast.walk(_parsed(path)):
        if isinstance(node, ast.Import):
            out += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.append((node.lineno, node.module))
        elif isinstance(node, ast.ImportFrom) and node.level > 0:
            out.append((node.lineno, path.parent.name + "." + (node.module or "")))
    return out


def _module_level_import_lines(path: Path) -> set[int]:
    """Lines of the import statements of a file outside every function body."""
    lines: set[int] = set()

    def visit(node):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
                continue
            if isinstance(child, (ast.Import, ast.ImportFrom)):
                lines.add(child.lineno)
            visit(child)

    visit(_parsed(path))
    return lines


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
                 "clairvoyant", "instance", "solve", "kernels", "mcts.fast", "mcts.kernel",
                 "mcts.reference", "conformance", "cli", "cli.solve", "cli.measure", "cli.bench", "cli.conformance"):
        assert f"planner.{name}" in core


def test_no_planner_module_imports_a_process_library_in_a_fresh_interpreter():
    """Every module of planner/ imported in turn in one fresh interpreter; what each import
    loaded first is kept. A module that loads a forbidden library on its own loads it here too
    (by itself, or an earlier module did: the union is empty only if each module's is), and the
    failure names the module whose import brought it in."""
    modules = _planner_modules()
    code = (
        "import importlib, json, sys\n"
        "new = {}\n"
        f"for name in {modules!r}:\n"
        "    before = set(sys.modules)\n"
        "    importlib.import_module(name)\n"
        "    new[name] = sorted(set(sys.modules) - before)\n"
        "print(json.dumps(new))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    new = json.loads(proc.stdout.splitlines()[-1])
    assert set(new) == set(modules)
    loaded = {name for names in new.values() for name in names}
    assert set(modules) <= loaded | {"planner"}  # each was imported (planner itself before the run's first)
    assert {name: bad for name, names in new.items() if (bad := _offending(names, CORE_FORBIDDEN))} == {}


def test_planner_package_and_limits_are_light():
    """Carriers import planner.limits: it must not load numpy, scipy or numba."""
    loaded = _loaded_after_import(["planner", "planner.limits", "planner.registry"])
    assert _offending(loaded, ("numpy", "scipy", "numba")) == []


#: The core has no command line: the planner's command lines live in planner/cli/ (the one place in
#: planner/ with argparse and ``__main__`` blocks of any shape). ``python -m`` runs the file it
#: names, so the planner modules whose commands the docs show keep a ``__main__`` block that only
#: forwards there: exactly ``from planner.cli.M import F`` and ``raise SystemExit(F())``, as the
#: file's first statement (after its docstring and ``from __future__``): the command's own import
#: of the module then runs its body once, under its name, never a second time as ``__main__``.
FORWARDS = {"planner/online_optimal.py": ("planner.cli.measure", "optimal_table"),
            "planner/clairvoyant.py": ("planner.cli.measure", "clairvoyant_times"),
            "planner/coverage_bounds.py": ("planner.cli.measure", "coverage_bound_times"),
            "planner/conformance.py": ("planner.cli.conformance", "main"),
            # mission/ has no command line either: ``python -m mission.simulate`` is launcher/simulate.py's
            "mission/simulate/__main__.py": ("launcher.simulate", "main"),
            # ``python -m world`` runs world/'s command with the wire's checks (launcher/scenario_check.py)
            "world/__main__.py": ("launcher.scenario_check", "world_command")}
CLI = "planner/cli/"


def _main_blocks(tree: ast.Module) -> list[ast.If]:
    return [node for node in tree.body if _is_main_guard(node)]


def _forward_lines(path: Path) -> set[int]:
    """Lines of the allowed forward's import (empty for every other file)."""
    rel = path.relative_to(REPO).as_posix()
    if rel not in FORWARDS:
        return set()
    return {node.lineno for block in _main_blocks(_parsed(path)) for node in block.body
            if isinstance(node, ast.ImportFrom) and node.module == FORWARDS[rel][0]}


@pytest.mark.parametrize("path", [*sorted((REPO / "planner").rglob("*.py")),
                                  *sorted((REPO / "mission" / "simulate").glob("*.py"))],
                         ids=lambda p: str(p.relative_to(REPO)))
def test_the_core_has_no_command_line(path):
    """No argparse in planner/ outside planner/cli/, and no ``__main__`` block but the forwards,
    each exactly one import of its function from planner/cli/ and ``raise SystemExit`` of its call."""
    tree = _parsed(path)
    rel = path.relative_to(REPO).as_posix()
    if rel.startswith(CLI):
        return
    assert "argparse" not in {module.split(".")[0] for _, module in _imports(path)}
    blocks = _main_blocks(tree)
    if rel not in FORWARDS:
        assert blocks == [] and not any(_is_main_guard(node) for node in ast.walk(tree))
        return
    module, function = FORWARDS[rel]
    assert len(blocks) == 1
    first = [node for node in tree.body if not (isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant))
             and not (isinstance(node, ast.ImportFrom) and node.module == "__future__")][0]
    assert first is blocks[0], f"{rel}: the forward is not the first statement"
    body = blocks[0].body
    assert len(body) == 2 and not blocks[0].orelse
    imp, stop = body
    assert isinstance(imp, ast.ImportFrom) and imp.module == module and imp.level == 0
    assert [a.name for a in imp.names] == [function] and imp.names[0].asname is None
    assert isinstance(stop, ast.Raise) and stop.cause is None
    exc = stop.exc
    assert (isinstance(exc, ast.Call) and isinstance(exc.func, ast.Name) and exc.func.id == "SystemExit"
            and len(exc.args) == 1 and not exc.keywords)
    call = exc.args[0]
    assert (isinstance(call, ast.Call) and not call.args and not call.keywords
            and isinstance(call.func, ast.Name) and call.func.id == function)


def test_nothing_of_the_planner_imports_its_command_lines():
    """planner/cli/ sits above the rest of planner/: only the forwards' ``__main__`` lines and the
    command lines themselves import it."""
    bad = []
    for path in sorted((REPO / "planner").rglob("*.py")):
        rel = path.relative_to(REPO).as_posix()
        if rel.startswith(CLI):
            continue
        forward = _forward_lines(path)
        bad += [f"{rel}:{line}: {module}" for line, module in _imports(path)
                if line not in forward and (module == "planner.cli" or module.startswith("planner.cli."))]
    assert bad == []
    assert (REPO / CLI / "solve.py").exists() and (REPO / CLI / "measure.py").exists()


@pytest.mark.parametrize("path", sorted((REPO / "planner").rglob("*.py")), ids=lambda p: str(p.relative_to(REPO)))
def test_planner_import_statements(path):
    bad = []
    module_level = _module_level_import_lines(path)
    forward = _forward_lines(path)
    for line, module in _imports(path):
        if line in forward:
            continue
        top = module.split(".")[0]
        if top == "__future__" or (top in sys.stdlib_module_names and top not in CORE_FORBIDDEN_STDLIB):
            continue
        if top in CORE_LAZY and line not in module_level:
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


def test_validation_toolkit_is_the_standard_library_only():
    """validation/ sits below every package: it imports nothing but the standard library."""
    bad = [f"{path.name}:{line}: {module}" for path in sorted((REPO / "validation").rglob("*.py"))
           for line, module in _imports(path) if module.split(".")[0] not in sys.stdlib_module_names | {"__future__"}]
    assert bad == []


def test_priors_table_is_pure():
    """planner/priors.py is shared by the planner and world/, so it may use only numpy, scipy and
    the validation toolkit (itself the standard library only)."""
    path = REPO / "planner" / "priors.py"
    bad = [f"{line}: {module}" for line, module in _imports(path)
           if module.split(".")[0] not in sys.stdlib_module_names | {"__future__", "numpy", "scipy", "validation"}]
    assert bad == []


# ----------------------------------------------------------------------------- the module graph

#: Folders above every layer (they may import anything of the project; nothing imports them), and
#: run_fleet.py, the launcher's entry point from a clone.
UNLAYERED = {"tools", "tests"}
SHIMS = ("run_fleet.py",)


def _project_modules() -> dict[str, Path]:
    """Module name -> file, for every package of the project (a folder with ``__init__.py`` at the
    repository root)."""
    out = {}
    for init in sorted(REPO.glob("*/__init__.py")):
        package = init.parent.name
        if package.startswith(".") or package in UNLAYERED:
            continue
        for path in sorted(init.parent.rglob("*.py")):
            parts = path.relative_to(REPO).with_suffix("").parts
            out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


@functools.lru_cache(maxsize=None)
def _parsed(path: Path) -> ast.Module:
    """The syntax tree of a file (parsed once per test session)."""
    return ast.parse(path.read_text(), str(path))


def _is_main_guard(node: ast.AST) -> bool:
    """``if __name__ == "__main__":`` (its imports count in the module graph like any other)."""
    test = getattr(node, "test", None)
    return (isinstance(node, ast.If) and isinstance(test, ast.Compare) and isinstance(test.left, ast.Name)
            and test.left.id == "__name__" and len(test.comparators) == 1
            and isinstance(test.comparators[0], ast.Constant) and test.comparators[0].value == "__main__")


def _import_nodes(tree: ast.AST, skip: set[int] = frozenset()):
    """Every import statement of a module, function bodies and ``__main__`` blocks included, but
    the lines ``skip`` (the planner's command-line forwards, :data:`FORWARDS`)."""
    stack = [tree]
    while stack:
        node = stack.pop()
        if isinstance(node, (ast.Import, ast.ImportFrom)) and node.lineno not in skip:
            yield node
        stack.extend(ast.iter_child_nodes(node))


def _imported(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """Absolute dotted names that module ``name`` imports, project or not. ``from P import n``
    counts as ``P.n`` when that is one of ``modules`` (else as ``P``); a relative import is
    resolved against the module's package."""
    package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    wanted = set()
    for node in _import_nodes(_parsed(path), _forward_lines(path)):
        if isinstance(node, ast.Import):
            wanted.update(alias.name for alias in node.names)
            continue
        base = node.module or ""
        if node.level:
            base = ".".join(package[: len(package) - node.level + 1] + ([node.module] if node.module else []))
        subs = [f"{base}.{alias.name}" for alias in node.names if f"{base}.{alias.name}" in modules]
        wanted.update(subs)
        if len(subs) < len(node.names):
            wanted.add(base)
    return wanted


def _targets(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """Project modules that module ``name`` imports (:func:`_imported`, each name cut back to the
    module it names)."""
    wanted = _imported(name, path, modules)
    out = set()
    for target in wanted:
        while target and target not in modules:
            target = target.rpartition(".")[0]
        if target and target != name:
            out.add(target)
    return out


def _graph() -> dict[str, set[str]]:
    modules = _project_modules()
    return {name: _targets(name, path, modules) for name, path in modules.items()}


def _components(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components (Tarjan, iterative)."""
    index, low, on_stack, stack, out = {}, {}, set(), [], []
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, edges = work[-1]
            for nxt in edges:
                if nxt not in index:
                    index[nxt] = low[nxt] = len(index)
                    stack.append(nxt)
                    on_stack.add(nxt)
                    work.append((nxt, iter(sorted(graph[nxt]))))
                    break
                if nxt in on_stack:
                    low[node] = min(low[node], index[nxt])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    component = []
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        component.append(member)
                        if member == node:
                            break
                    out.append(sorted(component))
    return out


def test_components_finds_a_cycle_and_only_it():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": set()}
    assert sorted(_components(graph)) == [["a", "b", "c"], ["d"], ["e"]]


def test_no_import_cycle_in_the_project():
    graph = _graph()
    assert "planner.registry" in graph and "experiments.run" in graph  # the graph covers the packages
    assert "planner.decentralised" in graph["planner.online"]  # function-level imports count
    cycles = [c for c in _components(graph) if len(c) > 1]
    assert cycles == [], "import cycles: " + "; ".join(
        " ".join(f"{m} -> {sorted(graph[m] & set(c))}" for m in c) for c in cycles)


def _documented_layers() -> list[set[str]]:
    """The layer list of docs/architecture.md (its first indented block), top first: per line
    the packages it names (``name/``)."""
    text = (REPO / "docs" / "architecture.md").read_text()
    block = re.search(r"\n\n((?:    \S.*\n)+)", text).group(1)
    layers = []
    for line in block.splitlines():
        head = line.split("(")[0] + "".join(re.findall(r"\),\s*([a-z0-9_]+/)", line))
        names = set(re.findall(r"(?<![\w.-])([a-z0-9_]+)/", head))
        layers.append(names)
    return layers


def test_nothing_layered_imports_the_unlayered_folders():
    """tools/ and tests/ sit above every layer: no package imports them (a benchmark of a package
    lives in tools/)."""
    modules = _project_modules()
    bad = [f"{name} -> {target}" for name, path in sorted(modules.items())
           for target in sorted(_imported(name, path, modules)) if target.split(".")[0] in UNLAYERED]
    assert bad == []


def test_every_package_is_in_the_documented_layers_once():
    layers = _documented_layers()
    named = [p for layer in layers for p in layer]
    packages = {name.split(".")[0] for name in _project_modules()}
    assert sorted(named) == sorted(packages), "docs/architecture.md's layer list must name every package once"


def test_imports_follow_the_documented_layers():
    """A module imports project modules of its own package or of packages on lower lines only."""
    rank = {p: i for i, layer in enumerate(_documented_layers()) for p in layer}
    bad = []
    for name, targets in sorted(_graph().items()):
        top = name.split(".")[0]
        for target in sorted(targets):
            other = target.split(".")[0]
            if other != top and rank[other] <= rank[top]:
                bad.append(f"{name} -> {target}")
    assert bad == []


# --------------------------------------------------------------------------- thin processes
#: The processes stay thin (docs/architecture.md, "Thin processes"): no function longer than
#: this many lines and no class longer than that many in carriers/, coordinator/ and launcher/.
PROCESS_FUNCTION_MAX = 80
PROCESS_CLASS_MAX = 300


def _process_files() -> list[Path]:
    return sorted([*(REPO / "carriers").glob("*.py"), *(REPO / "coordinator").glob("*.py"),
                   *(REPO / "launcher").glob("*.py")])


def _too_long(tree: ast.AST, function_max: int, class_max: int) -> list[tuple[str, int, int]]:
    """(kind and name, first line, length in lines) of every function (methods and nested
    functions included) longer than ``function_max`` lines and every class longer than
    ``class_max``; a length counts from the ``def``/``class`` line to the last line of its body."""
    out = []
    for node in ast.walk(tree):
        length = getattr(node, "end_lineno", 0) - getattr(node, "lineno", 0) + 1
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and length > function_max:
            out.append((f"def {node.name}", node.lineno, length))
        elif isinstance(node, ast.ClassDef) and length > class_max:
            out.append((f"class {node.name}", node.lineno, length))
    return out


def test_too_long_finds_long_functions_and_classes():
    body = "\n".join(f"    x{i} = {i}" for i in range(5))
    src = f"def short():\n    pass\n\ndef long():\n{body}\n\nclass C:\n    def m(self):\n{body.replace('    ', '        ')}\n"
    tree = ast.parse(src)
    assert sorted(_too_long(tree, 5, 6)) == [("class C", 11, 7), ("def long", 4, 6), ("def m", 12, 6)]
    assert _too_long(tree, 6, 7) == []  # at the limit is fine


def test_processes_are_thin():
    """carriers/, coordinator/ and launcher/: every function at most 80 lines, every class at
    most 300 (the jobs of a process live in modules of their own)."""
    files = _process_files()
    assert len(files) > 10  # the folders are where this test thinks they are
    problems = [f"{path.relative_to(REPO)}:{line}: {what} is {length} lines"
                for path in files for what, line, length in _too_long(
                    _parsed(path), PROCESS_FUNCTION_MAX, PROCESS_CLASS_MAX)]
    assert problems == []


def test_no_class_of_the_project_is_over_300_lines():
    """Every module of the project (the simulator's Simulation and drivers included): a class of
    more than 300 lines holds jobs that want modules of their own."""
    paths = [*_project_modules().values(), *(p for d in sorted(UNLAYERED) for p in sorted((REPO / d).rglob("*.py")))]
    problems = [f"{path.relative_to(REPO)}:{line}: {what} is {length} lines"
                for path in paths for what, line, length in _too_long(_parsed(path), 10**6, PROCESS_CLASS_MAX)
                if what.startswith("class ")]
    assert problems == []


#: Most attributes a process object holds (its parts are named structures and collaborators).
PROCESS_ATTRIBUTES_MAX = 15


@pytest.mark.parametrize("path, name", [("carriers/node.py", "Carrier"), ("coordinator/node.py", "Coordinator")])
def test_process_objects_hold_few_attributes(path, name):
    """A process object is a driver: its machines, its collaborators and its I/O, at most
    fifteen attributes (what they hold is theirs: properties name what it reads of them)."""
    tree = _parsed(REPO / path)
    cls = next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == name)
    stored = {n.attr for n in ast.walk(cls) if isinstance(n, ast.Attribute) and isinstance(n.ctx, ast.Store)
              and isinstance(n.value, ast.Name) and n.value.id == "self"}
    assert len(stored) <= PROCESS_ATTRIBUTES_MAX, sorted(stored)


#: Most lines a process object may span (docs/architecture.md, "Thin processes"): an I/O loop that
#: feeds its machines their messages and clock ticks and carries out their effects, about 150
#: lines; what is not the loop lives in its crew, its opening and closing, and its machines.
PROCESS_OBJECT_MAX = 160


@pytest.mark.parametrize("path, name", [("carriers/node.py", "Carrier"), ("coordinator/node.py", "Coordinator")])
def test_process_objects_are_io_loops(path, name):
    """``Carrier`` and ``Coordinator`` span at most 160 lines each, counted by ``ast`` from the
    ``class`` line to the last line of its body (docstrings and comments included)."""
    tree = _parsed(REPO / path)
    cls = next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == name)
    length = cls.end_lineno - cls.lineno + 1
    assert length <= PROCESS_OBJECT_MAX, f"{path}: class {name} is {length} lines"


@pytest.mark.parametrize("path, name", [("carriers/node.py", "Carrier"), ("coordinator/node.py", "Coordinator")])
def test_no_collaborator_calls_back_into_a_process_object(path, name):
    """A process object hands its collaborators data, never itself, its methods or a closure over
    it (etcd raft's shape: they return what they read, or yield what they ask, and the process
    carries it out). Allowed: its log (a sink for lines), and its own handler given to
    :func:`mission.timers.drive`, the loop that carries out a collaborator's requests."""
    tree = _parsed(REPO / path)
    cls = next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == name)
    methods = {f.name for f in cls.body if isinstance(f, ast.FunctionDef)}

    def names_self(node) -> bool:
        return any(isinstance(x, ast.Name) and x.id == "self" for x in ast.walk(node))

    def logs_only(node) -> bool:  # a lambda that only writes a line to its log
        return isinstance(node.body, ast.Call) and ast.unparse(node.body.func) == "self.log"

    bad = []
    for call in ast.walk(cls):
        if not isinstance(call, ast.Call) or ast.unparse(call.func) == "property":
            continue
        for arg in [*call.args, *(k.value for k in call.keywords)]:
            handed = ast.unparse(arg)
            if handed == "self" or (isinstance(arg, ast.Lambda) and names_self(arg) and not logs_only(arg)) or (
                    handed.startswith("self.") and handed[5:] in methods and handed != "self.log"
                    and ast.unparse(call.func) != "tm.drive"):
                bad.append(f"{path}:{call.lineno}: {ast.unparse(call)[:100]}")
    assert bad == []


#: Most parameters a function of the project may take (numba kernels included): beyond, pass named
#: structures (NamedTuples of arrays, as planner/mcts/kernel.py does).
MAX_PARAMETERS = 12


def test_no_function_takes_more_than_twelve_parameters():
    bad = []
    paths = [*_project_modules().values(), *(p for d in sorted(UNLAYERED) for p in sorted((REPO / d).rglob("*.py"))),
             *(REPO / shim for shim in SHIMS)]
    for path in paths:
        for node in ast.walk(_parsed(path)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
                a = node.args
                count = (len(a.posonlyargs) + len(a.args) + len(a.kwonlyargs) + (a.vararg is not None)
                         + (a.kwarg is not None))
                if count > MAX_PARAMETERS:
                    bad.append(f"{path.relative_to(REPO)}:{node.lineno} {getattr(node, 'name', 'lambda')}: {count}")
    assert bad == []
