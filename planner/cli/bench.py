"""Benchmark of the MCTS planners: speed, memory, decision quality, time budgets, warm start.

    python -m planner.cli.bench [--quick] [--sizes 2,4,6,12,32] [--instances K]
                                [--reference-instances M] [--iterations I]

Prints, for each fleet size R (D = 3 passengers, N = 10 stages, 10 overlaps, Poisson(3) prior,
instances from :func:`planner.instance.random_instance` with fixed seeds):

* speed at stage 0 with ``--iterations`` (10,000; 2,000 with ``--quick``) iterations: iterations per second, median and
  p95 decision time, peak memory of one decision (tracemalloc: every numpy allocation the planner
  makes, tree and scratch included), for ``mcts-ssap`` and, where feasible (R <= 6), for the
  plain reference implementation (:mod:`planner.mcts.reference`) measured in the same run; the
  speed-up pairs the reference's decisions with the fast planner's on the same instances and
  seeds (median of the per-decision ratios, wall and thread CPU time; both planners prepared
  with ``warm_up(problem)`` or the threshold table before the clock starts);
* quality: mean normalised reward (± standard error) of complete online runs over ``--instances``
  seeded instances at the same iterations, with SSAP and Random for context and, for R <= 6, the
  reference on the first ``--reference-instances`` of them (the paired difference ± its standard
  error is the parity figure);
* the ``plan_ms`` accuracy table (5, 20, 100, 1000 ms) at R = 6 and R = 32;
* warm start: a fresh interpreter importing the planner, loading the cached kernels and making its
  first decision.

Figures are wall-clock and depend on the machine's load; the load average is printed with them.
``python -m coordinator.bench`` (the earlier spelling) runs this same command.
"""
from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

from planner.instance import random_instance
from planner.mcts.fast import MCTSPlanner
from planner.mcts.reference import ReferenceMCTSPlanner
from planner.policies import RandomPlanner, SSAPPlanner
from planner.problem import make_view
from planner.online import run_online
from planner.settings import DEFAULT_ITERATIONS
from planner.ssap import table_for

#: Root seed of the benchmark's instances (instance i uses SeedSequence(SEED, spawn_key=(i,))).
SEED = 2024
#: Fleet sizes measured by default.
SIZES = (2, 4, 6, 12, 32)
#: Largest fleet the reference implementation is run on.
REFERENCE_MAX_R = 6
#: Time budgets of the plan_ms accuracy table, milliseconds.
BUDGETS_MS = (5.0, 20.0, 100.0, 1000.0)
PASSENGERS, STAGES, OVERLAPS = 3, 10, 10


def instance(carriers: int, i: int):
    """Benchmark instance i for a fleet of ``carriers`` (fixed by SEED)."""
    rng = np.random.default_rng(np.random.SeedSequence(SEED, spawn_key=(carriers, i)))
    return random_instance(rng, carriers=carriers, passengers=PASSENGERS, stages=STAGES, overlaps=OVERLAPS)


def _prepare(planner, problem) -> None:
    """What run_online does before a mission: warm_up(problem) (kernels loaded, per-problem
    tables cached); the reference has no warm_up, so its threshold table is computed here."""
    warm_up = getattr(planner, "warm_up", None)
    if callable(warm_up):
        warm_up(problem)
    else:
        table_for(problem)


def stage0_times(planner, carriers: int, count: int) -> tuple[np.ndarray, np.ndarray, float]:
    """Wall time and thread CPU time (ms) of ``count`` stage-0 decisions, decision i on instance i
    with seed i; peak MB of one more (with the planner's retained node arrays released first, so
    that their allocation counts)."""
    times, cpu = [], []
    for i in range(count):
        problem, x = instance(carriers, i)
        view = make_view(problem, 0, x, np.zeros(problem.valid.shape, dtype=bool))
        rng = np.random.default_rng(i)
        _prepare(planner, problem)
        c0 = time.thread_time()
        t0 = time.perf_counter()
        planner.decide(view, rng)
        times.append((time.perf_counter() - t0) * 1e3)
        cpu.append((time.thread_time() - c0) * 1e3)
    problem, x = instance(carriers, 0)
    view = make_view(problem, 0, x, np.zeros(problem.valid.shape, dtype=bool))
    release = getattr(planner, "release", None)
    if callable(release):  # count the node arrays the planner keeps between decisions too
        release()
    tracemalloc.start()
    planner.decide(view, np.random.default_rng(0))
    peak = tracemalloc.get_traced_memory()[1] / 2 ** 20
    tracemalloc.stop()
    return np.asarray(times), np.asarray(cpu), peak


