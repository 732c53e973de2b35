"""A mission in rerun: the scene and the mission stream as rerun entities on a ``sim_time`` timeline.

Entity layout (all positions in the map frame, metres; the 2D view shows north up):

=============================  ================  ===========================================
entity                         archetype         what
=============================  ================  ===========================================
world/bounds, world/walls      LineStrips2D      the map (static)
world/features                 Points2D          features of interest (static)
world/paths/<id>               LineStrips2D      planned paths in carrier colours (static)
world/overlaps                 LineStrips2D      overlap groups' outlines (static)
world/links/base, world/links/relays Points2D   the base and the relays dropped (static; links not perfect)
world/carriers/<id>            Points2D          each carrier, labelled ``id (passengers left)``
world/trails/<id>              LineStrips2D      where it drove (from its poses)
world/observations/<id>        LineStrips2D      its sensing circle at its last observation, ``x=…``
world/deployments/<id>/<j>     Points2D          a deployed passenger and its sensing disc
voxels                         Points3D          a 3D import's occupied (grey) and frontier (red)
                                                 voxels (static), in a 3D view beside the map
reward                         Scalars           reward so far (penalty rule, confirmed only)
log                            TextLog           joins, decisions, deployments, the end
=============================  ================  ===========================================

Time: every call sets ``sim_time`` (a duration timeline, seconds of simulated mission time).
"""
from __future__ import annotations

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from recording.stream import Sink, Tally
from world.scene import FEATURE_COLOUR, OVERLAP_COLOUR, WALL_COLOUR, Scene, rgb

TIMELINE = "sim_time"
#: Trail points kept per carrier (older ones are dropped from the drawn trail).
MAX_TRAIL_POINTS = 4000


def blueprint(voxels: bool = False) -> rrb.Blueprint:
    """The map large on the left, reward and the log on the right, time panel below; with
    ``voxels`` (a 3D import) the voxels in a 3D view under the map."""
    view = rrb.Spatial2DView(origin="/world", name="mission map")
    if voxels:
        view = rrb.Vertical(view, rrb.Spatial3DView(origin="/voxels", name="voxels (3D)"))
    return rrb.Blueprint(
        rrb.Horizontal(
            view,
            rrb.Vertical(rrb.TimeSeriesView(origin="/reward", name="reward so far"),
                         rrb.TextLogView(origin="/log", name="events")),
            column_shares=[3, 1]),
        rrb.BlueprintPanel(state="collapsed"), rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(state="expanded", timeline=TIMELINE, play_state="following"),
    )


def _light(colour: tuple[int, int, int], keep: float = 0.3) -> tuple[int, int, int]:
    """``colour`` mixed with white (``keep`` of the colour): an opaque stand-in for a translucent fill."""
    return tuple(int(round(255 - (255 - c) * keep)) for c in colour)


def _circle(x: float, y: float, r: float, n: int = 48) -> np.ndarray:
    a = np.linspace(0, 2 * np.pi, n + 1)
    return np.column_stack([x + r * np.cos(a), y + r * np.sin(a)])


