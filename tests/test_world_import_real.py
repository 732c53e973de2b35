"""A real floor plan through ``python -m world import``: HM3D house 1 as the binary map that
PyPI's ir-sim 2.12.0 ships (irsim/world/map/binary_map_generator_hm3d/hm3d_1.png), fetched from
the registry at test time and not committed.

The floor plan is the ground truth; three carriers drive shortest paths through its free space
(breadth-first over cells kept 0.4 m from the walls), and the map they would have built is their
union of 6 m discs so far, as 8 snapshots in a ROS 2 bag beside their odometry. The import must
accept the real map's geometry (outlines of every drawn line, routes that pass doors) and give
the paper's value, which the test recounts by brute force.
"""
from __future__ import annotations

import json
import subprocess
import sys
import zipfile
from collections import deque
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
WHEEL = "ir-sim==2.12.0"
MEMBER = "irsim/world/map/binary_map_generator_hm3d/hm3d_1.png"
RESOLUTION = 0.05  # m per pixel: the 775 x 770-pixel plan is a 39 x 39 m house
REVEAL = 6.0  # m

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def floor_plan(tmp_path_factory) -> Path:
    """hm3d_1.png out of the ir-sim wheel, as a map_server map (trinary, black occupied)."""
    d = tmp_path_factory.mktemp("hm3d")
    subprocess.run([sys.executable, "-m", "pip", "download", "--no-deps", "-q", "-d", str(d), WHEEL], check=True,
                   timeout=300)
    wheel = next(d.glob("ir_sim-*.whl"))
    (d / "hm3d_1.png").write_bytes(zipfile.ZipFile(wheel).read(MEMBER))
    (d / "hm3d_1.yaml").write_text(f"image: hm3d_1.png\nresolution: {RESOLUTION}\norigin: [0.0, 0.0, 0.0]\n"
                                   "negate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.25\nmode: trinary\n")
    return d / "hm3d_1.yaml"


def _shortest_path(free: np.ndarray, a, b) -> np.ndarray:
    """Cells (row, col) of a breadth-first shortest 8-connected path from a to b over ``free``."""
    h, w = free.shape
    prev = -np.ones((h, w, 2), dtype=np.int64)
    prev[a] = a
    queue = deque([a])
    while queue:
        r, c = queue.popleft()
        if (r, c) == b:
            break
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                n = (r + dr, c + dc)
                if 0 <= n[0] < h and 0 <= n[1] < w and free[n] and prev[n][0] < 0:
                    prev[n] = (r, c)
                    queue.append(n)
    assert prev[b][0] >= 0, "no path"
    out = [b]
    while out[-1] != a:
        out.append(tuple(prev[out[-1]]))
    return np.asarray(out[::-1], dtype=float)


def _recorded_run(grid):
    """Three carriers on shortest paths between far-apart free cells, 0.5 m/s, starting 30 s
    apart; maps of what their 6 m discs revealed so far at 8 stamps."""
    from scipy import ndimage

    from tools.synthetic_run import SyntheticRun

    truth = np.where(grid.classes == 1, 100, 0).astype(np.int8)
    clear = ndimage.binary_erosion(grid.classes == 0, iterations=int(0.4 / RESOLUTION))
    lab, n = ndimage.label(clear)
    big = lab == 1 + int(np.argmax(ndimage.sum(clear, lab, range(1, n + 1))))
    cells = np.argwhere(big)
    rng = np.random.default_rng(1)
    tracks = {}
    for i in range(3):
        a = tuple(cells[rng.integers(len(cells))])
        far = cells[np.argsort(-np.hypot(*(cells - np.asarray(a)).T))[: len(cells) // 20]]
        b = tuple(far[rng.integers(len(far))])
        rc = _shortest_path(big, a, b)[::4]
        xy = np.column_stack([(rc[:, 1] + 0.5) * RESOLUTION, (rc[:, 0] + 0.5) * RESOLUTION])
        t = 30.0 * i + np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))]) / 0.5
        tracks[f"c{i}"] = np.column_stack([t, xy])
    end = max(tr[-1, 0] for tr in tracks.values())
    h, w = truth.shape
    yy, xx = (np.mgrid[0:h, 0:w] + 0.5) * RESOLUTION
    snapshots = []
    for stamp in np.linspace(0.0, end, 8):
        known = np.zeros((h, w), dtype=bool)
        for tr in tracks.values():
            for x, y in tr[tr[:, 0] <= stamp][::10, 1:]:
                known |= (xx - x) ** 2 + (yy - y) ** 2 <= REVEAL**2
        snapshots.append((float(stamp), np.where(known, truth, -1).astype(np.int8)))
    return SyntheticRun(truth, RESOLUTION, tracks, snapshots)


