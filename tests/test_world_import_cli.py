"""``python -m world import`` as a user runs it: map_server maps read by nav2's rules, frontier
cells counted by hand, the report's format, the fleet's world from it, and every bad input of
the issue refused with one line and nothing left behind."""
from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import world
from cli_helpers import in_process
from launcher.scenario_check import world_command
from world import grid as G

ROOT = Path(__file__).resolve().parents[1]


def _process(*args, cwd=ROOT):
    """``python -m world import ARGS`` as a separate process."""
    return subprocess.run([sys.executable, "-m", "world", "import", *map(str, args)], cwd=cwd, capture_output=True,
                          text=True, timeout=120)


def _run(*args, cwd=ROOT):
    """``python -m world import ARGS`` through the command's own entry point in this process
    (:func:`cli_helpers.in_process`); test_static_import_report_and_world runs it as a process."""
    return in_process(world_command, ["import", *args], cwd)


def _map_yaml(tmp: Path, pixels: np.ndarray, name="m", fmt="PPM", suffix=".pgm", **fields) -> Path:
    image = tmp / f"{name}{suffix}"
    Image.fromarray(pixels).save(image, format=fmt)
    doc = {"image": image.name, "resolution": 0.1, "origin": [0.0, 0.0, 0.0], "negate": 0,
           "occupied_thresh": 0.65, "free_thresh": 0.25, **fields}
    path = tmp / f"{name}.yaml"
    path.write_text("".join(f"{k}: {json.dumps(v)}\n" for k, v in doc.items()))
    return path


def _room(h=60, w=80) -> np.ndarray:
    """A room: white (free) inside a black (occupied) wall, its east wall open onto grey
    (unknown, 205) in rows 20..39 of the image."""
    px = np.full((h, w), 205, dtype=np.uint8)
    px[5:55, 5:70] = 254
    px[5, 5:70] = px[54, 5:70] = 0
    px[5:55, 5] = px[5:55, 69] = 0
    px[20:40, 69] = 254  # the opening: free cells in the wall's column, unknown beyond
    return px


# --------------------------------------------------------------------------- map_server rules


def test_trinary_scale_raw_negate_and_thresholds(tmp_path):
    px = np.array([[0, 60, 100, 190, 200, 254, 255]], dtype=np.uint8)  # occupancy 1 - v/255
    tri = G.read_map_yaml(_map_yaml(tmp_path, px, "t"))
    assert tri.data[0].tolist() == [100, 100, -1, -1, 0, 0, 0]
    neg = G.read_map_yaml(_map_yaml(tmp_path, px, "n", negate=1))
    assert neg.data[0].tolist() == [0, 0, -1, 100, 100, 100, 100]  # occupancy v/255
    scale = G.read_map_yaml(_map_yaml(tmp_path, px, "s", mode="scale"))
    occ = 1 - px[0] / 255.0
    between = [int(np.rint((o - 0.25) / 0.4 * 100)) for o in occ[2:4]]
    assert scale.data[0].tolist() == [100, 100, *between, 0, 0, 0]
    raw = G.read_map_yaml(_map_yaml(tmp_path, np.array([[0, 50, 100, 101, 255]], dtype=np.uint8), "r", mode="raw"))
    assert raw.data[0].tolist() == [0, 50, 100, -1, -1]
    # strict thresholds: occupancy exactly at occupied_thresh is not occupied
    at = G.read_map_yaml(_map_yaml(tmp_path, np.array([[51]], dtype=np.uint8), "a", occupied_thresh=0.8))
    assert at.data[0, 0] == -1  # 1 - 51/255 = 0.8


