"""Speed and memory of the 3D import (``python -m world import``), printed as figures.

    python -m tools.import3d_bench [--scans 200] [--points 10000] [--range 40] [--voxel 0.2]
        [--families offices,atrium] [--busy] [--skip-scans] [--skip-octomap] [--work DIR]

Two cases, each on the generated families of tools/synthetic_3d.py (seed 0):

* scans: a three-storey building 80 m x 40 m, three carriers, ``--scans`` scans of ``--points``
  rays each (40 m range, 0.2 m voxels), imported from a folder with ``--replay --stages 19``;
* octomap: a 100 m x 100 m x 10 m building known by construction at 0.1 m (unknown rooms left in
  it), written as a .bt, imported with 3 carriers x 19 points.

Each import runs as the command a user runs (a child process); its wall time and its peak
resident memory (its own ru_maxrss, read by a wrapper process) are printed next to the targets (60 s and 4 GB; 30 s).
``--busy`` runs every case again with a CPU-bound process beside it (a busy host).
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from tools import synthetic_3d as S
from world import voxels as V

ROOT = Path(__file__).resolve().parents[1]


#: Runs one command and prints its peak resident memory (KiB, its own ru_maxrss) on stderr's last line.
_WRAP = ("import resource, subprocess, sys; rc = subprocess.run(sys.argv[1:]).returncode; "
         "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, file=sys.stderr); sys.exit(rc)")


def _timed(args: list[str]) -> tuple[float, float, str]:
    """(wall s, peak RSS GB, the values line) of ``python -m world import ...`` in its own process."""
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", _WRAP, sys.executable, "-m", "world", "import", *args], cwd=ROOT,
                          capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if done.returncode:
        raise SystemExit(f"import failed: {done.stderr.strip()}")
    peak_kib = int(done.stderr.strip().splitlines()[-1])
    return wall, peak_kib / 2**20, done.stdout.strip().splitlines()[-2]


def scans_case(work: Path, family: str, n_scans: int, points: int, max_range: float, voxel: float) -> list[str]:
    out = work / f"scans-{family}"
    t0 = time.perf_counter()
    run = S.run(seed=0, storeys=3, size=(80.0, 40.0), carriers=3, scans=n_scans, points=points,
                max_range=max_range, family=family, resolution=0.1, speed=1.0)
    S.write_folder(run, out)
    gen = time.perf_counter() - t0
    total = sum(len(s[3]) for s in run.scans)
    args = [str(out / "scans"), "--routes", str(out / "routes.yaml"), "--stages", "19", "--replay", "--voxel", str(voxel),
            "--max-range", str(max_range), "--out", str(out / "o.yaml"), "--report", str(out / "o.json")]
    return [f"scans/{family}: {len(run.scans)} scans, {total:,} returns of {len(run.scans) * points:,} rays "
            f"(generated in {gen:.1f} s)", *_runs(args, 60.0)]


def octomap_case(work: Path, family: str) -> list[str]:
    out = work / f"octomap-{family}"
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    rng = np.random.default_rng(0)
    b = S.building(rng, storeys=3, size=(100.0, 100.0), resolution=0.1, family=family)
    solid = b.solid[:, :, : int(round((3 * S.STOREY_HEIGHT + S.SLAB + 1.0) / 0.1))]  # 100 x 100 x 10 m
    classes = np.where(solid, V.OCCUPIED, V.FREE).astype(np.int8)
    inside = np.zeros(solid.shape, dtype=bool)
    n = int(round(1.0 / 0.1))
    inside[n:-n, n:-n, :] = True
    classes[~inside & ~solid] = V.UNKNOWN
    for _ in range(60):  # unexplored rooms: unknown boxes
        x, y = rng.integers(20, classes.shape[0] - 80, size=2)
        z = rng.integers(5, classes.shape[2] - 30)
        classes[x:x + 50, y:y + 50, z:z + 20] = V.UNKNOWN
    key0 = tuple(int(v) for v in np.floor(b.lower / 0.1 + 0.5).astype(np.int64) + V.KEY_ZERO)
    grid = V.VoxelGrid(classes, 0.1, key0)
    V.write_octomap(grid, out / "map.bt")
    gen = time.perf_counter() - t0
    W = b.size[0]
    routes = "carriers:\n" + "".join(
        f"  - {{id: c{k}, passengers: 3, start: {5 * k}, speed: 1.0, path: [[2.0, {b.corridor_y - 0.3 * k}, "
        f"{b.floor(k)}], [{W - 2.0}, {b.corridor_y - 0.3 * k}, {b.floor(k)}]]}}\n" for k in range(3))
    (out / "routes.yaml").write_text(routes)
    args = [str(out / "map.bt"), "--routes", str(out / "routes.yaml"), "--stages", "19", "--out", str(out / "o.yaml"),
            "--report", str(out / "o.json")]
    return [f"octomap/{family}: {classes.shape[0]} x {classes.shape[1]} x {classes.shape[2]} voxels of 0.1 m, "
            f".bt {(out / 'map.bt').stat().st_size / 2**20:.1f} MiB (generated in {gen:.1f} s)", *_runs(args, 30.0)]


BUSY = False


def _runs(args: list[str], target: float) -> list[str]:
    lines = []
    for busy in ((False, True) if BUSY else (False,)):
        burner = subprocess.Popen([sys.executable, "-c", "while True: pass"]) if busy else None
        try:
            wall, gb, last = _timed(args)
        finally:
            if burner is not None:
                burner.kill()
                burner.wait()
        lines.append(f"  {'busy host' if busy else 'idle host'}: {wall:.1f} s (target {target:g} s, ratio "
                     f"{wall / target:.2f}), peak RSS {gb:.2f} GB (target 4 GB); {last}")
    return lines


def main(argv: list[str] | None = None) -> int:
    global BUSY
    p = argparse.ArgumentParser(prog="python -m tools.import3d_bench", description=__doc__.split("\n\n")[0])
    p.add_argument("--scans", type=int, default=200)
    p.add_argument("--points", type=int, default=10_000)
    p.add_argument("--range", type=float, default=40.0)
    p.add_argument("--voxel", type=float, default=0.2)
    p.add_argument("--families", default="offices,atrium")
    p.add_argument("--busy", action="store_true")
    p.add_argument("--skip-scans", action="store_true")
    p.add_argument("--skip-octomap", action="store_true")
    p.add_argument("--work", default=None)
    a = p.parse_args(argv)
    BUSY = a.busy
    work = Path(a.work) if a.work else Path(tempfile.mkdtemp(prefix="import3d-bench-"))
    for family in a.families.split(","):
        if not a.skip_scans:
            print("\n".join(scans_case(work, family, a.scans, a.points, a.range, a.voxel)), flush=True)
        if not a.skip_octomap:
            print("\n".join(octomap_case(work, family)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
