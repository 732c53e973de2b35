"""A ROS 2 node on a zenoh session, as rmw_zenoh declares one: graph tokens, publishers, subscriptions.

``ros2 node list`` / ``ros2 topic list`` on a ROS 2 host (``RMW_IMPLEMENTATION=rmw_zenoh_cpp``,
connected to the same Zenoh network) see the node and its topics from the liveliness tokens;
``ros2 topic echo`` and RViz read the samples (CDR payload, attachment). A transient-local
publisher is a zenoh AdvancedPublisher with a cache of ``depth`` samples and publisher
detection, as rmw_zenoh declares it (rmw_publisher_data.cpp), so late transient-local
subscribers (RViz) get the last messages; a transient-local subscription is an
AdvancedSubscriber with history (rmw_subscription_data.cpp), so it gets the last messages of a
publisher such as map_server's that published before it subscribed.

Callbacks only decode and enqueue (the project's rule for zenoh callbacks); a sample of another
format, or a payload that does not decode, is counted and reported once, never raised.
"""
from __future__ import annotations

import queue
import threading
import time

import zenoh

from ros2 import msgs, rmw

#: Heartbeat period (s) of a reliable transient-local publisher (rmw_publisher_data.cpp: 500 ms).
HEARTBEAT_S = 0.5


class Publisher:
    """One ROS 2 publisher: its data key, token, GID and sequence numbers (from 1)."""

    def __init__(self, node: "Node", topic: str, typename: str, qos: rmw.QoS, eid: int):
        self.topic, self.typename, self.qos = topic, typename, qos
        dds, h = msgs.dds_name(typename), msgs.type_hash(typename)
        self.key = rmw.topic_key(node.domain, topic, dds, h)
        self.token_key = rmw.entity_token(node.domain, node.zid, node.nid, eid, rmw.PUBLISHER, node.namespace,
                                          node.name, topic, dds, h, qos)
        self.gid = rmw.gid(self.token_key)
        self.sequence = 0
        reliability = (zenoh.Reliability.RELIABLE if qos.reliability == rmw.RELIABLE
                       else zenoh.Reliability.BEST_EFFORT)
        if qos.durability == rmw.TRANSIENT_LOCAL:
            from zenoh import ext

            miss = (ext.MissDetectionConfig(heartbeat=None, sporadic_heartbeat=HEARTBEAT_S)
                    if qos.reliability == rmw.RELIABLE else None)
            self._pub = ext.declare_advanced_publisher(
                node.session, self.key, reliability=reliability, congestion_control=zenoh.CongestionControl.DROP,
                cache=ext.CacheConfig(max_samples=qos.depth), publisher_detection=True, sample_miss_detection=miss)
        else:
            self._pub = node.session.declare_publisher(self.key, reliability=reliability,
                                                       congestion_control=zenoh.CongestionControl.DROP)
        self._token = node.session.liveliness().declare_token(self.token_key)
        self._lock = threading.Lock()

    def publish(self, msg: dict) -> bytes:
        """Encode and put ``msg`` with its attachment; returns the payload."""
        payload = msgs.encode(self.typename, msg)
        with self._lock:
            self.sequence += 1
            att = rmw.attachment(self.sequence, time.time_ns(), self.gid)
            self._pub.put(payload, attachment=att)
        return payload

    def undeclare(self) -> None:
        for entity in (self._token, self._pub):
            try:
                entity.undeclare()
            except Exception:
                pass


class Subscription:
    """One ROS 2 subscription: decoded messages wait in :attr:`inbox` as ``(msg, attachment)``.

    At most ``capacity`` wait; when full, a new message is dropped (``keep_newest`` False) or
    the oldest waiting one makes room for it (``keep_newest``: ROS's keep-last, for large
    messages of which only the latest matter, such as maps). Either way :attr:`dropped` counts
    them. A transient-local subscription is a zenoh AdvancedSubscriber with history and late
    publisher detection, as rmw_zenoh declares it (rmw_subscription_data.cpp), so it gets the
    last ``depth`` messages a transient-local publisher sent before it subscribed.
    """

    def __init__(self, node: "Node", topic: str, typename: str, qos: rmw.QoS, eid: int, capacity: int = 1000,
                 keep_newest: bool = False):
        self.topic, self.typename = topic, typename
        dds, h = msgs.dds_name(typename), msgs.type_hash(typename)
        self.key = rmw.topic_key(node.domain, topic, dds, h)
        self.token_key = rmw.entity_token(node.domain, node.zid, node.nid, eid, rmw.SUBSCRIPTION, node.namespace,
                                          node.name, topic, dds, h, qos)
        self.inbox: "queue.Queue[tuple[dict, rmw.Attachment]]" = queue.Queue(capacity)
        self.dropped = 0
        report = node.report

        def on_sample(sample):
            att = sample.attachment
            if att is None:  # rmw_zenoh drops these too
                report(f"ros2: a sample on {topic} without an attachment was dropped")
                return
            try:
                meta = rmw.parse_attachment(att.to_bytes())
                msg = msgs.decode(typename, sample.payload.to_bytes())
            except rmw.ForeignFormat as exc:
                report(f"ros2: {topic}: {exc}")
                return
            except ValueError as exc:
                report(f"ros2: {topic}: undecodable {typename} payload dropped ({exc})")
                return
            while True:  # this callback is the inbox's only producer: one pass, or two with keep_newest
                try:
                    self.inbox.put_nowait((msg, meta))
                    return
                except queue.Full:
                    self.dropped += 1
                    if not keep_newest:
                        return
                try:
                    self.inbox.get_nowait()
                except queue.Empty:
                    pass

        if qos.durability == rmw.TRANSIENT_LOCAL:
            from zenoh import ext

            recovery = ext.RecoveryConfig(heartbeat=True) if qos.reliability == rmw.RELIABLE else None
            self._sub = ext.declare_advanced_subscriber(
                node.session, self.key, on_sample, subscriber_detection=True, recovery=recovery,
                history=ext.HistoryConfig(detect_late_publishers=True, max_samples=qos.depth))
        else:
            self._sub = node.session.declare_subscriber(self.key, on_sample)
        self._token = node.session.liveliness().declare_token(self.token_key)

    def latest(self):
        """The newest message waiting (older ones are discarded), or None."""
        item = None
        while True:
            try:
                item = self.inbox.get_nowait()
            except queue.Empty:
                return item

    def undeclare(self) -> None:
        for entity in (self._token, self._sub):
            try:
                entity.undeclare()
            except Exception:
                pass


