"""``python -m world import``: a team's own map and recorded run as a scenario (the paper's Urban
Circuit method).

SOURCE is a map_server map (its YAML) or a ROS 2 bag directory (maps on ``--map-topic``,
trajectories on ``--odom ID=TOPIC``). Routes come from a routes YAML (``--routes``) or from the
bag. Along each route, candidate deployment points lie every ``--stage-spacing`` metres of
travelled distance (or ``--stages N`` evenly), each with its recorded time; the value of a point
is the number of frontier cells whose centre lies within ``--radius`` of it, in the map given
(static) or in the latest map stamped at or before the point's time (``--replay``).

The scenario's stages. Stage j of the mission is every carrier's candidate at slot j: carrier r's
k-th candidate is stage ``offset_r + k``, where ``offset_r`` is its first candidate's recorded time
after the earliest carrier's, in stage intervals (``--align time``, staggered starts kept; or 0
with ``--align index``, the paper's "point j of every path"); a route that ends early leaves its
later stages invalid. The stage interval is ``--stage-interval`` or the median recorded time
between consecutive candidates. Each carrier drives its route (simplified within
``--path-tolerance``) at the constant speed that puts it on its k-th candidate at stage
``offset_r + k``; the recorded times stay in the report and decide the replayed values.

Files written (all or none): the scenario, its occupancy map beside it as a map_server map
(``NAME.map.yaml`` and ``NAME.map.pgm``: the map given, or the bag's last map), and the report.
"""
from __future__ import annotations

import json
import math
import os
import re
import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Callable

import numpy as np

from world import geometry
from world import grid as G
from world.grid import GridError

if TYPE_CHECKING:
    from world.scenario import Scenario
    from world.stages import StageGeometry

#: The paper's sensing radius for frontier values (m).
DEFAULT_RADIUS = 10.0
#: Candidate points per route when neither ``--stages`` nor ``--stage-spacing`` is given: the
#: paper's N = 19.
DEFAULT_STAGES = 19
#: Largest carrier body the importer gives a scenario (m): the project's default.
MAX_CARRIER_RADIUS = 0.4
#: How deep (m) a recorded route may go into occupied cells and still be taken as driven
#: (``--graze-depth``): localisation puts poses a few centimetres into walls and a run recorded
#: at 1 Hz cuts corners between its poses. Deeper, the route is refused.
DEFAULT_GRAZE_DEPTH = 0.2
#: Around every leg of a recorded route that grazes occupied cells, the occupied cells whose
#: centre lies within this many cells of the leg are free in the world's walls (the wall gives
#: way where the robot drove); the map written beside the scenario keeps them as recorded.
GRAZE_CARVE_CELLS = 2.0
#: Candidate points a carrier may have (planner.limits caps the stages of a scenario).
_ID = re.compile(r"[A-Za-z0-9_\-]+")
PRIOR_CHOICES = ("auto", "poisson", "negative_binomial")


@dataclass(frozen=True)
class ImportSettings:
    """What ``python -m world import`` was asked (flags of the same names)."""

    source: str
    out: str
    routes: str | None = None
    map_topic: str = "/map"
    odom: tuple[tuple[str, str], ...] = ()
    passengers: tuple[tuple[str, int], ...] = ()
    stage_spacing: float | None = None
    stages: int | None = None
    radius: float = DEFAULT_RADIUS
    replay: bool = False
    report: str | None = None
    stage_interval: float | None = None
    align: str = "time"
    name: str | None = None
    seed: int = 0
    conflict_radius: float | None = None
    carrier_radius: float | None = None
    path_tolerance: float | None = None
    wall_tolerance: float | None = None
    prior: str = "auto"
    free_level: int = G.DEFAULT_FREE_LEVEL
    occupied_level: int = G.DEFAULT_OCCUPIED_LEVEL
    # 3D sources (world/import3d.py): PointCloud2 topics as (carrier id or "", topic), the
    # paper's height filter (m), the voxel size (m; None: the OctoMap's, or 0.2 for scans),
    # frontier neighbours, the longest ray (m, < 0 whole), the sensor's fixed mounting (m) and
    # OctoMap's sensor model as (prob_hit, prob_miss, occupancy, clamp_min, clamp_max)
    cloud_topics: tuple[tuple[str, str], ...] = ()
    keep_above: float = 1.0
    keep_below: float = 0.1
    voxel: float | None = None
    neighbours: int = 6
    max_range: float = -1.0
    sensor_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    log_odds: tuple[float, float, float, float, float] = (0.7, 0.4, 0.5, 0.1192, 0.971)
    graze_depth: float = DEFAULT_GRAZE_DEPTH
    literal_thresholds: bool = False
    radii: str = "paper"  # "paper": --radius and --conflict-radius as given; "map": from the map's size


