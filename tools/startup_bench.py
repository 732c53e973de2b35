"""Start-up benchmark: how long a freshly installed fleet takes to decide its first stage.

    python -m tools.startup_bench [--baseline main] [--scenario scenarios/six_carriers.yaml ...]
        [--grid 12] [--work DIR] [--json FILE]

For the working tree (its tracked and untracked, not ignored, files) and for a baseline commit
(``--baseline``, a git revision; ``--baseline none`` skips it), in the same run:

1. the tree is copied into a new folder and installed with ``pip install TREE -c constraints.txt``
   into a new virtual environment (pip's cache makes that a matter of unpacking wheels);
2. ``python run_fleet.py SCENARIO --out ...`` runs from that folder **cold** (no compiled kernel
   anywhere: numba's default cache files beside the sources are removed, ``NUMBA_CACHE_DIR``
   is unset and ``XDG_CACHE_HOME`` points at an empty folder, the user cache of a new machine),
   then **warm** (the same command again), then **compiled**: cold again, but after ``python -m
   planner.cli.compile`` (a new machine whose installation compiled the kernels; trees with that
   command only);
3. each run's output lines are time-stamped as they arrive: ``first stage s`` is the time from
   the command to its first decided stage's line (``stage ...``), ``silence s`` the longest gap
   between two output lines before it.

Scenarios: each ``--scenario`` (default ``scenarios/six_carriers.yaml``, mcts-ssap) and a grid
fleet generated from seed 3 by ``tools.scale`` with ``--grid`` carriers (default 12, closed-loop;
``--grid 0``: none). The decisions of the two trees are compared per scenario (every stage's
``deploy`` column): start-up work must not change what the fleet decides.

Prints one row per tree, scenario and run, the ratios against the baseline, and the load
average before and after (the figures are upper bounds on a shared host). ``--json FILE``
writes the rows.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: Targets (s from the command to the first decided stage): a freshly installed machine, warm.
COLD_TARGET_S, WARM_TARGET_S = 5.0, 3.0
#: A decided stage's console line, in either numbering a baseline may print: ``stage   0 of 0..11``
#: (coordinator.clock.progress_line; stages count from 0 everywhere) or the earlier ``stage 1/12``.
STAGE_LINE = re.compile(r"^stage\s+\d+(/\d+| of \d+\.\.\d+) ")
#: A run that has not ended after this long is stopped (s).
RUN_TIMEOUT_S = 600.0


@dataclass
class Run:
    """One ``run_fleet.py`` of one tree on one scenario."""
    tree: str
    scenario: str
    mode: str  # cold | warm
    first_stage_s: float | None
    silence_s: float
    wall_s: float
    returncode: int
    decisions: list[str] = field(default_factory=list)
    log: list[tuple[float, str]] = field(default_factory=list)


def _copy_worktree(dest: Path) -> None:
    files = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"], cwd=ROOT,
                           check=True, capture_output=True).stdout.split(b"\0")
    for name in filter(None, files):
        src = ROOT / os.fsdecode(name)
        if src.is_file():
            (dest / os.fsdecode(name)).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / os.fsdecode(name))


def _export_revision(rev: str, dest: Path) -> None:
    archive = subprocess.run(["git", "archive", rev], cwd=ROOT, check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(dest)], input=archive, check=True)


def install(tree: Path, venv: Path) -> float:
    """A new venv at ``venv`` with ``tree`` pip-installed (its constraints); seconds taken."""
    start = time.monotonic()
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    out = subprocess.run([str(venv / "bin" / "python"), "-m", "pip", "install", "-q", str(tree), "-c",
                          str(tree / "constraints.txt")], cwd=tree, capture_output=True, text=True)
    if out.returncode != 0:
        raise SystemExit(f"startup_bench: pip install {tree} failed:\n{out.stderr[-2000:]}")
    return time.monotonic() - start


def _clear_numba_cache(tree: Path) -> None:
    for pattern in ("*.nbi", "*.nbc"):
        for path in tree.rglob(pattern):
            path.unlink()


def run_fleet(name: str, tree: Path, venv: Path, scenario: Path, out: Path, mode: str, cache_home: Path) -> Run:
    """``run_fleet.py scenario`` from ``tree`` with the venv's interpreter, its lines time-stamped."""
    if mode in ("cold", "compiled"):
        _clear_numba_cache(tree)
        shutil.rmtree(cache_home, ignore_errors=True)
    cache_home.mkdir(parents=True, exist_ok=True)
    shutil.rmtree(out, ignore_errors=True)
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "PYTHONPATH", "VIRTUAL_ENV")}
    env.update(XDG_CACHE_HOME=str(cache_home), PYTHONUNBUFFERED="1",
               PATH=f"{venv / 'bin'}{os.pathsep}{env.get('PATH', '')}")
    if mode == "compiled":  # the install step for a robot host: compile ahead of the first run
        began = time.monotonic()
        subprocess.run([str(venv / "bin" / "python"), "-m", "planner.cli.compile"], cwd=tree, env=env, check=True,
                       capture_output=True)
        print(f"  {name:8} python -m planner.cli.compile: {time.monotonic() - began:.1f} s", flush=True)
    start = time.monotonic()
    proc = subprocess.Popen([str(venv / "bin" / "python"), "run_fleet.py", str(scenario), "--out", str(out)],
                            cwd=tree, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            bufsize=1)
    timer = threading.Timer(RUN_TIMEOUT_S, proc.kill)
    timer.start()
    log = []
    for line in proc.stdout:
        log.append((time.monotonic() - start, line.rstrip("\n")))
    proc.wait()
    timer.cancel()
    wall = time.monotonic() - start
    first = next((t for t, line in log if STAGE_LINE.match(line)), None)
    before = [0.0] + [t for t, _ in log if first is None or t <= first]
    silence = max(b - a for a, b in zip(before, before[1:])) if len(before) > 1 else wall
    decisions = [line.split("| deploy ")[1].split(" |")[0] for _, line in log
                 if STAGE_LINE.match(line) and "| deploy " in line]
    return Run(name, scenario.name, mode, first, silence, wall, proc.returncode, decisions, log)