def _frontier_brute(data: np.ndarray) -> np.ndarray:
    """Centres (m) of free cells with an unknown 8-neighbour, by a loop over the cells."""
    h, w = data.shape
    out = []
    for r, c in zip(*np.nonzero((data >= 0) & (data <= 25))):
        nb = data[max(0, r - 1):r + 2, max(0, c - 1):c + 2]
        if (nb == -1).any():
            out.append(((c + 0.5) * RESOLUTION, (r + 0.5) * RESOLUTION))
    return np.asarray(out).reshape(-1, 2)


def test_a_real_floor_plan_imports_and_replays_the_paper_value(floor_plan, tmp_path):
    import world
    from tools.synthetic_run import write_bag
    from world.grid import read_map_yaml

    grid = read_map_yaml(floor_plan)
    assert grid.shape == (770, 775)
    run = _recorded_run(grid)
    topics = write_bag(run, tmp_path / "bag", "mcap")
    out, report = tmp_path / "s" / "house.yaml", tmp_path / "s" / "report.json"
    cmd = [sys.executable, "-m", "world", "import", str(tmp_path / "bag"), "--stages", "19", "--replay",
           "--out", str(out), "--report", str(report), "--passengers", "c0=3", "--passengers", "c1=3",
           "--passengers", "c2=2"]
    for cid, topic in topics.items():
        cmd += ["--odom", f"{cid}={topic}"]
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    rep = json.loads(report.read_text())
    stamps = [s for s, _ in run.snapshots]
    fronts = [_frontier_brute(d) for _, d in run.snapshots]
    assert rep["frontier_cells"] == len(fronts[-1])
    for cid, points in rep["carriers"].items():
        assert len(points) == 19
        for p in points:
            k = max(i for i, s in enumerate(stamps) if s <= p["t"] + 1e-9)
            f = fronts[k]
            assert p["value"] == int((np.hypot(f[:, 0] - p["x"], f[:, 1] - p["y"]) <= 10.0).sum())
    values = [p["value"] for ps in rep["carriers"].values() for p in ps]
    assert len(set(values)) > 5  # the growing map matters
    scenario = world.load_scenario(out)
    x = world.observe_all(scenario)
    for r, c in enumerate(scenario.carriers):
        assert x[r][np.isfinite(x[r])].tolist() == [p["value"] for p in rep["carriers"][c.id]]
    # walls: the drawn lines' outlines, not a body per occupied cell
    occupied = int((grid.classes == 1).sum())
    assert 0 < len(scenario.map.segments) < occupied / 5
    # the carriers drive the real plan's routes to their last candidate (walls included)
    trace = world.simulate_mission(scenario)
    for r, c in enumerate(scenario.carriers):
        last = trace.trajectories[r][-1, 1:]
        assert np.hypot(*(last - np.asarray(c.waypoints[-1]))) < 0.5, c.id
    world.render_map(scenario, tmp_path / "map.png", trajectories=trace.trajectories)
    assert (tmp_path / "map.png").stat().st_size > 10_000
