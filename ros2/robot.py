"""A real ROS 2 robot as a carrier's body (``--role carrier --carrier ID --ros2-robot``).

:class:`RobotBody` offers what the carrier loop asks of its ``world.Simulation`` — ``time``,
``advance_to(t)``, ``position(id)``, ``sense(id)``, ``deploy(id)``, ``passengers_left(id)``,
``trajectory(id)`` — from the robot's own topics, so Hello, State, resynchronisation, the
durable log and on-board decisions are the carrier's as for a simulated one (carriers/node.py).

The robot's topics, in its namespace ``NS`` (docs/fleet.md, "A ROS 2 robot in a mission"):

=================  ==============================  =====================================================
topic              type                            what
=================  ==============================  =====================================================
``NS/odom``        nav_msgs/msg/Odometry           the robot's pose; ``pose.pose.position`` x, y (and z)
                                                   in the scenario's map frame (m), heading from the
                                                   orientation
``NS/features``    geometry_msgs/msg/PoseArray     ``--robot-sensing features`` (the default): the features
                                                   its detector sees now (within its sensing radius):
                                                   x = ``len(poses)``
``NS/map``         nav_msgs/msg/OccupancyGrid      ``--robot-sensing frontier``: its map (SLAM's or
                                                   map_server's; reliable, transient local, so a map sent
                                                   before the carrier subscribed arrives too): x = the
                                                   frontier cells within the scenario's sensing radius
``NS/octomap_``    octomap_msgs/msg/Octomap        ``--robot-sensing frontier3d``: its 3D map (octomap_server's,
``binary``                                         binary or full; QoS as ``NS/map``): x = the frontier voxels
                                                   within the sensing radius in the paper's height band
``NS/deploy``      std_msgs/msg/UInt32             published by the carrier: release passenger ``data``
                                                   (its index, 0-based, as in the protocol's Decision)
``NS/deployed``    std_msgs/msg/UInt32             published by the robot's launcher: passenger ``data``
                                                   has left
=================  ==============================  =====================================================

Time. Unpaced missions (``--realtime 0``: a simulated robot on ``/clock``) read the stamps as
mission time: reaching t waits for an odometry (and, to sense, a features) message stamped at or
after t and uses the last one stamped at or before t, so the robot's clock drives the carrier's
(conservative synchronisation). Paced missions (``--realtime F > 0``, a robot in the field) use
the latest message at each stage (sample and hold). A robot silent for ``timeout_s`` is taken
where it last was (one line in the log).

Frontier. With ``sensing="frontier"`` x at a stage is the paper's value of the robot's position
(from odometry, as above) in its own map: the frontier cells (a free cell with an unknown
8-neighbour) whose centre lies within ``sensing_radius``, counted by world/grid.py's
:class:`~world.grid.FrontierCounter` in the map :func:`~world.grid.latest_at` picks — the latest
stamped at or before the stage time, 0 before the first — which is what ``python -m world
import --replay`` computes from a bag of the same maps. Unpaced, sensing waits for a map stamped
at or after the stage time or an odometry stamped after it (maps come now and then, odometry
always); paced, it counts in the latest map. A map that does not convert is logged (one line per
kind of fault) and ignored. At most :data:`MAX_MAPS` maps wait and as many are kept.

Frontier in 3D. With ``sensing="frontier3d"`` the maps are the robot's OctoMaps and x is the 3D
import's value of the robot's position (x, y and z from odometry; its storey's base while it has
sent none): the frontier voxels (a free voxel with an unknown face neighbour, 26 neighbours if
the scenario's ``map.voxels`` says so) whose centre lies within ``sensing_radius`` (3D) and more
than ``keep_above`` above or ``keep_below`` below it (``map.voxels``' values, else the paper's
1 m and 0.1 m), counted by world/voxels.py's :class:`~world.voxels.FrontierCounter3D` in the
tree as :func:`~world.voxels.octomap_from_message` reads it (the reader of ``python -m world
import MAP.bt``: a binary message's data is the ``.bt`` stream, a full one's the ``.ot`` stream,
every pruned leaf expanded to voxels). Which map, the waits and the bad maps are as in 2D.
With ``cloud_topic`` (``--robot-cloud-topic``) the body makes the map itself from the robot's
``sensor_msgs/msg/PointCloud2`` scans on ``NS/cloud_topic`` (:class:`_Scans`: the 3D import's
ray caster and pose interpolation), and a stage counts in the scans stamped at or before it.

Deployments. The carrier publishes the command once and waits at most ``ack_timeout_s`` for
``NS/deployed`` with the same index. Without it, it logs one line and goes on: the deployment
was decided and is already in its durable log, and a repeated command could release a second
passenger, so the Confirm says deployed either way.
"""
from __future__ import annotations

