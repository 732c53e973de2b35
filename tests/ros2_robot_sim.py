"""A simulated ROS 2 robot for the tests: a plain zenoh session speaking rmw_zenoh's format,
written independently of ros2/ (keys and tokens from rmw_zenoh's design document, payloads by
rosbags, attachments by zenoh-ext, GIDs by xxhash), so that a carrier flying it checks ros2/
against another implementation.

The robot is one carrier of a scenario driven by the project's physics (``world.Simulation``):
it publishes ``NS/odom`` (nav_msgs/Odometry) and ``NS/features`` (geometry_msgs/PoseArray, one
pose per feature its sensor sees) at every whole second and every stage time, stamped with
mission time, and answers every ``NS/deploy`` (std_msgs/UInt32) with ``NS/deployed``.

With ``sensing="frontier"`` it publishes ``NS/map`` (nav_msgs/OccupancyGrid: :func:`growing_map`)
instead of the features, every ``MAP_PERIOD_S`` from ``MAP_FIRST_S``, as map_server and SLAM do:
reliable, transient local, depth 1 — a zenoh-ext AdvancedPublisher with a cache of one sample,
publisher detection and sporadic heartbeats (rmw_zenoh's rmw_publisher_data.cpp). Each map goes
out before the odometry of the same second. :attr:`SimulatedRobot.maps` holds what it sent.

With ``sensing="frontier3d"`` it publishes ``NS/octomap_binary`` (octomap_msgs/Octomap) the same
way, as octomap_server does: its 3D map is an OcTree of the OctoMap library itself (its Python
binding) into which the robot inserts a LiDAR scan (:func:`lidar_scan`, ray cast in numpy
against :data:`ROOM`) at every map time, sent as ``writeBinary`` writes it (``binary``) or as
``write`` does (full, ``binary=False``); its odometry's z is ``ROBOT_Z``.
"""
from __future__ import annotations

import math
import threading
import time

import numpy as np
import xxhash
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from zenoh.ext import Int64, z_serialize

import world
from wire.zconfig import make_config, open_session

STORE = get_typestore(Stores.ROS2_JAZZY)
#: octomap_msgs/msg/Octomap (octomap_msgs' .msg file; not in common_interfaces).
OCTOMAP_TYPE = "octomap_msgs/msg/Octomap"
STORE.register(get_types_from_msg(
    "std_msgs/Header header\nbool binary\nstring id\nfloat64 resolution\nint8[] data\n", OCTOMAP_TYPE))
T = STORE.types

#: The growing map: cells of 0.5 m, 88 x 78 of them from the corner (-2, 1) m, the known part
#: x in [0, 8 + 2.5 t], y in [17 - 0.1 t, 22 + 0.25 t] (m, t = the map's stamp in s), free but
#: for tiny.yaml's wall at y = 23.5 (x 12..30) once it is known; the rest unknown.
MAP_RESOLUTION, MAP_ORIGIN, MAP_SIZE = 0.5, (-2.0, 1.0), (88, 78)
#: When the robot publishes its map (s of mission time): MAP_FIRST_S, then every MAP_PERIOD_S.
MAP_FIRST_S, MAP_PERIOD_S = 2.0, 3.0
#: QoS field of a reliable, transient-local, depth-1 publisher's token (rmw_zenoh's qos_to_keyexpr).
TRANSIENT_LOCAL_DEPTH_1 = ":1:,1:,:,:,,"


def growing_map(t: float) -> np.ndarray:
    """int8 ``[78, 88]``: the cells of the map stamped ``t`` (s), row-major from the origin."""
    width, height = MAP_SIZE
    xs = MAP_ORIGIN[0] + (np.arange(width) + 0.5) * MAP_RESOLUTION
    ys = MAP_ORIGIN[1] + (np.arange(height) + 0.5) * MAP_RESOLUTION
    x, y = np.meshgrid(xs, ys)
    cells = np.full((height, width), -1, dtype=np.int8)
    known = (x >= 0) & (x <= 8 + 2.5 * t) & (y >= 17 - 0.1 * t) & (y <= 22 + 0.25 * t)
    cells[known] = 0
    cells[known & (np.abs(y - 23.5) < 0.5 * MAP_RESOLUTION + 1e-9) & (x >= 12) & (x <= 30)] = 100
    return cells


