"""Benchmark: mcts-ssap's decision time under the coverage reward against the penalty model.

    python -m planner.cli.bench_coverage [--sizes 6,32] [--instances K] [--iterations I]
                                         [--busy | --no-busy]

The same worlds planned both ways (issue 35, item 7: the target is coverage within 2x of the
penalty model's time): a world is :func:`planner.instance.random_coverage_instance` (D = 3, N = 10,
Poisson(3) per point, 2 own regions per point) and its penalty twin is the same schedule, pooled
prior and observations with the overlap groups the coverage geometry implies (one per shared
region, :meth:`planner.coverage.Coverage.overlaps`). Two families from fixed seeds:

* ``paper``: 10 shared regions of 2-3 points drawn uniformly (the MCTS benchmark's overlap level);
* ``near``: one shared region per point among neighbours within a stage (heavy, local overlap).

For each fleet size, family and model: the median and p95 wall time of every decision of complete
online missions (``run_online``'s ``decision_ms``: kernels loaded and per-problem tables built
before the first timed decision) at ``--iterations`` (10,000) iterations, and the ratio of the
medians. With ``--busy`` (default) every row is measured twice: on the host as it is, and with a
busy loop of this benchmark's own (one process spinning on a core) running alongside. Figures are
wall-clock; the load average is printed with them.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time

import numpy as np

from planner.instance import penalty_twin, random_coverage_instance
from planner.mcts.fast import MCTSPlanner
from planner.online import run_online
from planner.problem import Problem
from planner.settings import DEFAULT_ITERATIONS

#: Root seed of the worlds (family f, fleet R, world i: SeedSequence(SEED, spawn_key=(f, R, i))).
SEED = 3507
SIZES = (6, 32)
PASSENGERS, STAGES, MEAN, OWN = 3, 10, 3.0, 2
#: Family name -> (shared regions for R carriers, reach).
FAMILIES = {"paper": (lambda carriers: 10, None), "near": (lambda carriers: carriers * STAGES, 1)}


def worlds(family: str, carriers: int, i: int) -> tuple[Problem, Problem, np.ndarray, np.ndarray]:
    """World i of a family: (coverage problem, its penalty twin, observations, region counts)."""
    f = list(FAMILIES).index(family)
    shared, reach = FAMILIES[family]
    rng = np.random.default_rng(np.random.SeedSequence(SEED, spawn_key=(f, carriers, i)))
    (problem, x), counts = random_coverage_instance(rng, carriers=carriers, passengers=PASSENGERS, stages=STAGES,
                                                    overlaps=shared(carriers), mean=MEAN, own=OWN, reach=reach)
    return problem, penalty_twin(problem), x, counts


def decision_ms(planner: MCTSPlanner, family: str, carriers: int, count: int, coverage: bool) -> np.ndarray:
    """Every decision's wall time (ms) of complete missions on worlds 0..count-1 (seed i)."""
    out = []
    for i in range(count):
        problem, penalty, x, counts = worlds(family, carriers, i)
        if coverage:
            out.extend(run_online(problem, x, planner, seed=i, counts=counts).decision_ms)
        else:
            out.extend(run_online(penalty, x, planner, seed=i).decision_ms)
    return np.asarray(out)


def busy_loop() -> subprocess.Popen:
    """A process spinning on one core (the busy host), ended by the caller."""
    return subprocess.Popen([sys.executable, "-c", "while True: pass"])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m planner.cli.bench_coverage", description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default=",".join(map(str, SIZES)), help="fleet sizes R (comma-separated)")
    ap.add_argument("--instances", type=int, default=3, help="worlds per family and size")
    ap.add_argument("--iterations", type=int, default=DEFAULT_ITERATIONS, help="MCTS iterations per decision")
    ap.add_argument("--busy", action=argparse.BooleanOptionalAction, default=True,
                    help="also measure with a busy loop running alongside")
    args = ap.parse_args(argv)
    sizes = [int(s) for s in args.sizes.split(",")]
    planner = MCTSPlanner("ssap", iterations=args.iterations)
    print(f"mcts-ssap, {args.iterations} iterations, D = {PASSENGERS}, N = {STAGES}, {args.instances} worlds "
          f"per row; load average {os.getloadavg()[0]:.1f}")
    print("| host | R | family | penalty median ms (p95) | coverage median ms (p95) | coverage / penalty |")
    print("|---|---|---|---|---|---|")
    for host in ["as is", "busy loop"] if args.busy else ["as is"]:
        spinner = busy_loop() if host == "busy loop" else None
        try:
            time.sleep(0.2 if spinner else 0.0)
            for carriers in sizes:
                for family in FAMILIES:
                    pen = decision_ms(planner, family, carriers, args.instances, coverage=False)
                    cov = decision_ms(planner, family, carriers, args.instances, coverage=True)
                    ratio = float(np.median(cov) / np.median(pen))
                    print(f"| {host} | {carriers} | {family} | {np.median(pen):.1f} ({np.percentile(pen, 95):.1f}) | "
                          f"{np.median(cov):.1f} ({np.percentile(cov, 95):.1f}) | {ratio:.2f} |", flush=True)
        finally:
            if spinner is not None:
                spinner.kill()
                spinner.wait()
    print(f"load average after: {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
