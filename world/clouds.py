"""LiDAR scans for the 3D import: PCD and PLY files, TUM trajectories, and
``sensor_msgs/msg/PointCloud2`` with ``nav_msgs/msg/Odometry`` and ``/tf_static`` in ROS 2 bags.

A :class:`Scan` is a stamp, the sensor's origin in the map frame and its returns in the map
frame. How a scan's pose is found:

* a folder: each scan file's stem is its stamp (s); ``poses.txt`` beside them is the sensor's
  trajectory in the map frame in TUM format (``t x y z qx qy qz qw`` per line, ``#`` comments),
  interpolated at the stamp (positions linearly, orientations by slerp); a scan's points are in
  the sensor's frame;
* a bag: a PointCloud2 on a carrier's cloud topic, stamped by its header, in its
  ``header.frame_id``. If that frame is the odometry's own frame (``map``, say), the points are
  in the map frame already; otherwise they are in the sensor's frame and the sensor's pose is
  the carrier's odometry (``pose.pose``, interpolated at the stamp) composed with the sensor's
  mounting: the chain of ``/tf_static`` transforms from the odometry's ``child_frame_id`` to the
  cloud's frame, or, when ``/tf_static`` has none, the fixed offset given
  (``--sensor-offset X Y Z``, metres in the base frame, no rotation). Dynamic ``/tf`` is not read.

A stamp outside its trajectory's first and last pose has no pose: refused, naming the scan.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from world.grid import GridError

CLOUD_TYPE = "sensor_msgs/msg/PointCloud2"
ODOM_TYPE = "nav_msgs/msg/Odometry"
SCAN_SUFFIXES = (".pcd", ".ply")
POSES_FILE = "poses.txt"
#: PointField datatypes of x, y, z this reader takes: FLOAT32 (7) and FLOAT64 (8).
_FIELD_TYPES = {7: "f4", 8: "f8"}


@dataclass
class Scan:
    """stamp (s), origin float ``(3,)`` (m, map frame), points float32 ``[P, 3]`` (m, map frame),
    where it came from."""

    stamp: float
    origin: np.ndarray
    points: np.ndarray
    where: str


# --------------------------------------------------------------------------- poses


def quat_matrix(q) -> np.ndarray:
    """3 x 3 rotation of a unit quaternion (x, y, z, w)."""
    x, y, z, w = np.asarray(q, dtype=float) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _slerp(q0: np.ndarray, q1: np.ndarray, u: float) -> np.ndarray:
    d = float(np.dot(q0, q1))
    if d < 0:
        q1, d = -q1, -d
    if d > 0.9995:
        q = q0 + u * (q1 - q0)
    else:
        th = math.acos(d)
        q = (math.sin((1 - u) * th) * q0 + math.sin(u * th) * q1) / math.sin(th)
    return q / np.linalg.norm(q)


class Trajectory:
    """Poses float ``[K, 8]`` (t, x, y, z, qx, qy, qz, qw) sorted by t."""

    def __init__(self, poses: np.ndarray, where: str):
        self.poses = poses[np.argsort(poses[:, 0], kind="stable")]
        self.where = where

    def at(self, t: float, what: str) -> tuple[np.ndarray, np.ndarray]:
        """(position ``(3,)``, rotation 3 x 3) at ``t``, interpolated."""
        p = self.poses
        if not (p[0, 0] - 1e-9 <= t <= p[-1, 0] + 1e-9):
            raise GridError(what, f"a stamp within its poses ({self.where}: {p[0, 0]:.6f} .. {p[-1, 0]:.6f} s)",
                            f"stamp {t:.6f} s has no pose")
        k = int(np.clip(np.searchsorted(p[:, 0], t, side="right") - 1, 0, len(p) - 1))
        if k == len(p) - 1 or p[k + 1, 0] == p[k, 0]:
            return p[k, 1:4].copy(), quat_matrix(p[k, 4:8])
        u = (t - p[k, 0]) / (p[k + 1, 0] - p[k, 0])
        pos = p[k, 1:4] + u * (p[k + 1, 1:4] - p[k, 1:4])
        return pos, quat_matrix(_slerp(p[k, 4:8] / np.linalg.norm(p[k, 4:8]), p[k + 1, 4:8] / np.linalg.norm(p[k + 1, 4:8]), u))


def read_tum(path: str | Path) -> Trajectory:
    """A TUM trajectory file: ``t x y z qx qy qz qw`` per line."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise GridError(str(path), "a readable TUM trajectory (t x y z qx qy qz qw per line)",
                        getattr(exc, "strerror", None) or str(exc)) from None
    rows = []
    for n, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.replace(",", " ").split()
        try:
            row = [float(v) for v in parts]
        except ValueError:
            row = []
        if len(row) != 8 or not all(math.isfinite(v) for v in row) or np.linalg.norm(row[4:]) == 0:
            raise GridError(f"{path}: line {n}", "t x y z qx qy qz qw (8 numbers, a non-zero quaternion)", repr(line[:60]))
        rows.append(row)
    if not rows:
        raise GridError(str(path), "at least one pose (t x y z qx qy qz qw)", "none")
    return Trajectory(np.asarray(rows, dtype=float), str(path))


