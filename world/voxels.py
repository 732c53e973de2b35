"""3D occupancy: voxel maps from LiDAR scans or OctoMap files, their frontier voxels and the
paper's height-filtered value.

One home for what the 3D import (``python -m world import`` with an OctoMap, a bag of
``PointCloud2`` scans or a folder of PCD/PLY scans; world/import3d.py) computes from a 3D map:

* :class:`VoxelGrid`: a dense grid of voxel classes (int8 ``[X, Y, Z]``: ``UNKNOWN``, ``FREE``,
  ``OCCUPIED``) aligned with OctoMap's key grid: voxel index i is OctoMap key ``i + key0`` and
  its centre is at ``(key - 32768 + 0.5) x resolution`` on each axis. A grid always has at
  least one unknown voxel of margin round everything known, so a voxel on the grid's edge has
  its outside neighbours unknown, as everything outside an OctoMap is.
* :class:`VoxelMapper`: ray casting of scans by OctoMap's rules (``insertPointCloud`` without
  discretisation, Hornung et al. 2013): per scan, every voxel a ray from the sensor origin
  passes before its return's voxel is *free*, the return's voxel *occupied*; a voxel is updated
  at most once per scan and occupied wins over free within a scan; a return farther than the
  maximum range gives free voxels up to that range and no occupied voxel. An update adds
  ``log(p / (1 - p))`` of ``prob_hit`` (occupied) or ``prob_miss`` (free) to the voxel's log-odds
  (float32, starting at 0), clamped to ``[logit(clamp_min), logit(clamp_max)]``; a voxel never
  updated is unknown, one above ``logit(occupancy)`` occupied, the others free. The ray's voxels
  are OctoMap's ``computeRayKeys`` (Amanatides-Woo traversal, its tie-breaking and end test).
  The defaults are OctoMap's (:class:`OccupancyParams`).
* :func:`read_octomap` / :func:`write_octomap`: OctoMap files (``.bt``: binary, free and
  occupied leaves only, pruned; ``.ot``: full, a float32 log-odds per node, ``OcTree`` or
  ``ColorOcTree``), every leaf, pruned or not, expanded to voxels at the tree's resolution.
* :func:`frontier_mask`: a free voxel with an unknown voxel among its 6 face neighbours (26 with
  ``neighbours=26``). Six is the default: it is the connectivity a ray or a flying passenger
  crosses a face with, and 26 also counts free voxels that touch unknown space only at an edge
  or a corner, which a wall's staircase of voxels makes on every slanted surface.
* :class:`FrontierCounter3D`: the paper's value of a point: frontier voxels whose centre lies
  within a 3D radius of it and more than ``keep_above`` above it or more than ``keep_below``
  below it (both 0: every voxel counts).

Every array kernel is compiled with numba (a core dependency); nothing here imports the
OctoMap library (tests compare with its Python binding, octomap-python).
"""
from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field
from pathlib import Path

import numba
import numpy as np

from world.grid import GridError

#: Voxel classes of :attr:`VoxelGrid.classes`.
UNKNOWN, FREE, OCCUPIED = -1, 0, 1
#: OctoMap's key of the voxel whose lower corner is at coordinate 0 (its tree_max_val, 16 levels).
KEY_ZERO = 32768
TREE_DEPTH = 16
#: Largest dense grid (voxels): 4·10^8 int8 voxels is 400 MB.
MAX_VOXELS = 400_000_000
#: The paper's height filter (m): frontier voxels more than 1 m above or 0.1 m below the carrier.
DEFAULT_KEEP_ABOVE = 1.0
DEFAULT_KEEP_BELOW = 0.1
NEIGHBOURS = (6, 26)


def _logit(p: float) -> float:
    return math.log(p / (1.0 - p))


@dataclass(frozen=True)
class OccupancyParams:
    """OctoMap's sensor model (its defaults): probabilities in (0, 1).

    Attributes:
        prob_hit: a return in the voxel (log-odds +0.847).
        prob_miss: a ray through the voxel (log-odds -0.405).
        occupancy: a voxel whose probability exceeds this is occupied.
        clamp_min, clamp_max: the log-odds are clamped to these probabilities' (0.1192, 0.971).
    """

    prob_hit: float = 0.7
    prob_miss: float = 0.4
    occupancy: float = 0.5
    clamp_min: float = 0.1192
    clamp_max: float = 0.971

    def check(self, where: str = "--log-odds") -> None:
        for name in ("prob_hit", "prob_miss", "occupancy", "clamp_min", "clamp_max"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and 0.0 < v < 1.0):
                raise GridError(f"{where} {name}", "a probability in (0, 1)", repr(v))
        if not self.prob_miss < 0.5 < self.prob_hit:
            raise GridError(where, "prob_miss < 0.5 < prob_hit", f"{self.prob_miss:g}, {self.prob_hit:g}")
        if not self.clamp_min <= self.occupancy <= self.clamp_max:
            raise GridError(where, "clamp_min <= occupancy <= clamp_max",
                            f"{self.clamp_min:g}, {self.occupancy:g}, {self.clamp_max:g}")

    @property
    def logs(self) -> tuple[float, float, float, float, float]:
        """(hit, miss, occupancy, clamp min, clamp max) as float32 log-odds, as OctoMap keeps them."""
        return tuple(float(np.float32(_logit(p))) for p in (self.prob_hit, self.prob_miss, self.occupancy,
                                                              self.clamp_min, self.clamp_max))


