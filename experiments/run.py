"""Reproduce the paper's experiments: overlap sweep, scaling sweep, Urban Circuit run.

Usage::

    python -m experiments all                      # everything at the paper's settings
    python -m experiments overlap --trials 50 --iterations 10000 --jobs 2
    python -m experiments scaling --carriers 2,3,4,5,6,12,24,32
    python -m experiments urban --urban-trials 10
    python -m experiments all --quick --out /tmp/results   # smoke test (seconds)
    python -m experiments comms --trials 50 --iterations 10000   # reward against message loss
    python -m experiments priors --trials 20 --iterations 2000   # stated / learned / oracle priors
    python -m experiments types                                  # type-aware vs type-blind (30 trials, 2000 iterations)
    python -m experiments bound                                  # the upper bound against V* and the planners
    python -m experiments coverage                               # coverage-planned vs 1/p-planned, same worlds
    python -m experiments marine --trials 10 --iterations 2000   # the marine family, perfect vs acoustic links
    python -m experiments check                                  # do the committed results come from this code?

``comms``, ``priors`` (experiments.priors), ``types`` (experiments.types), ``bound``
(experiments.bound), ``coverage`` (experiments.coverage) and ``marine`` (experiments.marine) are not
part of ``all``.

Each sweep writes to ``--out`` (default: a fresh folder ``results/<experiment>-<timestamp>`` under
the current directory, ``--quick`` runs a temporary directory, so that a run never overwrites the
committed results; ``--out docs/results`` updates them): ``<sweep>_trials.csv`` (one row per
planner and trial, with the deployments), ``<sweep>_summary.csv`` (mean ± standard error, fraction
of the clairvoyant bound), ``<sweep>.md`` (the tables), ``<sweep>.png`` (±1 SEM error bars), and
``run_info.json`` (settings, wall times). The urban run also draws ``urban_map_<planner>.png``.

Common random numbers: within a trial every planner sees the same instance, the same observations
and the same planner seed (see :mod:`experiments.trials`). Tasks (one planner on one trial) run on a
``spawn`` process pool of ``--jobs`` workers (default: all cores), longest first, or on the
workers of a Dask distributed cluster with ``--cluster tcp://HOST:8786`` (the same tasks, the same
seeds, so the same results; see :func:`cluster_executor`).
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from multiprocessing import get_context
from pathlib import Path

from experiments import bound, cluster, coverage, marine, priors, report, types
from experiments.cluster import UsageError
from experiments.trials import CLAIRVOYANT, Sweep, Task, decode, run_trial, urban_trial, warm_up_worker
from planner.settings import DEFAULT_ITERATIONS
from world.paths import REPO_ROOT as ROOT

#: The results shipped with a clone (docs/results.md links the files there): written only when
#: named by ``--out``; by default a run writes a fresh folder under the current directory
#: (:func:`fresh_out`), so it never overwrites them.
SHIPPED_OUT = ROOT / "docs" / "results"
#: How ``--help`` names the default.
DEFAULT_OUT_SHOWN = "results/<experiment>-<timestamp> under the current directory"
DEFAULT_SCENARIO = ROOT / "scenarios" / "urban_alpha.yaml"
#: The paper's four planners, plus ours.
DEFAULT_PLANNERS = ("mcts-ssap", "mcts-random", "ssap", "random", "closed-loop")
OVERLAP_LEVELS = (0, 4, 8, 12, 16, 20)
CARRIER_LEVELS = (2, 3, 4, 5, 6, 12, 24, 32)
QUICK = {"trials": 3, "iterations": 300, "overlaps": (0, 10, 20), "carriers": (2, 4, 8), "urban_trials": 2,
         "losses": (0.0, 0.5, 1.0)}
#: The comms experiment: message-loss levels, and (sweep name, carriers, overlaps) configurations.
LOSS_LEVELS = (0.0, 0.25, 0.5, 0.75, 0.9, 1.0)
COMMS_CONFIGS = (("comms-r4", 4, 20), ("comms-r6", 6, 10))
#: Planners of the comms experiment: centralised (with their fallback), decentralised, SSAP.
COMMS_PLANNERS = ("dec-closed-loop", "dec-mcts", "closed-loop", "mcts-ssap", "ssap")
#: The paper's Urban Circuit result (features captured): MCTS-SSAP, SSAP, MCTS-Random, Random.
PAPER_URBAN = {"mcts-ssap": 157, "ssap": 122, "mcts-random": 114, "random": 68}


#: How each sweep's tasks run (experiments.trials.run_trial): its trial builder and hooks.
SWEEPS: dict[str, Sweep] = {
    "overlap": Sweep(), "scaling": Sweep(), "urban": Sweep(urban_trial),
    **{name: Sweep(comms=True) for name, _, _ in COMMS_CONFIGS},
    "priors": priors.SWEEP, "types": types.SWEEP,
}


def run_task(task: Task) -> dict:
    """Run one task (in this process or a worker): :func:`experiments.trials.run_trial` with the
    task's sweep from :data:`SWEEPS`."""
    if task.sweep in ("bound", "bound-tiny"):
        return bound.run_task(task)
    if task.sweep == "coverage":
        return coverage.run_task(task)
    if task.sweep == "marine":
        return marine.run_task(task)
    return run_trial(task, SWEEPS[task.sweep])


