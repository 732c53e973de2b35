"""The marine family (world/marine.py), the current field (world/current.py) and the wire's fit
to an acoustic frame (wire/sizes.py, ``python -m world check``)."""
from __future__ import annotations

import copy
import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from launcher.scenario_check import world_command
from wire import messages as wm
from wire.sizes import STAGE_KINDS, UNCHECKED_KINDS, fit_trail, frame_problems, link_sizes, message_sizes
from world.current import CurrentSpec, Vortex
from world.marine import MarineSettings, draw_hotspots, marine_document, write_marine
from world.scenario import ScenarioError, load_scenario, parse_scenario
from world.sim import simulate_mission

ROOT = Path(__file__).resolve().parents[1]
MARINE = ROOT / "scenarios" / "marine_survey.yaml"
SMALL = MarineSettings(name="small", seed=5, vessels=2, width=1200.0, height=800.0, prior_seeds=3)


# --------------------------------------------------------------------------- the generator
def test_the_bundled_file_is_the_generators_output(tmp_path):
    out = write_marine(tmp_path / "m.yaml")
    assert out.read_text() == MARINE.read_text()


def test_generator_is_deterministic_and_the_seed_matters():
    a, b = marine_document(SMALL), marine_document(SMALL)
    assert a == b
    c = marine_document(dataclasses.replace(SMALL, seed=6))
    assert c["features"]["clusters"] != a["features"]["clusters"] or c["current"] != a["current"]


def test_vessels_run_lawnmower_transects_in_their_own_strips():
    doc = marine_document(SMALL)
    strip = SMALL.width / SMALL.vessels
    for v, c in enumerate(doc["carriers"]):
        wps = np.asarray(c["waypoints"])
        assert ((wps[:, 0] > v * strip) & (wps[:, 0] < (v + 1) * strip)).all()
        xs = wps[::2, 0]
        assert np.allclose(np.diff(xs), SMALL.line_spacing)              # lines line_spacing apart
        assert np.allclose(wps[0::2, 0], wps[1::2, 0])                   # each line parallel to y
        ends = wps[:, 1]
        assert np.allclose(ends[1::4], SMALL.height - SMALL.line_spacing / 2)  # alternate ends
        assert c["passengers"] == ["auv", "auv", "glider"]


def test_hotspots_are_matern_cluster_parents():
    doc = marine_document(SMALL)
    r, mean = SMALL.hotspot_radius, SMALL.hotspot_mean
    for cl in doc["features"]["clusters"]:
        x, y = cl["disc"]["center"]
        assert r <= x <= SMALL.width - r and r <= y <= SMALL.height - r
        assert cl["disc"]["radius"] == r
        assert cl["density"] == pytest.approx(mean / (math.pi * r * r), rel=1e-5)
    # parents: Poisson with hotspots_per_km2 over the area, across generator seeds
    counts = [len(draw_hotspots(np.random.default_rng(s), SMALL)) for s in range(200)]
    assert np.mean(counts) == pytest.approx(SMALL.hotspots_per_km2 * SMALL.width * SMALL.height / 1e6, rel=0.15)


def test_the_marine_scenario_loads_with_acoustic_links_current_and_a_fitted_prior():
    s = load_scenario(MARINE)
    assert s.links.model == "acoustic" and s.current is not None and s.prior.kind == "negative_binomial"
    assert {t for c in s.carriers for t in c.passenger_types} == {"auv", "glider"}
    assert frame_problems(s) == []


# --------------------------------------------------------------------------- the current
V = Vortex(center=(100.0, 50.0), radius=20.0, speed=0.5)


@pytest.mark.parametrize("spec, at, velocity", [
    (CurrentSpec(), (3.0, 4.0), (0.0, 0.0)),
    (CurrentSpec(drift=(0.2, -0.1)), (3.0, 4.0), (0.2, -0.1)),
    (CurrentSpec(vortices=(V,)), (100.0, 50.0), (0.0, 0.0)),          # calm at the centre
    (CurrentSpec(vortices=(V,)), (120.0, 50.0), (0.0, 0.5)),          # peak speed at R, counter-clockwise
    (CurrentSpec(vortices=(V,)), (100.0, 70.0), (-0.5, 0.0)),
    (CurrentSpec(vortices=(dataclasses.replace(V, speed=-0.5),)), (120.0, 50.0), (0.0, -0.5)),
    (CurrentSpec(drift=(0.1, 0.0), vortices=(V,)), (120.0, 50.0), (0.1, 0.5)),
    (CurrentSpec(vortices=(V,)), (100.0 + 40.0, 50.0), (0.0, 0.5 * 2 * math.exp(-1.5))),  # Gaussian decay
], ids=["none", "drift", "centre", "peak-east", "peak-north", "clockwise", "sum", "decay"])
def test_current_field(spec, at, velocity):
    assert spec.at(*at) == pytest.approx(velocity, abs=1e-12)