@dataclass(frozen=True)
class Route:
    """One carrier's recorded route: ``poses`` float ``[K, 3]`` (t s, x m, y m) in time order."""

    id: str
    passengers: int
    poses: np.ndarray
    where: str  # the file and field (or topic) it came from, for messages
    recorded: bool = False  # driven by a robot (a bag's poses, or ``recorded: true``): grazes taken


@dataclass
class Candidates:
    """A route's candidate deployment points.

    Attributes:
        path: float ``[M, 2]`` the polyline the carrier drives (m): the route simplified within
            the path tolerance, ending at the last candidate.
        arcs: float ``[n]`` each candidate's distance along ``path`` (m), ``k x spacing``.
        points: float ``[n, 2]`` the candidates (m); times: float ``[n]`` recorded (s).
        values: int ``[n]`` the paper's value of each (filled by :func:`import_run`).
        offset: the stage of the first candidate.
    """

    route: Route
    path: np.ndarray
    arcs: np.ndarray
    points: np.ndarray
    times: np.ndarray
    values: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    offset: int = 0

    @property
    def spacing(self) -> float:
        return float(self.arcs[1] - self.arcs[0])


@dataclass
class ImportResult:
    scenario_text: str
    report: dict
    grid: G.OccupancyGrid | None
    summary: list[str]
    #: a 3D import's map as OctoMap .bt bytes, written beside the scenario (world/import3d.py)
    octomap: bytes | None = None


# --------------------------------------------------------------------------- routes


def read_routes(path: str) -> list[Route]:
    """A routes YAML: ``carriers:`` a list of ``{id, passengers, start (s), speed (m/s), path
    [[x, y], ...] (m, map frame), recorded (bool, default false)}``; a pose's time is ``start +
    distance along the path / speed``. ``recorded: true`` marks poses a robot drove (they may
    graze walls, :func:`grazes`); a hand-written route may not enter an occupied cell.

    Raises:
        GridError: naming the file and field, one line.
    """
    import yaml

    from world.scenario import _Checker, _parse_yaml

    try:
        doc = _parse_yaml(Path(path).read_text(encoding="utf-8"))  # libyaml, duplicate keys refused
    except FileNotFoundError:
        raise GridError(path, "an existing routes YAML file", "no such file") from None
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise GridError(path, "a readable routes YAML file", f"{exc.__class__.__name__}: {str(exc).splitlines()[0]}") from None
    ck = _Checker(path)
    top = ck.mapping(doc, "", ("carriers",), ("carriers",))
    routes = []
    items = top.get("carriers") if top else None
    if top is not None and (not isinstance(items, list) or not items):
        ck.bad("carriers", "a non-empty list of carriers {id, passengers, start, speed, path}", items)
    for r, item in enumerate(items if isinstance(items, list) else []):
        where = f"carriers[{r}]"
        m = ck.mapping(item, where, ("id", "passengers", "start", "speed", "path", "recorded"), ("id", "path"))
        if m is None or len(ck.problems):
            break
        cid = str(m["id"])
        if not _ID.fullmatch(cid):
            ck.bad(f"{where}.id", "a string of letters, digits, '_' or '-'", m["id"])
        pas = ck.number(m.get("passengers", 1), f"{where}.passengers", minimum=0, integer=True)
        start = ck.number(m.get("start", 0.0), f"{where}.start", minimum=0)
        speed = ck.number(m.get("speed", 1.0), f"{where}.speed", minimum=0, exclusive=True)
        pts = ck.points(m["path"], f"{where}.path", 2)
        recorded = m.get("recorded", False)
        if not isinstance(recorded, bool):
            ck.bad(f"{where}.recorded", "true or false", recorded)
        if ck.problems:
            break
        assert pas is not None and start is not None and speed is not None  # read without a problem
        xy = np.asarray(pts, dtype=float)
        t = start + np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))]) / speed
        routes.append(Route(cid, int(pas), np.column_stack([t, xy]), f"{path}: {where}.path", recorded))
    if ck.problems:
        raise GridError(*_split(ck.problems[0]))
    ids = [r.id for r in routes]
    for cid in ids:
        if ids.count(cid) > 1:
            raise GridError(f"{path}: carriers", "unique carrier ids", f"'{cid}' twice")
    return routes


