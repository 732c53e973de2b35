"""The processes' ROS 2 side (``--ros2``): the coordinator's node and each carrier's node.

* The coordinator runs node ``/mission/coordinator``: a sink of the mission stream it records
  (:class:`CoordinatorTopics`, fed by recording/live.py) that publishes the mission-wide topics
  of ros2/topics.py.
* Every carrier runs node ``/<id>/carrier`` on its own session (:class:`CarrierRos2`):
  ``/<id>/pose`` and ``/tf`` at each Pose it sends; with ``--ros2-robot`` its body is the robot
  (ros2/robot.py).

Both use the process's own zenoh session: the ROS 2 keys (``<domain>/...``, ``@ros2_lv/...``) are
outside the mission's ``marsupial/`` prefix, so the mission protocol is unchanged. A ROS 2 error
is logged once and turns that node off, never the mission.
"""
from __future__ import annotations

import os
import queue
import threading
from dataclasses import dataclass

from ros2 import topics
from ros2.graph import Node
from ros2.topics import CARRIER_TOPICS, TOPICS, MissionTopics

#: Stream calls the coordinator's ROS 2 publisher holds at most (about a stage of a large fleet).
QUEUE = 100_000


def default_domain() -> int:
    """``ROS_DOMAIN_ID`` when set (an integer 0..232), else 0."""
    text = os.environ.get("ROS_DOMAIN_ID", "").strip()
    return int(text) if text.isdigit() else 0


def check_domain(domain: int) -> str | None:
    """One line about a bad domain id, or None (ROS 2 domains are 0..232)."""
    if not 0 <= int(domain) <= 232:
        return f"--ros2-domain: expected an integer 0..232 (a ROS domain id), found {domain}"
    return None


def check_namespace(ns: str) -> str | None:
    """One line about a namespace that is not a ROS 2 name, or None."""
    import re

    if not re.fullmatch(r"(/[A-Za-z][A-Za-z0-9_]*)+/?|/", ns or ""):
        return (f"--ros2-namespace: expected a ROS 2 namespace such as /robot1 (tokens of letters, digits "
                f"and _ starting with a letter), found {ns!r}")
    return None


@dataclass(frozen=True)
class Ros2Settings:
    """What ``--ros2`` / ``--ros2-robot`` asked for.

    Attributes:
        domain: the ROS domain id.
        robot: this carrier's body is a real ROS 2 robot (ros2/robot.py).
        namespace: the robot's namespace (its odometry, feature, map and deploy topics).
        ack_timeout_s: how long a robot carrier waits for the robot to acknowledge a deployment.
        robot_timeout_s: how long a robot carrier waits for the robot's odometry, features or map.
        sensing: what a robot carrier observes (``--robot-sensing``, ros2/robot.py
            :data:`~ros2.robot.SENSING`): ``features`` (the poses in ``NS/features``),
            ``frontier`` (the frontier cells of ``NS/map`` within the sensing radius) or
            ``frontier3d`` (the frontier voxels of ``NS/octomap_binary`` in the height band).
        cloud_topic: with ``frontier3d``, the robot's PointCloud2 topic (in its namespace) whose
            scans the carrier makes its map of (``--robot-cloud-topic``); "" reads the OctoMap.
        voxel: that map's voxel size (m, ``--robot-voxel``); 0: the scenario's ``map.voxels``
            map's, else the import's default (0.2 m).
        sensor_offset: the LiDAR's position in the robot's base frame (m, ``--robot-sensor-offset``):
            each scan's ray origin.
    """

    domain: int = 0
    robot: bool = False
    namespace: str = "/"
    ack_timeout_s: float = 10.0
    robot_timeout_s: float = 30.0
    sensing: str = "features"
    cloud_topic: str = ""
    voxel: float = 0.0
    sensor_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def coordinator_sink(self, session, problem=None, log=print):
        """A factory ``scene -> CoordinatorTopics`` for recording/live.py's extra sinks."""
        return lambda scene: CoordinatorTopics(session, scene, self.domain, problem, log)

    def attach(self, session, scenario, cid: str, realtime: float, stop, log) -> "CarrierRos2":
        """Carrier ``cid``'s ROS 2 node on its Zenoh ``session``, and with ``robot`` its robot body
        (``realtime``: the carrier's pace, 0 unpaced; ``stop``: its stop request; ``log``: where its
        lines go)."""
        return CarrierRos2(self, session, scenario, cid, realtime, stop, log)


