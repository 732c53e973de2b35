"""``python -m mission.simulate SCENARIO --seeds A:B [--faults KINDS|all|none] [--json OUT]``: a
campaign of seeded missions of one scenario in the deterministic simulator (mission/simulate/;
docs/fleet.md, "Deterministic simulation").

Each seed is one mission: its fault schedule, network delays and clocks come from the seed; the
world (features, paths, what each carrier senses) is the scenario's. The invariants are checked
after every event; a seed that breaks one is printed with the command that replays it and its
fault schedule shrunk to a minimal one that still fails.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path

from mission import simulate as sim
from mission.exits import EXIT_USAGE
from mission.modes import Mode

#: Most simulations one shrink may run (each removes a fault or halves one).
SHRINK_RUNS = 40


def build_fleet(path: str, mode: str = Mode.HYBRID, onboard_iterations: int | None = None,
                seed: int | None = None, perfect_links: bool = False, workers: int = 1) -> sim.Fleet:
    """The simulator's :class:`mission.simulate.Fleet` of a scenario file (ScenarioError on bad
    input); ``seed``: the world's root seed instead of the scenario's (run_fleet.py's ``--seed``);
    ``perfect_links``: fly it on perfect links whatever its ``links`` say (a comparison);
    ``workers``: processes for a large fleet's physics (``world.observe_all``)."""
    import numpy as np

    import world
    from planner.registry import make_planner, planner_settings, used_options
    from planner.settings import ONBOARD_PLANNER
    from wire.messages import scenario_fingerprint
    from mission.timeouts import DEFAULTS, over_links
    from wire.sizes import frame_problems, link_sizes
    from world.fleet_links import FleetLinks, latency_bound

    scenario = world.load_scenario(path)
    if perfect_links:
        scenario = dataclasses.replace(scenario, links=dataclasses.replace(scenario.links, model="perfect", params=(),
                                                                           relays=type(scenario.links.relays)()))
    frames = frame_problems(scenario)
    if frames:  # a message the acoustic frame cannot hold is refused here, never lost in flight
        raise world.ScenarioError([p.line(path) for p in frames])
    if scenario.reward == "coverage":  # its carriers send no region counts: refused, not flown wrong
        raise world.ScenarioError([f"{path}: reward: expected penalty (the deterministic simulator does not model "
                                   f"region counts yet), found coverage"])
    if seed is not None:
        scenario = scenario.with_seed(int(seed))
    problem = world.build_problem(scenario)
    name, options = planner_settings(scenario)
    planner = make_planner(name, **used_options(name, options))
    if callable(getattr(planner, "warm_up", None)):
        planner.warm_up(problem)
    onboard = make_planner(ONBOARD_PLANNER, **({} if onboard_iterations is None else {"iterations": onboard_iterations}))
    onboard.warm_up(problem)
    sizes = link_sizes(scenario)
    return sim.Fleet(tuple(scenario.carrier_ids), tuple(int(p) for p in problem.passengers), np.asarray(problem.valid),
                     tuple(float(t) for t in scenario.stage_times()), world.observe_all(scenario, workers=workers), problem, planner,
                     onboard, int(scenario.seed), scenario_fingerprint(scenario), mode,
                     links=FleetLinks(scenario, sizes) if scenario.links.model != "perfect" else None,
                     timeouts=over_links(DEFAULTS, latency_bound(scenario, sizes)))


def parse_seeds(text: str) -> range:
    a, sep, b = text.partition(":")
    try:
        lo, hi = int(a), int(b) if sep else int(a) + 1
    except ValueError:
        raise argparse.ArgumentTypeError(f"--seeds: expected A:B (integers, B > A), found {text!r}") from None
    if hi <= lo or lo < 0:
        raise argparse.ArgumentTypeError(f"--seeds: expected A:B with 0 <= A < B, found {text!r}")
    return range(lo, hi)


def parse_kinds(text: str) -> tuple[str, ...]:
    if text == "all":
        return sim.FAULT_KINDS
    if text == "none":
        return ()
    kinds = tuple(k.strip() for k in text.split(",") if k.strip())
    bad = [k for k in kinds if k not in sim.FAULT_KINDS]
    if bad or not kinds:
        raise argparse.ArgumentTypeError(f"--faults: unknown kind(s) {', '.join(bad) or text!r}; expected all, none "
                                         f"or a comma-separated list of {', '.join(sim.FAULT_KINDS)}")
    return kinds


def parse_schedule(text: str, ids=None) -> tuple[sim.Fault, ...]:
    """``--schedule``: a schedule file, or its JSON inline (what a shrunk failure prints);
    :class:`mission.simulate.schedule.ScheduleError` naming the file, the fault and the field."""
    from mission.simulate import schedule

    if text.lstrip().startswith("["):
        try:
            data = json.loads(text)
        except ValueError as exc:
            raise schedule.ScheduleError(f"--schedule: not JSON ({exc})") from None
        return schedule.parse(data, "--schedule", ids)
    return schedule.load(text, ids)


def mission_json(fleet: sim.Fleet, seed: int, kinds, faults=None, plant=None) -> dict:
    """One mission's report (a row of ``per_seed``): :meth:`mission.simulate.Outcome.as_json`, its
    faults with the mission points each struck and ended at (:func:`mission.simulate.schedule.with_points`)."""
    from mission.simulate import schedule

    s = sim.Simulation(fleet, seed, faults=faults, kinds=kinds, plant=plant)
    out = s.run().as_json()
    out["faults"] = schedule.with_points(s.faults, s.decided_at, s.accepted_at, s.started_at)
    return out


def shrink(fleet: sim.Fleet, seed: int, faults, plant=None) -> tuple:
    """A minimal fault schedule that still breaks an invariant: faults removed one at a time,
    then each one's window halved, while the mission still fails (at most :data:`SHRINK_RUNS`)."""
    faults, runs = list(faults), 0

    def fails(candidate) -> bool:
        nonlocal runs
        runs += 1
        return bool(sim.simulate(fleet, seed, faults=tuple(candidate), plant=plant).violations)

    changed = True
    while changed and runs < SHRINK_RUNS:
        changed = False
        for k in range(len(faults)):
            candidate = faults[:k] + faults[k + 1:]
            if runs < SHRINK_RUNS and fails(candidate):
                faults, changed = candidate, True
                break
    for k in range(len(faults)):
        while runs < SHRINK_RUNS and faults[k].until - faults[k].at > 0.5:
            f = faults[k]
            half = sim.Fault(f.kind, f.at, f.at + (f.until - f.at) / 2, f.who, f.size)
            if not fails(faults[:k] + [half] + faults[k + 1:]):
                break
            faults[k] = half
    return tuple(faults)


def replay_command(scenario: str, seed: int, kinds, faults=None, plant=None) -> str:
    base = f"python -m mission.simulate {scenario} --seeds {seed}:{seed + 1}"
    base += " --faults " + (",".join(kinds) if kinds else "none")  # the draws a schedule replays after
    if faults is not None:
        base += " --schedule '" + json.dumps([f.as_json() for f in faults]) + "'"
    return base + (f" --plant {plant}" if plant else "")


_FLEET: sim.Fleet | None = None  # a worker's fleet (inherited from the parent by fork)
_BUILT: dict = {}  # a cluster worker's fleets, by the arguments that built them

#: Seeds per task on a cluster (one task per seed would cost the scheduler more than the missions).
CLUSTER_CHUNK = 25


def _one(args) -> dict:
    seed, kinds, schedule, plant = args
    return mission_json(_FLEET, seed, kinds, schedule, plant)


def _chunk(build: tuple, tasks: list) -> list[dict]:
    """A cluster worker's missions: the fleet built once per worker from ``build`` (the arguments
    of :func:`build_fleet`; the scenario file read where the worker runs), then the seeds."""
    fleet = _BUILT.get(build)
    if fleet is None:
        fleet = _BUILT[build] = build_fleet(*build)
    return [mission_json(fleet, seed, kinds, schedule, plant) for seed, kinds, schedule, plant in tasks]


def _cpu() -> float:
    """CPU seconds of this process and its reaped workers (what the campaign costs, whatever else
    runs on the machine)."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def _on_cluster(executor, build: tuple, tasks: list):
    """The missions of ``tasks`` run on a cluster's executor, in seed order."""
    chunks = [tasks[k:k + CLUSTER_CHUNK] for k in range(0, len(tasks), CLUSTER_CHUNK)]
    for rows in executor.map(_chunk, [build] * len(chunks), chunks):
        yield from rows


def campaign(fleet: sim.Fleet, seeds, kinds, schedule=None, plant=None, progress=None, jobs: int = 1,
             cluster=None) -> dict:
    """Run every seed (``jobs`` worker processes, or ``cluster``: (executor, the arguments of
    :func:`build_fleet` each cluster worker builds its fleet with); each seed's mission the same
    in any); the report's figures (the keys of ``--json``). On a cluster ``cpu_seconds`` counts
    this process only."""
    global _FLEET
    t0, cpu0 = time.perf_counter(), _cpu()
    tasks = [(seed, tuple(kinds), schedule, plant) for seed in seeds]
    _FLEET = fleet
    pool = None
    if cluster is not None:
        results = _on_cluster(cluster[0], cluster[1], tasks)
    elif jobs > 1:
        import multiprocessing

        pool = multiprocessing.get_context("fork").Pool(jobs)
        results = pool.imap(_one, tasks, chunksize=max(1, min(50, len(tasks) // (8 * jobs))))
    else:
        results = map(_one, tasks)
    per_seed, violations, events = [], [], 0
    try:
        for k, out in enumerate(results):
            events += out["events"]
            per_seed.append(out)
            violations += [{"seed": out["seed"], "violation": line} for line in out["violations"]]
            if progress is not None:
                progress(k + 1, len(tasks), out)
        if pool is not None:
            pool.close()
            pool.join()  # reaped: their CPU time counts in os.times()
    finally:
        if pool is not None:
            pool.terminate()
    seconds, cpu = time.perf_counter() - t0, _cpu() - cpu0
    return {"missions": len(per_seed), "events": events, "seconds": round(seconds, 3), "cpu_seconds": round(cpu, 3),
            "missions_per_s": round(len(per_seed) / seconds, 2) if seconds else None,
            "events_per_s": round(events / seconds, 1) if seconds else None,
            "violations": violations, "per_seed": per_seed}


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m mission.simulate", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scenario", help="a scenario file")
    p.add_argument("--seeds", type=parse_seeds, default=range(0, 100), help="A:B: missions with seeds A..B-1 (0:100)")
    p.add_argument("--faults", type=parse_kinds, default=sim.FAULT_KINDS,
                   help="all (default), none, or a comma-separated list of: " + ", ".join(sim.FAULT_KINDS))
    p.add_argument("--schedule", default=None, metavar="FILE|JSON",
                   help="a schedule file (a JSON list of faults: the faults of a seed in --json) or the list "
                        "inline (what a shrunk failure prints), to use instead of drawing them")
    p.add_argument("--mode", choices=(Mode.HYBRID.value, Mode.COORDINATED.value), default=Mode.HYBRID.value,
                   help="the carriers' mode")
    p.add_argument("--plant", choices=sim.PLANTS, default=None,
                   help="put back a known bug class (the campaign's power test); never for real use")
    p.add_argument("--json", dest="json_out", type=Path, default=None, help="write the report as JSON here")
    p.add_argument("--jobs", type=int, default=1, help="worker processes (the missions are the same with any)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="run the missions on a Dask distributed scheduler (e.g. tcp://10.0.0.5:8786) instead of "
                        "--jobs local processes: the same missions, the same trace hashes")
    p.add_argument("--scheduler-timeout", type=float, default=20.0,
                   help="seconds to wait for the --scheduler and its first worker (default 20)")
    p.add_argument("--onboard-iterations", type=int, default=None,
                   help="the on-board planner's iteration budget (default: its own); a campaign of large "
                        "fleets lowers it: the invariants do not depend on how well carriers decide alone")
    p.add_argument("--perfect-links", action="store_true",
                   help="fly the scenario on perfect links whatever its links say (to compare with its link model)")
    p.add_argument("--no-shrink", action="store_true", help="do not shrink the failing schedules")
    p.add_argument("--quiet", action="store_true", help="no progress line")
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    from mission.simulate.schedule import ScheduleError
    from world import ScenarioError

    try:
        if args.schedule is not None:  # its form first: refused before the fleet's seconds of building
            parse_schedule(args.schedule)
        fleet = build_fleet(args.scenario, args.mode, args.onboard_iterations, perfect_links=args.perfect_links,
                            workers=args.jobs)
        if args.schedule is not None:  # then its carrier ids
            args.schedule = parse_schedule(args.schedule, fleet.ids)
    except (ScenarioError, ScheduleError, OSError) as exc:
        print(f"python -m mission.simulate: {exc}", file=sys.stderr)
        return EXIT_USAGE

    def progress(done: int, total: int, out) -> None:
        if not args.quiet and (done == total or done % max(1, total // 20) == 0):
            print(f"  {done}/{total} missions, {out['events']} events in the last, "
                  f"{len(out['violations'])} violation(s) in the last", file=sys.stderr, end="\r" if done < total else "\n")

    client = cluster = None
    if args.scheduler:
        from experiments.cluster import UsageError, connect

        build = (str(Path(args.scenario).resolve()), args.mode, args.onboard_iterations, None, args.perfect_links)
        try:
            client, executor, _ = connect(args.scheduler, args.scheduler_timeout, "--scheduler")
        except UsageError as exc:
            print(f"python -m mission.simulate: {exc}", file=sys.stderr)
            return EXIT_USAGE
        cluster = (executor, build)
    try:
        report = campaign(fleet, args.seeds, args.faults, args.schedule, args.plant, progress, max(1, args.jobs),
                          cluster)
    finally:
        if client is not None:
            client.close()
    failing = sorted({v["seed"] for v in report["violations"]})
    for seed in failing[:5]:
        row = next(r for r in report["per_seed"] if r["seed"] == seed)
        print(f"seed {seed}: {row['violations'][0]}")
        print(f"  replay: {replay_command(args.scenario, seed, args.faults, args.schedule, args.plant)}")
        if not args.no_shrink:
            faults = parse_schedule(json.dumps(row["faults"]))
            small = shrink(fleet, seed, faults, args.plant)
            print(f"  shrunk to {len(small)} fault(s): {replay_command(args.scenario, seed, args.faults, small, args.plant)}")
    hashes = [r["trace_hash"] for r in report["per_seed"]]
    print(f"{report['missions']} missions, {report['events']:,} events in {report['seconds']:.1f} s "
          f"({report['missions_per_s']} missions/s, {report['events_per_s']:,} events/s); "
          f"{len(report['violations'])} violation(s) in {len(failing)} seed(s); "
          f"trace {hashes[0] if len(hashes) == 1 else sim.combined_hash(hashes)}")
    if args.json_out is not None:
        args.json_out.parent.mkdir(parents=True, exist_ok=True)
        args.json_out.write_text(json.dumps(report, indent=1) + "\n")
    return 1 if failing else 0
