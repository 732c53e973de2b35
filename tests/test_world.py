"""world/: determinism across processes, sensing and overlaps against brute force, physics."""
from __future__ import annotations

import dataclasses
import itertools
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pymunk
import pytest

import world
from world import geometry
from world.scenario import CARRIER_RADIUS, parse_scenario
from world.sim import step_of
from world.stages import proximity_overlaps

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ROOT / "scenarios"
ALL = ["tiny", "open_field", "six_carriers", "urban_alpha"]


@pytest.fixture(scope="module")
def tiny():
    return world.load_scenario(SCENARIOS / "tiny.yaml")


@pytest.fixture(scope="module")
def urban():
    return world.load_scenario(SCENARIOS / "urban_alpha.yaml")


@pytest.mark.parametrize("name", ALL)
def test_shipped_scenarios_load(name):
    s = world.load_scenario(SCENARIOS / f"{name}.yaml")
    geo = world.stage_geometry(s)
    assert geo.positions.shape == (s.n_carriers, s.stages, 2)
    assert np.isnan(geo.positions[~geo.valid]).all() and np.isfinite(geo.positions[geo.valid]).all()
    # every carrier can deploy all its passengers at its valid stages
    assert (geo.valid.sum(axis=1) >= s.passengers).all()


def test_scenario_shapes_match_the_brief():
    six = world.load_scenario(SCENARIOS / "six_carriers.yaml")
    assert six.n_carriers == 6 and (six.passengers == 3).all() and 10 <= six.stages <= 12
    assert len({c.start_time for c in six.carriers}) > 1, "staggered starts"
    geo = world.stage_geometry(six)
    cross = [g for g in geo.overlaps if len({r for r, _ in g}) >= 2]
    assert len(cross) >= 10, "paths must cross so that conflicts between carriers matter"
    of = world.load_scenario(SCENARIOS / "open_field.yaml")
    assert (of.n_carriers, int(of.passengers.max()), of.stages) == (4, 3, 10)
    ua = world.load_scenario(SCENARIOS / "urban_alpha.yaml")
    assert (ua.n_carriers, ua.stages, ua.stage_interval, ua.sensing_radius, ua.conflict_radius) == (3, 19, 100, 10, 30)
    valid = ua.valid()
    assert len({int(np.argmax(v)) for v in valid}) == 3, "staggered starts"
    assert (~valid[:, -1]).sum() == 1, "exactly one carrier finishes early"
    assert ua.map.building is not None and ua.features.clusters
    assert ua.planner.name == "mcts-ssap" and ua.planner.iterations == 10000


# ----------------------------------------------------------------------------- determinism

_HASH_SCRIPT = r"""
import hashlib, json, sys
import numpy as np
import world
h = hashlib.sha256()
for name in sys.argv[1:]:
    s = world.load_scenario(name)
    m = world.simulate_mission(s)
    for arr in (m.features, m.positions, m.x, *m.trajectories):
        h.update(np.ascontiguousarray(arr, dtype=np.float64).tobytes())
    h.update(json.dumps(world.stage_geometry(s).overlaps).encode())
    sim = world.Simulation(s, carriers=[s.carriers[-1].id])
    for t in s.stage_times():
        sim.advance_to(float(t))
        h.update(np.asarray(sim.position(s.carriers[-1].id)).tobytes())
        h.update(str(sim.sense(s.carriers[-1].id)).encode())
print(h.hexdigest())
"""


def test_same_world_in_two_fresh_processes():
    files = [str(SCENARIOS / "tiny.yaml"), str(SCENARIOS / "six_carriers.yaml")]
    digests = []
    for hash_seed in ("1", "12345"):
        env = dict(os.environ, PYTHONHASHSEED=hash_seed)
        out = subprocess.run([sys.executable, "-c", _HASH_SCRIPT, *files], cwd=ROOT, env=env,
                             capture_output=True, text=True, timeout=120)
        assert out.returncode == 0, out.stderr
        digests.append(out.stdout.strip())
    assert len(digests[0]) == 64 and digests[0] == digests[1]


