"""Scenario files: the schema, loading with full validation, and the value types.

A scenario is a YAML mapping (every field and its unit is documented in ``docs/scenario.md``).
:func:`load_scenario` validates the whole file and collects *every* problem before raising
:class:`ScenarioError`, one line per problem::

    FILE: field.path: expected WHAT, found WHAT

Units: metres (m), seconds (s), metres per second (m/s), features per square metre (1/m²).
"""
from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any, Literal, overload

import numpy as np
import yaml

from planner import links as _links
from planner import priors
from planner import registry as planners
from planner.limits import MAX_CARRIERS, MAX_PASSENGERS, MAX_STAGES
from validation import MISSING, Found, Number, Flaws, Text, did_you_mean
from world import building as _building
from world import geometry
from world.current import CurrentSpec, check_current
from world import grid as _grid

#: Default conflict radius as a multiple of the sensing radius (the paper's choice).
CONFLICT_RADIUS_FACTOR = 3.0
#: Sanity limits that keep a mistyped number from exhausting memory or time. Stages, carriers and
#: passengers share planner.limits with the wire, so a valid scenario's messages always encode.
MAX_COORDINATE = 1e6  # m
MAX_EXPECTED_FEATURES = 2e6  # expected features over the whole map (density x area)
MAX_MISSION_TIME = 1e5  # s, time of the last stage (the physics runs at 20 steps per second)
#: Carrier body radius (m): paths must keep at least this clearance from walls.
CARRIER_RADIUS = 0.4


#: Explicit prior kinds (shared with the planner's instance format, see planner/priors.py).
PRIOR_KINDS = tuple(priors.PRIOR_KINDS)


class ScenarioError(ValueError):
    """A scenario file is wrong. ``problems`` holds one line per problem."""

    def __init__(self, problems: list[str]):
        self.problems = list(problems)
        super().__init__("\n".join(self.problems))


# --------------------------------------------------------------------------- value types


@dataclass(frozen=True)
class Building:
    """A rooms-and-corridors building: a grid of ``cols x rows`` rectangular rooms separated and
    surrounded by corridors, inside an outer wall.

    Attributes:
        origin: lower-left corner of the outer wall (m).
        cols, rows: number of rooms along x and y.
        room_size: (width, height) of each room (m).
        corridor_width: width of every corridor (m).
        door_width: width of the door gap in the middle of each room wall (m).
        entrances: sides of the outer wall with an entrance ("west", "east", "south", "north").
    """

    origin: tuple[float, float]
    cols: int
    rows: int
    room_size: tuple[float, float]
    corridor_width: float
    door_width: float
    entrances: tuple[str, ...]

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) of the outer wall (m)."""
        return _building.extent(self)

    def room_rect(self, col: int, row: int) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) of room (col, row) (m)."""
        return _building.room_rect(self, col, row)


@dataclass(frozen=True)
class MapSpec:
    """The map.

    Attributes:
        bounds: (xmin, ymin, xmax, ymax) of the world (m). Features live inside.
        walls: polylines ((x, y), ...) (m) given in the file.
        obstacles: closed polygons ((x, y), ...) (m): solid, no features inside.
        building: optional generated building; its walls are added to ``segments``.
        occupancy: optional occupancy grid (``map.occupancy``, a map_server map): drawn under
            the map and the source of ``features.from_map``; its walls are the file's ``walls``
            (``python -m world import`` writes them from the occupied cells).
    """

    bounds: tuple[float, float, float, float]
    walls: tuple[tuple[tuple[float, float], ...], ...] = ()
    obstacles: tuple[tuple[tuple[float, float], ...], ...] = ()
    building: Building | None = None
    occupancy: _grid.OccupancyGrid | None = None
    storeys: tuple["Storey", ...] = ()
    voxels: "VoxelsSpec | None" = None

    def storey(self, name: str) -> "Storey | None":
        return next((s for s in self.storeys if s.name == name), None)

    def carrier_segments(self, storey: str = "") -> np.ndarray:
        """float ``[W, 4]``: the walls a carrier on ``storey`` meets: :attr:`segments` and its
        storey's walls ("": none)."""
        st = self.storey(storey) if storey else None
        if st is None or not st.walls:
            return self.segments
        segs = [(a[0], a[1], b[0], b[1]) for line in st.walls for a, b in zip(line[:-1], line[1:])]
        return np.concatenate([self.segments, np.asarray(segs, dtype=float).reshape(-1, 4)])

    @cached_property
    def segments(self) -> np.ndarray:
        """float ``[W, 4]``: every wall segment (x1, y1, x2, y2) in m — file walls, obstacle
        edges and generated building walls. Read-only."""
        segs: list[tuple[float, float, float, float]] = []
        for line in self.walls:
            segs.extend((a[0], a[1], b[0], b[1]) for a, b in zip(line[:-1], line[1:]))
        for poly in self.obstacles:
            ring = list(poly) + [poly[0]]
            segs.extend((a[0], a[1], b[0], b[1]) for a, b in zip(ring[:-1], ring[1:]))
        if self.building is not None:
            segs.extend(_building.wall_segments(self.building))
        arr = np.asarray(segs, dtype=float).reshape(-1, 4)
        arr.setflags(write=False)
        return arr


@dataclass(frozen=True)
class Cluster:
    """A denser region of features (a stairwell, a shaft...): an extra Poisson process.

    Attributes:
        shape: "disc" (params = (cx, cy, radius)) or "rect" (params = (xmin, ymin, xmax, ymax)), m.
        params: see ``shape``.
        density: extra features per m² inside the region (added to the background).
        label: free text shown on the map.
    """

    shape: str
    params: tuple[float, ...]
    density: float
    label: str = ""

    @property
    def area(self) -> float:
        """Region area (m²)."""
        if self.shape == "disc":
            return math.pi * self.params[2] * self.params[2]
        xmin, ymin, xmax, ymax = self.params
        return (xmax - xmin) * (ymax - ymin)


@dataclass(frozen=True)
class FeatureSpec:
    """Features of interest: a Poisson point process of ``density`` features per m² over the free
    area, plus the ``clusters``' extra processes; or fixed by the map and a recorded run.

    Attributes:
        density, clusters: the Poisson processes (density 0 and no clusters otherwise).
        from_map: "frontier": the features are the centres of the frontier cells of
            ``map.occupancy`` (the same for every seed); "" otherwise.
        replay: recorded observations, one ``(carrier id, values)`` pair per carrier in carrier
            order, a value per stage (NaN where the stage is not valid): what each carrier
            observes, instead of sensing features. Empty otherwise.
    """

    density: float
    clusters: tuple[Cluster, ...] = ()
    from_map: str = ""
    replay: tuple[tuple[str, tuple[float, ...]], ...] = ()

    def replayed(self, r: int, j: int) -> float:
        """Carrier r's recorded observation at stage j (NaN where it has none)."""
        return self.replay[r][1][j]


