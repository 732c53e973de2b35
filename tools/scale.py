"""Scale benchmark: the real fleet (coordinator + K carrier processes over Zenoh on loopback) on
generated scenarios fixed by seed, for growing numbers of carriers R, on an idle or a saturated
host, each run checked against the offline planner (fidelity).

    python -m tools.scale                                   # R = 6, 32, 128, 256, 1024, street grid
    python -m tools.scale --sizes 6,32 --out runs/scale     # a quick look
    python -m tools.scale --family grid --family long-streets --busy 0,4   # both families, idle and saturated
    python -m tools.scale --sizes 256 --no-autonomy       # carriers that never decide on board
    python -m tools.scale --write-scenario 256 /tmp/g256.yaml [--family long-streets]

Per R it prints wall time, peak memory of the whole process tree (total and per carrier),
the stage round trip p50/p99 (coordinator's decision publication to each carrier's Confirm),
decision time (mean and max planner wall time per stage), messages per second, carrier CPU
time per carrier and stage (``carrier_cpu_ms``), a stage's wall time against the work in it
(``idle_ratio``: wall time per stage / (carrier CPU per stage / cores + planning time), over the
whole run; ``loop_idle_ratio``: the same over the stage loop alone, first Observation to last
Confirm, with the carriers' CPU in that window; ``loop_cpu_ratio``: the stage loop's wall
time against all the fleet's CPU in it, the coordinator's outside planning and the routers'
included), the
fidelity (``fidelity``: observations and decisions identical to ``planner.online.run_online``
over ``world.observe_all``, and ``fidelity_reward_ratio``, the reward against the offline one)
and the reward against the clairvoyant bound (an exact optimum, or a labelled conflict-free
upper bound when the exact search is too large). Results: ``<out>/scale.csv``, ``<out>/scale.json`` and, with
``--plot``, a PNG of cost against R. See docs/performance.md, "Fleet scale".

The scenario (:func:`grid_scenario`): a square grid of streets ``STREET_SPACING_M`` apart,
about sqrt(R) in each direction; carriers alternate between east-west and north-south
streets, each on a street, start point, direction and start time drawn from the seed, so that
several carriers share a street (overlapping decision points) and crossings bring a few more.
The physics-heavy family (:func:`long_streets_scenario`): few long streets, slow carriers and
480 s stages, so that the carriers' physics (about 10,000 steps per carrier and stage) is most
of the work. ``--busy N`` starts N busy processes for the run (a saturated host).
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import os
import sqlite3
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
from world.paths import REPO_ROOT as ROOT

#: Distance between parallel streets (m).
STREET_SPACING_M = 40.0
#: Default sizes of the benchmark (carriers).
SIZES = (6, 32, 128, 256, 1024)
#: Carrier speed (m/s), stage interval (s), stages, passengers per carrier.
SPEED, STAGE_INTERVAL_S, STAGES, PASSENGERS = 1.0, 10.0, 12, 3


def _valid_stages(start: float, stop: float, stage_interval: float, stages: int) -> int:
    """How many stage times fall within a carrier's [start, stop] (s): the most passengers the
    scenario schema lets it carry."""
    return sum(1 for j in range(stages) if start <= j * stage_interval <= stop)


def grid_scenario(n_carriers: int, seed: int = 1, planner: str = "closed-loop", stages: int = STAGES) -> dict:
    """A scenario (the YAML mapping) of ``n_carriers`` carriers on a street grid, fixed by ``seed``."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, n_carriers]))
    streets = max(4, math.ceil(math.sqrt(n_carriers)))
    size = (streets + 1) * STREET_SPACING_M
    travel = SPEED * STAGE_INTERVAL_S * (stages + 1)
    carriers = []
    for k in range(n_carriers):
        street = (k // 2 + int(rng.integers(0, 2))) % streets  # spread over the streets, some share
        along = (street + 1) * STREET_SPACING_M
        lo = float(rng.uniform(STREET_SPACING_M / 2, size - STREET_SPACING_M / 2 - travel))
        a, b = round(lo, 1), round(lo + travel, 1)
        if rng.random() < 0.5:
            a, b = b, a
        path = [[a, along], [b, along]] if k % 2 == 0 else [[along, a], [along, b]]
        start = float(rng.choice([0.0, 0.0, 0.0, STAGE_INTERVAL_S, 2 * STAGE_INTERVAL_S]))
        valid = _valid_stages(start, start + travel / SPEED, STAGE_INTERVAL_S, stages)
        carriers.append({"id": f"c{k:04d}", "passengers": min(PASSENGERS, valid), "start_time": start,
                         "speed": SPEED, "waypoints": path})
    return {
        "name": f"grid_{n_carriers}",
        "seed": int(seed),
        "map": {"bounds": [0, 0, size, size]},
        "features": {"density": 0.03},
        "sensing_radius": 4.0,
        "conflict_radius": 8.0,  # m: below the 10 m between a carrier's own decision points
        "stage_interval": STAGE_INTERVAL_S,
        "stages": int(stages),
        "carriers": carriers,
        "planner": {"name": planner},
    }


#: Physics-heavy family: simulated seconds per stage, carrier speed (m/s), stages.
LONG_STAGE_S, LONG_SPEED, LONG_STAGES = 480.0, 0.25, 10


def long_streets_scenario(n_carriers: int, seed: int = 1, planner: str = "closed-loop",
                          stages: int = LONG_STAGES, stage_interval: float = LONG_STAGE_S) -> dict:
    """A physics-heavy scenario (the YAML mapping) of ``n_carriers`` carriers, fixed by ``seed``:
    few long streets, slow carriers and long stages (``stage_interval`` simulated seconds of
    driving per carrier and stage, ``PHYSICS_DT`` steps each), so that the carriers' physics,
    not the planner, is most of a stage's work. Carriers of a street start at staggered points
    and times, so that some of their decision points fall within the conflict radius of each
    other's; about a fifth start a stage or two late."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, n_carriers, 0x4C4F4E47]))  # "LONG"
    streets = max(2, math.ceil(math.sqrt(n_carriers) / 2))
    step = LONG_SPEED * stage_interval  # m between a carrier's decision points
    length = step * (stages + 1)
    spacing = 60.0
    # the map holds the paths and every street (few stages and many carriers: more streets than length)
    size = max(length + 2 * spacing, spacing * (streets + 1) + spacing / 2)
    carriers = []
    for k in range(n_carriers):
        street = int(rng.integers(0, streets))
        along = spacing * (street + 1)
        offset = float(rng.uniform(0.0, 2.0 * step))
        a, b = round(spacing / 2 + offset, 1), round(spacing / 2 + offset + length - 2 * step, 1)
        if rng.random() < 0.5:
            a, b = b, a
        path = [[a, along], [b, along]] if k % 2 == 0 else [[along, a], [along, b]]
        start = float(rng.choice([0.0, 0.0, 0.0, 0.0, stage_interval, 2 * stage_interval]))
        stop = start + abs(b - a) / LONG_SPEED
        valid = _valid_stages(start, stop, stage_interval, stages)
        carriers.append({"id": f"c{k:04d}", "passengers": min(PASSENGERS, valid), "start_time": start,
                         "speed": LONG_SPEED, "waypoints": path})
    return {
        "name": f"long_{n_carriers}",
        "seed": int(seed),
        "map": {"bounds": [0, 0, size, size]},
        "features": {"density": 0.01},
        "sensing_radius": 10.0,
        "conflict_radius": 25.0,
        "stage_interval": stage_interval,
        "stages": int(stages),
        "carriers": carriers,
        "planner": {"name": planner},
    }


#: Scenario families of the benchmark: name -> generator (n_carriers, seed, planner) -> mapping.
FAMILIES = {"grid": grid_scenario, "long-streets": long_streets_scenario}


def write_scenario(n_carriers: int, path: Path, seed: int = 1, planner: str = "closed-loop",
                   family: str = "grid") -> Path:
    import yaml

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(f"# Generated by python -m tools.scale: {n_carriers} carriers, family {family}, seed {seed}.\n"
                    + yaml.safe_dump(FAMILIES[family](n_carriers, seed, planner), sort_keys=False))
    return path


def default_processes(n_carriers: int) -> int:
    """Carrier processes for R carriers in the benchmark: one per carrier up to 8, then about
    32 carriers per process, at most 16 processes."""
    return n_carriers if n_carriers <= 8 else min(16, max(2, math.ceil(n_carriers / 32)))


#: The roles of a fleet's processes whose CPU :class:`TreeSampler` follows over time.
ROLES = ("carrier", "coordinator", "router")


class TreeSampler:
    """Samples the RSS of a process tree every ``period_s`` seconds in a thread.

    Attributes:
        peak_total: largest sum of RSS over the tree (bytes).
        peak: pid -> (largest RSS in bytes, role): coordinator, carrier, router or launcher.
        cpu: pid -> (user + system CPU seconds at the last sample, role).
        series: (time.time(), CPU seconds so far of the carriers, the coordinator and the
            routers) at every sample, so that the CPU of a window of the run (its stage loop)
            can be read off.
    """

    def __init__(self, pid: int, period_s: float = 0.5):
        import psutil

        self.root = psutil.Process(pid)
        self.period_s = period_s
        self.peak_total = 0
        self.peak_carriers = 0
        self.peak: dict[int, tuple[int, str]] = {}
        self.cpu: dict[int, tuple[float, str]] = {}
        self.series: list[tuple[float, float, float, float]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self):
        import psutil

        while not self._stop.is_set():
            total = carriers = 0
            try:
                procs = [self.root] + self.root.children(recursive=True)
            except psutil.Error:
                procs = []
            for proc in procs:
                try:
                    rss = proc.memory_info().rss
                    cmd = proc.cmdline()
                    times = proc.cpu_times()
                except psutil.Error:
                    continue
                role = ("carrier" if "carrier" in cmd and "--role" in cmd else
                        "coordinator" if "coordinator" in cmd else "router" if "router" in cmd else "launcher")
                total += rss
                carriers += rss if role == "carrier" else 0
                old = self.peak.get(proc.pid, (0, role))[0]
                self.peak[proc.pid] = (max(old, rss), role)
                self.cpu[proc.pid] = (times.user + times.system, role)
            self.peak_total = max(self.peak_total, total)
            self.peak_carriers = max(self.peak_carriers, carriers)
            self.series.append((time.time(), *(sum(v for v, role in self.cpu.values() if role == which)
                                               for which in ROLES)))
            self._stop.wait(self.period_s)

    def cpu_between(self, start: float, end: float, role: str = "carrier") -> float:
        """The CPU seconds of the processes of ``role`` (one of :data:`ROLES`) between two
        ``time.time()`` instants (linear between samples)."""
        if len(self.series) < 2:
            return 0.0
        times, *by_role = zip(*self.series)
        cpu = by_role[ROLES.index(role)]
        return float(np.interp(end, times, cpu) - np.interp(start, times, cpu))

    def stop(self):
        self._stop.set()
        self._thread.join(5)


def message_counts(db: Path, n_carriers: int) -> dict:
    """Messages of a run from its mission.db: those the coordinator received (Hello,
    Observation, Confirm, Bye) and those delivered to carriers (each Decision to every carrier)."""
    with sqlite3.connect(str(db)) as con:
        kinds = dict(con.execute("SELECT kind, COUNT(*) FROM events GROUP BY kind").fetchall())
        first, last = con.execute("SELECT MIN(wall_time), MAX(wall_time) FROM events "
                                  "WHERE kind IN ('observation', 'confirm')").fetchone()
    received = sum(kinds.get(k, 0) for k in ("hello", "observation", "confirm", "bye"))
    decisions = kinds.get("published", 0)
    return {"received": received, "decisions": decisions, "delivered": decisions * n_carriers,
            "first": first, "last": last, "span_s": (last - first) if first is not None else 0.0}


#: Start-up waits of the benchmark's fleets (the sim clock's other waits need no setting): up to
#: 16 carrier processes and the coordinator loading at once on two cores take longer than the
#: defaults to be there.
START_FLAGS = ("--join-timeout", "300", "--coordinator-timeout", "120")


def offline_reference(path: Path, workers: int = 0):
    """What the fleet must reproduce: ``(x, result)``, the fault-free observations
    (``world.observe_all``; the carriers' physics spread over ``workers`` processes, default one
    per core) and ``planner.online.run_online`` with the scenario's planner over them."""
    import os

    import world

    result, x = world.offline_mission(world.load_scenario(path), workers=workers or os.cpu_count() or 1)
    return x, result


def fidelity(summary: dict, x: np.ndarray, reference) -> dict:
    """Whether the fleet made exactly the offline decisions (and saw the offline observations),
    and its reward as a fraction of the offline reward."""
    seen = np.array([[np.nan if v is None else v for v in row] for row in summary["observations"]], dtype=float)
    deployed = np.zeros(reference.deployed.shape, dtype=bool)
    for r, carrier in enumerate(summary["carriers"]):
        for dep in carrier["deployments"]:
            deployed[r, dep["stage"]] = True
    same = bool(np.array_equal(seen, x, equal_nan=True) and np.array_equal(deployed, reference.deployed))
    return {"identical": same, "offline_reward": reference.reward,
            "reward_ratio": summary.get("total_reward", 0.0) / reference.reward if reference.reward else None,
            "empty_observations": int(np.sum(np.isnan(seen) & ~np.isnan(x)))}


class BusyHost:
    """``n`` busy processes (pure CPU, normal priority) while the block runs: a saturated host."""

    def __init__(self, n: int):
        self.n = n
        self.procs: list[subprocess.Popen] = []

    def __enter__(self):
        self.procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(self.n)]
        return self

    def __exit__(self, *exc):
        for proc in self.procs:
            proc.kill()
        for proc in self.procs:
            proc.wait()


