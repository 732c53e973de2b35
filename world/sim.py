"""The pymunk world: static walls, carrier bodies driven along their paths, deployed passengers,
and sensing with line of sight.

Invariant: a carrier's trajectory depends only on the scenario and its own id. Each carrier lives
in its own pymunk space (the same static walls, only its own body), so a carrier process that
simulates one carrier, the coordinator and :func:`observe_all` compute bit-identical positions.
Carriers therefore never collide with each other; they do collide with walls.

Control: every PHYSICS_DT the carrier's velocity is set to the path's feed-forward velocity plus
CONTROL_GAIN × (reference − position), capped at MAX_SPEED_FACTOR × nominal speed, where the
reference is the planned (schedule) position at the start of the step (so a carrier on
schedule has zero error and moves exactly with the feed-forward). A scenario's ``current``
(world/current.py) adds the water's velocity at the carrier's position to that command. The
physics then advances in SUBSTEPS equal sub-steps and resolves wall contacts.
"""
from __future__ import annotations

import bisect
import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Iterable

import numpy as np
import pymunk
from pymunk._chipmunk import lib as cp

from world import geometry
from world.features import sample_features
from world.scenario import Scenario

#: Physics time step (s); the controller runs once per step.
PHYSICS_DT = 0.05
#: pymunk sub-steps per physics step.
SUBSTEPS = 2
#: Wall half-thickness for collisions (m).
WALL_RADIUS = 0.05
#: Carrier mass (kg); the body does not rotate (infinite moment).
CARRIER_MASS = 50.0
#: Position-error gain of the tracking controller (1/s).
CONTROL_GAIN = 1.0
#: Speed cap as a multiple of the nominal speed.
MAX_SPEED_FACTOR = 1.5
#: After stop_time the carrier is allowed this long to settle on its final reference, then it
#: is frozen (s).
SETTLE_TIME = 5.0
#: A trajectory sample is recorded every TRACE_STEPS physics steps (1 s).
TRACE_STEPS = 20
#: Radius of a deployed passenger's marker body (m).
PASSENGER_RADIUS = 0.3


def step_of(t: float) -> int:
    """Index of the first physics step boundary at or after time ``t`` (s)."""
    return max(0, int(math.ceil(t / PHYSICS_DT - 1e-9)))


@dataclass(frozen=True)
class Deployment:
    """A passenger deployed by carrier ``carrier`` at mission time ``time`` (s) at ``position`` (m)."""

    carrier: str
    time: float
    position: tuple[float, float]


#: What pymunk's Space.step does around chipmunk's step (:meth:`_CarrierBody._drive`).
_WRAPPER_STATE = ("_space", "_bodies_to_check", "_add_later", "_remove_later", "_post_step_callbacks")


