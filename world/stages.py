"""Stage geometry known before the mission: planned decision points, validity and overlaps.

Overlaps (the paper's "groups of decision points in close proximity") are defined here as the
**maximal cliques** of the proximity graph whose nodes are the valid planned decision points
(r, j) — of any carriers, the same carrier included — and whose edges join two points at most
``conflict_radius`` apart. Consequences, which the tests check against brute force:

* every pair of points inside one overlap is within the conflict radius;
* two points share an overlap **iff** they are within the conflict radius (every edge lies in a
  maximal clique), so the planner core's "shares an overlap" matrix is exactly the proximity
  graph and the penalty p of a deployment counts the selected deployments near it;
* no overlap is a subset of another; singletons (isolated points) are left out.

Clusters (connected components) were rejected because chains of points along a path would merge
into one large group penalising deployments far apart; "one group per point" centred groups
were rejected because they make points up to 2× the radius apart conflict.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from world import geometry


@dataclass(frozen=True, eq=False)
class StageGeometry:
    """Planned stage geometry.

    Attributes:
        times: float ``[N]`` stage times (s).
        positions: float ``[R, N, 2]`` planned decision-point positions (m); NaN where invalid.
        valid: bool ``[R, N]`` — start_time <= t_j <= stop_time.
        overlaps: list of overlaps, each a sorted list of ``(r, j)`` tuples (planner core format).
    """

    times: np.ndarray
    positions: np.ndarray
    valid: np.ndarray
    overlaps: list[list[tuple[int, int]]]


def planned_positions(scenario) -> np.ndarray:
    """float ``[R, N, 2]``: planned positions at every stage time, valid or not (m)."""
    times = scenario.stage_times()
    return np.array([[c.position_at(float(t)) for t in times] for c in scenario.carriers], dtype=float).reshape(
        scenario.n_carriers, scenario.stages, 2)


def proximity_overlaps(positions: np.ndarray, valid: np.ndarray, radius: float) -> list[list[tuple[int, int]]]:
    """Maximal cliques (size >= 2) of the valid points within ``radius`` (m) of each other.

    Args:
        positions: float ``[R, N, 2]`` (m).
        valid: bool ``[R, N]``.
        radius: conflict radius (m); pairs at distance <= radius are joined.
    """
    idx = np.argwhere(valid)  # [M, 2] (r, j) in row-major order
    if len(idx) < 2:
        return []
    pts = positions[idx[:, 0], idx[:, 1]]
    groups = [g for g in geometry.maximal_cliques(neighbours(pts, radius)) if len(g) >= 2]
    return sorted([[(int(idx[m, 0]), int(idx[m, 1])) for m in g] for g in groups])


#: Up to this many points :func:`neighbours` compares all pairs; beyond, candidates come from
#: a k-d tree (memory and time near-linear in the points instead of quadratic).
DENSE_PAIRS_MAX = 2000


def neighbours(pts: np.ndarray, radius: float) -> list[frozenset]:
    """For each point of ``pts`` (float ``[M, 2]``, m), the indices of the other points at most
    ``radius`` (m) away. The test is always ``np.hypot(dx, dy) <= radius`` on the same floats,
    so the k-d tree only proposes candidates (with a little slack) and never changes the answer."""
    m = len(pts)
    if m <= DENSE_PAIRS_MAX:
        dist = np.hypot(pts[:, None, 0] - pts[None, :, 0], pts[:, None, 1] - pts[None, :, 1])
        adj = dist <= radius
        np.fill_diagonal(adj, False)
        return [frozenset(np.flatnonzero(row).tolist()) for row in adj]
    from scipy.spatial import cKDTree

    pairs = cKDTree(pts).query_pairs(radius * (1 + 1e-9) + 1e-9, output_type="ndarray")
    a, b = pairs[:, 0], pairs[:, 1]
    keep = np.hypot(pts[a, 0] - pts[b, 0], pts[a, 1] - pts[b, 1]) <= radius
    sets: list[set] = [set() for _ in range(m)]
    for u, v in zip(a[keep].tolist(), b[keep].tolist()):
        sets[u].add(v)
        sets[v].add(u)
    return [frozenset(s) for s in sets]


def stage_geometry(scenario) -> StageGeometry:
    """Planned decision points, validity and overlaps from the schedules alone."""
    valid = scenario.valid()
    pos = planned_positions(scenario)
    overlaps = proximity_overlaps(pos, valid, scenario.conflict_radius)
    pos = pos.copy()
    pos[~valid] = np.nan
    return StageGeometry(times=scenario.stage_times(), positions=pos, valid=valid, overlaps=overlaps)


#: The radii "dwarf" a map when the sensing disc's diameter exceeds its shorter side, or the
#: conflict radius its diagonal (every point then conflicts with every other).
def radii_warning(bounds, sensing_radius: float, conflict_radius: float) -> str | None:
    """One line when the radii dwarf the map ``bounds`` (xmin, ymin, xmax, ymax; m): a sensing
    disc wider than the map's shorter side, or a conflict radius beyond its diagonal; None
    otherwise."""
    w, h = bounds[2] - bounds[0], bounds[3] - bounds[1]
    if 2 * sensing_radius <= min(w, h) and conflict_radius <= (w * w + h * h) ** 0.5:
        return None
    small, large = map_radii(bounds)
    return (f"sensing radius {sensing_radius:g} m and conflict radius {conflict_radius:g} m dwarf the "
            f"{w:.3g} x {h:.3g} m map (the paper's radii are for a mine-sized map): nearly every point conflicts "
            f"with every other; radii from the map's size would be {small:g} m and {large:g} m "
            f"(python -m world import --radii map)")


def map_radii(bounds) -> tuple[float, float]:
    """(sensing radius, conflict radius) (m) chosen from the map's size: a quarter of its shorter
    side (rounded to 0.1 m, at least 0.1 m), and twice that (two sensing discs overlap)."""
    w, h = bounds[2] - bounds[0], bounds[3] - bounds[1]
    sensing = max(0.1, round(min(w, h) / 4.0, 1))
    return sensing, round(2.0 * sensing, 6)
