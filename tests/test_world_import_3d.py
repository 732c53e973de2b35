"""``python -m world import`` from 3D sources as a field team runs it: a generated two-storey
building (a shaft, a stairwell, a sealed room) scanned by simulated LiDAR, imported from a
folder of PCD/PLY scans, from a ROS 2 bag of PointCloud2 and odometry, and from OctoMap files;
values against frontier voxels known by construction; storeys with their own walls; every bad
input of the 3D path refused with one line and nothing left behind."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tools import synthetic_3d as S
from world import voxels as V

ROOT = Path(__file__).resolve().parents[1]


def _run(*args):
    return subprocess.run([sys.executable, "-m", "world", "import", *map(str, args)], cwd=ROOT, capture_output=True,
                          text=True, timeout=300)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """Two carriers, one per storey, 24 scans of 2,500 rays: a folder (PCD binary and ascii,
    and PLY) and a bag."""
    out = tmp_path_factory.mktemp("run3d")
    run = S.run(seed=4, scans=24, points=2500, max_range=30.0, resolution=0.2)
    S.write_folder(run, out, ply_every=5)
    S.write_bag(run, out)
    return run, out


@pytest.mark.slow
def test_folder_and_bag_replay_agree_and_the_mission_observes_them(recorded, tmp_path):
    run, src = recorded
    a = _run(src / "scans", "--routes", src / "routes.yaml", "--stages", 6, "--replay",
             "--out", tmp_path / "f.yaml", "--report", tmp_path / "f.json")
    assert a.returncode == 0, a.stderr
    b = _run(src / "bag", "--cloud-topic", "c0=/c0/points", "--cloud-topic", "c1=/c1/points", "--odom", "c0=/c0/odom",
             "--odom", "c1=/c1/odom", "--passengers", "c0=2", "--passengers", "c1=2", "--stages", 6, "--replay",
             "--out", tmp_path / "b.yaml", "--report", tmp_path / "b.json")
    assert b.returncode == 0, b.stderr
    fr, br = (json.loads((tmp_path / f"{k}.json").read_text()) for k in "fb")
    assert list(fr)[:2] == ["frontier_voxels", "carriers"] and fr["frontier_voxels"] > 0
    for cid, z in (("c0", run.building.floor(0)), ("c1", run.building.floor(1))):
        pts = fr["carriers"][cid]
        assert [set(p) for p in pts] == [{"t", "x", "y", "z", "value"}] * 6
        assert all(p["z"] == pytest.approx(z) for p in pts)
        # the same scans through the bag's PointCloud2, odometry and /tf_static mounting
        assert [p["value"] for p in pts] == [p["value"] for p in br["carriers"][cid]]
    assert fr["frontier_voxels"] == br["frontier_voxels"]
    assert [s["carriers"] for s in fr["storeys"]] == [["c0"], ["c1"]]
    # the mission observes the reported values exactly, stage by stage
    import world
    from world.scenario import load_scenario

    s = load_scenario(tmp_path / "f.yaml")
    x = world.observe_all(s)
    for r, c in enumerate(s.carriers):
        first = fr["first_stage"][c.id]
        assert x[r, first:first + 6].tolist() == [p["value"] for p in fr["carriers"][c.id]]
        assert c.storey == f"s{r}"
    # both carriers share x-y on different storeys and drive their whole corridor
    trace = world.simulate_mission(s)
    for r, c in enumerate(s.carriers):
        assert np.hypot(*(trace.trajectories[r][-1, 1:] - np.asarray(c.waypoints[-1]))) < 0.5, c.id
    # the picture: a top view, one panel per storey
    out = world.render_map(s, tmp_path / "map.png", trajectories=trace.trajectories,
                           deployments=[(c.id, tuple(trace.positions[r, fr["first_stage"][c.id] + 2])) for r, c in enumerate(s.carriers)])
    import matplotlib.image as mpimg

    img = mpimg.imread(out)
    assert img.shape[1] > 1.8 * img.shape[0]  # two panels side by side


@pytest.mark.slow
def test_static_map_the_scans_made_is_sound_and_the_sealed_room_unknown(recorded, tmp_path):
    run, src = recorded
    done = _run(src / "scans", "--routes", src / "routes.yaml", "--stages", 5, "--out", tmp_path / "s.yaml",
                "--report", tmp_path / "s.json")
    assert done.returncode == 0, done.stderr
    grid = V.read_octomap(tmp_path / "s.map.bt")
    b = run.building
    # every voxel the rays made free is free in the building, every occupied one solid (up to
    # the returns placed 0.1 mm inside the solid voxel they hit)
    idx = np.argwhere(grid.classes != V.UNKNOWN)
    centres = grid.centres(grid.classes != V.UNKNOWN)
    truth = np.floor((centres - b.lower) / b.resolution).astype(int)
    solid = b.solid[tuple(truth.T)]
    cls = grid.classes[tuple(idx.T)]
    assert (solid[cls == V.FREE]).mean() < 0.001 and (~solid[cls == V.OCCUPIED]).mean() < 0.001
    # nobody sees into the sealed room
    x0, y0, z0, x1, y1, z1 = b.sealed
    inside = (centres[:, 0] > x0 + 0.1) & (centres[:, 0] < x1 - 0.1) & (centres[:, 1] > y0 + 0.1) \
        & (centres[:, 1] < y1 - 0.1) & (centres[:, 2] > z0 + 0.1) & (centres[:, 2] < z1 - 0.1)
    assert not inside.any()
    # static values: the frontier voxels of the written map, by brute force
    rep = json.loads((tmp_path / "s.json").read_text())
    front = grid.centres(V.frontier_mask(grid.classes, 6))
    assert rep["frontier_voxels"] == len(front)
    for p in rep["carriers"]["c1"]:
        q = np.array([p["x"], p["y"], p["z"]])
        dz = front[:, 2] - q[2]
        assert p["value"] == int(((np.linalg.norm(front - q, axis=1) <= 10.0) & ((dz > 1.0) | (dz < -0.1))).sum())
    # a storey's walls are its own: the sealed room stands on the ground storey only
    from world.scenario import load_scenario

    s = load_scenario(tmp_path / "s.yaml")
    segs = {st.name: s.map.carrier_segments(st.name) for st in s.map.storeys}
    near = {k: int(((np.abs(v[:, [1, 3]] - (y0 - S.WALL / 2)).max(axis=1) < 0.25)
                    & (np.minimum(v[:, 0], v[:, 2]) > x0 - 0.5)).sum()) for k, v in segs.items()}
    assert near["s0"] > 0 and near["s1"] == 0


def _building_bt(tmp_path) -> tuple[Path, np.ndarray, V.VoxelGrid]:
    """Two storeys known by construction (voxels of 0.25 m): free inside, an occupied shell and
    slab, a shaft through the slab, and one unexplored box (unknown) on the upper storey with
    free voxels all round it. Returns the .bt, the unknown box's index range and the grid."""
    classes = np.full((44, 28, 30), V.UNKNOWN, dtype=np.int8)
    classes[1:43, 1:27, 1:29] = V.OCCUPIED           # the shell
    classes[2:42, 2:26, 2:13] = V.FREE              # storey 0: floor top at 0.5 m
    classes[2:42, 2:26, 14:28] = V.FREE             # storey 1 above a slab: floor top at 3.5 m
    classes[10:14, 10:14, 13] = V.FREE              # the shaft through the slab
    box = (np.array([9, 9, 18]), np.array([15, 15, 23]))
    classes[9:15, 9:15, 18:23] = V.UNKNOWN
    grid = V.VoxelGrid(classes, 0.25, (V.KEY_ZERO, V.KEY_ZERO, V.KEY_ZERO))
    return V.write_octomap(grid, tmp_path / "b.bt"), box, grid


