"""The coverage reward's regions: the cells of the arrangement of the candidate discs (issue 35).

A passenger released by carrier r at stage j explores the disc of radius ``sensing_radius``
centred at the carrier's planned stage position (docs/scenario.md, "Coverage reward"). A
*region* is a maximal set of points with the same *signature*, the set of candidate discs that
contain it (so a region may have several connected pieces). Regions of zero area are dropped.

Areas are exact up to floating-point rounding, by Green's theorem over the boundary arcs: every
circle is cut into arcs at its intersections with the other circles; an arc of circle i bounds the
region of signature S ∪ {i} on its inside (counter-clockwise, +) and the region S on its outside
(−), where S is the set of the other discs containing the arc's midpoint. Summing
``½∮(x dy − y dx)`` per signature gives each region's area (docs/scenario.md states the bound).

Cost: discs are hashed into a grid of cells 2ρ wide, so only discs whose circles can meet are
paired; work and memory grow with the number of meeting pairs, which is bounded up front
(:data:`MAX_PAIRS`, refused in time linear in the discs).
"""
from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from planner.limits import MAX_POINT_REGIONS

#: At most this many pairs of candidate discs whose centres share a neighbourhood of the 2ρ grid
#: (an upper bound of the meeting pairs, counted in time linear in the discs); beyond it the
#: arrangement is refused: its regions would be too many to plan with.
MAX_PAIRS = 2_000_000
#: At most this many other distinct discs may meet one disc: k circles cut a disc into at most
#: k (k + 1) + 1 regions, so 63 keep every point's regions within MAX_POINT_REGIONS (4096).
MAX_MET = 63
#: Regions whose area is at most this fraction of a disc's are dropped as zero-area (tangencies
#: and rounding leave such slivers; a feature lands in one with probability 0).
ZERO_AREA = 1e-9


class ArrangementTooLarge(ValueError):
    """The candidate discs meet too often to enumerate their regions (:data:`MAX_PAIRS`)."""


@dataclass(frozen=True, eq=False)
class Regions:
    """The arrangement of the candidate discs.

    Attributes:
        radius: ρ, the discs' radius (m).
        centres: float ``[K, 2]``: the distinct disc centres (m), in first-seen flat point order.
        disc_of: int64 ``[R, N]``: the distinct disc of each point (-1 at an invalid stage).
        signatures: tuple of M sorted tuples of disc indices: each region's signature, sorted.
        areas: float ``[M]``: each region's area (m²).
        covers: per point, ``covers[r][j]``: the sorted region indices its disc covers, None at
            an invalid stage (the instance format's ``covers``).
    """

    radius: float
    centres: np.ndarray
    disc_of: np.ndarray
    signatures: tuple[tuple[int, ...], ...]
    areas: np.ndarray
    covers: tuple[tuple[tuple[int, ...] | None, ...], ...]

    @property
    def n_regions(self) -> int:
        return len(self.signatures)

    def near(self, points: np.ndarray, discs: np.ndarray) -> np.ndarray:
        """The ``points`` (float ``[F, 2]``, m) within ρ of one of the ``discs`` (indices): all a
        region covered by those discs can count."""
        from scipy.spatial import cKDTree

        points = np.asarray(points, dtype=float).reshape(-1, 2)
        discs = np.unique(np.asarray(discs, dtype=np.int64))
        if not len(points) or not len(discs):
            return points[:0]
        dist, _ = cKDTree(self.centres[discs]).query(points, distance_upper_bound=self.radius * (1 + 1e-9) + 1e-9)
        return points[np.isfinite(dist)]

    def counts(self, points: np.ndarray) -> np.ndarray:
        """int64 ``[M]``: how many of ``points`` (float ``[F, 2]``, m) lie in each region (a point
        lies in disc k iff its distance to the centre is at most ρ). Points in no disc, or whose
        signature is a dropped zero-area one, count nowhere."""
        out = np.zeros(self.n_regions, dtype=np.int64)
        if not len(points) or not len(self.centres):
            return out
        from scipy.spatial import cKDTree

        points = np.asarray(points, dtype=float).reshape(-1, 2)
        # Only points near some centre can lie in a disc (the exact test is _signatures_of's).
        dist, _ = cKDTree(self.centres).query(points, distance_upper_bound=self.radius * (1 + 1e-9) + 1e-9)
        index = {sig: m for m, sig in enumerate(self.signatures)}
        for sig in _signatures_of(points[np.isfinite(dist)], self.centres, self.radius):
            m = index.get(sig)
            if m is not None:
                out[m] += 1
        return out


def _cells(pts: np.ndarray, size: float) -> np.ndarray:
    return np.floor(pts / size).astype(np.int64)


