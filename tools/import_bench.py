"""Import benchmark: how long ``python -m world import`` takes and how much memory it peaks at,
on generated recorded runs (``tools.synthetic_run``) of two floor-plan families, on a quiet and
on a busy host; and how a fleet mission on an imported map compares in wall time with one on a
hand-written scenario of the same carriers.

    python -m tools.import_bench [--quick] [--json FILE] [--families rooms,caves] [--busy no,yes]
        [--seed 0] [--repeat 3] [--iterations 300] [--work DIR]

prints a table of the import rows and one of the fleet rows (exit status 1 if a target is
missed); ``--json FILE`` writes the same rows. About 6 minutes on a quiet 2-core host.

Import rows: each import runs as its own subprocess; its wall time is measured round the
process and its peak RSS is the child's ``ru_maxrss`` from ``os.wait4`` (that process alone).
"met?" is judged on the slowest of ``--repeat`` runs and the largest peak. Sizes: 600 x 400
cells with 16 maps (bag, ``--replay``) and the same map from its map_server YAML with
``--routes`` (static), target 10 s; 4,000 x 4,000 cells static and from a bag of 8 maps
(``--replay``), target 60 s and 2,048 MB. ``--quick`` runs only the small sizes, one repeat,
and the replay fleet pair of the first family on the quiet host (a smoke run, under a minute).

Fleet rows: ``run_fleet.py S.yaml --planner-option iterations=N`` on the imported 600 x 400
scenario (replay and static) and on its hand-written twin: the same carriers (waypoints,
start and stop times, speeds, passengers), stages, stage interval, radii, prior and bounds, but
no occupancy and no walls, features a Poisson process of the imported map's frontier density
(frontier cells per m² of free area). The wall time is the one run_fleet.py prints; target:
imported <= 2 x hand-written.

Busy host: ``--busy yes`` starts two CPU-burning processes (one per core of a 2-core host) for
the measurement and ends them after it.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import time
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: Targets: a 600 x 400 import (s); a 4,000 x 4,000 import (s, MB of peak RSS); the fleet's
#: wall-time ratio imported / hand-written.
SMALL_S, LARGE_S, LARGE_MB, FLEET_RATIO = 10.0, 60.0, 2048.0, 2.0
#: CPU burners started for a busy host.
BURNERS = 2
#: Candidate spacing along the routes (m) and passengers of the bag's carriers.
SPACING = 2.0
PASSENGERS = ("c0=3", "c1=3", "c2=2")


@dataclass(frozen=True)
class Case:
    """One import measured: ``cells`` (W, H), ``snapshots`` maps in the bag, ``mode`` replay
    (the bag, values from the latest map at each time) or static (map YAML + routes YAML);
    targets in s and MB (None: not targeted)."""

    family: str
    cells: tuple[int, int]
    snapshots: int
    mode: str
    target_s: float
    target_mb: float | None = None

    @property
    def label(self) -> str:
        return f"{self.cells[0]}x{self.cells[1]}"


def cases(families: list[str], quick: bool) -> list[Case]:
    out = []
    for fam in families:
        out += [Case(fam, (600, 400), 16, "replay", SMALL_S), Case(fam, (600, 400), 16, "static", SMALL_S)]
        if not quick:
            out += [Case(fam, (4000, 4000), 8, "static", LARGE_S, LARGE_MB),
                    Case(fam, (4000, 4000), 8, "replay", LARGE_S, LARGE_MB)]
    return out


# --------------------------------------------------------------------------- processes


def run_measured(cmd: list[str], log: Path, cwd: Path = ROOT) -> tuple[float, float, str]:
    """Run ``cmd`` to its end; (wall s, the process's peak RSS MB, its output). Raises
    RuntimeError with the output's tail when it fails."""
    with open(log, "w+", encoding="utf-8") as out:
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, cwd=cwd, stdout=out, stderr=subprocess.STDOUT)
        try:
            _, status, usage = os.wait4(proc.pid, 0)  # this child's own rusage (Linux: ru_maxrss in KiB)
        except BaseException:
            proc.kill()
            proc.wait()
            raise
        wall = time.perf_counter() - t0
        proc.returncode = os.waitstatus_to_exitcode(status)
        out.seek(0)
        text = out.read()
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} exited {proc.returncode}:\n{text[-2000:]}")
    return wall, usage.ru_maxrss / 1024.0, text


@contextmanager
def busy_host(on: bool):
    """BURNERS processes spinning on the CPU while the block runs (none when ``on`` is false);
    each is ended by its own pid afterwards."""
    procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(BURNERS if on else 0)]
    try:
        if procs:
            time.sleep(0.5)  # let them reach the CPU before timing
        yield
    finally:
        for p in procs:
            p.terminate()
        for p in procs:
            p.wait(timeout=10)


# --------------------------------------------------------------------------- inputs