def test_one_carrier_simulation_matches_observe_all(tiny):
    """A carrier process simulating only itself sees exactly what observe_all computes."""
    trace = world.simulate_mission(tiny)
    valid = tiny.valid()
    for r, cid in enumerate(tiny.carrier_ids):
        sim = world.Simulation(tiny, carriers=[cid])
        for j, t in enumerate(tiny.stage_times()):
            sim.advance_to(float(t))
            if valid[r, j]:
                assert sim.position(cid) == tuple(trace.positions[r, j])
                assert sim.sense(cid) == trace.x[r, j]


@pytest.mark.parametrize("name", ["tiny", "urban_alpha"])
def test_stepping_chipmunk_directly_gives_the_wrappers_bits(name):
    # world.sim steps through chipmunk's functions when pymunk's wrapper has nothing to do;
    # against the wrapper on every step: the same trajectory bit for bit, with walls, a carrier
    # that deploys (a body added to its space) and one halted on the way.
    scenario = world.load_scenario(ROOT / "scenarios" / f"{name}.yaml")
    ids = scenario.carrier_ids
    runs = []
    for direct in (True, False):
        sim = world.Simulation(scenario)
        for body in sim._bodies.values():
            body.direct = direct
        for j, t in enumerate(scenario.stage_times()):
            sim.advance_to(float(t))
            if j == 1:
                sim.deploy(ids[0])
            if j == 2 and len(ids) > 1:
                sim.halt(ids[1])
        runs.append([sim.trajectory(cid) for cid in ids])
    assert all(body.direct for body in world.Simulation(scenario)._bodies.values())  # the pinned pymunk has it
    for a, b in zip(*runs):
        assert np.array_equal(a, b)
    body = world.Simulation(scenario)._bodies[ids[0]]
    body.direct = False  # as with a pymunk whose wrapper keeps its state elsewhere: the wrapper only
    body.advance(step_of(float(scenario.stage_times()[-1])))
    assert np.array_equal(np.asarray(body.trace, dtype=float), runs[0][0][: len(body.trace)])


def test_seed_changes_features_not_physics(tiny):
    a = world.simulate_mission(tiny)
    b = world.simulate_mission(tiny, seed=tiny.seed + 1)
    c = world.simulate_mission(tiny.with_seed(tiny.seed + 1))
    assert not np.array_equal(a.features, b.features)
    np.testing.assert_array_equal(a.positions, b.positions)
    np.testing.assert_array_equal(b.x, c.x)
    np.testing.assert_array_equal(b.features, c.features)
    np.testing.assert_array_equal(np.isnan(a.x), ~tiny.valid())
    np.testing.assert_array_equal(world.observe_all(tiny, seed=tiny.seed + 1), b.x)


def test_features_thin_to_free_area(urban):
    f = world.sample_features(urban)
    assert len(f) > 50
    d = geometry.point_segment_distance(f, urban.map.segments).min(axis=1)
    assert (d >= world.features.FEATURE_CLEARANCE).all()
    xmin, ymin, xmax, ymax = urban.map.bounds
    assert ((f[:, 0] >= xmin) & (f[:, 0] <= xmax) & (f[:, 1] >= ymin) & (f[:, 1] <= ymax)).all()


def test_obstacles_hold_no_features():
    s = world.load_scenario(SCENARIOS / "six_carriers.yaml")
    f = world.sample_features(s)
    for poly in s.map.obstacles:
        assert not geometry.inside_polygon(f, poly).any()


# ----------------------------------------------------------------------------- sensing


def _brute_force_count(pos, features, radius, segments) -> int:
    """Per-feature loop: distance test, then a pymunk segment query against zero-width walls."""
    space = pymunk.Space()
    for x1, y1, x2, y2 in segments:
        space.add(pymunk.Segment(space.static_body, (x1, y1), (x2, y2), 0.0))
    n = 0
    for fx, fy in features:
        if (fx - pos[0]) ** 2 + (fy - pos[1]) ** 2 > radius**2:
            continue
        if space.segment_query_first(tuple(pos), (fx, fy), 0.0, pymunk.ShapeFilter()) is None:
            n += 1
    return n