def _split(line: str) -> tuple[str, str, str]:
    """A checker line ``FILE: path: expected X, found Y`` as GridError's parts."""
    where, _, rest = line.partition(": expected ")
    expected, _, found = rest.rpartition(", found ")
    return where, expected or rest, found


def _dedup(poses: np.ndarray) -> np.ndarray:
    """Poses with consecutive repeats of the same position dropped (the first arrival kept)."""
    keep = np.ones(len(poses), dtype=bool)
    keep[1:] = np.any(np.diff(poses[:, 1:], axis=0) != 0, axis=1)
    return poses[keep]


def candidates(route: Route, spacing: float | None, count: int | None, tolerance: float) -> Candidates:
    """Candidate points every ``spacing`` metres of travelled distance from the route's first
    pose, or ``count`` points evenly from its first to its last, on the route simplified by
    Douglas–Peucker within ``tolerance`` (m). A candidate's time is when the recorded run first
    reached the same fraction of the corresponding stretch of the recorded poses."""
    poses = _dedup(route.poses)
    xy = poses[:, 1:]
    if len(poses) < 2:
        raise GridError(route.where, "a route of at least two distinct points", f"{len(poses)} point")
    orig = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
    idx = np.flatnonzero(G.simplify_mask(xy, tolerance))
    simple = xy[idx]
    cum = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(simple, axis=0).T))])
    length = float(cum[-1])
    if spacing is not None:
        n = int(math.floor(length / spacing + 1e-9)) + 1
        if n < 2:
            raise GridError(route.where, f"a route longer than --stage-spacing {spacing:g} m (two candidate points)",
                            f"{length:.2f} m")
        arcs = np.arange(n) * float(spacing)
    else:
        assert count is not None  # one of spacing and count is given
        arcs = np.linspace(0.0, length, int(count))
    points = np.array([geometry.point_along(simple, cum, float(s)) for s in arcs])
    leg = np.clip(np.searchsorted(cum, arcs, side="right") - 1, 0, len(cum) - 2)
    u = np.where(cum[leg + 1] > cum[leg], (arcs - cum[leg]) / np.where(cum[leg + 1] > cum[leg], cum[leg + 1] - cum[leg], 1.0), 0.0)
    recorded = orig[idx[leg]] + np.clip(u, 0.0, 1.0) * (orig[idx[leg + 1]] - orig[idx[leg]])
    times = np.interp(recorded, orig, poses[:, 0])
    last = arcs[-1]
    inner = simple[1:][cum[1:] < last - 1e-9]
    path = np.concatenate([simple[:1], inner, points[-1:]])
    return Candidates(route, path, arcs, points, times)