def generated(work: Path, family: str, cells: tuple[int, int], snapshots: int, seed: int) -> tuple[Path, list[str]]:
    """The recorded run of that family and size (generated once per benchmark): its directory
    and the ``--odom`` flags for its bag."""
    d = work / f"{family}-{cells[0]}x{cells[1]}-{snapshots}-s{seed}"
    flags_file = d / "odom.txt"
    if not flags_file.is_file():
        cmd = [sys.executable, "-m", "tools.synthetic_run", str(d), "--cells", f"{cells[0]}x{cells[1]}",
               "--snapshots", str(snapshots), "--seed", str(seed), "--family", family, "--storage", "mcap"]
        d.mkdir(parents=True, exist_ok=True)
        wall, mb, text = run_measured(cmd, d.with_suffix(".gen.log"))
        line = next(ln for ln in text.splitlines() if ln.startswith("odom: "))
        flags_file.write_text(line[len("odom: "):], encoding="utf-8")
        print(f"  generated {d.name}: {wall:.1f} s, {mb:.0f} MB", flush=True)
    return d, flags_file.read_text(encoding="utf-8").split()


def import_command(run_dir: Path, odom: list[str], mode: str, out: Path) -> list[str]:
    cmd = [sys.executable, "-m", "world", "import"]
    if mode == "replay":
        cmd += [str(run_dir / "bag"), *odom, "--replay"]
        for p in PASSENGERS:
            cmd += ["--passengers", p]
    else:
        cmd += [str(run_dir / "map.yaml"), "--routes", str(run_dir / "routes.yaml")]
    return cmd + ["--stage-spacing", str(SPACING), "--out", str(out)]


def handwritten(imported: Path, out: Path) -> float:
    """Write the hand-written twin of an imported scenario (see the module) to ``out``;
    returns its feature density (1/m²)."""
    import yaml

    from world import grid as G
    from world.scenario import load_scenario

    scenario = load_scenario(imported)
    grid = scenario.map.occupancy
    free = int((grid.classes == G.FREE).sum())
    density = float(G.frontier_mask(grid).sum()) / (free * grid.resolution ** 2)
    doc = yaml.safe_load(imported.read_text(encoding="utf-8"))
    doc["name"] = f"{doc['name']}_hand"
    doc["map"] = {"bounds": doc["map"]["bounds"]}
    doc["features"] = {"density": round(density, 6)}
    out.write_text(f"# Hand-written twin of {imported.name} (tools.import_bench): same carriers, no map.\n"
                   + yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=200), encoding="utf-8")
    load_scenario(out)  # it must load
    return density


def fleet_wall(scenario: Path, out: Path, iterations: int) -> tuple[float, float]:
    """(wall s that run_fleet.py prints, wall s of the whole process) of one mission."""
    cmd = [sys.executable, "run_fleet.py", str(scenario), "--out", str(out), "--planner-option",
           f"iterations={iterations}"]
    out.mkdir(parents=True, exist_ok=True)
    wall, _, text = run_measured(cmd, out.with_suffix(".log"))
    m = re.findall(r"; wall ([0-9.]+) s", text)
    if not m:
        raise RuntimeError(f"no 'wall X s' in the output of {' '.join(cmd)}:\n{text[-2000:]}")
    return float(m[-1]), wall


# --------------------------------------------------------------------------- the benchmark


def measure_imports(work: Path, families: list[str], busy: list[bool], seed: int, repeat: int, quick: bool) -> list[dict]:
    rows = []
    for case in cases(families, quick):
        run_dir, odom = generated(work, case.family, case.cells, case.snapshots, seed)
        for on in busy:
            times, peaks = [], []
            with busy_host(on):
                for k in range(repeat):
                    out = work / "imports" / f"{run_dir.name}-{case.mode}-{'busy' if on else 'quiet'}-{k}" / "s.yaml"
                    out.parent.mkdir(parents=True, exist_ok=True)
                    wall, mb, _ = run_measured(import_command(run_dir, odom, case.mode, out), out.with_suffix(".log"))
                    times.append(wall)
                    peaks.append(mb)
            worst_s, peak = max(times), max(peaks)
            met = worst_s <= case.target_s and (case.target_mb is None or peak <= case.target_mb)
            target = f"<= {case.target_s:g} s" + (f", <= {case.target_mb:g} MB" if case.target_mb else "")
            row = {**asdict(case), "cells": case.label, "busy": on, "runs": repeat,
                   "import_s": round(statistics.median(times), 2), "max_s": round(worst_s, 2),
                   "peak_mb": round(peak, 1), "target": target, "met": met}
            rows.append(row)
            print(f"  import {case.family} {case.label} {case.mode} busy={'yes' if on else 'no'}: "
                  f"median {row['import_s']} s, max {row['max_s']} s, peak {row['peak_mb']} MB", flush=True)
    return rows


