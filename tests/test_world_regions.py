"""world/regions.py: the coverage reward's regions against closed forms, quadrature and brute force;
the scenario's ``reward`` field; the instance export (issue 35)."""
from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

import world
from planner.instance import parse_instance_counts
from world import regions as rg
from world.__main__ import export, main

ROOT = Path(__file__).resolve().parents[1]
COVERAGE = ROOT / "scenarios" / "six_carriers_coverage.yaml"


def _arr(points, radius=1.0):
    pos = np.asarray(points, dtype=float).reshape(1, -1, 2)
    return rg.arrangement(pos, np.ones(pos.shape[:2], dtype=bool), radius)


def _brute_signature(p, centres, radius):
    return tuple(int(k) for k in np.flatnonzero(np.hypot(*(centres - p).T) <= radius))


def test_one_disc_and_a_lens_have_their_closed_form_areas():
    one = _arr([[3.0, -2.0]], radius=2.5)
    assert one.signatures == ((0,),)
    assert one.areas[0] == pytest.approx(math.pi * 2.5**2, rel=1e-13)
    for d in (0.1, 1.0, 1.9, 1.999):
        lens = 2 * math.acos(d / 2) - d / 2 * math.sqrt(4 - d * d)  # unit discs d apart
        two = _arr([[0.0, 0.0], [d * 0.6, d * 0.8]])
        assert two.signatures == ((0,), (0, 1), (1,))
        assert two.areas[1] == pytest.approx(lens, rel=1e-9, abs=1e-12)
        assert two.areas[0] == pytest.approx(math.pi - lens, rel=1e-12)
    apart = _arr([[0.0, 0.0], [2.0, 0.0]])  # tangent: no shared region of positive area
    assert apart.signatures == ((0,), (1,))


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_regions_partition_every_disc_and_match_a_quadrature(seed):
    rng = np.random.default_rng(seed)
    centres = rng.uniform(0, 6, (14, 2))
    arr = _arr(centres, radius=1.3)
    for k in range(len(arr.centres)):  # the regions inside a disc tile it
        inside = sum(a for sig, a in zip(arr.signatures, arr.areas) if k in sig)
        assert inside == pytest.approx(math.pi * 1.3**2, rel=1e-11)
    # midpoint quadrature on a 1200^2 grid (signatures as bit masks): each region's area within
    # the grid's error, a cell's width times the boundary's length
    n = 1200
    h = 8.6 / n
    g = -1.3 + h * (np.arange(n) + 0.5)
    xx, yy = np.meshgrid(g, g)
    masks = np.zeros(xx.shape, dtype=np.int64)
    for k, (cx, cy) in enumerate(arr.centres):
        masks |= (((xx - cx) ** 2 + (yy - cy) ** 2) <= 1.3**2).astype(np.int64) << k
    cells = dict(zip(*np.unique(masks[masks > 0], return_counts=True)))
    perimeter = 2 * math.pi * 1.3 * len(centres)
    for sig, area in zip(arr.signatures, arr.areas):
        assert abs(cells.pop(sum(1 << k for k in sig), 0) * h * h - area) <= 2 * h * perimeter, sig
    assert sum(cells.values()) * h * h <= 2 * h * perimeter  # no signature left out but slivers
    assert (masks > 0).sum() * h * h == pytest.approx(arr.areas.sum(), rel=5e-3)


def test_counts_are_the_brute_force_signatures():
    rng = np.random.default_rng(7)
    centres = rng.uniform(0, 20, (40, 2))
    arr = _arr(centres, radius=2.0)
    pts = rng.uniform(-2, 22, (3000, 2))
    expected = np.zeros(arr.n_regions, dtype=np.int64)
    index = {sig: m for m, sig in enumerate(arr.signatures)}
    for p in pts:
        sig = _brute_signature(p, arr.centres, 2.0)
        if sig:
            expected[index[sig]] += 1  # every signature a point has is a region of positive area
    np.testing.assert_array_equal(arr.counts(pts), expected)


def test_points_at_one_place_share_their_disc_and_invalid_points_cover_nothing():
    pos = np.array([[[0, 0], [0, 0], [5, 5]], [[0, 0], [1, 0], [9, 9]]], dtype=float)
    valid = np.array([[True, True, True], [True, True, False]])
    arr = rg.arrangement(pos, valid, 1.0)
    assert len(arr.centres) == 3
    assert arr.covers[0][0] == arr.covers[0][1] == arr.covers[1][0]
    assert arr.covers[1][2] is None


def test_a_too_large_arrangement_is_refused_before_any_arc():
    rng = np.random.default_rng(0)
    pos = rng.uniform(0, 10, (64, 200, 2))
    t0 = time.perf_counter()
    with pytest.raises(rg.ArrangementTooLarge, match="pairs of candidate discs"):
        rg.arrangement(pos, np.ones((64, 200), dtype=bool), 5.0)
    assert rg.candidate_pairs(pos.reshape(-1, 2), 5.0) > rg.MAX_PAIRS
    print(f"refused in {time.perf_counter() - t0:.3f} s")


def _coverage_yaml(tmp_path, **changes):
    data = yaml.safe_load(COVERAGE.read_text())
    data.update(changes)
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


@pytest.mark.parametrize("changes, line", [
    ({"reward": "set-cover"}, "reward: expected one of penalty, coverage, found 'set-cover'"),
    ({"prior": {"kind": "poisson", "mean": 3}}, "prior: expected derived under reward: coverage"),
])
def test_bad_reward_settings_are_one_line_errors(tmp_path, changes, line):
    with pytest.raises(world.ScenarioError) as err:
        world.load_scenario(_coverage_yaml(tmp_path, **changes))
    assert any(line in p for p in err.value.problems), err.value.problems