def checked_candidates(grid: G.OccupancyGrid, route: Route, spacing: float | None, count: int | None,
                       tolerance: float, walls: G.OccupancyGrid | None = None) -> Candidates:
    """:func:`candidates` of a route on the map: a route off the map or through an occupied cell
    is refused (naming the point); where only its simplification would cut a wall, it is
    simplified again within a quarter of the tolerance, down to none. ``walls``: the grid the
    world's walls come from (:func:`take_grazes`; the map itself by default): a recorded route
    is checked against it, a hand-written one against the map."""
    walls = grid if walls is None else walls
    poses = _dedup(route.poses)
    hit = (walls if route.recorded else grid).first_blocked(poses[:, 1:])
    if hit is not None:
        k, what, (x, y) = hit
        hint = "" if what == "off the map" else \
            " (a route a robot drove may say recorded: true, and is then taken within --graze-depth)"
        raise GridError(f"{route.where}: carrier '{route.id}'",
                        "a route on the map's free or unknown cells",
                        f"it goes {what if what == 'off the map' else 'into ' + what} at ({x:.2f}, {y:.2f}) "
                        f"between its points {k} ({poses[k, 1]:.2f}, {poses[k, 2]:.2f}) and {k + 1} "
                        f"({poses[k + 1, 1]:.2f}, {poses[k + 1, 2]:.2f}){hint}")
    c = candidates(route, spacing, count, tolerance)
    while walls.first_blocked(c.path) is not None and tolerance > 0:
        tolerance = tolerance / 4 if tolerance > 1e-6 else 0.0
        c = candidates(route, spacing, count, tolerance)
    return c


def take_grazes(grid: G.OccupancyGrid, walls: G.OccupancyGrid, route: Route, limit: float,
                progress: Callable[[str], None]) -> G.OccupancyGrid:
    """A recorded route's grazes taken as driven: every leg that enters occupied cells at most
    ``limit`` (m) deep (:meth:`world.grid.OccupancyGrid.grazes`, on the map ``grid``) is said in
    one warning naming the deepest graze, and ``walls`` is returned with the occupied cells
    within :data:`GRAZE_CARVE_CELLS` cells of those legs made free, so that the carrier's body
    follows the route without colliding. A hand-written route is returned ``walls`` unchanged
    (:func:`checked_candidates` refuses it if it enters a wall).

    Raises:
        GridError: a graze deeper than ``limit``, naming the point and the two poses around it.
    """
    if not route.recorded:
        return walls
    poses = _dedup(route.poses)
    found = grid.grazes(poses[:, 1:])
    if not found:
        return walls
    deep = max(found, key=lambda g: g.depth)
    k, (x, y) = deep.leg, deep.point
    where = (f"at ({x:.2f}, {y:.2f}) between its points {k} ({poses[k, 1]:.2f}, {poses[k, 2]:.2f}) and {k + 1} "
             f"({poses[k + 1, 1]:.2f}, {poses[k + 1, 2]:.2f})")
    if deep.depth > limit:
        raise GridError(f"{route.where}: carrier '{route.id}' (recorded)",
                        f"a route at most --graze-depth {limit:g} m into the map's occupied cells",
                        f"it goes {deep.depth:.3f} m into an occupied cell {where}")
    progress(f"warning: carrier '{route.id}' (recorded) grazes occupied cells on {len(found)} leg(s), deepest "
             f"{deep.depth:.3f} m {where}; taken as driven (within --graze-depth {limit:g} m): the walls within "
             f"{GRAZE_CARVE_CELLS:g} cells of those legs give way")
    return walls.carved(poses[:, 1:], [g.leg for g in found], GRAZE_CARVE_CELLS * grid.resolution)


# --------------------------------------------------------------------------- values and prior


def fit_prior(values: np.ndarray, choice: str = "auto") -> dict:
    """The prior of a stage's count fitted to ``values`` by the method of moments: Poisson with
    their mean, or (``auto`` when the variance exceeds the mean, or asked for) a negative
    binomial with the same mean m and variance v (scipy ``nbinom(n, p)``: n = m² / (v - m),
    p = m / v)."""
    v = np.asarray(values, dtype=float)
    mean = float(v.mean())
    var = float(v.var(ddof=1)) if len(v) > 1 else mean
    if mean <= 0:
        raise GridError("values", "at least one candidate point with a frontier cell within the radius "
                        "(the prior is fitted from the values)", "every value 0")
    if choice == "negative_binomial" or (choice == "auto" and var > mean * 1.0001):
        var = max(var, mean * 1.0001)
        return {"kind": "negative_binomial", "n": round(mean * mean / (var - mean), 6), "p": round(mean / var, 6)}
    return {"kind": "poisson", "mean": round(mean, 6)}


# --------------------------------------------------------------------------- the import