def test_png_colour_alpha_rows_and_yaw(tmp_path):
    rgba = np.zeros((2, 3, 4), dtype=np.uint8)
    rgba[..., 3] = 255
    rgba[0, 0, :3] = (255, 255, 255)     # top-left: free
    rgba[1, 0, :3] = (0, 0, 0)           # bottom-left: occupied
    rgba[0, 1, :3] = (255, 255, 0)       # mean 170: occupancy 0.33, unknown
    rgba[0, 2, 3] = 0                    # transparent white: unknown in scale mode only
    rgba[0, 2, :3] = 255
    rgba[1, 1:, :3] = 255
    tri = G.read_map_yaml(_map_yaml(tmp_path, rgba, "c", fmt="PNG", suffix=".png"))
    # image row 0 is the map's top: the grid's last row
    assert tri.data.tolist() == [[100, 0, 0], [0, -1, 0]]
    scale = G.read_map_yaml(_map_yaml(tmp_path, rgba, "d", fmt="PNG", suffix=".png", mode="scale"))
    assert scale.data[1, 2] == -1 and tri.data[1, 2] == 0
    turned = G.read_map_yaml(_map_yaml(tmp_path, rgba, "y", fmt="PNG", suffix=".png", origin=[1.0, 2.0, math.pi / 2]))
    centre = turned.cell_centres(np.eye(2, 3, dtype=bool))[0]  # cell (row 0, col 0)
    assert centre == pytest.approx([1.0 - 0.05, 2.0 + 0.05])
    back = G.read_map_yaml(_map_yaml(tmp_path, _room(), "rt"))
    G.write_map_yaml(back, tmp_path / "again.yaml")
    assert np.array_equal(G.read_map_yaml(tmp_path / "again.yaml").classes, back.classes)


def test_frontier_cells_by_hand():
    d = np.full((5, 6), -1, dtype=np.int8)
    d[1:4, 1:4] = 0      # a 3 x 3 free block in unknown: its 8 border cells touch unknown, the centre not
    d[2, 2] = 0
    g = G.OccupancyGrid(d, 1.0)
    assert G.frontier_mask(g).sum() == 8 and not G.frontier_mask(g)[2, 2]
    e = np.zeros((3, 3), dtype=np.int8)
    e[0, 0] = -1         # only a diagonal neighbour is unknown for (1, 1)
    assert G.frontier_mask(G.OccupancyGrid(e, 1.0)).tolist() == [[False, True, False], [True, True, False],
                                                                  [False, False, False]]
    # the grid's edge is not unknown
    assert G.frontier_mask(G.OccupancyGrid(np.zeros((4, 4), dtype=np.int8), 1.0)).sum() == 0
    counter = G.FrontierCounter(g)
    pts = G.frontier_points(g)
    for q in ([2.5, 2.5], [0.0, 0.0], [5.0, 1.0]):
        for radius in (0.5, 1.0, 1.5, 3.0):
            assert counter.count([q], radius)[0] == int((np.hypot(*(pts - q).T) <= radius).sum())


# --------------------------------------------------------------------------- the command


@pytest.fixture()
def room(tmp_path):
    path = _map_yaml(tmp_path, _room(), free_thresh=0.196)  # ROS 1 map_saver's: 205 is unknown
    (tmp_path / "routes.yaml").write_text(
        "carriers:\n"
        "  - {id: a, passengers: 2, start: 0, speed: 1.0, path: [[1.0, 1.0], [6.0, 1.0], [6.0, 3.0]]}\n"
        "  - {id: b, passengers: 1, start: 4, speed: 0.5, path: [[1.0, 4.5], [5.0, 4.5]]}\n")
    return path


def test_static_import_report_and_world(room, tmp_path):
    out, rep = tmp_path / "out" / "s.yaml", tmp_path / "out" / "r.json"
    done = _process(room, "--routes", tmp_path / "routes.yaml", "--stage-spacing", "1", "--radius", "2",
                    "--out", out, "--report", rep)
    assert done.returncode == 0, done.stderr
    report = json.loads(rep.read_text())
    grid = G.read_map_yaml(room)
    front = G.frontier_points(grid)
    assert report["frontier_cells"] == len(front) == 20  # the free cells of the opening's column
    a = report["carriers"]["a"]
    assert [round(p["t"], 9) for p in a] == [float(k) for k in range(8)]  # 1 m apart at 1 m/s
    assert [(p["x"], p["y"]) for p in a][:6] == [(1.0 + k, 1.0) for k in range(6)]
    for p in a + report["carriers"]["b"]:
        assert p["value"] == int((np.hypot(front[:, 0] - p["x"], front[:, 1] - p["y"]) <= 2.0).sum())
    assert [p["t"] for p in report["carriers"]["b"]] == [4.0, 6.0, 8.0, 10.0, 12.0]  # 0.5 m/s from 4 s
    scenario = world.load_scenario(out)
    assert np.array_equal(world.sample_features(scenario), front)
    assert [c.start_time for c in scenario.carriers] == [0.0, 4.0]  # b starts 4 stages of 1 s later
    # walls: a handful of outline segments for 230 occupied cells
    assert 0 < len(scenario.map.segments) < 30 < int((grid.classes == G.OCCUPIED).sum())