def test_a_dense_coverage_scenario_is_refused_at_load(tmp_path, monkeypatch):
    monkeypatch.setattr(rg, "MAX_PAIRS", 10)
    with pytest.raises(world.ScenarioError, match=r"reward: expected at most 10 pairs"):
        world.load_scenario(_coverage_yaml(tmp_path))


def test_a_disc_met_by_too_many_is_refused_at_load(tmp_path):
    """64 carriers whose paths all cross one point: their discs there meet 63 + others."""
    data = yaml.safe_load(COVERAGE.read_text())
    data.update(map={"bounds": [0, 0, 200, 200]}, features={"density": 0.01}, stages=3, stage_interval=1.0,
                sensing_radius=6.0)
    data["carriers"] = [{"id": f"c{k}", "passengers": 1, "start_time": 0, "speed": 1.0,
                         "waypoints": [[100 + 2 * math.cos(k), 100 + 2 * math.sin(k)], [150, 150]]}
                        for k in range(64)]
    path = tmp_path / "crowd.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    with pytest.raises(world.ScenarioError, match=r"reward: expected at most 63 other candidate discs"):
        world.load_scenario(path)


def test_penalty_scenarios_are_unchanged():
    s = world.load_scenario(ROOT / "scenarios" / "six_carriers.yaml")
    assert s.reward == "penalty" and world.build_problem(s).coverage is None
    assert world.observe_counts(s) is None and world.simulate_mission(s).counts is None


def test_the_fleet_observes_the_sum_of_its_regions_counts():
    s = world.load_scenario(COVERAGE)
    trace = world.simulate_mission(s)
    regions = rg.scenario_regions(s)
    np.testing.assert_array_equal(trace.counts, regions.counts(trace.features))
    for r, cid in enumerate(s.carrier_ids[:3]):
        sim = world.Simulation(s, [cid])
        for j in range(s.stages):
            sim.advance_to(s.stage_time(j))
            if s.valid()[r, j]:
                counts = sim.sense_counts(cid, j)
                assert len(counts) == len(regions.covers[r][j])
                assert sim.sense(cid) == sum(counts) == trace.x[r, j]
            else:
                assert sim.sense_counts(cid, j) is None


def test_export_is_a_coverage_instance_the_planner_reads(tmp_path):
    s = world.load_scenario(COVERAGE)
    out = tmp_path / "i.json"
    assert main(["export", str(COVERAGE), "-o", str(out)]) == 0
    data = json.loads(out.read_text())
    assert data["reward"] == "coverage" and len(data["regions"]) == len(data["counts"])
    (problem, x), counts, sampled = parse_instance_counts(data, str(out))
    assert not sampled and problem.reward == "coverage"
    np.testing.assert_array_equal(counts, world.observe_counts(s))
    np.testing.assert_array_equal(x, world.observe_all(s))
    ref = world.build_problem(s).coverage
    np.testing.assert_array_equal(problem.coverage.idx, ref.idx)
    np.testing.assert_allclose(problem.coverage.means, ref.means, rtol=1e-15)
    penalty = export(world.load_scenario(ROOT / "scenarios" / "tiny.yaml"))
    assert "reward" not in penalty and "overlaps" in penalty


def test_check_reports_the_regions(capsys):
    assert main(["check", str(COVERAGE), "--seeds", "2"]) == 0
    text = capsys.readouterr().out
    assert "reward: coverage; regions: " in text and "regions per point" in text


def test_the_carriers_of_one_process_compute_the_regions_once(monkeypatch):
    """Threads asking at once (a process's carriers at their first observation) wait for one
    arrangement instead of each computing it."""
    import threading

    scenario = world.load_scenario(COVERAGE).with_seed(5)
    rg._scenario_regions.cache_clear()
    calls = []
    real = rg.arrangement

    def counted(*args, **kwargs):
        calls.append(threading.get_ident())
        time.sleep(0.2)  # long enough for every thread to ask while it runs
        return real(*args, **kwargs)

    monkeypatch.setattr(rg, "arrangement", counted)
    got = []
    threads = [threading.Thread(target=lambda: got.append(rg.scenario_regions(scenario))) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    rg._scenario_regions.cache_clear()
    assert len(calls) == 1 and len(got) == 8 and all(g is got[0] for g in got)


def test_the_lazy_poisson_priors_give_the_frozen_priors_numbers():
    from scipy import stats

    from planner import priors
    from planner.coverage import Coverage, PoissonPriors

    scenario = world.load_scenario(COVERAGE)
    means = rg.region_means(scenario)
    lazy = rg.coverage(scenario)
    eager = Coverage.build(rg.scenario_regions(scenario).covers, [stats.poisson(m) for m in means])
    assert lazy.poisson and eager.poisson and len(lazy.priors) == len(eager.priors) == len(means)
    np.testing.assert_array_equal(lazy.means, eager.means)
    np.testing.assert_array_equal(lazy.idx, eager.idx)
    for m in (0, len(means) // 2, -1):
        assert lazy.priors[m].mean() == eager.priors[m].mean() and lazy.priors[m].dist.name == "poisson"
        assert lazy.priors[m] is lazy.priors[m]  # frozen once
    with pytest.raises(IndexError):
        PoissonPriors([1.0])[1]
    for mean in (0.01, 0.7, 3.3, 41.5):
        a, b = priors.support(stats.poisson(mean)), priors.poisson_support(mean)
        np.testing.assert_array_equal(a[0], b[0])
        np.testing.assert_array_equal(a[1], b[1])