def import_run(st: ImportSettings, progress: Callable[[str], None] = print) -> ImportResult:
    """Everything the import writes, computed; nothing written yet.

    Raises:
        GridError: bad input, naming the file, field or topic.
    """
    from world import bag as B

    source = Path(st.source)
    is_bag = source.is_dir()
    history_stamps: list[float] = []
    tracks: dict[str, np.ndarray] = {}
    if is_bag:
        if not B.is_bag(source):
            raise GridError(str(source), "a ROS 2 bag directory (metadata.yaml and its storage files) or a map YAML",
                            "a directory without metadata.yaml")
        if not st.odom and not st.routes:
            raise GridError("--odom", "ID=TOPIC for each carrier (or --routes ROUTES.yaml)", "neither")
        tracks, history_stamps = B.read_tracks(source, dict(st.odom), st.map_topic)
        progress(f"read {sum(len(t) for t in tracks.values())} poses of {len(tracks)} carriers and "
                 f"{len(history_stamps)} maps from {source}")
    else:
        if st.odom:
            raise GridError("--odom", "a ROS 2 bag as SOURCE (a map YAML holds no trajectories)", str(source))
        if not st.routes:
            raise GridError("--routes", "ROUTES.yaml with the carriers' paths (a map YAML holds none)", "nothing")
    passengers = dict(st.passengers)
    routes = read_routes(st.routes) if st.routes else []
    for cid, poses in tracks.items():
        routes.append(Route(cid, passengers.get(cid, 1), poses, f"{source}: topic {dict(st.odom)[cid]}", True))
    ids = [r.id for r in routes]
    for cid in passengers:
        if cid not in ids:
            raise GridError(f"--passengers {cid}", f"a carrier id ({', '.join(ids)})", f"unknown carrier '{cid}'")
    routes = [Route(r.id, passengers.get(r.id, r.passengers), r.poses, r.where, r.recorded) for r in routes]
    if len(set(ids)) != len(ids):
        raise GridError("--odom/--routes", "each carrier once", f"carriers {ids}")

    # the map the world is built from: the map given, or the bag's last map
    if is_bag:
        order = sorted(range(len(history_stamps)), key=lambda k: (history_stamps[k], k))
        stamps = [history_stamps[k] for k in order]
        (_, grid), = B.iter_maps(source, st.map_topic, st.free_level, st.occupied_level, {order[-1]})
    else:
        grid = G.read_map_yaml(source, st.free_level, st.occupied_level, literal=st.literal_thresholds)
        stamps, order = [0.0], [0]
    for line in grid.warnings:
        progress(f"warning: {line}")
    if st.radii == "map":  # the sensing and conflict radii from the map's size (world.stages.map_radii)
        from world.stages import map_radii

        radius, conflict = map_radii(grid.extent)
        st = dataclasses.replace(st, radius=radius, conflict_radius=conflict)
        progress(f"radii from the map's size: sensing {radius:g} m, conflict {conflict:g} m")
    tol = 0.5 * grid.resolution if st.path_tolerance is None else st.path_tolerance
    # the world's walls: the map's, giving way where a recorded route grazed them
    walls_grid = grid
    for r in routes:
        walls_grid = take_grazes(grid, walls_grid, r, st.graze_depth, progress)
    cands = [checked_candidates(grid, r, st.stage_spacing, st.stages, tol, walls_grid) for r in routes]

    # values: the frontier cells within the radius, in the map given or the latest at each time
    frontier_total = int(G.frontier_mask(grid).sum())
    if frontier_total == 0:
        raise GridError(grid.source or str(source), "a map with at least one frontier cell (a free cell next to an "
                        "unknown one)", "none" + (" (no free cell)" if not (grid.classes == G.FREE).any() else "")
                        + "".join(f" ({w.partition(': ')[2]})" for w in grid.warnings))
    for c in cands:
        c.values = np.zeros(len(c.points), dtype=np.int64)
    if st.replay:
        need: dict[int, list[tuple[Candidates, int]]] = {}
        early = 0
        for c in cands:
            for k, t in enumerate(c.times):
                i = G.latest_at(stamps, float(t))
                if i < 0:
                    early += 1
                else:
                    need.setdefault(order[i], []).append((c, k))
        if early:
            progress(f"{early} candidate points precede the first map: their value is 0")
        maps = B.iter_maps(source, st.map_topic, st.free_level, st.occupied_level, set(need)) if is_bag \
            else iter([(0, grid)])
        for bag_index, g in maps:
            counter = G.FrontierCounter(g)
            for c, k in need.get(bag_index, []):
                c.values[k] = counter.count(c.points[k:k + 1], st.radius)[0]
    else:
        counter = G.FrontierCounter(grid)
        for c in cands:
            c.values = counter.count(c.points, st.radius)

    interval, n_stages = schedule(st, cands)

    walls = G.wall_lines(walls_grid, st.wall_tolerance)
    segs = np.concatenate([np.column_stack([w[:-1], w[1:]]) for w in walls]) if walls else np.zeros((0, 4))
    body = st.carrier_radius if st.carrier_radius is not None else _carrier_radius(cands, segs)
    observed = np.concatenate([c.values for c in cands]) if st.replay else _sensed(cands, grid, segs, st.radius)
    from world.stages import radii_warning

    said = radii_warning(grid.extent, st.radius, 3.0 * st.radius if st.conflict_radius is None else st.conflict_radius)
    if said:
        progress(f"warning: {said}")
    prior = fit_prior(observed, st.prior)
    name = st.name or Path(st.out).name.split(".")[0]
    text = _scenario_text(st, name, grid, walls, cands, interval, n_stages, body, prior)
    report = {
        "frontier_cells": frontier_total,
        "carriers": {c.route.id: [{"t": float(t), "x": float(p[0]), "y": float(p[1]), "value": int(v)}
                                  for t, p, v in zip(c.times, c.points, c.values)] for c in cands},
        "mode": "replay" if st.replay else "static",
        "radius": st.radius,
        "maps": len(stamps),
        "stage_interval": interval,
        "stages": n_stages,
        "first_stage": {c.route.id: c.offset for c in cands},
        "prior": prior,
    }
    summary = [f"{len(cands)} carriers, {n_stages} stages every {interval:g} s; "
               + ", ".join(f"{c.route.id}: {len(c.points)} points (stages {c.offset}..{c.offset + len(c.points) - 1}, "
                           f"every {c.spacing:.2f} m)" for c in cands),
               f"map {grid.shape[1]} x {grid.shape[0]} cells of {grid.resolution:g} m, {frontier_total} frontier cells, "
               f"{len(walls)} wall outlines ({len(segs)} segments), carrier radius {body:.3g} m",
               f"values ({'replay: latest map at each time' if st.replay else 'static map'}, radius {st.radius:g} m): "
               f"mean {observed.mean():.2f}, max {int(observed.max())}; prior {prior}"]
    return ImportResult(text, report, grid, summary)


