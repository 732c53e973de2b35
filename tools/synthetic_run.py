"""A generated recorded run for tests and benchmarks of ``python -m world import``: a floor plan
(rooms and corridors, or caves) as an occupancy grid, carriers driving routes through it, and the
map their sensors reveal growing over time, written as a map_server map and as ROS 2 bags (MCAP
or sqlite3, by rosbags), every part from one seed.

    python -m tools.synthetic_run OUT_DIR [--cells 600x400] [--resolution 0.05] [--snapshots 16]
        [--carriers 3] [--seed 0] [--storage mcap|sqlite3] [--family rooms|caves]

writes ``OUT_DIR/map.yaml`` (the map at the end of the run), ``OUT_DIR/bag/`` (maps on ``/map``,
carrier i's poses on ``/c<i>/odom`` as nav_msgs/msg/Odometry, or as
geometry_msgs/msg/PoseStamped on ``/c<i>/pose`` for odd i) and ``OUT_DIR/routes.yaml``.
``--family rooms`` (the default) is a grid of rooms with a door in every wall stretch;
``--family caves`` a cellular automaton's caves (:func:`caves`). Only the floor plan depends on
the family: the routes and maps are drawn the same way on either, from the same stream.
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: Cell values of the ground truth.
FREE, OCCUPIED = 0, 100
#: How far a carrier's sensor reveals the map (m).
REVEAL_RADIUS = 6.0
#: Floor plans ``--family`` may name: rooms and corridors (the default), or caves.
FAMILIES = ("rooms", "caves")
#: Caves: side of a cellular-automaton cell (m), its initial chance of rock, smoothing steps.
CAVE_CELL, CAVE_FILL, CAVE_STEPS = 0.5, 0.45, 5


@dataclass
class SyntheticRun:
    """truth: int8 ``[H, W]`` the fully known floor plan (0 free, 100 occupied); resolution m;
    tracks: per carrier float ``[K, 3]`` (t s, x m, y m); snapshots: (stamp s, int8 ``[H, W]``)
    maps in time order, unknown (-1) where no carrier has looked yet."""

    truth: np.ndarray
    resolution: float
    tracks: dict[str, np.ndarray]
    snapshots: list[tuple[float, np.ndarray]]


def floor_plan(width: int, height: int, rng: np.random.Generator) -> tuple[np.ndarray, list[float], list[float]]:
    """Rooms between corridors: outer wall, walls along a grid of random pitch with a door in
    every wall stretch. Returns (grid, corridor x centres, corridor y centres) in cells."""
    g = np.zeros((height, width), dtype=np.int8)
    g[[0, -1], :] = OCCUPIED
    g[:, [0, -1]] = OCCUPIED
    xs = list(np.cumsum(rng.integers(width // 8, width // 4, size=16)))
    xs = [x for x in xs if x < width - width // 10]
    ys = list(np.cumsum(rng.integers(height // 6, height // 3, size=16)))
    ys = [y for y in ys if y < height - height // 10]
    for x in xs:
        g[:, x] = OCCUPIED
    for y in ys:
        g[y, :] = OCCUPIED
    door = max(6, width // 40)
    bx = [0] + xs + [width - 1]
    by = [0] + ys + [height - 1]
    for x in xs:  # a door in every stretch of a vertical wall
        for lo, hi in zip(by[:-1], by[1:]):
            c = int(rng.integers(lo + door, max(lo + door + 1, hi - 2 * door)))
            g[c:c + 2 * door, x] = FREE
    for y in ys:
        for lo, hi in zip(bx[:-1], bx[1:]):
            c = int(rng.integers(lo + door, max(lo + door + 1, hi - 2 * door)))
            g[y, c:c + 2 * door] = FREE
    g[[0, -1], :] = OCCUPIED
    g[:, [0, -1]] = OCCUPIED
    return g, bx, by


def drivable(truth: np.ndarray) -> np.ndarray:
    """bool ``[H, W]``: the largest 4-connected region of free cells kept 3 cells clear of walls
    (where the carriers' routes run)."""
    from scipy import ndimage

    clear = ndimage.binary_erosion(truth == FREE, iterations=3)
    lab, n = ndimage.label(clear)
    sizes = np.bincount(lab.ravel(), minlength=n + 1)[1:]
    return lab == 1 + int(np.argmax(sizes))


def caves(width: int, height: int, resolution: float, rng: np.random.Generator) -> np.ndarray:
    """Caves: a cellular automaton on cells of CAVE_CELL m (rock with chance CAVE_FILL, then
    CAVE_STEPS steps of the 4-5 rule: rock stays rock with at least 4 rock neighbours of 8 and
    floor turns to rock with at least 5, beyond the edge is rock), interpolated bilinearly to the
    grid and cut at one half, so that walls are smooth curves rather than staircases. Returns
    int8 ``[height, width]`` (0 free, 100 occupied) with an outer wall."""
    from scipy import ndimage

    k = max(1, int(round(CAVE_CELL / resolution)))
    rock = rng.random((-(-height // k), -(-width // k))) < CAVE_FILL
    ring = np.ones((3, 3), dtype=np.uint8)
    ring[1, 1] = 0
    for _ in range(CAVE_STEPS):
        n = ndimage.convolve(rock.astype(np.uint8), ring, mode="constant", cval=1)
        rock = np.where(rock, n >= 4, n >= 5)
    fine = ndimage.zoom(rock.astype(np.float32), k, order=1, mode="nearest", grid_mode=True)[:height, :width]
    g = np.where(fine > 0.5, OCCUPIED, FREE).astype(np.int8)
    g[[0, -1], :] = OCCUPIED
    g[:, [0, -1]] = OCCUPIED
    return g


def _route(region: np.ndarray, cells: np.ndarray, res: float, rng: np.random.Generator,
           length_cells: int) -> np.ndarray:
    """A random walk of ``length_cells`` cells through ``region`` (4-connected moves) from a
    random one of ``cells`` (``np.argwhere(region)``), as cell centres (m)."""
    h, w = region.shape
    here = cells[rng.integers(len(cells))]
    r, c = int(here[0]), int(here[1])
    out = np.empty((length_cells, 2), dtype=np.int64)
    out[0] = r, c
    k = 1
    step = ((0, 1), (1, 0), (0, -1), (-1, 0))
    d = int(rng.integers(4))
    # one draw per move (plus one per turn), in the original order: the walk is data dependent
    while k < length_cells:
        if rng.random() < 0.05:
            d = int(rng.integers(4))
        nr, nc = r + step[d][0], c + step[d][1]
        if not (0 <= nr < h and 0 <= nc < w) or not region[nr, nc]:
            d = int(rng.integers(4))
            continue
        r, c = nr, nc
        out[k] = r, c
        k += 1
    rc = out.astype(float)
    return np.column_stack([(rc[:, 1] + 0.5) * res, (rc[:, 0] + 0.5) * res])


def generate(width: int = 600, height: int = 400, resolution: float = 0.05, carriers: int = 3,
             snapshots: int = 16, seed: int = 0, speed: float = 0.5, pose_rate: float = 10.0,
             family: str = "rooms") -> SyntheticRun:
    """A recorded run on a floor plan of ``family`` (FAMILIES): carrier i starts 20 i s after the
    first, drives its route at ``speed`` (poses at ``pose_rate`` Hz), and the map at each of
    ``snapshots`` stamps knows every cell within REVEAL_RADIUS of a pose so far (no line of
    sight: enough for a test)."""
    if family not in FAMILIES:
        raise ValueError(f"family: expected one of {', '.join(FAMILIES)}, found {family!r}")
    rng = np.random.default_rng(seed)
    truth = floor_plan(width, height, rng)[0] if family == "rooms" else caves(width, height, resolution, rng)
    length = int(0.8 * (width + height))
    region = drivable(truth)
    cells = np.argwhere(region)
    tracks = {}
    for i in range(carriers):
        xy = _route(region, cells, resolution, rng, length)[:: max(1, int(round(speed / pose_rate / resolution)))]
        t = 20.0 * i + np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))]) / speed
        tracks[f"c{i}"] = np.column_stack([t, xy])
    end = max(float(tr[-1, 0]) for tr in tracks.values())
    stamps = np.linspace(0.0, end, snapshots)
    known = np.zeros(truth.shape, dtype=bool)
    h, w = truth.shape
    rr = int(np.ceil(REVEAL_RADIUS / resolution))
    dy, dx = np.mgrid[-rr:rr + 1, -rr:rr + 1]
    disc = dy * dy + dx * dx <= rr * rr
    done = {cid: 0 for cid in tracks}
    out = []
    for stamp in stamps:
        for cid, tr in tracks.items():
            upto = int(np.searchsorted(tr[:, 0], stamp, side="right"))
            for x, y in tr[done[cid]:upto:5, 1:]:
                c, r = int(x / resolution), int(y / resolution)
                r0, r1, c0, c1 = max(0, r - rr), min(h, r + rr + 1), max(0, c - rr), min(w, c + rr + 1)
                known[r0:r1, c0:c1] |= disc[r0 - r + rr:r1 - r + rr, c0 - c + rr:c1 - c + rr]
            done[cid] = max(done[cid], upto)
        out.append((float(stamp), np.where(known, truth, -1).astype(np.int8)))
    return SyntheticRun(truth, resolution, tracks, out)