# --------------------------------------------------------------------------- PCD and PLY


def read_pcd(path: str | Path) -> np.ndarray:
    """float32 ``[P, 3]``: the x, y, z of a PCD file (v0.5-0.7, DATA ascii or binary; points
    with a NaN coordinate dropped)."""
    path = Path(path)
    data = path.read_bytes()
    head: dict[str, list[str]] = {}
    pos = 0
    while "DATA" not in head:
        end = data.find(b"\n", pos)
        if end < 0:
            raise GridError(str(path), "a PCD header ending in a DATA line", "the file ends in its header")
        line = data[pos:end].decode("ascii", errors="replace").strip()
        pos = end + 1
        if line and not line.startswith("#"):
            key, *vals = line.split()
            head[key.upper()] = vals
    fields = head.get("FIELDS", [])
    if not all(f in fields for f in "xyz"):
        raise GridError(f"{path}: FIELDS", "float x, y and z fields", " ".join(fields) or "none")
    n = len(fields)
    size = [int(v) for v in head.get("SIZE", ["4"] * n)]
    types = head.get("TYPE", ["F"] * n)
    count = [int(v) for v in head.get("COUNT", ["1"] * n)]
    points = int(head.get("POINTS", [0])[0]) if "POINTS" in head else \
        int(head.get("WIDTH", ["0"])[0]) * int(head.get("HEIGHT", ["1"])[0])
    for f in "xyz":
        i = fields.index(f)
        if types[i] != "F" or size[i] not in (4, 8) or count[i] != 1:
            raise GridError(f"{path}: field {f}", "a float (TYPE F, SIZE 4 or 8, COUNT 1)",
                            f"TYPE {types[i]} SIZE {size[i]} COUNT {count[i]}")
    mode = head["DATA"][0].lower() if head["DATA"] else ""
    if mode == "ascii":
        rows = [line.split() for line in data[pos:].decode("ascii", errors="replace").splitlines() if line.strip()]
        cols = np.cumsum([0] + count)
        try:
            arr = np.array([[float(r[cols[fields.index(f)]]) for f in "xyz"] for r in rows], dtype=np.float64)
        except (ValueError, IndexError):
            raise GridError(str(path), "ascii rows of numbers, one per point", "a malformed row") from None
        arr = arr.reshape(-1, 3)
    elif mode == "binary":
        kinds = {"F": "f", "I": "i", "U": "u"}
        dtype = np.dtype([(f if f else f"_{k}", f"<{kinds.get(t, 'u')}{s}", (c,) if c > 1 else ())
                          for k, (f, t, s, c) in enumerate(zip(fields, types, size, count))])
        need = points * dtype.itemsize
        if len(data) - pos < need:
            raise GridError(str(path), f"{points} points of {dtype.itemsize} bytes", f"{len(data) - pos} bytes")
        rec = np.frombuffer(data, dtype=dtype, count=points, offset=pos)
        arr = np.column_stack([rec[f].astype(np.float64) for f in "xyz"])
    else:
        raise GridError(f"{path}: DATA", "ascii or binary (save binary_compressed scans as binary)", mode or "none")
    arr = arr[np.all(np.isfinite(arr), axis=1)]
    return arr.astype(np.float32)