def _grid(centres: np.ndarray, size: float) -> dict[tuple[int, int], list[int]]:
    grid: dict[tuple[int, int], list[int]] = {}
    for k, (cx, cy) in enumerate(_cells(centres, size).tolist()):
        grid.setdefault((cx, cy), []).append(k)
    return grid


def _near(grid: dict, cell: tuple[int, int]) -> list[int]:
    cx, cy = cell
    out: list[int] = []
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            out.extend(grid.get((cx + dx, cy + dy), ()))
    return out


def candidate_pairs(centres: np.ndarray, radius: float) -> int:
    """An upper bound of the pairs of discs whose circles can meet (centres within 2ρ): the
    pairs of centres in neighbouring cells of the 2ρ grid, counted in time linear in the discs."""
    if not len(centres):
        return 0
    grid = _grid(centres, 2.0 * radius)
    sizes = {cell: len(ks) for cell, ks in grid.items()}
    total = 0
    for (cx, cy), n in sizes.items():
        around = sum(sizes.get((cx + dx, cy + dy), 0) for dx in (-1, 0, 1) for dy in (-1, 0, 1))
        total += n * (around - 1)
    return total // 2


def _signatures_of(points: np.ndarray, centres: np.ndarray, radius: float) -> list[tuple[int, ...]]:
    """The signature of each point: the sorted discs (``dist <= radius``) containing it."""
    size = 2.0 * radius
    grid = _grid(centres, size)
    out = []
    r2 = radius * radius
    for p, cell in zip(points, _cells(points, size).tolist()):
        near = _near(grid, (cell[0], cell[1]))
        if not near:
            out.append(())
            continue
        ks = np.array(sorted(near))
        d2 = (centres[ks, 0] - p[0]) ** 2 + (centres[ks, 1] - p[1]) ** 2
        out.append(tuple(ks[d2 <= r2].tolist()))
    return out