def schedule(st: ImportSettings, cands: list[Candidates]) -> tuple[float, int]:
    """The mission's stage interval (s) and stage count; sets each candidate list's offset.

    Raises:
        GridError: too many stages or carriers, more passengers than candidates.
    """
    all_gaps = np.concatenate([np.diff(c.times) for c in cands])
    if st.stage_interval is not None:
        interval = float(st.stage_interval)
    else:
        interval = max(0.1, round(float(np.median(all_gaps)) if len(all_gaps) else 1.0, 1))
    t_min = min(float(c.times[0]) for c in cands)
    for c in cands:
        c.offset = 0 if st.align == "index" else int(round((float(c.times[0]) - t_min) / interval))
    n_stages = max(c.offset + len(c.points) for c in cands)
    from planner.limits import MAX_CARRIERS, MAX_STAGES

    if n_stages > MAX_STAGES or len(cands) > MAX_CARRIERS:
        raise GridError("--stage-spacing/--stages", f"at most {MAX_STAGES} stages and {MAX_CARRIERS} carriers",
                        f"{n_stages} stages, {len(cands)} carriers")
    for c in cands:
        if c.route.passengers > len(c.points):
            # blame where the count came from: the flag, the routes file's field, or a bag's default
            r = c.route
            where = (f"--passengers {r.id}" if r.id in dict(st.passengers) else
                     r.where.removesuffix(".path") + ".passengers" if r.where.endswith(".path") else
                     f"{r.where}: carrier '{r.id}'")
            raise GridError(where, f"at most {len(c.points)} passengers for carrier '{r.id}' (its candidate points; "
                            f"more with --stages or a smaller --stage-spacing)", str(r.passengers))
    return interval, n_stages


