"""A simulated ROS 2 robot for the tests: a plain zenoh session speaking rmw_zenoh's format,
written independently of ros2/ (keys and tokens from rmw_zenoh's design document, payloads by
rosbags, attachments by zenoh-ext), so that a carrier flying it checks ros2/ against another
implementation.

The robot is one carrier of a scenario driven by the project's physics (``world.Simulation``):
it publishes ``NS/odom`` (nav_msgs/Odometry) and ``NS/features`` (geometry_msgs/PoseArray, one
pose per feature its sensor sees) at every whole second and every stage time, stamped with
mission time, and answers every ``NS/deploy`` (std_msgs/UInt32) with ``NS/deployed``.
"""
from __future__ import annotations

import math
import threading
import time

import numpy as np
import zenoh
from rosbags.typesys import Stores, get_typestore
from zenoh.ext import Int64, z_serialize

import world
from wire.zconfig import make_config, open_session

STORE = get_typestore(Stores.ROS2_JAZZY)
T = STORE.types


def _dds(typename: str) -> str:
    pkg, kind, name = typename.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


class SimulatedRobot:
    def __init__(self, scenario, cid: str, endpoint: str, namespace: str = "/robot1", domain: int = 0,
                 acknowledge: bool = True):
        self.scenario, self.cid, self.ns, self.domain = scenario, cid, namespace.strip("/"), domain
        self.acknowledge = acknowledge
        self.session = open_session(make_config("client", [], [endpoint]), 20.0)
        self.zid = str(self.session.zid())
        self.commands: list[int] = []
        self.released: list[tuple[float, int]] = []
        self._lock = threading.Lock()
        self._seq: dict[str, int] = {}
        self._entities = [self.session.liveliness().declare_token(
            f"@ros2_lv/{domain}/{self.zid}/0/0/NN/%/%{self.ns}/robot")]
        self.keys = {}
        for eid, (topic, typename, kind) in enumerate((
                ("odom", "nav_msgs/msg/Odometry", "MP"), ("features", "geometry_msgs/msg/PoseArray", "MP"),
                ("deployed", "std_msgs/msg/UInt32", "MP"), ("deploy", "std_msgs/msg/UInt32", "MS")), start=1):
            h = STORE.hash_rihs01(typename)
            self.keys[topic] = f"{domain}/{self.ns}/{topic}/{_dds(typename)}/{h}"
            self._entities.append(self.session.liveliness().declare_token(
                f"@ros2_lv/{domain}/{self.zid}/0/{eid}/{kind}/%/%{self.ns}/robot/%{self.ns}%{topic}/"
                f"{_dds(typename)}/{h}/::,10:,:,:,,"))
        self._entities.append(self.session.declare_subscriber(self.keys["deploy"], self._on_deploy))

    def _on_deploy(self, sample):
        msg = STORE.deserialize_cdr(sample.payload.to_bytes(), "std_msgs/msg/UInt32")
        with self._lock:
            self.commands.append(int(msg.data))

    def _put(self, topic: str, msg, typename: str) -> None:
        seq = self._seq[topic] = self._seq.get(topic, 0) + 1
        gid = (topic.encode() + bytes(16))[:16]
        att = z_serialize((Int64(seq), Int64(time.time_ns()), gid))
        self.session.put(self.keys[topic], bytes(STORE.serialize_cdr(msg, typename)), attachment=att)

    def _header(self, t: float, frame: str):
        sec = int(math.floor(t))
        return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](
            sec=sec, nanosec=int(round((t - sec) * 1e9))), frame_id=frame)

    def _pose(self, x: float, y: float):
        return T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
                                           orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0))

    def _wait_for_subscriber(self, stop: threading.Event, timeout_s: float = 60.0) -> None:
        """Until the carrier's subscription to NS/odom is in the graph (ROS discovery)."""
        want = f"%{self.ns}%odom/"
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
        self._wait_for_subscriber(stop)
        zeros = np.zeros(36)
        for t in times:
            if stop.is_set():
                return
            sim.advance_to(t)
            x, y = (float(v) for v in sim.position(self.cid))
            self._put("odom", T["nav_msgs/msg/Odometry"](
                header=self._header(t, "map"), child_frame_id="base_link",
                pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=self._pose(x, y), covariance=zeros),
                twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=T["geometry_msgs/msg/Twist"](
                    linear=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                    angular=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)), covariance=zeros)),
                "nav_msgs/msg/Odometry")
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