@dataclass(frozen=True)
class Storey:
    """One storey of a multi-storey map (``map.storeys``): ``name``, ``base`` (m, the floor's
    height in the map frame) and its ``walls`` (polylines, m): only carriers on this storey
    meet them."""

    name: str
    base: float
    walls: tuple[tuple[tuple[float, float], ...], ...] = ()


@dataclass(frozen=True)
class VoxelsSpec:
    """``map.voxels``: the 3D map a scenario was imported from (an OctoMap ``.bt`` beside it),
    read only by what draws it. ``path`` the file, ``sha256`` its bytes' digest, and the
    frontier rule its values used (``neighbours``, ``keep_above``, ``keep_below`` m)."""

    path: Path
    sha256: str
    neighbours: int = 6
    keep_above: float = 1.0
    keep_below: float = 0.1


@dataclass(frozen=True)
class CarrierSpec:
    """One carrier's declared schedule.

    Attributes:
        id: carrier id (string, unique).
        passengers: passengers D it carries and must deploy.
        start_time: when it starts driving (s, mission time).
        stop_time: when it stops for good (s); the end of its path at nominal speed when the
            file omits it. If later than that, it waits at the last waypoint until then.
        speed: nominal speed along the path (m/s).
        waypoints: the path ((x, y), ...) (m), at least two points.
        passenger_values: the value weight of each passenger, in listed order (empty when the
            file gives a count: every passenger weighs 1).
        passenger_types: the type name of each passenger ("" for none), in listed order (empty
            when the file gives a count).
        storey: the storey it drives on (``map.storeys``; "" without storeys): its world holds
            that storey's walls.
    """

    id: str
    passengers: int
    start_time: float
    stop_time: float
    speed: float
    waypoints: tuple[tuple[float, float], ...]
    passenger_values: tuple[float, ...] = ()
    passenger_types: tuple[str, ...] = ()
    storey: str = ""

    @cached_property
    def _cumulative(self) -> np.ndarray:
        pts = np.asarray(self.waypoints, dtype=float)
        return np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(pts, axis=0).T))])

    @property
    def path_length(self) -> float:
        """Total path length (m)."""
        return float(self._cumulative[-1])

    def distance_at(self, t: float) -> float:
        """Planned arc length travelled by time ``t`` (m)."""
        moving = min(max(t, self.start_time), self.stop_time) - self.start_time
        return min(self.speed * moving, self.path_length)

    def position_at(self, t: float) -> tuple[float, float]:
        """Planned position at mission time ``t`` (s): on the path at nominal speed from
        ``start_time``, frozen before the start and after ``stop_time`` (m)."""
        return geometry.point_along(self.waypoints, self._cumulative, self.distance_at(t))


_OPT = planners.OPTIONS


@dataclass(frozen=True)
class PlannerSpec:
    """Planner settings: ``name`` for ``make_planner``; budget ``iterations`` per decision or
    ``plan_ms`` milliseconds (anytime, takes precedence when given); UCT ``exploration``
    constant; ``samples`` rollouts per iteration; MCTS tree ``layout``; ``learn_prior`` (learn the
    prior online, any planner: planner.learning). Names, options and
    defaults are :mod:`planner.registry`'s."""

    name: str = planners.DEFAULT_PLANNER
    iterations: int = _OPT["iterations"].default
    plan_ms: float | None = _OPT["plan_ms"].default
    exploration: float = _OPT["exploration"].default
    samples: int = _OPT["samples"].default
    layout: str = _OPT["layout"].default
    learn_prior: bool = _OPT["learn_prior"].default
    #: A plug-in planner's own options as the file gives them, checked: ``(key, value)`` pairs
    #: (docs/planner.md, "Writing a planner plug-in").
    plugin_options: tuple[tuple[str, Any], ...] = ()

    def options(self) -> dict[str, Any]:
        """Keyword options for ``planner.registry.make_planner(name, **options)`` (``plan_ms``
        only when set; a plug-in's own options too)."""
        out: dict[str, Any] = {key: getattr(self, key) for key in planners.OPTIONS}
        if self.plan_ms is None:
            out.pop("plan_ms")
        out.update(self.plugin_options)
        return out


@dataclass(frozen=True)
class PriorSpec:
    """The prior f(x) of a valid stage's feature count.

    ``kind == "derived"``: Poisson with mean = background density × π r² (open-field sensed
    area; walls and clusters ignored). Otherwise one of :data:`PRIOR_KINDS` with ``params`` as
    (name, value) pairs (list values as tuples), as in the planner's instance format.
    """

    kind: str = "derived"
    params: tuple[tuple[str, float | tuple[float, ...]], ...] = ()


@dataclass(frozen=True)
class Scenario:
    """A mission: everything every process needs to build the identical world.

    Attributes:
        name: scenario name.
        seed: root seed (features and the planner's streams derive from it).
        map: walls, obstacles, bounds.
        features: the feature process.
        sensing_radius: r (m).
        stage_interval: Δt between stages (s).
        stages: N, number of stages.
        conflict_radius: decision points closer than this share an overlap (m).
        carriers: the carriers, in index order r = 0..R-1.
        planner: planner settings.
        prior: prior spec; see :meth:`prior_distribution`.
        first_stage_time: t_0 (s); stage j is at t_0 + j·Δt.
        carrier_radius: the carriers' body radius (m); every leg keeps this clearance from walls.
        links: the link model (``links``: perfect by default; planner.links, world/links.py).
        current: the water's current field (``current``), or None (no current: the default).
        reward: ``penalty`` (the paper's 1/p rule) or ``coverage`` (deployments valued by the
            features in the union of their discs: world/regions.py, docs/scenario.md).
        source: the file it was loaded from ("" if built in code).
    """

    name: str
    seed: int
    map: MapSpec
    features: FeatureSpec
    sensing_radius: float
    stage_interval: float
    stages: int
    conflict_radius: float
    carriers: tuple[CarrierSpec, ...]
    planner: PlannerSpec = PlannerSpec()
    prior: PriorSpec = PriorSpec()
    first_stage_time: float = 0.0
    carrier_radius: float = CARRIER_RADIUS
    links: _links.LinkSpec = _links.LinkSpec()
    current: CurrentSpec | None = None
    reward: str = "penalty"
    source: str = field(default="", compare=False)

    @property
    def n_carriers(self) -> int:
        return len(self.carriers)

    @property
    def carrier_ids(self) -> tuple[str, ...]:
        return tuple(c.id for c in self.carriers)

    @property
    def passengers(self) -> np.ndarray:
        """int64 ``[R]``."""
        return np.array([c.passengers for c in self.carriers], dtype=np.int64)

    def passenger_values(self) -> list[list[float]] | None:
        """One list of passenger value weights per carrier (``Problem.build(weights=...)``), or
        None when no carrier lists its passengers (the unweighted problem, exactly as before)."""
        if not any(c.passenger_values for c in self.carriers):
            return None
        return [list(c.passenger_values) if c.passenger_values else [1.0] * c.passengers for c in self.carriers]

    def passenger_type(self, r: int, i: int) -> str:
        """Type name of carrier r's passenger i ("" when the file gives none)."""
        types = self.carriers[r].passenger_types
        return types[i] if 0 <= i < len(types) else ""

    def carrier_index(self, cid: str) -> int:
        """Index r of carrier ``cid`` (KeyError if unknown)."""
        for r, c in enumerate(self.carriers):
            if c.id == cid:
                return r
        raise KeyError(f"no carrier {cid!r} in scenario {self.name!r}")

    def stage_time(self, j: int) -> float:
        """t_j = t_0 + j·Δt (s)."""
        return self.first_stage_time + j * self.stage_interval

    def stage_times(self) -> np.ndarray:
        """float ``[N]`` stage times (s)."""
        return self.first_stage_time + self.stage_interval * np.arange(self.stages)

    def valid(self) -> np.ndarray:
        """bool ``[R, N]``: stage j is valid for carrier r iff start_time <= t_j <= stop_time."""
        t = self.stage_times()
        return np.array([(c.start_time <= t) & (t <= c.stop_time) for c in self.carriers], dtype=bool)

    def with_seed(self, seed: int) -> "Scenario":
        """The same scenario with another root seed (other features, same schedules)."""
        return dataclasses.replace(self, seed=int(seed))

    def prior_distribution(self) -> Any:
        """The prior of a valid stage's feature count: a frozen ``scipy.stats`` distribution, or
        :class:`planner.priors.Poisson` (its numbers without the scipy.stats import)."""
        if self.prior.kind == "derived":
            return priors.Poisson(self.derived_prior_mean())
        return priors.build_prior({"kind": self.prior.kind, **{k: list(v) if isinstance(v, tuple) else v
                                                               for k, v in self.prior.params}})

    def derived_prior_mean(self) -> float:
        """Background density × π r²: the open-field expected count (walls and clusters ignored).
        With ``features.from_map`` the density is the frontier cells per m² of free map area."""
        return self.feature_density() * math.pi * self.sensing_radius**2

    def feature_density(self) -> float:
        """The background density (1/m²); for ``features.from_map`` the frontier cells over the
        free area of ``map.occupancy``."""
        grid = self.map.occupancy
        if self.features.from_map and grid is not None:
            free = int((grid.classes == _grid.FREE).sum())
            return float(_grid.frontier_mask(grid).sum()) / max(free * grid.resolution**2, 1e-12)
        return self.features.density

    @property
    def replays(self) -> bool:
        """Whether the carriers observe recorded values (``features.replay``) instead of sensing."""
        return bool(self.features.replay)