@pytest.mark.parametrize("name", ["tiny", "urban_alpha", "six_carriers"])
def test_sensing_matches_brute_force_with_line_of_sight(name):
    s = world.load_scenario(SCENARIOS / f"{name}.yaml")
    trace = world.simulate_mission(s)
    blocked_somewhere = False
    for r, j in np.argwhere(s.valid()):
        pos = trace.positions[r, j]
        expected = _brute_force_count(pos, trace.features, s.sensing_radius, s.map.segments)
        assert trace.x[r, j] == expected, (r, j)
        in_disc = int((np.hypot(*(trace.features - pos).T) <= s.sensing_radius).sum())
        blocked_somewhere |= expected < in_disc
    if len(s.map.segments):
        assert blocked_somewhere, "walls must hide some features somewhere, or this test proves nothing"


def test_visibility_random_against_pymunk():
    rng = np.random.default_rng(3)
    segs = rng.uniform(0, 20, size=(15, 4))
    space = pymunk.Space()
    for x1, y1, x2, y2 in segs:
        space.add(pymunk.Segment(space.static_body, (x1, y1), (x2, y2), 0.0))
    origin = (10.0, 10.0)
    targets = rng.uniform(0, 20, size=(400, 2))
    got = geometry.visible(origin, targets, segs)
    want = np.array([space.segment_query_first(origin, tuple(t), 0.0, pymunk.ShapeFilter()) is None for t in targets])
    np.testing.assert_array_equal(got, want)
    assert 0 < got.sum() < len(got)


def test_open_field_counts_follow_the_prior():
    """No walls: the observed counts are Poisson(density x pi r²) (a check of sensing, loose)."""
    s = world.load_scenario(SCENARIOS / "open_field.yaml")
    xs = np.concatenate([world.observe_all(s, seed=k)[s.valid()] for k in range(60)])
    lam = s.prior_distribution().mean()
    se = np.sqrt(lam / len(xs)) * 3 * 3  # paths cross: samples are correlated; be generous
    assert abs(xs.mean() - lam) < se


# ----------------------------------------------------------------------------- overlaps


def _brute_maximal_cliques(pts: np.ndarray, radius: float) -> set[frozenset[int]]:
    n = len(pts)
    close = np.hypot(*(pts[:, None] - pts[None, :]).transpose(2, 0, 1)) <= radius
    cliques = [frozenset(c) for k in range(2, n + 1) for c in itertools.combinations(range(n), k)
               if all(close[a, b] for a, b in itertools.combinations(c, 2))]
    return {c for c in cliques if not any(c < d for d in cliques)}


@pytest.mark.parametrize("seed", range(6))
def test_overlaps_equal_brute_force_maximal_cliques(seed):
    rng = np.random.default_rng(seed)
    n_carriers, n_stages = 3, 4
    pos = rng.uniform(0, 30, size=(n_carriers, n_stages, 2))
    valid = rng.random((n_carriers, n_stages)) < 0.8
    got = proximity_overlaps(pos, valid, 12.0)
    idx = [tuple(p) for p in np.argwhere(valid)]
    want = _brute_maximal_cliques(pos[valid], 12.0)
    assert {frozenset(g) for g in got} == {frozenset(idx[m] for m in c) for c in want}
    assert len(got) == len(want)