#: Default output of --quick runs (never the committed results).
QUICK_OUT = Path(tempfile.gettempdir()) / "marsupial-experiments-quick"


def fresh_out(what: str) -> Path:
    """A new folder ``results/<what>-<YYYYmmdd-HHMMSS>`` under the current directory (``-2``,
    ``-3``, ... when one of that name exists)."""
    base = Path("results") / f"{what}-{time.strftime('%Y%m%d-%H%M%S')}"
    out, k = base, 1
    while out.exists():
        k += 1
        out = base.with_name(f"{base.name}-{k}")
    return out


def paper_scenario(path: Path) -> bool:
    """Whether ``path`` is the paper's Urban Circuit scenario (the only one the paper's column
    compares with)."""
    try:
        return Path(path).resolve() == DEFAULT_SCENARIO.resolve() or \
            Path(path).read_bytes() == DEFAULT_SCENARIO.read_bytes()
    except OSError:
        return False


def _int_list(text: str, what: str, minimum: int) -> tuple[int, ...]:
    try:
        values = tuple(int(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise UsageError(f"--{what}: expected comma-separated integers, found {text!r}") from None
    if not values or min(values) < minimum:
        raise UsageError(f"--{what}: expected integers >= {minimum}, found {text!r}")
    return values


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m experiments", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog="python -m experiments check [--help]: re-run a seeded sample of a results "
                                       "directory's tasks and compare them with its rows (experiments.check)")
    p.add_argument("what", nargs="?", default="all", choices=("overlap", "scaling", "urban", "comms", "all", "priors", "types", "bound",
                                              "coverage", "marine"),
                   help="which experiment (default: all)")
    p.add_argument("--trials", type=int, default=None, help="trials per level (default 50; quick 3)")
    p.add_argument("--iterations", type=int, default=None,
                   help=f"planning budget per decision: MCTS iterations (default {DEFAULT_ITERATIONS}; quick 300)")
    p.add_argument("--seed", type=int, default=0, help="root seed (default 0)")
    p.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="worker processes (default: all cores)")
    p.add_argument("--cluster", default=None, metavar="ADDRESS",
                   help="run the tasks on a Dask distributed scheduler (e.g. tcp://10.0.0.5:8786) "
                        "instead of a local process pool; --jobs is then ignored")
    p.add_argument("--cluster-timeout", type=float, default=20.0,
                   help="seconds to wait for the --cluster scheduler and its first worker (default 20)")
    p.add_argument("--quick", action="store_true", help="tiny settings for a smoke test")
    p.add_argument("--out", type=Path, default=None,
                   help=f"output directory (default {DEFAULT_OUT_SHOWN}; with --quick {QUICK_OUT})")
    p.add_argument("--planners", default=None,
                   help="comma-separated planner names (the clairvoyant bound is always added; default: the "
                        "paper's four and closed-loop, or for comms: " + ",".join(COMMS_PLANNERS) + ")")
    p.add_argument("--losses", default=None,
                   help="message-loss levels of the comms experiment (default 0,0.25,0.5,0.75,0.9,1)")
    p.add_argument("--message-delay", type=int, default=0, help="message delay (stages) in the comms experiment")
    p.add_argument("--overlaps", default=None,
                   help="overlap levels of the overlap and coverage sweeps (default 0,4,...,20)")
    p.add_argument("--carriers", default=None, help="fleet sizes of the scaling sweep (default 2,...,6,12,24,32) "
                                                    "and of the coverage sweep (default 4,8,16,32,64; quick 4,8)")
    p.add_argument("--scaling-overlaps", type=int, default=10, help="overlaps in the scaling sweep (default 10)")
    p.add_argument("--urban-trials", type=int, default=None, help="world seeds of the urban run (default 20; quick 2)")
    p.add_argument("--scenario", type=Path, default=DEFAULT_SCENARIO, help="scenario of the urban run")
    p.add_argument("--bound-method", choices=bound.BOUND_METHODS, default=bound.BOUND_METHODS[0],
                   help="inner maxima of the bound sweep's scale rows: mixed-root (default): up to R = 128 "
                        "(experiments.bound.MIXED_MAX_CARRIERS; --quick: R = 6) exact per component where it "
                        "fits, else the MIP (adaptive penalty), and beyond the same with every MIP stopped after "
                        "its root node; mixed: the same up to R = 128 and the LP relaxation beyond (the default "
                        "until 2026-12-07); lp: the LP relaxation, fixed penalty, everywhere (looser, faster; the "
                        "default before that)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--report-only", action="store_true",
                   help="rewrite summaries, tables and plots from the CSVs already in --out (no planning)")
    return p.parse_args(argv)