# --------------------------------------------------------------------------- validation


class _Checker(Flaws):
    """Collects a scenario file's problems (:class:`validation.Flaws`); ``problems`` are the
    ``FILE: path: expected ..., found ...`` lines."""

    def __init__(self, file: str):
        super().__init__()
        self.file = file

    @property
    def problems(self) -> list[str]:
        return self.lines(self.file)

    def bad(self, path: str, expected: str, found: Any) -> None:
        """Record a problem; ``found`` is shown as YAML-ish text (a :class:`Found` verbatim)."""
        self.add(path, expected, found)

    def raw(self, path: str, text: str) -> None:
        self.note(path, text)

    def mapping(self, node: Any, path: str, allowed: tuple[str, ...], required: tuple[str, ...] = ()) -> dict | None:
        if not isinstance(node, dict):
            self.bad(path, "a mapping", node)
            return None
        self.unknown_keys(node, path, allowed)
        self.missing(node, path, required)
        return node

    @overload
    def number(self, node: Any, path: str, *, minimum: float | None = None, exclusive: bool = False,
               integer: Literal[True], maximum: float | None = None) -> int | None: ...
    @overload
    def number(self, node: Any, path: str, *, minimum: float | None = None, exclusive: bool = False,
               integer: bool = False, maximum: float | None = None) -> float | None: ...

    def number(self, node: Any, path: str, *, minimum: float | None = None, exclusive: bool = False,
               integer: bool = False, maximum: float | None = None) -> float | None:
        """The number (an int when ``integer``), or None with the problem recorded (the maximum is named only when exceeded)."""
        value = self.check(Number(integer, minimum, None, exclusive), node, path)
        if value is None or maximum is None:
            return value
        return self.check(Number(integer, minimum, maximum, exclusive), node, path)

    def string(self, node: Any, path: str) -> str | None:
        return self.check(Text(), node, path)

    def point(self, node: Any, path: str) -> tuple[float, float] | None:
        if (not isinstance(node, (list, tuple)) or len(node) != 2
                or any(isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) for v in node)):
            self.bad(path, "a point [x, y] of two numbers (m)", node)
            return None
        if any(abs(v) > MAX_COORDINATE for v in node):
            self.bad(path, f"a point [x, y] of two numbers within +-{MAX_COORDINATE:g} (m)", node)
            return None
        return (float(node[0]), float(node[1]))

    def points(self, node: Any, path: str, min_count: int) -> tuple[tuple[float, float], ...] | None:
        if not isinstance(node, (list, tuple)) or len(node) < min_count:
            self.bad(path, f"a list of at least {min_count} points [x, y] (m)", node)
            return None
        pts = [self.point(p, f"{path}[{i}]") for i, p in enumerate(node)]
        if any(p is None for p in pts):
            return None
        return tuple(pts)  # type: ignore[arg-type]


_TOP_KEYS = ("name", "seed", "map", "features", "sensing_radius", "stage_interval", "stages",
             "first_stage_time", "conflict_radius", "carriers", "planner", "prior", "passenger_types",
             "carrier_radius", "links", "current", "reward")
_TOP_REQUIRED = ("name", "seed", "map", "features", "sensing_radius", "stage_interval", "stages", "carriers")
_MAP_KEYS = ("bounds", "walls", "obstacles", "building", "occupancy", "storeys", "voxels")
_STOREY_KEYS = ("name", "base", "walls")
_VOXELS_KEYS = ("file", "sha256", "neighbours", "keep_above", "keep_below")
_OCCUPANCY_KEYS = ("file", "sha256", "free_level", "occupied_level", "literal_thresholds")
_BUILDING_KEYS = ("origin", "rooms", "room_size", "corridor_width", "door_width", "entrances")
_FEATURE_KEYS = ("density", "clusters", "from_map", "replay")
#: What ``features.from_map`` may name.
FROM_MAP_KINDS = ("frontier",)
_CLUSTER_KEYS = ("disc", "rect", "room", "density", "label")
_CARRIER_KEYS = ("id", "passengers", "start_time", "stop_time", "speed", "waypoints", "storey")
_PASSENGER_KEYS = ("type", "value")
_PLANNER_KEYS = ("name", *planners.OPTIONS)
_SIDES = ("west", "east", "south", "north")


class _UniqueKeyLoader(yaml.SafeLoader):
    """SafeLoader that rejects duplicate mapping keys (pyyaml silently keeps the last one)."""