def _around(box, neighbours: int) -> np.ndarray:
    """Centres (m) of the voxels next to the box: its faces' layers (6), or its whole one-voxel
    shell (26)."""
    lo, hi = box
    idx = np.array(np.meshgrid(*[np.arange(lo[a] - 1, hi[a] + 1) for a in range(3)], indexing="ij")).reshape(3, -1).T
    inside = np.all((idx >= lo) & (idx < hi), axis=1)
    outside_axes = ((idx < lo) | (idx >= hi)).sum(axis=1)
    keep = ~inside & (outside_axes == 1 if neighbours == 6 else True)
    return (idx[keep] + 0.5) * 0.25


def test_in_process_import_of_a_known_building(tmp_path):
    """The library path (world.import3d) on the building known by construction: the paper's
    default filter, the report's additions and the files written."""
    from world import import3d
    from world.importer import ImportSettings

    path, box, _ = _building_bt(tmp_path)
    (tmp_path / "r.yaml").write_text(
        "carriers:\n  - {id: low, passengers: 1, start: 0, speed: 1, path: [[1.0, 3.0, 0.5], [9.0, 3.0, 0.5]]}\n")
    st = ImportSettings(source=str(path), out=str(tmp_path / "k.yaml"), routes=str(tmp_path / "r.yaml"), stages=4,
                        report=str(tmp_path / "k.json"))
    assert import3d.is_3d(st)
    result = import3d.import_3d(st, progress=lambda line: None)
    written = import3d.write_outputs_3d(st, result)
    assert [Path(p).name for p in written] == ["k.yaml", "k.map.bt", "k.json"]
    assert (tmp_path / "k.map.bt").read_bytes() == path.read_bytes()  # a .bt source is kept as it is
    rep = json.loads((tmp_path / "k.json").read_text())
    front = _around(box, 6)
    assert rep["frontier_voxels"] == len(front)
    for p in rep["carriers"]["low"]:
        q = np.array([p["x"], p["y"], p["z"]])
        dz = front[:, 2] - q[2]
        assert p["value"] == int(((np.linalg.norm(front - q, axis=1) <= 10.0) & ((dz > 1.0) | (dz < -0.1))).sum())
    assert sum(p["value"] for p in rep["carriers"]["low"]) > 0