def _carrier_radius(cands: list[Candidates], segs: np.ndarray) -> float:
    """The project's carrier radius, or less where a route passes closer to a wall: 90 % of the
    smallest clearance, so that every leg passes the scenario's clearance check."""
    if not len(segs):
        return MAX_CARRIER_RADIUS
    clearance, reach = math.inf, MAX_CARRIER_RADIUS / 0.9
    lo_x, hi_x = np.minimum(segs[:, 0], segs[:, 2]), np.maximum(segs[:, 0], segs[:, 2])
    lo_y, hi_y = np.minimum(segs[:, 1], segs[:, 3]), np.maximum(segs[:, 1], segs[:, 3])
    for c in cands:
        for a, b in zip(c.path[:-1], c.path[1:]):
            # walls farther than the largest radius's reach do not lower it
            near = ((hi_x >= min(a[0], b[0]) - reach) & (lo_x <= max(a[0], b[0]) + reach)
                    & (hi_y >= min(a[1], b[1]) - reach) & (lo_y <= max(a[1], b[1]) + reach))
            d = float(geometry.segment_segment_distance(a, b, segs[near]).min()) if near.any() else math.inf
            if d < clearance:
                clearance, closest = d, (c.route, a, b)
    radius = min(MAX_CARRIER_RADIUS, 0.9 * clearance)
    if radius < 1e-3:
        route, a, b = closest
        raise GridError(f"{route.where}: carrier '{route.id}'",
                        "a route at least 1 mm from the walls traced round the occupied cells",
                        f"its leg ({a[0]:.2f}, {a[1]:.2f})-({b[0]:.2f}, {b[1]:.2f}) {clearance:.4f} m from a wall")
    return float(radius)


def _sensed(cands: list[Candidates], grid: G.OccupancyGrid, segs: np.ndarray, radius: float) -> np.ndarray:
    """What the world senses at the candidates in static mode (frontier cells within the radius
    with line of sight): the values the mission observes, which the prior is fitted to."""
    pts = G.frontier_points(grid)
    return np.array([geometry.count_visible(p, pts, radius, segs) for c in cands for p in c.points], dtype=float)


def _num(v: float) -> str:
    return repr(float(v))


def _scenario_text(st: ImportSettings, name: str, grid: G.OccupancyGrid, walls: list[np.ndarray],
                   cands: list[Candidates], interval: float, n_stages: int, body: float, prior: dict) -> str:
    stem = Path(st.out).name.split(".")[0]
    xmin, ymin, xmax, ymax = grid.extent
    pad = grid.resolution
    lines = [
        f"# Imported by python -m world import from {st.source}"
        + (f" with routes {st.routes}" if st.routes else "") + f" ({'replay' if st.replay else 'static'}).",
        f"name: {json.dumps(name)}",
        f"seed: {int(st.seed)}",
        "map:",
        f"  bounds: [{_num(xmin - pad)}, {_num(ymin - pad)}, {_num(xmax + pad)}, {_num(ymax + pad)}]",
        f"  occupancy: {{file: {stem}.map.yaml, sha256: {grid.digest}, free_level: {grid.free_level}, "
        f"occupied_level: {grid.occupied_level}}}",
        "  # the outlines of the occupied cells (world.grid.wall_lines), less those a recorded route grazed",
        "  walls:" + ("" if walls else " []"),
    ]
    lines += ["    - [" + ", ".join(f"[{x:.4f}, {y:.4f}]" for x, y in w) + "]" for w in walls]
    lines.append("features:")
    if st.replay:
        lines.append(f"  # the paper's value at each candidate point, in the latest map at its recorded time")
        lines.append("  replay:")
        for c in cands:
            row = ["null"] * n_stages
            for k, v in enumerate(c.values):
                row[c.offset + k] = str(int(v))
            lines.append(f"    {c.route.id}: [{', '.join(row)}]")
    else:
        lines.append("  from_map: frontier")
    lines += [
        f"sensing_radius: {_num(st.radius)}",
        f"stage_interval: {_num(interval)}",
        f"stages: {n_stages}",
    ]
    if st.conflict_radius is not None:
        lines.append(f"conflict_radius: {_num(st.conflict_radius)}")
    lines.append(f"carrier_radius: {_num(body)}")
    lines.append("# fitted to the values the mission observes (docs/scenario.md, \"Your own map and runs\")")
    lines.append("prior: {" + ", ".join(f"{k}: {v}" for k, v in prior.items()) + "}")
    lines.append("carriers:")
    for c in cands:
        start = interval * c.offset
        stop = interval * (c.offset + len(c.points) - 1)
        lines.append(f"  - id: {c.route.id}")
        lines.append(f"    passengers: {c.route.passengers}")
        lines.append(f"    start_time: {_num(start)}")
        lines.append(f"    stop_time: {_num(stop)}")
        lines.append(f"    speed: {_num(c.spacing / interval)}")
        lines.append("    waypoints: [" + ", ".join(f"[{_num(x)}, {_num(y)}]" for x, y in c.path) + "]")
    return "\n".join(lines) + "\n"