@pytest.mark.parametrize("name", ALL)
def test_overlap_properties_on_scenarios(name):
    s = world.load_scenario(SCENARIOS / f"{name}.yaml")
    geo = world.stage_geometry(s)
    pts = {tuple(p): geo.positions[tuple(p)] for p in np.argwhere(geo.valid)}
    near = {(a, b) for a in pts for b in pts
            if a != b and np.hypot(*(pts[a] - pts[b])) <= s.conflict_radius}
    shared = set()
    for g in geo.overlaps:
        assert len(g) >= 2 and len(set(g)) == len(g) and all(geo.valid[p] for p in g)
        shared |= {(a, b) for a in g for b in g if a != b}
        # maximal: no other point is near every member
        for q in pts:
            if q not in g:
                assert not all((q, p) in near for p in g)
    assert shared == near  # share an overlap <=> within the conflict radius
    groups = [frozenset(g) for g in geo.overlaps]
    assert not any(a < b for a in groups for b in groups)
    assert json.loads(json.dumps(geo.overlaps)) is not None  # plain ints and lists


def test_overlaps_build_a_planner_problem(tiny):
    """The format is the planner core's: Problem.build accepts it and sees the same conflicts."""
    problem_mod = pytest.importorskip("planner.problem")
    geo = world.stage_geometry(tiny)
    p = problem_mod.Problem.build(tiny.passengers, geo.valid, geo.overlaps, tiny.prior_distribution())
    n = tiny.stages
    for r1, j1 in np.argwhere(geo.valid):
        for r2, j2 in np.argwhere(geo.valid):
            if (r1, j1) == (r2, j2):
                continue
            near = np.hypot(*(geo.positions[r1, j1] - geo.positions[r2, j2])) <= tiny.conflict_radius
            assert p.conflict[r1 * n + j1, r2 * n + j2] == near


# ----------------------------------------------------------------------------- physics


def test_walls_stop_a_carrier(tiny):
    """Collisions are real: a wall dropped across carrier a's path (bypassing validation) stops it."""
    wall_x = 20.0
    blocked = dataclasses.replace(tiny, map=dataclasses.replace(tiny.map, walls=((
        (wall_x, 10.0), (wall_x, 30.0)),)))
    sim = world.Simulation(blocked, carriers=["a"])
    sim.advance_to(15.0)
    x, y = sim.position("a")
    assert tiny.carriers[0].position_at(15.0)[0] > 30  # the plan is far past the wall
    assert wall_x - CARRIER_RADIUS - 0.2 < x < wall_x  # held at the wall, not through it
    assert abs(y - 20.0) < 0.05


def test_planned_and_actual_positions_agree(urban):
    trace = world.simulate_mission(urban)
    geo = world.stage_geometry(urban)
    err = np.hypot(*(trace.positions - geo.positions).transpose(2, 0, 1))[geo.valid]
    assert err.max() < 0.05


def test_simulation_api(tiny):
    sim = world.Simulation(tiny)
    sim.advance_to(5.0)
    assert sim.time == pytest.approx(5.0) and step_of(5.0) == 100
    assert sim.position("b") == pytest.approx((20.0, 4.0))  # b starts at 5 s
    dep = sim.deploy("b")
    assert dep.carrier == "b" and dep.position == sim.position("b") and sim.passengers_left("b") == 0
    with pytest.raises(ValueError):
        sim.deploy("b")
    sim.halt("a")
    here = sim.position("a")
    sim.advance_to(12.0)
    assert sim.position("a") == here
    assert sim.trajectory("b").shape[1] == 3
    # a carrier that stopped for good stays put
    sim.advance_to(40.0)
    end = sim.position("b")
    sim.advance_to(60.0)
    assert sim.position("b") == end


def test_render_map_writes_png(tmp_path, tiny):
    trace = world.simulate_mission(tiny)
    dep = np.zeros(tiny.valid().shape, bool)
    dep[0, 1] = dep[1, 3] = True
    out = world.render_map(tiny, tmp_path / "m.png", deployments=dep, trajectories=trace.trajectories,
                           positions=trace.positions, title="t")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    out2 = world.render_map(tiny, tmp_path / "m2.png", deployments=[("a", (10.0, 20.0))],
                            trajectories={"b": trace.trajectories[1]})
    assert out2.stat().st_size > 10000