def settings_of(args) -> dict:
    """The settings of a command line (trials, iterations, levels, planners...), checked; raises
    UsageError with one line naming the flag."""
    quick = args.quick
    # The types sweep's defaults keep its default run to a few minutes on two cores.
    full_trials, full_iterations = (30, 2000) if args.what == "types" else (50, DEFAULT_ITERATIONS)
    if args.what == "marine":
        full_trials, full_iterations = marine.DEFAULT_TRIALS, marine.DEFAULT_ITERATIONS
    if args.what == "bound":  # trials per configuration: experiments.bound.CONFIGS unless given
        full_iterations = bound.DEFAULT_ITERATIONS
    trials = args.trials if args.trials is not None else (QUICK["trials"] if quick else full_trials)
    iterations = args.iterations if args.iterations is not None else (QUICK["iterations"] if quick else full_iterations)
    urban_trials = args.urban_trials if args.urban_trials is not None else (QUICK["urban_trials"] if quick else 20)
    if trials < 1:
        raise UsageError(f"--trials: expected an integer >= 1, found {trials}")
    if iterations < 1:
        raise UsageError(f"--iterations: expected an integer >= 1, found {iterations}")
    if urban_trials < 1:
        raise UsageError(f"--urban-trials: expected an integer >= 1, found {urban_trials}")
    if args.seed < 0:
        raise UsageError(f"--seed: expected an integer >= 0, found {args.seed}")
    if args.jobs < 1:
        raise UsageError(f"--jobs: expected an integer >= 1, found {args.jobs}")
    if args.scaling_overlaps < 0:
        raise UsageError(f"--scaling-overlaps: expected an integer >= 0, found {args.scaling_overlaps}")
    overlaps = _int_list(args.overlaps, "overlaps", 0) if args.overlaps else (QUICK["overlaps"] if quick else OVERLAP_LEVELS)
    if args.what == "coverage":
        carrier_defaults = coverage.QUICK_CARRIERS if quick else coverage.CARRIER_LEVELS
    else:
        carrier_defaults = QUICK["carriers"] if quick else CARRIER_LEVELS
    carriers = _int_list(args.carriers, "carriers", 1) if args.carriers else carrier_defaults
    from planner.registry import is_planner, planner_names

    if args.planners is None:
        args.planners = ",".join(COMMS_PLANNERS if args.what == "comms" else DEFAULT_PLANNERS)
    planners = tuple(p.strip() for p in args.planners.split(",") if p.strip())
    if args.what == "priors" and args.planners == ",".join(DEFAULT_PLANNERS):
        planners = priors.DEFAULT_PLANNERS
    if args.what == "types" and args.planners == ",".join(DEFAULT_PLANNERS):
        planners = types.DEFAULT_PLANNERS
    if args.what == "bound" and args.planners == ",".join(DEFAULT_PLANNERS):
        planners = bound.DEFAULT_PLANNERS
    if args.what == "coverage" and args.planners == ",".join(DEFAULT_PLANNERS):
        planners = coverage.DEFAULT_PLANNERS
    if args.what == "marine":  # its arms are fixed (experiments.marine.ARMS)
        planners = tuple(dict.fromkeys(name for _, name in marine.ARMS if name != CLAIRVOYANT))
    if args.losses:
        try:
            losses = tuple(float(v) for v in args.losses.split(",") if v.strip())
        except ValueError:
            losses = ()
        if not losses or not all(0.0 <= v <= 1.0 for v in losses):
            raise UsageError(f"--losses: expected comma-separated probabilities in [0, 1], found {args.losses!r}")
    else:
        losses = QUICK["losses"] if quick else LOSS_LEVELS
    if args.message_delay < 0:
        raise UsageError(f"--message-delay: expected an integer >= 0, found {args.message_delay}")
    unknown = [p for p in planners if not is_planner(p)]
    if unknown or not planners:
        raise UsageError(f"--planners: expected names among {', '.join(planner_names())} or plug-ins (an entry "
                         f"point's name, package.module:Factory), found {args.planners!r}")
    if args.what in ("urban", "all") and not args.scenario.is_file():
        raise UsageError(f"--scenario: expected an existing scenario file, found {str(args.scenario)!r}")
    return {"trials": trials, "iterations": iterations, "urban_trials": urban_trials, "overlaps": overlaps,
            "carriers": carriers, "planners": planners, "seed": args.seed, "losses": losses,
            "delay": args.message_delay, "quick": quick, "bound_trials": args.trials,
            "bound_method": args.bound_method}