def rewards(planner, carriers: int, count: int) -> np.ndarray:
    """Normalised reward of complete online runs on instances 0..count-1 (seed i for instance i)."""
    out = []
    for i in range(count):
        problem, x = instance(carriers, i)
        out.append(run_online(problem, x, planner, seed=i).reward)
    return np.asarray(out)


def _se(v: np.ndarray) -> float:
    return float(v.std(ddof=1) / np.sqrt(len(v))) if len(v) > 1 else float("nan")


def warm_start(cache_dir: str | None = None) -> dict:
    """Fresh interpreter: import, warm_up (cached kernels) and first decision, seconds.

    With ``cache_dir`` (an empty directory) numba's cache starts empty: a cold start that
    compiles the kernels.
    """
    code = (
        "import time; t0 = time.perf_counter()\n"
        "from planner.mcts.fast import MCTSPlanner\n"
        "from planner.instance import random_instance\n"
        "from planner.problem import make_view\n"
        "import numpy as np\n"
        "t1 = time.perf_counter()\n"
        "problem, x = random_instance(np.random.default_rng(0), carriers=6, passengers=3, stages=10, overlaps=10)\n"
        "p = MCTSPlanner('ssap'); p.warm_up(problem)\n"
        "t2 = time.perf_counter()\n"
        "p.decide(make_view(problem, 0, x, np.zeros(problem.valid.shape, dtype=bool)), np.random.default_rng(0))\n"
        "t3 = time.perf_counter()\n"
        "print(t1 - t0, t2 - t1, t3 - t2, t3 - t0)\n"
    )
    root = str(Path(__file__).resolve().parents[2])  # the directory holding planner/
    env = dict(os.environ, PYTHONPATH=root + os.pathsep + os.environ.get("PYTHONPATH", ""))
    if cache_dir is not None:
        env["NUMBA_CACHE_DIR"] = cache_dir
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=root, check=True)
    wall = time.perf_counter() - t0
    imp, warm, first, total = map(float, out.stdout.split())
    return {"process_s": wall, "import_s": imp, "warm_up_s": warm, "first_decision_s": first, "in_process_s": total}