def test_priors_explicit_and_derived(tmp_path):
    base = {"name": "p", "seed": 1, "map": {"bounds": [0, 0, 10, 10]}, "features": {"density": 0.1},
            "sensing_radius": 2.0, "stage_interval": 1.0, "stages": 3,
            "carriers": [{"id": "a", "passengers": 1, "start_time": 0, "speed": 1, "waypoints": [[1, 1], [9, 1]]}]}
    s = parse_scenario(base)
    assert s.prior_distribution().mean() == pytest.approx(0.1 * np.pi * 4)
    assert s.conflict_radius == pytest.approx(6.0)
    geo = parse_scenario({**base, "prior": {"kind": "geometric", "p": 0.25}}).prior_distribution()
    assert geo.pmf(0) == pytest.approx(0.25)  # failures before the first success: support from 0
    ln = parse_scenario({**base, "prior": {"kind": "lognormal", "mu": 1.0, "sigma": 0.5}}).prior_distribution()
    assert ln.median() == pytest.approx(np.e)
    tab = parse_scenario({**base, "prior": {"kind": "table", "values": [0, 5], "probabilities": [0.5, 0.5]}})
    assert tab.prior_distribution().mean() == pytest.approx(2.5)


def test_building_generator_geometry():
    from world import building as bld
    from world.scenario import Building

    b = Building(origin=(10.0, 5.0), cols=2, rows=1, room_size=(20.0, 10.0), corridor_width=4.0, door_width=2.0,
                 entrances=("west",))
    assert b.extent == (10.0, 5.0, 10 + 2 * 20 + 3 * 4, 5 + 10 + 2 * 4)
    assert b.room_rect(1, 0) == (10 + 4 + 24, 9.0, 10 + 4 + 24 + 20, 19.0)
    segs = np.asarray(bld.wall_segments(b))
    assert len(segs) == 2 * 4 * 2 + 3 + 2  # 2 rooms x 4 walls x 2 halves; outer: 3 sides + west in 2
    cx, cy = 24.0, 14.0  # centre of room (0, 0)
    # straight out of the room through its south door into the corridor: visible
    assert geometry.visible((cx, cy), np.array([[cx, 7.0]]), segs)[0]
    # diagonally through the room's wall: hidden
    assert not geometry.visible((cx, cy), np.array([[cx + 8, 7.0]]), segs)[0]
    # the west entrance opens the corridor: from outside, a point in the corridor is visible
    y_mid = bld.corridor_y(b, b.rows // 2)
    assert geometry.visible((2.0, y_mid), np.array([[12.0, y_mid]]), segs)[0]
    assert not geometry.visible((2.0, y_mid + 6), np.array([[12.0, y_mid + 6]]), segs)[0]


def test_prior_report_pools_valid_stages(tiny):
    from world.report import prior_report

    rep = prior_report(tiny, seeds=4, first_seed=10)
    xs = np.concatenate([world.observe_all(tiny, seed=10 + k)[tiny.valid()] for k in range(4)])
    assert rep.samples == len(xs) == 4 * int(tiny.valid().sum())
    assert rep.mean == pytest.approx(xs.mean()) and rep.var == pytest.approx(xs.var(ddof=1))
    assert rep.prior_mean == pytest.approx(tiny.derived_prior_mean())


def test_collinear_segments_meet_only_where_their_extents_overlap():
    """The sign test alone calls every pair of collinear segments crossing; walls traced on a
    grid are often collinear with a route 7 m away (world.grid.wall_lines)."""
    from world import geometry

    walls = np.array([[12.4, 10.925, 12.45, 10.925], [19.7, 10.925, 19.9, 10.925], [19.825, 10.925, 20.0, 10.925],
                      [19.7, 10.0, 19.7, 12.0]])
    d = geometry.segment_segment_distance((19.625, 10.925), (19.825, 10.925), walls)
    assert d.tolist() == [pytest.approx(7.175), 0.0, 0.0, 0.0]
    assert geometry.visible((0.0, 0.0), np.array([[1.0, 0.0], [3.0, 0.0]]),
                            np.array([[2.0, 0.0, 2.5, 0.0]])).tolist() == [True, False]