class Node:
    """A ROS 2 node on ``session``.

    Args:
        session: an open zenoh session (shared with the process's mission traffic: the ROS 2
            keys, ``<domain>/...`` and ``@ros2_lv/...``, are outside ``marsupial/``).
        domain: the ROS domain id.
        namespace: the node's namespace (``/`` or ``/c1``).
        name: the node name.
        nid: the node's id within the session (0 for the first).
        log: callable taking one line (reports of foreign formats, once each).
        watch: watch the domain's graph tokens and report peers of another rmw_zenoh format.
    """

    def __init__(self, session, domain: int, namespace: str, name: str, nid: int = 0, log=None, watch: bool = True):
        self.session, self.domain, self.namespace, self.name, self.nid = session, int(domain), namespace, name, nid
        self.zid = str(session.zid())
        self._log = log or (lambda line: None)
        self._reported: set[str] = set()
        self._report_lock = threading.Lock()
        self.foreign: list[tuple[str, str]] = []  # (token, line) of every peer of a foreign format
        self._next_eid = nid + 1
        self.entities: list = []
        self.token_key = rmw.node_token(self.domain, self.zid, nid, namespace, name)
        self._token = session.liveliness().declare_token(self.token_key)
        self._watch = None
        #: Tokens someone else answers for (a robot body: its own topics): not reported here.
        self.claimed = lambda key: False
        if watch:
            self.watch_graph()

    def watch_graph(self) -> None:
        """Watch the domain's graph tokens; a peer of another rmw_zenoh format is recorded in
        :attr:`foreign` and reported once (unless :attr:`claimed`)."""
        def on_token(sample):
            if sample.kind != zenoh.SampleKind.PUT:
                return
            key = str(sample.key_expr)
            try:
                rmw.parse_token(key)
            except rmw.ForeignFormat as exc:
                self.foreign.append((key, str(exc)))
                if not self.claimed(key):
                    self.report(f"ros2: {exc}; ignored")
            except ValueError:
                pass

        if self._watch is None:
            self._watch = self.session.liveliness().declare_subscriber(f"{rmw.ADMIN_SPACE}/{self.domain}/**",
                                                                       on_token, history=True)

    def report(self, line: str) -> None:
        """Log ``line`` once (its first 60 characters identify it)."""
        with self._report_lock:
            key = line[:60]
            if key in self._reported:
                return
            self._reported.add(key)
        self._log(line)

    def _eid(self) -> int:
        eid, self._next_eid = self._next_eid, self._next_eid + 1
        return eid

    def publisher(self, topic: str, typename: str, qos: rmw.QoS = rmw.QoS(depth=10)) -> Publisher:
        """A publisher on ``topic`` (resolved in the node's namespace)."""
        pub = Publisher(self, rmw.fully_qualified(self.namespace, topic), typename, qos, self._eid())
        self.entities.append(pub)
        return pub

    def subscription(self, topic: str, typename: str, qos: rmw.QoS = rmw.QoS(depth=10), capacity: int = 1000,
                     keep_newest: bool = False) -> Subscription:
        """A subscription to ``topic`` (resolved in the node's namespace); see :class:`Subscription`."""
        sub = Subscription(self, rmw.fully_qualified(self.namespace, topic), typename, qos, self._eid(), capacity,
                           keep_newest)
        self.entities.append(sub)
        return sub

    def close(self) -> None:
        """Undeclare everything (the session stays open: it is not ours)."""
        for entity in reversed(self.entities):
            entity.undeclare()
        self.entities.clear()
        for entity in (self._watch, self._token):
            if entity is not None:
                try:
                    entity.undeclare()
                except Exception:
                    pass
        self._watch = None