def plan_ms_table(carriers: int, repeats: int) -> list[tuple[float, float, float, int]]:
    """(budget ms, median ms, max ms, median iterations) of stage-0 decisions under plan_ms."""
    rows = []
    for budget in BUDGETS_MS:
        planner = MCTSPlanner("ssap", plan_ms=budget)
        times, iters = [], []
        n = repeats if budget < 1000 else max(2, repeats // 3)
        for i in range(n):
            problem, x = instance(carriers, i)
            view = make_view(problem, 0, x, np.zeros(problem.valid.shape, dtype=bool))
            _prepare(planner, problem)
            t0 = time.perf_counter()
            planner.decide(view, np.random.default_rng(i))
            times.append((time.perf_counter() - t0) * 1e3)
            iters.append(planner.last_iterations)
        rows.append((budget, float(np.median(times)), float(np.max(times)), int(np.median(iters))))
    return rows


def main(argv=None, prog: str = "python -m planner.cli.bench") -> int:
    """Run the benchmark on ``argv`` (``sys.argv[1:]`` when None); ``prog`` names the command."""
    parser = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true",
                        help="2,000 iterations, fewer instances and decisions (a minute or two)")
    parser.add_argument("--sizes", default=",".join(map(str, SIZES)), help="fleet sizes R, comma-separated")
    parser.add_argument("--iterations", type=int, default=None,
                        help=f"MCTS iterations per decision ({DEFAULT_ITERATIONS:,}; 2,000 with --quick)")
    parser.add_argument("--instances", type=int, default=None, help="instances for the quality table")
    parser.add_argument("--reference-instances", type=int, default=None,
                        help="instances (of the same set) on which the reference runs, R <= 6")
    parser.add_argument("--sections", default="warm,speed,quality,plan",
                        help="comma-separated subset of warm,speed,quality,plan")
    parser.add_argument("--layout", default="auto", choices=("auto", "joint", "binary"),
                        help="tree layout of the fast planner (auto: joint up to 8 carriers, binary beyond)")
    parser.add_argument("--timing-decisions", type=int, default=None, help="stage-0 decisions timed per R")
    args = parser.parse_args(argv)
    try:
        sizes = [int(s) for s in args.sizes.split(",") if s.strip()]
        if not sizes or min(sizes) < 1:
            raise ValueError
    except ValueError:
        print(f"bench: --sizes: expected comma-separated positive integers, found {args.sizes!r}", file=sys.stderr)
        return 2
    sections = {x.strip() for x in args.sections.split(",") if x.strip()}
    if not sections or not sections <= {"warm", "speed", "quality", "plan"}:
        print(f"bench: --sections: expected a subset of warm,speed,quality,plan, found {args.sections!r}",
              file=sys.stderr)
        return 2
    iterations = args.iterations if args.iterations is not None else (2_000 if args.quick else DEFAULT_ITERATIONS)
    if iterations < 1:
        print(f"bench: --iterations: expected a positive integer, found {iterations}", file=sys.stderr)
        return 2
    quick = args.quick
    n_quality = args.instances or (6 if quick else 30)
    n_reference = args.reference_instances if args.reference_instances is not None else (2 if quick else 10)
    n_timing = args.timing_decisions or (5 if quick else 20)
    n_reference_timing = 2 if quick else 3

    import numba

    print(f"# planner.cli.bench  iterations={iterations}  D={PASSENGERS} N={STAGES} overlaps={OVERLAPS}"
          f"  quality instances={n_quality} (reference: {n_reference})  numba {numba.__version__}"
          f"  cpus={os.cpu_count()}  layout={args.layout}  load average at start {os.getloadavg()[0]:.2f}")

    fast = MCTSPlanner("ssap", iterations=iterations, layout=args.layout)
    fast.warm_up()
    reference = ReferenceMCTSPlanner("ssap", iterations=iterations)
    if "warm" in sections:
        warm_section()
    if "speed" in sections:
        speed_section(fast, reference, sizes, iterations, n_timing, n_reference_timing)
    if "quality" in sections:
        quality_section(fast, reference, sizes, iterations, n_quality, n_reference)
    if "plan" in sections:
        plan_section(4 if quick else 10)
    print(f"\nload average at end {os.getloadavg()[0]:.2f}; process peak RSS "
          f"{resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")
    return 0


def warm_section() -> None:
    import tempfile

    with tempfile.TemporaryDirectory() as empty:
        cold = warm_start(empty)
    ws = warm_start()
    ws2 = warm_start()
    print(f"\n## start-up (fresh interpreter: import + warm_up + first {DEFAULT_ITERATIONS:,}-iteration decision, R = 6)")
    for label, w in (("cold (empty numba cache)", cold), ("warm, run 1", ws), ("warm, run 2", ws2)):
        print(f"{label:>24}: process {w['process_s']:.2f} s  (import {w['import_s']:.2f} s, warm_up {w['warm_up_s']:.2f} s,"
              f" first decision {w['first_decision_s'] * 1e3:.1f} ms)")