def run_one(n_carriers: int, out: Path, seed: int, processes: int | None, planner: str,
            timeout_s: float, quiet: bool = True, carrier_flags=(), family: str = "grid", busy: int = 0,
            check: bool = True) -> dict:
    name = f"{family}_{n_carriers}" + (f"_busy{busy}" if busy else "")
    scen = write_scenario(n_carriers, out / f"{name}.yaml", seed, planner, family)
    run_dir = out / name
    k = processes or default_processes(n_carriers)
    argv = [sys.executable, str(ROOT / "run_fleet.py"), str(scen), "--out", str(run_dir), "--no-map",
            "--carrier-processes", str(k), *START_FLAGS, *carrier_flags]
    started = time.monotonic()
    load_before = os.getloadavg()[0]
    with BusyHost(busy):
        proc = subprocess.Popen(argv, stdout=subprocess.PIPE if quiet else None, stderr=subprocess.STDOUT, text=True)
        sampler = TreeSampler(proc.pid)
        try:
            output, _ = proc.communicate(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            proc.terminate()
            output, _ = proc.communicate(timeout=60)
        finally:
            sampler.stop()
    wall = time.monotonic() - started
    # The host's 1-minute load average before and at the end of the run: the timing columns
    # depend on it (a shared host), the fidelity columns must not.
    row = {"R": n_carriers, "family": family, "busy": busy, "processes": k,
           "load": max(load_before, os.getloadavg()[0]),
           "carriers": " ".join(carrier_flags) or "hybrid", "returncode": proc.returncode, "wall_s": wall,
           "mem_total_mb": sampler.peak_total / 1e6, "mem_carriers_mb": sampler.peak_carriers / 1e6,
           "mem_per_carrier_mb": sampler.peak_carriers / 1e6 / n_carriers,
           "routers": sum(1 for _, role in sampler.peak.values() if role == "router"),
           "mem_coordinator_mb": max((v for v, role in sampler.peak.values() if role == "coordinator"),
                                     default=0) / 1e6,
           "mem_carrier_process_mb": max((v for v, role in sampler.peak.values() if role == "carrier"),
                                         default=0) / 1e6,
           "cpu_carriers_s": sum(v for v, role in sampler.cpu.values() if role == "carrier"),
           "cpu_coordinator_s": sum(v for v, role in sampler.cpu.values() if role == "coordinator"),
           "cpu_routers_s": sum(v for v, role in sampler.cpu.values() if role == "router")}
    summary_path = run_dir / "summary.json"
    if summary_path.exists():
        s = json.loads(summary_path.read_text())
        # The clairvoyant bound is left out (null) where it would not fit its budget.
        lat, plan, bound = s.get("latency_ms") or {}, s.get("planning_ms") or {}, s.get("clairvoyant") or {}
        counts = message_counts(run_dir / "mission.db", n_carriers)
        stages = s.get("stages_decided") or 1
        row.update({
            "mission_s": s.get("wall_time_s"), "stages_decided": s.get("stages_decided"),
            "rtt_p50_ms": lat.get("p50"), "rtt_p99_ms": lat.get("p99"), "rtt_count": lat.get("count"),
            "decision_mean_ms": plan.get("mean"), "decision_max_ms": plan.get("max"),
            "messages": counts["received"] + counts["delivered"],
            "messages_per_s": (counts["received"] + counts["delivered"]) / max(1e-9, s.get("wall_time_s") or wall),
            "reward": s.get("total_reward"), "bound": bound.get("reward"), "bound_exact": bound.get("exact"),
            "fraction": bound.get("fraction"),
            "rejected": sum(s.get("rejected", {}).get("coordinator", {}).values()),
            "carrier_cpu_ms": row["cpu_carriers_s"] * 1e3 / max(1, n_carriers * stages),
            # No idle waiting: a stage's wall time against the work in it (the carriers' CPU
            # spread over the cores, plus the planner's time).
            "stage_wall_s": (s.get("wall_time_s") or wall) / stages,
            "stage_work_s": row["cpu_carriers_s"] / stages / (os.cpu_count() or 1) + (plan.get("mean") or 0) / 1e3,
        })
        row["idle_ratio"] = row["stage_wall_s"] / max(1e-9, row["stage_work_s"])
        # The same ratio over the stage loop only (first Observation to last Confirm, from
        # mission.db, and the carriers' CPU in that window): the whole run's figure above also
        # holds the processes' start, the join and the summary's bound, which are not stages.
        # loop_cpu_ratio also counts the coordinator's CPU outside planning (decoding, the state,
        # mission.db, mission.mcap) and the routers', which the carriers' CPU and planning leave
        # out: near 1, no core waited while there was fleet work to do.
        if counts["first"] is not None:
            cores, plan_s = os.cpu_count() or 1, (plan.get("mean") or 0) / 1e3
            loop_cpu = sampler.cpu_between(counts["first"], counts["last"])
            coordinator_cpu = sampler.cpu_between(counts["first"], counts["last"], "coordinator")
            routers_cpu = sampler.cpu_between(counts["first"], counts["last"], "router")
            row["loop_stage_s"] = counts["span_s"] / stages
            row["loop_work_s"] = loop_cpu / stages / cores + plan_s
            row["loop_idle_ratio"] = row["loop_stage_s"] / max(1e-9, row["loop_work_s"])
            row["loop_coordinator_cpu_s"] = coordinator_cpu / stages
            row["loop_routers_cpu_s"] = routers_cpu / stages
            row["loop_busy_s"] = ((loop_cpu + routers_cpu) / stages + max(0.0, coordinator_cpu / stages - plan_s)) \
                / cores + plan_s
            row["loop_cpu_ratio"] = row["loop_stage_s"] / max(1e-9, row["loop_busy_s"])
        if check:
            x, reference = offline_reference(scen)
            row.update({f"fidelity_{k}" if k != "identical" else "fidelity": v
                        for k, v in fidelity(s, x, reference).items()})
    if not quiet or proc.returncode != 0:
        print((output or "")[-3000:], file=sys.stderr)
    return row


COLUMNS = (("family", "{}"), ("busy", "{:d}"), ("load", "{:.0f}"), ("R", "{:d}"), ("processes", "{:d}"), ("carriers", "{}"), ("wall_s", "{:.1f}"), ("mem_total_mb", "{:.0f}"),
           ("mem_per_carrier_mb", "{:.1f}"), ("mem_coordinator_mb", "{:.0f}"), ("rtt_p50_ms", "{:.0f}"),
           ("rtt_p99_ms", "{:.0f}"), ("decision_mean_ms", "{:.0f}"), ("decision_max_ms", "{:.0f}"),
           ("messages_per_s", "{:.0f}"), ("carrier_cpu_ms", "{:.1f}"), ("idle_ratio", "{:.2f}"),
           ("loop_idle_ratio", "{:.2f}"), ("loop_cpu_ratio", "{:.2f}"),
           ("fidelity", "{}"), ("fidelity_reward_ratio", "{:.3f}"), ("fraction", "{:.2f}"), ("bound_exact", "{}"))


def table(rows) -> str:
    head = "| " + " | ".join(name for name, _ in COLUMNS) + " |"
    lines = [head, "|" + "---|" * len(COLUMNS)]
    for row in rows:
        cells = []
        for name, fmt in COLUMNS:
            value = row.get(name)
            cells.append("-" if value is None else fmt.format(value))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def plot(rows, path: Path) -> None:
    """Cost and fidelity against R, one line per (family, busy processes)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [r for r in rows if r.get("rtt_p99_ms") is not None]
    series: dict[tuple, list] = {}
    for row in rows:
        series.setdefault((row.get("family", "grid"), row.get("busy", 0)), []).append(row)
    fig, axes = plt.subplots(1, 4, figsize=(17, 3.9))
    for (family, busy), group in sorted(series.items()):
        group = sorted(group, key=lambda row: row["R"])
        r = [row["R"] for row in group]
        label = f"{family}{', %d busy' % busy if busy else ''}"
        axes[0].loglog(r, [row["wall_s"] for row in group], "o-", label=f"{label}: wall (s)")
        axes[0].loglog(r, [row["mem_total_mb"] / 1e3 for row in group], "s--", label=f"{label}: memory (GB)")
        axes[1].loglog(r, [row["rtt_p99_ms"] for row in group], "o-", label=f"{label}: round trip p99 (ms)")
        axes[1].loglog(r, [max(1e-3, row["decision_mean_ms"]) for row in group], "^--", label=f"{label}: decision (ms)")
        axes[2].semilogx(r, [row.get("idle_ratio") or float("nan") for row in group], "o-", label=f"{label}: run")
        axes[2].semilogx(r, [row.get("loop_idle_ratio") or float("nan") for row in group], "s--",
                         label=f"{label}: stage loop")
        axes[3].semilogx(r, [row.get("fidelity_reward_ratio") or float("nan") for row in group], "o-",
                         label=label + " (decisions identical)" * all(row.get("fidelity") for row in group))
    axes[0].set_title("whole run")
    axes[1].set_title("per stage")
    axes[2].set_title("stage wall / (carrier CPU / cores + planning)")
    axes[2].axhline(1.3, color="grey", ls=":", lw=1)
    axes[3].set_title("fleet reward / offline reward")
    axes[3].set_ylim(0.0, 1.1)
    for ax in axes:
        ax.set_xlabel("carriers R")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m tools.scale", description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", default=",".join(map(str, SIZES)), help="carrier counts, comma-separated")
    p.add_argument("--family", action="append", choices=sorted(FAMILIES),
                   help="scenario family (repeatable; default grid): grid (tools.scale's street grid, 10 s "
                        "stages) or long-streets (physics-heavy: 480 s of driving per carrier and stage)")
    p.add_argument("--busy", default="0", metavar="N[,N...]",
                   help="also run each size with N busy processes on the host (comma-separated; 0 = an idle "
                        "host; e.g. 0,4 = idle and saturated on two cores; default 0)")
    p.add_argument("--no-fidelity", action="store_true",
                   help="skip the offline reference (world.observe_all + run_online, the physics spread over "
                        "the cores) that the fidelity columns compare with")
    p.add_argument("--seed", type=int, default=1, help="scenario seed (default 1)")
    p.add_argument("--processes", type=int, help="carrier processes per run (default: see default_processes)")
    p.add_argument("--planner", default="closed-loop", help="planner of the generated scenarios")
    p.add_argument("--out", default="runs/scale", help="results directory")
    p.add_argument("--timeout", type=float, default=1200.0, help="per run (s)")
    p.add_argument("--plot", metavar="PNG", help="write a plot of cost against R")
    p.add_argument("--write-scenario", nargs=2, metavar=("R", "PATH"), help="only write one scenario file")
    p.add_argument("--no-autonomy", action="store_true",
                   help="carriers that never decide on board (run_fleet.py --no-autonomy): no planner "
                        "core in the carrier processes, no listening to other carriers")
    p.add_argument("--merge", metavar="JSON",
                   help="also merge this run's rows into JSON (docs/results/fidelity_scale.json): a row "
                        "replaces the one of the same family, R, busy count and carrier flags; each row keeps "
                        "its 'measured' date; the .csv beside it and --plot are written from the merged rows")
    p.add_argument("--verbose", action="store_true", help="show each run's output")
    args = p.parse_args(argv)
    families = args.family or ["grid"]
    if args.write_scenario:
        write_scenario(int(args.write_scenario[0]), Path(args.write_scenario[1]), args.seed, args.planner, families[0])
        return 0
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for family in families:
        for n in (int(s) for s in args.sizes.split(",") if s):
            for busy in (int(b) for b in args.busy.split(",") if b):
                row = run_one(n, out, args.seed, args.processes, args.planner, args.timeout, quiet=not args.verbose,
                              carrier_flags=("--no-autonomy",) if args.no_autonomy else (), family=family,
                              busy=busy, check=not args.no_fidelity)
                row["measured"] = time.strftime("%Y-%m-%d")
                rows.append(row)
                print(table([row]).splitlines()[-1] if len(rows) > 1 else table([row]), flush=True)
                (out / "scale.json").write_text(json.dumps(rows, indent=2))
    write_csv(rows, out / "scale.csv")
    print()
    print(table(rows))
    shown = rows
    if args.merge:
        shown = merge_rows(Path(args.merge), rows)
        print(f"merged into {args.merge} ({len(shown)} rows)")
    if args.plot:
        plot(shown, Path(args.plot))
    return 0 if all(row.get("returncode") == 0 for row in rows) else 1


def write_csv(rows, path: Path) -> None:
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=sorted({k for row in rows for k in row}))
        writer.writeheader()
        writer.writerows(rows)


def merge_rows(path: Path, new_rows) -> list:
    """The rows of ``path`` (a scale.json) with ``new_rows`` in place of those of the same family,
    R, busy count and carrier flags (new ones appended), sorted; written back to ``path`` and to
    the .csv beside it."""
    def key(row):
        return (row.get("family", "grid"), row["R"], row.get("busy", 0), row.get("carriers", "hybrid"))

    merged = {key(row): row for row in (json.loads(path.read_text()) if path.exists() else [])}
    merged.update((key(row), row) for row in new_rows)
    rows = [merged[k] for k in sorted(merged)]
    path.write_text(json.dumps(rows, indent=2))
    write_csv(rows, path.with_suffix(".csv"))
    return rows


if __name__ == "__main__":
    sys.exit(main())
