"""Plane geometry on numpy arrays: paths, line of sight, distances, polygons.

Points are ``(x, y)`` in metres; segments are rows ``(x1, y1, x2, y2)`` of a float ``[W, 4]`` array.
"""
from __future__ import annotations

import bisect
from typing import Sequence

import numpy as np


def point_along(waypoints: Sequence[tuple[float, float]] | np.ndarray, cumulative: np.ndarray,
                s: float) -> tuple[float, float]:
    """The point at arc length ``s`` (m) along the polyline ``waypoints`` whose cumulative leg
    lengths are ``cumulative`` (``[K]``, starting at 0). ``s`` is clamped to the path."""
    if s <= 0.0:
        return (float(waypoints[0][0]), float(waypoints[0][1]))
    if s >= cumulative[-1]:
        return (float(waypoints[-1][0]), float(waypoints[-1][1]))
    k = bisect.bisect_right(cumulative, s) - 1
    k = min(max(k, 0), len(waypoints) - 2)
    leg = cumulative[k + 1] - cumulative[k]
    u = 0.0 if leg <= 0 else (s - cumulative[k]) / leg
    (ax, ay), (bx, by) = waypoints[k], waypoints[k + 1]
    return (ax + u * (bx - ax), ay + u * (by - ay))


def _cross(ax, ay, bx, by):
    return ax * by - ay * bx


def crossings(origin: Sequence[float], targets: np.ndarray, segments: np.ndarray) -> np.ndarray:
    """bool ``[K, W]``: does the sight line origin→targets[k] touch or cross segment w?

    Closed test (touching counts as blocked) by orientation signs.
    """
    targets = np.asarray(targets, dtype=float).reshape(-1, 2)
    if len(segments) == 0 or len(targets) == 0:
        return np.zeros((len(targets), len(segments)), dtype=bool)
    px, py = float(origin[0]), float(origin[1])
    qx, qy = targets[:, 0:1], targets[:, 1:2]          # [K, 1]
    ax, ay, bx, by = (segments[:, i][None, :] for i in range(4))  # [1, W]
    d1 = _cross(bx - ax, by - ay, px - ax, py - ay)     # [1, W]: origin vs wall line
    d2 = _cross(bx - ax, by - ay, qx - ax, qy - ay)     # [K, W]: target vs wall line
    d3 = _cross(qx - px, qy - py, ax - px, ay - py)     # [K, W]: wall end a vs sight line
    d4 = _cross(qx - px, qy - py, bx - px, by - py)     # [K, W]: wall end b vs sight line
    hit = (d1 * d2 <= 0) & (d3 * d4 <= 0)
    # collinear segments pass the sign test wherever they lie on the line: they meet only where
    # their extents overlap (walls traced on a grid are often collinear with a route)
    collinear = hit & (d1 == 0) & (d2 == 0)
    if collinear.any():
        apart = ((np.maximum(px, qx) < np.minimum(ax, bx)) | (np.minimum(px, qx) > np.maximum(ax, bx))
                 | (np.maximum(py, qy) < np.minimum(ay, by)) | (np.minimum(py, qy) > np.maximum(ay, by)))
        hit &= ~(collinear & apart)
    return hit


def visible(origin: Sequence[float], targets: np.ndarray, segments: np.ndarray) -> np.ndarray:
    """bool ``[K]``: targets with a clear line of sight from ``origin`` (no wall touched)."""
    return ~crossings(origin, targets, segments).any(axis=1)


def count_visible(origin: Sequence[float], points: np.ndarray, radius: float, segments: np.ndarray) -> int:
    """Number of ``points`` (``[F, 2]``, m) within ``radius`` (m) of ``origin`` with line of sight."""
    if len(points) == 0:
        return 0
    d2 = (points[:, 0] - origin[0]) ** 2 + (points[:, 1] - origin[1]) ** 2
    near = points[d2 <= radius * radius]
    if len(near) == 0:
        return 0
    if len(segments):
        # only walls whose bounding box meets the sensing disc can block
        x0, y0 = origin
        lo_x = np.minimum(segments[:, 0], segments[:, 2])
        hi_x = np.maximum(segments[:, 0], segments[:, 2])
        lo_y = np.minimum(segments[:, 1], segments[:, 3])
        hi_y = np.maximum(segments[:, 1], segments[:, 3])
        keep = (hi_x >= x0 - radius) & (lo_x <= x0 + radius) & (hi_y >= y0 - radius) & (lo_y <= y0 + radius)
        segments = segments[keep]
    return int(visible(origin, near, segments).sum())


def visible_region(origin: Sequence[float], radius: float, segments: np.ndarray, rays: int = 360) -> np.ndarray:
    """float ``[rays, 2]``: the outline of what ``origin`` sees within ``radius`` (m) past the
    walls ``segments`` (``[W, 4]``): along each of ``rays`` evenly spaced directions, the point
    at the radius or at the first wall met, whichever is nearer (the sensing rule's line of
    sight, drawn)."""
    x0, y0 = float(origin[0]), float(origin[1])
    angles = np.linspace(0.0, 2.0 * np.pi, rays, endpoint=False)
    dx, dy = np.cos(angles)[:, None], np.sin(angles)[:, None]
    reach = np.full(rays, float(radius))
    if len(segments):
        lo_x = np.minimum(segments[:, 0], segments[:, 2])
        hi_x = np.maximum(segments[:, 0], segments[:, 2])
        lo_y = np.minimum(segments[:, 1], segments[:, 3])
        hi_y = np.maximum(segments[:, 1], segments[:, 3])
        near = segments[(hi_x >= x0 - radius) & (lo_x <= x0 + radius) & (hi_y >= y0 - radius) & (lo_y <= y0 + radius)]
        if len(near):
            ax, ay, bx, by = (near[:, i][None, :] for i in range(4))
            ex, ey = bx - ax, by - ay
            denom = _cross(dx, dy, ex, ey)  # [rays, W]
            with np.errstate(divide="ignore", invalid="ignore"):
                t = _cross(ax - x0, ay - y0, ex, ey) / denom   # along the ray
                u = _cross(ax - x0, ay - y0, dx, dy) / denom   # along the wall
            hit = (denom != 0) & (t >= 0) & (u >= 0) & (u <= 1)
            reach = np.minimum(reach, np.where(hit, t, np.inf).min(axis=1))
    return np.column_stack([x0 + reach * dx[:, 0], y0 + reach * dy[:, 0]])