def _construct_mapping(loader: _UniqueKeyLoader, node: yaml.MappingNode, deep: bool = False) -> dict:
    seen: dict[Any, int] = {}
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=deep)
        try:
            hash(key)
        except TypeError:
            continue
        if key in seen:
            raise yaml.constructor.ConstructorError(
                None, None, f"duplicate key '{key}' (first at line {seen[key] + 1})", key_node.start_mark)
        seen[key] = key_node.start_mark.line
    return loader.construct_mapping(node, deep=deep)


_UniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)

if getattr(yaml, "__with_libyaml__", False):
    class _FastUniqueKeyLoader(yaml.CSafeLoader):
        """:class:`_UniqueKeyLoader` on libyaml's parser: every process of a fleet reads the
        scenario, so its parse time is paid once per process (docs/performance.md)."""

    _FastUniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)
else:  # a PyYAML built without libyaml
    _FastUniqueKeyLoader = None  # type: ignore[misc, assignment]


def _parse_yaml(text: str) -> Any:
    """The YAML document in ``text``, read by libyaml when PyYAML has it; a document it refuses
    is read again by the pure-Python parser, whose error (the documented message) is raised."""
    if _FastUniqueKeyLoader is not None:
        try:
            return yaml.load(text, Loader=_FastUniqueKeyLoader)  # noqa: S506 - CSafeLoader subclass
        except yaml.YAMLError:
            pass
    return yaml.load(text, Loader=_UniqueKeyLoader)  # noqa: S506 - SafeLoader subclass


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario file.

    Raises:
        ScenarioError: listing every problem, one line each (file, field path, expected, found),
            also for a missing file or a YAML syntax error (with its line number).
    """
    file = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ScenarioError([f"{file}: expected an existing scenario file, found no such file"]) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ScenarioError([f"{file}: expected a readable UTF-8 scenario file, found {exc.__class__.__name__}: {exc}"]) from None
    try:
        data = _parse_yaml(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}" if mark is not None else "YAML"
        what = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise ScenarioError([f"{file}: {where}: expected valid YAML, found {what}"]) from None
    return parse_scenario(data, file)


def parse_scenario(data: Any, file: str = "<scenario>") -> Scenario:
    """Validate an already-parsed YAML document (a dict); see :func:`load_scenario`."""
    ck = _Checker(file)
    top = ck.mapping(data, "", _TOP_KEYS, _TOP_REQUIRED)
    if top is None:
        raise ScenarioError(ck.problems)
    name = ck.string(top["name"], "name") if "name" in top else None
    seed = ck.number(top["seed"], "seed", minimum=0, integer=True) if "seed" in top else None
    radius = ck.number(top["sensing_radius"], "sensing_radius", minimum=0, exclusive=True, maximum=MAX_COORDINATE) if "sensing_radius" in top else None
    interval = ck.number(top["stage_interval"], "stage_interval", minimum=0, exclusive=True) if "stage_interval" in top else None
    n_stages = ck.number(top["stages"], "stages", minimum=1, integer=True, maximum=MAX_STAGES) if "stages" in top else None
    t0 = ck.number(top.get("first_stage_time", 0.0), "first_stage_time", minimum=0)
    conflict = None
    if "conflict_radius" in top:
        conflict = ck.number(top["conflict_radius"], "conflict_radius", minimum=0, maximum=4 * MAX_COORDINATE)
    elif radius is not None:
        conflict = CONFLICT_RADIUS_FACTOR * radius

    body = ck.number(top.get("carrier_radius", CARRIER_RADIUS), "carrier_radius", minimum=0, exclusive=True,
                     maximum=100.0)
    the_map = _parse_map(ck, top["map"]) if "map" in top else None
    feats = _parse_features(ck, top["features"], the_map) if "features" in top else None
    types = _parse_passenger_types(ck, top.get("passenger_types", {}))
    carriers = (_parse_carriers(ck, top["carriers"], the_map, types, body or CARRIER_RADIUS)
                if "carriers" in top else None)
    planner = _parse_planner(ck, top.get("planner", {}))
    prior = _parse_prior(ck, top.get("prior", "derived"))

    if interval is not None and n_stages is not None and t0 is not None and t0 + interval * (n_stages - 1) > MAX_MISSION_TIME:
        ck.bad("stages", f"a last stage (first_stage_time + (stages - 1) x stage_interval) at most {MAX_MISSION_TIME:g} s",
               Found(f"{t0 + interval * (n_stages - 1):g} s"))
        n_stages = None
    if the_map is not None and feats is not None:
        xmin, ymin, xmax, ymax = the_map.bounds
        expected = feats.density * (xmax - xmin) * (ymax - ymin) + sum(c.density * c.area for c in feats.clusters)
        if expected > MAX_EXPECTED_FEATURES:
            ck.bad("features.density", f"densities giving at most {MAX_EXPECTED_FEATURES:g} expected features on the map",
                   Found(f"{expected:.3g} expected features"))
    if carriers is not None and interval is not None and n_stages is not None and t0 is not None:
        times = t0 + interval * np.arange(n_stages)
        for r, c in enumerate(carriers):
            n_valid = int(((c.start_time <= times) & (times <= c.stop_time)).sum())
            if c.passengers > n_valid:
                ck.bad(f"carriers[{r}].passengers",
                       f"at most {n_valid} (the valid stages of carrier '{c.id}' between start_time and stop_time)",
                       c.passengers)
    if feats is not None and isinstance(top["features"], dict) and "replay" in top["features"]:
        feats = _parse_replay(ck, top["features"]["replay"], feats, carriers, interval, n_stages, t0)
    links, problems = _links.check_links(top.get("links"), None if carriers is None else tuple(c.id for c in carriers),
                                         None if the_map is None else the_map.bounds)
    ck.extend(problems)
    current, problems = check_current(top["current"]) if "current" in top else (None, [])
    ck.extend(problems)
    reward = _parse_reward(ck, top, feats, prior)
    if ck.problems:
        raise ScenarioError(ck.problems)
    # no problem recorded: every value was read (a reader returns None only with a problem)
    assert (name is not None and seed is not None and the_map is not None and feats is not None and radius is not None
            and interval is not None and n_stages is not None and conflict is not None and carriers is not None
            and planner is not None and prior is not None and t0 is not None and body is not None
            and links is not None)
    scenario = Scenario(name=name, seed=seed, map=the_map, features=feats, sensing_radius=radius,
                        stage_interval=interval, stages=n_stages, conflict_radius=conflict,
                        carriers=carriers, planner=planner, prior=prior, first_stage_time=t0,
                        carrier_radius=body, links=links, current=current, reward=reward,
                        source=file)
    if reward == "coverage":
        from world import regions

        try:  # refused before any arc is computed (time linear in the decision points)
            regions.check_size(scenario)
        except regions.ArrangementTooLarge as err:
            raise ScenarioError([f"{file}: reward: {err}"]) from None
    return scenario


#: The reward models a scenario may name (``reward``); the first is the default.
REWARDS = ("penalty", "coverage")


def _parse_reward(ck: _Checker, top: dict, feats: FeatureSpec | None, prior: PriorSpec | None) -> str:
    """``reward``: ``penalty`` (default) or ``coverage``. Under coverage every region's prior is
    Poisson(density x area), so the prior must be derived, the density positive, and the
    carriers must sense features (not replay recorded counts, which say nothing of regions)."""
    reward = top.get("reward", REWARDS[0])
    if reward not in REWARDS:
        ck.bad("reward", f"one of {', '.join(REWARDS)}", reward)
        return REWARDS[0]
    if reward == "coverage":
        if prior is not None and prior.kind != "derived":
            ck.bad("prior", "derived under reward: coverage (each region's prior is Poisson(density x area))",
                   Found(prior.kind))
        if feats is not None and feats.replay:
            ck.bad("features.replay", "absent under reward: coverage (recorded counts are not region counts)",
                   Found("recorded observations"))
        elif feats is not None and not feats.from_map and feats.density <= 0:
            ck.bad("features.density", "a density > 0 under reward: coverage (the regions' prior intensity)",
                   feats.density)
    return reward


def _parse_map(ck: _Checker, node: Any) -> MapSpec | None:
    m = ck.mapping(node, "map", _MAP_KEYS, () if isinstance(node, dict) and "occupancy" in node else ("bounds",))
    if m is None:
        return None
    ok = True
    bounds = None
    occupancy = _parse_occupancy(ck, m["occupancy"]) if "occupancy" in m else None
    if "occupancy" in m and occupancy is None:
        ok = False
    if "bounds" not in m and occupancy is not None:
        bounds = occupancy.extent
    if "bounds" in m:
        b = m["bounds"]
        if (not isinstance(b, (list, tuple)) or len(b) != 4
                or any(isinstance(v, bool) or not isinstance(v, (int, float)) or not abs(v) <= MAX_COORDINATE for v in b)):
            ck.bad("map.bounds", f"[xmin, ymin, xmax, ymax] of four numbers within +-{MAX_COORDINATE:g} (m)", b)
            ok = False
        elif not (b[0] < b[2] and b[1] < b[3]):
            ck.bad("map.bounds", "xmin < xmax and ymin < ymax", b)
            ok = False
        else:
            bounds = (float(b[0]), float(b[1]), float(b[2]), float(b[3]))
    walls: list = []
    for key, min_count, out in (("walls", 2, walls),):
        lines = m.get(key, [])
        if not isinstance(lines, list):
            ck.bad(f"map.{key}", "a list of polylines (each a list of points [x, y] in m)", lines)
            ok = False
        else:
            for i, line in enumerate(lines):
                pts = ck.points(line, f"map.{key}[{i}]", min_count)
                ok &= pts is not None
                if pts is not None:
                    out.append(pts)
    obstacles: list = []
    polys = m.get("obstacles", [])
    if not isinstance(polys, list):
        ck.bad("map.obstacles", "a list of polygons (each a list of at least 3 points [x, y] in m)", polys)
        ok = False
    else:
        for i, poly in enumerate(polys):
            pts = ck.points(poly, f"map.obstacles[{i}]", 3)
            ok &= pts is not None
            if pts is not None:
                obstacles.append(pts)
    building = _parse_building(ck, m["building"]) if "building" in m else None
    if "building" in m and building is None:
        ok = False
    if bounds is not None:
        for what, groups in (("walls", walls), ("obstacles", obstacles)):
            for i, pts in enumerate(groups):
                for k, p in enumerate(pts):
                    if not _inside(p, bounds):
                        ck.bad(f"map.{what}[{i}][{k}]", f"a point inside map.bounds {list(bounds)}", list(p))
                        ok = False
        if building is not None and not _rect_inside(building.extent, bounds):
            ck.bad("map.building", f"a building inside map.bounds {list(bounds)}",
                   Found(f"its outer wall spans {[round(v, 3) for v in building.extent]}"))
            ok = False
    storeys = _parse_storeys(ck, m["storeys"], bounds) if "storeys" in m else ()
    ok &= storeys is not None
    voxels = _parse_voxels(ck, m["voxels"]) if "voxels" in m else None
    ok &= "voxels" not in m or voxels is not None
    if not ok or bounds is None:
        return None
    return MapSpec(bounds=bounds, walls=tuple(walls), obstacles=tuple(obstacles), building=building,
                   occupancy=occupancy, storeys=storeys or (), voxels=voxels)


def _parse_storeys(ck: _Checker, node: Any, bounds: tuple[float, float, float, float] | None
                   ) -> tuple[Storey, ...] | None:
    """``map.storeys``: a list of ``{name, base (m), walls}``; a carrier names its storey."""
    if not isinstance(node, list) or not node:
        ck.bad("map.storeys", "a non-empty list of storeys {name, base, walls}", node)
        return None
    out: list[Storey] = []
    n0 = len(ck)
    for i, item in enumerate(node):
        where = f"map.storeys[{i}]"
        sm = ck.mapping(item, where, _STOREY_KEYS, ("name", "base"))
        if sm is None:
            continue
        name = sm["name"]
        if not isinstance(name, (str, int)) or isinstance(name, bool) or not re.fullmatch(r"[A-Za-z0-9_\-]+", str(name)):
            ck.bad(f"{where}.name", "a string of letters, digits, '_' or '-'", name)
        elif any(s.name == str(name) for s in out):
            ck.bad(f"{where}.name", "a unique storey name", name)
        base = ck.number(sm["base"], f"{where}.base", minimum=-MAX_COORDINATE)
        lines = sm.get("walls", [])
        walls = []
        if not isinstance(lines, list):
            ck.bad(f"{where}.walls", "a list of polylines (each a list of points [x, y] in m)", lines)
        else:
            for k, line in enumerate(lines):
                pts = ck.points(line, f"{where}.walls[{k}]", 2)
                if pts is not None:
                    if bounds is not None and not all(_inside(p, bounds) for p in pts):
                        ck.bad(f"{where}.walls[{k}]", f"points inside map.bounds {list(bounds)}", [list(p) for p in pts][:3])
                    walls.append(pts)
        if len(ck) == n0 and base is not None:
            out.append(Storey(str(name), float(base), tuple(walls)))
    return tuple(out) if len(ck) == n0 else None


def _parse_voxels(ck: _Checker, node: Any) -> VoxelsSpec | None:
    """``map.voxels``: ``{file, sha256, neighbours, keep_above, keep_below}``; the file (relative
    to the scenario) must exist and match its digest."""
    vm = ck.mapping(node, "map.voxels", _VOXELS_KEYS, ("file", "sha256"))
    if vm is None:
        return None
    name = ck.string(vm["file"], "map.voxels.file")
    digest = ck.string(vm["sha256"], "map.voxels.sha256")
    nb = vm.get("neighbours", 6)
    if nb not in (6, 26):
        ck.bad("map.voxels.neighbours", "6 or 26", nb)
        return None
    above = ck.number(vm.get("keep_above", 1.0), "map.voxels.keep_above", minimum=0)
    below = ck.number(vm.get("keep_below", 0.1), "map.voxels.keep_below", minimum=0)
    if name is None or digest is None or above is None or below is None:
        return None
    base = Path(ck.file).parent if ck.file and not ck.file.startswith("<") else Path(".")
    path = Path(name) if Path(name).is_absolute() else base / name
    try:
        found = _grid.file_sha256(path)
    except OSError as exc:
        ck.bad("map.voxels.file", "an existing OctoMap file beside the scenario", Found(f"{path}: {exc.strerror or exc}"))
        return None
    if found != digest:
        ck.bad("map.voxels.sha256", f"the digest of {path} ({found[:16]}...)",
               Found(f"{digest[:16]}... (the map changed since the scenario was written)"))
        return None
    return VoxelsSpec(path, digest, int(nb), float(above), float(below))


def _parse_occupancy(ck: _Checker, node: Any) -> _grid.OccupancyGrid | None:
    """``map.occupancy``: a map_server map (its YAML, relative to the scenario file), as a file
    name or ``{file, sha256, free_level, occupied_level, literal_thresholds}``; ``sha256`` (the grid's
    :attr:`~world.grid.OccupancyGrid.digest`) ties the scenario's fingerprint to the cells."""
    spec = {"file": node} if isinstance(node, str) else ck.mapping(node, "map.occupancy", _OCCUPANCY_KEYS, ("file",))
    if spec is None or "file" not in spec:
        return None
    name = ck.string(spec["file"], "map.occupancy.file")
    levels = [ck.number(spec.get(key, default), f"map.occupancy.{key}", minimum=0, integer=True, maximum=100)
              for key, default in (("free_level", _grid.DEFAULT_FREE_LEVEL),
                                   ("occupied_level", _grid.DEFAULT_OCCUPIED_LEVEL))]
    free, occupied = levels
    literal = spec.get("literal_thresholds", False)
    if not isinstance(literal, bool):
        ck.bad("map.occupancy.literal_thresholds", "true or false", literal)
        return None
    if name is None or free is None or occupied is None:
        return None
    if free >= occupied:
        ck.bad("map.occupancy.free_level", f"less than occupied_level ({occupied})", free)
        return None
    base = Path(ck.file).parent if ck.file and not ck.file.startswith("<") else Path(".")
    path = Path(name) if Path(name).is_absolute() else base / name
    try:
        grid = _grid.read_map_yaml(path, free_level=free, occupied_level=occupied, literal=literal)
    except _grid.GridError as err:
        ck.raw("map.occupancy.file", f"expected a map_server map, found {err}")
        return None
    digest = spec.get("sha256")
    if digest is not None and digest != grid.digest:
        ck.bad("map.occupancy.sha256", f"the digest of the map in {path} ({grid.digest[:16]}...)",
               Found(f"{str(digest)[:16]}... (the map changed since the scenario was written)"))
        return None
    return grid