import bisect
import math
import threading
import time
from dataclasses import dataclass

import numpy as np

from ros2.rmw import TRANSIENT_LOCAL, ForeignFormat, QoS, mangle

#: How often a waiting body looks for the robot's messages (s).
POLL_S = 0.005
#: What a robot's carrier observes (``--robot-sensing``): its detector's features, its 2D map's
#: frontier cells, or its 3D map's frontier voxels in the paper's height band.
SENSING = ("features", "frontier", "frontier3d")
#: Maps a frontier body lets wait in its inbox (the newest) and keeps as grids: a map may have
#: up to 10^8 cells (world.grid.MAX_CELLS), so both are bounded.
MAX_MAPS = 8
#: The map's QoS as map_server and slam_toolbox publish it (reliable, transient local, depth 1).
MAP_QOS = QoS(durability=TRANSIENT_LOCAL, depth=1)
#: Scans a ``--robot-cloud-topic`` body holds before inserting them (those stamped after the
#: carrier's time), and the scans that may wait in its inbox.
MAX_SCANS, SCAN_INBOX = 64, 256
#: How much a scan map's region grows beyond what a scan needs, when it grows (m).
SCAN_SLACK_M = 5.0


def _stamp(msg: dict) -> float:
    s = msg["header"]["stamp"]
    return s["sec"] + s["nanosec"] * 1e-9


def _waiting(sub):
    """The messages waiting in a subscription's inbox, oldest first (without waiting)."""
    while True:
        try:
            msg, _ = sub.inbox.get_nowait()
        except Exception:
            return
        yield msg


class _Faults:
    """One log line per kind of fault (a GridError's ``expected``, else the exception's type):
    ``what`` ignored, and any later one wrong the same way, silently."""

    def __init__(self, log, robot: str, what: str):
        self.log, self.robot, self.what = log, robot, what
        self.kinds: set[str] = set()

    def __call__(self, exc: Exception) -> None:
        from world.grid import GridError

        kind = exc.expected if isinstance(exc, GridError) else type(exc).__name__
        if kind not in self.kinds:
            self.kinds.add(kind)
            self.log(f"robot {self.robot}: {self.what} ignored (and any later one wrong the same way): {exc}")


#: What a message a map or scan is made of may raise when it is not one.
_BAD_INPUT = (ValueError, TypeError, KeyError)  # GridError is a ValueError


def _yaw(q: dict) -> float:
    return math.atan2(2.0 * (q["w"] * q["z"] + q["x"] * q["y"]), 1.0 - 2.0 * (q["y"] ** 2 + q["z"] ** 2))


class _History:
    """Stamped values from one subscription, in stamp order (bounded)."""

    def __init__(self, sub, value, keep: int = 4096):
        self.sub, self.value, self.keep = sub, value, keep
        self.stamps: list[float] = []
        self.values: list = []
        self.frame = ""  # the latest message's header.frame_id (no leading /)

    def pull(self) -> None:
        for msg in _waiting(self.sub):
            t = _stamp(msg)
            self.frame = str(msg["header"]["frame_id"]).lstrip("/")
            k = bisect.bisect_right(self.stamps, t)
            self.stamps.insert(k, t)
            self.values.insert(k, self.value(msg))
            if len(self.stamps) > self.keep:
                del self.stamps[:-self.keep], self.values[:-self.keep]

    def reached(self, t: float) -> bool:
        return bool(self.stamps) and self.stamps[-1] >= t - 1e-6

    def at(self, t: float):
        """The value stamped last at or before t (the first one if all are later), or None."""
        if not self.values:
            return None
        k = bisect.bisect_right(self.stamps, t + 1e-6) - 1
        return self.values[max(k, 0)]

    def latest(self):
        return self.values[-1] if self.values else None


