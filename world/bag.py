"""Reading a team's recorded run from a ROS 2 bag (MCAP or sqlite3 storage, by rosbags).

Two passes, so that memory holds at most two maps whatever the bag's length: :func:`read_tracks`
reads the trajectories (``nav_msgs/msg/Odometry``, ``geometry_msgs/msg/PoseStamped`` or
``geometry_msgs/msg/PoseWithCovarianceStamped``, taken as map-frame positions) and the
maps' stamps; :func:`iter_maps` then yields the ``nav_msgs/msg/OccupancyGrid`` messages one at a
time in stamp order of the bag. Times are the messages' header stamps (s).
"""
from __future__ import annotations

from pathlib import Path
from typing import Iterator

import numpy as np

from world.grid import GridError, OccupancyGrid, grid_from_message

MAP_TYPE = "nav_msgs/msg/OccupancyGrid"
#: Pose messages a carrier's trajectory may come in (a localiser's /amcl_pose is the third).
POSE_TYPES = ("nav_msgs/msg/Odometry", "geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/PoseWithCovarianceStamped")


def is_bag(path: str | Path) -> bool:
    """Whether ``path`` is a ROS 2 bag directory (it holds a ``metadata.yaml``)."""
    return Path(path).is_dir() and (Path(path) / "metadata.yaml").is_file()


def _open(path: Path):
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise GridError(str(path), "rosbags installed to read ROS 2 bags (pip install 'marsupial-fleet[ros2]')",
                        "no module rosbags") from None
    if not is_bag(path):
        raise GridError(str(path), "a ROS 2 bag directory (metadata.yaml and its storage files) or a map YAML",
                        "no metadata.yaml" if Path(path).is_dir() else "no such directory")
    try:
        reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except Exception as exc:  # rosbags raises its own errors for damaged bags and storage plugins
        raise GridError(str(path), "a readable ROS 2 bag (MCAP or sqlite3)", f"{exc.__class__.__name__}: {exc}") from None
    return reader


def _connections(reader, path: Path, topic: str, types: tuple[str, ...]):
    conns = [c for c in reader.connections if c.topic == topic]
    if not conns:
        known = ", ".join(sorted({c.topic for c in reader.connections})) or "none"
        raise GridError(f"{path}: topic {topic}", f"{' or '.join(types)} messages", f"no such topic (topics: {known})")
    wrong = [c.msgtype for c in conns if c.msgtype not in types]
    if wrong:
        raise GridError(f"{path}: topic {topic}", f"{' or '.join(types)} messages", f"type {wrong[0]}")
    return conns


def _stamp(header) -> float:
    return float(header.stamp.sec) + float(header.stamp.nanosec) * 1e-9


def read_tracks(path: str | Path, odom: dict[str, str], map_topic: str | None) -> tuple[dict[str, np.ndarray], list[float]]:
    """The carriers' recorded poses and the maps' stamps.

    Args:
        odom: carrier id -> topic of its Odometry or PoseStamped messages.
        map_topic: the OccupancyGrid topic, or None to read no maps.

    Returns:
        (carrier id -> float ``[K, 3]`` (t s, x m, y m) sorted by stamp, map stamps in bag order).

    Raises:
        GridError: naming the bag and topic (absent, of another type, without messages).
    """
    path = Path(path)
    reader = _open(path)
    try:
        by_conn = {}
        for cid, topic in odom.items():
            for c in _connections(reader, path, topic, POSE_TYPES):
                by_conn[c.id] = cid
        map_conns = _connections(reader, path, map_topic, (MAP_TYPE,)) if map_topic else []
        map_ids = {c.id for c in map_conns}
        rows: dict[str, list[tuple[float, float, float]]] = {cid: [] for cid in odom}
        stamps: list[float] = []
        conns = [c for c in reader.connections if c.id in by_conn or c.id in map_ids]
        for conn, _, raw in reader.messages(connections=conns):
            try:
                msg = reader.deserialize(raw, conn.msgtype)
            except Exception as exc:
                raise GridError(f"{path}: topic {conn.topic}", f"{conn.msgtype} messages that decode",
                                f"{exc.__class__.__name__}: {exc}") from None
            if conn.id in map_ids:
                stamps.append(_stamp(msg.header))
                continue
            pose = msg.pose if conn.msgtype == "geometry_msgs/msg/PoseStamped" else msg.pose.pose
            rows[by_conn[conn.id]].append((_stamp(msg.header), float(pose.position.x), float(pose.position.y)))
    finally:
        reader.close()
    tracks = {}
    for cid, topic in odom.items():
        if not rows[cid]:
            raise GridError(f"{path}: topic {topic}", f"poses of carrier '{cid}'", "no messages")
        arr = np.asarray(rows[cid], dtype=float)
        tracks[cid] = arr[np.argsort(arr[:, 0], kind="stable")]
    if map_topic and not stamps:
        raise GridError(f"{path}: topic {map_topic}", f"{MAP_TYPE} messages", "no messages")
    return tracks, stamps


def iter_maps(path: str | Path, map_topic: str, free_level: int, occupied_level: int,
              wanted: set[int] | None = None) -> Iterator[tuple[int, OccupancyGrid]]:
    """(index in bag order, map) for every map message on ``map_topic`` (only the indices in
    ``wanted`` when given: the others are not decoded)."""
    path = Path(path)
    reader = _open(path)
    try:
        conns = _connections(reader, path, map_topic, (MAP_TYPE,))
        for k, (conn, _, raw) in enumerate(reader.messages(connections=conns)):
            if wanted is not None and k not in wanted:
                continue
            msg = reader.deserialize(raw, conn.msgtype)
            yield k, grid_from_message(msg, source=f"{path}: topic {map_topic}", free_level=free_level,
                                       occupied_level=occupied_level)
    finally:
        reader.close()