_PLY_TYPES = {"char": "i1", "uchar": "u1", "short": "i2", "ushort": "u2", "int": "i4", "uint": "u4",
              "float": "f4", "double": "f8", "int8": "i1", "uint8": "u1", "int16": "i2", "uint16": "u2",
              "int32": "i4", "uint32": "u4", "float32": "f4", "float64": "f8"}


def read_ply(path: str | Path) -> np.ndarray:
    """float32 ``[P, 3]``: the vertices' x, y, z of a PLY file (ascii or binary, the vertex
    element first)."""
    path = Path(path)
    data = path.read_bytes()
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise GridError(str(path), "a PLY file (a 'ply' line and a header ending in end_header)", repr(data[:20]))
    lines = data[:end].decode("ascii", errors="replace").splitlines()
    pos = data.find(b"\n", end) + 1
    fmt, n, props, element = "", 0, [], None
    for line in lines[1:]:
        w = line.split()
        if not w:
            continue
        if w[0] == "format":
            fmt = w[1]
        elif w[0] == "element":
            element = w[1]
            if element == "vertex":
                n = int(w[2])
            elif n and not props:
                break
        elif w[0] == "property" and element == "vertex":
            if w[1] == "list":
                raise GridError(f"{path}: vertex", "scalar vertex properties", "a list property")
            props.append((w[2], _PLY_TYPES.get(w[1], "")))
    names = [p for p, _ in props]
    if not all(f in names for f in "xyz") or any(not t for _, t in props):
        raise GridError(f"{path}: vertex", "float x, y and z properties", " ".join(names) or "none")
    if any(t[0] != "f" for p, t in props if p in "xyz"):
        raise GridError(f"{path}: vertex", "float x, y and z properties", "integer coordinates")
    if fmt == "ascii":
        rows = data[pos:].decode("ascii", errors="replace").split("\n")[:n]
        arr = np.array([[float(r.split()[names.index(f)]) for f in "xyz"] for r in rows], dtype=np.float64)
    elif fmt in ("binary_little_endian", "binary_big_endian"):
        e = "<" if fmt == "binary_little_endian" else ">"
        dtype = np.dtype([(p, e + t) for p, t in props])
        if len(data) - pos < n * dtype.itemsize:
            raise GridError(str(path), f"{n} vertices of {dtype.itemsize} bytes", f"{len(data) - pos} bytes")
        rec = np.frombuffer(data, dtype=dtype, count=n, offset=pos)
        arr = np.column_stack([rec[f].astype(np.float64) for f in "xyz"])
    else:
        raise GridError(f"{path}: format", "ascii, binary_little_endian or binary_big_endian", fmt or "none")
    arr = arr.reshape(-1, 3)
    return arr[np.all(np.isfinite(arr), axis=1)].astype(np.float32)


def is_scan_folder(path: str | Path) -> bool:
    path = Path(path)
    return path.is_dir() and (path / POSES_FILE).is_file()