def needed_maps(stamps, stage_times, now: float, sync: bool) -> list[int]:
    """Indices (ascending) of the maps a stage at or after ``now`` (s) can count in: the newest
    (paced missions count in nothing else), and with ``sync`` the latest stamped at or before
    each such stage time. ``stamps`` and ``stage_times`` sorted (s)."""
    from world.grid import latest_at

    if not len(stamps):
        return []
    keep = {len(stamps) - 1}
    if sync:
        for t in stage_times[bisect.bisect_left(stage_times, now - 1e-6):]:
            k = latest_at(stamps, float(t))
            if k >= 0:
                keep.add(k)
            if k == len(stamps) - 1:
                break  # every later stage counts in the newest too
    return sorted(keep)


def plane_maps(scenario, where: str):
    """``--robot-sensing frontier``: (read, counter) for :class:`_Maps` over
    ``nav_msgs/msg/OccupancyGrid`` messages on ``where``: world/grid.py's classes (an imported
    scenario's thresholds, else map_saver's) and :class:`~world.grid.FrontierCounter` (x, y)."""
    from world import grid as G

    occupancy = scenario.map.occupancy  # an imported scenario's thresholds: the importer's classes
    free, occupied = ((occupancy.free_level, occupancy.occupied_level) if occupancy is not None
                      else (G.DEFAULT_FREE_LEVEL, G.DEFAULT_OCCUPIED_LEVEL))

    def read(msg):
        grid = G.grid_from_message(msg, source=where, free_level=free, occupied_level=occupied)
        if not all(math.isfinite(v) for v in grid.origin):
            raise G.GridError(f"{where} (stamp {grid.stamp:.3f} s): info.origin", "a finite pose", repr(grid.origin))
        return grid.stamp, grid

    def counter(grid):
        c = G.FrontierCounter(grid)
        return lambda point, radius: int(c.count([point[:2]], radius)[0])

    return read, counter


def voxel_rule(scenario) -> tuple[int, float, float]:
    """(neighbours, keep_above, keep_below) of a scenario's 3D values: its ``map.voxels``', else
    the paper's (6, 1 m, 0.1 m)."""
    from world import voxels as V

    spec = scenario.map.voxels
    return ((spec.neighbours, spec.keep_above, spec.keep_below) if spec is not None
            else (6, V.DEFAULT_KEEP_ABOVE, V.DEFAULT_KEEP_BELOW))


def voxel_maps(scenario, where: str):
    """``--robot-sensing frontier3d``: (read, counter) for :class:`_Maps` over
    ``octomap_msgs/msg/Octomap`` messages on ``where``: world/voxels.py's reader (the import's
    for ``.bt``/``.ot`` files) and :class:`~world.voxels.FrontierCounter3D` (x, y, z) with the
    scenario's frontier rule (``map.voxels``: neighbours, keep_above, keep_below; the paper's 6,
    1 m, 0.1 m without it)."""
    from world import voxels as V

    neighbours, above, below = voxel_rule(scenario)

    def read(msg):
        t = _stamp(msg)
        return t, V.octomap_from_message(msg, f"{where} (stamp {t:.3f} s)")

    def counter(grid):
        if grid is None:  # an empty tree
            return lambda point, radius: 0
        c = V.FrontierCounter3D(grid, neighbours)
        return lambda point, radius: int(c.count([point], radius, above, below)[0])

    return read, counter


#: The map a ``--robot-sensing`` kind counts in: (topic in the robot's namespace, type, (read,
#: counter) maker).
MAP_TOPICS = {"frontier": ("map", "nav_msgs/msg/OccupancyGrid", plane_maps),
              "frontier3d": ("octomap_binary", "octomap_msgs/msg/Octomap", voxel_maps)}


