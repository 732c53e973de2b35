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
before the first timed decision) at ``--iterations`` (10,000) iterations, the median CPU time of
the same decisions (``time.thread_time``: what the decision itself costs, whatever else runs on
the host), and the ratios of the medians. The two models fly each world back to back, so they
share the host's conditions. With ``--busy`` (default) every row is measured twice: on the host as
it is, and with a busy loop of this benchmark's own (one process spinning on a core) running
alongside. The load average is printed with the figures.
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


class _CPUTimed:
    """A planner whose decisions' CPU times (ms, ``time.thread_time``) are recorded."""

    def __init__(self, planner: MCTSPlanner):
        self.planner, self.name, self.cpu_ms = planner, planner.name, []

    def warm_up(self, problem: Problem) -> None:
        self.planner.warm_up(problem)

    def decide(self, view, rng):
        t0 = time.thread_time()
        out = self.planner.decide(view, rng)
        self.cpu_ms.append((time.thread_time() - t0) * 1e3)
        return out


def decision_ms(planner: MCTSPlanner, family: str, carriers: int, count: int) -> dict:
    """Every decision's wall and CPU time (ms) of complete missions on worlds 0..count-1 (seed i),
    per model (``"penalty"``, ``"coverage"``), the two models flying each world back to back."""
    out = {model: {"wall": [], "cpu": []} for model in ("penalty", "coverage")}
    for i in range(count):
        problem, penalty, x, counts = worlds(family, carriers, i)
        for model in out:
            timed = _CPUTimed(planner)
            if model == "coverage":
                result = run_online(problem, x, timed, seed=i, counts=counts)
            else:
                result = run_online(penalty, x, timed, seed=i)
            out[model]["wall"].extend(result.decision_ms)
            out[model]["cpu"].extend(timed.cpu_ms)
    return {model: {k: np.asarray(v) for k, v in times.items()} for model, times in out.items()}


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
    print("| host | R | family | penalty wall median ms (p95) | coverage wall median ms (p95) | wall ratio | "
          "penalty CPU median ms | coverage CPU median ms | CPU ratio |")
    print("|---|---|---|---|---|---|---|---|---|")
    for host in ["as is", "busy loop"] if args.busy else ["as is"]:
        spinner = busy_loop() if host == "busy loop" else None
        try:
            time.sleep(0.2 if spinner else 0.0)
            for carriers in sizes:
                for family in FAMILIES:
                    times = decision_ms(planner, family, carriers, args.instances)
                    pen, cov = times["penalty"], times["coverage"]
                    wall = [f"{np.median(t['wall']):.1f} ({np.percentile(t['wall'], 95):.1f})" for t in (pen, cov)]
                    cpu = [float(np.median(t["cpu"])) for t in (pen, cov)]
                    print(f"| {host} | {carriers} | {family} | {wall[0]} | {wall[1]} | "
                          f"{np.median(cov['wall']) / np.median(pen['wall']):.2f} | {cpu[0]:.1f} | {cpu[1]:.1f} | "
                          f"{cpu[1] / cpu[0]:.2f} |", flush=True)
        finally:
            if spinner is not None:
                spinner.kill()
                spinner.wait()
    print(f"load average after: {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
