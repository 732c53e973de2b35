"""The mission as ROS 2 topics: one home for topic names, types, QoS and message contents.

:class:`MissionTopics` has the methods of a ``recording.stream.Sink``: fed the mission stream (what the
coordinator records, or mission.db's events), it turns every call into ROS 2 messages and hands
each to ``emit(topic, typename, msg, t)``. The live publisher (ros2/publisher.py) emits them on
Zenoh in rmw_zenoh's format, the bag writer (ros2/bag.py) into a rosbag2 MCAP file, so the two
hold the same messages. Times are simulated mission time (s): ``header.stamp`` and ``/clock``
count from t = 0 (RViz: ``use_sim_time``).

Topics (docs/fleet.md, "ROS 2 topics"; frame ``map``: metres, x east, y north, z up):

=========================  ================================  =========  ==========================
topic                      type                              QoS        what
=========================  ================================  =========  ==========================
/mission/world             visualization_msgs/MarkerArray    latched 1  the map, paths, decision points, overlaps
/mission/carriers          visualization_msgs/MarkerArray    latched 1  every carrier at its last pose (full state)
/mission/deployments       visualization_msgs/MarkerArray    latched 1  deployed passengers, sensing discs (full state)
/mission/decisions         std_msgs/String (JSON)            depth 100  one per stage decided
/mission/observations      std_msgs/String (JSON)            depth 100  one per observation
/mission/confirmations     std_msgs/String (JSON)            depth 100  one per Confirm
/mission/reward            std_msgs/Float64                  depth 100  normalised reward so far
/mission/log               std_msgs/String                   depth 100  mission events as text
/clock                     rosgraph_msgs/Clock               depth 10   mission time
/<carrier>/pose            geometry_msgs/PoseStamped         depth 10   per Pose (carriers publish it live)
/tf                        tf2_msgs/TFMessage                depth 100  map -> <carrier>, per Pose
=========================  ================================  =========  ==========================

"latched 1": transient local, depth 1 (a late RViz gets the last message).
"""
from __future__ import annotations

import json
import math
import re

from mission.records import Tally, confirm_record, decision_record, observation_record
from ros2 import msgs
from ros2.rmw import TRANSIENT_LOCAL, QoS
from world.scene import FEATURE_COLOUR, OBSTACLE_COLOUR, OVERLAP_COLOUR, WALL_COLOUR, Scene, rgb

FRAME = "map"
MISSION_NS = "/mission"
LATCHED = QoS(durability=TRANSIENT_LOCAL, depth=1)
EVENTS = QoS(depth=100)
STREAM = QoS(depth=10)

#: Mission-wide topics: name -> (type, QoS).
TOPICS = {
    "/mission/world": ("visualization_msgs/msg/MarkerArray", LATCHED),
    "/mission/carriers": ("visualization_msgs/msg/MarkerArray", LATCHED),
    "/mission/deployments": ("visualization_msgs/msg/MarkerArray", LATCHED),
    "/mission/decisions": ("std_msgs/msg/String", EVENTS),
    "/mission/observations": ("std_msgs/msg/String", EVENTS),
    "/mission/confirmations": ("std_msgs/msg/String", EVENTS),
    "/mission/reward": ("std_msgs/msg/Float64", EVENTS),
    "/mission/log": ("std_msgs/msg/String", EVENTS),
    "/clock": ("rosgraph_msgs/msg/Clock", STREAM),
}
#: Per-carrier topics (``{ns}`` = the carrier's namespace, ``/<carrier id>``): name -> (type, QoS).
CARRIER_TOPICS = {
    "{ns}/pose": ("geometry_msgs/msg/PoseStamped", STREAM),
    "/tf": ("tf2_msgs/msg/TFMessage", EVENTS),
}


def ros_token(cid: str) -> str:
    """A carrier id as a ROS 2 name token (letters, digits, ``_``; not starting with a digit):
    ``c1`` stays ``c1``, ``robot-1.a`` becomes ``robot_1_a``, ``0007`` becomes ``c_0007``."""
    token = re.sub(r"[^A-Za-z0-9_]", "_", cid)
    return token if token[:1].isalpha() else f"c_{token}"


def carrier_namespace(cid: str) -> str:
    """The ROS 2 namespace of a carrier's mission topics: ``/<id>`` (as a ROS name token)."""
    return f"/{ros_token(cid)}"