def _parse_building(ck: _Checker, node: Any) -> Building | None:
    n0 = len(ck)
    b = ck.mapping(node, "map.building", _BUILDING_KEYS, ("origin", "rooms", "room_size", "corridor_width", "door_width"))
    if b is None:
        return None
    origin = ck.point(b["origin"], "map.building.origin") if "origin" in b else None
    rooms = b.get("rooms")
    cols = rows = None
    if "rooms" in b:
        if (not isinstance(rooms, list) or len(rooms) != 2
                or any(isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= 100 for v in rooms)):
            ck.bad("map.building.rooms", "[cols, rows], two integers from 1 to 100", rooms)
        else:
            cols, rows = rooms
    size = ck.point(b["room_size"], "map.building.room_size") if "room_size" in b else None
    if size is not None and min(size) <= 0:
        ck.bad("map.building.room_size", "[width, height], two numbers > 0 (m)", list(size))
        size = None
    corridor = ck.number(b["corridor_width"], "map.building.corridor_width", minimum=0, exclusive=True,
                         maximum=MAX_COORDINATE) if "corridor_width" in b else None
    door = ck.number(b["door_width"], "map.building.door_width", minimum=0, exclusive=True) if "door_width" in b else None
    if door is not None and size is not None and door >= min(size):
        ck.bad("map.building.door_width", f"less than the smaller room side {min(size):g} m", door)
    entrances = b.get("entrances", [])
    if not isinstance(entrances, list) or any(e not in _SIDES for e in entrances):
        ck.bad("map.building.entrances", f"a list of sides among {list(_SIDES)}", entrances)
    if len(ck) > n0:
        return None
    assert origin is not None and cols is not None and rows is not None and size is not None  # no problem
    assert corridor is not None and door is not None
    return Building(origin=origin, cols=cols, rows=rows, room_size=size, corridor_width=corridor,
                    door_width=door, entrances=tuple(entrances))