def map_message(t: float, cells: np.ndarray | None = None, frame: str = "map"):
    """The nav_msgs/OccupancyGrid (a rosbags object) of :func:`growing_map` at ``t`` (s), or of
    ``cells`` (int8, row-major, any length: a wrong one makes a malformed map)."""
    width, height = MAP_SIZE
    cells = growing_map(t) if cells is None else cells
    sec = int(math.floor(t))
    stamp = T["builtin_interfaces/msg/Time"](sec=sec, nanosec=int(round((t - sec) * 1e9)))
    origin = T["geometry_msgs/msg/Pose"](
        position=T["geometry_msgs/msg/Point"](x=MAP_ORIGIN[0], y=MAP_ORIGIN[1], z=0.0),
        orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0))
    return T["nav_msgs/msg/OccupancyGrid"](
        header=T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame),
        info=T["nav_msgs/msg/MapMetaData"](map_load_time=stamp, resolution=MAP_RESOLUTION, width=width,
                                           height=height, origin=origin),
        data=np.ascontiguousarray(cells, dtype=np.int8).reshape(-1))


#: The 3D robot's world (m): a floor at z = 0 and a ceiling at z = 3, but for a shaft (x, y in
#: the box) whose floor is at z = -4. Its LiDAR: ``ROBOT_Z`` (its odometry's z) plus ``LIDAR_UP``,
#: range ``LIDAR_RANGE`` (no return beyond), voxels of ``VOXEL``.
ROOM = {"floor": 0.0, "ceiling": 3.0, "shaft": ((20.0, 24.0), (18.0, 22.0)), "shaft_floor": -4.0}
ROBOT_Z, LIDAR_UP, LIDAR_RANGE, VOXEL = 0.2, 0.8, 7.0, 0.4


def lidar_scan(x: float, y: float, rays: int = 2000) -> tuple[np.ndarray, np.ndarray]:
    """(returns float ``[N, 3]`` within range, origin ``(3,)``) of a scan from the robot at
    (x, y): rays on a Fibonacci sphere hitting :data:`ROOM`'s floor, shaft or ceiling."""
    origin = np.array([x, y, ROBOT_Z + LIDAR_UP])
    k = np.arange(rays) + 0.5
    zc = 1 - 2 * k / rays
    phi = k * math.pi * (3 - math.sqrt(5))
    d = np.column_stack([np.sqrt(1 - zc ** 2) * np.cos(phi), np.sqrt(1 - zc ** 2) * np.sin(phi), zc])
    with np.errstate(divide="ignore", invalid="ignore"):
        up = (ROOM["ceiling"] - origin[2]) / d[:, 2]
        down = (ROOM["floor"] - origin[2]) / d[:, 2]
        hit = origin + d * down[:, None]
        (x0, x1), (y0, y1) = ROOM["shaft"]
        in_shaft = (hit[:, 0] >= x0) & (hit[:, 0] <= x1) & (hit[:, 1] >= y0) & (hit[:, 1] <= y1)
        down = np.where(in_shaft, (ROOM["shaft_floor"] - origin[2]) / d[:, 2], down)
        dist = np.where(d[:, 2] > 0, up, np.where(d[:, 2] < 0, down, np.inf))
    ends = origin + d * np.minimum(dist, 2 * LIDAR_RANGE)[:, None]
    return ends[dist <= LIDAR_RANGE], origin


