"""world.voxels against the OctoMap library itself (its binding octomap-python): ray casting
voxel by voxel and log-odds by log-odds, .bt and .ot files both ways; frontier voxels and the
paper's height-filtered value against counts known by construction and brute force."""
from __future__ import annotations

import numpy as np
import pytest

from world import voxels as V
from world.grid import GridError

octomap = pytest.importorskip("octomap")  # in the test extra: pip install -e '.[test]'


def _octree_dense(tree, grid: V.VoxelGrid):
    """OctoMap's leaves expanded into ``grid``'s frame: (classes, log-odds) arrays."""
    res = grid.resolution
    classes = np.full(grid.shape, V.UNKNOWN, dtype=np.int8)
    values = np.full(grid.shape, np.nan, dtype=np.float32)
    leaves = pruned = 0
    for leaf in tree.begin_leafs():
        size = leaf.getSize()
        n = int(round(size / res))
        lo = np.floor((np.asarray(leaf.getCoordinate()) - size / 2) / res + 0.5).astype(int) + V.KEY_ZERO - np.asarray(grid.key0)
        assert np.all(lo >= 0) and np.all(lo + n <= grid.shape), "an OctoMap leaf outside the grid"
        sl = tuple(slice(a, a + n) for a in lo)
        classes[sl] = V.OCCUPIED if tree.isNodeOccupied(leaf) else V.FREE
        values[sl] = leaf.getValue()
        leaves += 1
        pruned += n > 1
    return classes, values, leaves, pruned


def _scans(rng, k=4, n=1500):
    out = []
    for s in range(k):
        origin = np.array([0.7 * s + 0.013, 0.31 - 0.2 * s, 1.07])
        d = rng.normal(size=(n, 3))
        d /= np.linalg.norm(d, axis=1)[:, None]
        out.append(((origin + d * rng.uniform(0.5, 7.0, size=(n, 1))).astype(np.float32), origin))
    return out


@pytest.mark.parametrize("res,maxrange,params", [
    (0.2, 5.0, V.OccupancyParams()),
    (0.1, -1.0, V.OccupancyParams(prob_hit=0.8, prob_miss=0.3, occupancy=0.6, clamp_min=0.2, clamp_max=0.9)),
], ids=["defaults-maxrange", "own-model-whole-rays"])
def test_ray_casting_is_octomaps(res, maxrange, params):
    rng = np.random.default_rng(7)
    scans = _scans(rng, 4, 1500 if res >= 0.2 else 400)
    tree = octomap.OcTree(res)
    tree.setProbHit(params.prob_hit)
    tree.setProbMiss(params.prob_miss)
    tree.setOccupancyThres(params.occupancy)
    tree.setClampingThresMin(params.clamp_min)
    tree.setClampingThresMax(params.clamp_max)
    mapper = V.VoxelMapper([-9, -9, -9], [12, 9, 9], res, params, maxrange)
    for pts, origin in scans:
        tree.insertPointCloud(pts.astype(float), origin, maxrange=maxrange)
        mapper.insert(pts, origin)
    grid = mapper.grid()
    classes, values, _, _ = _octree_dense(tree, grid)
    counts = grid.counts()
    assert counts["free"] > 1000 and counts["occupied"] > 1000 and counts["occupied"] < counts["free"]
    assert np.array_equal(classes, grid.classes)
    known = ~np.isnan(values)
    assert np.array_equal(known, ~np.isnan(mapper.logodds))
    assert np.array_equal(values[known], mapper.logodds[known])  # float32 log-odds, bit for bit


def test_octomap_files_both_ways(tmp_path):
    rng = np.random.default_rng(3)
    tree = octomap.OcTree(0.2)
    # a large free block (pruned into big leaves) and scans (fine leaves)
    xs = np.arange(-2.0, 2.0, 0.2) + 0.1
    block = np.array(np.meshgrid(xs, xs, xs + 4.0, indexing="ij")).reshape(3, -1).T
    tree.updateNodes(block, False)
    for pts, origin in _scans(rng, 2, 800):
        tree.insertPointCloud(pts.astype(float), origin, maxrange=6.0)
    tree.updateInnerOccupancy()
    tree.writeBinary(str(tmp_path / "m.bt").encode())
    tree.write(str(tmp_path / "m.ot").encode())
    bt = V.read_octomap(tmp_path / "m.bt")
    ot = V.read_octomap(tmp_path / "m.ot")
    for got in (bt, ot):
        classes, _, leaves, pruned = _octree_dense(tree, got)
        assert pruned > 0 and leaves < got.counts()["free"] + got.counts()["occupied"]
        assert np.array_equal(classes, got.classes)
    assert bt.digest == ot.digest
    # ours, read by OctoMap
    V.write_octomap(bt, tmp_path / "ours.bt")
    back = octomap.OcTree(0.1)
    assert back.readBinary(str(tmp_path / "ours.bt").encode())
    assert back.getResolution() == pytest.approx(0.2)
    classes, _, _, _ = _octree_dense(back, bt)
    assert np.array_equal(classes, bt.classes)
    assert V.read_octomap(tmp_path / "ours.bt").digest == bt.digest