@dataclass(frozen=True, eq=False)
class VoxelGrid:
    """A dense voxel map.

    Attributes:
        classes: int8 ``[X, Y, Z]``: ``UNKNOWN`` (-1), ``FREE`` (0), ``OCCUPIED`` (1).
        resolution: voxel side (m).
        key0: int ``(3,)``: the OctoMap key of voxel (0, 0, 0).
        source: where it came from, for messages.
    """

    classes: np.ndarray
    resolution: float
    key0: tuple[int, int, int]
    source: str = field(default="", compare=False)

    @property
    def shape(self) -> tuple[int, int, int]:
        return tuple(self.classes.shape)  # type: ignore[return-value]

    @property
    def lower(self) -> np.ndarray:
        """float ``(3,)``: the lower corner of voxel (0, 0, 0) (m)."""
        return (np.asarray(self.key0, dtype=float) - KEY_ZERO) * self.resolution

    @property
    def extent(self) -> tuple[float, float, float, float, float, float]:
        lo = self.lower
        hi = lo + np.asarray(self.shape) * self.resolution
        return (float(lo[0]), float(lo[1]), float(lo[2]), float(hi[0]), float(hi[1]), float(hi[2]))

    def centres(self, mask: np.ndarray) -> np.ndarray:
        """float ``[K, 3]``: the centres (m) of the voxels where ``mask`` is true, in C order."""
        idx = np.argwhere(mask)
        return (idx + np.asarray(self.key0) - KEY_ZERO + 0.5) * self.resolution

    def index_of(self, points) -> np.ndarray:
        """int ``[K, 3]``: the voxel holding each point (may lie outside the grid)."""
        keys = np.floor(np.asarray(points, dtype=float).reshape(-1, 3) / self.resolution).astype(np.int64) + KEY_ZERO
        return keys - np.asarray(self.key0)

    @property
    def digest(self) -> str:
        """SHA-256 of the resolution, the key of voxel 0 and the classes: the map's identity."""
        h = hashlib.sha256()
        h.update(np.float64(self.resolution).tobytes())
        h.update(np.asarray(self.key0, dtype=np.int64).tobytes())
        h.update(np.asarray(self.shape, dtype=np.int64).tobytes())
        h.update(np.ascontiguousarray(self.classes).tobytes())
        return h.hexdigest()

    def counts(self) -> dict[str, int]:
        free = int(np.count_nonzero(self.classes == FREE))
        occ = int(np.count_nonzero(self.classes == OCCUPIED))
        return {"free": free, "occupied": occ, "unknown": int(self.classes.size) - free - occ}


def check_voxel(voxel, where: str = "--voxel") -> float:
    if not (isinstance(voxel, (int, float)) and math.isfinite(voxel) and voxel > 0):
        raise GridError(where, "a voxel size > 0 (m)", repr(voxel))
    return float(voxel)


def _check_size(shape, where: str) -> None:
    n = int(np.prod(np.asarray(shape, dtype=np.int64)))
    if n > MAX_VOXELS:
        raise GridError(where, f"a map of at most {MAX_VOXELS:,} voxels at this voxel size",
                        f"{shape[0]} x {shape[1]} x {shape[2]} = {n:,} (a larger --voxel, or a smaller region)")


# --------------------------------------------------------------------------- frontier and value


def frontier_mask(classes: np.ndarray, neighbours: int = 6) -> np.ndarray:
    """bool like ``classes``: free voxels with an unknown voxel among their 6 face (or all 26)
    neighbours; voxels outside the array count as unknown."""
    if neighbours not in NEIGHBOURS:
        raise GridError("--neighbours", "6 or 26", repr(neighbours))
    unknown = np.pad(classes == UNKNOWN, 1, constant_values=True)
    free = classes == FREE
    X, Y, Z = classes.shape
    near = np.zeros_like(free)
    if neighbours == 6:
        for axis in range(3):
            for d in (-1, 1):
                sl = [slice(1, X + 1), slice(1, Y + 1), slice(1, Z + 1)]
                sl[axis] = slice(1 + d, 1 + d + classes.shape[axis])
                near |= unknown[tuple(sl)]
    else:
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                for dz in (-1, 0, 1):
                    if dx or dy or dz:
                        near |= unknown[1 + dx:1 + dx + X, 1 + dy:1 + dy + Y, 1 + dz:1 + dz + Z]
    return free & near


def kept(dz: np.ndarray, keep_above: float, keep_below: float) -> np.ndarray:
    """The paper's height filter on heights relative to the carrier (m): more than
    ``keep_above`` above or more than ``keep_below`` below; both 0 keeps every voxel."""
    dz = np.asarray(dz, dtype=float)
    if keep_above == 0 and keep_below == 0:
        return np.ones(dz.shape, dtype=bool)
    return (dz > keep_above) | (dz < -keep_below)


def check_keep(keep_above: float, keep_below: float) -> None:
    for flag, v in (("--keep-above", keep_above), ("--keep-below", keep_below)):
        if not (math.isfinite(v) and v >= 0):
            raise GridError(flag, "a height >= 0 (m)", repr(v))


class FrontierCounter3D:
    """The paper's value of points in one map: frontier voxels within ``radius`` (3D) whose
    height relative to the point passes :func:`kept`."""

    def __init__(self, grid: VoxelGrid, neighbours: int = 6, mask: np.ndarray | None = None):
        from scipy.spatial import cKDTree

        self.mask = frontier_mask(grid.classes, neighbours) if mask is None else mask
        self.points = grid.centres(self.mask)
        self._tree = cKDTree(self.points) if len(self.points) else None

    def __len__(self) -> int:
        return len(self.points)

    def count(self, points, radius: float, keep_above: float = DEFAULT_KEEP_ABOVE,
              keep_below: float = DEFAULT_KEEP_BELOW) -> np.ndarray:
        """int ``[K]`` for float ``[K, 3]`` points (m)."""
        pts = np.asarray(points, dtype=float).reshape(-1, 3)
        out = np.zeros(len(pts), dtype=np.int64)
        if self._tree is None:
            return out
        for k, (q, near) in enumerate(zip(pts, self._tree.query_ball_point(pts, radius))):
            if near:
                out[k] = int(kept(self.points[near, 2] - q[2], keep_above, keep_below).sum())
        return out