def _arc_integral(cx: float, cy: float, radius: float, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """½∫(x dy − y dx) along the circle (cx, cy, radius) counter-clockwise from angle a to b."""
    return 0.5 * (radius * radius * (b - a) + radius * (cx * (np.sin(b) - np.sin(a)) - cy * (np.cos(b) - np.cos(a))))


def arrangement(positions: np.ndarray, valid: np.ndarray, radius: float, max_pairs: int = MAX_PAIRS) -> Regions:
    """The regions of the discs of radius ``radius`` (m) centred at the valid ``positions``.

    Args:
        positions: float ``[R, N, 2]`` planned stage positions (m).
        valid: bool ``[R, N]``.
        radius: ρ > 0 (m).
        max_pairs: the bound of :func:`candidate_pairs` beyond which the arrangement is refused.

    Raises:
        ArrangementTooLarge: more candidate pairs than ``max_pairs`` (checked before any arc).
    """
    n_r, n_s = valid.shape
    disc_of = np.full((n_r, n_s), -1, dtype=np.int64)
    seen: dict[tuple[float, float], int] = {}
    for r, j in zip(*np.nonzero(valid)):
        key = (float(positions[r, j, 0]), float(positions[r, j, 1]))
        disc_of[r, j] = seen.setdefault(key, len(seen))  # points at one place share one disc
    centres = np.array(list(seen), dtype=float).reshape(-1, 2)
    _bound(centres, radius, max_pairs)
    area: dict[tuple[int, ...], float] = {}
    grid = _grid(centres, 2.0 * radius)
    cells = _cells(centres, 2.0 * radius).tolist()
    r2 = radius * radius
    for i, (cx, cy) in enumerate(centres.tolist()):
        near = np.array([k for k in _near(grid, (cells[i][0], cells[i][1])) if k != i], dtype=np.int64)
        dx, dy = centres[near, 0] - cx, centres[near, 1] - cy
        d = np.hypot(dx, dy)
        meet = (d <= 2.0 * radius) & (d > 0)  # a tangent point cuts too: no arc has its midpoint there
        base = np.arctan2(dy[meet], dx[meet])
        half = np.arccos(np.clip(d[meet] / (2.0 * radius), -1.0, 1.0))
        cuts = np.sort(np.mod(np.concatenate([base - half, base + half]), 2 * math.pi))
        if len(cuts):
            starts = cuts
            stops = np.append(cuts[1:], cuts[0] + 2 * math.pi)
            keep = stops - starts > 0
            starts, stops = starts[keep], stops[keep]
        else:
            starts, stops = np.array([0.0]), np.array([2 * math.pi])
        mids = 0.5 * (starts + stops)
        mx, my = cx + radius * np.cos(mids), cy + radius * np.sin(mids)
        inside = ((centres[near, 0][None, :] - mx[:, None]) ** 2
                  + (centres[near, 1][None, :] - my[:, None]) ** 2) <= r2  # [arcs, near]
        parts = _arc_integral(cx, cy, radius, starts, stops)
        for row, part in zip(inside, parts.tolist()):
            outside = tuple(sorted(near[row].tolist()))
            inner = tuple(sorted(outside + (i,)))
            area[inner] = area.get(inner, 0.0) + part
            if outside:
                area[outside] = area.get(outside, 0.0) - part
    floor = ZERO_AREA * math.pi * r2
    signatures = tuple(sorted(sig for sig, a in area.items() if a > floor))
    areas = np.array([area[sig] for sig in signatures], dtype=float)
    by_disc: list[list[int]] = [[] for _ in range(len(centres))]
    for m, sig in enumerate(signatures):
        for k in sig:
            by_disc[k].append(m)
    widest = max((len(regions) for regions in by_disc), default=0)
    if widest > MAX_POINT_REGIONS:  # its Observation's counts would not fit one wire payload
        raise ArrangementTooLarge(f"expected at most {MAX_POINT_REGIONS} regions in one candidate disc "
                                  f"(planner.limits.MAX_POINT_REGIONS), found {widest}")
    covers = tuple(tuple(tuple(by_disc[k]) if k >= 0 else None for k in row) for row in disc_of.tolist())
    for arr in (centres, disc_of, areas):
        arr.setflags(write=False)
    return Regions(float(radius), centres, disc_of, signatures, areas, covers)


# --------------------------------------------------------------------------- a scenario's regions

def _positions(scenario) -> tuple[np.ndarray, np.ndarray]:
    from world.stages import planned_positions

    return planned_positions(scenario), scenario.valid()


def check_size(scenario, max_pairs: int | None = None) -> None:
    """Raise :class:`ArrangementTooLarge` when the scenario's discs meet more often than
    ``max_pairs`` (:data:`MAX_PAIRS` by default) allows (cheap: the planned positions and one pass
    of the grid; no arc is computed)."""
    positions, valid = _positions(scenario)
    centres = np.unique(positions[valid].reshape(-1, 2), axis=0)
    _bound(centres, scenario.sensing_radius, MAX_PAIRS if max_pairs is None else max_pairs)
    if len(centres):  # walks the meeting pairs, bounded above
        from scipy.spatial import cKDTree

        met = cKDTree(centres).query_ball_point(centres, 2.0 * scenario.sensing_radius, return_length=True) - 1
        if met.max() > MAX_MET:
            k = int(np.argmax(met))
            raise ArrangementTooLarge(
                f"expected at most {MAX_MET} other candidate discs within 2 x sensing_radius of any one (so that "
                f"its regions' counts fit one message), found {int(met[k])} round ({centres[k, 0]:g}, {centres[k, 1]:g})")


def _bound(centres: np.ndarray, radius: float, max_pairs: int) -> None:
    pairs = candidate_pairs(centres, radius)
    if pairs > max_pairs:
        raise ArrangementTooLarge(
            f"expected at most {max_pairs} pairs of candidate discs within 2 x sensing_radius of each other "
            f"(the coverage regions would be too many), found up to {pairs} among {len(centres)} discs")


@lru_cache(maxsize=16)
def _scenario_regions(scenario) -> Regions:
    positions, valid = _positions(scenario)
    return arrangement(positions, valid, scenario.sensing_radius)


#: One arrangement computed at a time in a process: the carriers of one process (one thread each,
#: carriers/process.py) ask for it at once at their first observation, and without the lock each
#: thread computed it again (a 256-carrier coverage grid's 32 carriers per process stalled a
#: minute at stage 0 on a loaded host).
_REGIONS_LOCK = threading.Lock()


def scenario_regions(scenario) -> Regions:
    """The regions of a ``reward: coverage`` scenario's candidate discs (the schedules fix them:
    the same for every seed; cached, computed once per process however many threads ask)."""
    with _REGIONS_LOCK:
        return _scenario_regions(scenario.with_seed(0))


def region_means(scenario) -> np.ndarray:
    """float ``[M]``: each region's prior mean count, the scenario's feature density × its area
    (open field: walls, obstacles, the map's edge and clusters ignored, as in the derived prior)."""
    return scenario.feature_density() * scenario_regions(scenario).areas


def region_counts(scenario, features: np.ndarray | None = None, seed: int | None = None) -> np.ndarray:
    """int64 ``[M]``: the world's features in each region (``features``, or those of ``seed``)."""
    if features is None:
        from world.features import sample_features

        features = sample_features(scenario, seed)
    return scenario_regions(scenario).counts(features)


def coverage(scenario):
    """The planner core's :class:`planner.coverage.Coverage` of a coverage scenario: its regions'
    covers and Poisson(mean) priors."""
    from planner.coverage import Coverage, PoissonPriors

    return Coverage.build(scenario_regions(scenario).covers, PoissonPriors(region_means(scenario)))
