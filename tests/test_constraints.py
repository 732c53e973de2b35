"""constraints.txt pins every package the project and its extras install (docs/architecture.md,
"Determinism across machines"): a dependency added to pyproject.toml without its pin would
install whatever version is newest on a fresh machine."""
from __future__ import annotations

import re
from importlib import metadata
from pathlib import Path

from packaging.markers import Marker
from packaging.requirements import Requirement

ROOT = Path(__file__).resolve().parents[1]


def _norm(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def _pins() -> dict[str, tuple[str, str]]:
    """{normalised name: (version, marker)} of constraints.txt."""
    pins = {}
    for line in (ROOT / "constraints.txt").read_text().splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        req = Requirement(line)
        (spec,) = req.specifier
        assert spec.operator == "==", line
        pins[_norm(req.name)] = (spec.version, str(req.marker))
    return pins


def _closure(requirements: list[str]) -> set[str]:
    """Normalised names of the distributions these requirements pull in (recursively, extras
    followed, markers evaluated for this interpreter); a distribution not installed here (an
    extra the suite does not need) is named but not followed."""
    seen: set[str] = set()
    todo = [(Requirement(r), ()) for r in requirements]
    while todo:
        req, extras = todo.pop()
        if req.marker is not None and not any(req.marker.evaluate({"extra": e}) for e in (extras or ("",))):
            continue
        name = _norm(req.name)
        key = name + "[" + ",".join(sorted(req.extras)) + "]"
        if key in seen:
            continue
        seen.add(key)
        try:
            subs = metadata.requires(req.name) or []
        except metadata.PackageNotFoundError:
            continue
        for sub in subs:
            todo.append((Requirement(sub), tuple(req.extras)))
    return {k.split("[")[0] for k in seen}


def test_every_dependency_and_extra_is_pinned_to_the_installed_version():
    """The project's requirements with every extra (as installed from pyproject.toml), and what
    they pull in, each pinned at the version installed here (the suite's own environment)."""
    extras = metadata.metadata("marsupial-fleet").get_all("Provides-Extra") or []
    assert {"test", "view", "cluster"} <= set(extras)
    installed = {_norm(d.metadata["Name"]) for d in metadata.distributions()}
    pins = _pins()
    needed = _closure([f"marsupial-fleet[{','.join(extras)}]"]) - {"marsupial-fleet"}
    missing = sorted(needed - set(pins))
    assert not missing, f"constraints.txt: no pin for {missing}"
    for name in sorted(needed & installed):
        version, marker = pins[name]
        if Marker(marker).evaluate() if marker != "None" else True:
            assert metadata.version(name) == version, (name, metadata.version(name), version)
