"""The ``ros2`` MCAP profile: the mission as a rosbag2 bag (MCAP storage) that ``ros2 bag`` plays.

The bag holds the topics of ros2/topics.py (the same messages the live ``--ros2`` publisher
sends), CDR payloads with ``ros2msg`` schemas, each message at its simulated mission time, and
each topic's offered QoS (the latched ones transient local, so ``ros2 bag play`` re-latches
them for RViz). Written with PyPI's ``rosbags`` (the optional ``[ros2]`` extra) as a bag
directory: ``<dir>/metadata.yaml`` and ``<dir>/<dir name>.mcap``. The directory is complete once
the writer is closed (metadata.yaml is written last); ``python -m recording rebuild --profile
ros2`` writes one from mission.db.
"""
from __future__ import annotations

import shutil
from pathlib import Path

from ros2 import msgs, rmw
from ros2.topics import CARRIER_TOPICS, TOPICS, MissionTopics

#: Name of the bag directory in a results directory.
BAG_NAME = "ros2bag"


def _qos(q: rmw.QoS):
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

    def t(pair):
        return QosTime(sec=int(pair[0]), nsec=int(pair[1]))

    return Qos(history=QosHistory(q.history), depth=int(q.depth), reliability=QosReliability(q.reliability),
               durability=QosDurability(q.durability), deadline=t(q.deadline), lifespan=t(q.lifespan),
               liveliness=QosLiveliness(q.liveliness), liveliness_lease_duration=t(q.lease),
               avoid_ros_namespace_conventions=False)


def _topic_qos(topic: str) -> rmw.QoS:
    if topic in TOPICS:
        return TOPICS[topic][1]
    if topic in CARRIER_TOPICS:
        return CARRIER_TOPICS[topic][1]
    return CARRIER_TOPICS["{ns}/pose"][1]


class BagRecorder(MissionTopics):
    """A mission written into a rosbag2 bag as the stream arrives (a sink of ``recording.stream``).

    Args:
        path: the bag directory (replaced if it exists).
        scene: the mission's scene.
        problem: the planner problem (for ``/mission/reward``).
        metadata: ignored but for the interface's sake (rosbag2 has no free metadata record).
    """

    def __init__(self, path, scene, problem=None, metadata: dict | None = None):
        from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
        from rosbags.typesys import Stores, get_typestore

        self.path = Path(path)
        if self.path.exists():
            shutil.rmtree(self.path)
        self.store = get_typestore(Stores.ROS2_JAZZY)
        # Version 8: the bag metadata of Jazzy's rosbag2 (later releases read it too).
        self.writer = Writer(self.path, version=8, storage_plugin=StoragePlugin.MCAP)
        # zstd inside the MCAP chunks (1 MiB each): the storage plugin's own compression, which
        # rosbag2's MCAP reader decodes without any bag-level compression setting.
        self.writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        self.writer.open()
        self.connections: dict[str, object] = {}
        self.counts: dict[str, int] = {}
        self.closed = False
        super().__init__(scene, self._write, problem, carriers=True)

    def _write(self, topic: str, typename: str, msg: dict, t: float) -> None:
        conn = self.connections.get(topic)
        if conn is None:
            conn = self.writer.add_connection(topic, typename, typestore=self.store,
                                              offered_qos_profiles=[_qos(_topic_qos(topic))])
            self.connections[topic] = conn
        self.writer.write(conn, max(0, int(round(float(t) * 1e9))), msgs.encode(typename, msg))
        self.counts[topic] = self.counts.get(topic, 0) + 1

    def close(self) -> None:
        """Finish the bag (metadata.yaml; idempotent)."""
        if not self.closed:
            self.closed = True
            self.writer.close()
