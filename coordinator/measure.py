"""The exact solvers' measurement command lines, now in :mod:`planner.cli.measure` (``python -m
planner.online_optimal`` and ``python -m planner.clairvoyant`` forward there); importable here
under their earlier name."""
from __future__ import annotations

from planner.cli.measure import clairvoyant_times, optimal_table  # noqa: F401