# --------------------------------------------------------------------------- ray casting


@numba.njit(cache=True, nogil=True)
def _coord_key(c: float, factor: float) -> int:
    return int(math.floor(factor * c)) + KEY_ZERO


@numba.njit(cache=True, nogil=True)
def _ray(o, e, res, key0, stamp, code, logodds, model):
    """OctoMap's computeRayKeys from ``o`` to ``e`` (float32 (x, y, z)), each voxel not yet
    marked in this scan given one miss update; ``model`` (miss, clamp lo, clamp hi)."""
    ox, oy, oz = o
    ex, ey, ez = e
    key0x, key0y, key0z = key0[0], key0[1], key0[2]
    miss, lo, hi = model
    factor = 1.0 / res
    kox, koy, koz = _coord_key(ox, factor), _coord_key(oy, factor), _coord_key(oz, factor)
    kex, key_, kez = _coord_key(ex, factor), _coord_key(ey, factor), _coord_key(ez, factor)
    if kox == kex and koy == key_ and koz == kez:
        return
    _free(kox - key0x, koy - key0y, koz - key0z, stamp, code, logodds, miss, lo, hi)
    dx, dy, dz = np.float32(ex - ox), np.float32(ey - oy), np.float32(ez - oz)
    length = np.float32(math.sqrt(np.float32(dx * dx) + np.float32(dy * dy) + np.float32(dz * dz)))
    dx, dy, dz = np.float32(dx / length), np.float32(dy / length), np.float32(dz / length)
    k = np.array([kox, koy, koz], dtype=np.int64)
    d = (dx, dy, dz)
    o = (ox, oy, oz)
    step = np.zeros(3, dtype=np.int64)
    tmax = np.empty(3)
    tdelta = np.empty(3)
    big = 1.7976931348623157e308
    for i in range(3):
        if d[i] > 0.0:
            step[i] = 1
        elif d[i] < 0.0:
            step[i] = -1
        if step[i] != 0:
            border = (float(k[i] - KEY_ZERO) + 0.5) * res
            border += float(np.float32(step[i] * res * 0.5))
            tmax[i] = (border - float(o[i])) / float(d[i])
            tdelta[i] = res / abs(float(d[i]))
        else:
            tmax[i] = big
            tdelta[i] = big
    while True:
        if tmax[0] < tmax[1]:
            dim = 0 if tmax[0] < tmax[2] else 2
        else:
            dim = 1 if tmax[1] < tmax[2] else 2
        k[dim] += step[dim]
        tmax[dim] += tdelta[dim]
        if k[0] == kex and k[1] == key_ and k[2] == kez:
            return
        if min(tmax[0], min(tmax[1], tmax[2])) > length:
            return
        _free(k[0] - key0x, k[1] - key0y, k[2] - key0z, stamp, code, logodds, miss, lo, hi)


@numba.njit(cache=True, nogil=True, inline="always")
def _free(i, j, k, stamp, code, logodds, miss, lo, hi):
    if stamp[i, j, k] >= code:  # already free or occupied in this scan
        return
    stamp[i, j, k] = code
    v = logodds[i, j, k]
    if v != v:
        v = np.float32(0.0)
    v = np.float32(v + miss)
    logodds[i, j, k] = min(max(v, lo), hi)


@numba.njit(cache=True, nogil=True)
def _insert_scan(points, origin, maxrange, res, key0, stamp, scan, logodds, hit, miss, lo, hi):
    """One scan (float32 ``[P, 3]``, map frame) from ``origin`` (float32 ``(3,)``); the codes of
    scan s in ``stamp``: 3s+1 free, 3s+2 occupied (marked), 3s+3 occupied (updated)."""
    free_code, occ_code, done_code = 3 * scan + 1, 3 * scan + 2, 3 * scan + 3
    factor = 1.0 / res
    ox, oy, oz = origin[0], origin[1], origin[2]
    n = points.shape[0]
    inside = np.zeros(n, dtype=np.bool_)
    for p in range(n):
        ex, ey, ez = points[p, 0], points[p, 1], points[p, 2]
        dx, dy, dz = np.float32(ex - ox), np.float32(ey - oy), np.float32(ez - oz)
        norm = np.float32(math.sqrt(np.float32(dx * dx) + np.float32(dy * dy) + np.float32(dz * dz)))
        if maxrange < 0.0 or norm <= maxrange:
            inside[p] = True
            i = _coord_key(ex, factor) - key0[0]
            j = _coord_key(ey, factor) - key0[1]
            k = _coord_key(ez, factor) - key0[2]
            if stamp[i, j, k] < occ_code:
                stamp[i, j, k] = occ_code
    for p in range(n):
        ex, ey, ez = points[p, 0], points[p, 1], points[p, 2]
        if not inside[p]:
            dx, dy, dz = np.float32(ex - ox), np.float32(ey - oy), np.float32(ez - oz)
            norm = np.float32(math.sqrt(np.float32(dx * dx) + np.float32(dy * dy) + np.float32(dz * dz)))
            m = np.float32(maxrange)
            ex = np.float32(ox + np.float32(np.float32(dx / norm) * m))
            ey = np.float32(oy + np.float32(np.float32(dy / norm) * m))
            ez = np.float32(oz + np.float32(np.float32(dz / norm) * m))
        _ray((ox, oy, oz), (ex, ey, ez), res, key0, stamp, free_code, logodds, (miss, lo, hi))
    for p in range(n):
        if inside[p]:
            i = _coord_key(points[p, 0], factor) - key0[0]
            j = _coord_key(points[p, 1], factor) - key0[1]
            k = _coord_key(points[p, 2], factor) - key0[2]
            if stamp[i, j, k] == occ_code:
                stamp[i, j, k] = done_code
                v = logodds[i, j, k]
                if v != v:
                    v = np.float32(0.0)
                v = np.float32(v + hit)
                logodds[i, j, k] = min(max(v, lo), hi)