def _load() -> str:
    return " ".join(f"{x:.1f}" for x in os.getloadavg())


def _fmt(x: float | None) -> str:
    return "-" if x is None else f"{x:.1f}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--baseline", default="main", help="git revision to compare with ('none': skip)")
    ap.add_argument("--scenario", action="append", type=Path,
                    help="scenario file, relative to the tree (repeatable; default scenarios/six_carriers.yaml)")
    ap.add_argument("--grid", type=int, default=12, help="carriers of the generated grid scenario (0: none)")
    ap.add_argument("--work", type=Path, help="folder for trees, venvs and runs (default: a temporary one)")
    ap.add_argument("--json", type=Path, help="write the rows here")
    args = ap.parse_args(argv)
    work = args.work or Path(tempfile.mkdtemp(prefix="startup_bench_"))
    work.mkdir(parents=True, exist_ok=True)
    scenarios = args.scenario or [Path("scenarios/six_carriers.yaml")]
    trees = {"tree": None} if args.baseline == "none" else {"tree": None, "baseline": args.baseline}
    print(f"startup_bench: work in {work}; load {_load()}", flush=True)
    installed = {}
    for name, rev in trees.items():
        src = work / name / "src"
        shutil.rmtree(work / name, ignore_errors=True)
        src.mkdir(parents=True)
        _copy_worktree(src) if rev is None else _export_revision(rev, src)
        seconds = install(src, work / name / "venv")
        installed[name] = (src, work / name / "venv")
        print(f"  {name}{'' if rev is None else f' ({rev})'}: installed in a fresh venv in {seconds:.1f} s", flush=True)
    if args.grid:
        grid = work / f"grid_{args.grid}.yaml"
        src, venv = installed["tree"]
        subprocess.run([str(venv / "bin" / "python"), "-m", "tools.scale", "--write-scenario", str(args.grid),
                        str(grid), "--seed", "3"], cwd=src, check=True, capture_output=True)
        scenarios.append(grid.resolve())
    runs: list[Run] = []
    for scenario in scenarios:
        for mode in ("cold", "warm", "compiled"):
            for name, (src, venv) in installed.items():
                if mode == "compiled" and not (src / "planner" / "cli" / "compile.py").exists():
                    continue  # a tree without the compile command
                run = run_fleet(name, src, venv, scenario if scenario.is_absolute() else src / scenario,
                                work / name / f"run_{scenario.stem}_{mode}", mode, work / name / "cache_home")
                runs.append(run)
                print(f"  {name:8} {scenario.stem:14} {mode}: first stage {_fmt(run.first_stage_s)} s, longest "
                      f"silence before it {run.silence_s:.1f} s, whole run {run.wall_s:.1f} s, exit {run.returncode}",
                      flush=True)
    print(f"\nload after: {_load()}\n")
    print("| scenario | run | tree: first stage s | silence s | baseline: first stage s | silence s | ratio | target |")
    print("|---|---|---|---|---|---|---|---|")
    ok = True
    for scenario in scenarios:
        for mode in ("cold", "warm", "compiled"):
            row = {r.tree: r for r in runs if r.scenario == scenario.name and r.mode == mode}
            if "tree" not in row:
                continue
            t, b = row["tree"], row.get("baseline")
            ratio = (f"{t.first_stage_s / b.first_stage_s:.2f}" if b and t.first_stage_s and b.first_stage_s
                     else "-")
            target = WARM_TARGET_S if mode == "warm" else COLD_TARGET_S
            met = t.first_stage_s is not None and t.first_stage_s <= target
            print(f"| {scenario.stem} | {mode} | {_fmt(t.first_stage_s)} | {t.silence_s:.1f} | "
                  f"{_fmt(b.first_stage_s) if b else '-'} | {f'{b.silence_s:.1f}' if b else '-'} | {ratio} | "
                  f"≤ {target:.0f} s: {'met' if met else 'not met'} |")
            ok &= t.returncode == 0
            for run in (t, b):
                if run is not None and run.returncode == 0 and run.first_stage_s is None:
                    print(f"startup_bench: {run.tree} {run.scenario} {mode}: the run exited 0 but printed no "
                          f"stage line this benchmark recognises ({STAGE_LINE.pattern}); its last lines: "
                          f"{[line for _, line in run.log[-3:]]}", file=sys.stderr)
                    ok = False
    for scenario in scenarios:
        same = {tuple(r.decisions) for r in runs if r.scenario == scenario.name}
        decided = all(same)  # no run without a decided stage: an empty list compares equal to any other
        print(f"{scenario.stem}: decisions {'identical' if len(same) == 1 and decided else 'DIFFER' if decided else 'MISSING'}"
              " across trees and runs")
        ok &= len(same) == 1 and decided
    if args.json:
        args.json.write_text(json.dumps([asdict(r) for r in runs], indent=1))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
