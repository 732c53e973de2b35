"""Broken scenario files: each mistake gets its own clear line (file, field path, expected, found),
and the CLI exits with code 2 without a traceback."""
from __future__ import annotations

import copy
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

import world

ROOT = Path(__file__).resolve().parents[1]
TINY = ROOT / "scenarios" / "tiny.yaml"
BASE = yaml.safe_load(TINY.read_text())


def _set(path: list, value):
    def edit(d):
        node = d
        for key in path[:-1]:
            node = node[key]
        if value is _DELETE:
            del node[path[-1]]
        else:
            node[path[-1]] = value
    return edit


_DELETE = object()


def _rename(path: list, new_key: str):
    def edit(d):
        node = d
        for key in path[:-1]:
            node = node[key]
        node[new_key] = node.pop(path[-1])
    return edit


# (id, edit of the tiny scenario, substring every error line set must contain)
CASES = [
    ("typo-top-key", _rename(["sensing_radius"], "sensing_radus"),
     "sensing_radus: expected a known key (did you mean 'sensing_radius'?), found unknown key 'sensing_radus'"),
    ("typo-carrier-key", _rename(["carriers", 0, "speed"], "sped"),
     "carriers[0].sped: expected a known key (did you mean 'speed'?), found unknown key 'sped'"),
    ("missing-carriers", _set(["carriers"], _DELETE), "carriers: expected a value, found nothing (missing)"),
    ("speed-not-a-number", _set(["carriers", 1, "speed"], "fast"),
     "carriers[1].speed: expected a number > 0, found 'fast'"),
    ("negative-radius", _set(["sensing_radius"], -1), "sensing_radius: expected a number > 0, found -1"),
    ("zero-stages", _set(["stages"], 0), "stages: expected an integer >= 1, found 0"),
    ("absurd-stages", _set(["stages"], 10**9), "stages: expected an integer >= 1 and <= 100000, found 1000000000"),
    ("mission-too-long", _set(["stage_interval"], 1e6),
     "stages: expected a last stage (first_stage_time + (stages - 1) x stage_interval) at most 100000 s, found 3e+06 s"),
    ("absurd-density", _set(["features", "density"], 1e6),
     "features.density: expected densities giving at most 2e+06 expected features on the map, found 1.6e+09 expected features"),
    ("bool-seed", _set(["seed"], True), "seed: expected an integer >= 0, found True"),
    ("waypoint-outside", _set(["carriers", 0, "waypoints", 1], [50, 20]),
     "carriers[0].waypoints[1]: expected a point inside map.bounds [0.0, 0.0, 40.0, 40.0], found [50.0, 20.0]"),
    ("waypoint-shape", _set(["carriers", 0, "waypoints", 0], [4]),
     "carriers[0].waypoints[0]: expected a point [x, y] of two numbers (m), found [4]"),
    ("path-through-wall", _set(["carriers", 1, "waypoints"], [[20, 4], [20, 30]]),
     "carriers[1].waypoints[0]->[1]: expected a leg clear of walls by 0.4 m, found it meets the wall (12, 23.5)-(30, 23.5)"),
    ("waypoint-in-obstacle", _set(["map", "obstacles"], [[[33, 17], [39, 17], [39, 23], [33, 23]]]),
     "carriers[0].waypoints[1]: expected a point outside every obstacle, found [36.0, 20.0] inside map.obstacles[0]"),
    ("stop-before-start", _set(["carriers", 1, "stop_time"], 2),
     "carriers[1].stop_time: expected a time >= start_time (5 s), found 2"),
    ("duplicate-id", _set(["carriers", 1, "id"], "a"),
     "carriers[1].id: expected a unique id (carriers[0] is already 'a'), found 'a'"),
    ("too-many-passengers", _set(["carriers", 0, "passengers"], 9),
     "carriers[0].passengers: expected at most 4 (the valid stages of carrier 'a' between start_time and stop_time), found 9"),
    ("unknown-passenger-type", _set(["carriers", 0, "passengers"], ["scout", "drone"]),
     "carriers[0].passengers[0]: expected a type of passenger_types (none defined in passenger_types) or a "
     "mapping {type: NAME, value: W}, found 'scout'"),
    ("passenger-value-not-positive", _set(["carriers", 0, "passengers"], [{"type": "scout", "value": 0}]),
     "carriers[0].passengers[0].value: expected a number > 0, found 0"),
    ("passenger-without-value", _set(["carriers", 0, "passengers"], [{"type": "scout"}]),
     "carriers[0].passengers[0].value: expected a number > 0 (type 'scout' is not in passenger_types), found nothing (missing)"),
    ("passenger-typo-key", _set(["carriers", 0, "passengers"], [{"type": "scout", "valeu": 1}]),
     "carriers[0].passengers[0].valeu: expected a known key (did you mean 'value'?), found unknown key 'valeu'"),
    ("passenger-types-bad-weight", _set(["passenger_types"], {"scout": -1}),
     "passenger_types.scout: expected a number > 0, found -1"),
    ("too-many-typed-passengers", _set(["carriers", 0, "passengers"], [{"value": 1}] * 9),
     "carriers[0].passengers: expected at most 4 (the valid stages of carrier 'a' between start_time and stop_time), found 9"),
    ("bounds-inverted", _set(["map", "bounds"], [40, 0, 0, 40]),
     "map.bounds: expected xmin < xmax and ymin < ymax, found [40, 0, 0, 40]"),
    ("unknown-prior-kind", _set(["prior"], {"kind": "poison", "mean": 3}),
     "prior.kind: expected derived or one of poisson, binomial, geometric, negative_binomial, discrete_uniform, "
     "table, gamma, exponential, lognormal, normal, uniform (did you mean 'poisson'?), found 'poison'"),
    ("bad-prior-parameter", _set(["prior"], {"kind": "binomial", "n": 10, "p": 1.5}),
     "prior.p: expected a number in (0, 1], found 1.5"),
    ("missing-prior-parameter", _set(["prior"], {"kind": "normal", "mean": 3}),
     "prior.std: expected a number > 0 (normal prior), found nothing (missing)"),
    ("unknown-planner", _set(["planner", "name"], "mcts-sap"),
     "planner.name: expected one of random, ssap, mcts-random, mcts-ssap, closed-loop, closed-loop-gated, online-optimal, dec-mcts, dec-closed-loop (did you mean 'mcts-ssap'?), found 'mcts-sap'"),
    ("room-cluster-without-building", _set(["features", "clusters"], [{"room": [0, 0], "density": 1}]),
     "features.clusters[0].room: expected a map.building to take the room from, found no building in map"),
    ("carriers-not-a-list", _set(["carriers"], {"id": "a"}), "carriers: expected a non-empty list of carriers, found a mapping"),
    ("building-outside-bounds", _set(["map", "building"], {"origin": [0, 0], "rooms": [3, 3], "room_size": [20, 20],
                                                            "corridor_width": 4, "door_width": 2}),
     "map.building: expected a building inside map.bounds [0.0, 0.0, 40.0, 40.0], found its outer wall spans [0.0, 0.0, 76.0, 76.0]"),
]


