"""The coverage reward in a mission (issue 35): what the coordinator's state knows of the region
counts, and what the mission needs of its carriers.

Under ``reward: coverage`` a carrier's Observation carries the counts of the regions its disc
covers (wire revision 5, ``counts``), in the order of the point's regions
(:meth:`planner.coverage.Coverage.regions`); the coordinator folds them into its state
(:attr:`mission.state.MissionState.counts`) and plans with the counts revealed so far, NaN for the
others — exactly what :func:`planner.coverage.revealed` gives the offline planner from the same
observations. Pure: numpy only; the coverage object is duck-typed.
"""
from __future__ import annotations

import numpy as np

#: The first protocol revision whose carriers send region counts (wire.messages.COUNTS_REVISION;
#: kept here too so that the pure core imports nothing of the wire).
COUNTS_REVISION = 5


def spec_options(problem) -> dict:
    """The :meth:`mission.state.MissionSpec.build` options of a problem: under the coverage reward,
    carriers of revision :data:`COUNTS_REVISION` or later only, and each point's region count."""
    cov = problem.coverage
    if cov is None:
        return {}
    n_regions = np.diff(cov.ptr).reshape(problem.valid.shape)
    return {"min_revision": COUNTS_REVISION, "point_regions": n_regions.tolist()}


def revealed_counts(state, coverage) -> np.ndarray:
    """float ``[M]``: the region counts the accepted Observations and accounts carried, NaN for
    the regions none revealed."""
    out = np.full(coverage.n_regions, np.nan)
    n_stages = state.spec.n_stages
    for (cid, j), counts in state.counts.items():
        out[coverage.regions(state.spec.index(cid) * n_stages + j)] = counts
    return out


def planning_counts(state, problem) -> np.ndarray | None:
    """The ``counts`` argument of :func:`planner.online.stage_step` (None under the penalty reward)."""
    return None if problem.coverage is None else revealed_counts(state, problem.coverage)


def summary_fields(problem, deployed: np.ndarray, released: np.ndarray | None, x: np.ndarray,
                   known: np.ndarray) -> dict:
    """summary.json's ``coverage`` entry: the reward model, the features covered by the
    deployments (``covered_features``, each region once, worth its best passenger's weight under
    passenger types; ``reward`` the same over the problem's scale), the regions and how many were
    revealed. Every deployment's own regions were revealed by its observation; a region revealed by
    nobody counts 0. ``x``: the observations; ``known``: :func:`revealed_counts` (NaN unrevealed)."""
    from planner.problem import evaluate

    reward, covered = evaluate(problem, deployed, x, released, counts=np.nan_to_num(known))
    return {"reward": "coverage", "total_reward": float(reward), "covered_features": float(covered),
            "regions": int(problem.coverage.n_regions), "regions_revealed": int((~np.isnan(known)).sum()),
            "revealed_features": float(np.nansum(known))}