def measure_fleet(work: Path, families: list[str], modes: list[str], busy: list[bool], seed: int,
                  iterations: int) -> list[dict]:
    rows = []
    for fam in families:
        run_dir, _ = generated(work, fam, (600, 400), 16, seed)
        for mode in modes:
            imported = work / "imports" / f"{run_dir.name}-{mode}-quiet-0" / "s.yaml"
            if not imported.is_file():  # the import rows were all on a busy host
                imported.parent.mkdir(parents=True, exist_ok=True)
                _, odom = generated(work, fam, (600, 400), 16, seed)
                run_measured(import_command(run_dir, odom, mode, imported), imported.with_suffix(".log"))
            hand = imported.with_name("hand.yaml")
            density = handwritten(imported, hand)
            for on in busy:
                tag = "busy" if on else "quiet"
                with busy_host(on):
                    imp_wall, imp_proc = fleet_wall(imported, work / "fleet" / f"{run_dir.name}-{mode}-{tag}-imported",
                                                    iterations)
                    hand_wall, hand_proc = fleet_wall(hand, work / "fleet" / f"{run_dir.name}-{mode}-{tag}-hand",
                                                      iterations)
                ratio = imp_wall / hand_wall
                row = {"family": fam, "cells": "600x400", "mode": mode, "busy": on, "iterations": iterations,
                       "imported_wall_s": imp_wall, "hand_wall_s": hand_wall, "ratio": round(ratio, 2),
                       "imported_process_s": round(imp_proc, 2), "hand_process_s": round(hand_proc, 2),
                       "hand_density": round(density, 4), "target": f"<= {FLEET_RATIO:g}x",
                       "met": ratio <= FLEET_RATIO}
                rows.append(row)
                print(f"  fleet {fam} {mode} busy={'yes' if on else 'no'}: imported {imp_wall} s, hand {hand_wall} s, "
                      f"ratio {ratio:.2f}", flush=True)
    return rows


def tables(imports: list[dict], fleet: list[dict]) -> str:
    yn = {True: "yes", False: "no"}
    lines = ["| family | busy | source | cells | snapshots | import s (median) | max s | peak MB | target | met? |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in imports:
        src = "bag --replay" if r["mode"] == "replay" else "map YAML + --routes"
        snaps = str(r["snapshots"]) if r["mode"] == "replay" else "1 (final map)"
        lines.append(f"| {r['family']} | {yn[r['busy']]} | {src} | {r['cells']} | {snaps} | {r['import_s']:.2f} | "
                     f"{r['max_s']:.2f} | {r['peak_mb']:.0f} | {r['target']} | {yn[r['met']]} |")
    if fleet:
        lines += ["", "| family | busy | scenario | cells | fleet wall s, imported | hand-written | ratio | target | met? |",
                  "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
        for r in fleet:
            lines.append(f"| {r['family']} | {yn[r['busy']]} | {r['mode']} import | {r['cells']} | "
                         f"{r['imported_wall_s']:.1f} | {r['hand_wall_s']:.1f} | {r['ratio']:.2f} | {r['target']} | "
                         f"{yn[r['met']]} |")
    return "\n".join(lines)


def main(families: list[str], busy: list[bool], seed: int, repeat: int, iterations: int, quick: bool,
         work: Path, json_path: str | None, command: str) -> int:
    work.mkdir(parents=True, exist_ok=True)
    load = os.getloadavg()
    print(f"import bench: {os.cpu_count()} CPUs, load average {load[0]:.2f} at start; work in {work}", flush=True)
    imports = measure_imports(work, families, busy, seed, 1 if quick else repeat, quick)
    fleet = measure_fleet(work, families[:1] if quick else families, ["replay"] if quick else ["replay", "static"],
                          [False] if quick else busy, seed, iterations)
    text = tables(imports, fleet)
    print("\n" + text)
    if json_path:
        doc = {"command": command, "cpus": os.cpu_count(), "load_at_start": load, "seed": seed,
               "imports": imports, "fleet": fleet}
        Path(json_path).write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
    return 0 if all(r["met"] for r in imports + fleet) else 1


if __name__ == "__main__":
    p = argparse.ArgumentParser(prog="python -m tools.import_bench", description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="small sizes only, one repeat, one fleet pair (under a minute)")
    p.add_argument("--json", metavar="FILE", help="also write the rows as JSON")
    p.add_argument("--families", default="rooms,caves", help="tools.synthetic_run families (default rooms,caves)")
    p.add_argument("--busy", default="no,yes", help="host states: no (quiet), yes (2 CPU burners); default no,yes")
    p.add_argument("--seed", type=int, default=0, help="seed of the generated runs (default 0)")
    p.add_argument("--repeat", type=int, default=3, help="imports per row (default 3)")
    p.add_argument("--iterations", type=int, default=300, help="planner iterations of the fleet runs (default 300)")
    p.add_argument("--work", default=None,
                   help="directory for the runs, kept (default: a temporary one, removed at the end)")
    a = p.parse_args()
    states = {"no": False, "yes": True}

    def bench(work: str) -> int:
        return main([f for f in a.families.split(",") if f], [states[b] for b in a.busy.split(",") if b], a.seed,
                    a.repeat, a.iterations, a.quick, Path(work), a.json,
                    "python -m tools.import_bench " + " ".join(sys.argv[1:]))

    if a.work is None:
        import tempfile

        with tempfile.TemporaryDirectory(prefix="import_bench-") as tmp:
            sys.exit(bench(tmp))
    sys.exit(bench(a.work))
