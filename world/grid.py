"""Occupancy grids: a team's own map, its frontier cells and the walls it implies.

One home for what both the importer (``python -m world import``) and a live robot's sensing
(``--ros2-robot`` with ``--robot-sensing frontier``) compute from a map, so that they compute the same value:

* :class:`OccupancyGrid`: cells as ``nav_msgs/msg/OccupancyGrid`` holds them (int8, row-major
  from the origin cell, -1 unknown, 0..100 occupancy), the resolution (m per cell), the origin
  pose (x m, y m, yaw rad) of cell (0, 0)'s outer corner, and a stamp (s);
* :func:`read_map_yaml`: a ROS map_server map (YAML and its PGM or PNG image) loaded by the
  rules of nav2's map_io (``mode`` trinary, scale or raw; ``negate``; ``occupied_thresh``,
  ``free_thresh``), image row 0 at the top;
* :func:`frontier_mask` (Yamauchi 1997): a free cell with at least one unknown cell among its
  8 neighbours (cells beyond the grid's edge are not unknown);
* :class:`FrontierCounter`: the paper's value of a point — the frontier cells whose centre lies
  within a radius of it;
* :func:`wall_lines`: the occupied cells' outlines (marching squares at the cell edges, then
  Douglas–Peucker within a tolerance) as polylines in the map frame, never a body per cell.

Cells are classified as a map_saver does: a value in 0..``free_level`` is free, one in
``occupied_level``..100 is occupied, -1 and everything between is unknown (``DEFAULT_FREE_LEVEL``,
``DEFAULT_OCCUPIED_LEVEL``: map_saver's 0.25 and 0.65 of 100).
"""
from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np

#: Cell classes of :meth:`OccupancyGrid.classes`.
FREE, OCCUPIED, UNKNOWN = 0, 1, 2
#: map_saver's thresholds on the 0..100 occupancy scale (0.25 and 0.65).
DEFAULT_FREE_LEVEL = 25
DEFAULT_OCCUPIED_LEVEL = 65
#: Largest grid accepted (cells): 10^8 int8 cells is 100 MB, and everything derived from it is
#: linear in the cells.
MAX_CELLS = 100_000_000
#: The PGM values :func:`write_map_yaml` writes (map_saver's) and the thresholds it writes with
#: them so that a map_server reads the same classes back: occupancy 1 - v / 255.
PGM_FREE, PGM_OCCUPIED, PGM_UNKNOWN = 254, 0, 205
WRITE_FREE_THRESH, WRITE_OCCUPIED_THRESH = 0.1, 0.65
#: nav2 map_saver's ``free_thresh``, part of its signature (:func:`map_saver_signature`).
MAP_SAVER_FREE_THRESH = 0.25


class GridError(ValueError):
    """A map is wrong: ``where`` names the file, field or topic, ``expected`` and ``found`` say
    what was wanted and what was there (one line: ``WHERE: expected ..., found ...``)."""

    def __init__(self, where: str, expected: str, found: str):
        self.where, self.expected, self.found = where, expected, found
        super().__init__(f"{where}: expected {expected}, found {found}")


