"""mission.mcap: a mission as an MCAP file (the ROS 2 bag format) with Foxglove's well-known schemas.

Written with foxglove-sdk into its own ``foxglove.Context`` (nothing leaks into the global one),
incrementally, in zstd chunks of at most :data:`CHUNK_BYTES`, flushed after every decision, so
that a writer killed without closing still leaves a readable prefix (read it with
``mcap.stream_reader.StreamReader``); a closed file has a summary section and reads with
``mcap.reader.make_reader``.

Every message's log time is the simulated mission time in nanoseconds (t = 0 is the mission's
time origin, shown by Foxglove as 1970-01-01T00:00:00Z), and entity and log timestamps carry the
same time. The frame of everything is ``map`` (metres, x east, y north, z up).

Channels (docs/fleet.md, "mission.mcap"):

=================  =======================  ==============================================
topic              schema                   what
=================  =======================  ==============================================
/world             foxglove.SceneUpdate     the map once at t = 0: bounds, walls, obstacles,
                                            features, planned paths, overlap groups, the
                                            links' base and relays (drop time as metadata)
/world/voxels      foxglove.PointCloud      a 3D import's map once at t = 0 (only then):
                                            occupied voxels grey, frontier voxels red
/carriers          foxglove.SceneUpdate     each carrier as a labelled entity, per pose
/tf                foxglove.FrameTransform  map -> <carrier id>, per pose
/deployments       foxglove.SceneUpdate     each deployed passenger with its sensing disc
/observations      marsupial.Observation    one per observation received (JSON)
/decisions         marsupial.Decision       one per stage decided (JSON)
/confirmations     marsupial.Confirm        one per Confirm accepted (JSON)
/reward            marsupial.Reward         the reward so far after each decision and
                                            each deployment (JSON)
/operator          marsupial.Operator       operator mode: each action taken, and how each
                                            stage's hold ended (JSON)
/log               foxglove.Log             mission events as text lines
=================  =======================  ==============================================
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import foxglove
import numpy as np
from foxglove import channels as fch
from foxglove.mcap import MCAPWriteOptions
from foxglove.messages import (
    Color, CylinderPrimitive, FrameTransform, LinePrimitive, LinePrimitiveLineType, Log, LogLevel, Point3, Pose,
    Quaternion, SceneEntity, SceneUpdate, SpherePrimitive, TextPrimitive, Timestamp, Vector3,
)

from mission.records import Tally, confirm_record, decision_record, observation_record
from recording.stream import Sink
from world.scene import FEATURE_COLOUR, OBSTACLE_COLOUR, OVERLAP_COLOUR, WALL_COLOUR, Scene, rgb

#: Target uncompressed size of one MCAP chunk (bytes): small, so a killed writer loses little.
CHUNK_BYTES = 64 * 1024
#: The MCAP header's profile (empty: Foxglove's own schemas, no ROS message definitions).
PROFILE = ""
FRAME = "map"

_LEVELS = {"debug": LogLevel.Debug, "info": LogLevel.Info, "warning": LogLevel.Warning, "error": LogLevel.Error}

#: JSON schemas of the mission's own channels (field meanings: docs/protocol.md).
JSON_SCHEMAS = {
    "/observations": ("marsupial.Observation", {
        "type": "object", "properties": {
            "t": {"type": "number", "description": "stage time t_j, s"},
            "stage": {"type": "integer"}, "carrier": {"type": "string"},
            "x": {"type": ["integer", "null"], "description": "features sensed; null = not scheduled"},
            "position": {"type": "array", "items": {"type": "number"}, "description": "[x, y] m"},
            "passengers_left": {"type": "integer"}}}),
    "/decisions": ("marsupial.Decision", {
        "type": "object", "properties": {
            "t": {"type": "number", "description": "stage time t_j, s"}, "stage": {"type": "integer"},
            "deploy": {"type": "array", "items": {"type": "string"}, "description": "carriers that deploy now"},
            "planning_ms": {"type": "number"}}}),
    "/confirmations": ("marsupial.Confirm", {
        "type": "object", "properties": {
            "t": {"type": "number"}, "stage": {"type": "integer"}, "carrier": {"type": "string"},
            "deployed": {"type": "boolean"}, "status": {"type": "string"},
            "position": {"type": "array", "items": {"type": "number"}}, "passengers_left": {"type": "integer"}}}),
    "/operator": ("marsupial.Operator", {
        "type": "object", "properties": {
            "t": {"type": "number", "description": "stage time t_j, s"}, "stage": {"type": "integer"},
            "kind": {"type": "string", "description": "action (an operator's action) or decision (the stage's outcome)"},
            "action": {"type": "string", "description": "approve, veto or force"},
            "carrier": {"type": ["string", "null"]}, "operator": {"type": "string", "description": "who sent it"},
            "deploy": {"type": "array", "items": {"type": "string"}},
            "recommended": {"type": "array", "items": {"type": "string"}},
            "forced": {"type": "array", "items": {"type": "string"}},
            "vetoed": {"type": "array", "items": {"type": "string"}},
            "hold": {"type": "string", "description": "approved, timeout or watching"},
            "gain": {"type": ["number", "null"], "description": "planner's estimate, normalised reward"}}}),
    "/reward": ("marsupial.Reward", {
        "type": "object", "properties": {
            "t": {"type": "number"}, "reward": {"type": "number", "description": "normalised, penalty rule"},
            "features": {"type": "number", "description": "raw sum of x/p"},
            "deployments": {"type": "integer"}}}),
}


def ns(t: float) -> int:
    """Simulated time ``t`` (s) as a log time in nanoseconds (clamped at 0)."""
    return max(0, int(round(float(t) * 1e9)))


def stamp(t: float) -> Timestamp:
    n = ns(t)
    return Timestamp(sec=n // 1_000_000_000, nsec=n % 1_000_000_000)


def colour(hex_colour: str, alpha: float = 1.0) -> Color:
    r, g, b = rgb(hex_colour)
    return Color(r=r / 255, g=g / 255, b=b / 255, a=float(alpha))


def _point(x, y, z=0.0) -> Point3:
    return Point3(x=float(x), y=float(y), z=float(z))


def _pose(x, y, z=0.0, yaw=0.0) -> Pose:
    return Pose(position=Vector3(x=float(x), y=float(y), z=float(z)),
                orientation=Quaternion(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)))


def _line(points, hex_colour, thickness, kind=LinePrimitiveLineType.LineStrip, alpha=1.0, z=0.0) -> LinePrimitive:
    return LinePrimitive(type=kind, pose=_pose(0, 0), thickness=float(thickness), scale_invariant=False,
                         points=[_point(x, y, z) for x, y in points], color=colour(hex_colour, alpha))


def _text(x, y, z, text, hex_colour="#000000", size=14.0) -> TextPrimitive:
    return TextPrimitive(pose=_pose(x, y, z), billboard=True, font_size=size, scale_invariant=True,
                         color=colour(hex_colour), text=text)


def voxel_cloud(scene: Scene, t: float):
    """A 3D import's voxels as a foxglove.PointCloud: float32 x, y, z and uint8 RGBA (occupied
    grey, frontier red)."""
    from foxglove.messages import PackedElementField, PackedElementFieldNumericType, PointCloud

    v = scene.voxels
    rec = np.zeros(len(v), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"),
                                  ("blue", "u1"), ("alpha", "u1")])
    rec["x"], rec["y"], rec["z"] = v[:, 0], v[:, 1], v[:, 2]
    frontier = v[:, 3] == 1
    rec["red"] = np.where(frontier, 214, 150)
    rec["green"] = np.where(frontier, 39, 150)
    rec["blue"] = np.where(frontier, 40, 150)
    rec["alpha"] = 255
    F, U = PackedElementFieldNumericType.Float32, PackedElementFieldNumericType.Uint8
    fields = [PackedElementField(name=n, offset=o, type=F) for n, o in (("x", 0), ("y", 4), ("z", 8))]
    fields += [PackedElementField(name=n, offset=12 + k, type=U) for k, n in enumerate(("red", "green", "blue", "alpha"))]
    return PointCloud(timestamp=stamp(t), frame_id=FRAME, pose=_pose(0.0, 0.0), point_stride=16, fields=fields,
                      data=rec.tobytes())


def world_entities(scene: Scene, t: float) -> list[SceneEntity]:
    """The static scene as SceneEntities (frame ``map``, never expiring)."""
    ts = stamp(t)
    xmin, ymin, xmax, ymax = scene.bounds
    ents = [SceneEntity(timestamp=ts, frame_id=FRAME, id="map/bounds", lines=[_line(
        [(xmin, ymin), (xmax, ymin), (xmax, ymax), (xmin, ymax)], "#808080", 0.2, LinePrimitiveLineType.LineLoop)])]
    wall_points = [p for x1, y1, x2, y2 in scene.walls for p in ((x1, y1), (x2, y2))]
    if wall_points:
        ents.append(SceneEntity(timestamp=ts, frame_id=FRAME, id="map/walls", lines=[_line(
            wall_points, WALL_COLOUR, 0.4, LinePrimitiveLineType.LineList, z=0.05)]))
    for k, poly in enumerate(scene.obstacles):
        ents.append(SceneEntity(timestamp=ts, frame_id=FRAME, id=f"map/obstacle/{k}", lines=[_line(
            poly, OBSTACLE_COLOUR, 0.6, LinePrimitiveLineType.LineLoop, z=0.05)]))
    if len(scene.features):
        ents.append(SceneEntity(timestamp=ts, frame_id=FRAME, id="map/features", spheres=[
            SpherePrimitive(pose=_pose(x, y, 0.3), size=Vector3(x=0.6, y=0.6, z=0.6), color=colour(FEATURE_COLOUR))
            for x, y in scene.features]))
    for c in scene.carriers:
        ents.append(SceneEntity(timestamp=ts, frame_id=FRAME, id=f"path/{c.id}", lines=[_line(
            c.path, c.colour, 0.15, alpha=0.5, z=0.02)]))
    for k, group in enumerate(scene.overlaps):
        label = ", ".join(f"{cid}@{j}" for cid, j in group.members)
        ents.append(SceneEntity(timestamp=ts, frame_id=FRAME, id=f"overlap/{k}", lines=[_line(
            group.outline, OVERLAP_COLOUR, 0.2, LinePrimitiveLineType.LineStrip, alpha=0.8, z=0.03)],
            metadata=[foxglove.messages.KeyValuePair(key="members", value=label)]))
    ents.extend(link_entities(scene, ts))
    return ents


def link_entities(scene: Scene, ts) -> list[SceneEntity]:
    """The base (``links/base``) and each relay (``links/relay/<carrier>/<k>``, in its carrier's
    colour, its planned drop time as metadata ``dropped_at_s``) when the scene has a link model."""
    if scene.base is None:
        return []
    x, y = scene.base
    ents = [SceneEntity(timestamp=ts, frame_id=FRAME, id="links/base", texts=[_text(x, y, 1.0, f"base ({scene.links})")],
                        spheres=[SpherePrimitive(pose=_pose(x, y, 0.5), size=Vector3(x=3.0, y=3.0, z=3.0),
                                                 color=colour("#1a1a1a"))])]
    for relay in scene.relays:
        rx, ry = relay.position
        ents.append(SceneEntity(
            timestamp=ts, frame_id=FRAME, id=f"links/relay/{relay.carrier}/{relay.index}",
            spheres=[SpherePrimitive(pose=_pose(rx, ry, 0.5), size=Vector3(x=2.0, y=2.0, z=2.0),
                                     color=colour(scene.carrier(relay.carrier).colour))],
            metadata=[foxglove.messages.KeyValuePair(key="dropped_at_s", value=f"{relay.time:.3f}")]))
    return ents


class McapRecorder(Sink):
    """Writes one mission into an MCAP file as the stream arrives (see the module docstring).

    Args:
        path: the file (overwritten).
        scene: the mission's :class:`world.scene.Scene` (logged on ``/world`` at t = 0).
        problem: the planner problem, for the reward so far (None: no ``/reward`` values).
        metadata: strings written as the MCAP metadata record ``mission``.
    """

    def __init__(self, path, scene: Scene, problem=None, metadata: dict | None = None):
        self.path = Path(path)
        self.scene = scene
        self.ctx = foxglove.Context()
        self.writer = foxglove.open_mcap(
            str(self.path), allow_overwrite=True, context=self.ctx,
            writer_options=MCAPWriteOptions(chunk_size=CHUNK_BYTES, profile=PROFILE))
        self.world = fch.SceneUpdateChannel("/world", context=self.ctx)
        self.carriers = fch.SceneUpdateChannel("/carriers", context=self.ctx)
        self.tf = fch.FrameTransformChannel("/tf", context=self.ctx)
        self.deployments = fch.SceneUpdateChannel("/deployments", context=self.ctx)
        self.logs = fch.LogChannel("/log", context=self.ctx)
        self.json = {
            topic: foxglove.Channel(topic, schema=foxglove.Schema(
                name=name, encoding="jsonschema", data=json.dumps(schema).encode()), message_encoding="json",
                context=self.ctx)
            for topic, (name, schema) in JSON_SCHEMAS.items()}
        self.tally = Tally([c.id for c in scene.carriers], len(scene.stage_times), problem)
        self.decided = 0
        self.closed = False
        if metadata:
            self.writer.write_metadata("mission", {str(k): str(v) for k, v in metadata.items()})
        t0 = min(0.0, float(scene.stage_times[0])) if len(scene.stage_times) else 0.0  # before the first pose
        self.world.log(SceneUpdate(entities=world_entities(scene, t0)), log_time=ns(t0))
        if len(scene.voxels):
            fch.PointCloudChannel("/world/voxels", context=self.ctx).log(voxel_cloud(scene, t0), log_time=ns(t0))

    # ------------------------------------------------------------------ the stream
    def _json(self, topic: str, t: float, body: dict) -> None:
        self.json[topic].log(dict(body, t=float(t)), log_time=ns(t))

    def observation(self, t, stage, carrier, x, position, passengers_left):
        self.tally.observe(carrier, stage, x)
        self._json("/observations", t, observation_record(stage, carrier, x, position, passengers_left))

    def decision(self, t, stage, deploy, planning_ms):
        self.decided = max(self.decided, int(stage) + 1)
        self._json("/decisions", t, decision_record(stage, deploy, planning_ms))
        self.log(t, "info", f"stage {stage}: deploy {' '.join(deploy) or '-'} (planned in {planning_ms:.1f} ms)")
        self._reward(t)
        self.writer.flush()

    def confirm(self, t, stage, carrier, deployed, status, position, passengers_left):
        self._json("/confirmations", t, confirm_record(stage, carrier, deployed, status, position, passengers_left))
        if not deployed:
            return
        self.tally.confirm(carrier, stage, True)
        c = self.scene.carrier(carrier)
        x, y = float(position[0]), float(position[1])
        r = self.scene.sensing_radius
        self.deployments.log(SceneUpdate(entities=[SceneEntity(
            timestamp=stamp(t), frame_id=FRAME, id=f"passenger/{carrier}/{stage}",
            spheres=[SpherePrimitive(pose=_pose(x, y, 0.5), size=Vector3(x=1.0, y=1.0, z=1.0), color=colour(c.colour))],
            cylinders=[CylinderPrimitive(pose=_pose(x, y, 0.01), size=Vector3(x=2 * r, y=2 * r, z=0.02),
                                         bottom_scale=1.0, top_scale=1.0, color=colour(c.colour, 0.25))],
            texts=[_text(x, y, 2.0, f"{carrier}@{stage}", c.colour, 12.0)])]), log_time=ns(t))
        self.log(t, "info", f"carrier {carrier} deployed a passenger at stage {stage} at ({x:.1f}, {y:.1f}) m")
        self._reward(t)

    def pose(self, t, carrier, position, heading, passengers_left):
        c = self.scene.carrier(carrier)
        x, y = float(position[0]), float(position[1])
        self.tf.log(FrameTransform(timestamp=stamp(t), parent_frame_id=FRAME, child_frame_id=carrier,
                                   translation=Vector3(x=x, y=y, z=0.0),
                                   rotation=Quaternion(x=0.0, y=0.0, z=math.sin(heading / 2), w=math.cos(heading / 2))),
                    log_time=ns(t))
        self.carriers.log(SceneUpdate(entities=[SceneEntity(
            timestamp=stamp(t), frame_id=FRAME, id=f"carrier/{carrier}",
            cylinders=[CylinderPrimitive(pose=_pose(x, y, 0.5, heading), size=Vector3(x=2.0, y=2.0, z=1.0),
                                         bottom_scale=1.0, top_scale=1.0, color=colour(c.colour))],
            texts=[_text(x, y, 2.5, f"{carrier} ({passengers_left})", c.colour, 14.0)])]), log_time=ns(t))

    def log(self, t, level, text):
        self.logs.log(Log(timestamp=stamp(t), level=_LEVELS.get(level, LogLevel.Info), message=str(text),
                          name="marsupial"), log_time=ns(t))

    def end(self, t, stages, reason):
        stages = self.decided if stages is None else stages
        self.log(t, "info", f"mission {reason} after {stages} stage(s)")

    def operator(self, t, record):
        self._json("/operator", t, record)
        if record.get("kind") == "action":
            self.log(t, "info", f"stage {record['stage']}: operator {record['operator']} {record['action']}"
                                f"{' ' + record['carrier'] if record.get('carrier') else ''}")

    def _reward(self, t) -> None:
        reward, features = self.tally.reward()
        self._json("/reward", t, {"reward": float(reward), "features": float(features),
                                  "deployments": int(self.tally.deployed.sum())})

    # ------------------------------------------------------------------ finalisation
    def close(self) -> None:
        """Write the summary section and close the file (idempotent)."""
        if self.closed:
            return
        self.closed = True
        self.writer.close()