def _parse_features(ck: _Checker, node: Any, the_map: MapSpec | None) -> FeatureSpec | None:
    n0 = len(ck)
    fixed = isinstance(node, dict) and ("from_map" in node or "replay" in node)
    f = ck.mapping(node, "features", _FEATURE_KEYS, () if fixed else ("density",))
    if f is None:
        return None
    density = ck.number(f["density"], "features.density", minimum=0) if "density" in f else 0.0
    from_map = f.get("from_map", "")
    if "from_map" in f:
        if from_map not in FROM_MAP_KINDS:
            ck.bad("features.from_map", f"one of {', '.join(FROM_MAP_KINDS)}", from_map)
        elif the_map is not None and the_map.occupancy is None:
            ck.bad("features.from_map", "a map.occupancy to take the frontier cells from", Found("no map.occupancy"))
        if "density" in f or "clusters" in f:
            ck.bad("features.from_map", "no density or clusters beside it (the map fixes the features)",
                   Found(", ".join(k for k in ("density", "clusters") if k in f)))
    clusters = []
    raw = f.get("clusters", [])
    if not isinstance(raw, list):
        ck.bad("features.clusters", "a list of cluster regions", raw)
        raw = []
    for i, c in enumerate(raw):
        path = f"features.clusters[{i}]"
        cm = ck.mapping(c, path, _CLUSTER_KEYS, ("density",))
        if cm is None:
            continue
        shapes = [k for k in ("disc", "rect", "room") if k in cm]
        if len(shapes) != 1:
            ck.bad(path, "exactly one region among disc, rect, room", Found(", ".join(shapes) or "none"))
            continue
        cdens = ck.number(cm["density"], f"{path}.density", minimum=0) if "density" in cm else None
        label = cm.get("label", "")
        if not isinstance(label, str):
            ck.bad(f"{path}.label", "a string", label)
        shape = shapes[0]
        val = cm[shape]
        params: tuple[float, ...] | None = None
        if shape == "disc":
            dm = ck.mapping(val, f"{path}.disc", ("center", "radius"), ("center", "radius"))
            if dm is not None and "center" in dm and "radius" in dm:
                ctr = ck.point(dm["center"], f"{path}.disc.center")
                rad = ck.number(dm["radius"], f"{path}.disc.radius", minimum=0, exclusive=True, maximum=MAX_COORDINATE)
                if ctr is not None and rad is not None:
                    params = (ctr[0], ctr[1], rad)
        elif shape == "rect":
            if (not isinstance(val, list) or len(val) != 4
                    or any(isinstance(v, bool) or not isinstance(v, (int, float)) or not abs(v) <= MAX_COORDINATE
                           for v in val)
                    or not (val[0] < val[2] and val[1] < val[3])):
                ck.bad(f"{path}.rect", "[xmin, ymin, xmax, ymax] with xmin < xmax, ymin < ymax (m)", val)
            else:
                params = tuple(float(v) for v in val)
        else:
            bld = the_map.building if the_map is not None else None
            if the_map is None:
                pass  # the map's own problems are already reported
            elif bld is None:
                ck.bad(f"{path}.room", "a map.building to take the room from", Found("no building in map"))
            elif (not isinstance(val, list) or len(val) != 2
                  or any(isinstance(v, bool) or not isinstance(v, int) for v in val)
                  or not (0 <= val[0] < bld.cols and 0 <= val[1] < bld.rows)):
                ck.bad(f"{path}.room", f"[col, row] with 0 <= col < {bld.cols} and 0 <= row < {bld.rows}", val)
            else:
                params = bld.room_rect(val[0], val[1])
                shape = "rect"
        if params is not None and cdens is not None and isinstance(label, str):
            clusters.append(Cluster(shape=shape, params=params, density=cdens, label=label))
    if len(ck) > n0:
        return None
    assert density is not None  # no problem recorded
    return FeatureSpec(density=density, clusters=tuple(clusters), from_map=from_map)