def point_segment_distance(points: np.ndarray, segments: np.ndarray) -> np.ndarray:
    """float ``[K, W]``: Euclidean distance from each point to each segment (m)."""
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    if len(segments) == 0:
        return np.full((len(points), 0), np.inf)
    px, py = points[:, 0:1], points[:, 1:2]
    ax, ay, bx, by = (segments[:, i][None, :] for i in range(4))
    dx, dy = bx - ax, by - ay
    len2 = dx * dx + dy * dy
    u = np.where(len2 > 0, ((px - ax) * dx + (py - ay) * dy) / np.where(len2 > 0, len2, 1.0), 0.0)
    u = np.clip(u, 0.0, 1.0)
    return np.hypot(px - (ax + u * dx), py - (ay + u * dy))


def segment_segment_distance(a: Sequence[float], b: Sequence[float], segments: np.ndarray) -> np.ndarray:
    """float ``[W]``: distance between segment a-b and each segment (0 when they cross) (m)."""
    if len(segments) == 0:
        return np.zeros(0)
    cross = crossings(a, np.asarray([b], dtype=float), segments)[0]
    ends = np.stack([segments[:, 0:2], segments[:, 2:4]], axis=0).reshape(-1, 2)
    d_ends = point_segment_distance(ends, np.asarray([[a[0], a[1], b[0], b[1]]])).reshape(2, -1).min(axis=0)
    d_ab = point_segment_distance(np.asarray([a, b], dtype=float), segments).min(axis=0)
    return np.where(cross, 0.0, np.minimum(d_ends, d_ab))


def first_blocking_segment(a: Sequence[float], b: Sequence[float], segments: np.ndarray, clearance: float = 0.0) -> int | None:
    """Index of the first segment closer than ``clearance`` (m) to the leg a-b, or None."""
    if len(segments) == 0:
        return None
    # only segments whose box comes within the clearance of the leg's box can be that close
    # (cheap, and it keeps the index order, so the first hit is the same)
    lo_x, hi_x = min(a[0], b[0]) - clearance, max(a[0], b[0]) + clearance
    lo_y, hi_y = min(a[1], b[1]) - clearance, max(a[1], b[1]) + clearance
    near = np.flatnonzero((np.maximum(segments[:, 0], segments[:, 2]) >= lo_x)
                          & (np.minimum(segments[:, 0], segments[:, 2]) <= hi_x)
                          & (np.maximum(segments[:, 1], segments[:, 3]) >= lo_y)
                          & (np.minimum(segments[:, 1], segments[:, 3]) <= hi_y))
    if not len(near):
        return None
    d = segment_segment_distance(a, b, segments[near])
    hits = np.flatnonzero(d < clearance) if clearance > 0 else np.flatnonzero(d <= 0)
    return int(near[hits[0]]) if len(hits) else None


def inside_polygon(points: np.ndarray, polygon: Sequence[tuple[float, float]]) -> np.ndarray:
    """bool ``[K]``: points strictly inside the closed polygon (even-odd ray casting)."""
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    poly = np.asarray(polygon, dtype=float)
    x, y = points[:, 0:1], points[:, 1:2]
    x1, y1 = poly[:, 0][None, :], poly[:, 1][None, :]
    x2, y2 = np.roll(poly[:, 0], -1)[None, :], np.roll(poly[:, 1], -1)[None, :]
    straddle = (y1 > y) != (y2 > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        x_at = x1 + (y - y1) * (x2 - x1) / (y2 - y1)
    hits = straddle & (x < x_at)
    return (hits.sum(axis=1) % 2) == 1


def maximal_cliques(adjacency) -> list[list[int]]:
    """All maximal cliques of an undirected graph, by Bron–Kerbosch with pivoting. Each clique
    sorted; list sorted. Deterministic.

    Args:
        adjacency: bool ``[n, n]`` (zero diagonal), or the neighbour sets of the n nodes (a
            sequence of sets of node indices, no self-loops).
    """
    n = len(adjacency)
    if isinstance(adjacency, np.ndarray):
        nbrs = [frozenset(np.flatnonzero(adjacency[i]).tolist()) for i in range(n)]
    else:
        nbrs = [frozenset(s) for s in adjacency]
    out: list[list[int]] = []

    def expand(r: list[int], p: set[int], x: set[int]) -> None:
        if not p and not x:
            out.append(sorted(r))
            return
        pivot = max(p | x, key=lambda u: (len(nbrs[u] & p), -u))
        for v in sorted(p - nbrs[pivot]):
            expand(r + [v], p & nbrs[v], x & nbrs[v])
            p.discard(v)
            x.add(v)

    expand([], set(range(n)), set())
    return sorted(out)