def read_folder(path: str | Path) -> list[Scan]:
    """Every PCD/PLY scan of a folder, in stamp order, moved into the map frame by ``poses.txt``."""
    path = Path(path)
    traj = read_tum(path / POSES_FILE)
    files = sorted(p for p in path.iterdir() if p.suffix.lower() in SCAN_SUFFIXES)
    if not files:
        raise GridError(str(path), "PCD or PLY scans beside poses.txt", "none")
    scans = []
    for f in files:
        try:
            t = float(f.stem)
        except ValueError:
            raise GridError(str(f), "a scan file named by its stamp in seconds (e.g. 12.500000.pcd)", repr(f.stem)) from None
        pos, rot = traj.at(t, str(f))
        try:
            local = read_pcd(f) if f.suffix.lower() == ".pcd" else read_ply(f)
        except OSError as exc:
            raise GridError(str(f), "a readable scan", exc.strerror or str(exc)) from None
        scans.append(Scan(t, pos, (local.astype(np.float64) @ rot.T + pos).astype(np.float32), str(f)))
    scans.sort(key=lambda s: s.stamp)
    return scans


# --------------------------------------------------------------------------- bags


def cloud_points(msg, where: str) -> np.ndarray:
    """float64 ``[P, 3]`` of a PointCloud2 (x, y, z as FLOAT32 or FLOAT64 at the offsets its
    fields give; NaN points dropped). ``msg``: a rosbags message, or a dict (ros2/msgs.py's)."""
    if isinstance(msg, dict):
        from types import SimpleNamespace

        msg = SimpleNamespace(**{**msg, "fields": [SimpleNamespace(**f) for f in msg["fields"]]})
    fields = {f.name: f for f in msg.fields}
    for name in "xyz":
        f = fields.get(name)
        if f is None or int(f.datatype) not in _FIELD_TYPES:
            raise GridError(where, "a PointCloud2 with float x, y and z fields (FLOAT32 or FLOAT64)",
                            f"fields {', '.join(f'{n}:{int(v.datatype)}' for n, v in fields.items()) or 'none'}")
    n = int(msg.width) * int(msg.height)
    step = int(msg.point_step)
    raw = np.asarray(msg.data, dtype=np.uint8).tobytes()
    if len(raw) < step * n:
        raise GridError(where, f"{n} points of {step} bytes", f"{len(raw)} bytes")
    e = ">" if msg.is_bigendian else "<"
    dtype = np.dtype({"names": list("xyz"), "formats": [e + _FIELD_TYPES[int(fields[c].datatype)] for c in "xyz"],
                      "offsets": [int(fields[c].offset) for c in "xyz"], "itemsize": step})
    rec = np.frombuffer(raw, dtype=dtype, count=n)
    arr = np.column_stack([rec[c].astype(np.float64) for c in "xyz"])
    return arr[np.all(np.isfinite(arr), axis=1)]


def _stamp(header) -> float:
    return float(header.stamp.sec) + float(header.stamp.nanosec) * 1e-9


def _tf_matrix(tr) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = quat_matrix([tr.rotation.x, tr.rotation.y, tr.rotation.z, tr.rotation.w])
    m[:3, 3] = [tr.translation.x, tr.translation.y, tr.translation.z]
    return m


def _static_chain(edges: dict[tuple[str, str], np.ndarray], parent: str, child: str) -> np.ndarray | None:
    """The transform parent <- child through the static edges (either direction), or None."""
    strip = lambda f: f.lstrip("/")  # noqa: E731 - tf2 ignores a leading slash
    graph: dict[str, list[tuple[str, np.ndarray]]] = {}
    for (p, c), m in edges.items():
        graph.setdefault(strip(p), []).append((strip(c), m))
        graph.setdefault(strip(c), []).append((strip(p), np.linalg.inv(m)))
    start, goal = strip(parent), strip(child)
    todo, seen = [(start, np.eye(4))], {start}
    while todo:
        f, m = todo.pop()
        if f == goal:
            return m
        for g, e in graph.get(f, []):
            if g not in seen:
                seen.add(g)
                todo.append((g, m @ e))
    return None