@numba.njit(cache=True, nogil=True)
def _classify(logodds, occ, out):
    X, Y, Z = logodds.shape
    for i in range(X):
        for j in range(Y):
            for k in range(Z):
                v = logodds[i, j, k]
                out[i, j, k] = -1 if v != v else (1 if v > occ else 0)


class VoxelMapper:
    """A map built scan by scan (OctoMap's rules, module docstring) over a fixed region.

    Args:
        lower, upper: float ``(3,)`` the region (m) every ray stays in (origins and ray ends
            clipped to ``maxrange``); the grid adds one voxel of margin.
        resolution: voxel side (m).
        maxrange: longest ray inserted (m; < 0: every ray whole).
    """

    def __init__(self, lower, upper, resolution: float, params: OccupancyParams = OccupancyParams(),
                 maxrange: float = -1.0, source: str = ""):
        params.check()
        self.resolution = check_voxel(resolution)
        self.params = params
        self.maxrange = float(maxrange)
        self.source = source
        lo, hi = self._keys(lower, upper)
        shape = tuple(int(v) for v in hi - lo)
        _check_size(shape, source or "--voxel")
        self.key0 = tuple(int(v) for v in lo)
        self._key0 = np.asarray(self.key0, dtype=np.int64)
        self.logodds = np.full(shape, np.nan, dtype=np.float32)
        self._stamp = np.zeros(shape, dtype=np.int32)
        self.scans = 0
        hit, miss, self._occ, clo, chi = params.logs
        self._args = (np.float32(hit), np.float32(miss), np.float32(clo), np.float32(chi))

    def _keys(self, lower, upper) -> tuple[np.ndarray, np.ndarray]:
        """The key range (lowest, one past the highest) of the region ``lower`` .. ``upper`` (m)
        with a voxel of margin.

        Raises:
            GridError: past OctoMap's key range at this voxel size.
        """
        res = self.resolution
        lo = np.floor(np.asarray(lower, dtype=float) / res).astype(np.int64) + KEY_ZERO - 1
        hi = np.floor(np.asarray(upper, dtype=float) / res).astype(np.int64) + KEY_ZERO + 2
        if np.any(lo < 0) or np.any(hi > 2 * KEY_ZERO):
            raise GridError(self.source or "scans", f"points within ±{KEY_ZERO * res:g} m of the origin "
                            "(OctoMap's key range at this voxel size)", f"a region {lower} .. {upper}")
        return lo, hi

    def cover(self, lower, upper, slack: float = 0.0) -> None:
        """Grow the region to hold ``lower`` .. ``upper`` (m), keeping every voxel's state (a
        voxel is an OctoMap key: the map is the same whatever region holds it); when it grows,
        by ``slack`` (m) more on each side that grows, so that a map built scan by scan is
        copied now and then, not at every scan.

        Raises:
            GridError: past OctoMap's key range or :data:`MAX_VOXELS`.
        """
        lo, hi = self._keys(lower, upper)
        old_hi = self._key0 + np.asarray(self.logodds.shape)
        if np.all(lo >= self._key0) and np.all(hi <= old_hi):
            return
        extra = int(math.ceil(slack / self.resolution))
        lo = np.where(lo < self._key0, np.maximum(lo - extra, 0), self._key0)
        hi = np.where(hi > old_hi, np.minimum(hi + extra, 2 * KEY_ZERO), old_hi)
        shape = tuple(int(v) for v in hi - lo)
        _check_size(shape, self.source or "--voxel")
        at = self._key0 - lo
        sl = tuple(slice(int(a), int(a) + n) for a, n in zip(at, self.logodds.shape))
        logodds = np.full(shape, np.nan, dtype=np.float32)
        stamp = np.zeros(shape, dtype=np.int32)
        logodds[sl], stamp[sl] = self.logodds, self._stamp
        self.logodds, self._stamp = logodds, stamp
        self.key0 = tuple(int(v) for v in lo)
        self._key0 = np.asarray(self.key0, dtype=np.int64)

    def insert(self, points, origin) -> None:
        """One scan: float ``[P, 3]`` returns and the sensor ``origin`` ``(3,)``, map frame (m)."""
        pts = np.ascontiguousarray(np.asarray(points, dtype=np.float32).reshape(-1, 3))
        org = np.asarray(origin, dtype=np.float32).reshape(3)
        if len(pts) == 0:
            self.scans += 1
            return
        if self.scans >= (2**31 - 4) // 3:
            raise GridError(self.source or "scans", "fewer scans than int32 stamps hold", str(self.scans))
        hit, miss, lo, hi = self._args
        _insert_scan(pts, org, self.maxrange, self.resolution, self._key0, self._stamp, self.scans,
                     self.logodds, hit, miss, lo, hi)
        self.scans += 1

    def classes(self) -> np.ndarray:
        out = np.empty(self.logodds.shape, dtype=np.int8)
        _classify(self.logodds, np.float32(self._occ), out)
        return out

    def grid(self) -> VoxelGrid:
        return VoxelGrid(self.classes(), self.resolution, self.key0, self.source)

    def value(self, point, radius: float, neighbours: int = 6, keep_above: float = DEFAULT_KEEP_ABOVE,
              keep_below: float = DEFAULT_KEEP_BELOW) -> int:
        """The paper's value of ``point`` (x, y, z; m) in the current map
        (:class:`FrontierCounter3D` in the :meth:`window` round it: the frontier of the whole map
        within ``radius``)."""
        q = np.asarray(point, dtype=float).reshape(1, 3)
        win = self.window(q[0], radius)
        return int(FrontierCounter3D(win, neighbours).count(q, radius, keep_above, keep_below)[0])

    def window(self, centre, radius: float) -> VoxelGrid:
        """The current map within ``radius`` (plus one voxel) of ``centre``: a :class:`VoxelGrid`
        (cut at the region's edge, which is unknown anyway)."""
        idx = np.floor(np.asarray(centre, dtype=float) / self.resolution).astype(np.int64) + KEY_ZERO - self._key0
        r = int(math.ceil(radius / self.resolution)) + 2
        lo = np.clip(idx - r, 0, self.logodds.shape)
        hi = np.clip(idx + r + 1, 0, self.logodds.shape)
        sub = self.logodds[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]]
        out = np.empty(sub.shape, dtype=np.int8)
        _classify(np.ascontiguousarray(sub), np.float32(self._occ), out)
        return VoxelGrid(out, self.resolution, tuple(int(v) for v in self._key0 + lo), self.source)