def build_tasks(sweep: str, s: dict, args) -> list[Task]:
    """Every (level, trial, planner) task of a sweep; the clairvoyant bound is one more 'planner'."""
    if sweep == "priors":
        return priors.build_tasks(s)
    if sweep == "types":
        return types.build_tasks(s)
    if sweep == "bound":
        return bound.build_tasks(s)
    if sweep == "coverage":
        return coverage.build_tasks(s)
    if sweep == "marine":
        return marine.build_tasks(s)
    names = (*s["planners"], CLAIRVOYANT)
    tasks = []
    if sweep == "overlap":
        for level in s["overlaps"]:
            for t in range(s["trials"]):
                tasks += [Task("overlap", level, t, p, s["seed"], s["iterations"], carriers=4, overlaps=level)
                          for p in names]
    elif sweep == "scaling":
        for level in s["carriers"]:
            for t in range(s["trials"]):
                tasks += [Task("scaling", level, t, p, s["seed"], s["iterations"], carriers=level,
                               overlaps=args.scaling_overlaps) for p in names]
    elif sweep == "comms":
        # Level: message loss in percent. Every planner of a trial sees the same instance, the
        # same observations, the same planner seed and so the same message deliveries.
        for name, carriers, overlaps in COMMS_CONFIGS:
            for loss in s["losses"]:
                for t in range(s["trials"]):
                    tasks += [Task(name, int(round(100 * loss)), t, p, s["seed"], s["iterations"], carriers=carriers,
                                   overlaps=overlaps, loss=loss, delay=s["delay"]) for p in names]
    else:
        for t in range(s["urban_trials"]):
            tasks += [Task("urban", 0, t, p, s["seed"], s["iterations"], carriers=3, stages=19,
                           scenario=str(args.scenario)) for p in names]
    return tasks


