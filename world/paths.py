"""Where the checkout's files are: the repository root and its scenarios (one definition for the
experiments, the tools, the recording and world's own benchmark)."""
from __future__ import annotations

from pathlib import Path

#: The repository root (the folder holding run_fleet.py).
REPO_ROOT = Path(__file__).resolve().parents[1]
#: The scenario files.
SCENARIOS = REPO_ROOT / "scenarios"
