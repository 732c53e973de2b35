"""Features of interest: Poisson point processes over the free area of the map.

Randomness: the background process draws from ``SeedSequence(seed, spawn_key=(FEATURES_SPAWN_KEY, 0))``
and cluster i from ``SeedSequence(seed, spawn_key=(FEATURES_SPAWN_KEY, 1 + i))``, so every process
that loads the same scenario with the same seed builds the same features, and adding a cluster
does not move the background features.
"""
from __future__ import annotations

import numpy as np

from world import geometry

#: First element of the features' SeedSequence spawn keys (planner streams use ``(j,)``,
#: experiments ``(1000, t)``).
FEATURES_SPAWN_KEY = 7001
#: Features closer than this to a wall are dropped (m): a feature sits in free space, never
#: inside a wall, so line-of-sight tests never graze it.
FEATURE_CLEARANCE = 0.25


def feature_rng(seed: int, stream: int) -> np.random.Generator:
    """Generator for feature stream ``stream`` (0 = background, 1 + i = cluster i)."""
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(FEATURES_SPAWN_KEY, int(stream))))


def poisson_points(rect: tuple[float, float, float, float], density: float, rng: np.random.Generator) -> np.ndarray:
    """A homogeneous Poisson point process of ``density`` points per m² on ``rect``
    (xmin, ymin, xmax, ymax). Returns float ``[K, 2]`` (m)."""
    xmin, ymin, xmax, ymax = rect
    n = rng.poisson(density * (xmax - xmin) * (ymax - ymin))
    u = rng.random((n, 2))
    return np.column_stack([xmin + u[:, 0] * (xmax - xmin), ymin + u[:, 1] * (ymax - ymin)])


def free_mask(points: np.ndarray, the_map) -> np.ndarray:
    """bool ``[K]``: points in the free area (inside bounds, outside obstacles, at least
    FEATURE_CLEARANCE from every wall). Thinning a Poisson process by this mask keeps it Poisson
    with the same density on the free area."""
    xmin, ymin, xmax, ymax = the_map.bounds
    ok = (points[:, 0] >= xmin) & (points[:, 0] <= xmax) & (points[:, 1] >= ymin) & (points[:, 1] <= ymax)
    for poly in the_map.obstacles:
        ok &= ~geometry.inside_polygon(points, poly)
    segs = the_map.segments
    if len(segs) and ok.any():
        idx = np.flatnonzero(ok)
        for chunk in np.array_split(idx, max(1, len(idx) // 2000)):
            near = (geometry.point_segment_distance(points[chunk], segs) < FEATURE_CLEARANCE).any(axis=1)
            ok[chunk[near]] = False
    return ok


def sample_features(scenario, seed: int | None = None) -> np.ndarray:
    """Every feature of the scenario's world for root seed ``seed`` (scenario.seed by default).

    Returns float ``[F, 2]`` positions (m): background process first, then each cluster's; for
    ``features.from_map`` (and a replayed mission) the frontier cells of ``map.occupancy``.
    """
    seed = scenario.seed if seed is None else int(seed)
    the_map = scenario.map
    if scenario.features.from_map or scenario.features.replay:
        # the map fixes the features (the same for every seed): its frontier cells, which a
        # replayed mission draws but does not sense
        if the_map.occupancy is None:
            return np.zeros((0, 2))
        from world.grid import frontier_points

        return frontier_points(the_map.occupancy)
    parts = [poisson_points(the_map.bounds, scenario.features.density, feature_rng(seed, 0))]
    for i, cl in enumerate(scenario.features.clusters):
        rng = feature_rng(seed, 1 + i)
        if cl.shape == "disc":
            cx, cy, r = cl.params
            pts = poisson_points((cx - r, cy - r, cx + r, cy + r), cl.density, rng)
            pts = pts[(pts[:, 0] - cx) ** 2 + (pts[:, 1] - cy) ** 2 <= r * r]
        else:
            pts = poisson_points(cl.params, cl.density, rng)
        parts.append(pts)
    points = np.concatenate(parts, axis=0) if parts else np.zeros((0, 2))
    return points[free_mask(points, the_map)]