def stamp(t: float) -> dict:
    """builtin_interfaces/Time of mission time ``t`` (s, clamped at 0)."""
    n = max(0, int(round(float(t) * 1e9)))
    return {"sec": n // 1_000_000_000, "nanosec": n % 1_000_000_000}


def header(t: float, frame: str = FRAME) -> dict:
    return {"stamp": stamp(t), "frame_id": frame}


def yaw_quaternion(yaw: float) -> dict:
    return {"x": 0.0, "y": 0.0, "z": math.sin(yaw / 2), "w": math.cos(yaw / 2)}


def colour(hex_colour: str, alpha: float = 1.0) -> dict:
    r, g, b = rgb(hex_colour)
    return {"r": r / 255, "g": g / 255, "b": b / 255, "a": float(alpha)}


def pose_stamped(t: float, x: float, y: float, heading: float) -> dict:
    return {"header": header(t), "pose": {"position": {"x": float(x), "y": float(y), "z": 0.0},
                                          "orientation": yaw_quaternion(heading)}}


def transform(t: float, child: str, x: float, y: float, heading: float) -> dict:
    """tf2_msgs/TFMessage with ``map`` -> ``child``."""
    return {"transforms": [{"header": header(t), "child_frame_id": child, "transform": {
        "translation": {"x": float(x), "y": float(y), "z": 0.0}, "rotation": yaw_quaternion(heading)}}]}


def _marker(t, ns, mid, kind, hex_colour, alpha=1.0, scale=(1.0, 1.0, 1.0), points=(), at=(0.0, 0.0, 0.0),
            yaw=0.0, text="") -> dict:
    return {"header": header(t), "ns": ns, "id": int(mid), "type": kind, "action": msgs.ADD,
            "pose": {"position": {"x": float(at[0]), "y": float(at[1]), "z": float(at[2])},
                     "orientation": yaw_quaternion(yaw)},
            "scale": {"x": float(scale[0]), "y": float(scale[1]), "z": float(scale[2])},
            "color": colour(hex_colour, alpha), "points": [{"x": float(p[0]), "y": float(p[1]),
                                                            "z": float(p[2]) if len(p) > 2 else 0.0} for p in points],
            "text": text}


def world_markers(scene: Scene, t: float = 0.0) -> dict:
    """The static scene as a MarkerArray: bounds, walls, obstacles, features, planned paths,
    planned decision points, overlap outlines with their members."""
    xmin, ymin, xmax, ymax = scene.bounds
    out = [_marker(t, "bounds", 0, msgs.LINE_STRIP, "#808080", scale=(0.2, 0, 0),
                   points=[(xmin, ymin), (xmax, ymin), (xmax, ymax), (xmin, ymax), (xmin, ymin)])]
    if len(scene.walls):
        out.append(_marker(t, "walls", 0, msgs.LINE_LIST, WALL_COLOUR, scale=(0.4, 0, 0),
                           points=[p for x1, y1, x2, y2 in scene.walls for p in ((x1, y1, 0.05), (x2, y2, 0.05))]))
    for k, poly in enumerate(scene.obstacles):
        out.append(_marker(t, "obstacles", k, msgs.LINE_STRIP, OBSTACLE_COLOUR, scale=(0.6, 0, 0),
                           points=[*map(tuple, poly), tuple(poly[0])]))
    if len(scene.features):
        out.append(_marker(t, "features", 0, msgs.SPHERE_LIST, FEATURE_COLOUR, scale=(0.6, 0.6, 0.6),
                           points=[(x, y, 0.3) for x, y in scene.features]))
    for c in scene.carriers:
        out.append(_marker(t, "paths", c.index, msgs.LINE_STRIP, c.colour, 0.5, scale=(0.15, 0, 0),
                           points=[(x, y, 0.02) for x, y in c.path]))
        planned = [(x, y, 0.1) for x, y in scene.planned[c.index] if not (math.isnan(x) or math.isnan(y))]
        if planned:
            out.append(_marker(t, "decision_points", c.index, msgs.SPHERE_LIST, c.colour, 0.8,
                               scale=(0.5, 0.5, 0.5), points=planned))
    for k, group in enumerate(scene.overlaps):
        out.append(_marker(t, "overlaps", k, msgs.LINE_STRIP, OVERLAP_COLOUR, 0.8, scale=(0.2, 0, 0),
                           points=[(x, y, 0.03) for x, y in group.outline]))
        cx, cy = (float(v) for v in group.points.mean(axis=0))
        out.append(_marker(t, "overlap_members", k, msgs.TEXT_VIEW_FACING, OVERLAP_COLOUR, scale=(0, 0, 1.0),
                           at=(cx, cy, 1.5), text=", ".join(f"{cid}@{j}" for cid, j in group.members)))
    return {"markers": out}


class MissionTopics:
    """The mission stream as ROS 2 messages (see the module docstring).

    Args:
        scene: the mission's scene.
        emit: ``emit(topic, typename, msg: dict, t: float)``.
        problem: the planner problem, for the reward so far (None: no reward).
        carriers: also emit the per-carrier topics (``/<id>/pose``, ``/tf``) from the poses: the
            bag does; live, every carrier publishes its own.
    """

    def __init__(self, scene: Scene, emit, problem=None, carriers: bool = True):
        self.scene = scene
        self.emit = emit
        self.carriers = carriers
        self.tally = Tally([c.id for c in scene.carriers], len(scene.stage_times), problem)
        self.poses: dict[str, tuple] = {}  # carrier -> (x, y, heading, passengers_left)
        self.deployed: list[tuple] = []  # (carrier, stage, x, y)
        self.decided = 0
        self._second = None  # the last whole second of /clock and /mission/carriers
        t0 = min(0.0, float(scene.stage_times[0])) if len(scene.stage_times) else 0.0
        self.emit("/mission/world", "visualization_msgs/msg/MarkerArray", world_markers(scene, t0), t0)

    # ------------------------------------------------------------------ helpers
    def _json(self, topic: str, t: float, body: dict) -> None:
        self.emit(topic, "std_msgs/msg/String", {"data": json.dumps(dict(body, t=float(t)))}, t)

    def _clock(self, t: float, force: bool = False) -> None:
        """``/clock`` and ``/mission/carriers`` once per whole simulated second (and at every
        decision and deployment)."""
        second = math.floor(float(t))
        if force or second != self._second:
            self._second = second
            self.emit("/clock", "rosgraph_msgs/msg/Clock", {"clock": stamp(t)}, t)
            if self.poses:
                self.emit("/mission/carriers", "visualization_msgs/msg/MarkerArray", self.carrier_markers(t), t)

    def carrier_markers(self, t: float) -> dict:
        """Every carrier at its last pose: a cylinder turned to its heading and a label
        ``id (passengers left)``."""
        out = []
        for cid, (x, y, heading, left) in sorted(self.poses.items()):
            c = self.scene.carrier(cid)
            out.append(_marker(t, "carriers", c.index, msgs.CYLINDER, c.colour, scale=(2.0, 2.0, 1.0),
                               at=(x, y, 0.5), yaw=heading))
            out.append(_marker(t, "carrier_labels", c.index, msgs.TEXT_VIEW_FACING, c.colour, scale=(0, 0, 1.2),
                               at=(x, y, 2.5), text=f"{cid} ({left})"))
        return {"markers": out}

    def deployment_markers(self, t: float) -> dict:
        """Every deployed passenger: a sphere, its translucent sensing disc and a label."""
        out = []
        n = len(self.scene.stage_times)
        r = self.scene.sensing_radius
        for cid, j, x, y in self.deployed:
            c = self.scene.carrier(cid)
            mid = c.index * n + int(j)
            out.append(_marker(t, "passengers", mid, msgs.SPHERE, c.colour, at=(x, y, 0.5)))
            out.append(_marker(t, "sensing_discs", mid, msgs.CYLINDER, c.colour, 0.25, scale=(2 * r, 2 * r, 0.02),
                               at=(x, y, 0.01)))
            out.append(_marker(t, "passenger_labels", mid, msgs.TEXT_VIEW_FACING, c.colour, scale=(0, 0, 1.0),
                               at=(x, y, 2.0), text=f"{cid}@{j}"))
        return {"markers": out}

    def _reward(self, t: float) -> None:
        reward, _ = self.tally.reward()
        self.emit("/mission/reward", "std_msgs/msg/Float64", {"data": float(reward)}, t)

    # ------------------------------------------------------------------ the stream
    def observation(self, t, stage, carrier, x, position, passengers_left):
        self.tally.observe(carrier, stage, x)
        self._json("/mission/observations", t, observation_record(stage, carrier, x, position, passengers_left))

    def decision(self, t, stage, deploy, planning_ms):
        self.decided = max(self.decided, int(stage) + 1)
        self._json("/mission/decisions", t, decision_record(stage, deploy, planning_ms))
        self.log(t, "info", f"stage {stage}: deploy {' '.join(deploy) or '-'} (planned in {planning_ms:.1f} ms)")
        self._reward(t)
        self._clock(t, force=True)

    def confirm(self, t, stage, carrier, deployed, status, position, passengers_left):
        self._json("/mission/confirmations", t,
                   confirm_record(stage, carrier, deployed, status, position, passengers_left))
        if not deployed:
            return
        self.tally.confirm(carrier, stage, True)
        self.deployed.append((carrier, int(stage), float(position[0]), float(position[1])))
        self.log(t, "info", f"carrier {carrier} deployed a passenger at stage {stage} at "
                            f"({float(position[0]):.1f}, {float(position[1]):.1f}) m")
        self._reward(t)
        self.emit("/mission/deployments", "visualization_msgs/msg/MarkerArray", self.deployment_markers(t), t)

    def pose(self, t, carrier, position, heading, passengers_left):
        x, y = float(position[0]), float(position[1])
        self.poses[carrier] = (x, y, float(heading), int(passengers_left))
        if self.carriers:
            ns = carrier_namespace(carrier)
            self.emit(f"{ns}/pose", "geometry_msgs/msg/PoseStamped", pose_stamped(t, x, y, heading), t)
            self.emit("/tf", "tf2_msgs/msg/TFMessage", transform(t, carrier, x, y, heading), t)
        self._clock(t)

    def log(self, t, level, text):
        self.emit("/mission/log", "std_msgs/msg/String", {"data": f"[{level}] {text}"}, t)

    def end(self, t, stages, reason):
        stages = self.decided if stages is None else stages
        self.log(t, "info", f"mission {reason} after {stages} stage(s)")