def test_vortex_field_is_smooth_and_divergence_free():
    spec = CurrentSpec(vortices=(V, Vortex((60.0, 20.0), 35.0, -0.3)))
    h = 1e-4
    for x, y in np.random.default_rng(0).uniform(0, 150, (50, 2)):
        du = (spec.at(x + h, y)[0] - spec.at(x - h, y)[0]) / (2 * h)
        dv = (spec.at(x, y + h)[1] - spec.at(x, y - h)[1]) / (2 * h)
        assert abs(du + dv) < 1e-6


def test_a_current_pushes_carriers_and_none_leaves_the_physics_as_it_was():
    s = parse_scenario(marine_document(SMALL), "small.yaml")
    calm = dataclasses.replace(s, current=None)
    strong = dataclasses.replace(s, current=CurrentSpec(drift=(0.0, 0.8)))
    p_calm, p_strong = simulate_mission(calm).positions, simulate_mission(strong).positions
    offset = np.hypot(*(p_strong - p_calm).transpose(2, 0, 1))
    assert np.nanmax(offset) > 0.3                     # pushed off the calm track...
    assert np.nanmax(offset) < 0.8 / 1.0 * 1.5         # ...by about drift / CONTROL_GAIN at most
    assert np.array_equal(simulate_mission(calm).positions, p_calm)


@pytest.mark.parametrize("current, field, words", [
    ({"drift": [0.1]}, "current.drift", "[u, v], two speeds"),
    ({"drift": [0.1, 20]}, "current.drift", "within +-10 m/s"),
    ({"vortices": [{"center": [0, 0], "radius": 0, "speed": 1}]}, "current.vortices[0].radius", "a number > 0"),
    ({"vortices": [{"center": [0, 0], "radius": 5}]}, "current.vortices[0].speed", "missing"),
    ({"vortex": []}, "current.vortex", "unknown key"),
    ([1, 2], "current", "a mapping {drift"),
], ids=["drift-short", "drift-fast", "radius", "speed-missing", "unknown-key", "not-a-mapping"])
def test_bad_current_names_the_field(current, field, words):
    data = yaml.safe_load(MARINE.read_text())
    data["current"] = current
    with pytest.raises(ScenarioError) as err:
        parse_scenario(data, "m.yaml")
    lines = [line for line in err.value.problems if line.startswith(f"m.yaml: {field}:")]
    assert lines and words in lines[0], err.value.problems


# --------------------------------------------------------------------------- the wire and the frame
def test_sizes_are_the_codecs():
    s = load_scenario(MARINE)
    sizes = {m.kind: m for m in message_sizes(s)}
    assert set(STAGE_KINDS) <= set(sizes) and all(sizes[k].stage for k in STAGE_KINDS)
    obs = wm.Observation("marine_survey", "vessel1", s.stages - 1, 2400.123456789, 10**9 - 1,
                         (1234.56789, -987.654321), 3, ())
    assert sizes["obs"].size == len(wm.encode(obs))
    assert sizes["obs+trail"].size > sizes["obs"].size


def _with_frame(frame: int) -> Path:
    data = yaml.safe_load(MARINE.read_text())
    data["links"]["frame_bytes"] = frame
    return data


@pytest.mark.parametrize("frame, kinds", [(256, []), (130, ["obs", "confirm", "own"]), (128, ["obs", "confirm", "own"])],
                         ids=["fits", "some-do-not", "tight"])
def test_frame_check_names_each_message_that_does_not_fit(frame, kinds):
    s = parse_scenario(_with_frame(frame), "m.yaml")
    sizes = {m.kind: m.size for m in message_sizes(s)}
    assert [k for k in STAGE_KINDS if sizes[k] > frame] == [k for k in kinds if sizes[k] > frame]
    expected = [k for k in sizes if k not in UNCHECKED_KINDS and sizes[k] > frame]  # every kind that crosses the links
    problems = frame_problems(s)
    assert [p.field for p in problems] == ["links.frame_bytes"] * len(expected)
    for p, k in zip(problems, expected):
        assert f"the {k} message, {sizes[k]} bytes" in p.expected and p.found == f"{frame} bytes"


def test_frame_too_small_for_any_message():
    s = parse_scenario(_with_frame(16), "m.yaml")
    (problem,) = frame_problems(s)
    assert problem.field == "links.frame_bytes" and "no message fits" in problem.found