def rebuild_settings(sweep: str, s: dict, args) -> dict:
    """What a sweep's run_info.json entry records besides trials, iterations, seed, planners and
    levels so that its task list can be rebuilt (``python -m experiments check``)."""
    if s["quick"]:
        return {"quick": True, **rebuild_settings(sweep, {**s, "quick": False}, args)}
    if sweep == "scaling":
        return {"scaling_overlaps": args.scaling_overlaps}
    if sweep == "comms":
        return {"message_delay": s["delay"]}
    if sweep == "urban":
        scenario = args.scenario.resolve()
        return {"scenario": str(scenario.relative_to(ROOT) if scenario.is_relative_to(ROOT) else scenario)}
    if sweep == "bound":  # a record without bound_method was written when lp was the default
        return {"bound_trials": s["bound_trials"], "bound_method": s["bound_method"]}
    if sweep == "coverage":
        return {"carriers": list(s["carriers"])}
    return {}


def run_tasks(tasks: list[Task], pool, desc: str, progress: bool) -> list[dict]:
    """Run tasks (longest first) on the pool, or in this process when ``pool`` is None."""
    from tqdm import tqdm

    order = sorted(tasks, key=lambda t: -t.cost)
    bar = tqdm(total=len(order), desc=desc, unit="task", disable=not progress, file=sys.stderr,
               dynamic_ncols=True)
    rows = []
    if pool is None:
        for task in order:
            rows.append(run_task(task))
            bar.update()
    else:
        futures = [pool.submit(run_task, task) for task in order]
        for fut in as_completed(futures):
            rows.append(fut.result())
            bar.update()
    bar.close()
    return rows


def local_pool(jobs: int, planners: tuple[str, ...] | None):
    """A ``spawn`` process pool of ``jobs`` workers, every one started with the kernels of
    ``planners`` (None: every registered planner) loaded, so no task is timed while a kernel
    loads; for one job None (tasks run in this process, which is warmed up here)."""
    if jobs <= 1:
        warm_up_worker(planners)
        return None
    pool = ProcessPoolExecutor(max_workers=jobs, mp_context=get_context("spawn"), initializer=warm_up_worker,
                               initargs=(planners,))
    for fut in [pool.submit(time.sleep, 0.5) for _ in range(jobs)]:
        fut.result()
    return pool


def cluster_executor(address: str, timeout_s: float, planners: tuple[str, ...] | None = None):
    """A ``concurrent.futures`` executor running tasks on a Dask distributed cluster
    (:func:`experiments.cluster.connect`), every worker with the planners' compiled kernels
    loaded before any sweep is timed: (client, executor, worker threads); UsageError."""
    return cluster.connect(address, timeout_s, "--cluster", warm_up_worker, planners)