def read_bag_scans(path: str | Path, clouds: dict[str, str], odom: dict[str, str],
                   sensor_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
                   ) -> tuple[list[Scan], dict[str, np.ndarray]]:
    """The scans of every carrier's cloud topic and the carriers' tracks.

    Args:
        clouds: carrier id -> PointCloud2 topic.
        odom: carrier id -> Odometry topic (its pose; also the carrier's route).

    Returns:
        (scans in stamp order, carrier id -> float ``[K, 4]`` (t, x, y, z) of its odometry).
    """
    from world import bag as B

    path = Path(path)
    reader = B._open(path)
    try:
        cloud_conn, odom_conn = {}, {}
        for cid, topic in clouds.items():
            for c in B._connections(reader, path, topic, (CLOUD_TYPE,)):
                cloud_conn[c.id] = cid
        for cid, topic in odom.items():
            for c in B._connections(reader, path, topic, (ODOM_TYPE,)):
                odom_conn[c.id] = cid
        tf_conns = [c for c in reader.connections if c.topic == "/tf_static" and c.msgtype == "tf2_msgs/msg/TFMessage"]
        edges: dict[tuple[str, str], np.ndarray] = {}
        rows: dict[str, list[list[float]]] = {cid: [] for cid in odom}
        frames: dict[str, tuple[str, str]] = {}
        raw_scans: list[tuple[float, str, str, np.ndarray, str]] = []
        conns = [c for c in reader.connections if c.id in cloud_conn or c.id in odom_conn] + tf_conns
        for conn, _, raw in reader.messages(connections=conns):
            where = f"{path}: topic {conn.topic}"
            try:
                msg = reader.deserialize(raw, conn.msgtype)
            except Exception as exc:
                raise GridError(where, f"{conn.msgtype} messages that decode", f"{exc.__class__.__name__}: {exc}") from None
            if conn.msgtype == "tf2_msgs/msg/TFMessage":
                for t in msg.transforms:
                    edges[(t.header.frame_id, t.child_frame_id)] = _tf_matrix(t.transform)
            elif conn.id in odom_conn:
                cid = odom_conn[conn.id]
                p, q = msg.pose.pose.position, msg.pose.pose.orientation
                rows[cid].append([_stamp(msg.header), p.x, p.y, p.z, q.x, q.y, q.z, q.w])
                frames.setdefault(cid, (msg.header.frame_id, msg.child_frame_id))
            else:
                cid = cloud_conn[conn.id]
                t = _stamp(msg.header)
                raw_scans.append((t, cid, msg.header.frame_id, cloud_points(msg, f"{where} at {t:.6f} s"), where))
    finally:
        reader.close()
    tracks = {}
    trajs = {}
    for cid, topic in odom.items():
        if not rows[cid]:
            raise GridError(f"{path}: topic {topic}", f"odometry of carrier '{cid}'", "no messages")
        arr = np.asarray(rows[cid], dtype=float)
        trajs[cid] = Trajectory(arr, f"{path}: topic {topic}")
        tracks[cid] = trajs[cid].poses[:, :4]
    if not raw_scans:
        raise GridError(f"{path}: topic {', '.join(clouds.values())}", f"{CLOUD_TYPE} messages", "no messages")
    offset = np.eye(4)
    offset[:3, 3] = sensor_offset
    scans = []
    for t, cid, frame, pts, where in raw_scans:
        if cid not in trajs:
            raise GridError(f"--cloud-topic {clouds[cid]}", f"a carrier with odometry (--odom {cid}=TOPIC)", "none")
        pos, rot = trajs[cid].at(t, f"{where}: scan at {t:.6f} s")
        fixed, child = frames[cid]
        base = np.eye(4)
        base[:3, :3], base[:3, 3] = rot, pos
        if frame.lstrip("/") == fixed.lstrip("/"):
            origin = (base @ offset)[:3, 3]  # points in the map frame already: the origin by the offset
            scans.append(Scan(t, origin, pts.astype(np.float32), where))
            continue
        mount = _static_chain(edges, child, frame)
        sensor = base @ (offset if mount is None else mount)
        scans.append(Scan(t, sensor[:3, 3].copy(), (pts @ sensor[:3, :3].T + sensor[:3, 3]).astype(np.float32), where))
    scans.sort(key=lambda s: s.stamp)
    return scans, tracks