class OctoMapRobot:
    """The 3D robot's map: an OctoMap OcTree (the library's binding) of its scans."""

    def __init__(self, binary: bool = True):
        self.binary = binary
        self.scans: list[tuple[np.ndarray, np.ndarray]] = []

    def scan(self, x: float, y: float) -> tuple[np.ndarray, np.ndarray]:
        """A scan from (x, y) (:func:`lidar_scan`) added to the map; returns it."""
        pts, origin = lidar_scan(x, y)
        self.scans.append((pts, origin))
        return pts, origin

    def file_bytes(self, tmp: str) -> bytes:
        """The tree of the scans so far as a ``.bt`` (binary) or ``.ot`` (full) file, written by
        OctoMap. A new tree each time: the binding's writeBinary turns the tree it writes into
        its maximum-likelihood estimate (OctoMap's non-const ``writeBinary``), which octomap_server's
        ``writeBinaryData`` does not, so a tree written once would map the next scans otherwise."""
        import octomap

        tree = octomap.OcTree(VOXEL)
        for pts, origin in self.scans:
            tree.insertPointCloud(pts, origin, maxrange=LIDAR_RANGE)
        tree.updateInnerOccupancy()
        path = f"{tmp}/map.{'bt' if self.binary else 'ot'}"
        (tree.writeBinary if self.binary else tree.write)(path.encode())
        with open(path, "rb") as f:
            return f.read()

    def message(self, t: float, tmp: str, frame: str = "map"):
        """The octomap_msgs/Octomap (a rosbags object) of the tree: what follows the file's
        ``data`` line, as octomap_msgs' binaryMapToMsg / fullMapToMsg put it."""
        raw = self.file_bytes(tmp)
        data = raw[raw.index(b"\ndata\n") + 6:]
        sec = int(math.floor(t))
        stamp = T["builtin_interfaces/msg/Time"](sec=sec, nanosec=int(round((t - sec) * 1e9)))
        return T[OCTOMAP_TYPE](header=T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame), binary=self.binary,
                               id="OcTree", resolution=VOXEL, data=np.frombuffer(data, dtype=np.int8).copy())


def map_publisher(session, domain: int, namespace: str, eid: int = 9, node: str = "map_server",
                  topic: str = "map", typename: str = "nav_msgs/msg/OccupancyGrid"):
    """``(put, entities)``: ``put(payload: bytes)`` sends a map on ``NS/topic`` as a reliable,
    transient-local, depth-1 ROS 2 publisher in rmw_zenoh's format; ``entities`` to undeclare."""
    from zenoh import ext

    ns = namespace.strip("/")
    h = STORE.hash_rihs01(typename)
    key = f"{domain}/{ns}/{topic}/{_dds(typename)}/{h}"
    zid = str(session.zid())
    pub = ext.declare_advanced_publisher(
        session, key, cache=ext.CacheConfig(max_samples=1), publisher_detection=True,
        sample_miss_detection=ext.MissDetectionConfig(heartbeat=None, sporadic_heartbeat=0.5))
    token_key = (f"@ros2_lv/{domain}/{zid}/0/{eid}/MP/%/%{ns}/{node}/%{ns}%{topic}/{_dds(typename)}/{h}/"
                 f"{TRANSIENT_LOCAL_DEPTH_1}")
    token = session.liveliness().declare_token(token_key)
    seq = [0]
    gid = _gid(token_key)

    def put(payload: bytes) -> None:
        seq[0] += 1
        pub.put(payload, attachment=z_serialize((Int64(seq[0]), Int64(time.time_ns()), gid)))

    return put, [token, pub]


def _gid(token_key: str) -> bytes:
    """rmw_zenoh's GID of the entity with this token (liveliness_utils.cpp, ``Entity::Entity``):
    XXH3-128 of the token, low 64 bits then high 64 bits, each little-endian."""
    value = xxhash.xxh3_128_intdigest(token_key.encode())
    return (value & (2**64 - 1)).to_bytes(8, "little") + (value >> 64).to_bytes(8, "little")


def _dds(typename: str) -> str:
    pkg, kind, name = typename.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