def _write_sweep(sweep: str, rows: list[dict], out: Path, seconds: float, jobs: int, s: dict, args) -> dict:
    if sweep == "priors":
        return priors.write(rows, out, s, seconds, jobs)
    if sweep == "types":
        return types.write(rows, out, s, seconds, jobs)
    if sweep == "bound":
        return bound.write(rows, out, s, seconds, jobs)
    if sweep == "coverage":
        return coverage.write(rows, out, s, seconds, jobs)
    if sweep == "marine":
        return marine.write(rows, out, s, seconds, jobs)
    report.write_trials(rows, out / f"{sweep}_trials.csv")
    summary = report.summarise(rows)
    report.write_summary(summary, out / f"{sweep}_summary.csv")
    if sweep == "comms":
        text = _comms_report(rows, summary, out, s, jobs)
    elif sweep in ("overlap", "scaling"):
        if sweep == "overlap":
            key, x_label, log_x = "overlaps", "number of overlaps", False
            setting = "R = 4 carriers, D = 3, N = 10"
            title = f"Overlap sweep: R = 4, D = 3, N = 10, Poisson(3), {s['trials']} trials, {s['iterations']} iterations"
        else:
            key, x_label, log_x = "R", "carriers R", True
            setting = f"D = 3, N = 10, {args.scaling_overlaps} overlaps"
            title = (f"Scaling sweep: D = 3, N = 10, {args.scaling_overlaps} overlaps, {s['trials']} trials, "
                     f"{s['iterations']} iterations")
        report.plot(summary, out / f"{sweep}.png", x_label, title, log_x=log_x)
        text = [f"## {sweep.capitalize()} sweep", "",
                f"{setting}, Poisson(3) observations, {s['trials']} trials per level, "
                f"{s['iterations']} iterations per decision. Mean normalised reward ± SEM "
                "(mean fraction of the clairvoyant bound).", "",
                report.markdown_table(summary, key), "",
                "Paired differences on the same instances (mean ± SEM, wins/losses):", "",
                report.paired_table(rows, "closed-loop", ["mcts-ssap", "ssap"], key), "",
                report.paired_table(rows, "mcts-ssap", ["mcts-random", "ssap"], key), "",
                f"Mean decision time per stage, ms ({jobs} worker process(es) on {os.cpu_count()} cores, shared with other work):", "",
                report.timing_table(summary, key)]
    else:
        text = _urban_report(rows, summary, out, s, args)
    cpu = {}
    for r in rows:
        cpu[r["planner"]] = cpu.get(r["planner"], 0.0) + float(r["wall_s"])
    timing = {"sweep": sweep, "seconds": round(seconds, 1), "tasks": len(rows), "jobs": jobs,
              "worker_seconds": {k: round(v, 1) for k, v in sorted(cpu.items(), key=lambda kv: report.planner_order(kv[0]))}}
    text += ["", f"Wall time: {seconds:.1f} s with {jobs} worker process(es) for {len(rows)} tasks. "
             "Worker seconds per planner (sum of task run times): "
             + ", ".join(f"{report.STYLE.get(k, (k,))[0]} {v:.0f} s" for k, v in timing["worker_seconds"].items()) + "."]
    (out / f"{sweep}.md").write_text("\n".join(text) + "\n")
    return timing


def _urban_report(rows, summary, out: Path, s: dict, args) -> list[str]:
    import numpy as np
    import world

    scenario = world.load_scenario(args.scenario)
    paper_run = paper_scenario(args.scenario)  # the paper's column only against the paper's scenario
    trace = world.simulate_mission(scenario)
    n_carriers, n_stages = scenario.n_carriers, scenario.stages
    maps = []
    for r in sorted((r for r in rows if r["trial"] == 0), key=lambda r: report.planner_order(r["planner"])):
        deployed = decode(r["deployed"], n_carriers, n_stages)
        name = f"urban_map_{r['planner']}.png"
        label = report.STYLE.get(r["planner"], (r["planner"],))[0]
        world.render_map(scenario, out / name, deployments=deployed, trajectories=trace.trajectories,
                         positions=trace.positions, features=trace.features,
                         title=f"{scenario.name}: {label}, {r['features']:.2f} features captured")
        maps.append(name)
    feats = {p: [r["features"] for r in sorted(rows, key=lambda r: r["trial"]) if r["planner"] == p]
             for p in {r["planner"] for r in rows}}
    lines = ["## Urban run", "",
             f"Scenario `{args.scenario.name}` through the world (`world.observe_all`): "
             f"{n_carriers} carriers with staggered starts, N = {n_stages}, {scenario.conflict_radius:g} m "
             f"conflicts, {s['urban_trials']} world seeds (trial 0 is the scenario's own seed), "
             f"{s['iterations']} iterations. Features captured (sum of x / p), mean ± SEM over seeds."
             + (" The observations are the run's recorded values (`features.replay`, from `python -m world "
                "import --replay`): every world seed observes the same values, and the seeds vary only the "
                "planners' random streams; the maps draw the occupancy grid under the routes."
                if scenario.replays else ""), "",
             *(("| planner | features (mean ± SEM) | seed 0 | paper | ratio to SSAP (ours / paper) "
                "| ratio to Random (ours / paper) |", "|---|---|---|---|---|---|") if paper_run else
               ("| planner | features (mean ± SEM) | seed 0 | ratio to SSAP | ratio to Random |",
                "|---|---|---|---|---|"))]
    seeds_label = lambda _level: f"all {s['urban_trials']}"  # noqa: E731
    base_ssap = np.mean(feats.get("ssap", [np.nan]))
    base_rand = np.mean(feats.get("random", [np.nan]))
    for p in sorted(feats, key=report.planner_order):
        v = np.asarray(feats[p])
        paper = PAPER_URBAN.get(p) if paper_run else None
        r_ssap = (f"{v.mean() / base_ssap:.2f}" if np.isfinite(base_ssap) else "–") + (
            f" / {paper / PAPER_URBAN['ssap']:.2f}" if paper else "")
        r_rand = (f"{v.mean() / base_rand:.2f}" if np.isfinite(base_rand) else "–") + (
            f" / {paper / PAPER_URBAN['random']:.2f}" if paper else "")
        label = report.STYLE.get(p, (p,))[0]
        lines.append(f"| {label} | {report.pm(v.mean(), report.sem(v))} | {v[0]:.2f} | "
                     + (f"{paper if paper else '–'} | " if paper_run else "") + f"{r_ssap} | {r_rand} |")
    lines += ["", "Paired differences in normalised reward on the same world seeds (mean ± SEM, wins/losses):", "",
              report.paired_table(rows, "closed-loop", ["mcts-ssap", "ssap"], "world seeds", seeds_label), "",
              report.paired_table(rows, "mcts-ssap", ["mcts-random", "ssap", "random"], "world seeds", seeds_label), "",
              "Maps of the chosen deployments (seed 0): " + ", ".join(f"[{m}]({m})" for m in maps)]
    return lines