@pytest.mark.slow
def test_octomap_values_known_by_construction(tmp_path):
    path, box, grid = _building_bt(tmp_path)
    (tmp_path / "r.yaml").write_text(
        "carriers:\n"
        "  - {id: low, passengers: 1, start: 0, speed: 1, path: [[1.0, 3.0, 0.5], [9.0, 3.0, 0.5]]}\n"
        "  - {id: high, passengers: 1, start: 0, speed: 1, path: [[1.0, 2.0, 3.5], [9.0, 2.0, 3.5]]}\n")
    assert len(_around(box, 6)) == 2 * (36 + 30 + 30) and len(_around(box, 26)) == 8 * 8 * 7 - 6 * 6 * 5
    for above, below, nb in ((1.0, 0.1, 6), (0.0, 0.0, 6), (1.0, 0.1, 26), (2.5, 0.0, 26)):
        done = _run(path, "--routes", tmp_path / "r.yaml", "--stages", 5, "--out", tmp_path / "o.yaml",
                    "--report", tmp_path / "o.json", "--keep-above", above, "--keep-below", below, "--neighbours", nb)
        assert done.returncode == 0, done.stderr
        rep = json.loads((tmp_path / "o.json").read_text())
        front = _around(box, nb)
        assert rep["frontier_voxels"] == len(front)
        for cid in ("low", "high"):
            for p in rep["carriers"][cid]:
                q = np.array([p["x"], p["y"], p["z"]])
                dz = front[:, 2] - q[2]
                keep = (dz > above) | (dz < -below) if above or below else np.ones(len(front), dtype=bool)
                assert p["value"] == int(((np.linalg.norm(front - q, axis=1) <= 10.0) & keep).sum())
        assert [(s["name"], s["base"], s["carriers"]) for s in rep["storeys"]] == [("s0", 0.5, ["low"]),
                                                                                  ("s1", 3.5, ["high"])]
    # a carrier on the lower storey counts the box above it; the filter keeps everything 1 m up
    low = json.loads((tmp_path / "o.json").read_text())["carriers"]["low"]
    assert max(p["value"] for p in low) > 0
    # [x, y] points: the floor under the first point when there is one, refused over two
    (tmp_path / "f.yaml").write_text("carriers:\n  - {id: flat, passengers: 1, start: 0, speed: 1, path: [[2.0, 5.5], [9.0, 5.5]]}\n")
    done = _run(path, "--routes", tmp_path / "f.yaml", "--stages", 4, "--out", tmp_path / "two.yaml")
    assert done.returncode == 2 and "found [x, y] over 2 floors at z = 0.50, 3.50 m" in done.stderr, done.stderr
    one = grid.classes[:, :, :13].copy()
    one[:, :, 12] = V.UNKNOWN
    V.write_octomap(V.VoxelGrid(one, grid.resolution, grid.key0), tmp_path / "one.bt")
    done = _run(tmp_path / "one.bt", "--routes", tmp_path / "f.yaml", "--stages", 4, "--out", tmp_path / "one.yaml",
                "--report", tmp_path / "one.json", "--keep-above", 0, "--keep-below", 0)
    assert done.returncode == 0, done.stderr
    assert {p["z"] for p in json.loads((tmp_path / "one.json").read_text())["carriers"]["flat"]} == {0.5}