# --------------------------------------------------------------------------- OctoMap files


BT_HEADER = b"# Octomap OcTree binary file"
OT_HEADER = b"# Octomap OcTree file"
OCTOMAP_SUFFIXES = (".bt", ".ot")


def _header(data: bytes, where: str, binary: bool) -> tuple[str, float, int, int]:
    """(tree id, resolution, size, offset of the data) of an OctoMap file's header."""
    first = BT_HEADER if binary else OT_HEADER
    if not data.startswith(first):
        raise GridError(where, f"an OctoMap {'.bt' if binary else '.ot'} file starting with "
                        f"'{first.decode()}'", repr(data[:40]))
    pos = 0
    tree_id, res, size = ("OcTree" if binary else None), None, None
    while True:
        end = data.find(b"\n", pos)
        if end < 0:
            raise GridError(where, "an OctoMap header ending in a 'data' line", "the file ends in its header")
        line = data[pos:end].strip()
        pos = end + 1
        if not line or line.startswith(b"#"):
            continue
        word, _, value = line.partition(b" ")
        try:
            if word == b"id":
                tree_id = value.decode().strip()
            elif word == b"res":
                res = float(value)
            elif word == b"size":
                size = int(value)
            elif word == b"data":
                break
            else:
                raise ValueError
        except ValueError:
            raise GridError(where, "an OctoMap header of id, size, res and data lines",
                            repr(line[:40].decode(errors="replace"))) from None
    if res is None or not (math.isfinite(res) and res > 0):
        raise GridError(where, "an OctoMap header with 'res' > 0", repr(res))
    if size is None or size < 0:
        raise GridError(where, "an OctoMap header with 'size' >= 0", repr(size))
    return str(tree_id), float(res), int(size), pos


@numba.njit(cache=True)
def _bt_leaves(data, pos):
    """The leaves of a .bt stream from ``pos``: (keys int64 ``[L, 3]`` lower corners, depth int64
    ``[L]``, occupied bool ``[L]``, end position); end -1 if the stream is truncated."""
    cap = 1024
    keys = np.empty((cap, 3), dtype=np.int64)
    depth = np.empty(cap, dtype=np.int64)
    occ = np.empty(cap, dtype=np.bool_)
    n = 0
    sk = np.empty((TREE_DEPTH + 1, 3), dtype=np.int64)
    scode = np.empty(TREE_DEPTH + 1, dtype=np.int64)
    si = np.empty(TREE_DEPTH + 1, dtype=np.int64)
    if pos + 2 > len(data):
        return keys[:0], depth[:0], occ[:0], -1
    sk[0, :] = 0
    scode[0] = int(data[pos]) | (int(data[pos + 1]) << 8)
    si[0] = 0
    pos += 2
    top = 0
    while top >= 0:
        i = si[top]
        if i == 8:
            top -= 1
            continue
        si[top] = i + 1
        v = (scode[top] >> (2 * i)) & 3
        if v == 0:
            continue
        half = 1 << (TREE_DEPTH - top - 1)
        cx = sk[top, 0] + (half if i & 1 else 0)
        cy = sk[top, 1] + (half if i & 2 else 0)
        cz = sk[top, 2] + (half if i & 4 else 0)
        if v == 3:
            if top + 1 >= TREE_DEPTH or pos + 2 > len(data):
                return keys[:n], depth[:n], occ[:n], -1 if pos + 2 > len(data) else -2
            top += 1
            sk[top, 0], sk[top, 1], sk[top, 2] = cx, cy, cz
            scode[top] = int(data[pos]) | (int(data[pos + 1]) << 8)
            si[top] = 0
            pos += 2
            continue
        if n == cap:
            cap *= 2
            keys2 = np.empty((cap, 3), dtype=np.int64)
            keys2[:n] = keys[:n]
            keys = keys2
            depth2 = np.empty(cap, dtype=np.int64)
            depth2[:n] = depth[:n]
            depth = depth2
            occ2 = np.empty(cap, dtype=np.bool_)
            occ2[:n] = occ[:n]
            occ = occ2
        keys[n, 0], keys[n, 1], keys[n, 2] = cx, cy, cz
        depth[n] = top + 1
        occ[n] = v == 2
        n += 1
    return keys[:n], depth[:n], occ[:n], pos