def _comms_report(rows, summary, out: Path, s: dict, jobs: int) -> list[str]:
    """Tables and plots of the comms experiment, one block per configuration."""
    text = ["## Comms sweep", "",
            f"Reward against message loss P (each observation, intent and decision message dropped "
            f"independently with probability P{', delayed ' + str(s['delay']) + ' stage(s)' if s['delay'] else ''}; "
            f"planner/comms.py), D = 3, N = 10, Poisson(3), {s['trials']} paired trials per point, "
            f"{s['iterations']} iterations per decision (per carrier for the decentralised planners). "
            "Centralised planners use their fallback (a carrier whose decision is lost deploys only when "
            "forced). Mean normalised reward ± SEM (mean fraction of the clairvoyant bound); level = P in percent."]
    for name, carriers, overlaps in COMMS_CONFIGS:
        sub = [r for r in summary if r["sweep"] == name]
        rs = [r for r in rows if r["sweep"] == name]
        if not sub:
            continue
        report.plot(sub, out / f"{name}.png", "message loss P (%)",
                    f"R = {carriers}, {overlaps} overlaps, D = 3, N = 10: reward against message loss "
                    f"({s['trials']} trials, {s['iterations']} iterations)")
        text += ["", f"### R = {carriers}, {overlaps} overlaps", "", report.markdown_table(sub, "P (%)"), "",
                 f"![R = {carriers}]({name}.png)", "",
                 "Paired differences on the same trials and deliveries (mean ± SEM, wins/losses):", "",
                 report.paired_table(rs, "dec-closed-loop", ["closed-loop", "mcts-ssap", "dec-mcts", "ssap"], "P (%)"),
                 "", f"Mean decision time per stage, ms ({jobs} worker process(es); decentralised: the slowest carrier):",
                 "", report.timing_table(sub, "P (%)")]
    return text


def _write_index(out: Path, timings: dict) -> None:
    parts = ["# Experiment results", "", "Generated by `python -m experiments`; see docs/results.md for the discussion.", ""]
    for sweep in ("overlap", "scaling", "urban", "comms", "priors"):
        path = out / f"{sweep}.md"
        if path.is_file():
            parts += [path.read_text(), ""]
    (out / "summary.md").write_text("\n".join(parts))