class _Maps:
    """The robot's maps (what ``read`` makes of a message: (stamp, map)), in stamp order (a
    later arrival with the same stamp after the earlier, as :class:`world.grid.MapHistory`
    orders them); ``counter(map)`` gives the map's value function ``(point (x, y, z), radius)
    -> int``.

    Invariant: after :meth:`pull` only the maps :func:`needed_maps` names at the body's time are
    held, and at most ``keep`` of them (when more are named, the ``keep - 1`` oldest and the
    newest stay, logged once)."""

    def __init__(self, sub, kind, scenario, now, sync: bool, log, robot: str, where: str, keep: int = MAX_MAPS):
        self.read, self.counter = kind
        self.sub, self.now, self.sync, self._log, self.keep = sub, now, sync, log, keep
        self.robot, self.where = robot, where  # for the log: the robot's namespace, the map's topic
        self.stage_times = [float(t) for t in scenario.stage_times()]
        self.stamps: list[float] = []
        self.grids: list = []
        self.newest = -math.inf  # the latest stamp that arrived, kept or not (s)
        self._counters: dict[int, object] = {}  # id(map) -> its value function, for maps held
        self._fault = _Faults(log, robot, "map")
        self._overflow = False

    def pull(self) -> None:
        for msg in _waiting(self.sub):
            try:
                stamp, grid = self.read(msg)
            except _BAD_INPUT as exc:
                self._fault(exc)
                continue
            k = bisect.bisect_right(self.stamps, stamp)
            self.stamps.insert(k, stamp)
            self.grids.insert(k, grid)
            self.newest = max(self.newest, stamp)
        self._prune()

    def _prune(self) -> None:
        keep = needed_maps(self.stamps, self.stage_times, self.now(), self.sync)
        if len(keep) > self.keep:
            if not self._overflow:
                self._overflow = True
                self._log(f"robot {self.robot}: more than {self.keep} maps on {self.where} ahead of the carrier's "
                          f"stages; the ones before the newest are dropped (their stages count in an earlier map)")
            keep = keep[:self.keep - 1] + keep[-1:]  # the nearest stages' maps, and the newest
        if len(keep) != len(self.grids):
            self.stamps = [self.stamps[k] for k in keep]
            self.grids = [self.grids[k] for k in keep]
            held = {id(g) for g in self.grids}
            self._counters = {i: c for i, c in self._counters.items() if i in held}

    def reached(self, t: float) -> bool:
        return self.newest >= t - 1e-6

    def latest(self) -> int | None:
        """The index of the newest map, or None."""
        return len(self.grids) - 1 if self.grids else None

    def at(self, t: float) -> int | None:
        """The index of the map stamped last at or before ``t`` (s), or None (world.grid.latest_at)."""
        from world.grid import latest_at

        k = latest_at(self.stamps, t)
        return k if k >= 0 else None

    def value(self, k: int, point, radius: float) -> int:
        """The value of ``point`` (x, y, z; m) in map ``k``: its frontier within ``radius`` (m)."""
        grid = self.grids[k]
        counter = self._counters.get(id(grid))
        if counter is None:
            counter = self._counters[id(grid)] = self.counter(grid)
        return counter(point, radius)


@dataclass(frozen=True)
class ScanSource:
    """Where a frontier3d body's scans come from (``--robot-cloud-topic``, ``--robot-voxel``,
    ``--robot-sensor-offset``): the PointCloud2 ``topic`` in the robot's namespace, the map's
    ``voxel`` size (m; 0: the scenario's ``map.voxels`` map's, else 0.2) and the LiDAR's
    ``sensor_offset`` in the robot's base frame (m)."""

    topic: str
    voxel: float = 0.0
    sensor_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)