def speed_section(fast, reference, sizes, iterations, n_timing, n_reference_timing) -> None:
    print(f"\n## speed at stage 0, {iterations} iterations (mcts-ssap)")
    print(f"{'R':>3} {'impl':>9} {'iter/s':>11} {'median ms':>10} {'p95 ms':>9} {'peak MB':>8} {'speed-up':>9}")
    for r in sizes:
        times, cpu, peak = stage0_times(fast, r, n_timing)
        med = float(np.median(times))
        print(f"{r:>3} {'fast':>9} {iterations / med * 1e3:>11,.0f} {med:>10.2f} "
              f"{np.percentile(times, 95):>9.2f} {peak:>8.2f} {'':>9}", flush=True)
        if r <= REFERENCE_MAX_R:
            rtimes, rcpu, rpeak = stage0_times(reference, r, n_reference_timing)
            rmed = float(np.median(rtimes))
            # Paired: the same instances, seeds, stage and iterations (decision i of both on
            # instance i with seed i), the median of the per-decision ratios.
            n = min(len(rtimes), len(times))
            wall = float(np.median(rtimes[:n] / times[:n]))
            thread = float(np.median(rcpu[:n] / cpu[:n]))
            print(f"{r:>3} {'reference':>9} {iterations / rmed * 1e3:>11,.0f} {rmed:>10.2f} "
                  f"{np.percentile(rtimes, 95):>9.2f} {rpeak:>8.2f} {wall:>8.1f}x", flush=True)
            print(f"    speed-up on the same {n} decisions (instances 0-{n - 1}, their seeds), median of the"
                  f" per-decision ratios: wall {wall:.1f}x, thread CPU {thread:.1f}x"
                  f" (fast {np.median(times[:n]):.2f} ms wall, {np.median(cpu[:n]):.2f} ms CPU)", flush=True)
    print(f"process peak RSS so far: {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")


def quality_section(fast, reference, sizes, iterations, n_quality, n_reference) -> None:
    print(f"\n## quality: mean normalised reward (± s.e.) of online runs, {iterations} iterations per stage")
    print(f"{'R':>3} {'mcts-ssap':>15} {'ssap':>15} {'random':>15} | {'n ref':>5} {'fast (same n)':>15}"
          f" {'reference':>15} {'fast - ref':>16}")
    layout_rows = []
    for r in sizes:
        f = rewards(fast, r, n_quality)
        s = rewards(SSAPPlanner(), r, n_quality)
        rnd = rewards(RandomPlanner(), r, n_quality)
        line = (f"{r:>3} {f.mean():>8.3f} ± {_se(f):<4.2f} {s.mean():>8.3f} ± {_se(s):<4.2f}"
                f" {rnd.mean():>8.3f} ± {_se(rnd):<4.2f} |")
        if r <= REFERENCE_MAX_R and n_reference > 0:
            ref = rewards(reference, r, n_reference)
            fr = f[:n_reference]
            d = fr - ref
            line += (f" {n_reference:>5} {fr.mean():>8.3f} ± {_se(fr):<4.2f} {ref.mean():>8.3f} ± {_se(ref):<4.2f}"
                     f" {d.mean():>+8.3f} ± {_se(d):<5.3f}")
        print(line, flush=True)
        used = fast.layout_for(instance(r, 0)[0])
        if used == "joint":  # the same instances with the other layout, paired
            other = MCTSPlanner("ssap", iterations=iterations, exploration=fast.exploration, layout="binary")
            b = rewards(other, r, n_quality)
            layout_rows.append((r, f, b))
    if layout_rows:
        print("\nlayouts at equal iterations (same instances and seeds): joint-action tree vs binary levels")
        print(f"{'R':>3} {'joint':>15} {'binary':>15} {'binary - joint':>18}")
        for r, f, b in layout_rows:
            d = b - f
            print(f"{r:>3} {f.mean():>8.3f} ± {_se(f):<4.2f} {b.mean():>8.3f} ± {_se(b):<4.2f} {d.mean():>+10.3f} ± {_se(d):<5.3f}")


def plan_section(repeats: int) -> None:
    print("\n## plan_ms accuracy (stage 0, mcts-ssap; wall time of decide())")
    print(f"{'R':>3} {'budget ms':>10} {'median ms':>10} {'max ms':>9} {'median error':>13} {'iterations':>11}")
    for r in (6, 32):
        for budget, med, mx, iters in plan_ms_table(r, repeats):
            print(f"{r:>3} {budget:>10.0f} {med:>10.2f} {mx:>9.2f} {100 * (med - budget) / budget:>+12.1f}% {iters:>11,}")


if __name__ == "__main__":
    sys.exit(main())