def test_world_check_refuses_a_frame_too_small(tmp_path, capsys):
    path = tmp_path / "m.yaml"
    path.write_text(yaml.safe_dump(_with_frame(100)))
    assert world_command(["check", str(path), "--seeds", "2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err and all(line.startswith(f"{path}: links.frame_bytes: expected at least ") for line in err)
    assert any("obs message" in line for line in err)


def test_world_check_passes_the_marine_scenario(capsys):
    assert world_command(["check", str(MARINE), "--seeds", "2"]) == 0
    out = capsys.readouterr().out
    assert "links: acoustic" in out and "decision points reaching the base" in out


def test_other_models_have_no_frame():
    data = copy.deepcopy(yaml.safe_load(MARINE.read_text()))
    data["links"] = {"model": "radio", "relays": {"count": 1}}
    assert frame_problems(parse_scenario(data, "m.yaml")) == []


def test_wire_sizes_tool(tmp_path, capsys):
    from tools.wire_sizes import main

    assert main([str(MARINE)]) == 0
    out = capsys.readouterr().out
    sizes = {m.kind: m.size for m in message_sizes(load_scenario(MARINE))}
    assert f"obs           {sizes['obs']:>3}   yes" in out and "obs+trail" in out and "not sent so: see obs+fitted" in out and "DOES NOT FIT" not in out
    path = tmp_path / "m.yaml"
    path.write_text(yaml.safe_dump(_with_frame(130)))
    assert main([str(path)]) == 2
    assert "links.frame_bytes" in capsys.readouterr().err


# --------------------------------------------------------------------------- the trail fitted to the frame
def _obs(trail) -> wm.Observation:
    return wm.Observation("marine_survey", "vessel1", 20, 2400.123456789, 10**9 - 1, (1234.56789, -987.654321), 3,
                          tuple(trail))


def test_a_trail_that_fits_is_sent_as_it_is():
    obs = _obs([(1.0, 2.0), (3.0, 4.0)])
    assert fit_trail(obs, 256) is obs


def test_a_straight_trail_keeps_its_ends_and_a_turn_its_corner():
    straight = _obs([(100.0 + k, 200.0) for k in range(120)])
    fitted = fit_trail(straight, 256)
    assert fitted.trail == ((100.0, 200.0), (219.0, 200.0)) and len(wm.encode(fitted)) <= 256
    turn = _obs([(float(k), 0.0) for k in range(60)] + [(59.0, float(k)) for k in range(1, 60)])
    assert fit_trail(turn, 256).trail == ((0.0, 0.0), (59.0, 0.0), (59.0, 59.0))
    assert fitted.position == straight.position and fitted.x == straight.x  # only the informative trail changes


def test_a_wiggling_trail_is_thinned_until_it_fits_and_decodes():
    rng = np.random.default_rng(3)
    wiggle = _obs([(float(k), float(v)) for k, v in enumerate(rng.normal(0, 50, 400))])
    for frame in (140, 166, 256, 600):
        fitted = fit_trail(wiggle, frame)
        data = wm.encode(fitted)
        assert len(data) <= frame and wm.decode(data) == fitted
        assert set(fitted.trail) <= set(wiggle.trail)
    assert fit_trail(wiggle, 128).trail == ()  # room for the Observation alone: an empty trail


def test_link_sizes_count_the_fitted_observation():
    s = load_scenario(MARINE)
    sizes = link_sizes(s)
    assert sizes["obs"] == {m.kind: m.size for m in message_sizes(s)}["obs+fitted"] <= s.links.frame_bytes
    assert max(sizes[k] for k in sizes if k not in UNCHECKED_KINDS) <= s.links.frame_bytes


# --------------------------------------------------------------------------- bad links through `python -m world check`
@pytest.mark.parametrize("links, field, words", [
    ({"bitrate_bps": 0}, "links.bitrate_bps", "expected a number from 1 to 1e+06 (bit/s"),
    ({"fade_db": 25}, "links.fade_db", "expected a number from 0 to 20 (dB"),
    ({"frame_bytes": 16}, "links.frame_bytes", "no message fits"),
    ({"relays": {"count": 1}}, "links.relays", "only with links.model radio"),
    ({"model": "perfect", "relays": {"count": 1}}, "links.relays", "found links.model perfect"),
], ids=["param-out-of-range", "fade-out-of-range", "frame-too-small-for-any", "relays-acoustic", "relays-perfect"])
def test_world_check_names_the_bad_links_field(tmp_path, capsys, links, field, words):
    data = yaml.safe_load(MARINE.read_text())
    data["links"].update(links)
    if links.get("model") == "perfect":
        data["links"] = {"model": "perfect", "relays": links["relays"]}
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(data))
    assert world_command(["check", str(path), "--seeds", "2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    hits = [line for line in err if line.startswith(f"{path}: {field}: ")]
    assert hits and words in hits[0], err