def main(argv=None) -> int:
    args = parse_args(argv)
    try:
        s = settings_of(args)
    except UsageError as err:
        print(f"python -m experiments: error: {err}", file=sys.stderr)
        return 2
    if args.report_only and args.out is None:
        print("python -m experiments: error: --report-only: expected --out DIR (the results to redraw, e.g. "
              "docs/results), found none", file=sys.stderr)
        return 2
    out = args.out if args.out is not None else (QUICK_OUT if args.quick else fresh_out(args.what))
    if out.exists() and not out.is_dir() or any(p.exists() and not p.is_dir() for p in out.parents):
        print(f"python -m experiments: error: --out: expected a results directory (existing or new), found "
              f"{str(out)!r}, a file or under one", file=sys.stderr)
        return 2
    args.out = out
    out.mkdir(parents=True, exist_ok=True)
    sweeps = ("overlap", "scaling", "urban") if args.what == "all" else (args.what,)
    info_path = out / "run_info.json"
    info = json.loads(info_path.read_text()) if info_path.is_file() else {}
    info.setdefault("sweeps", {})
    started = time.perf_counter()
    if args.report_only:
        for sweep in sweeps:
            path = out / f"{sweep}_trials.csv"
            prior = info["sweeps"].get(sweep)
            if not path.is_file() or prior is None:
                print(f"python -m experiments: error: --report-only: expected {path} and its entry in "
                      f"{info_path}, found none", file=sys.stderr)
                return 2
            if sweep == "priors":
                rows = priors.read_trials(path)
            elif sweep == "types":
                rows = types.read_trials(path)
            elif sweep == "bound":
                rows = bound.read_trials(path)
            elif sweep == "coverage":
                rows = coverage.read_trials(path)
            elif sweep == "marine":
                rows = marine.read_trials(path)
            else:
                rows = report.read_trials(path)
            s = {**s, "trials": prior["trials"], "urban_trials": prior["trials"], "iterations": prior["iterations"]}
            _write_sweep(sweep, rows, out, prior["seconds"], prior["jobs"], s, args)
        _write_index(out, info)
        return 0
    pool = client = None
    if args.cluster:
        try:
            client, pool, args.jobs = cluster_executor(args.cluster, args.cluster_timeout, s["planners"])
        except UsageError as err:
            print(f"python -m experiments: error: {err}", file=sys.stderr)
            return 2
        info["cluster"] = {"address": args.cluster, "worker_threads": args.jobs}
    else:
        pool = local_pool(args.jobs, s["planners"])
    info["warm_up_seconds"] = round(time.perf_counter() - started, 1)
    try:
        for sweep in sweeps:
            tasks = build_tasks(sweep, s, args)
            t0 = time.perf_counter()
            rows = run_tasks(tasks, pool, sweep, not args.no_progress)
            seconds = time.perf_counter() - t0
            timing = _write_sweep(sweep, rows, out, seconds, args.jobs, s, args)
            info["sweeps"][sweep] = {**timing, "trials": s["urban_trials"] if sweep == "urban" else s["trials"],
                                     "iterations": s["iterations"], "seed": s["seed"],
                                     "planners": list(s["planners"]),
                                     "levels": list(s["overlaps"] if sweep in ("overlap", "coverage") else
                                                    s["carriers"] if sweep == "scaling" else
                                                    s["losses"] if sweep == "comms" else [0]),
                                     **rebuild_settings(sweep, s, args)}
            info_path.write_text(json.dumps(info, indent=2) + "\n")
            print(f"{sweep}: {len(tasks)} tasks in {seconds:.1f} s -> {out / (sweep + '.md')}", file=sys.stderr)
    finally:
        if client is not None:
            pool.shutdown(wait=False)
            client.close()
        elif pool is not None:
            pool.shutdown(cancel_futures=True)
    info["machine"] = {"cpus": os.cpu_count(), "python": platform.python_version(), "platform": platform.platform()}
    info["last_run_seconds"] = round(time.perf_counter() - started, 1)
    info_path.write_text(json.dumps(info, indent=2) + "\n")
    _write_index(out, info)
    print(f"total {time.perf_counter() - started:.1f} s; results in {out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