class SimulatedRobot:
    def __init__(self, scenario, cid: str, endpoint: str, namespace: str = "/robot1", domain: int = 0,
                 acknowledge: bool = True, sensing: str = "features", binary: bool = True):
        self.scenario, self.cid, self.ns, self.domain = scenario, cid, namespace.strip("/"), domain
        self.acknowledge, self.sensing = acknowledge, sensing
        self.z = ROBOT_Z if sensing == "frontier3d" else 0.0
        self.octomap = OctoMapRobot(binary) if sensing == "frontier3d" else None
        #: frontier3d: (stamp s, the tree as an OctoMap file's bytes) of every map sent.
        self.files: list[tuple[float, bytes]] = []
        #: frontier3d: (stamp s, returns float ``[N, 3]``, origin) of every scan sent on NS/points.
        self.scans: list[tuple[float, np.ndarray, np.ndarray]] = []
        #: (stamp s, CDR payload) of every map sent, in order.
        self.maps: list[tuple[float, bytes]] = []
        self.session = open_session(make_config("client", [], [endpoint]), 20.0)
        self.zid = str(self.session.zid())
        self.commands: list[int] = []
        self.released: list[tuple[float, int]] = []
        self._lock = threading.Lock()
        self._seq: dict[str, int] = {}
        self._entities = [self.session.liveliness().declare_token(
            f"@ros2_lv/{domain}/{self.zid}/0/0/NN/%/%{self.ns}/robot")]
        self.keys = {}
        self._gids: dict[str, bytes] = {}
        topics = [("odom", "nav_msgs/msg/Odometry", "MP"), ("features", "geometry_msgs/msg/PoseArray", "MP"),
                  ("deployed", "std_msgs/msg/UInt32", "MP"), ("deploy", "std_msgs/msg/UInt32", "MS")]
        if sensing == "frontier3d":
            topics.append(("points", "sensor_msgs/msg/PointCloud2", "MP"))
        if sensing in ("frontier", "frontier3d"):
            del topics[1]
            topic, typename = (("map", "nav_msgs/msg/OccupancyGrid") if sensing == "frontier"
                               else ("octomap_binary", OCTOMAP_TYPE))
            self._put_map, entities = map_publisher(self.session, domain, self.ns, eid=len(topics) + 1,
                                                    node="robot", topic=topic, typename=typename)
            self._entities += entities
        for eid, (topic, typename, kind) in enumerate(topics, start=1):
            h = STORE.hash_rihs01(typename)
            self.keys[topic] = f"{domain}/{self.ns}/{topic}/{_dds(typename)}/{h}"
            token_key = (f"@ros2_lv/{domain}/{self.zid}/0/{eid}/{kind}/%/%{self.ns}/robot/%{self.ns}%{topic}/"
                         f"{_dds(typename)}/{h}/::,10:,:,:,,")
            self._gids[topic] = _gid(token_key)
            self._entities.append(self.session.liveliness().declare_token(token_key))
        self._entities.append(self.session.declare_subscriber(self.keys["deploy"], self._on_deploy))

    def _on_deploy(self, sample):
        msg = STORE.deserialize_cdr(sample.payload.to_bytes(), "std_msgs/msg/UInt32")
        with self._lock:
            self.commands.append(int(msg.data))

    def _put(self, topic: str, msg, typename: str) -> None:
        seq = self._seq[topic] = self._seq.get(topic, 0) + 1
        att = z_serialize((Int64(seq), Int64(time.time_ns()), self._gids[topic]))
        self.session.put(self.keys[topic], bytes(STORE.serialize_cdr(msg, typename)), attachment=att)

    def _header(self, t: float, frame: str):
        sec = int(math.floor(t))
        return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](
            sec=sec, nanosec=int(round((t - sec) * 1e9))), frame_id=frame)

    def _pose(self, x: float, y: float, z: float = 0.0):
        return T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=x, y=y, z=z),
                                           orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0))

    def publish_odometry(self, t: float, x: float, y: float) -> None:
        """``NS/odom`` stamped ``t`` (s): at (x, y, :attr:`z`) (m), heading east, at rest."""
        zeros = np.zeros(36)
        self._put("odom", T["nav_msgs/msg/Odometry"](
            header=self._header(t, "map"), child_frame_id="base_link",
            pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=self._pose(x, y, self.z), covariance=zeros),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=T["geometry_msgs/msg/Twist"](
                linear=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                angular=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)), covariance=zeros)),
            "nav_msgs/msg/Odometry")

    def publish_map(self, t: float, payload: bytes | None = None, at: tuple[float, float] | None = None) -> bytes:
        """``NS/map``: :func:`map_message` at ``t`` (s), or any ``payload`` (a malformed one);
        recorded in :attr:`maps`. frontier3d: ``NS/octomap_binary``, the tree after a scan from
        ``at`` (x, y; none: no new scan). Returns the payload."""
        if payload is None and self.octomap is not None:
            import tempfile

            if at is not None:
                self.publish_scan(t, *at)
            with tempfile.TemporaryDirectory() as tmp:
                msg = self.octomap.message(t, tmp)
                self.files.append((t, self.octomap.file_bytes(tmp)))
            payload = bytes(STORE.serialize_cdr(msg, OCTOMAP_TYPE))
        elif payload is None:
            payload = bytes(STORE.serialize_cdr(map_message(t), "nav_msgs/msg/OccupancyGrid"))
        self.maps.append((t, payload))
        self._put_map(payload)
        return payload

    def publish_scan(self, t: float, x: float, y: float, frame: str = "map") -> None:
        """``NS/points``: a LiDAR scan from (x, y) stamped ``t`` (s), its returns in the map frame
        (a SLAM's registered cloud), FLOAT32 x, y, z and a padding field; also inserted into the
        robot's OctoMap."""
        pts, origin = self.octomap.scan(x, y)
        self.scans.append((t, pts, origin))
        rec = np.zeros(len(pts), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("pad", "<f4")])
        rec["x"], rec["y"], rec["z"] = pts[:, 0], pts[:, 1], pts[:, 2]
        fields = [T["sensor_msgs/msg/PointField"](name=c, offset=4 * i, datatype=7, count=1) for i, c in enumerate("xyz")]
        self._put("points", T["sensor_msgs/msg/PointCloud2"](
            header=self._header(t, frame), height=1, width=len(pts), fields=fields, is_bigendian=False,
            point_step=16, row_step=16 * len(pts), data=np.frombuffer(rec.tobytes(), dtype=np.uint8), is_dense=True),
            "sensor_msgs/msg/PointCloud2")

    def wait_for_subscriber(self, stop: threading.Event, topic: str = "odom", timeout_s: float = 60.0) -> None:
        """Until the carrier's subscription to NS/``topic`` is in the graph (ROS discovery)."""
        want = f"%{self.ns}%{topic}/"
        deadline = time.monotonic() + timeout_s
        while not stop.is_set() and time.monotonic() < deadline:
            for reply in self.session.liveliness().get(f"@ros2_lv/{self.domain}/**", timeout=1.0):
                if reply.ok is not None and "/MS/" in str(reply.ok.key_expr) and want in str(reply.ok.key_expr):
                    return
            time.sleep(0.05)

    def run(self, stop: threading.Event) -> None:
        sim = world.Simulation(self.scenario, carriers=[self.cid])
        end = float(self.scenario.stage_times()[-1])
        times = sorted(set(float(s) for s in range(int(end) + 2)) | set(map(float, self.scenario.stage_times())))
        next_map = MAP_FIRST_S
        self.wait_for_subscriber(stop)
        for t in times:
            if stop.is_set():
                return
            sim.advance_to(t)
            x, y = (float(v) for v in sim.position(self.cid))
            if self.sensing in ("frontier", "frontier3d") and t >= next_map - 1e-9:
                self.publish_map(next_map, at=(x, y))
                next_map += MAP_PERIOD_S
            self.publish_odometry(t, x, y)
            if self.sensing == "features":
                self._put("features", T["geometry_msgs/msg/PoseArray"](
                    header=self._header(t, "map"), poses=[self._pose(x, y) for _ in range(sim.sense(self.cid))]),
                    "geometry_msgs/msg/PoseArray")
            self._answer()
            time.sleep(0.002)
        while not stop.wait(0.01):
            self._answer()

    def _answer(self) -> None:
        with self._lock:
            pending, self.commands[:] = list(self.commands), []
        for passenger in pending:
            self.released.append((time.monotonic(), passenger))
            if self.acknowledge:
                self._put("deployed", T["std_msgs/msg/UInt32"](data=passenger), "std_msgs/msg/UInt32")

    def close(self) -> None:
        for e in reversed(self._entities):
            try:
                e.undeclare()
            except Exception:
                pass
        self.session.close()