@dataclass(frozen=True, eq=False)
class OccupancyGrid:
    """An occupancy grid in the map frame.

    Attributes:
        data: int8 ``[H, W]``; ``data[row, col]`` is the cell ``col`` steps along the origin's x
            axis and ``row`` steps along its y axis (ROS's row-major order from the origin):
            -1 unknown, 0..100 occupancy.
        resolution: cell side (m).
        origin: (x m, y m, yaw rad): the pose of cell (0, 0)'s outer corner in the map frame.
        stamp: when the map was made (s; the message's header stamp, 0 for a file).
        free_level, occupied_level: the classification thresholds (0..100), see the module.
        source: where it came from (a file, or ``bag:topic``), for messages.
    """

    data: np.ndarray
    resolution: float
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    stamp: float = 0.0
    free_level: int = DEFAULT_FREE_LEVEL
    occupied_level: int = DEFAULT_OCCUPIED_LEVEL
    source: str = field(default="", compare=False)
    warnings: tuple[str, ...] = field(default=(), compare=False)

    @property
    def shape(self) -> tuple[int, int]:
        """(H rows, W columns)."""
        return self.data.shape  # type: ignore[return-value]

    @cached_property
    def digest(self) -> str:
        """SHA-256 over the cells, shape, resolution, origin and thresholds (hex)."""
        h = hashlib.sha256()
        h.update(repr((self.shape, float(self.resolution), tuple(map(float, self.origin)),
                       int(self.free_level), int(self.occupied_level))).encode())
        h.update(np.ascontiguousarray(self.data, dtype=np.int8).tobytes())
        return h.hexdigest()

    def __eq__(self, other) -> bool:
        return isinstance(other, OccupancyGrid) and self.digest == other.digest

    def __hash__(self) -> int:
        return hash(self.digest)

    @cached_property
    def classes(self) -> np.ndarray:
        """uint8 ``[H, W]`` of FREE, OCCUPIED, UNKNOWN (read-only)."""
        d = self.data
        out = np.full(d.shape, UNKNOWN, dtype=np.uint8)
        out[(d >= 0) & (d <= self.free_level)] = FREE
        out[(d >= self.occupied_level) & (d <= 100)] = OCCUPIED
        out.setflags(write=False)
        return out

    # ------------------------------------------------------------------ frames

    def _axes(self) -> tuple[float, float, float, float]:
        x0, y0, yaw = self.origin
        return x0, y0, math.cos(yaw), math.sin(yaw)

    def to_world(self, local: np.ndarray) -> np.ndarray:
        """float ``[K, 2]``: points given in the grid's frame (m from cell (0, 0)'s corner along
        its columns and rows) in the map frame."""
        x0, y0, c, s = self._axes()
        local = np.asarray(local, dtype=float).reshape(-1, 2)
        return np.column_stack([x0 + c * local[:, 0] - s * local[:, 1], y0 + s * local[:, 0] + c * local[:, 1]])

    def to_local(self, points: np.ndarray) -> np.ndarray:
        """The inverse of :meth:`to_world` (m in the grid's frame)."""
        x0, y0, c, s = self._axes()
        p = np.asarray(points, dtype=float).reshape(-1, 2)
        dx, dy = p[:, 0] - x0, p[:, 1] - y0
        return np.column_stack([c * dx + s * dy, -s * dx + c * dy])

    def cell_centres(self, mask: np.ndarray) -> np.ndarray:
        """float ``[K, 2]``: map-frame centres of the cells where ``mask`` (bool ``[H, W]``) is
        set, in row-major order."""
        rows, cols = np.nonzero(mask)
        return self.to_world(np.column_stack([(cols + 0.5) * self.resolution, (rows + 0.5) * self.resolution]))

    def cell_of(self, points: np.ndarray) -> np.ndarray:
        """int ``[K, 2]`` (row, col) of the cell holding each point; may lie outside the grid."""
        local = self.to_local(points) / self.resolution
        return np.column_stack([np.floor(local[:, 1]), np.floor(local[:, 0])]).astype(np.int64)

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) of the grid in the map frame (m): the box round its corners."""
        h, w = self.shape
        corners = self.to_world(np.array([[0, 0], [w, 0], [w, h], [0, h]], dtype=float) * self.resolution)
        return (float(corners[:, 0].min()), float(corners[:, 1].min()),
                float(corners[:, 0].max()), float(corners[:, 1].max()))

    def _samples(self, polyline) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The polyline (``[K, 2]``, m) sampled every quarter cell along each leg: (leg index
        ``[S]``, points ``[S, 2]``, off the grid bool ``[S]``, in an occupied cell bool ``[S]``)."""
        pts = np.asarray(polyline, dtype=float).reshape(-1, 2)
        if len(pts) == 1:
            pts = np.concatenate([pts, pts])
        a, b = pts[:-1], pts[1:]
        n = np.maximum(1, np.ceil(np.hypot(*(b - a).T) / (0.25 * self.resolution)).astype(np.int64))
        leg = np.repeat(np.arange(len(a)), n + 1)
        u = np.concatenate([np.linspace(0.0, 1.0, k + 1) for k in n]) if len(n) < 64 else \
            (np.arange(int((n + 1).sum())) - np.repeat(np.cumsum(n + 1) - (n + 1), n + 1)) / np.repeat(n, n + 1)
        samples = a[leg] + u[:, None] * (b - a)[leg]
        cells = self.cell_of(samples)
        h, w = self.shape
        off = (cells[:, 0] < 0) | (cells[:, 0] >= h) | (cells[:, 1] < 0) | (cells[:, 1] >= w)
        occ = np.zeros(len(samples), dtype=bool)
        inside = ~off
        occ[inside] = self.classes[cells[inside, 0], cells[inside, 1]] == OCCUPIED
        return leg, samples, off, occ

    def first_blocked(self, polyline) -> tuple[int, str, tuple[float, float]] | None:
        """Where the polyline (``[K, 2]``, m) first leaves the grid or enters an occupied cell,
        each leg sampled every quarter cell: ``(leg index, "off the map" | "an occupied cell",
        (x, y))``, or None when it stays on free and unknown cells."""
        leg, samples, off, occ = self._samples(polyline)
        bad = np.flatnonzero(off | occ)
        if not len(bad):
            return None
        k = int(bad[0])
        return (int(leg[k]), "off the map" if off[k] else "an occupied cell",
                (float(samples[k, 0]), float(samples[k, 1])))

    def grazes(self, polyline) -> list[Graze]:
        """Every leg of the polyline (``[K, 2]``, m, on the grid) that enters occupied cells, with
        its deepest sample (quarter-cell steps): how far (m) that point lies from the nearest cell
        that is not occupied (its square; cells beyond the grid's edge are not occupied)."""
        from scipy import ndimage

        leg, samples, off, occ = self._samples(polyline)
        inside = np.flatnonzero(occ & ~off)
        if not len(inside):
            return []
        occupied = np.pad(self.classes == OCCUPIED, 1)
        reach = ndimage.distance_transform_edt(occupied)  # cells to the nearest non-occupied centre
        local = self.to_local(samples[inside]) / self.resolution + 1.0  # in padded cells
        best: dict[int, Graze] = {}
        for k, (ux, uy) in zip(inside, local):
            r, c = int(math.floor(uy)), int(math.floor(ux))
            half = int(math.ceil(reach[r, c])) + 3
            r0, c0 = max(0, r - half), max(0, c - half)
            window = ~occupied[r0:r + half + 1, c0:c + half + 1]
            rows, cols = np.nonzero(window)
            rows, cols = rows + r0, cols + c0
            dx = np.maximum.reduce([cols - ux, np.zeros(len(cols)), ux - (cols + 1)])
            dy = np.maximum.reduce([rows - uy, np.zeros(len(rows)), uy - (rows + 1)])
            depth = float(np.hypot(dx, dy).min()) * self.resolution
            i = int(leg[k])
            if i not in best or depth > best[i].depth:
                best[i] = Graze(i, depth, (float(samples[k, 0]), float(samples[k, 1])))
        return [best[i] for i in sorted(best)]

    def carved(self, polyline, legs, distance: float) -> "OccupancyGrid":
        """This grid with the occupied cells whose centre lies within ``distance`` (m) of the
        polyline's ``legs`` (indices) made free (0): where a robot drove, the wall gives way."""
        from world import geometry

        pts = np.asarray(polyline, dtype=float).reshape(-1, 2)
        occupied = self.classes == OCCUPIED
        rows, cols = np.nonzero(occupied)
        centres = self.cell_centres(occupied)
        clear = np.zeros(len(centres), dtype=bool)
        for i in legs:
            a, b = pts[i], pts[i + 1]
            lo, hi = np.minimum(a, b) - distance, np.maximum(a, b) + distance
            near = np.flatnonzero((centres[:, 0] >= lo[0]) & (centres[:, 0] <= hi[0])
                                  & (centres[:, 1] >= lo[1]) & (centres[:, 1] <= hi[1]))
            if len(near):
                d = geometry.point_segment_distance(centres[near], np.array([[*a, *b]]))[:, 0]
                clear[near[d <= distance]] = True
        if not clear.any():
            return self
        data = self.data.copy()
        data[rows[clear], cols[clear]] = 0
        return OccupancyGrid(data=data, resolution=self.resolution, origin=self.origin, stamp=self.stamp,
                             free_level=self.free_level, occupied_level=self.occupied_level, source=self.source,
                             warnings=self.warnings)


