"""A generated 3D recorded run for tests and benchmarks of the 3D import: a multi-storey
building (floor slabs, outer and inner walls with doors, a shaft through every storey, a
stairwell between storeys, a sealed room nobody can see into) as solid voxels, carriers driving
its storeys, and simulated LiDAR scans ray cast in it, every part from one seed.

    python -m tools.synthetic_3d OUT_DIR [--storeys 2] [--size 24x14] [--carriers 2] [--scans 40]
        [--points 4000] [--range 40] [--family offices|atrium] [--seed 0] [--bag]

writes ``OUT_DIR/scans/`` (one PCD per scan, named by its stamp, points in the sensor frame, and
``poses.txt``: the sensor's pose per stamp, TUM format), ``OUT_DIR/c<i>.txt`` (carrier i's base
trajectory, TUM format), ``OUT_DIR/routes.yaml`` ([x, y, z] paths) and with ``--bag`` a ROS 2
bag ``OUT_DIR/bag/`` (``/c<i>/points`` sensor_msgs/msg/PointCloud2 in frame ``c<i>/lidar``,
``/c<i>/odom`` nav_msgs/msg/Odometry, the lidar's mounting on ``/tf_static``).
``--family offices`` puts an inner wall with a door on each storey; ``--family atrium`` cuts a
large opening through every slab instead.
"""
from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numba
import numpy as np

#: Carrier geometry (m): the lidar sits this high above the carrier's base.
SENSOR_HEIGHT = 0.5
STOREY_HEIGHT = 3.0
SLAB = 0.2
WALL = 0.2
FAMILIES = ("offices", "atrium")


@dataclass
class Building:
    """solid: bool ``[X, Y, Z]`` voxels of ``resolution`` m from ``lower`` (m, the corner of
    voxel 0); storey k's floor top at ``k x STOREY_HEIGHT + SLAB``; shaft and stairwell as
    (x0, y0, x1, y1) m; sealed: the sealed room's box (x0, y0, z0, x1, y1, z1) m."""

    solid: np.ndarray
    resolution: float
    lower: np.ndarray
    storeys: int
    size: tuple[float, float]
    shaft: tuple[float, float, float, float]
    stairs: tuple[float, float, float, float]
    sealed: tuple[float, float, float, float, float, float]
    corridor_y: float

    def floor(self, k: int) -> float:
        return k * STOREY_HEIGHT + SLAB


def building(rng: np.random.Generator, storeys: int = 2, size: tuple[float, float] = (24.0, 14.0),
             resolution: float = 0.1, family: str = "offices") -> Building:
    W, D = size
    H = storeys * STOREY_HEIGHT + SLAB
    lower = np.array([-1.0, -1.0, -1.0])
    shape = tuple(int(math.ceil(v / resolution)) for v in (W + 2, D + 2, H + 2))
    solid = np.zeros(shape, dtype=bool)

    def box(x0, y0, z0, x1, y1, z1, value=True):
        a = np.floor((np.array([x0, y0, z0]) - lower) / resolution + 1e-9).astype(int)
        b = np.ceil((np.array([x1, y1, z1]) - lower) / resolution - 1e-9).astype(int)
        solid[a[0]:b[0], a[1]:b[1], a[2]:b[2]] = value

    for k in range(storeys + 1):  # slabs; the top one is the roof
        box(0, 0, k * STOREY_HEIGHT, W, D, k * STOREY_HEIGHT + SLAB)
    box(0, 0, 0, WALL, D, H), box(W - WALL, 0, 0, W, D, H)
    box(0, 0, 0, W, WALL, H), box(0, D - WALL, 0, W, D, H)
    corridor_y = D / 2
    sx = float(rng.uniform(3, W / 2 - 4))
    shaft = (sx, D - 4.0, sx + 2.0, D - 2.0)
    tx = float(rng.uniform(W / 2 + 1, W - 7))
    stairs = (tx, 1.5, tx + 4.0, 3.5)
    for k in range(1, storeys + 1):  # the shaft opens every slab above the ground, up through the roof
        box(shaft[0], shaft[1], k * STOREY_HEIGHT, shaft[2], shaft[3], k * STOREY_HEIGHT + SLAB, False)
    for k in range(1, storeys):  # a stairwell from each storey to the next
        z0 = (k - 1) * STOREY_HEIGHT + SLAB
        box(stairs[0], stairs[1], k * STOREY_HEIGHT, stairs[2], stairs[3], k * STOREY_HEIGHT + SLAB, False)
        steps = 10
        for s in range(steps):
            box(stairs[0] + s * 0.4, stairs[1], z0, stairs[0] + (s + 1) * 0.4, stairs[3], z0 + (s + 1) * 0.3)
    if family == "atrium":
        for k in range(1, storeys):
            box(W / 2 - 2, D / 2 + 1.5, k * STOREY_HEIGHT, W / 2 + 2, D / 2 + 4, k * STOREY_HEIGHT + SLAB, False)
    for k in range(storeys):
        z0, z1 = k * STOREY_HEIGHT, (k + 1) * STOREY_HEIGHT
        # a wall along the corridor's north side with a door per storey (offices), shaft side open
        if family == "offices":
            door = float(rng.uniform(W / 2 + 1, W - 3))
            box(WALL, corridor_y + 1.0, z0, door, corridor_y + 1.0 + WALL, z1)
            box(door + 1.2, corridor_y + 1.0, z0, W - WALL, corridor_y + 1.0 + WALL, z1)
    # a sealed room on the ground storey, walls all round and its own ceiling
    sealed = (W - 5.0, D - 5.0, SLAB, W - 1.0, D - 1.0, STOREY_HEIGHT)
    box(sealed[0] - WALL, sealed[1] - WALL, 0, sealed[3] + WALL, sealed[4] + WALL, STOREY_HEIGHT + SLAB)
    box(*sealed, value=False)
    return Building(solid, resolution, lower, storeys, (W, D), shaft, stairs, sealed, corridor_y)