@numba.njit(cache=True)
def _ot_leaves(data, pos, extra, occ_log):
    """The leaves of a .ot stream (float32 value, ``extra`` bytes, a children byte per node)."""
    cap = 1024
    keys = np.empty((cap, 3), dtype=np.int64)
    depth = np.empty(cap, dtype=np.int64)
    occ = np.empty(cap, dtype=np.bool_)
    n = 0
    sk = np.empty((TREE_DEPTH + 1, 3), dtype=np.int64)
    smask = np.empty(TREE_DEPTH + 1, dtype=np.int64)
    si = np.empty(TREE_DEPTH + 1, dtype=np.int64)
    step = 4 + extra + 1
    # the node at stack level `top` has been read; push its children one by one
    if pos + step > len(data):
        return keys[:0], depth[:0], occ[:0], -1
    top = 0
    sk[0, :] = 0
    smask[0] = int(data[pos + 4 + extra])
    si[0] = 0
    root_value = data[pos:pos + 4].copy().view(np.float32)[0]
    pos += step
    if smask[0] == 0:  # the root alone: one leaf covering the whole tree
        keys[0, :] = 0
        depth[0] = 0
        occ[0] = root_value > occ_log
        return keys[:1], depth[:1], occ[:1], pos
    while top >= 0:
        i = si[top]
        if i == 8:
            top -= 1
            continue
        si[top] = i + 1
        if not (smask[top] >> i) & 1:
            continue
        if pos + step > len(data):
            return keys[:n], depth[:n], occ[:n], -1
        half = 1 << (TREE_DEPTH - top - 1)
        cx = sk[top, 0] + (half if i & 1 else 0)
        cy = sk[top, 1] + (half if i & 2 else 0)
        cz = sk[top, 2] + (half if i & 4 else 0)
        value = data[pos:pos + 4].copy().view(np.float32)[0]
        children = int(data[pos + 4 + extra])
        pos += step
        if children != 0:
            if top + 1 >= TREE_DEPTH:
                return keys[:n], depth[:n], occ[:n], -2
            top += 1
            sk[top, 0], sk[top, 1], sk[top, 2] = cx, cy, cz
            smask[top] = children
            si[top] = 0
            continue
        if n == cap:
            cap *= 2
            keys2 = np.empty((cap, 3), dtype=np.int64)
            keys2[:n] = keys[:n]
            keys = keys2
            depth2 = np.empty(cap, dtype=np.int64)
            depth2[:n] = depth[:n]
            depth = depth2
            occ2 = np.empty(cap, dtype=np.bool_)
            occ2[:n] = occ[:n]
            occ = occ2
        keys[n, 0], keys[n, 1], keys[n, 2] = cx, cy, cz
        depth[n] = top + 1
        occ[n] = value > occ_log
        n += 1
    return keys[:n], depth[:n], occ[:n], pos


@numba.njit(cache=True)
def _fill(out, keys, depth, occ, key0):
    for n in range(keys.shape[0]):
        size = 1 << (TREE_DEPTH - depth[n])
        v = 1 if occ[n] else 0
        x0, y0, z0 = keys[n, 0] - key0[0], keys[n, 1] - key0[1], keys[n, 2] - key0[2]
        for i in range(max(x0, 0), min(x0 + size, out.shape[0])):
            for j in range(max(y0, 0), min(y0 + size, out.shape[1])):
                for k in range(max(z0, 0), min(z0 + size, out.shape[2])):
                    out[i, j, k] = v


def _stream_leaves(buf: np.ndarray, pos: int, tree_id: str, binary: bool, params: OccupancyParams, where: str,
                   nodes: str, file: bool):
    """(keys, depth, occupied) of the node stream in ``buf`` from ``pos`` to its end: a ``.bt``
    stream (``binary``, tree id OcTree) or a full one (OcTree or ColorOcTree); ``nodes`` says
    what a truncated stream lacks and ``file`` whether it is a file's (else a message's), for
    the error."""
    if binary:
        if tree_id != "OcTree":
            raise GridError(where, f"a {'.bt file' if file else 'binary OctoMap'} of id OcTree", f"id {tree_id}")
        keys, depth, occ, end = _bt_leaves(buf, pos)
    else:
        extra = {"OcTree": 0, "ColorOcTree": 3}.get(tree_id)
        if extra is None:
            raise GridError(where, f"a{'n .ot file' if file else ' full OctoMap'} of id OcTree or ColorOcTree", f"id {tree_id}")
        keys, depth, occ, end = _ot_leaves(buf, pos, extra, np.float32(params.logs[2]))
    if end == -1:
        raise GridError(where, nodes, f"the {'file' if file else 'data'} truncated")
    if end == -2:
        raise GridError(where, "a tree of at most 16 levels", "deeper nodes")
    if end != len(buf):
        raise GridError(where, "nothing after the tree's nodes", f"{len(buf) - end} bytes more")
    return keys, depth, occ


def _no_leaves():
    return np.zeros((0, 3), dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0, dtype=bool)