def _parse_replay(ck: _Checker, node: Any, feats: FeatureSpec, carriers: tuple[CarrierSpec, ...] | None,
                  interval: float | None, n_stages: int | None, t0: float | None) -> FeatureSpec | None:
    """``features.replay``: carrier id -> one recorded count per stage (``null`` where the stage
    is not valid for it); every carrier listed, a number >= 0 at every valid stage."""
    if not isinstance(node, dict) or not node:
        ck.bad("features.replay", "a mapping of carrier ids to lists of recorded counts, one per stage", node)
        return None
    if carriers is None or interval is None or n_stages is None or t0 is None:
        return None  # their own problems are reported
    n0 = len(ck)
    ids = [c.id for c in carriers]
    for key in node:
        if str(key) not in ids:
            ck.bad(f"features.replay.{key}", f"a carrier id ({', '.join(ids)})", Found(f"unknown carrier '{key}'"))
    times = t0 + interval * np.arange(n_stages)
    rows = []
    for c in carriers:
        values = node.get(c.id)
        where = f"features.replay.{c.id}"
        if not isinstance(values, list) or len(values) != n_stages:
            ck.bad(where, f"a list of {n_stages} recorded counts (one per stage, null where not valid)",
                   MISSING if values is None else values)
            continue
        valid = (c.start_time <= times) & (times <= c.stop_time)
        row = []
        for j, v in enumerate(values):
            if v is None and not valid[j]:
                row.append(math.nan)
            elif (isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0
                  or not float(v).is_integer()):
                ck.bad(f"{where}[{j}]", f"an integer count >= 0 (stage {j} is {'' if valid[j] else 'not '}valid for "
                       f"carrier '{c.id}')" + ("" if valid[j] else " or null"), v)
            else:
                row.append(float(v) if valid[j] else math.nan)
        rows.append((c.id, tuple(row)))
    if len(ck) > n0:
        return None
    return dataclasses.replace(feats, replay=tuple(rows))


def _parse_passenger_types(ck: _Checker, node: Any) -> dict[str, float]:
    """``passenger_types``: a mapping from type name to its value weight (> 0)."""
    if not isinstance(node, dict):
        ck.bad("passenger_types", "a mapping of type names to value weights > 0 (e.g. {scout: 1.0, rover: 0.6})", node)
        return {}
    out = {}
    for name, value in node.items():
        if not isinstance(name, str) or not re.fullmatch(r"[A-Za-z0-9_\-]+", name):
            ck.bad("passenger_types", "type names of letters, digits, '_' or '-'", name)
            continue
        w = ck.number(value, f"passenger_types.{name}", minimum=0, exclusive=True)
        if w is not None:
            out[name] = w
    return out


def _parse_passengers(ck: _Checker, node: Any, path: str,
                      types: dict[str, float]) -> tuple[int | None, tuple[float, ...], tuple[str, ...]]:
    """A carrier's ``passengers``: a count (every passenger weighs 1), or a list of passengers,
    each a type name of ``passenger_types`` or a mapping ``{type: NAME, value: W}`` (``value``
    required unless the type is in ``passenger_types``). Returns (count, values, type names)."""
    if not isinstance(node, list):
        count = ck.number(node, path, minimum=0, integer=True, maximum=MAX_PASSENGERS)
        return count, (), ()
    if len(node) > MAX_PASSENGERS:
        ck.bad(path, f"at most {MAX_PASSENGERS} passengers", Found(f"{len(node)} passengers"))
        return None, (), ()
    values, names = [], []
    known = ", ".join(types) or "none defined in passenger_types"
    for i, item in enumerate(node):
        where = f"{path}[{i}]"
        if isinstance(item, str):
            if item not in types:
                ck.bad(where, f"a type of passenger_types ({known}) or a mapping {{type: NAME, value: W}}", item)
                continue
            values.append(types[item])
            names.append(item)
            continue
        m = ck.mapping(item, where, _PASSENGER_KEYS)
        if m is None:
            continue
        name = m.get("type", "")
        if "type" in m and (not isinstance(name, str) or not re.fullmatch(r"[A-Za-z0-9_\-]+", name)):
            ck.bad(f"{where}.type", "a type name of letters, digits, '_' or '-'", name)
            continue
        if "value" in m:
            w = ck.number(m["value"], f"{where}.value", minimum=0, exclusive=True)
        elif name in types:
            w = types[name]
        else:
            ck.bad(f"{where}.value", f"a number > 0 (type '{name}' is not in passenger_types)" if name
                   else "a number > 0", MISSING)
            continue
        if w is not None:
            values.append(w)
            names.append(name)
    if len(values) != len(node):
        return None, (), ()
    return len(values), tuple(values), tuple(names)