def _write(tmp_path: Path, data) -> Path:
    p = tmp_path / "broken.yaml"
    p.write_text(yaml.safe_dump(data, sort_keys=False))
    return p


@pytest.mark.parametrize("edit,expected", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_broken_scenario_has_its_clear_line(tmp_path, edit, expected):
    data = copy.deepcopy(BASE)
    edit(data)
    path = _write(tmp_path, data)
    with pytest.raises(world.ScenarioError) as info:
        world.load_scenario(path)
    lines = info.value.problems
    assert f"{path}: {expected}" in lines, "\n".join(lines)
    assert all(line.startswith(f"{path}: ") and "\n" not in line for line in lines)


def test_all_problems_are_collected_at_once(tmp_path):
    data = copy.deepcopy(BASE)
    data["sensing_radius"] = "five"
    data["carriers"][0]["speed"] = -2
    data["carriers"][1]["waypoints"] = "north"
    data["colour"] = "red"
    path = _write(tmp_path, data)
    with pytest.raises(world.ScenarioError) as info:
        world.load_scenario(path)
    fields = [line.split(": ")[1] for line in info.value.problems]
    assert fields == ["colour", "sensing_radius", "carriers[0].speed", "carriers[1].waypoints"], info.value.problems


def test_missing_file(tmp_path):
    path = tmp_path / "nope.yaml"
    with pytest.raises(world.ScenarioError) as info:
        world.load_scenario(path)
    assert info.value.problems == [f"{path}: expected an existing scenario file, found no such file"]


def test_yaml_syntax_error_names_the_line(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("name: x\nseed: 1\nmap: {bounds: [0, 0, 10, 10]\nfeatures: {density: 1}\n")
    with pytest.raises(world.ScenarioError) as info:
        world.load_scenario(path)
    (line,) = info.value.problems
    assert line.startswith(f"{path}: line 4, column 1: expected valid YAML, found expected ',' or '}}'"), line


def test_duplicate_yaml_key(tmp_path):
    path = tmp_path / "dup.yaml"
    path.write_text(TINY.read_text() + "seed: 8\n")
    with pytest.raises(world.ScenarioError) as info:
        world.load_scenario(path)
    (line,) = info.value.problems
    assert "expected valid YAML, found duplicate key 'seed' (first at line 3)" in line, line


def test_top_level_must_be_a_mapping(tmp_path):
    path = tmp_path / "list.yaml"
    path.write_text("- 1\n- 2\n")
    with pytest.raises(world.ScenarioError) as info:
        world.load_scenario(path)
    assert info.value.problems == [f"{path}: (top level): expected a mapping, found [1, 2]"]


# ----------------------------------------------------------------------------- CLI


def _cli(*args, timeout=120):
    return subprocess.run([sys.executable, "-m", "world", *map(str, args)], cwd=ROOT, capture_output=True,
                          text=True, timeout=timeout)


def test_cli_check_ok():
    out = _cli("check", TINY, "--seeds", "5")
    assert out.returncode == 0, out.stderr
    assert "scenario tiny" in out.stdout and "overlaps: " in out.stdout and "observed" in out.stdout


def test_cli_check_broken_exits_2_with_lines(tmp_path):
    data = copy.deepcopy(BASE)
    data["carriers"][0]["sped"] = 1
    data["stages"] = "many"
    path = _write(tmp_path, data)
    out = _cli("check", path)
    assert out.returncode == 2
    assert "Traceback" not in out.stderr and out.stdout == ""
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 2 and all(line.startswith(f"{path}: ") for line in lines), lines


@pytest.mark.parametrize("content,command", [(None, "check"), ("a: [1\n", "render")],
                         ids=["missing-file-check", "yaml-error-render"])
def test_cli_bad_files_exit_2(tmp_path, content, command):
    path = tmp_path / "x.yaml"
    if content is not None:
        path.write_text(content)
    args = [command, path] + (["-o", tmp_path / "m.png"] if command == "render" else [])
    out = _cli(*args)
    assert out.returncode == 2 and "Traceback" not in out.stderr
    assert out.stderr.startswith(f"{path}: ") and len(out.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "m.png").exists()


def test_cli_render(tmp_path):
    out = _cli("render", TINY, "-o", tmp_path / "map.png", "--trajectories")
    assert out.returncode == 0, out.stderr
    assert (tmp_path / "map.png").read_bytes()[:4] == b"\x89PNG"


def test_cli_usage_error_exits_2():
    out = _cli("check")
    assert out.returncode == 2 and "Traceback" not in out.stderr


def test_typed_passengers_load(tmp_path):
    data = copy.deepcopy(BASE)
    data["passenger_types"] = {"scout": 1.0, "rover": 0.6}
    data["carriers"][0]["passengers"] = ["rover", {"type": "scout"}]
    data["carriers"][1]["passengers"] = [{"value": 0.3}]
    scenario = world.load_scenario(_write(tmp_path, data))
    assert scenario.passenger_values() == [[0.6, 1.0], [0.3]]
    assert scenario.passengers.tolist() == [2, 1]
    assert scenario.passenger_type(0, 1) == "scout" and scenario.passenger_type(1, 0) == ""
    assert world.load_scenario(TINY).passenger_values() is None