@pytest.mark.parametrize("case", [
    "missing-image", "jpeg-image", "text-image", "resolution-0", "thresholds", "one-point", "off-map",
    "through-wall", "no-frontier", "map-saver-unknown", "bag-no-topic", "odom-absent", "odom-wrong-type", "unknown-key"])
def test_bad_input_is_one_line_and_leaves_nothing(case, room, tmp_path):
    out, rep = tmp_path / "o" / "s.yaml", tmp_path / "o" / "r.json"
    routes = tmp_path / "routes.yaml"
    source, extra, named = room, ["--routes", routes], None
    text = room.read_text()
    if case == "missing-image":
        (tmp_path / "m.pgm").unlink()
        named = "m.pgm"
    elif case == "jpeg-image":
        Image.fromarray(_room()).save(tmp_path / "m.pgm", format="JPEG")
        named = "PGM or PNG"
    elif case == "text-image":
        (tmp_path / "m.pgm").write_text("not an image")
        named = "PGM or PNG"
    elif case == "resolution-0":
        room.write_text(text.replace("resolution: 0.1", "resolution: 0"))
        named = "resolution"
    elif case == "thresholds":
        room.write_text(text.replace("free_thresh: 0.196", "free_thresh: 0.7"))
        named = "free_thresh"
    elif case == "unknown-key":
        room.write_text(text + "resolutoin: 0.1\n")
        named = "resolutoin"
    elif case in ("one-point", "off-map", "through-wall"):
        path = {"one-point": "[[1.0, 1.0]]", "off-map": "[[1.0, 1.0], [9.0, 1.0]]",
                "through-wall": "[[1.0, 1.0], [1.0, 6.0]]"}[case]
        routes.write_text(f"carriers:\n  - {{id: zed, passengers: 1, start: 0, speed: 1, path: {path}}}\n")
        named = "path" if case == "one-point" else "zed"
    elif case == "no-frontier":
        px = _room()
        px[px == 205] = 0
        _map_yaml(tmp_path, px, free_thresh=0.196)
        named = "frontier"
    elif case == "map-saver-unknown":  # nav2 map_saver's, read literally: 205 is free, no frontier left
        room.write_text(text.replace("free_thresh: 0.196", "free_thresh: 0.25"))
        extra = extra + ["--literal-thresholds"]
        named = "205"
    else:
        from tools.synthetic_run import generate, write_bag

        write_bag(generate(120, 80, 0.1, carriers=1, snapshots=2, seed=1), tmp_path / "bag", "mcap")
        source, extra = tmp_path / "bag", ["--odom", "c0=/c0/odom"]
        if case == "bag-no-topic":
            extra += ["--map-topic", "/nomap"]
            named = "/nomap"
        elif case == "odom-absent":
            extra = ["--odom", "c0=/c9/odom"]
            named = "/c9/odom"
        else:
            extra = ["--odom", "c0=/map"]
            named = "nav_msgs/msg/OccupancyGrid"
    done = _run(source, *extra, "--stages", "3", "--out", out, "--report", rep)
    assert done.returncode == 2, (case, done.stdout, done.stderr)
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in done.stderr, lines
    assert named in lines[0] and "expected" in lines[0], lines[0]
    assert not out.exists() and not rep.exists()
    assert not (out.parent.exists() and any(out.parent.iterdir())), list(out.parent.iterdir())


# --------------------------------------------------------------------------- recorded runs graze walls


_GRAZING = "[[1.0, 1.0], [3.0, 1.0], [3.0, 0.57], [3.3, 1.0], [6.0, 1.0], [6.0, 3.0]]"  # 3 cm into the south wall