def test_storeys_keep_their_own_walls(tmp_path):
    """A wall across the upper carrier's x-y on the storey below: its world does not hold it,
    the lower storey's does (the scenario refuses the leg there)."""
    from world.scenario import ScenarioError, load_scenario

    text = ("name: st\nseed: 0\nmap:\n  bounds: [0, 0, 10, 10]\n  storeys:\n"
            "    - {name: ground, base: 0, walls: [[[5, 0.5], [5, 9.5]]]}\n    - {name: upper, base: 3, walls: []}\n"
            "features: {density: 0.1}\nsensing_radius: 3\nstage_interval: 2\nstages: 4\ncarriers:\n"
            "  - {id: a, storey: STOREY, passengers: 1, start_time: 0, speed: 1, waypoints: [[1, 5], [9, 5]]}\n")
    (tmp_path / "ok.yaml").write_text(text.replace("STOREY", "upper"))
    s = load_scenario(tmp_path / "ok.yaml")
    import world

    assert world.simulate_mission(s).trajectories[0][-1, 1] > 6.0  # drove through x = 5
    (tmp_path / "bad.yaml").write_text(text.replace("STOREY", "ground"))
    with pytest.raises(ScenarioError, match=r"carriers\[0\].waypoints\[0\]->\[1\]: expected a leg clear of walls"):
        load_scenario(tmp_path / "bad.yaml")
    (tmp_path / "none.yaml").write_text(text.replace("STOREY", "attic"))
    with pytest.raises(ScenarioError, match=r"carriers\[0\].storey: expected one of map.storeys' names \(ground, upper\)"):
        load_scenario(tmp_path / "none.yaml")