def _shell(free_box, unknown_box=None, pad=2):
    """A grid: an occupied shell round a free box, an unknown box inside it (index ranges)."""
    (a0, b0, c0), (a1, b1, c1) = free_box
    classes = np.full((a1 + pad + 1, b1 + pad + 1, c1 + pad + 1), V.UNKNOWN, dtype=np.int8)
    classes[a0 - 1:a1 + 1, b0 - 1:b1 + 1, c0 - 1:c1 + 1] = V.OCCUPIED
    classes[a0:a1, b0:b1, c0:c1] = V.FREE
    if unknown_box is not None:
        (u0, v0, w0), (u1, v1, w1) = unknown_box
        classes[u0:u1, v0:v1, w0:w1] = V.UNKNOWN
    return classes


def test_frontier_voxels_known_by_construction():
    # an unexplored box of a x b x c voxels inside explored free space, all of it walled in
    a, b, c = 3, 4, 5
    classes = _shell(((2, 2, 2), (20, 18, 16)), ((8, 6, 5), (8 + a, 6 + b, 5 + c)))
    assert V.frontier_mask(classes, 6).sum() == 2 * (a * b + b * c + a * c)
    assert V.frontier_mask(classes, 26).sum() == 2 * (a * b + b * c + a * c) + 4 * (a + b + c) + 8
    # walled in and fully explored: no frontier; a free box open to unknown space: its surface
    assert V.frontier_mask(_shell(((2, 2, 2), (9, 9, 9))), 6).sum() == 0
    open_box = np.full((9, 8, 7), V.UNKNOWN, dtype=np.int8)
    open_box[1:8, 1:7, 1:6] = V.FREE
    assert V.frontier_mask(open_box, 6).sum() == 7 * 6 * 5 - 5 * 4 * 3
    # the array's edge counts as unknown
    assert V.frontier_mask(np.zeros((3, 3, 3), dtype=np.int8), 6).sum() == 26


def test_value_against_brute_force():
    rng = np.random.default_rng(11)
    classes = rng.choice(np.array([V.UNKNOWN, V.FREE, V.OCCUPIED], dtype=np.int8), size=(30, 25, 20), p=[0.2, 0.7, 0.1])
    grid = V.VoxelGrid(classes, 0.25, (V.KEY_ZERO - 10, V.KEY_ZERO - 5, V.KEY_ZERO))
    counter = V.FrontierCounter3D(grid, 6)
    pts = grid.centres(V.frontier_mask(classes, 6))
    assert len(counter) == len(pts) > 100
    queries = rng.uniform([-2.5, -1.25, 0.0], [5.0, 5.0, 5.0], size=(12, 3))
    for above, below in ((1.0, 0.1), (0.0, 0.0), (0.5, 2.0)):
        for radius in (1.0, 2.5):
            got = counter.count(queries, radius, above, below)
            for q, g in zip(queries, got):
                dz = pts[:, 2] - q[2]
                near = np.linalg.norm(pts - q, axis=1) <= radius
                keep = (dz > above) | (dz < -below) if (above or below) else np.ones(len(pts), dtype=bool)
                assert g == int((near & keep).sum())
    # the paper's filter: a frontier voxel level with the carrier is never counted
    assert counter.count([[1.0, 1.0, 2.0]], 100.0, 1.0, 0.1)[0] == int(((pts[:, 2] > 3.0) | (pts[:, 2] < 1.9)).sum())


@pytest.mark.parametrize("name,content,expected", [
    ("m.xyz", b"", "expected an OctoMap file (.bt binary or .ot full), found a '.xyz' file"),
    ("m.bt", b"# Octomap OcTree file\nid OcTree\nsize 1\nres 0.1\ndata\n", "expected an OctoMap .bt file starting with"),
    ("m.bt", b"# Octomap OcTree binary file\nid OcTree\nsize 9\nres 0.1\ndata\n\xff", "found the file truncated"),
    ("m.bt", b"# Octomap OcTree binary file\nid OcTree\nsize 9\nres 0\ndata\n", "expected an OctoMap header with 'res' > 0"),
    ("m.ot", b"# Octomap OcTree file\nid CountingOcTree\nsize 1\nres 0.1\ndata\n", "expected an .ot file of id OcTree"),
])
def test_bad_octomap_files(tmp_path, name, content, expected):
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(GridError) as err:
        V.read_octomap(path)
    assert str(err.value).startswith(str(path)) and expected in str(err.value) and "\n" not in str(err.value)


def test_bad_model_and_sizes():
    with pytest.raises(GridError, match="prob_miss < 0.5 < prob_hit"):
        V.VoxelMapper([0, 0, 0], [1, 1, 1], 0.1, V.OccupancyParams(prob_hit=0.4))
    with pytest.raises(GridError, match="expected a voxel size > 0"):
        V.VoxelMapper([0, 0, 0], [1, 1, 1], 0.0)
    with pytest.raises(GridError, match="voxels at this voxel size"):
        V.VoxelMapper([0, 0, 0], [1000, 1000, 100], 0.05)