def test_a_recorded_route_grazing_a_wall_is_taken_as_driven(room, tmp_path):
    from world.stages import stage_geometry

    routes, out = tmp_path / "routes.yaml", tmp_path / "o" / "s.yaml"
    routes.write_text(f"carriers:\n  - {{id: rec, passengers: 2, start: 0, speed: 1, recorded: true, path: {_GRAZING}}}\n")
    done = _run(room, "--routes", routes, "--stage-spacing", "1", "--radius", "2", "--out", out)
    assert done.returncode == 0, done.stderr
    warned = [line for line in done.stdout.splitlines() if line.startswith("warning: carrier 'rec'")]
    assert len(warned) == 1 and "deepest 0.030 m at (3.00, 0.57)" in warned[0], done.stdout
    scenario = world.load_scenario(out)
    # the map written is the map as recorded; the world's walls give way round the graze
    written = G.read_map_yaml(out.parent / "s.map.yaml")
    assert written.classes[tuple(written.cell_of([[3.0, 0.57]])[0])] == G.OCCUPIED
    # the carrier's body follows the route: at every stage where it was planned to be
    geo = stage_geometry(scenario)
    trace = world.simulate_mission(scenario)
    ok = geo.valid
    assert np.abs(trace.positions[ok] - geo.positions[ok]).max() < 0.05
    assert [3.0, 0.57] in np.round(np.asarray(scenario.carriers[0].waypoints), 6).tolist()  # the route as driven

    # the same route written by hand stays refused, and says how to take a recorded one
    routes.write_text(f"carriers:\n  - {{id: rec, passengers: 2, start: 0, speed: 1, path: {_GRAZING}}}\n")
    refused = _run(room, "--routes", routes, "--stage-spacing", "1", "--out", tmp_path / "h" / "s.yaml")
    assert refused.returncode == 2 and "occupied cell" in refused.stderr and "recorded: true" in refused.stderr
    # a recorded route deeper than --graze-depth is refused, naming the depth
    routes.write_text(f"carriers:\n  - {{id: rec, passengers: 2, start: 0, speed: 1, recorded: true, path: {_GRAZING}}}\n")
    deep = _run(room, "--routes", routes, "--stage-spacing", "1", "--graze-depth", "0.02", "--out", tmp_path / "d" / "s.yaml")
    assert deep.returncode == 2 and len(deep.stderr.strip().splitlines()) == 1
    assert "--graze-depth 0.02 m" in deep.stderr and "0.030 m" in deep.stderr and "(3.00, 0.57)" in deep.stderr


def test_grazes_their_depth_and_the_walls_that_give_way():
    from world import importer as imp

    rows = np.array([[0.0, 1.0, 1.0], [1.0, 3.0, 0.57], [2.0, 5.0, 1.0]])
    d = np.zeros((20, 80), dtype=np.int8)
    d[5, :] = 100  # a wall along y in [0.5, 0.6]
    g = G.OccupancyGrid(d, 0.1)
    found = g.grazes(rows[:, 1:])
    assert [f.leg for f in found] == [0, 1] and max(f.depth for f in found) == pytest.approx(0.03)
    route = imp.Route("c", 1, rows, "bag: topic /c/odom", recorded=True)
    said = []
    walls = imp.take_grazes(g, g, route, 0.2, said.append)
    assert len(said) == 1 and (walls.classes == G.OCCUPIED).sum() < (g.classes == G.OCCUPIED).sum()
    assert walls.first_blocked(rows[:, 1:]) is None
    assert imp.take_grazes(g, g, imp.Route("c", 1, rows, "routes.yaml", recorded=False), 0.2, said.append) is g


