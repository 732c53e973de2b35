"""A SLAM map grows the way a real one does: each snapshot larger than the last, its origin moving
(and turned), so the same place is another cell in every snapshot. The replayed value of a
candidate must still be the frontier cells within the radius in the latest snapshot, counted in
the map frame; and a localiser's PoseWithCovarianceStamped is a trajectory like any other."""
from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
RES = 0.1


def _grid_msg(T, stamp, data, origin):
    x, y, yaw = origin
    sec = int(math.floor(stamp))
    return T["nav_msgs/msg/OccupancyGrid"](
        header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=int((stamp - sec) * 1e9)),
                                        frame_id="map"),
        info=T["nav_msgs/msg/MapMetaData"](
            map_load_time=T["builtin_interfaces/msg/Time"](sec=0, nanosec=0), resolution=RES,
            width=data.shape[1], height=data.shape[0],
            origin=T["geometry_msgs/msg/Pose"](
                position=T["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
                orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)))),
        data=data.reshape(-1))


def _snapshot(k: int):
    """Snapshot k: a (40 + 10k) x (40 + 10k)-cell grid whose origin sits 0.5k m further south-west
    each time, turned by 0.1k rad; known (free) inside a disc of radius 1 + k m round the map
    point (1, 1), unknown elsewhere."""
    n = 40 + 10 * k
    origin = (-0.5 * k, -0.5 * k, 0.1 * k)
    c, s = math.cos(origin[2]), math.sin(origin[2])
    rows, cols = np.mgrid[0:n, 0:n]
    lx, ly = (cols + 0.5) * RES, (rows + 0.5) * RES
    wx, wy = origin[0] + c * lx - s * ly, origin[1] + s * lx + c * ly
    data = np.where(np.hypot(wx - 1.0, wy - 1.0) <= 1.0 + k, 0, -1).astype(np.int8)
    return origin, data, np.column_stack([wx.ravel(), wy.ravel()]), data.ravel()


def _frontier_centres(data: np.ndarray, centres: np.ndarray) -> np.ndarray:
    n = data.shape[0]
    pad = np.pad(data == -1, 1)
    near = np.zeros_like(pad[1:-1, 1:-1])
    for dr in (0, 1, 2):
        for dc in (0, 1, 2):
            near |= pad[dr:dr + n, dc:dc + n]
    return centres[((data == 0) & near).ravel()]


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_values_follow_a_growing_moving_turning_map(tmp_path, storage):
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    bag = tmp_path / "bag"
    snaps = [(2.0 * k, *_snapshot(k)) for k in range(4)]
    # a straight drive from (1, 1) east at 0.25 m/s, stamped 0..8 s
    poses = [(0.25 * i, 1.0 + 0.0625 * i, 1.0) for i in range(33)]
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    kind = "geometry_msgs/msg/PoseWithCovarianceStamped"
    with Writer(bag, version=9, storage_plugin=plugin) as w:
        cmap = w.add_connection("/map", "nav_msgs/msg/OccupancyGrid", typestore=ts)
        cpose = w.add_connection("/amcl_pose", kind, typestore=ts)
        msgs = [(int(t * 1e9), cmap, ts.serialize_cdr(_grid_msg(T, t, d, o), "nav_msgs/msg/OccupancyGrid"))
                for t, o, d, _, _ in snaps]
        for t, x, y in poses:
            sec = int(math.floor(t))
            m = T[kind](header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](
                sec=sec, nanosec=int(round((t - sec) * 1e9))), frame_id="map"),
                pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=T["geometry_msgs/msg/Pose"](
                    position=T["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
                    orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)),
                    covariance=np.zeros(36)))
            msgs.append((int(round(t * 1e9)), cpose, ts.serialize_cdr(m, kind)))
        for t_ns, conn, raw in sorted(msgs, key=lambda m: m[0]):
            w.write(conn, t_ns, raw)
    out, report = tmp_path / "s.yaml", tmp_path / "r.json"
    done = subprocess.run([sys.executable, "-m", "world", "import", str(bag), "--odom", "a=/amcl_pose", "--stages", "9",
                           "--radius", "1.5", "--replay", "--out", str(out), "--report", str(report)],
                          cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    points = json.loads(report.read_text())["carriers"]["a"]
    assert [round(p["t"], 6) for p in points] == [float(k) for k in range(9)]
    seen = set()
    for p in points:
        k = min(int(p["t"] // 2.0), len(snaps) - 1)  # the latest snapshot at or before t
        _, _, data, centres, _ = snaps[k]
        f = _frontier_centres(data, centres)
        want = int((np.hypot(f[:, 0] - p["x"], f[:, 1] - p["y"]) <= 1.5).sum())
        assert p["value"] == want, (p, k)
        seen.add(want)
    assert len(seen) >= 3  # the growth shows in the values