class _Scans:
    """``--robot-cloud-topic``: the robot's PointCloud2 scans made a 3D map by the import's ray
    caster (:class:`world.voxels.VoxelMapper`, OctoMap's rules; its region grown as the robot
    goes), inserted in stamp order, each from the robot's odometry pose at its stamp
    (:class:`world.clouds.Trajectory`, the import's interpolation): a cloud in the odometry's
    frame (``header.frame_id``, e.g. ``map``: a SLAM's registered scan) is in the map frame
    already, any other is taken in the robot's base frame. A stage counts in the scans stamped
    at or before its time (unpaced; paced: every scan its odometry covers), as ``python -m world
    import BAG --cloud-topic ... --replay`` does.

    Invariant: :attr:`pending` holds the scans not yet inserted, in stamp order; at most
    ``keep`` (beyond, the oldest is inserted early, logged once)."""

    def __init__(self, sub, scenario, odom: "_History", sync: bool, log, robot: str, where: str,
                 voxel: float = 0.0, offset=(0.0, 0.0, 0.0), keep: int = MAX_SCANS):
        from world import voxels as V
        from world.import3d import DEFAULT_VOXEL

        spec = scenario.map.voxels
        self.voxel = (voxel if voxel > 0 else V.octomap_resolution(spec.path) if spec is not None
                      else DEFAULT_VOXEL)
        self.rule = voxel_rule(scenario)
        self.sub, self.odom, self.sync, self._log, self.keep = sub, odom, sync, log, keep
        self.robot, self.where = robot, where
        self.offset = np.asarray(offset, dtype=float)
        self.pending: list[tuple[float, np.ndarray, str]] = []  # (stamp, points, frame)
        self.mapper = None
        self.newest = -math.inf
        self._fault = _Faults(log, robot, "scan")
        self._overflow = False

    def pull(self) -> None:
        from world.clouds import cloud_points

        for msg in _waiting(self.sub):
            try:
                t = _stamp(msg)
                pts = cloud_points(msg, f"{self.where} (stamp {t:.3f} s)").astype(np.float32)
            except _BAD_INPUT as exc:
                self._fault(exc)
                continue
            k = bisect.bisect_right([p[0] for p in self.pending], t)
            self.pending.insert(k, (t, pts, str(msg["header"]["frame_id"]).lstrip("/")))
            self.newest = max(self.newest, t)
        while len(self.pending) > self.keep:
            if not self._overflow:
                self._overflow = True
                self._log(f"robot {self.robot}: more than {self.keep} scans on {self.where} ahead of the carrier's "
                          f"stages; the oldest go into the map early")
            self._insert(self.pending.pop(0))

    def reached(self, t: float) -> bool:
        return self.newest >= t - 1e-6

    def latest(self):
        return 0 if (self.mapper is not None or self.pending) else None

    def _insert(self, scan) -> None:
        from world import voxels as V
        from world.clouds import Trajectory
        from world.grid import GridError

        t, pts, frame = scan
        try:
            if not self.odom.stamps:
                raise GridError(f"{self.where} (stamp {t:.3f} s)", "odometry at the scan's stamp", "none yet")
            poses = np.array([[s, v[0], v[1], v[3], *v[4]] for s, v in zip(self.odom.stamps, self.odom.values)])
            base, rot = Trajectory(poses, "odometry").at(t, f"{self.where} (stamp {t:.3f} s)")
            origin = base + rot @ self.offset
            if frame != self.odom.frame:
                pts = (pts @ rot.T + base).astype(np.float32)
            if self.mapper is None:
                self.mapper = V.VoxelMapper(origin, origin, self.voxel, source=self.where)
            if len(pts):
                self.mapper.cover(np.minimum(pts.min(axis=0), origin), np.maximum(pts.max(axis=0), origin),
                                  slack=SCAN_SLACK_M)
            self.mapper.insert(pts, origin)
        except GridError as exc:
            self._fault(exc)

    def value(self, t: float, point, radius: float) -> int:
        """The value of ``point`` (x, y, z; m) in the map of the scans stamped at or before
        ``t`` (s) that the odometry covers (:meth:`_insert`)."""
        last = self.odom.stamps[-1] if self.odom.stamps else -math.inf
        while self.pending and self.pending[0][0] <= min(t, last) + 1e-6:
            self._insert(self.pending.pop(0))
        return 0 if self.mapper is None else self.mapper.value(point, radius, *self.rule)