def _parse_carriers(ck: _Checker, node: Any, the_map: MapSpec | None, types: dict[str, float] | None = None,
                    body: float = CARRIER_RADIUS) -> tuple[CarrierSpec, ...] | None:
    if not isinstance(node, list) or not node:
        ck.bad("carriers", "a non-empty list of carriers", node)
        return None
    if len(node) > MAX_CARRIERS:
        ck.bad("carriers", f"a list of at most {MAX_CARRIERS} carriers", Found(f"{len(node)} carriers"))
        return None
    n0 = len(ck)
    out = []
    seen: dict[str, int] = {}
    for r, c in enumerate(node):
        path = f"carriers[{r}]"
        k0 = len(ck)
        cm = ck.mapping(c, path, _CARRIER_KEYS, ("id", "passengers", "start_time", "speed", "waypoints"))
        if cm is None:
            continue
        cid = cm.get("id")
        if "id" in cm:
            if isinstance(cid, bool) or not isinstance(cid, (str, int)) or not re.fullmatch(r"[A-Za-z0-9_\-]+", str(cid)):
                ck.bad(f"{path}.id", "a string of letters, digits, '_' or '-'", cid)
            else:
                cid = str(cid)
                if cid in seen:
                    ck.bad(f"{path}.id", f"a unique id (carriers[{seen[cid]}] is already '{cid}')", cid)
                seen.setdefault(cid, r)
        pas, values, names = (_parse_passengers(ck, cm["passengers"], f"{path}.passengers", types or {})
                               if "passengers" in cm else (None, (), ()))
        start = ck.number(cm["start_time"], f"{path}.start_time", minimum=0) if "start_time" in cm else None
        speed = ck.number(cm["speed"], f"{path}.speed", minimum=0, exclusive=True) if "speed" in cm else None
        wps = ck.points(cm["waypoints"], f"{path}.waypoints", 2) if "waypoints" in cm else None
        storey = ""
        if the_map is not None and the_map.storeys:
            storey_names = [s.name for s in the_map.storeys]
            storey = str(cm.get("storey", ""))
            if storey not in storey_names:
                ck.bad(f"{path}.storey", f"one of map.storeys' names ({', '.join(storey_names)})", cm.get("storey"))
        elif "storey" in cm:
            ck.bad(f"{path}.storey", "no storey (the map has no map.storeys)", cm["storey"])
        stop = None
        if "stop_time" in cm:
            stop = ck.number(cm["stop_time"], f"{path}.stop_time", minimum=0)
            if stop is not None and start is not None and stop < start:
                ck.bad(f"{path}.stop_time", f"a time >= start_time ({start:g} s)", cm["stop_time"])
        if wps is not None and the_map is not None:
            for k, p in enumerate(wps):
                if not _inside(p, the_map.bounds):
                    ck.bad(f"{path}.waypoints[{k}]", f"a point inside map.bounds {list(the_map.bounds)}", list(p))
            for k, p in enumerate(wps):
                for i, poly in enumerate(the_map.obstacles):
                    if geometry.inside_polygon(np.asarray([p]), poly)[0]:
                        ck.bad(f"{path}.waypoints[{k}]", "a point outside every obstacle",
                               Found(f"{list(p)} inside map.obstacles[{i}]"))
            segs = the_map.carrier_segments(storey)
            for k, (a, b) in enumerate(zip(wps[:-1], wps[1:])):
                hit = geometry.first_blocking_segment(a, b, segs, clearance=body)
                if hit is not None:
                    w = segs[hit]
                    ck.bad(f"{path}.waypoints[{k}]->[{k + 1}]",
                           f"a leg clear of walls by {body:g} m",
                           Found(f"it meets the wall ({w[0]:g}, {w[1]:g})-({w[2]:g}, {w[3]:g})"))
                    break
            if all(a == b for a, b in zip(wps[:-1], wps[1:])):
                ck.bad(f"{path}.waypoints", "a path of non-zero length", Found("all points equal"))
        if len(ck) > k0:
            continue
        assert cid is not None and pas is not None and start is not None and speed is not None and wps is not None
        length = float(np.hypot(*np.diff(np.asarray(wps), axis=0).T).sum())
        if stop is None:
            stop = start + length / speed
        out.append(CarrierSpec(id=cid, passengers=pas, start_time=start, stop_time=stop, speed=speed, waypoints=wps,
                               passenger_values=values, passenger_types=names, storey=storey))
    if len(ck) > n0:
        return None
    return tuple(out)


def _parse_planner(ck: _Checker, node: Any) -> PlannerSpec | None:
    """The ``planner`` block, checked by the planner registry (names, option types and ranges)."""
    own = _plugin_options(node.get("name") if isinstance(node, dict) else None)
    p = ck.mapping(node, "planner", (*_PLANNER_KEYS, *(o.name for o in own)))
    if p is None:
        return None
    name = p.get("name", planners.DEFAULT_PLANNER)
    options = {key: p[key] for key in (*planners.OPTIONS, *(o.name for o in own)) if key in p}
    problems = planners.check_settings(name, options)
    for problem in problems:
        ck.bad(f"planner.{problem.field}", problem.expected, problem.found)
    if problems:
        return None
    checked = {key: planners.OPTIONS[key].check(v) for key, v in options.items()
               if v is not None and key in planners.OPTIONS}
    extra = tuple((o.name, o.check(options[o.name])) for o in own if options.get(o.name) is not None)
    return PlannerSpec(name=name, **checked, plugin_options=extra)


def _plugin_options(name: Any) -> tuple[planners.Option, ...]:
    """The own options of a plug-in planner named in a file (none for a built-in, or a name the
    registry cannot resolve: :func:`planner.registry.check_settings` reports that one)."""
    if not isinstance(name, str) or name in planners.planner_names():
        return ()
    try:
        return planners.entry(name).own
    except ValueError:
        return ()


def _parse_prior(ck: _Checker, node: Any) -> PriorSpec | None:
    if node == "derived" or node is None:
        return PriorSpec()
    if not isinstance(node, dict):
        ck.bad("prior", "'derived' or a mapping like {kind: poisson, mean: 3.0}", node)
        return None
    if "kind" not in node:
        ck.bad("prior.kind", f"a value (derived or one of {', '.join(PRIOR_KINDS)})", MISSING)
        return None
    kind = node["kind"]
    if kind == "derived":
        extra = [k for k in node if k != "kind"]
        if extra:
            ck.bad(f"prior.{extra[0]}", "no parameters for the derived prior", node[extra[0]])
            return None
        return PriorSpec()
    if not isinstance(kind, str) or kind not in priors.PRIOR_KINDS:
        hint = did_you_mean(kind, PRIOR_KINDS + ("derived",), cutoff=0.5)
        ck.bad("prior.kind", f"derived or one of {', '.join(PRIOR_KINDS)}{hint}", kind)
        return None
    params, _ = priors.PRIOR_KINDS[kind]
    n0 = len(ck)
    ck.mapping(node, "prior", ("kind",) + tuple(params), ())
    for problem in priors.prior_problems(node, unknown=False):
        ck.bad(f"prior.{problem.field}", problem.expected, problem.found)
    if len(ck) > n0:
        return None
    vals = tuple((name, tuple(node[name]) if isinstance(node[name], list) else node[name]) for name in params)
    return PriorSpec(kind=kind, params=vals)


def _inside(p: tuple[float, float], bounds: tuple[float, float, float, float]) -> bool:
    return bounds[0] <= p[0] <= bounds[2] and bounds[1] <= p[1] <= bounds[3]


def _rect_inside(rect: tuple[float, float, float, float], bounds: tuple[float, float, float, float]) -> bool:
    return _inside(rect[:2], bounds) and _inside(rect[2:], bounds)