class _CarrierBody:
    """One carrier in its own pymunk space."""

    def __init__(self, scenario: Scenario, r: int):
        self.spec = scenario.carriers[r]
        self.space = pymunk.Space()
        self.space.iterations = 10
        for x1, y1, x2, y2 in scenario.map.carrier_segments(self.spec.storey):
            seg = pymunk.Segment(self.space.static_body, (float(x1), float(y1)), (float(x2), float(y2)), WALL_RADIUS)
            seg.friction = 0.0
            seg.elasticity = 0.0
            self.space.add(seg)
        self.body = pymunk.Body(CARRIER_MASS, math.inf)
        self.body.position = self.spec.waypoints[0]
        shape = pymunk.Circle(self.body, scenario.carrier_radius)
        shape.friction = 0.0
        shape.elasticity = 0.0
        self.space.add(self.body, shape)
        self.step = 0
        self.halted = False
        # step through chipmunk's functions when pymunk's wrapper has nothing to do (:meth:`_drive`);
        # only with a pymunk whose wrapper keeps its pending work where _drive looks (7.x)
        self.direct = all(hasattr(self.space, name) for name in _WRAPPER_STATE) and hasattr(self.body, "_body")
        self.max_speed = MAX_SPEED_FACTOR * self.spec.speed
        # the water's velocity field (world/current.py), None without one (the physics is then unchanged)
        self.current = scenario.current
        self.frozen_after = step_of(self.spec.stop_time + SETTLE_TIME)
        self.start_step = step_of(self.spec.start_time)
        # path as plain floats for the per-step reference (legs of zero length are dropped)
        pts = [tuple(map(float, w)) for w in self.spec.waypoints]
        legs = [(a, b) for a, b in zip(pts[:-1], pts[1:]) if a != b]
        self.points = [a for a, _ in legs]
        self.units = [((b[0] - a[0]) / math.hypot(b[0] - a[0], b[1] - a[1]),
                       (b[1] - a[1]) / math.hypot(b[0] - a[0], b[1] - a[1])) for a, b in legs]
        self.cum = [0.0]
        for a, b in legs:
            self.cum.append(self.cum[-1] + math.hypot(b[0] - a[0], b[1] - a[1]))
        self.length = self.cum[-1]
        p = self.body.position
        self.trace: list[tuple[float, float, float]] = [(0.0, p.x, p.y)]

    def advance(self, target_step: int) -> None:
        while self.step < target_step:
            # idle stretches (halted, before the start, frozen after stop_time) are skipped in one
            # go: an idle step only zeroes the velocity, so this equals stepping one by one
            if self.halted or self.step >= self.frozen_after:
                idle_end = target_step
            elif self.step < self.start_step:
                idle_end = min(target_step, self.start_step)
            else:
                self._drive(min(target_step, self.frozen_after))
                continue
            self.body.velocity = (0.0, 0.0)
            p = self.body.position
            first = (self.step // TRACE_STEPS + 1) * TRACE_STEPS
            self.trace.extend((k * PHYSICS_DT, p.x, p.y) for k in range(first, idle_end + 1, TRACE_STEPS))
            self.step = idle_end

    def _drive(self, end: int) -> None:
        """The steps up to ``end`` of a carrier driving its path: at each, the planned position
        and feed-forward velocity at t, the velocity command (capped), then SUBSTEPS steps of
        the space.

        Written as one loop over local names (with long stages a carrier's physics is most of its
        CPU), and through chipmunk's functions directly when pymunk's
        wrapper has nothing to do around them (no body to check, nothing to add or remove after
        the step, no post-step callback: always so between two deployments), through the
        wrapper otherwise: the same C calls with the same arguments and the same float
        operations in the same order either way, so the same bits (tests/test_world.py)."""
        dt, sub, gain, substeps = PHYSICS_DT, PHYSICS_DT / SUBSTEPS, CONTROL_GAIN, range(SUBSTEPS)
        spec = self.spec
        t_start, t_stop, speed, length = spec.start_time, spec.stop_time, spec.speed, self.length
        cum, units, points, last_leg = self.cum, self.units, self.points, len(self.cum) - 2
        max_speed, trace, current = self.max_speed, self.trace, self.current
        space, body = self.space, self.body
        c_body = body._body if self.direct else None
        c_space = space._space if self.direct else None
        get_position, set_velocity, space_step = cp.cpBodyGetPosition, cp.cpBodySetVelocity, cp.cpSpaceStep
        step = self.step
        while step < end:
            t = step * dt
            # the reference: where the path puts the carrier at t, and its velocity there
            s = min(speed * (min(max(t, t_start), t_stop) - t_start), length)
            k = min(max(bisect.bisect_right(cum, s) - 1, 0), last_leg)
            ux, uy = units[k]
            ax, ay = points[k]
            d = s - cum[k]
            rx, ry = ax + d * ux, ay + d * uy
            if t_start <= t < t_stop and s < length:
                fx, fy = ux * speed, uy * speed
            else:
                fx, fy = 0.0, 0.0
            p = get_position(c_body) if c_body is not None else body.position
            vx = fx + gain * (rx - p.x)
            vy = fy + gain * (ry - p.y)
            v = math.hypot(vx, vy)
            if v > max_speed:
                vx, vy = vx * max_speed / v, vy * max_speed / v
            if current is not None:  # the command is relative to the water, which moves the body
                cx, cy = current.at(p.x, p.y)
                vx, vy = vx + cx, vy + cy
            if c_body is None or space._bodies_to_check or space._add_later or space._remove_later \
                    or space._post_step_callbacks:
                body.velocity = (vx, vy)
                for _ in substeps:
                    space.step(sub)
            else:
                set_velocity(c_body, (vx, vy))
                for _ in substeps:
                    space_step(c_space, sub)
            step += 1
            self.step = step
            if step % TRACE_STEPS == 0:
                p = get_position(c_body) if c_body is not None else body.position
                trace.append((step * dt, p.x, p.y))

    @property
    def position(self) -> tuple[float, float]:
        p = self.body.position
        return (float(p.x), float(p.y))


class Simulation:
    """A pymunk world with walls and the given carriers' bodies (all by default).

    Args:
        scenario: the mission.
        carriers: ids of the carriers to simulate (a carrier process passes its own id).
        seed: root seed of the features (scenario.seed by default).
        features: the features ``[F, 2]`` (m) when the caller sampled them already (several
            carriers of one process share one array); sampled from the seed otherwise.

    Attributes:
        features: float ``[F, 2]`` feature positions (m).
        deployments: list of :class:`Deployment`, in order.
    """

    def __init__(self, scenario: Scenario, carriers: Iterable[str] | None = None, seed: int | None = None,
                 features=None):
        self.scenario = scenario
        ids = scenario.carrier_ids if carriers is None else tuple(carriers)
        self._bodies = {cid: _CarrierBody(scenario, scenario.carrier_index(cid)) for cid in ids}
        self.features = sample_features(scenario, seed) if features is None else features
        # Sensing looks at the features in an x window of the sensing disc: sorted by x once
        # (no copy when the caller passes them sorted, as carriers sharing a process do).
        xs = self.features[:, 0]
        self._sense_pts = self.features if bool(np.all(xs[1:] >= xs[:-1])) else \
            self.features[np.argsort(xs, kind="stable")]
        self._sense_xs = self._sense_pts[:, 0]
        self.deployments: list[Deployment] = []
        self._left = {cid: scenario.carriers[scenario.carrier_index(cid)].passengers for cid in ids}
        self._counts: np.ndarray | None = None  # region counts (reward: coverage), on first use
        self._step = 0

    @property
    def time(self) -> float:
        """Current mission time (s), a multiple of PHYSICS_DT."""
        return self._step * PHYSICS_DT

    @property
    def carrier_ids(self) -> tuple[str, ...]:
        return tuple(self._bodies)

    def advance_to(self, t: float) -> None:
        """Step the physics at PHYSICS_DT until the first step boundary at or after ``t`` (s)."""
        target = step_of(t)
        for body in self._bodies.values():
            body.advance(target)
        self._step = max(self._step, target)

    def position(self, cid: str) -> tuple[float, float]:
        """Actual position of carrier ``cid`` (m)."""
        return self._bodies[cid].position

    def sense(self, cid: str, stage: int | None = None) -> int:
        """Features within the sensing radius of ``cid``'s actual position with line of sight; in
        a replayed mission (``features.replay``) the recorded value of ``stage`` (the stage whose
        time the simulation is at when None)."""
        if self.scenario.reward == "coverage":  # the passenger's disc: its regions' features
            s = self.scenario
            j = round((self.time - s.first_stage_time) / s.stage_interval) if stage is None else int(stage)
            return sum(self.sense_counts(cid, j) or ())
        if self.scenario.replays:
            s = self.scenario
            j = round((self.time - s.first_stage_time) / s.stage_interval) if stage is None else int(stage)
            value = s.features.replayed(s.carrier_index(cid), j)
            return 0 if math.isnan(value) else int(value)
        origin = self.position(cid)
        radius = self.scenario.sensing_radius
        # Every feature within the radius has |dx| <= radius: the window loses none (the margin
        # absorbs rounding), and the count is order-free, so it equals the count over all features.
        lo, hi = np.searchsorted(self._sense_xs, [origin[0] - radius - 1e-6, origin[0] + radius + 1e-6])
        return geometry.count_visible(origin, self._sense_pts[lo:hi], radius, self.scenario.map.segments)

    def sense_counts(self, cid: str, stage: int) -> tuple[int, ...] | None:
        """Under ``reward: coverage``: the feature counts of the regions carrier ``cid``'s disc
        covers at ``stage`` (in the order of the scenario's ``covers``; world/regions.py), None
        at an invalid stage or under the penalty reward. Its observation is their sum."""
        if self.scenario.reward != "coverage":
            return None
        from world.regions import scenario_regions

        regions = scenario_regions(self.scenario)
        covered = regions.covers[self.scenario.carrier_index(cid)][int(stage)]
        if covered is None:
            return None
        if self._counts is None:  # the features near this simulation's carriers' discs suffice
            rows = [self.scenario.carrier_index(c) for c in self._bodies]
            discs = regions.disc_of[rows][regions.disc_of[rows] >= 0]
            self._counts = regions.counts(regions.near(self.features, discs))
        return tuple(int(self._counts[m]) for m in covered)

    def passengers_left(self, cid: str) -> int:
        return self._left[cid]

    def deploy(self, cid: str) -> Deployment:
        """Deploy one of ``cid``'s passengers where the carrier is now: a static marker body
        (a sensor shape, so the carrier's motion is unchanged) appears in the carrier's space.

        Raises:
            ValueError: if the carrier has no passenger left.
        """
        if self._left[cid] <= 0:
            raise ValueError(f"carrier {cid!r} has no passenger left to deploy")
        self._left[cid] -= 1
        carrier = self._bodies[cid]
        pos = carrier.position
        marker = pymunk.Body(body_type=pymunk.Body.STATIC)
        marker.position = pos
        shape = pymunk.Circle(marker, PASSENGER_RADIUS)
        shape.sensor = True
        carrier.space.add(marker, shape)
        dep = Deployment(cid, self.time, pos)
        self.deployments.append(dep)
        return dep

    def halt(self, cid: str) -> None:
        """Stop carrier ``cid`` where it is for the rest of the mission (a stalled carrier)."""
        self._bodies[cid].halted = True

    def trajectory(self, cid: str) -> np.ndarray:
        """float ``[K, 3]`` samples (t s, x m, y m) every TRACE_STEPS steps so far."""
        return np.asarray(self._bodies[cid].trace, dtype=float)


@dataclass(frozen=True, eq=False)
class MissionTrace:
    """A whole mission simulated without the network.

    Attributes:
        x: float ``[R, N]`` observations; NaN at invalid stages.
        positions: float ``[R, N, 2]`` actual positions at the stage times (m); NaN where invalid.
        trajectories: per carrier, float ``[K, 3]`` samples (t s, x m, y m) up to the last stage.
        features: float ``[F, 2]`` feature positions (m).
        counts: int64 ``[M]`` the realised region counts under ``reward: coverage`` (x is then the
            sum of a point's regions' counts); None under the penalty reward.
    """

    x: np.ndarray
    positions: np.ndarray
    trajectories: tuple[np.ndarray, ...]
    features: np.ndarray
    counts: np.ndarray | None = None


@lru_cache(maxsize=32)
def _carrier_run(scenario: Scenario, r: int) -> tuple[np.ndarray, np.ndarray]:
    """(positions ``[N, 2]`` at every stage time, trajectory ``[K, 3]``) of carrier r.

    Cached: physics does not depend on the feature seed (callers pass ``with_seed(0)``)."""
    body = _CarrierBody(scenario, r)
    out = np.empty((scenario.stages, 2))
    for j, t in enumerate(scenario.stage_times()):
        body.advance(step_of(float(t)))
        out[j] = body.position
    out.setflags(write=False)
    trace = np.asarray(body.trace, dtype=float)
    trace.setflags(write=False)
    return out, trace


def simulate_mission(scenario: Scenario, seed: int | None = None, rows: Iterable[int] | None = None) -> MissionTrace:
    """Run every carrier (no network, no faults) and observe every valid stage.

    ``seed`` overrides the scenario's root seed for the features; the physics is the same for
    every seed and is computed once per scenario (cached). ``rows``: only these carriers (the
    others' rows are NaN and their trajectories empty), so that a caller can spread a large
    fleet's physics over processes and put the rows together.
    """
    seed = scenario.seed if seed is None else int(seed)
    physics_key = scenario.with_seed(0)
    features = sample_features(scenario, seed)
    valid = scenario.valid()
    x = np.full(valid.shape, np.nan)
    pos = np.full(valid.shape + (2,), np.nan)
    trajectories = []
    segs = scenario.map.segments
    wanted = range(scenario.n_carriers) if rows is None else set(int(r) for r in rows)
    counts = None
    if scenario.reward == "coverage":  # a point observes its disc's regions (world/regions.py)
        from world.regions import region_counts, scenario_regions

        counts = region_counts(scenario, features)
        sums = [[None if c is None else int(counts[list(c)].sum()) for c in row]
                for row in scenario_regions(scenario).covers]
    for r in range(scenario.n_carriers):
        if r not in wanted:
            trajectories.append(np.empty((0, 3)))
            continue
        stage_pos, trace = _carrier_run(physics_key, r)
        trajectories.append(trace)
        for j in np.flatnonzero(valid[r]):
            pos[r, j] = stage_pos[j]
            if counts is not None:
                x[r, j] = sums[r][j]
            else:
                x[r, j] = (scenario.features.replayed(r, j) if scenario.replays
                           else geometry.count_visible(stage_pos[j], features, scenario.sensing_radius, segs))
    return MissionTrace(x=x, positions=pos, trajectories=tuple(trajectories), features=features, counts=counts)


#: Carriers per worker below which :func:`observe_all` runs the physics in this process (a worker
#: process costs about a second to start).
ROWS_PER_WORKER = 16


def observe_all(scenario: Scenario, seed: int | None = None, workers: int = 1) -> np.ndarray:
    """float ``[R, N]``: what the fleet observes with no faults (NaN at invalid stages).

    ``seed`` overrides the root seed of the features (``scenario.with_seed(s)`` does the same).
    ``workers`` > 1: the carriers' physics (each carrier its own space) spread over that many
    processes when the fleet has at least :data:`ROWS_PER_WORKER` carriers per worker; the same
    figures as in one process.
    """
    workers = min(int(workers), scenario.n_carriers // ROWS_PER_WORKER)
    if workers <= 1:
        return simulate_mission(scenario, seed).x
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    chunks = [list(range(k, scenario.n_carriers, workers)) for k in range(workers)]
    x = np.full((scenario.n_carriers, scenario.stages), np.nan)
    with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
        for rows, part in zip(chunks, pool.map(_observe_rows, [scenario] * workers, [seed] * workers, chunks)):
            x[rows] = part
    return x


def _observe_rows(scenario: Scenario, seed: int | None, rows: list[int]) -> np.ndarray:
    """:func:`observe_all`'s rows ``rows`` (in a worker process)."""
    return simulate_mission(scenario, seed, rows=rows).x[rows]
