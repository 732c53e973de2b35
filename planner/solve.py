"""Run one planner online over one instance file: what ``python -m coordinator.solve`` prints.

Pure: reads the instance file, runs :func:`planner.problem.run_online` and the clairvoyant bound,
returns a JSON-ready dict. The command line (argparse, exit codes) is in :mod:`coordinator.solve`.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from planner.instance import load_instance
from planner.problem import run_online


def solve_instance(path: str | Path, planner, planner_name: str, seed: int, clairvoyant: bool = True) -> dict:
    """Load the instance at ``path``, run ``planner`` online with root seed ``seed``, evaluate.

    Returns:
        ``{"planner", "seed", "deployments" [[stage, ...] per carrier], "reward", "features",
        "decision_ms" [ms per stage], "observations" [[x or None]], "observations_sampled",
        "clairvoyant" {"reward", "features", "exact"} (with ``clairvoyant``)}``.

    Raises:
        planner.instance.InstanceError: a bad instance file (one line).
    """
    (problem, x), sampled = load_instance(path, seed=seed)
    result = run_online(problem, x, planner, seed)
    out = {
        "planner": planner_name,
        "seed": seed,
        "deployments": [np.flatnonzero(row).tolist() for row in result.deployed],
        "reward": result.reward,
        "features": result.features,
        "decision_ms": [round(t, 3) for t in result.decision_ms],
        "observations": [[None if np.isnan(v) else float(v) for v in row] for row in x],
        "observations_sampled": sampled,
    }
    if clairvoyant:
        from planner import clairvoyant as bound_mod  # numba: loaded only when needed

        bound = bound_mod.solve(problem, x)
        out["clairvoyant"] = {"reward": bound.reward, "features": bound.features, "exact": bound.exact}
    return out