class RerunView(Sink):
    """Logs a mission into a rerun ``RecordingStream``.

    Args:
        rec: the recording stream (its sinks decide where the data goes: a web viewer, a file).
        scene: the mission's :class:`world.scene.Scene`.
        problem: the planner problem, for the reward so far (None: no reward plot).
    """

    def __init__(self, rec: rr.RecordingStream, scene: Scene, problem=None):
        self.rec = rec
        self.scene = scene
        self.tally = Tally([c.id for c in scene.carriers], len(scene.stage_times), problem)
        self.trails: dict[str, list] = {}
        self.decided = 0
        self._static()

    def _at(self, t: float) -> None:
        self.rec.set_time(TIMELINE, duration=float(t))

    def _static(self) -> None:
        s, rec = self.scene, self.rec
        # North up: the 2D view's y axis points down, so the world is mirrored once at its root.
        rec.log("world", rr.Transform3D(scale=[1.0, -1.0, 1.0]), static=True)
        xmin, ymin, xmax, ymax = s.bounds
        rec.log("world/bounds", rr.LineStrips2D([[(xmin, ymin), (xmax, ymin), (xmax, ymax), (xmin, ymax), (xmin, ymin)]],
                                                radii=0.15, colors=[(128, 128, 128)]), static=True)
        if len(s.walls):
            rec.log("world/walls", rr.LineStrips2D([[(a, b), (c, d)] for a, b, c, d in s.walls], radii=0.35,
                                                   colors=[rgb(WALL_COLOUR)]), static=True)
        if len(s.voxels):
            frontier = s.voxels[:, 3] == 1
            rec.log("voxels", rr.Points3D(s.voxels[:, :3], radii=0.05,
                                          colors=np.where(frontier[:, None], [[214, 39, 40]], [[150, 150, 150]])),
                    static=True)
        if len(s.features):
            rec.log("world/features", rr.Points2D(s.features, radii=0.35, colors=[rgb(FEATURE_COLOUR)]), static=True)
        for c in s.carriers:
            rec.log(f"world/paths/{c.id}", rr.LineStrips2D([c.path], radii=0.12, colors=[rgb(c.colour) + (90,)]),
                    static=True)
        if s.overlaps:
            rec.log("world/overlaps", rr.LineStrips2D([g.outline for g in s.overlaps], radii=0.12,
                                                      colors=[rgb(OVERLAP_COLOUR) + (160,)]), static=True)
        if s.base is not None:
            rec.log("world/links/base", rr.Points2D([s.base], radii=1.5, colors=[(26, 26, 26)],
                                                    labels=[f"base ({s.links})"]), static=True)
        if s.relays:
            rec.log("world/links/relays", rr.Points2D([r.position for r in s.relays], radii=1.0,
                                                      colors=[rgb(s.carrier(r.carrier).colour) for r in s.relays]),
                    static=True)

    # ------------------------------------------------------------------ the stream
    def pose(self, t, carrier, position, heading, passengers_left):
        c = self.scene.carrier(carrier)
        x, y = float(position[0]), float(position[1])
        self._at(t)
        self.rec.log(f"world/carriers/{carrier}", rr.Points2D(
            [(x, y)], radii=1.6, colors=[rgb(c.colour)], labels=[f"{carrier} ({passengers_left})"], show_labels=True,
            draw_order=30.0))
        trail = self.trails.setdefault(carrier, [])
        trail.append((x, y))
        del trail[:-MAX_TRAIL_POINTS]
        self.rec.log(f"world/trails/{carrier}", rr.LineStrips2D([trail], radii=0.35, colors=[rgb(c.colour)],
                                                                 draw_order=20.0))

    def observation(self, t, stage, carrier, x, position, passengers_left):
        self.tally.observe(carrier, stage, x)
        if x is None:
            return
        c = self.scene.carrier(carrier)
        self._at(t)
        self.rec.log(f"world/observations/{carrier}", rr.LineStrips2D(
            [_circle(float(position[0]), float(position[1]), self.scene.sensing_radius)], radii=0.15,
            colors=[rgb(c.colour)], labels=[f"x={x}"], show_labels=False, draw_order=25.0))

    def decision(self, t, stage, deploy, planning_ms):
        self.decided = max(self.decided, int(stage) + 1)
        self._at(t)
        self.rec.log("log", rr.TextLog(f"stage {stage}: deploy {' '.join(deploy) or '-'} ({planning_ms:.1f} ms)",
                                       level="INFO"))
        self._reward(t)

    def confirm(self, t, stage, carrier, deployed, status, position, passengers_left):
        if not deployed:
            return
        self.tally.confirm(carrier, stage, True)
        c = self.scene.carrier(carrier)
        x, y = float(position[0]), float(position[1])
        self._at(t)
        base = f"world/deployments/{carrier}/{stage}"
        self.rec.log(f"{base}/disc", rr.Points2D([(x, y)], radii=self.scene.sensing_radius,
                                                 colors=[_light(rgb(c.colour))], draw_order=5.0))
        self.rec.log(f"{base}/passenger", rr.Points2D([(x, y)], radii=0.9, colors=[rgb(c.colour)],
                                                      labels=[f"{carrier}@{stage}"], draw_order=28.0))
        self.rec.log("log", rr.TextLog(f"{carrier} deployed a passenger at stage {stage} ({x:.1f}, {y:.1f}) m",
                                       level="INFO"))
        self._reward(t)

    def log(self, t, level, text):
        self._at(t)
        self.rec.log("log", rr.TextLog(str(text), level={"warning": "WARN", "error": "ERROR"}.get(level, "INFO")))

    def end(self, t, stages, reason):
        self.log(t, "info", f"mission {reason} after {self.decided if stages is None else stages} stage(s)")

    def _reward(self, t) -> None:
        if self.tally.problem is None:
            return
        reward, _features = self.tally.reward()
        self._at(t)
        self.rec.log("reward", rr.Scalars(float(reward)))