@numba.njit(cache=True)
def _cast(solid, lower, res, origin, dirs, max_range, out):
    """First solid voxel along each ray (Amanatides-Woo); out[i] = the point 1e-4 m inside it,
    NaN where nothing is hit within max_range."""
    X, Y, Z = solid.shape
    for r in range(dirs.shape[0]):
        d = dirs[r]
        idx = np.empty(3, dtype=np.int64)
        step = np.zeros(3, dtype=np.int64)
        tmax = np.empty(3)
        tdelta = np.empty(3)
        for a in range(3):
            idx[a] = int(math.floor((origin[a] - lower[a]) / res))
            if d[a] > 0:
                step[a] = 1
                tmax[a] = (lower[a] + (idx[a] + 1) * res - origin[a]) / d[a]
                tdelta[a] = res / d[a]
            elif d[a] < 0:
                step[a] = -1
                tmax[a] = (lower[a] + idx[a] * res - origin[a]) / d[a]
                tdelta[a] = -res / d[a]
            else:
                tmax[a] = 1e300
                tdelta[a] = 1e300
        out[r, :] = np.nan
        t = 0.0
        while t <= max_range:
            if idx[0] < 0 or idx[1] < 0 or idx[2] < 0 or idx[0] >= X or idx[1] >= Y or idx[2] >= Z:
                break
            if solid[idx[0], idx[1], idx[2]]:
                for a in range(3):
                    out[r, a] = origin[a] + d[a] * (t + 1e-4)
                break
            a = 0
            if tmax[1] < tmax[a]:
                a = 1
            if tmax[2] < tmax[a]:
                a = 2
            t = tmax[a]
            tmax[a] += tdelta[a]
            idx[a] += step[a]


def lidar(b: Building, origin, n: int, max_range: float, rng: np.random.Generator) -> np.ndarray:
    """float ``[P, 3]`` returns (map frame, m) of ``n`` rays in uniformly random directions from
    ``origin``; rays without a return within ``max_range`` give no point."""
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    out = np.empty((n, 3))
    _cast(b.solid, b.lower.astype(float), float(b.resolution), np.asarray(origin, dtype=float), d, float(max_range), out)
    return out[~np.isnan(out[:, 0])]


@dataclass
class Run3D:
    """routes: carrier id -> float ``[K, 4]`` (t s, x, y, z m: the base); scans: (stamp s, carrier
    id, sensor origin ``(3,)`` m, points float ``[P, 3]`` in the map frame)."""

    building: Building
    routes: dict[str, np.ndarray]
    scans: list[tuple[float, str, np.ndarray, np.ndarray]]