class RobotBody:
    """One carrier's body backed by a ROS 2 robot (see the module docstring).

    Args:
        scenario: the mission's scenario.
        cid: the carrier id.
        node: the carrier's ROS 2 node (ros2/graph.py).
        namespace: the robot's namespace.
        sync: read stamps as mission time and wait for the robot's clock (unpaced missions).
        log: callable taking one line.
        stop: the carrier's stop request (ends every wait).
        ack_timeout_s, timeout_s: see the module docstring.
        sensing: one of :data:`SENSING` (see the module docstring).
        scans: with ``frontier3d``, the robot's scans to make the map of (else its OctoMap).
    """

    def __init__(self, scenario, cid: str, node, namespace: str, sync: bool, log, stop: threading.Event,
                 ack_timeout_s: float = 10.0, timeout_s: float = 30.0, sensing: str = "features",
                 scans: ScanSource | None = None):
        if sensing not in SENSING:
            raise ValueError(f"sensing: expected one of {', '.join(SENSING)}, found {sensing!r}")
        if scans is not None and sensing != "frontier3d":
            raise ValueError(f"scans: only with sensing frontier3d, found sensing {sensing!r}")
        self.cid = cid
        self.ns = "/" + namespace.strip("/") if namespace.strip("/") else ""
        self.node = node
        self.sync, self._log, self._stop = sync, log, stop
        self.ack_timeout_s, self.timeout_s = ack_timeout_s, timeout_s
        self.sensing = sensing
        self.cloud_topic = ""
        self.radius = float(scenario.sensing_radius)
        self.time = 0.0
        keep = QoS(depth=1000)
        # The map first: by the time the robot sees the odometry subscription, the map's exists.
        self.features = self.maps = None
        if scans is not None:
            self.cloud_topic = f"{self.ns}/{scans.topic.strip('/')}"
        elif sensing in MAP_TOPICS:
            topic, msgtype, kind = MAP_TOPICS[sensing]
            where = f"{self.ns}/{topic}"
            sub = node.subscription(where, msgtype, MAP_QOS, capacity=MAX_MAPS, keep_newest=True)
            self.maps = _Maps(sub, kind(scenario, where), scenario, lambda: self.time, sync, log, self.ns or "/", where)
        self.odom = _History(node.subscription(f"{self.ns}/odom", "nav_msgs/msg/Odometry", keep), lambda m: (
            float(m["pose"]["pose"]["position"]["x"]), float(m["pose"]["pose"]["position"]["y"]),
            _yaw(m["pose"]["pose"]["orientation"]), float(m["pose"]["pose"]["position"]["z"]),
            tuple(float(m["pose"]["pose"]["orientation"][c]) for c in "xyzw")))
        if scans is not None:  # after the odometry's: the scans are placed by it
            sub = node.subscription(self.cloud_topic, "sensor_msgs/msg/PointCloud2", QoS(depth=10), capacity=SCAN_INBOX)
            self.maps = _Scans(sub, scenario, self.odom, sync, log, self.ns or "/", self.cloud_topic, scans.voxel,
                               scans.sensor_offset)
        if sensing == "features":
            self.features = _History(node.subscription(f"{self.ns}/features", "geometry_msgs/msg/PoseArray", keep),
                                     lambda m: len(m["poses"]))
        self.acks = node.subscription(f"{self.ns}/deployed", "std_msgs/msg/UInt32", QoS(depth=10))
        self.command = node.publisher(f"{self.ns}/deploy", "std_msgs/msg/UInt32", QoS(depth=10))
        self._spec = scenario.carriers[scenario.carrier_index(cid)]
        self._left = int(self._spec.passengers)
        self._pos = (float("nan"), float("nan"))
        self._z = float("nan")  # the robot's height (odometry's z; its storey's base without odometry)
        storey = scenario.map.storey(self._spec.storey) if self._spec.storey else None
        self._base = float(storey.base) if storey is not None else 0.0
        self._trace: list[tuple[float, float, float]] = []
        self._silent: set[str] = set()

    # ------------------------------------------------------------------ waiting for the robot
    def ours(self, key: str) -> bool:
        """Whether a graph token is about one of the robot's topics."""
        return any(f"/{mangle(f'{self.ns}/{topic}')}/" in key
                   for topic in ("odom", "features", *(t for t, _, _ in MAP_TOPICS.values()), "deploy", "deployed",
                                 *([self.cloud_topic[len(self.ns) + 1:]] if self.cloud_topic else [])))

    def _check_format(self) -> None:
        """Raise :class:`ForeignFormat` (the carrier stops, one line) when the robot's own topics
        are in the graph in another distribution's format: its data could never reach us."""
        for key, line in self.node.foreign:
            if self.ours(key):
                raise ForeignFormat(f"robot {self.ns or '/'}: {line}")

    def _passed(self, t: float) -> bool:
        """Whether odometry stamped after ``t`` (s) has arrived."""
        self.odom.pull()
        return bool(self.odom.stamps) and self.odom.stamps[-1] > t + 1e-6

    def _wait(self, history, t: float, what: str, or_odometry: bool = False) -> None:
        """Until ``history`` (a :class:`_History` or :class:`_Maps`) holds what time ``t`` (s)
        needs (see the module docstring); ``or_odometry``: odometry stamped after t will do."""
        deadline = time.monotonic() + self.timeout_s
        history.pull()
        self._check_format()
        while (self.sync and not history.reached(t) and not (or_odometry and self._passed(t))
               and not self._stop.is_set()):
            if time.monotonic() >= deadline:
                if what not in self._silent:
                    self._silent.add(what)
                    self._log(f"robot {self.ns or '/'}: no {what} stamped {t:.1f} s or later within "
                              f"{self.timeout_s:.0f} s; using the last one")
                return
            time.sleep(POLL_S)
            history.pull()
            self._check_format()
        while not self.sync and history.latest() is None and not self._stop.is_set():
            if time.monotonic() >= deadline:
                if what not in self._silent:
                    self._silent.add(what)
                    self._log(f"robot {self.ns or '/'}: no {what} within {self.timeout_s:.0f} s")
                return
            time.sleep(POLL_S)
            history.pull()
            self._check_format()

    def _pose_at(self, t: float):
        """(x, y, heading, z) of the robot at ``t``; its planned position (on its storey's
        floor) while it has sent no odometry at all (a silent robot, logged by :meth:`_wait`)."""
        p = self.odom.at(t) if self.sync else self.odom.latest()
        if p is None:
            x, y = (float(v) for v in self._spec.position_at(t))
            return x, y, 0.0, self._base
        return p

    # ------------------------------------------------------------------ what the carrier asks
    def advance_to(self, t: float) -> None:
        """Mission time ``t`` (s): the robot's pose then, and one trajectory sample per whole
        second passed."""
        self._wait(self.odom, t, "odometry")
        first = len(self._trace)
        for s in range(first, int(math.floor(t + 1e-9)) + 1):
            p = self._pose_at(float(s))
            self._trace.append((float(s), p[0], p[1]))
        p = self._pose_at(t)
        self._pos, self._z = (p[0], p[1]), p[3]
        self.time = max(self.time, float(t))

    def position(self, cid: str) -> tuple[float, float]:
        return self._pos

    def sense(self, cid: str, stage: int | None = None) -> int:
        """x at the current time: the number of features the robot's detector saw, or of
        frontier cells (voxels) within the sensing radius in its map (``stage``, the stage being
        sensed, is the carrier loop's and not needed here)."""
        if self.maps is not None:
            self._wait(self.maps, self.time, "scan" if isinstance(self.maps, _Scans) else "map", or_odometry=True)
            point = (*self._pos, self._z)
            if isinstance(self.maps, _Scans):
                return self.maps.value(self.time if self.sync else math.inf, point, self.radius)
            k = self.maps.at(self.time) if self.sync else self.maps.latest()
            return 0 if k is None else self.maps.value(k, point, self.radius)
        self._wait(self.features, self.time, "feature detections")
        x = self.features.at(self.time) if self.sync else self.features.latest()
        return int(x) if x is not None else 0

    def passengers_left(self, cid: str) -> int:
        return self._left

    def deploy(self, cid: str):
        """The carrier's count of passengers (a deployment done or replayed); the command to the
        robot is :meth:`release`."""
        if self._left <= 0:
            raise ValueError(f"carrier {cid!r} has no passenger left to deploy")
        self._left -= 1

    def trajectory(self, cid: str) -> np.ndarray:
        return np.asarray(self._trace, dtype=float).reshape(-1, 3)

    def release(self, stage: int, passenger: int) -> bool:
        """Command the robot to release ``passenger`` and wait for its acknowledgement; True if
        it came within ``ack_timeout_s``."""
        self.command.publish({"data": int(passenger)})
        deadline = time.monotonic() + self.ack_timeout_s
        while time.monotonic() < deadline and not self._stop.is_set():
            item = self.acks.latest()
            if item is not None and int(item[0]["data"]) == int(passenger):
                return True
            time.sleep(POLL_S)
        self._log(f"robot {self.ns or '/'}: no acknowledgement of passenger {passenger} (stage {stage}) on "
                  f"{self.ns}/deployed within {self.ack_timeout_s:.0f} s; counted as deployed (never re-sent)")
        return False