class CoordinatorTopics:
    """The mission-wide topics, published live by the coordinator (ROS 2 node
    ``/mission/coordinator``). A sink of the stream the coordinator records: each call is queued
    and turned into messages, encoded and put by a thread of its own, so the coordinator's loop
    never waits for the ROS 2 side (at most :data:`QUEUE` calls wait; more are dropped and
    counted in :attr:`dropped`)."""

    name = "ROS 2 topics"
    STREAM = ("observation", "decision", "confirm", "pose", "log", "end")

    def __init__(self, session, scene, domain: int, problem=None, log=print):
        self.node = Node(session, domain, topics.MISSION_NS, "coordinator", log=log)
        self.pubs = {topic: self.node.publisher(topic, typename, qos) for topic, (typename, qos) in TOPICS.items()}
        self._log = log
        self.dropped = 0
        self._queue: "queue.Queue" = queue.Queue(QUEUE)
        self.topics = MissionTopics(scene, self._emit, problem, carriers=False)  # /mission/world, now
        self._worker = threading.Thread(target=self._work, name="ros2-topics", daemon=True)
        self._worker.start()

    def __getattr__(self, name):
        if name not in CoordinatorTopics.STREAM:
            raise AttributeError(name)

        def call(*args):
            try:
                self._queue.put_nowait((name, args))
            except queue.Full:
                self.dropped += 1
        return call

    def _work(self) -> None:
        while True:
            item = self._queue.get()
            if item is None:
                return
            name, args = item
            try:
                getattr(self.topics, name)(*args)
            except Exception as exc:  # never the mission: log once, stop publishing
                self._log(f"coordinator: ROS 2 topics stopped: {type(exc).__name__}: {exc}")
                return

    def _emit(self, topic, typename, msg, t) -> None:
        self.pubs[topic].publish(msg)

    def close(self, timeout_s: float = 5.0) -> None:
        """Publish what is queued (at most ``timeout_s``), then undeclare the node."""
        try:
            self._queue.put(None, timeout=timeout_s)
        except queue.Full:
            pass
        self._worker.join(timeout_s)
        self.node.close()


class CarrierRos2:
    """A carrier's ROS 2 node ``/<id>/carrier``: its pose topics, and with a robot its body
    (:attr:`robot`, which the carrier then drives instead of its simulated one).

    The carrier calls :meth:`pose` for every Pose it publishes, :meth:`release` when it deploys
    (the robot's launcher gets the command), and :meth:`close` when it stops.
    """

    def __init__(self, settings: Ros2Settings, session, scenario, cid: str, realtime: float, stop, log):
        self.cid, self.log = cid, log
        self.node = Node(session, settings.domain, topics.carrier_namespace(cid), "carrier", log=log, watch=False)
        self.pose_pub = self.node.publisher("pose", *CARRIER_TOPICS["{ns}/pose"])
        self.tf_pub = self.node.publisher("/tf", *CARRIER_TOPICS["/tf"])
        self.robot = None
        self._failed = False
        if settings.robot:
            from ros2.robot import RobotBody, ScanSource

            self.robot = RobotBody(scenario, cid, self.node, settings.namespace,
                                   sync=realtime <= 0, log=log, stop=stop,
                                   ack_timeout_s=settings.ack_timeout_s, timeout_s=settings.robot_timeout_s,
                                   sensing=settings.sensing,
                                   scans=ScanSource(settings.cloud_topic, settings.voxel, settings.sensor_offset)
                                   if settings.cloud_topic else None)
            self.node.claimed = self.robot.ours  # the robot's own topics: it refuses them itself
        self.node.watch_graph()

    def pose(self, t: float, x: float, y: float, heading: float) -> None:
        if self._failed:
            return
        try:
            self.pose_pub.publish(topics.pose_stamped(t, x, y, heading))
            self.tf_pub.publish(topics.transform(t, self.cid, x, y, heading))
        except Exception as exc:  # never the mission
            self._failed = True
            self.log(f"ROS 2 pose topics stopped: {type(exc).__name__}: {exc}")

    def release(self, stage: int, passenger: int) -> None:
        """Deploy command to the robot (no-op for a simulated carrier)."""
        if self.robot is not None:
            self.robot.release(stage, passenger)

    def close(self) -> None:
        try:
            self.node.close()
        except Exception:
            pass
