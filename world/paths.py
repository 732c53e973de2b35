"""Where the checkout's files are: the repository root and its scenarios (one definition for the
experiments, the tools, the recording and world's own benchmark)."""
from __future__ import annotations

from pathlib import Path

#: The folder holding the packages: a clone's root (the folder holding run_fleet.py), or the
#: site-packages of an installed wheel.
REPO_ROOT = Path(__file__).resolve().parents[1]
#: The scenario files (the ``scenarios`` package, bundled in the wheel too).
SCENARIOS = REPO_ROOT / "scenarios"
#: Whether the packages run from a clone (its pyproject.toml beside them) rather than from an
#: installed wheel: outputs that default into the clone (docs/results/) go under the current
#: directory instead, never into site-packages.
IN_CLONE = (REPO_ROOT / "pyproject.toml").is_file()
