"""Soak test: many consecutive missions, watching for leaked processes, sockets and memory growth.

    python tools/soak.py                         # 200 missions of scenarios/tiny.yaml
    python tools/soak.py --missions 20 --out runs/soak
    python tools/soak.py --missions 20 -- --planner ssap    # extra run_fleet.py flags after --

Each mission is `python run_fleet.py SCENARIO --out OUT/missions/NNNN [extra flags]`, started by
this process. While it runs, a sampler thread reads the resident set size (RSS) of every process
below this one (launcher, coordinator, carriers) every --sample-ms milliseconds; after it ends,
pids are named by role from the mission's summary.json. This process is made a child subreaper
(Linux), so a coordinator or carrier orphaned by its launcher is re-parented here and counted as
leaked instead of vanishing from view.

Printed per mission: exit status, wall time, processes still alive after the mission (leaked),
open file descriptors and inet connections of this process, of its leftover descendants, and of
any process that took part in the mission, peak RSS per role. At the end: missions completed,
totals of leaks, peak RSS per role over the whole run and its growth from the first to the last
tenth of the missions. Writes OUT/soak.json (every figure) and OUT/soak.png (memory over missions).
Not part of the test suite.
"""

from __future__ import annotations

import argparse
import ctypes
import json
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Sequence

import psutil

from world.paths import REPO_ROOT as ROOT

PR_SET_CHILD_SUBREAPER = 36  # linux/prctl.h
MB = 1024 * 1024
LEAK_GRACE_S = 2.0  # how long a mission's processes get to exit after the launcher has, seconds