@dataclass(frozen=True)
class Graze:
    """A leg of a route that enters occupied cells: ``leg`` its index, ``depth`` (m) how far its
    deepest sample ``point`` (x, y m) lies inside them."""

    leg: int
    depth: float
    point: tuple[float, float]


def check_grid(data: np.ndarray, resolution, where: str) -> None:
    """Refuse a grid that is empty, too large or has no positive finite resolution."""
    if isinstance(resolution, bool) or not isinstance(resolution, (int, float)) or not math.isfinite(resolution) \
            or resolution <= 0:
        raise GridError(f"{where}: resolution", "a number > 0 (m per cell)", repr(resolution))
    if data.ndim != 2 or data.size == 0:
        raise GridError(where, "a non-empty 2D grid", f"shape {tuple(data.shape)}")
    if data.size > MAX_CELLS:
        raise GridError(where, f"at most {MAX_CELLS:,} cells", f"{data.shape[1]} x {data.shape[0]} = {data.size:,}")


# --------------------------------------------------------------------------- frontier and value


def frontier_mask(grid: OccupancyGrid) -> np.ndarray:
    """bool ``[H, W]``: free cells with at least one unknown cell among their 8 neighbours."""
    cls = grid.classes
    unknown = np.pad(cls == UNKNOWN, 1, constant_values=False)
    h, w = cls.shape
    near = np.zeros((h, w), dtype=bool)
    for dr in (0, 1, 2):
        for dc in (0, 1, 2):
            if dr != 1 or dc != 1:
                near |= unknown[dr:dr + h, dc:dc + w]
    return (cls == FREE) & near


