"""``python -m world import`` from 3D sources: the paper's Urban Circuit pipeline as it was, an
occupancy map of voxels, its frontier voxels and their height filter.

SOURCE is an OctoMap file (``.bt``/``.ot``: one map, read as it is), a folder of PCD/PLY scans
with ``poses.txt`` (world/clouds.py), or a ROS 2 bag with ``sensor_msgs/msg/PointCloud2`` on
``--cloud-topic`` (its sensor poses from the carriers' odometry on ``--odom`` and ``/tf_static``,
or ``--sensor-offset``). Scans are ray cast into a voxel map by OctoMap's rules
(world/voxels.py); the value of a candidate point (x, y, z: the carrier's base) is the number of
frontier voxels within ``--radius`` (3D) more than ``--keep-above`` above or more than
``--keep-below`` below it, in the final map (static) or in the map of the scans stamped at or
before the candidate's time (``--replay``).

Routes are 3D: a routes YAML point is ``[x, y, z]`` (or ``[x, y]`` where the map has exactly one
floor under the route's first point), odometry keeps its z. Carriers whose bases lie within
``STOREY_GAP`` of each other share a storey; a storey's walls are the outlines of the columns
with an occupied voxel whose centre lies in ``WALL_BAND`` above the storey's base (above the
floor and whatever a carrier drives over, below the ceiling), traced as the 2D import traces an
occupancy grid's; each carrier's world holds only its own storey's walls. The mission observes
the reported values exactly (``features.replay``), static or replayed.

Files written (all or none): the scenario, the map as an OctoMap ``.bt`` beside it
(``NAME.map.bt``, named by ``map.voxels`` with its digest) and the report.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
from pathlib import Path
from typing import Callable

import numpy as np

from world import clouds as C
from world import grid as G
from world import voxels as V
from world.grid import GridError
from world.importer import (_ID, Candidates, ImportResult, ImportSettings, Route, _carrier_radius, _num, _split,
                            checked_candidates, fit_prior, schedule)

#: Carriers whose bases (median route height) lie within this of each other share a storey (m).
STOREY_GAP = 1.5
#: A storey's walls: columns with an occupied voxel centred this far above its base (m).
WALL_BAND = (0.3, 1.5)
#: The voxel size of a map built from scans when --voxel is not given (m).
DEFAULT_VOXEL = 0.2


def is_3d(st: ImportSettings) -> bool:
    """Whether SOURCE is an OctoMap file, a folder of scans, or a bag read for its clouds."""
    src = Path(st.source)
    return (src.suffix.lower() in V.OCTOMAP_SUFFIXES or C.is_scan_folder(src) or bool(st.cloud_topics)
            or (src.is_file() and src.suffix.lower() not in (".yaml", ".yml")))


# --------------------------------------------------------------------------- routes


def read_routes_3d(path: str) -> list[tuple[Route, np.ndarray | None]]:
    """A routes YAML whose path points are ``[x, y, z]`` or ``[x, y]`` (each path one or the
    other): (route of (t, x, y) poses, z ``[K]`` or None)."""
    import yaml

    from world.scenario import _Checker, _parse_yaml

    try:
        doc = _parse_yaml(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise GridError(path, "an existing routes YAML file", "no such file") from None
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise GridError(path, "a readable routes YAML file", f"{exc.__class__.__name__}: {str(exc).splitlines()[0]}") from None
    ck = _Checker(path)
    top = ck.mapping(doc, "", ("carriers",), ("carriers",))
    items = top.get("carriers") if top else None
    if top is not None and (not isinstance(items, list) or not items):
        ck.bad("carriers", "a non-empty list of carriers {id, passengers, start, speed, path}", items)
    out: list[tuple[Route, np.ndarray | None]] = []
    for r, item in enumerate(items if isinstance(items, list) else []):
        where = f"carriers[{r}]"
        m = ck.mapping(item, where, ("id", "passengers", "start", "speed", "path"), ("id", "path"))
        if m is None or ck.problems:
            break
        cid = str(m["id"])
        if not _ID.fullmatch(cid):
            ck.bad(f"{where}.id", "a string of letters, digits, '_' or '-'", m["id"])
        pas = ck.number(m.get("passengers", 1), f"{where}.passengers", minimum=0, integer=True)
        start = ck.number(m.get("start", 0.0), f"{where}.start", minimum=0)
        speed = ck.number(m.get("speed", 1.0), f"{where}.speed", minimum=0, exclusive=True)
        pts = m["path"]
        dims = {len(p) if isinstance(p, (list, tuple)) else -1 for p in pts} if isinstance(pts, list) else {-1}
        ok = (isinstance(pts, list) and len(pts) >= 2 and len(dims) == 1 and dims <= {2, 3}
              and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for p in pts for v in p))
        if not ok:
            ck.bad(f"{where}.path", "a list of at least 2 points, all [x, y, z] or all [x, y] (m)", pts)
        if ck.problems:
            break
        assert pas is not None and start is not None and speed is not None
        arr = np.asarray(pts, dtype=float)
        xy = arr[:, :2]
        t = start + np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))]) / speed
        out.append((Route(cid, int(pas), np.column_stack([t, xy]), f"{path}: {where}.path"),
                    arr[:, 2] if arr.shape[1] == 3 else None))
    if ck.problems:
        raise GridError(*_split(ck.problems[0]))
    ids = [r.id for r, _ in out]
    for cid in ids:
        if ids.count(cid) > 1:
            raise GridError(f"{path}: carriers", "unique carrier ids", f"'{cid}' twice")
    return out


def floor_under(grid: V.VoxelGrid, x: float, y: float, where: str) -> float:
    """The height (m) of the one floor under (x, y): the top of an occupied voxel with a free one
    on it. Refused when there is none, or several (the storey is ambiguous: give z)."""
    i, j, _ = grid.index_of([[x, y, 0.0]])[0]
    if not (0 <= i < grid.shape[0] and 0 <= j < grid.shape[1]):
        raise GridError(where, "a point over the map", f"({x:.2f}, {y:.2f}) outside it")
    col = grid.classes[i, j]
    tops = np.flatnonzero((col[:-1] == V.OCCUPIED) & (col[1:] == V.FREE))
    if len(tops) != 1:
        zs = ", ".join(f"{grid.lower[2] + (k + 1) * grid.resolution:.2f}" for k in tops) or "none"
        raise GridError(where, "[x, y, z] points (a 3D map: the carrier's base height)" if len(tops) > 1
                        else "a floor (an occupied voxel under a free one) under its first point, or [x, y, z] points",
                        f"[x, y] over {len(tops)} floors at z = {zs} m" if len(tops) > 1 else f"[x, y] over no floor")
    return float(grid.lower[2] + (tops[0] + 1) * grid.resolution)


# --------------------------------------------------------------------------- storeys


def storeys_of(bases: dict[str, float]) -> tuple[list[float], dict[str, int]]:
    """(storey base heights ascending, carrier id -> storey index): carriers whose bases lie
    within STOREY_GAP of the previous one's share its storey; a storey's base is its lowest."""
    order = sorted(bases, key=lambda c: (bases[c], c))
    levels: list[float] = []
    of: dict[str, int] = {}
    last = -math.inf
    for cid in order:
        if bases[cid] - last >= STOREY_GAP:
            levels.append(bases[cid])
        of[cid] = len(levels) - 1
        last = bases[cid]
    return levels, of


def storey_grid(grid: V.VoxelGrid, base: float) -> G.OccupancyGrid:
    """The storey's 2D occupancy: a column is occupied when a voxel centred in WALL_BAND above
    ``base`` is, else free when one there is free, else unknown."""
    zc = grid.lower[2] + (np.arange(grid.shape[2]) + 0.5) * grid.resolution
    band = (zc > base + WALL_BAND[0]) & (zc <= base + WALL_BAND[1])
    sub = grid.classes[:, :, band]
    occ = (sub == V.OCCUPIED).any(axis=2)
    free = (sub == V.FREE).any(axis=2)
    data = np.where(occ, 100, np.where(free, 0, -1)).astype(np.int8).T  # [Y, X]: ROS row-major
    lo = grid.lower
    return G.OccupancyGrid(data, grid.resolution, (float(lo[0]), float(lo[1]), 0.0), source=f"{grid.source} (storey at z {base:g} m)")


# --------------------------------------------------------------------------- the import


def _params(st: ImportSettings) -> V.OccupancyParams:
    p = V.OccupancyParams(*st.log_odds)
    p.check("--log-odds")
    return p


def _load(st: ImportSettings, progress: Callable[[str], None]):
    """(map or None, scans or None, carrier tracks ``[K, 4]``) of the source."""
    src = Path(st.source)
    params = _params(st)
    if src.suffix.lower() in V.OCTOMAP_SUFFIXES or (src.is_file() and not src.suffix.lower() in (".yaml", ".yml")):
        if st.cloud_topics:
            raise GridError("--cloud-topic", "a ROS 2 bag as SOURCE", f"the file {src}")
        if not src.is_file():
            raise GridError(str(src), "an existing OctoMap file (.bt or .ot)", "no such file")
        if st.replay:
            raise GridError("--replay", "scans to replay (a bag with --cloud-topic, or a folder of scans)",
                            f"one map ({src})")
        if st.odom:
            raise GridError("--odom", "a bag or a folder of scans as SOURCE (an OctoMap holds no trajectories)", str(src))
        grid = V.read_octomap(src, params)
        if st.voxel is not None and abs(st.voxel - grid.resolution) > 1e-9:
            raise GridError("--voxel", f"the OctoMap's own resolution ({grid.resolution:g} m) or nothing",
                            f"{st.voxel:g}")
        progress(f"read {src}: {grid.shape[0]} x {grid.shape[1]} x {grid.shape[2]} voxels of {grid.resolution:g} m "
                 f"({grid.counts()['free']} free, {grid.counts()['occupied']} occupied)")
        return grid, None, {}
    tracks: dict[str, np.ndarray] = {}
    if C.is_scan_folder(src):
        if st.cloud_topics:
            raise GridError("--cloud-topic", "a ROS 2 bag as SOURCE", f"the folder of scans {src}")
        scans = C.read_folder(src)
        for cid, name in st.odom:
            f = Path(name)
            if not f.is_absolute() and not f.exists():
                f = src / name
            tracks[cid] = C.read_tum(f).poses[:, :4]
    else:
        from world import bag as B

        if not B.is_bag(src):
            raise GridError(str(src), "an OctoMap file (.bt/.ot), a folder of scans with poses.txt, or a ROS 2 bag",
                            "no such file" if not src.exists() else "a directory without poses.txt or metadata.yaml")
        if not st.odom:
            raise GridError("--odom", "ID=TOPIC odometry of each carrier (the scans' poses)", "none")
        ids = [cid for cid, _ in st.odom]
        clouds: dict[str, str] = {}
        for cid, topic in st.cloud_topics:
            if not cid:
                if len(ids) != 1:
                    raise GridError("--cloud-topic", f"ID=TOPIC with several carriers ({', '.join(ids)})", topic)
                cid = ids[0]
            if cid not in ids:
                raise GridError(f"--cloud-topic {cid}={topic}", f"a carrier of --odom ({', '.join(ids)})", f"'{cid}'")
            clouds[cid] = topic
        scans, tracks = C.read_bag_scans(src, clouds, dict(st.odom), st.sensor_offset)
    progress(f"read {len(scans)} scans ({sum(len(s.points) for s in scans)} points) from {src}")
    return None, scans, tracks


def _mapper(st: ImportSettings, scans: list[C.Scan], where: str) -> V.VoxelMapper:
    voxel = V.check_voxel(DEFAULT_VOXEL if st.voxel is None else st.voxel)
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for s in scans:
        pts = s.points
        if st.max_range > 0 and len(pts):  # rays clipped to the range stay within it of the origin
            d = np.linalg.norm(pts - s.origin, axis=1)
            far = d > st.max_range
            if far.any():
                lo = np.minimum(lo, s.origin - st.max_range)
                hi = np.maximum(hi, s.origin + st.max_range)
        for arr in (pts, s.origin[None, :]):
            if len(arr):
                lo = np.minimum(lo, arr.min(axis=0))
                hi = np.maximum(hi, arr.max(axis=0))
    if not np.all(np.isfinite(lo)):
        raise GridError(where, "scans with points", "none")
    return V.VoxelMapper(lo, hi, voxel, _params(st), st.max_range, source=where)


def import_3d(st: ImportSettings, progress: Callable[[str], None] = print) -> ImportResult:
    """Everything the 3D import writes, computed; nothing written yet.

    Raises:
        GridError: bad input, naming the file, field or topic.
    """
    V.check_keep(st.keep_above, st.keep_below)
    if st.neighbours not in V.NEIGHBOURS:
        raise GridError("--neighbours", "6 or 26", str(st.neighbours))
    if st.voxel is not None:
        V.check_voxel(st.voxel)
    grid, scans, tracks = _load(st, progress)
    given = read_routes_3d(st.routes) if st.routes else []
    if not given and not tracks:
        raise GridError("--routes", "ROUTES.yaml with the carriers' paths, or --odom ID=TOPIC (bag) / ID=FILE (folder)",
                        "neither")
    passengers = dict(st.passengers)
    ids = [r.id for r, _ in given] + list(tracks)
    if len(set(ids)) != len(ids):
        raise GridError("--odom/--routes", "each carrier once", f"carriers {ids}")
    for cid in passengers:
        if cid not in ids:
            raise GridError(f"--passengers {cid}", f"a carrier id ({', '.join(ids)})", f"unknown carrier '{cid}'")

    mapper = None
    if scans is not None:
        mapper = _mapper(st, scans, str(st.source))
        progress(f"voxel map: {mapper.logodds.shape[0]} x {mapper.logodds.shape[1]} x {mapper.logodds.shape[2]} "
                 f"voxels of {mapper.resolution:g} m")
        needs_floor = any(z is None for _, z in given)
        if not st.replay or needs_floor:
            for s in scans:
                mapper.insert(s.points, s.origin)
            grid = mapper.grid()
    # routes with their z
    routes: list[tuple[Route, np.ndarray]] = []
    for r, z in given:
        if z is None:
            assert grid is not None
            z = np.full(len(r.poses), floor_under(grid, r.poses[0, 1], r.poses[0, 2], f"{r.where}[0]"))
        routes.append((Route(r.id, passengers.get(r.id, r.passengers), r.poses, r.where), np.asarray(z, dtype=float)))
    src_odom = dict(st.odom)
    for cid, tr in tracks.items():
        routes.append((Route(cid, passengers.get(cid, 1), tr[:, :3], f"{st.source}: {src_odom[cid]}"), tr[:, 3]))

    # storeys and their 2D worlds (built from the final map when it is known, else after replay)
    bases = {r.id: float(np.median(z)) for r, z in routes}
    levels, of = storeys_of(bases)

    def candidates_on(g3: V.VoxelGrid) -> tuple[list[G.OccupancyGrid], list[Candidates], list[np.ndarray]]:
        grids = [storey_grid(g3, b) for b in levels]
        tol_default = 0.5 * g3.resolution
        cands, heights = [], []
        for r, z in routes:
            c = checked_candidates(grids[of[r.id]], r, st.stage_spacing, st.stages,
                                   tol_default if st.path_tolerance is None else st.path_tolerance)
            cands.append(c)
            heights.append(np.interp(c.times, r.poses[:, 0], z))
        return grids, cands, heights

    if st.replay:
        assert mapper is not None and scans is not None
        # the candidates depend on the final map only where a route's simplification would cut
        # a wall: value them on the unchecked candidates, and again if the checked ones differ
        want = _positions(routes, st)
        fresh = mapper if grid is None else _mapper(st, scans, str(st.source))
        values, grid, early = _replay(st, scans, fresh, want)
        if early:
            progress(f"{early} candidate points precede the first scan: their value is 0")
    assert grid is not None
    sgrids, cands, heights = candidates_on(grid)
    counter = V.FrontierCounter3D(grid, st.neighbours)
    frontier_total = len(counter)
    if frontier_total == 0:
        c = grid.counts()
        raise GridError(grid.source or str(st.source), "a map with at least one frontier voxel (a free voxel next to an "
                        "unknown one)", "none" + (" (no free voxel)" if not c["free"] else ""))
    if st.replay:
        got = [np.column_stack([c.times, c.points, h]) for c, h in zip(cands, heights)]
        if any(a.shape != b.shape or not np.allclose(a, b, atol=1e-9) for a, b in zip(got, want)):
            values, _, _ = _replay(st, scans, _mapper(st, scans, str(st.source)), got)
        for ci, c in enumerate(cands):
            c.values = values[ci]
    else:
        for ci, c in enumerate(cands):
            c.values = counter.count(np.column_stack([c.points, heights[ci]]), st.radius, st.keep_above, st.keep_below)
    interval, n_stages = schedule(st, cands)

    walls_by = [G.wall_lines(g, st.wall_tolerance) for g in sgrids]
    segs_by = [np.concatenate([np.column_stack([w[:-1], w[1:]]) for w in walls]) if walls else np.zeros((0, 4))
               for walls in walls_by]
    if st.carrier_radius is not None:
        body = st.carrier_radius
    else:
        body = min(_carrier_radius([c for c, (r, _) in zip(cands, routes) if of[r.id] == k], segs_by[k])
                   for k in range(len(levels)) if any(of[r.id] == k for r, _ in routes))
    observed = np.concatenate([c.values for c in cands])
    prior = fit_prior(observed, st.prior)
    name = st.name or Path(st.out).name.split(".")[0]
    src = Path(st.source)
    # a .bt source is the map as it is: written beside the scenario unchanged
    data = src.read_bytes() if src.suffix.lower() == ".bt" and scans is None else V.octomap_bytes(grid)
    digest = hashlib.sha256(data).hexdigest()
    text = _scenario_text(st, name, grid, levels, walls_by, cands, of, (interval, n_stages, body), prior, digest)
    report = {
        "frontier_voxels": frontier_total,
        "carriers": {c.route.id: [{"t": float(t), "x": float(p[0]), "y": float(p[1]), "z": float(z), "value": int(v)}
                                  for t, p, z, v in zip(c.times, c.points, h, c.values)]
                     for c, h in zip(cands, heights)},
        "mode": "replay" if st.replay else "static",
        "radius": st.radius,
        "keep_above": st.keep_above,
        "keep_below": st.keep_below,
        "neighbours": st.neighbours,
        "voxel": grid.resolution,
        "scans": 0 if scans is None else len(scans),
        "storeys": [{"name": f"s{k}", "base": b, "carriers": [r.id for r, _ in routes if of[r.id] == k]}
                    for k, b in enumerate(levels)],
        "stage_interval": interval,
        "stages": n_stages,
        "first_stage": {c.route.id: c.offset for c in cands},
        "prior": prior,
    }
    counts = grid.counts()
    summary = [f"{len(cands)} carriers on {len(levels)} storeys, {n_stages} stages every {interval:g} s; "
               + ", ".join(f"{c.route.id}: {len(c.points)} points (stages {c.offset}..{c.offset + len(c.points) - 1})"
                           for c in cands),
               f"map {grid.shape[0]} x {grid.shape[1]} x {grid.shape[2]} voxels of {grid.resolution:g} m "
               f"({counts['free']} free, {counts['occupied']} occupied), {frontier_total} frontier voxels "
               f"({st.neighbours} neighbours); walls " + ", ".join(f"s{k} {len(w)} outlines" for k, w in enumerate(walls_by))
               + f"; carrier radius {body:.3g} m",
               f"values ({'replay: the scans up to each time' if st.replay else 'static map'}, radius {st.radius:g} m, "
               f"kept above {st.keep_above:g} m / below {st.keep_below:g} m): mean {observed.mean():.2f}, "
               f"max {int(observed.max())}; prior {prior}"]
    return ImportResult(text, report, None, summary, octomap=data)


def _replay(st: ImportSettings, scans: list[C.Scan], mapper: V.VoxelMapper, points: list[np.ndarray]
            ) -> tuple[list[np.ndarray], V.VoxelGrid, int]:
    """Each candidate's value in the map of the scans stamped at or before its time: (values per
    carrier, the final map, candidates before the first scan). ``points``: per carrier float
    ``[n, 4]`` (t, x, y, z)."""
    order = sorted((float(p[k, 0]), ci, k) for ci, p in enumerate(points) for k in range(len(p)))
    values = [np.zeros(len(p), dtype=np.int64) for p in points]
    s_i = early = 0
    for t, ci, k in order:
        while s_i < len(scans) and scans[s_i].stamp <= t:
            mapper.insert(scans[s_i].points, scans[s_i].origin)
            s_i += 1
        if s_i == 0:
            early += 1
            continue
        values[ci][k] = mapper.value(points[ci][k, 1:], st.radius, st.neighbours, st.keep_above, st.keep_below)
    for s in scans[s_i:]:
        mapper.insert(s.points, s.origin)
    return values, mapper.grid(), early


def _positions(routes: list[tuple[Route, np.ndarray]], st: ImportSettings) -> list[np.ndarray]:
    from world.importer import candidates

    tol = (0.5 * (DEFAULT_VOXEL if st.voxel is None else st.voxel)) if st.path_tolerance is None else st.path_tolerance
    out = []
    for r, z in routes:
        c = candidates(r, st.stage_spacing, st.stages, tol)
        out.append(np.column_stack([c.times, c.points, np.interp(c.times, r.poses[:, 0], z)]))
    return out


def _scenario_text(st: ImportSettings, name: str, grid: V.VoxelGrid, levels: list[float], walls_by: list,
                   cands: list[Candidates], of: dict[str, int], timing: tuple[float, int, float],
                   prior: dict, digest: str) -> str:
    interval, n_stages, body = timing  # stage interval (s), stages, carrier radius (m)
    stem = Path(st.out).name.split(".")[0]
    x0, y0, _, x1, y1, _ = grid.extent
    pad = grid.resolution
    lines = [
        f"# Imported by python -m world import from {st.source}"
        + (f" with routes {st.routes}" if st.routes else "") + f" ({'replay' if st.replay else 'static'}, 3D).",
        f"name: {json.dumps(name)}",
        f"seed: {int(st.seed)}",
        "map:",
        f"  bounds: [{_num(x0 - pad)}, {_num(y0 - pad)}, {_num(x1 + pad)}, {_num(y1 + pad)}]",
        f"  voxels: {{file: {stem}.map.bt, sha256: {digest}, neighbours: {st.neighbours}, "
        f"keep_above: {_num(st.keep_above)}, keep_below: {_num(st.keep_below)}}}",
        f"  # each storey's walls: the occupied voxels {WALL_BAND[0]:g}..{WALL_BAND[1]:g} m above its base "
        "(world.import3d.storey_grid), traced by world.grid.wall_lines",
        "  storeys:",
    ]
    for k, (base, walls) in enumerate(zip(levels, walls_by)):
        lines.append(f"    - name: s{k}")
        lines.append(f"      base: {_num(base)}")
        lines.append("      walls:" + ("" if walls else " []"))
        lines += ["        - [" + ", ".join(f"[{x:.4f}, {y:.4f}]" for x, y in w) + "]" for w in walls]
    lines.append("features:")
    lines.append("  # the paper's value at each candidate point (frontier voxels within the radius, height-filtered)")
    lines.append("  replay:")
    for c in cands:
        row = ["null"] * n_stages
        for k, v in enumerate(c.values):
            row[c.offset + k] = str(int(v))
        lines.append(f"    {c.route.id}: [{', '.join(row)}]")
    lines += [f"sensing_radius: {_num(st.radius)}", f"stage_interval: {_num(interval)}", f"stages: {n_stages}"]
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
        lines.append(f"    storey: s{of[c.route.id]}")
        lines.append(f"    passengers: {c.route.passengers}")
        lines.append(f"    start_time: {_num(start)}")
        lines.append(f"    stop_time: {_num(stop)}")
        lines.append(f"    speed: {_num(c.spacing / interval)}")
        lines.append("    waypoints: [" + ", ".join(f"[{_num(x)}, {_num(y)}]" for x, y in c.path) + "]")
    return "\n".join(lines) + "\n"


def write_outputs_3d(st: ImportSettings, result: ImportResult) -> list[str]:
    """Write the scenario, its OctoMap and the report, all or none; the scenario is loaded back
    and its stages checked against the candidates first."""
    from world.importer import _self_check
    from world.scenario import ScenarioError, load_scenario
    from world.stages import stage_geometry

    assert result.octomap is not None
    out = Path(st.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    stem = out.name.split(".")[0]
    bt = out.parent / f"{stem}.map.bt"
    finals = [out, bt] + ([Path(st.report)] if st.report else [])
    temps = [p.with_name(f".{p.name}.{os.getpid()}.tmp") for p in finals]
    scratch = out.parent / f".import-{os.getpid()}"
    try:
        scratch.mkdir(exist_ok=True)
        (scratch / bt.name).write_bytes(result.octomap)
        (scratch / out.name).write_text(result.scenario_text, encoding="utf-8")
        try:
            scenario = load_scenario(scratch / out.name)
        except ScenarioError as err:
            raise GridError(str(out), "an imported scenario that loads", err.problems[0]) from None
        _self_check(scenario, result.report, stage_geometry(scenario))
        os.replace(scratch / bt.name, temps[1])
        os.replace(scratch / out.name, temps[0])
        if st.report:
            temps[2].write_text(json.dumps(result.report, indent=1) + "\n", encoding="utf-8")
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