def write_map(run: SyntheticRun, path: Path, grid=None) -> None:
    """The fully explored map (or ``grid``) as a map_server map."""
    from world.grid import OccupancyGrid, write_map_yaml

    write_map_yaml(grid or OccupancyGrid(run.truth, run.resolution), path)


def write_routes(run: SyntheticRun, path: Path) -> None:
    lines = ["carriers:"]
    for cid, tr in run.tracks.items():
        speed = float(np.hypot(*np.diff(tr[:2, 1:], axis=0).T)[0] / (tr[1, 0] - tr[0, 0]))
        pts = ", ".join(f"[{float(x)!r}, {float(y)!r}]" for x, y in tr[:, 1:])
        lines.append(f"  - {{id: {cid}, passengers: 2, start: {float(tr[0, 0])!r}, speed: {speed!r}, path: [{pts}]}}")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def write_bag(run: SyntheticRun, path: Path, storage: str = "mcap", map_topic: str = "/map") -> dict[str, str]:
    """The run as a ROS 2 bag; returns carrier id -> its pose topic. Odd carriers publish
    PoseStamped, even ones Odometry."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3

    def header(t, frame="map"):
        sec = int(np.floor(t))
        return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=int(round((t - sec) * 1e9))),
                                        frame_id=frame)

    def pose(x, y):
        return T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=0.0),
                                           orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0))

    topics = {}
    messages = []  # (t ns, connection key, message, type)
    with Writer(path, version=9, storage_plugin=plugin) as writer:
        conns = {"map": writer.add_connection(map_topic, "nav_msgs/msg/OccupancyGrid", typestore=ts)}
        for i, cid in enumerate(run.tracks):
            kind = "nav_msgs/msg/Odometry" if i % 2 == 0 else "geometry_msgs/msg/PoseStamped"
            topic = f"/{cid}/odom" if i % 2 == 0 else f"/{cid}/pose"
            topics[cid] = topic
            conns[cid] = (writer.add_connection(topic, kind, typestore=ts), kind)
        h, w = run.truth.shape
        for stamp, data in run.snapshots:
            info = T["nav_msgs/msg/MapMetaData"](
                map_load_time=T["builtin_interfaces/msg/Time"](sec=0, nanosec=0), resolution=float(run.resolution),
                width=w, height=h, origin=pose(0.0, 0.0))
            msg = T["nav_msgs/msg/OccupancyGrid"](header=header(stamp), info=info, data=data.reshape(-1))
            messages.append((int(round(stamp * 1e9)), "map", msg, "nav_msgs/msg/OccupancyGrid"))
        for cid, tr in run.tracks.items():
            _, kind = conns[cid]
            for t, x, y in tr:
                if kind == "nav_msgs/msg/Odometry":
                    cov = np.zeros(36)
                    msg = T[kind](header=header(t, "odom"), child_frame_id="base_link",
                                  pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose(x, y), covariance=cov),
                                  twist=T["geometry_msgs/msg/TwistWithCovariance"](
                                      twist=T["geometry_msgs/msg/Twist"](
                                          linear=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                                          angular=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)),
                                      covariance=cov))
                else:
                    msg = T[kind](header=header(t), pose=pose(x, y))
                messages.append((int(round(t * 1e9)), cid, msg, kind))
        messages.sort(key=lambda m: m[0])
        for t_ns, key, msg, kind in messages:
            conn = conns[key] if key == "map" else conns[key][0]
            writer.write(conn, t_ns, ts.serialize_cdr(msg, kind))
    return topics


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m tools.synthetic_run", description=__doc__.splitlines()[0])
    p.add_argument("out")
    p.add_argument("--cells", default="600x400", help="W x H cells (default 600x400)")
    p.add_argument("--resolution", type=float, default=0.05)
    p.add_argument("--snapshots", type=int, default=16)
    p.add_argument("--carriers", type=int, default=3)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap")
    p.add_argument("--family", choices=FAMILIES, default="rooms",
                   help="floor plan: rooms and corridors (default) or cellular-automaton caves")
    a = p.parse_args(argv)
    w, h = (int(v) for v in a.cells.lower().split("x"))
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    run = generate(w, h, a.resolution, a.carriers, a.snapshots, a.seed, family=a.family)
    from world.grid import OccupancyGrid

    write_map(run, out / "map.yaml", OccupancyGrid(run.snapshots[-1][1], run.resolution))  # the map at the end
    write_routes(run, out / "routes.yaml")
    topics = write_bag(run, out / "bag", a.storage)
    print("odom: " + " ".join(f"--odom {cid}={t}" for cid, t in topics.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