def octomap_leaves(path: str | Path, params: OccupancyParams = OccupancyParams()):
    """(resolution, keys int ``[L, 3]`` lower corners, depth ``[L]`` (16: one voxel), occupied
    ``[L]``) of an OctoMap file.

    Raises:
        GridError: not .bt/.ot, unreadable, another tree type, truncated or with bytes left over.
    """
    path = Path(path)
    where = str(path)
    suffix = path.suffix.lower()
    if suffix not in OCTOMAP_SUFFIXES:
        raise GridError(where, "an OctoMap file (.bt binary or .ot full)", f"a '{path.suffix}' file")
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise GridError(where, "a readable OctoMap file", exc.strerror or str(exc)) from None
    tree_id, res, size, pos = _header(data, where, suffix == ".bt")
    if size == 0:
        return (res, *_no_leaves())
    buf = np.frombuffer(data, dtype=np.uint8)
    return (res, *_stream_leaves(buf, pos, tree_id, suffix == ".bt", params, where,
                                 f"the tree's nodes ({size} by its header)", True))


def octomap_resolution(path: str | Path) -> float:
    """The voxel size (m) an OctoMap file's header states (its first 4 KiB read)."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            head = f.read(4096)
    except OSError as exc:
        raise GridError(str(path), "a readable OctoMap file", exc.strerror or str(exc)) from None
    return _header(head, str(path), path.suffix.lower() == ".bt")[1]


def leaves_grid(res: float, keys: np.ndarray, depth: np.ndarray, occ: np.ndarray, where: str) -> VoxelGrid:
    """Leaves (:func:`octomap_leaves`) as a dense :class:`VoxelGrid`, every leaf expanded to
    voxels, one unknown voxel of margin round them."""
    if not len(keys):
        raise GridError(where, "an OctoMap with at least one known voxel", "an empty tree")
    size = 1 << (TREE_DEPTH - depth)
    lo = keys.min(axis=0) - 1
    hi = (keys + size[:, None]).max(axis=0) + 1
    shape = tuple(int(v) for v in hi - lo)
    _check_size(shape, where)
    out = np.full(shape, UNKNOWN, dtype=np.int8)
    _fill(out, keys, depth, occ, lo.astype(np.int64))
    return VoxelGrid(out, res, tuple(int(v) for v in lo), where)


def read_octomap(path: str | Path, params: OccupancyParams = OccupancyParams()) -> VoxelGrid:
    """An OctoMap file as a dense :class:`VoxelGrid`: every leaf (pruned ones too) expanded to
    voxels at the tree's resolution; ``.ot`` leaves occupied when their log-odds exceed
    ``params.occupancy``'s, ``.bt`` leaves as stored."""
    return leaves_grid(*octomap_leaves(path, params), str(path))


def octomap_from_message(msg: dict, where: str, params: OccupancyParams = OccupancyParams()) -> VoxelGrid | None:
    """An ``octomap_msgs/msg/Octomap`` (a dict: ``binary``, ``id``, ``resolution``, ``data``) as
    a dense :class:`VoxelGrid`, by the code that reads the files: ``binary`` data is the
    ``.bt`` stream (``writeBinaryData``), full data the ``.ot`` one (``writeData``); None for an
    empty tree (no data).

    Raises:
        GridError: a resolution that is not > 0, another tree type, a truncated stream or bytes
            left over (``where`` names the topic and stamp).
    """
    res = msg.get("resolution")
    if not (isinstance(res, (int, float)) and math.isfinite(res) and res > 0):
        raise GridError(f"{where}: resolution", "a voxel size > 0 (m)", repr(res))
    data = msg.get("data")
    buf = np.frombuffer(data if isinstance(data, (bytes, bytearray)) else np.asarray(data, dtype=np.int8).tobytes(),
                        dtype=np.uint8)
    if not len(buf):
        return None
    keys, depth, occ = _stream_leaves(buf, 0, str(msg.get("id", "")), bool(msg.get("binary")), params,
                                      f"{where}: data", "a whole tree", False)
    return leaves_grid(float(res), keys, depth, occ, where)


@numba.njit(cache=True)
def _codes(classes, out):
    X, Y, Z = classes.shape
    for i in range(X):
        for j in range(Y):
            for k in range(Z):
                v = classes[i, j, k]
                out[i, j, k] = 0 if v == -1 else (1 if v == 0 else 2)


@numba.njit(cache=True)
def _reduce(a, out):
    X, Y, Z = out.shape
    for i in range(X):
        for j in range(Y):
            for k in range(Z):
                first = a[2 * i, 2 * j, 2 * k]
                same = first != 3
                for c in range(1, 8):
                    if a[2 * i + (c & 1), 2 * j + ((c >> 1) & 1), 2 * k + ((c >> 2) & 1)] != first:
                        same = False
                        break
                out[i, j, k] = first if same else 3


