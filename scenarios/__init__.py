"""The bundled scenarios: the YAML files of this folder, shipped in the wheel as package data
(with any map file a scenario names beside it), so that ``marsupial-fleet run six_carriers``
works from an installed package and ``scenarios/six_carriers.yaml`` from a clone."""
from __future__ import annotations

from importlib import resources
from pathlib import Path

#: A bundled scenario is a file of this folder with this suffix.
SUFFIX = ".yaml"


def bundled_names() -> tuple[str, ...]:
    """The bundled scenarios' names (their file names without ``.yaml``), sorted."""
    return tuple(sorted(entry.name[: -len(SUFFIX)] for entry in resources.files(__name__).iterdir()
                        if entry.name.endswith(SUFFIX) and entry.is_file()))


def bundled_path(name: str) -> Path | None:
    """The file of the bundled scenario ``name`` (``six_carriers`` or ``six_carriers.yaml``), or
    None when there is none of that name. The package is installed as files (a wheel unpacked
    into site-packages, or a clone), so the path is a real file that ``world.load_scenario``
    and a child process can open, and the maps it names are beside it."""
    stem = name[: -len(SUFFIX)] if name.endswith(SUFFIX) else name
    if stem not in bundled_names():
        return None
    return Path(str(resources.files(__name__) / (stem + SUFFIX)))
