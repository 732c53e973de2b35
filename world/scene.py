"""The scene of a mission: what a viewer draws, as plain data, shared by every tool that shows one.

``build_scene(scenario)`` turns a scenario and its stage geometry into entities — the map
bounds, wall segments, solid obstacles, features, overlap groups (the hull of their planned
decision points), the carriers with their colours and planned paths — so that the MCAP file
(recording/mcap.py, Foxglove and Lichtblick) and the live view (viewer/, rerun) show the same
thing, in the same colours as map.png (world/render.py).

Units: metres in the scenario's map frame (x east, y north), seconds of simulated mission time.
Imports numpy and world/ only (no matplotlib, no zenoh).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from world.features import sample_features
from world.stages import stage_geometry

#: Carrier colours, in carrier order (cycled); map.png uses the same.
CARRIER_COLOURS = ("#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#17becf", "#8c564b", "#e377c2")
#: Colours of the other entities (hex RGB).
OVERLAP_COLOUR = "#7b3fa0"
WALL_COLOUR = "#303030"
OBSTACLE_COLOUR = "#9a9a9a"
FEATURE_COLOUR = "#e6b800"


def rgb(hex_colour: str) -> tuple[int, int, int]:
    """``"#rrggbb"`` as 0..255 integers."""
    h = hex_colour.lstrip("#")
    return int(h[0:2], 16), int(h[2:4], 16), int(h[4:6], 16)


def carrier_colour(r: int) -> str:
    """Hex colour of the carrier with index ``r``."""
    return CARRIER_COLOURS[r % len(CARRIER_COLOURS)]


@dataclass(frozen=True)
class SceneCarrier:
    """One carrier as drawn.

    Attributes:
        id: carrier id.
        index: r, its index in the scenario.
        colour: hex RGB.
        passengers: passengers on board at the start (count).
        path: float ``[K, 2]`` its waypoints (m).
        start_time, stop_time: when it drives (s).
    """

    id: str
    index: int
    colour: str
    passengers: int
    path: np.ndarray
    start_time: float
    stop_time: float


@dataclass(frozen=True)
class SceneOverlap:
    """One overlap group (a maximal clique of planned decision points within the conflict radius).

    Attributes:
        members: the ``(carrier id, stage)`` pairs of the group.
        points: float ``[M, 2]`` their planned positions (m).
        outline: float ``[K, 2]`` a closed outline around them (m): the hull grown by
            ``margin``, or a circle when the points are collinear.
    """

    members: tuple[tuple[str, int], ...]
    points: np.ndarray
    outline: np.ndarray


@dataclass(frozen=True, eq=False)
class Scene:
    """Everything static about a mission, ready to draw.

    Attributes:
        name: scenario name.
        bounds: (xmin, ymin, xmax, ymax) of the map (m).
        walls: float ``[W, 4]`` wall segments (x1, y1, x2, y2) (m), obstacle edges included.
        obstacles: closed polygons ``[K, 2]`` (m), solid.
        features: float ``[F, 2]`` feature positions for the mission's seed (m).
        sensing_radius: m.
        carriers: one :class:`SceneCarrier` per carrier, in scenario order.
        overlaps: the overlap groups.
        stage_times: float ``[N]`` (s).
        planned: float ``[R, N, 2]`` planned decision points (m), NaN where not scheduled.
        links: the link model's name (``perfect``: no base, no relays).
        base: (x, y) the coordinator's antenna or modem (m); None on perfect links.
        relays: the relays the carriers drop (:class:`world.relays.Relay`: carrier, position,
            planned drop time), in order.
        voxels: float32 ``[K, 4]`` a 3D import's map (``map.voxels``): x, y, z (m) and kind (0
            occupied, 1 frontier voxel), at most :data:`MAX_SCENE_VOXELS` (every k-th of each
            kind beyond); empty without one. Walls: every storey's, overlaid.
    """

    name: str
    bounds: tuple[float, float, float, float]
    walls: np.ndarray
    obstacles: tuple[np.ndarray, ...]
    features: np.ndarray
    sensing_radius: float
    carriers: tuple[SceneCarrier, ...]
    overlaps: tuple[SceneOverlap, ...]
    stage_times: np.ndarray
    planned: np.ndarray
    links: str = "perfect"
    base: tuple[float, float] | None = None
    relays: tuple = ()
    voxels: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), dtype=np.float32))

    def carrier(self, cid: str) -> SceneCarrier:
        """The carrier ``cid`` (KeyError for an unknown id); a lookup, not a scan: the recorders
        ask once per Pose and per confirmation."""
        return self._by_id[cid]

    @functools.cached_property
    def _by_id(self) -> dict[str, SceneCarrier]:
        return {c.id: c for c in self.carriers}

    def stage_time(self, j: int) -> float:
        return float(self.stage_times[j])


def outline(points: np.ndarray, margin: float, segments: int = 24) -> np.ndarray:
    """A closed outline (first point repeated last) around ``points`` ``[M, 2]``: the convex hull
    pushed out by ``margin`` metres (the Minkowski sum with a disc, approximated by ``segments``
    directions)."""
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    angles = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    ring = np.column_stack([np.cos(angles), np.sin(angles)]) * margin
    cloud = (pts[:, None, :] + ring[None, :, :]).reshape(-1, 2)
    hull = convex_hull(cloud)
    return np.vstack([hull, hull[:1]])


def convex_hull(points: np.ndarray) -> np.ndarray | None:
    """Convex hull (counter-clockwise) of ``[K, 2]`` points, or None if they are collinear."""
    pts = sorted(set(map(tuple, np.round(points, 9))))
    if len(pts) < 3:
        return None

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    lower: list = []
    for p in pts:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], p) <= 0:
            lower.pop()
        lower.append(p)
    upper: list = []
    for p in reversed(pts):
        while len(upper) >= 2 and cross(upper[-2], upper[-1], p) <= 0:
            upper.pop()
        upper.append(p)
    hull = lower[:-1] + upper[:-1]
    return np.asarray(hull) if len(hull) >= 3 else None


def build_scene(scenario, seed: int | None = None) -> Scene:
    """The scene of ``scenario`` (features drawn with ``seed``, the scenario's by default)."""
    geometry = stage_geometry(scenario)
    ids = scenario.carrier_ids
    carriers = tuple(
        SceneCarrier(c.id, r, carrier_colour(r), int(c.passengers), np.asarray(c.waypoints, dtype=float),
                     float(c.start_time), float(c.stop_time))
        for r, c in enumerate(scenario.carriers))
    margin = 0.5 * float(scenario.sensing_radius)
    overlaps = []
    for group in geometry.overlaps:
        pts = np.array([geometry.positions[r, j] for r, j in group], dtype=float)
        overlaps.append(SceneOverlap(tuple((ids[r], int(j)) for r, j in group), pts, outline(pts, margin)))
    return Scene(
        name=scenario.name,
        bounds=tuple(float(v) for v in scenario.map.bounds),
        walls=np.concatenate([np.asarray(scenario.map.segments, dtype=float).reshape(-1, 4)]
                             + [scenario.map.carrier_segments(st.name)[len(scenario.map.segments):]
                                for st in scenario.map.storeys]),
        obstacles=tuple(np.asarray(p, dtype=float) for p in scenario.map.obstacles),
        features=np.asarray(sample_features(scenario, seed), dtype=float).reshape(-1, 2),
        sensing_radius=float(scenario.sensing_radius),
        carriers=carriers,
        overlaps=tuple(overlaps),
        stage_times=np.asarray(scenario.stage_times(), dtype=float),
        planned=geometry.positions,
        voxels=_voxels(scenario),
        **_links(scenario),
    )


#: Most voxels a scene carries (each kind thinned to every k-th beyond its share).
MAX_SCENE_VOXELS = 400_000


def _voxels(scenario) -> np.ndarray:
    """The occupied and frontier voxels' centres of a 3D import's map (module docstring)."""
    spec = scenario.map.voxels
    if spec is None:
        return np.zeros((0, 4), dtype=np.float32)
    from world import voxels as V

    grid = V.read_octomap(spec.path)
    out = []
    for kind, mask in ((0, grid.classes == V.OCCUPIED), (1, V.frontier_mask(grid.classes, spec.neighbours))):
        pts = grid.centres(mask)
        step = max(1, -(-len(pts) // (MAX_SCENE_VOXELS // 2)))
        pts = pts[::step]
        out.append(np.column_stack([pts, np.full(len(pts), kind)]))
    return np.concatenate(out).astype(np.float32)


def _links(scenario) -> dict:
    """The scene's link fields: the model, the base and the relays (none on perfect links)."""
    if scenario.links.model == "perfect":
        return {}
    from world.links import LinkModel
    from world.relays import fleet_relays

    model = LinkModel(scenario)
    return {"links": scenario.links.model, "base": tuple(map(float, model.base)), "relays": fleet_relays(model)}