def write_outputs(st: ImportSettings, result: ImportResult) -> list[str]:
    """Write the scenario, its map and the report, all or none (temporary files renamed at the
    end); the scenario is loaded back and its stages checked against the candidates first."""
    from world.scenario import ScenarioError, load_scenario
    from world.stages import stage_geometry

    assert result.grid is not None and result.octomap is None  # a 3D import: world.import3d.write_outputs_3d
    out = Path(st.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    stem = out.name.split(".")[0]
    map_yaml = out.parent / f"{stem}.map.yaml"
    finals = [out, map_yaml, map_yaml.with_suffix(".pgm")] + ([Path(st.report)] if st.report else [])
    temps = [p.with_name(f".{p.name}.{os.getpid()}.tmp") for p in finals]
    scratch = out.parent / f".import-{os.getpid()}"
    try:
        # the scenario names the map by its final name: write the map under it in a scratch
        # directory, then move everything into place
        scratch.mkdir(exist_ok=True)
        image = G.write_map_yaml(result.grid, scratch / map_yaml.name)
        (scratch / out.name).write_text(result.scenario_text, encoding="utf-8")
        try:
            scenario = load_scenario(scratch / out.name)
        except ScenarioError as err:
            raise GridError(str(out), "an imported scenario that loads", err.problems[0]) from None
        _self_check(scenario, result.report, stage_geometry(scenario))
        os.replace(scratch / map_yaml.name, temps[1])
        os.replace(image, temps[2])
        os.replace(scratch / out.name, temps[0])
        if st.report:
            temps[3].write_text(json.dumps(result.report, indent=1) + "\n", encoding="utf-8")
        for tmp, final in zip(temps, finals):
            os.replace(tmp, final)
    finally:
        for tmp in temps:
            tmp.unlink(missing_ok=True)
        if scratch.exists():
            for p in scratch.iterdir():
                p.unlink()
            scratch.rmdir()
    return [str(p) for p in finals]


def _self_check(scenario: Scenario, report: dict, geo: StageGeometry) -> None:
    """The written scenario puts carrier r on its k-th candidate at stage offset_r + k, and
    nowhere valid else."""
    for r, c in enumerate(scenario.carriers):
        first = report["first_stage"][c.id]
        pts = report["carriers"][c.id]
        expect = np.zeros(scenario.stages, dtype=bool)
        expect[first:first + len(pts)] = True
        if not np.array_equal(geo.valid[r], expect):
            raise AssertionError(f"imported carrier {c.id}: valid stages {np.flatnonzero(geo.valid[r])} != candidates")
        got = geo.positions[r, first:first + len(pts)]
        want = np.array([[p["x"], p["y"]] for p in pts])
        if not np.allclose(got, want, atol=1e-6, rtol=0):
            raise AssertionError(f"imported carrier {c.id}: stage positions off by {np.abs(got - want).max():g} m")