def run(seed: int = 0, storeys: int = 2, size=(24.0, 14.0), carriers: int = 2, scans: int = 40,
        points: int = 4000, max_range: float = 40.0, family: str = "offices", resolution: float = 0.1,
        speed: float = 1.0) -> Run3D:
    """Carrier i drives the corridor of storey ``i % storeys`` west to east, starting 5 s after
    carrier i - 1; the scans are spread evenly over the carriers' drives."""
    rng = np.random.default_rng(seed)
    b = building(rng, storeys, size, resolution, family)
    W, _ = b.size
    routes = {}
    for i in range(carriers):
        z = b.floor(i % storeys)
        y = b.corridor_y - 0.3 * (i // storeys)
        xs = np.linspace(1.5, W - 1.5, 12)
        t = 5.0 * i + (xs - xs[0]) / speed
        routes[f"c{i}"] = np.column_stack([t, xs, np.full_like(xs, y), np.full_like(xs, z)])
    out = []
    per = max(1, scans // carriers)
    for cid, r in routes.items():
        for t in np.linspace(r[0, 0], r[-1, 0], per):
            p = np.array([np.interp(t, r[:, 0], r[:, a]) for a in (1, 2, 3)])
            origin = p + [0.0, 0.0, SENSOR_HEIGHT]
            out.append((float(t), cid, origin, lidar(b, origin, points, max_range, rng)))
    out.sort(key=lambda s: (s[0], s[1]))
    for k in range(1, len(out)):  # distinct stamps: a folder names each scan by its stamp
        if out[k][0] <= out[k - 1][0] + 1e-6:
            out[k] = (out[k - 1][0] + 1e-3, *out[k][1:])
    return Run3D(b, routes, out)


def write_pcd(path: Path, pts: np.ndarray, binary: bool = True) -> None:
    """A PCD v0.7 file of float32 x y z (binary, or ascii)."""
    pts = np.asarray(pts, dtype=np.float32)
    head = ("# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\n"
            f"COUNT 1 1 1\nWIDTH {len(pts)}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {len(pts)}\n"
            f"DATA {'binary' if binary else 'ascii'}\n")
    if binary:
        path.write_bytes(head.encode() + pts.tobytes())
    else:
        path.write_text(head + "".join(f"{x:.6f} {y:.6f} {z:.6f}\n" for x, y, z in pts))


def write_ply(path: Path, pts: np.ndarray) -> None:
    """A binary little-endian PLY of float32 x y z vertices."""
    pts = np.asarray(pts, dtype=np.float32)
    head = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(pts)}\nproperty float x\n"
            "property float y\nproperty float z\nend_header\n")
    path.write_bytes(head.encode() + pts.tobytes())


def write_folder(r: Run3D, out: Path, ply_every: int = 0) -> None:
    """scans/<stamp>.pcd (sensor frame: a pure translation from the map here) and
    scans/poses.txt; one carrier's scans only when several carriers share stamps is not an
    issue: every stamp is distinct. ``ply_every``: every k-th scan as PLY instead."""
    d = out / "scans"
    d.mkdir(parents=True, exist_ok=True)
    lines = ["# t x y z qx qy qz qw (the sensor in the map frame)"]
    for k, (t, _, origin, pts) in enumerate(r.scans):
        name = f"{t:.6f}"
        if ply_every and k % ply_every == 0:
            write_ply(d / f"{name}.ply", pts - origin)
        else:
            write_pcd(d / f"{name}.pcd", pts - origin, binary=k % 2 == 0)
        lines.append(f"{name} {origin[0]:.6f} {origin[1]:.6f} {origin[2]:.6f} 0 0 0 1")
    (d / "poses.txt").write_text("\n".join(lines) + "\n")
    for cid, rt in r.routes.items():
        (out / f"{cid}.txt").write_text("".join(f"{t:.6f} {x:.6f} {y:.6f} {z:.6f} 0 0 0 1\n" for t, x, y, z in rt))
    (out / "routes.yaml").write_text("carriers:\n" + "".join(
        f"  - {{id: {cid}, passengers: 2, start: {rt[0, 0]:g}, speed: 1.0, path: "
        f"[{', '.join(f'[{x:g}, {y:g}, {z:g}]' for x, y, z in rt[[0, -1], 1:])}]}}\n" for cid, rt in r.routes.items()))