def _pyramid(classes: np.ndarray, levels: int) -> list[np.ndarray]:
    """Per level l (node side 2^l voxels): 0 unknown, 1 free, 2 occupied (uniform) or 3 mixed."""
    base = np.empty(classes.shape, dtype=np.uint8)
    _codes(classes, base)
    out = [base]
    for _ in range(levels):
        a = out[-1]
        nxt = np.empty((a.shape[0] // 2, a.shape[1] // 2, a.shape[2] // 2), dtype=np.uint8)
        _reduce(a, nxt)
        out.append(nxt)
    return out


@numba.njit(cache=True)
def _subtree(flat, offsets, shapes, level, ix, iy, iz, out, n):
    """The .bt bytes of the mixed node at pyramid ``level`` index (ix, iy, iz), depth first,
    written to ``out`` from ``n``; returns (new n, nodes below it)."""
    sl = np.empty(TREE_DEPTH + 1, dtype=np.int64)
    sx = np.empty(TREE_DEPTH + 1, dtype=np.int64)
    sy = np.empty(TREE_DEPTH + 1, dtype=np.int64)
    sz = np.empty(TREE_DEPTH + 1, dtype=np.int64)
    si = np.empty(TREE_DEPTH + 1, dtype=np.int64)
    nodes = 0
    top = 0
    sl[0], sx[0], sy[0], sz[0], si[0] = level, ix, iy, iz, -1
    while top >= 0:
        lv, x, y, z = sl[top], sx[top], sy[top], sz[top]
        c = lv - 1
        Y, Z = shapes[c, 1], shapes[c, 2]
        if si[top] == -1:  # first visit: the node's two bytes
            bits = 0
            for i in range(8):
                cx, cy, cz = 2 * x + (i & 1), 2 * y + ((i >> 1) & 1), 2 * z + ((i >> 2) & 1)
                v = flat[offsets[c] + (cx * Y + cy) * Z + cz]
                if v != 0:
                    nodes += 1
                    bits |= int(v) << (2 * i)
            out[n] = bits & 0xFF
            out[n + 1] = bits >> 8
            n += 2
            si[top] = 0
        i = si[top]
        if i == 8:
            top -= 1
            continue
        si[top] = i + 1
        cx, cy, cz = 2 * x + (i & 1), 2 * y + ((i >> 1) & 1), 2 * z + ((i >> 2) & 1)
        if flat[offsets[c] + (cx * Y + cy) * Z + cz] == 3:
            top += 1
            sl[top], sx[top], sy[top], sz[top], si[top] = c, cx, cy, cz, -1
    return n, nodes


def write_octomap(grid: VoxelGrid, path: str | Path) -> Path:
    """Write ``grid`` as an OctoMap ``.bt`` file (:func:`octomap_bytes`)."""
    path = Path(path)
    path.write_bytes(octomap_bytes(grid))
    return path


def octomap_bytes(grid: VoxelGrid) -> bytes:
    """``grid`` as an OctoMap ``.bt`` file's bytes (free and occupied leaves, pruned where eight
    siblings agree), readable by OctoMap's ``readBinary`` and octovis."""
    key0 = np.asarray(grid.key0, dtype=np.int64)
    ext = np.asarray(grid.shape, dtype=np.int64)
    levels = 5  # the pyramid's nodes of up to 32 voxels a side; larger nodes are few
    side = 1 << levels
    lo = (key0 // side) * side
    hi = -((-(key0 + ext)) // side) * side
    padded = np.full(tuple(int(v) for v in hi - lo), UNKNOWN, dtype=np.int8)
    off = key0 - lo
    padded[off[0]:off[0] + ext[0], off[1]:off[1] + ext[1], off[2]:off[2] + ext[2]] = grid.classes
    pyr = _pyramid(padded, levels)
    shapes = np.array([p.shape for p in pyr], dtype=np.int64)
    offsets = np.concatenate([[0], np.cumsum([p.size for p in pyr])]).astype(np.int64)
    flat = np.concatenate([p.ravel() for p in pyr])
    top = pyr[levels]
    buf = np.empty(2 * int(flat.size) + 64, dtype=np.uint8)
    n = 0
    nodes = 1

    def code(side_log: int, kmin: np.ndarray) -> int:
        """0 unknown, 1 free, 2 occupied (uniform) or 3 mixed: the node of side 2^side_log at kmin."""
        if side_log <= levels:
            idx = (kmin - lo) >> side_log
            if np.any(idx < 0) or np.any(idx >= shapes[side_log]):
                return 0
            return int(pyr[side_log][tuple(idx)])
        a = np.clip((kmin - lo) >> levels, 0, shapes[levels])
        b = np.clip((kmin + (1 << side_log) - lo) >> levels, 0, shapes[levels])
        cells = top[a[0]:b[0], a[1]:b[1], a[2]:b[2]].ravel()
        values = set(cells.tolist()) | ({0} if len(cells) < (1 << (side_log - levels)) ** 3 else set())
        return values.pop() if len(values) == 1 else 3

    offsets8 = [np.array([i & 1, (i >> 1) & 1, (i >> 2) & 1], dtype=np.int64) for i in range(8)]

    def node(side_log: int, kmin: np.ndarray) -> None:
        nonlocal n, nodes
        if side_log == levels:
            idx = (kmin - lo) >> levels
            n, below = _subtree(flat, offsets, shapes, levels, int(idx[0]), int(idx[1]), int(idx[2]), buf, n)
            nodes += below
            return
        half = 1 << (side_log - 1)
        bits, inner = 0, []
        for i in range(8):
            c = kmin + offsets8[i] * half
            v = code(side_log - 1, c)
            if v:
                nodes += 1
                bits |= v << (2 * i)
                if v == 3:
                    inner.append(c)
        buf[n], buf[n + 1] = bits & 0xFF, bits >> 8
        n += 2
        for c in inner:
            node(side_log - 1, c)

    root = code(TREE_DEPTH, np.zeros(3, dtype=np.int64))
    if root == 3:
        node(TREE_DEPTH, np.zeros(3, dtype=np.int64))
    header = (f"{BT_HEADER.decode()}\nid OcTree\nsize {nodes if root == 3 else 0}\n"
              f"res {grid.resolution!r}\ndata\n").encode()
    return header + buf[:n].tobytes()