def test_a_nav2_map_saver_map_reads_205_as_unknown_saying_so_once(room, tmp_path):
    """map_saver writes unknown as 205 beside free_thresh 0.25 (occupancy 0.196: free by the
    YAML's own rule); its signature reads as the saver meant, --literal-thresholds as map_server."""
    saver = tmp_path / "saver.yaml"
    saver.write_text(room.read_text().replace("free_thresh: 0.196", "free_thresh: 0.25"))
    meant, literal = G.read_map_yaml(saver), G.read_map_yaml(saver, literal=True)
    assert np.array_equal(meant.classes, G.read_map_yaml(room).classes)
    assert (literal.classes == G.UNKNOWN).sum() == 0 and len(meant.warnings) == 1
    done = _run(saver, "--routes", tmp_path / "routes.yaml", "--stage-spacing", "1", "--radius", "2",
                "--out", tmp_path / "o" / "s.yaml", "--report", tmp_path / "o" / "r.json")
    assert done.returncode == 0, done.stderr
    said = [line for line in done.stdout.splitlines() if "205" in line]
    assert len(said) == 1 and "map_saver" in said[0] and "--literal-thresholds" in said[0], done.stdout
    assert json.loads((tmp_path / "o" / "r.json").read_text())["frontier_cells"] == 20
    # not the signature: another grey, or another free_thresh, is read as written
    px = _room()
    px[0, 0] = 128
    other = _map_yaml(tmp_path, px, "grey", free_thresh=0.25)
    assert (G.read_map_yaml(other).classes == G.UNKNOWN).sum() == 1


def test_stages_default_to_the_papers_19(room, tmp_path):
    rep = tmp_path / "o" / "r.json"
    done = _run(room, "--routes", tmp_path / "routes.yaml", "--radius", "2", "--out", tmp_path / "o" / "s.yaml",
                "--report", rep)
    assert done.returncode == 0, done.stderr
    assert [len(v) for v in json.loads(rep.read_text())["carriers"].values()] == [19, 19]


def test_too_many_passengers_are_blamed_where_they_were_given(room, tmp_path):
    routes = tmp_path / "routes.yaml"
    routes.write_text("carriers:\n  - {id: a, passengers: 9, start: 0, speed: 1.0, path: [[1.0, 1.0], [6.0, 1.0]]}\n")
    given = _run(room, "--routes", routes, "--stages", "3", "--out", tmp_path / "o" / "s.yaml")
    assert given.returncode == 2 and given.stderr.startswith(f"{routes}: carriers[0].passengers: expected at most 3"), \
        given.stderr
    assert "--passengers" not in given.stderr
    flag = _run(room, "--routes", routes, "--stages", "3", "--passengers", "a=5", "--out", tmp_path / "o" / "s.yaml")
    assert flag.returncode == 2 and flag.stderr.startswith("--passengers a: expected at most 3"), flag.stderr
    # --out naming a directory, or a path under a file: one line, nothing written
    (tmp_path / "f").write_text("x")
    for out in (tmp_path, tmp_path / "f" / "s.yaml"):
        done = _run(room, "--routes", routes, "--out", out)
        assert done.returncode == 2 and done.stderr.startswith("--out: expected a file path to write"), done.stderr
        assert len(done.stderr.strip().splitlines()) == 1


def test_radii_that_dwarf_the_map_are_warned_of_and_can_come_from_its_size(room, tmp_path):
    rep = tmp_path / "o" / "r.json"
    paper = _run(room, "--routes", tmp_path / "routes.yaml", "--out", tmp_path / "o" / "s.yaml", "--report", rep)
    assert paper.returncode == 0, paper.stderr
    warned = [line for line in paper.stdout.splitlines() if line.startswith("warning:") and "dwarf" in line]
    assert len(warned) == 1 and "sensing radius 10 m and conflict radius 30 m" in warned[0] and "--radii map" in warned[0]
    checked = subprocess.run([sys.executable, "-m", "world", "check", str(tmp_path / "o" / "s.yaml"), "--seeds", "2"],
                             cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert checked.returncode == 0 and "warning: sensing radius 10 m" in checked.stdout, checked.stderr
    sized = _run(room, "--routes", tmp_path / "routes.yaml", "--radii", "map", "--out", tmp_path / "m" / "s.yaml",
                 "--report", tmp_path / "m" / "r.json")
    assert sized.returncode == 0, sized.stderr
    assert "warning: sensing" not in sized.stdout and json.loads((tmp_path / "m" / "r.json").read_text())["radius"] == 1.5
    s = world.load_scenario(tmp_path / "m" / "s.yaml")
    assert (s.sensing_radius, s.conflict_radius) == (1.5, 3.0)  # a quarter of the 6.2 m side, and twice that