def frontier_points(grid: OccupancyGrid) -> np.ndarray:
    """float ``[F, 2]``: map-frame centres of the frontier cells (m), row-major."""
    return grid.cell_centres(frontier_mask(grid))


class FrontierCounter:
    """The paper's value of a point in one map: how many frontier cells have their centre within
    ``radius`` (m, closed disc) of it. Built once per map (a k-d tree over the centres)."""

    def __init__(self, grid: OccupancyGrid):
        from scipy.spatial import cKDTree

        self.grid = grid
        self.points = frontier_points(grid)
        self._tree = cKDTree(self.points) if len(self.points) else None

    def __len__(self) -> int:
        return len(self.points)

    def count(self, points, radius: float) -> np.ndarray:
        """int64 ``[K]``: frontier cells within ``radius`` of each point (``[K, 2]``, m)."""
        pts = np.asarray(points, dtype=float).reshape(-1, 2)
        if self._tree is None or not len(pts):
            return np.zeros(len(pts), dtype=np.int64)
        return np.asarray(self._tree.query_ball_point(pts, r=float(radius), return_length=True), dtype=np.int64)


def latest_at(stamps, t: float) -> int:
    """Index of the last of ``stamps`` (sorted, s) at or before ``t`` (s, within a nanosecond:
    stamps are integer nanoseconds), -1 if none."""
    import bisect

    return bisect.bisect_right(stamps, t + 1e-9) - 1