def _bad_cloud_bag(out: Path) -> Path:
    """A bag whose PointCloud2 has integer x/y/z fields."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    hdr = T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=1, nanosec=0), frame_id="map")
    fields = [T["sensor_msgs/msg/PointField"](name=n, offset=4 * k, datatype=5, count=1) for k, n in enumerate("xyz")]
    msg = T["sensor_msgs/msg/PointCloud2"](header=hdr, height=1, width=1, fields=fields, is_bigendian=False,
                                           point_step=12, row_step=12, data=np.zeros(12, dtype=np.uint8), is_dense=True)
    V3, Q = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
    odom = T["nav_msgs/msg/Odometry"](
        header=hdr, child_frame_id="base",
        pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=T["geometry_msgs/msg/Pose"](
            position=T["geometry_msgs/msg/Point"](x=0.0, y=0.0, z=0.0), orientation=Q(x=0.0, y=0.0, z=0.0, w=1.0)),
            covariance=np.zeros(36)),
        twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=T["geometry_msgs/msg/Twist"](
            linear=V3(x=0.0, y=0.0, z=0.0), angular=V3(x=0.0, y=0.0, z=0.0)), covariance=np.zeros(36)))
    with Writer(out, version=8, storage_plugin=StoragePlugin.MCAP) as w:
        c = w.add_connection("/points", msg.__msgtype__, typestore=ts)
        o = w.add_connection("/odom", odom.__msgtype__, typestore=ts)
        w.write(o, 1, ts.serialize_cdr(odom, odom.__msgtype__))
        w.write(c, 2, ts.serialize_cdr(msg, msg.__msgtype__))
    return out


@pytest.mark.slow
def test_bad_inputs_one_line_nothing_left(recorded, tmp_path):
    _, src = recorded
    path, _, grid = _building_bt(tmp_path)
    routes = src / "routes.yaml"
    (tmp_path / "b.yaml").write_text("carriers:\n  - {id: a, path: [[1.0, 3.0, 0.5], [9.0, 3.0, 0.5]]}\n")
    (tmp_path / "m.xyz").write_text("1 2 3\n")
    (tmp_path / "cut.bt").write_bytes(path.read_bytes()[:-7])
    short = tmp_path / "short"
    short.mkdir()
    for f in sorted((src / "scans").iterdir())[:4]:
        (short / f.name).write_bytes(f.read_bytes())
    (short / "poses.txt").write_text("\n".join((src / "scans" / "poses.txt").read_text().splitlines()[:3]) + "\n")
    closed = V.VoxelGrid(np.pad(np.zeros((6, 6, 6), dtype=np.int8), 1, constant_values=V.OCCUPIED), 0.25, grid.key0)
    V.write_octomap(V.VoxelGrid(np.pad(closed.classes, 1, constant_values=V.UNKNOWN), 0.25, grid.key0), tmp_path / "closed.bt")
    (tmp_path / "c.yaml").write_text("carriers:\n  - {id: a, path: [[0.8, 0.8, 0.5], [1.8, 1.8, 0.5]]}\n")
    (tmp_path / "r2.yaml").write_text("carriers:\n  - {id: a, path: [[1.0, 2.0], [9.0, 2.0]]}\n")
    bag = _bad_cloud_bag(tmp_path / "badbag")
    cases = {
        "not-bt-ot": ([tmp_path / "m.xyz", "--routes", routes], "expected an OctoMap file (.bt binary or .ot full)"),
        "truncated": ([tmp_path / "cut.bt", "--routes", routes], "found the file truncated"),
        "int-fields": ([bag, "--cloud-topic", "/points", "--odom", "a=/odom"],
                       "expected a PointCloud2 with float x, y and z fields"),
        "no-pose": ([short, "--routes", routes], "has no pose"),
        "ambiguous": ([path, "--routes", tmp_path / "r2.yaml"], "expected [x, y, z] points"),
        "voxel-0": ([src / "scans", "--routes", routes, "--voxel", 0], "--voxel: expected a voxel size > 0"),
        "keep-negative": ([path, "--routes", tmp_path / "b.yaml", "--keep-below", -1],
                          "--keep-below: expected a height >= 0"),
        "no-frontier": ([tmp_path / "closed.bt", "--routes", tmp_path / "c.yaml"],
                        "expected a map with at least one frontier voxel"),
        "replay-file": ([path, "--routes", tmp_path / "b.yaml", "--replay"], "--replay: expected scans to replay"),
    }
    for case, (args, expected) in cases.items():
        out = tmp_path / f"{case}.yaml"
        done = _run(*args, "--stages", 4, "--out", out, "--report", tmp_path / f"{case}.json")
        lines = done.stderr.strip().splitlines()
        assert done.returncode == 2 and len(lines) == 1 and "Traceback" not in done.stderr, (case, done.stderr)
        assert expected in lines[0], (case, lines[0])
        assert not out.exists() and not (tmp_path / f"{case}.json").exists() and not (tmp_path / f"{case}.map.bt").exists()
    assert not list(tmp_path.glob(".*tmp")) and not list(tmp_path.glob(".import-*"))


def test_mcap_and_rerun_draw_the_voxels(tmp_path):
    """A 3D import's scene carries its occupied and frontier voxels: mission.mcap's
    /world/voxels (foxglove.PointCloud) and the rerun view's Points3D; a 2D scene none."""
    import rerun as rr
    from mcap.reader import make_reader

    import world
    from recording.mcap import McapRecorder
    from viewer.rerun_view import RerunView, blueprint
    from world import import3d
    from world.importer import ImportSettings
    from world.scene import build_scene

    path, box, grid = _building_bt(tmp_path)
    (tmp_path / "r.yaml").write_text(
        "carriers:\n  - {id: low, passengers: 1, start: 0, speed: 1, path: [[1.0, 3.0, 0.5], [9.0, 3.0, 0.5]]}\n")
    st = ImportSettings(source=str(path), out=str(tmp_path / "k.yaml"), routes=str(tmp_path / "r.yaml"), stages=4)
    import3d.write_outputs_3d(st, import3d.import_3d(st, progress=lambda line: None))
    scene = build_scene(world.load_scenario(tmp_path / "k.yaml"))
    occupied = int((grid.classes == V.OCCUPIED).sum())
    assert int((scene.voxels[:, 3] == 0).sum()) == occupied and int((scene.voxels[:, 3] == 1).sum()) == len(_around(box, 6))
    rec = McapRecorder(tmp_path / "m.mcap", scene)
    rec.close()
    with open(tmp_path / "m.mcap", "rb") as f:
        msgs = [(s.name, m.data) for s, _, m in make_reader(f).iter_messages(topics=["/world/voxels"])]
    assert len(msgs) == 1 and msgs[0][0] == "foxglove.PointCloud"
    assert len(msgs[0][1]) >= 16 * len(scene.voxels)
    import dataclasses

    sizes = []
    for k, sc in enumerate((scene, dataclasses.replace(scene, voxels=scene.voxels[:0]))):
        stream = rr.RecordingStream("voxels-test")
        stream.save(str(tmp_path / f"v{k}.rrd"), default_blueprint=blueprint(voxels=True))
        RerunView(stream, sc)
        stream.flush()
        sizes.append((tmp_path / f"v{k}.rrd").stat().st_size)
    assert sizes[0] > sizes[1] + 4 * len(scene.voxels)  # the points, compressed
    assert len(build_scene(world.load_scenario(ROOT / "scenarios" / "tiny.yaml")).voxels) == 0