def write_bag(r: Run3D, out: Path) -> Path:
    """A ROS 2 bag (MCAP): per carrier ``/c<i>/points`` (PointCloud2, frame ``c<i>/lidar``, points
    in the lidar's frame), ``/c<i>/odom`` (Odometry of ``c<i>/base_link`` in ``map``) every 0.5 s,
    and ``/tf_static`` with each lidar's mounting on its base."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    Header, Time = T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]
    Point, Quat = T["geometry_msgs/msg/Point"], T["geometry_msgs/msg/Quaternion"]
    Pose, PoseCov = T["geometry_msgs/msg/Pose"], T["geometry_msgs/msg/PoseWithCovariance"]
    Vec, Twist, TwistCov = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Twist"], T["geometry_msgs/msg/TwistWithCovariance"]
    Odom, PF, PC2 = T["nav_msgs/msg/Odometry"], T["sensor_msgs/msg/PointField"], T["sensor_msgs/msg/PointCloud2"]
    TFM, TF, TS = T["tf2_msgs/msg/TFMessage"], T["geometry_msgs/msg/TransformStamped"], T["geometry_msgs/msg/Transform"]

    def stamp(t):
        sec = int(math.floor(t))
        return Time(sec=sec, nanosec=int(round((t - sec) * 1e9)) % 1_000_000_000)

    path = out / "bag"
    with Writer(path, version=8, storage_plugin=StoragePlugin.MCAP) as w:
        tf = w.add_connection("/tf_static", TFM.__msgtype__, typestore=ts)
        conns = {cid: (w.add_connection(f"/{cid}/points", PC2.__msgtype__, typestore=ts),
                       w.add_connection(f"/{cid}/odom", Odom.__msgtype__, typestore=ts)) for cid in r.routes}
        mounts = [TF(header=Header(stamp=stamp(0.0), frame_id=f"{cid}/base_link"), child_frame_id=f"{cid}/lidar",
                     transform=TS(translation=Vec(x=0.0, y=0.0, z=SENSOR_HEIGHT), rotation=Quat(x=0.0, y=0.0, z=0.0, w=1.0)))
                  for cid in r.routes]
        w.write(tf, 0, ts.serialize_cdr(TFM(transforms=mounts), TFM.__msgtype__))
        events = []
        for cid, rt in r.routes.items():
            for t in np.arange(rt[0, 0], rt[-1, 0] + 1e-9, 0.5):
                p = [float(np.interp(t, rt[:, 0], rt[:, a])) for a in (1, 2, 3)]
                msg = Odom(header=Header(stamp=stamp(t), frame_id="map"), child_frame_id=f"{cid}/base_link",
                           pose=PoseCov(pose=Pose(position=Point(x=p[0], y=p[1], z=p[2]), orientation=Quat(x=0.0, y=0.0, z=0.0, w=1.0)),
                                        covariance=np.zeros(36)),
                           twist=TwistCov(twist=Twist(linear=Vec(x=0.0, y=0.0, z=0.0), angular=Vec(x=0.0, y=0.0, z=0.0)),
                                          covariance=np.zeros(36)))
                events.append((t, conns[cid][1], ts.serialize_cdr(msg, Odom.__msgtype__)))
        fields = [PF(name=n, offset=4 * k, datatype=7, count=1) for k, n in enumerate("xyz")]
        for t, cid, origin, pts in r.scans:
            local = np.column_stack([pts - origin, np.zeros(len(pts))]).astype(np.float32)  # x y z pad
            msg = PC2(header=Header(stamp=stamp(t), frame_id=f"{cid}/lidar"), height=1, width=len(pts), fields=fields,
                      is_bigendian=False, point_step=16, row_step=16 * len(pts),
                      data=np.frombuffer(local.tobytes(), dtype=np.uint8), is_dense=True)
            events.append((t, conns[cid][0], ts.serialize_cdr(msg, PC2.__msgtype__)))
        for t, conn, raw in sorted(events, key=lambda e: e[0]):
            w.write(conn, int(t * 1e9) + 1, raw)
    return path


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m tools.synthetic_3d", description=__doc__.split("\n\n")[0])
    p.add_argument("out")
    p.add_argument("--storeys", type=int, default=2)
    p.add_argument("--size", default="24x14")
    p.add_argument("--carriers", type=int, default=2)
    p.add_argument("--scans", type=int, default=40)
    p.add_argument("--points", type=int, default=4000)
    p.add_argument("--range", type=float, default=40.0)
    p.add_argument("--family", choices=FAMILIES, default="offices")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--bag", action="store_true")
    a = p.parse_args(argv)
    w, d = (float(v) for v in a.size.split("x"))
    r = run(a.seed, a.storeys, (w, d), a.carriers, a.scans, a.points, a.range, a.family)
    out = Path(a.out)
    write_folder(r, out)
    if a.bag:
        write_bag(r, out)
    print(f"wrote {out}: {len(r.scans)} scans, {sum(len(s[3]) for s in r.scans)} points")
    return 0


if __name__ == "__main__":
    sys.exit(main())