class MapHistory:
    """Maps in stamp order; :meth:`value` counts in the latest map stamped at or before a time
    (zero before the first map: no map, no frontier). Counters are built on first use."""

    def __init__(self, grids=()):
        self.grids: list[OccupancyGrid] = sorted(grids, key=lambda g: g.stamp)
        self._counters: dict[int, FrontierCounter] = {}

    def add(self, grid: OccupancyGrid) -> None:
        """Insert a map (a later map with the same stamp replaces nothing: both are kept, the
        later-added one wins at that stamp)."""
        import bisect

        k = bisect.bisect_right([g.stamp for g in self.grids], grid.stamp)
        self.grids.insert(k, grid)
        self._counters = {}

    def latest_index(self, t: float) -> int:
        """Index of the latest map stamped at or before ``t`` (s), -1 if none."""
        return latest_at([g.stamp for g in self.grids], t)

    def counter(self, k: int) -> FrontierCounter:
        if k not in self._counters:
            self._counters[k] = FrontierCounter(self.grids[k])
        return self._counters[k]

    def value(self, t: float, point, radius: float) -> int:
        """The paper's value at ``point`` (m) at time ``t`` (s)."""
        k = self.latest_index(t)
        return 0 if k < 0 else int(self.counter(k).count([point], radius)[0])


# --------------------------------------------------------------------------- walls


def simplify_mask(line: np.ndarray, tolerance: float) -> np.ndarray:
    """Douglas–Peucker: bool ``[K]``, the vertices of ``line`` (``[K, 2]``) to keep so that no
    dropped vertex is farther than ``tolerance`` (m) from the kept polyline; the ends are kept."""
    n = len(line)
    keep = np.zeros(n, dtype=bool)
    keep[[0, -1]] = True
    if tolerance <= 0:
        keep[:] = True
        return keep
    stack = [(0, n - 1)]
    while stack:
        i, j = stack.pop()
        if j <= i + 1:
            continue
        a, b = line[i], line[j]
        seg = line[i + 1:j] - a
        d = b - a
        norm = math.hypot(d[0], d[1])
        dist = np.abs(seg[:, 0] * d[1] - seg[:, 1] * d[0]) / norm if norm > 0 else np.hypot(seg[:, 0], seg[:, 1])
        k = int(np.argmax(dist))
        if dist[k] > tolerance:
            m = i + 1 + k
            keep[m] = True
            stack.append((i, m))
            stack.append((m, j))
    return keep


def _simplify(line: np.ndarray, tolerance: float) -> np.ndarray:
    return line if len(line) <= 2 else line[simplify_mask(line, tolerance)]


def simplify_polyline(line: np.ndarray, tolerance: float) -> np.ndarray:
    """Douglas–Peucker on an open or closed polyline (closed: first point equals last; it is
    split at its farthest point from the start so that both halves keep their shape)."""
    line = np.asarray(line, dtype=float)
    if len(line) > 3 and np.allclose(line[0], line[-1]):
        far = int(np.argmax(np.hypot(*(line - line[0]).T)))
        first = _simplify(line[:far + 1], tolerance)
        second = _simplify(line[far:], tolerance)
        return np.concatenate([first, second[1:]])
    return _simplify(line, tolerance)


def wall_lines(grid: OccupancyGrid, tolerance: float | None = None) -> list[np.ndarray]:
    """The outlines of the occupied cells as polylines ``[K, 2]`` in the map frame (m).

    Marching squares (contourpy) on the occupied mask at level 0.5 over the cell centres traces
    each connected blob of occupied cells along its cell edges (diagonal steps cut the corners
    by half a cell); Douglas–Peucker then drops vertices within ``tolerance`` (m; half a cell by
    default). Outlines close round their blob; the grid's edge is padded with free cells."""
    import contourpy

    tol = 0.5 * grid.resolution if tolerance is None else float(tolerance)
    occ = np.pad((grid.classes == OCCUPIED).astype(np.float32), 1)
    if not occ.any():
        return []
    h, w = occ.shape
    res = grid.resolution
    xs = (np.arange(w) - 0.5) * res   # centres of the padded cells in the grid's frame
    ys = (np.arange(h) - 0.5) * res
    gen = contourpy.contour_generator(xs, ys, occ, line_type=contourpy.LineType.Separate)
    out = []
    for line in gen.lines(0.5):
        if len(line) < 2:
            continue
        simple = simplify_polyline(np.asarray(line, dtype=float), tol)
        if len(simple) >= 2:
            out.append(grid.to_world(simple))
    return out