def become_subreaper() -> bool:
    """Adopt orphaned descendants (Linux prctl); False where unsupported."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


@dataclass
class MissionFigures:
    """What one mission measured. RSS in MB; times in seconds."""

    index: int  # 1-based
    returncode: int | None
    completed: bool
    wall_s: float
    leaked_pids: list[int]
    leaked_fds: int  # open fds of leftover descendants
    leaked_connections: int  # inet sockets of leftover descendants
    soak_fds: int  # this process's open fds after the mission
    soak_connections: int  # this process's inet sockets after the mission
    soak_rss_mb: float
    peak_rss_mb: dict[str, float] = field(default_factory=dict)  # role -> peak RSS
    peak_fds: dict[str, int] = field(default_factory=dict)  # role -> most open fds at once
    error: str = ""
    roles: dict[int, str] = field(default_factory=dict)  # pid -> role


class Sampler(threading.Thread):
    """Reads RSS of every descendant of this process every `period_s` seconds.

    `peaks[pid]` is the largest RSS seen (bytes), `peak_fds[pid]` the most open fds; `series`
    holds (t, total RSS of descendants in MB) and `samples` (t, pid, RSS in MB), t in seconds
    since the soak started.
    """

    def __init__(self, period_s: float, t0: float):
        super().__init__(daemon=True, name="rss-sampler")
        self.period_s = period_s
        self.t0 = t0
        self.peaks: dict[int, int] = {}
        self.peak_fds: dict[int, int] = {}
        self.names: dict[int, str] = {}
        self.series: list[tuple[float, float]] = []
        self.samples: list[tuple[float, int, float]] = []
        self._stop_event = threading.Event()
        self._me = psutil.Process()

    def run(self) -> None:
        while not self._stop_event.is_set():
            total = 0
            now = time.monotonic() - self.t0
            for proc in self._me.children(recursive=True):
                try:
                    if proc.status() == psutil.STATUS_ZOMBIE:
                        continue  # exited, not yet reaped: no memory, no fds
                    rss = proc.memory_info().rss
                    fds = proc.num_fds()
                    if proc.pid not in self.names:
                        self.names[proc.pid] = " ".join(proc.cmdline()[:4])
                except (psutil.NoSuchProcess, psutil.AccessDenied, psutil.ZombieProcess):
                    continue
                total += rss
                self.samples.append((now, proc.pid, rss / MB))
                self.peaks[proc.pid] = max(self.peaks.get(proc.pid, 0), rss)
                self.peak_fds[proc.pid] = max(self.peak_fds.get(proc.pid, 0), fds)
            self.series.append((now, total / MB))
            self._stop_event.wait(self.period_s)

    def stop(self) -> None:
        self._stop_event.set()
        self.join()


def roles_from_summary(summary_path: Path, launcher_pid: int, pids: Sequence[int]) -> dict[int, str]:
    """Name each sampled pid: `launcher`, `coordinator`, `carrier <id>` (pids from summary.json),
    `resource tracker`, or `other`."""
    roles = {pid: "other" for pid in pids}
    roles[launcher_pid] = "launcher"
    try:
        summary = json.loads(summary_path.read_text())
    except (OSError, ValueError):
        summary = {}
    coordinator = summary.get("coordinator") if isinstance(summary.get("coordinator"), dict) else {}
    if coordinator.get("pid") in roles:
        roles[coordinator["pid"]] = "coordinator"
    for carrier in summary.get("carriers") or []:
        if isinstance(carrier, dict) and carrier.get("pid") in roles:
            roles[carrier["pid"]] = f"carrier {carrier.get('id')}"
    return roles


def reap_zombies() -> int:
    """Collect exit statuses of adopted descendants that have exited; returns how many."""
    n = 0
    while True:
        try:
            pid, _ = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            return n
        if pid == 0:
            return n
        n += 1


def alive_descendants() -> list[psutil.Process]:
    out = []
    for p in psutil.Process().children(recursive=True):
        try:
            if p.status() != psutil.STATUS_ZOMBIE:
                out.append(p)
        except psutil.Error:
            pass
    return out


def inet_connections(proc: psutil.Process) -> int:
    try:
        return len(proc.net_connections(kind="inet"))
    except (psutil.Error, AttributeError):
        try:
            return len(proc.connections(kind="inet"))
        except psutil.Error:
            return 0


def run_mission(
    index: int, scenario: Path, out: Path, extra: Sequence[str], sampler: Sampler, timeout_s: float
) -> MissionFigures:
    """Run one mission in a child process and collect its figures."""
    mission_dir = out / "missions" / f"{index:04d}"
    cmd = [sys.executable, str(ROOT / "run_fleet.py"), str(scenario), "--out", str(mission_dir), *extra]
    before = set(sampler.peaks)
    start = time.monotonic()
    log_path = out / "missions" / f"{index:04d}.log"
    log_path.parent.mkdir(parents=True, exist_ok=True)
    error = ""
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(cmd, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
        try:
            returncode = proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            error = f"timed out after {timeout_s:.0f} s"
            proc.kill()
            returncode = proc.wait()
    wall = time.monotonic() - start
    me = psutil.Process()
    # Give the mission's processes a moment to finish exiting, then anything left is a leak.
    deadline = time.monotonic() + LEAK_GRACE_S
    reap_zombies()
    leftovers = alive_descendants()
    while leftovers and time.monotonic() < deadline:
        time.sleep(0.1)
        reap_zombies()
        leftovers = alive_descendants()
    leaked_fds = leaked_conns = 0
    for p in leftovers:
        try:
            leaked_fds += p.num_fds()
        except psutil.Error:
            pass
        leaked_conns += inet_connections(p)
    mission_pids = [pid for pid in sampler.peaks if pid not in before]
    roles = roles_from_summary(mission_dir / "summary.json", proc.pid, mission_pids)
    peaks: dict[str, float] = {}
    peak_fds: dict[str, int] = {}
    for pid in mission_pids:
        role = roles.get(pid, "other")
        peaks[role] = max(peaks.get(role, 0.0), sampler.peaks[pid] / MB)
        peak_fds[role] = max(peak_fds.get(role, 0), sampler.peak_fds.get(pid, 0))
    completed = returncode == 0 and (mission_dir / "summary.json").is_file()
    if not completed and not error:
        tail = log_path.read_text(errors="replace").strip().splitlines()[-1:] or [""]
        error = f"exit {returncode}: {tail[0][:200]}"
    for p in leftovers:  # clean up so one leak does not snowball into the next missions
        try:
            p.kill()
        except psutil.Error:
            pass
    psutil.wait_procs(leftovers, timeout=5)
    reap_zombies()
    return MissionFigures(
        index=index, returncode=returncode, completed=completed, wall_s=wall,
        leaked_pids=[p.pid for p in leftovers], leaked_fds=leaked_fds, leaked_connections=leaked_conns,
        soak_fds=me.num_fds(), soak_connections=inet_connections(me),
        soak_rss_mb=me.memory_info().rss / MB, peak_rss_mb=peaks, peak_fds=peak_fds, error=error,
        roles={pid: roles.get(pid, "other") for pid in mission_pids},
    )


def growth(values: Sequence[float]) -> float:
    """Mean of the last tenth minus mean of the first tenth (at least one value each)."""
    n = max(1, len(values) // 10)
    return sum(values[-n:]) / n - sum(values[:n]) / n


def plot(path: Path, figures: Sequence[MissionFigures], samples: Sequence[tuple[float, int, float]]) -> None:
    """Top: peak RSS per role by mission. Bottom: RSS of every process over time, coloured by role."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (top, bottom) = plt.subplots(2, 1, figsize=(9, 7), constrained_layout=True)
    roles = sorted({r for f in figures for r in f.peak_rss_mb})
    colours = {role: f"C{k}" for k, role in enumerate(roles)}
    xs = [f.index for f in figures]
    for role in roles:
        top.plot(xs, [f.peak_rss_mb.get(role, float("nan")) for f in figures], marker=".",
                 color=colours[role], label=role)
    top.plot(xs, [f.soak_rss_mb for f in figures], marker=".", color="k", label="soak process", linestyle="--")
    top.set_xlabel("mission")
    top.set_ylabel("peak RSS (MB)")
    top.set_ylim(bottom=0)
    top.set_title("Peak resident memory per process, by mission")
    top.legend(fontsize="small", ncol=3)
    role_of = {pid: role for f in figures for pid, role in f.roles.items()}
    by_pid: dict[int, list[tuple[float, float]]] = {}
    for t, pid, mb in samples:
        by_pid.setdefault(pid, []).append((t, mb))
    for pid, points in by_pid.items():
        role = role_of.get(pid, "other")
        bottom.plot([t for t, _ in points], [mb for _, mb in points], linewidth=0.8,
                    color=colours.get(role, "grey"))
    bottom.set_xlabel("time since soak start (s)")
    bottom.set_ylabel("RSS (MB)")
    bottom.set_ylim(bottom=0)
    bottom.set_title("Resident memory of each process over time (colours as above)")
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    extra: list[str] = []
    if "--" in argv:
        cut = argv.index("--")
        argv, extra = argv[:cut], argv[cut + 1:]
    parser = argparse.ArgumentParser(description="Run many consecutive missions and report leaks and memory.")
    parser.add_argument("--missions", type=int, default=200, help="number of missions (default 200)")
    parser.add_argument("--scenario", type=Path, default=ROOT / "scenarios" / "tiny.yaml")
    parser.add_argument("--out", type=Path, default=ROOT / "runs" / "soak", help="results directory")
    parser.add_argument("--sample-ms", type=float, default=100.0, help="RSS sampling period, ms")
    parser.add_argument("--timeout", type=float, default=120.0, help="per-mission time limit, s")
    parser.add_argument("--keep", action="store_true", help="keep every mission's directory (default: last 3)")
    args = parser.parse_args(argv)
    if args.missions < 1:
        print(f"error: --missions: expected a positive integer, found {args.missions}", file=sys.stderr)
        return 2
    if not args.scenario.is_file():
        print(f"error: --scenario: file not found: {args.scenario}", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    reaper = become_subreaper()
    t0 = time.monotonic()
    sampler = Sampler(args.sample_ms / 1000.0, t0)
    sampler.start()
    figures: list[MissionFigures] = []
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    print(f"soak: {args.missions} missions of {args.scenario} -> {args.out} "
          f"(subreaper {'on' if reaper else 'unavailable: orphans may go unseen'})", flush=True)
    try:
        for i in range(args.missions):
            if stop.is_set():
                print("soak: interrupted", flush=True)
                break
            f = run_mission(i + 1, args.scenario, args.out, extra, sampler, args.timeout)
            figures.append(f)
            peaks = "  ".join(f"{role} {mb:.0f}" for role, mb in sorted(f.peak_rss_mb.items()))
            print(
                f"mission {i + 1:4d}/{args.missions} {'ok  ' if f.completed else 'FAIL'} {f.wall_s:5.1f} s"
                f" | leaked procs {len(f.leaked_pids)} fds {f.leaked_fds} conns {f.leaked_connections}"
                f" | soak fds {f.soak_fds} conns {f.soak_connections} rss {f.soak_rss_mb:.0f} MB"
                f" | peak RSS MB: {peaks}" + (f" | {f.error}" if f.error else ""),
                flush=True,
            )
            if f.returncode == 2 and i == 0:
                # run_fleet.py's exit code for bad input: every further mission would fail alike.
                print(f"error: run_fleet.py refused its input ({f.error}); see {args.out / 'missions' / '0001.log'}",
                      file=sys.stderr)
                return 2
            if not args.keep and i >= 3:
                old = args.out / "missions" / f"{i - 2:04d}"
                if old.is_dir() and figures[i - 3].completed:
                    import shutil

                    shutil.rmtree(old, ignore_errors=True)
    finally:
        sampler.stop()
    if not figures:
        return 1
    completed = sum(f.completed for f in figures)
    roles = sorted({r for f in figures for r in f.peak_rss_mb})
    report = {
        "scenario": str(args.scenario),
        "missions_run": len(figures),
        "missions_completed": completed,
        "leaked_processes": sum(len(f.leaked_pids) for f in figures),
        "leaked_fds": sum(f.leaked_fds for f in figures),
        "leaked_connections": sum(f.leaked_connections for f in figures),
        "soak_fds": {"first": figures[0].soak_fds, "last": figures[-1].soak_fds,
                     "max": max(f.soak_fds for f in figures)},
        "soak_connections": {"first": figures[0].soak_connections, "last": figures[-1].soak_connections,
                             "max": max(f.soak_connections for f in figures)},
        "soak_rss_mb": {"first": figures[0].soak_rss_mb, "last": figures[-1].soak_rss_mb},
        "peak_rss_mb": {role: max(f.peak_rss_mb.get(role, 0.0) for f in figures) for role in roles},
        "peak_fds": {role: max(f.peak_fds.get(role, 0) for f in figures) for role in roles},
        "peak_rss_growth_mb": {role: growth([f.peak_rss_mb[role] for f in figures if role in f.peak_rss_mb])
                               for role in roles},
        "wall_s": {"mean": sum(f.wall_s for f in figures) / len(figures), "max": max(f.wall_s for f in figures)},
        "missions": [asdict(f) for f in figures],
        "rss_series": sampler.series,
    }
    (args.out / "soak.json").write_text(json.dumps(report, indent=1))
    plot(args.out / "soak.png", figures, sampler.samples)
    print(f"\nmissions completed: {completed}/{len(figures)}")
    print(f"leaked: processes {report['leaked_processes']}, their fds {report['leaked_fds']}, "
          f"their inet connections {report['leaked_connections']}")
    print(f"soak process: fds {report['soak_fds']}, inet connections {report['soak_connections']}, "
          f"RSS MB first {report['soak_rss_mb']['first']:.1f} last {report['soak_rss_mb']['last']:.1f}")
    for role in roles:
        print(f"peak RSS {role:>16}: {report['peak_rss_mb'][role]:7.1f} MB "
              f"(growth first->last tenth {report['peak_rss_growth_mb'][role]:+.1f} MB), "
              f"most open fds {report['peak_fds'][role]}")
    print(f"mission wall time: mean {report['wall_s']['mean']:.1f} s, max {report['wall_s']['max']:.1f} s")
    print(f"wrote {args.out / 'soak.json'} and {args.out / 'soak.png'}")
    return 0 if completed == len(figures) else 1


if __name__ == "__main__":
    sys.exit(main())