# --------------------------------------------------------------------------- map_server files


_MAP_KEYS = ("image", "resolution", "origin", "negate", "occupied_thresh", "free_thresh", "mode")
MAP_MODES = ("trinary", "scale", "raw")


def _number(doc: dict, key: str, where: str, default=None) -> float:
    value = doc.get(key, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise GridError(f"{where}: {key}", "a number", "nothing (missing)" if value is None else repr(value))
    return float(value)


def map_saver_signature(mode: str, negate, free_thresh: float, pixels: np.ndarray) -> bool:
    """True for a map as nav2's map_saver writes it: ``mode: trinary``, ``negate: 0``,
    ``free_thresh: 0.25`` and an image of its three values only (254 free, 0 occupied, 205
    unknown), 205 among them. map_server reads its 205 (occupancy 0.196) as free, which the
    saver did not mean."""
    if mode != "trinary" or negate or abs(free_thresh - MAP_SAVER_FREE_THRESH) > 1e-9:
        return False
    values = np.unique(pixels)
    return bool(np.isin(PGM_UNKNOWN, values)) and bool(np.isin(values, (PGM_FREE, PGM_OCCUPIED, PGM_UNKNOWN)).all())


def read_map_yaml(path: str | Path, free_level: int = DEFAULT_FREE_LEVEL,
                  occupied_level: int = DEFAULT_OCCUPIED_LEVEL, literal: bool = False) -> OccupancyGrid:
    """A map_server map: its YAML (``image``, ``resolution``, ``origin`` [x, y, yaw],
    ``negate``, ``occupied_thresh``, ``free_thresh``, ``mode``) and the PGM or PNG it names
    (relative to the YAML), by nav2 map_io's rules: shade = the mean of the colour channels
    / 255; occupancy = shade if ``negate`` else 1 - shade; trinary: occupancy above
    ``occupied_thresh`` is 100, below ``free_thresh`` 0, else -1; scale: the same, a pixel not
    fully opaque -1 and in between 1..99 linearly; raw: round(shade x 255) if in 0..100, else -1.

    One exception unless ``literal``: a map with nav2 map_saver's signature
    (:func:`map_saver_signature`) reads its 205 pixels as unknown, as the saver meant, and says
    so in the grid's ``warnings``. ``literal=True`` reads it exactly as map_server does.

    Raises:
        GridError: naming the file and field (a missing or unreadable image, a format other
            than PGM or PNG, resolution <= 0, thresholds out of order, an unknown mode).
    """
    import yaml

    file = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except FileNotFoundError:
        raise GridError(file, "an existing map YAML file", "no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise GridError(file, "a readable UTF-8 map YAML file", f"{exc.__class__.__name__}: {exc}") from None
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise GridError(file, "valid YAML", str(exc).splitlines()[0]) from None
    if not isinstance(doc, dict):
        raise GridError(file, "a map_server YAML mapping (image, resolution, origin, ...)", type(doc).__name__)
    for key in doc:
        if key not in _MAP_KEYS:
            raise GridError(f"{file}: {key}", f"a map_server key ({', '.join(_MAP_KEYS)})", f"unknown key '{key}'")
    image = doc.get("image")
    if not isinstance(image, str) or not image.strip():
        raise GridError(f"{file}: image", "the file name of a PGM or PNG image", repr(image))
    resolution = doc.get("resolution")
    if isinstance(resolution, bool) or not isinstance(resolution, (int, float)) or not math.isfinite(resolution) \
            or resolution <= 0:
        raise GridError(f"{file}: resolution", "a number > 0 (m per pixel)", repr(resolution))
    origin = doc.get("origin", [0.0, 0.0, 0.0])
    if (not isinstance(origin, list) or len(origin) not in (2, 3)
            or any(isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) for v in origin)):
        raise GridError(f"{file}: origin", "[x, y, yaw] (m, m, rad)", repr(origin))
    origin = (float(origin[0]), float(origin[1]), float(origin[2]) if len(origin) == 3 else 0.0)
    negate = doc.get("negate", 0)
    if negate not in (0, 1, True, False):
        raise GridError(f"{file}: negate", "0 or 1", repr(negate))
    occ_th = _number(doc, "occupied_thresh", file, 0.65)
    free_th = _number(doc, "free_thresh", file, 0.25)
    if not 0.0 <= free_th < occ_th <= 1.0:
        raise GridError(f"{file}: free_thresh, occupied_thresh", "0 <= free_thresh < occupied_thresh <= 1",
                        f"free_thresh {free_th:g}, occupied_thresh {occ_th:g}")
    mode = doc.get("mode", "trinary")
    if mode not in MAP_MODES:
        raise GridError(f"{file}: mode", f"one of {', '.join(MAP_MODES)}", repr(mode))
    image_path = Path(image) if Path(image).is_absolute() else Path(path).parent / image
    pixels, alpha = _read_image(image_path, f"{file}: image")
    check_grid(pixels, float(resolution), str(image_path))
    shade = pixels / 255.0
    occ = shade if negate else 1.0 - shade
    if mode == "raw":
        value = np.round(shade * 255.0)
        data = np.where((value >= 0) & (value <= 100), value, -1)
    else:
        data = np.full(pixels.shape, -1, dtype=np.int16)
        data[occ > occ_th] = 100
        data[occ < free_th] = 0
        if mode == "scale":
            between = (occ >= free_th) & (occ <= occ_th)
            data[between] = np.rint((occ[between] - free_th) / (occ_th - free_th) * 100.0)
            if alpha is not None:
                data[alpha < 255] = -1
    warnings = ()
    grey = pixels == PGM_UNKNOWN
    if not literal and map_saver_signature(mode, negate, free_th, pixels):
        data[grey] = -1
        warnings = (f"{file}: nav2 map_saver's map (trinary, pixels 0/205/254, free_thresh 0.25): its "
                    f"{int(grey.sum())} pixels of 205 read as unknown, as the saver meant (--literal-thresholds "
                    f"reads them as map_server does: free)",)
    elif mode != "raw" and not negate and grey.any() and (data[grey] == 0).all():
        # 205 (map_saver's unknown) read as free by the thresholds as written: honoured, and said
        warnings = (f"{file}: free_thresh {free_th:g} reads the image's {int(grey.sum())} pixels of 205 "
                    f"(map_saver's unknown) as free; with free_thresh below 0.196 they are unknown",)
    # image row 0 is the top of the map; the grid's row 0 is at the origin (the bottom)
    return OccupancyGrid(data=np.ascontiguousarray(data[::-1].astype(np.int8)), resolution=float(resolution),
                         origin=origin, free_level=free_level, occupied_level=occupied_level, source=file,
                         warnings=warnings)


def _read_image(path: Path, where: str) -> tuple[np.ndarray, np.ndarray | None]:
    """(float ``[H, W]`` mean of the colour channels 0..255, uint8 alpha or None) of a PGM or PNG."""
    from PIL import Image, UnidentifiedImageError

    if not path.is_file():
        raise GridError(where, "an existing PGM or PNG image", f"no such file {str(path)!r}")
    try:
        with Image.open(path) as img:
            if img.format not in ("PPM", "PNG"):  # Pillow reads PGM as its PPM format
                raise GridError(where, "a PGM or PNG image", f"{img.format or 'an unknown'} image {str(path)!r}")
            img.load()
            bands = img.getbands()
            alpha = np.asarray(img.getchannel("A"), dtype=np.uint8) if "A" in bands else None
            if img.mode in ("I", "I;16", "I;16B", "I;16L", "F"):
                raw = np.asarray(img, dtype=float)
                top = 65535.0 if raw.max() > 255 else 255.0
                return raw * (255.0 / top), alpha
            colour = img.convert("RGBA" if alpha is not None else "RGB") if img.mode not in ("L", "LA") else img
            arr = np.asarray(colour, dtype=float)
    except (UnidentifiedImageError, OSError, SyntaxError) as exc:
        raise GridError(where, "a PGM or PNG image", f"{exc.__class__.__name__}: {exc}") from None
    if arr.ndim == 2:
        return arr, alpha
    colour_bands = arr[:, :, :3] if arr.shape[2] >= 3 else arr[:, :, :1]
    return colour_bands.mean(axis=2), alpha


def write_map_yaml(grid: OccupancyGrid, yaml_path: str | Path) -> Path:
    """Write ``grid`` as a map_server map (trinary PGM beside the YAML, map_saver's values
    254 free, 0 occupied, 205 unknown) that :func:`read_map_yaml` and map_server read back as
    the same classes. Returns the image's path."""
    from PIL import Image

    yaml_path = Path(yaml_path)
    image_path = yaml_path.with_suffix(".pgm")
    cls = grid.classes
    img = np.full(cls.shape, PGM_UNKNOWN, dtype=np.uint8)
    img[cls == FREE] = PGM_FREE
    img[cls == OCCUPIED] = PGM_OCCUPIED
    Image.fromarray(np.ascontiguousarray(img[::-1])).save(image_path, format="PPM")
    x, y, yaw = grid.origin
    yaml_path.write_text(
        f"image: {image_path.name}\nmode: trinary\nresolution: {grid.resolution!r}\n"
        f"origin: [{float(x)!r}, {float(y)!r}, {float(yaw)!r}]\nnegate: 0\n"
        f"occupied_thresh: {WRITE_OCCUPIED_THRESH}\nfree_thresh: {WRITE_FREE_THRESH}\n", encoding="utf-8")
    return image_path


def file_sha256(path: str | Path) -> str:
    """SHA-256 of a file's bytes (hex)."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def grid_from_message(msg, source: str = "", free_level: int = DEFAULT_FREE_LEVEL,
                      occupied_level: int = DEFAULT_OCCUPIED_LEVEL) -> OccupancyGrid:
    """An :class:`OccupancyGrid` from a ``nav_msgs/msg/OccupancyGrid`` given as a mapping or an
    object with the message's fields (``header.stamp``, ``info.resolution``, ``info.width``,
    ``info.height``, ``info.origin`` pose, ``data``). The origin's yaw is read from its
    quaternion.

    Raises:
        GridError: when ``data`` does not hold width x height cells or the resolution is not > 0.
    """
    def get(obj, name):
        return obj[name] if isinstance(obj, dict) else getattr(obj, name)

    info = get(msg, "info")
    stamp = get(get(msg, "header"), "stamp")
    t = float(get(stamp, "sec")) + float(get(stamp, "nanosec")) * 1e-9
    width, height = int(get(info, "width")), int(get(info, "height"))
    data = np.asarray(get(msg, "data"), dtype=np.int8)
    where = f"{source} (stamp {t:.3f} s)" if source else f"OccupancyGrid stamped {t:.3f} s"
    if data.size != width * height:
        raise GridError(f"{where}: data", f"width x height = {width} x {height} = {width * height} cells",
                        f"{data.size}")
    grid = data.reshape(height, width)
    check_grid(grid, float(get(info, "resolution")), where)
    pose = get(info, "origin")
    pos, q = get(pose, "position"), get(pose, "orientation")
    qx, qy, qz, qw = (float(get(q, k)) for k in ("x", "y", "z", "w"))
    yaw = math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
    return OccupancyGrid(data=grid, resolution=float(get(info, "resolution")),
                         origin=(float(get(pos, "x")), float(get(pos, "y")), yaw), stamp=t,
                         free_level=free_level, occupied_level=occupied_level, source=source)
