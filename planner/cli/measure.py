"""Measurement command lines of the exact solvers (the planner's command lines live in planner/cli/).

    python -m planner.online_optimal [--instances K] [--samples S] [--iterations I] [--seed SEED]
    python -m planner.clairvoyant [--instances K] [--carriers R] [--passengers D] [--stages N]
                                  [--overlaps G] [--seed SEED]
    python -m planner.coverage_bounds [--carriers R,R,...] [--instances K] [--passengers D]
                                      [--stages N] [--reach C] [--mean MU] [--seed SEED]

The commands are kept where the docs call them: ``python -m`` runs the named file, so each of
those modules keeps a ``__main__`` block that only forwards here (one import, one
``raise SystemExit`` of the call; tests/test_boundaries.py holds them to that), and all the
argument parsing and printing is in :func:`optimal_table`, :func:`clairvoyant_times` and
:func:`coverage_bound_times`.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from planner import clairvoyant
from planner.instance import random_instance
from planner.online import run_online
from planner.online_optimal import online_value
from planner.problem import sample_observations
from planner.registry import make_planner
from planner.settings import DEFAULT_ITERATIONS


def optimal_table(argv=None) -> None:
    """Print the docs table: V*, exact SSAP and random values, Monte Carlo means of closed-loop,
    MCTS-SSAP and the clairvoyant bound, all as % of V*, on seeded tiny random instances."""
    parser = argparse.ArgumentParser(prog="python -m planner.online_optimal", description=optimal_table.__doc__)
    parser.add_argument("--instances", type=int, default=6, help="instances (R alternates 2, 3)")
    parser.add_argument("--samples", type=int, default=400, help="sampled observation matrices per instance")
    parser.add_argument("--iterations", type=int, default=DEFAULT_ITERATIONS, help="closed-loop and MCTS-SSAP iterations per stage")
    parser.add_argument("--seed", type=int, default=16)
    args = parser.parse_args(argv)

    root = np.random.SeedSequence(args.seed)
    print(f"R = 2 and 3, N = 6, D = 2, Poisson(3), 2 to 4 overlap groups; {args.samples} sampled observation "
          f"matrices per instance (common to all planners), {args.iterations:,} iterations per stage; "
          f"Monte Carlo means ± one standard error, all as % of V*.\n")
    print("| instance | V* | SSAP (exact) | random (exact) | closed-loop | MCTS-SSAP | clairvoyant |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    columns = ("ssap", "random", "closed-loop", "mcts-ssap", "clairvoyant")
    shares = {name: [] for name in columns}
    for k, seq in enumerate(root.spawn(args.instances)):
        rng = np.random.default_rng(seq)
        carriers = 2 + k % 2
        groups = int(rng.integers(2, 5))
        problem = random_instance(rng, carriers=carriers, passengers=2, stages=6, overlaps=groups).problem
        best = online_value(problem).expected_reward
        exact = {name: online_value(problem, name).expected_reward for name in ("ssap", "random")}
        planners = {name: make_planner(name, iterations=args.iterations) for name in ("closed-loop", "mcts-ssap")}
        runs = {name: [] for name in (*planners, "clairvoyant")}
        for s in range(args.samples):
            x = sample_observations(problem, rng)
            for name, planner in planners.items():
                runs[name].append(run_online(problem, x, planner, s).reward)
            runs["clairvoyant"].append(clairvoyant.solve(problem, x).reward)

        def pct(values) -> str:
            values = 100.0 * np.asarray(values) / best
            return f"{values.mean():.1f} ± {values.std(ddof=1) / np.sqrt(len(values)):.1f}"

        print(f"| R={carriers}, {groups} groups (#{k}) | {best:.4f} | {100 * exact['ssap'] / best:.1f} | "
              f"{100 * exact['random'] / best:.1f} | {pct(runs['closed-loop'])} | {pct(runs['mcts-ssap'])} | "
              f"{pct(runs['clairvoyant'])} |", flush=True)
        for name in columns:
            shares[name].append(100.0 * (exact[name] if name in exact else np.mean(runs[name])) / best)
    print("| mean over instances | 100 | " + " | ".join(f"{np.mean(shares[name]):.1f}" for name in columns) + " |")


def clairvoyant_times(argv=None) -> None:
    """``python -m planner.clairvoyant``: time the exact search on random paper-style instances."""


    parser = argparse.ArgumentParser(prog="python -m planner.clairvoyant",
                                     description="Time the clairvoyant search on random instances.")
    parser.add_argument("--instances", type=int, default=200)
    parser.add_argument("--carriers", type=int, default=4)
    parser.add_argument("--passengers", type=int, default=3)
    parser.add_argument("--stages", type=int, default=10)
    parser.add_argument("--overlaps", type=int, default=20)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    clairvoyant.warm_up()
    rng = np.random.default_rng(args.seed)
    times, nodes, exact = [], [], 0
    for _ in range(args.instances):
        problem, x = random_instance(rng, args.carriers, args.passengers, args.stages, args.overlaps)
        start = time.perf_counter()
        result = clairvoyant.solve(problem, x)
        times.append((time.perf_counter() - start) * 1e3)
        nodes.append(result.nodes)
        exact += result.exact
    print(f"R={args.carriers} D={args.passengers} N={args.stages} overlaps={args.overlaps}: "
          f"{args.instances} instances, exact {exact}, ms mean {np.mean(times):.2f} median "
          f"{np.median(times):.2f} max {np.max(times):.2f}, nodes mean {np.mean(nodes):.0f} max {np.max(nodes)}")


def _lattice_coverage(rng: np.random.Generator, carriers: int, passengers: int, stages: int, reach: int,
                      mean: float):
    """A coverage instance on a lattice (benchmark only): carrier r's stage j sits near cell
    (2r, 2j) (jittered by one cell) and explores the cells within ``reach`` (Chebyshev), each
    cell a region with a Poisson(``mean``) count. Returns (problem, x, counts)."""
    from planner import coverage as cov, priors
    from planner.problem import Problem

    width, height = 2 * carriers + 2 * reach + 2, 2 * stages + 2 * reach + 2
    covers = []
    for r in range(carriers):
        row = []
        for j in range(stages):
            cx, cy = 2 * r + reach + int(rng.integers(0, 2)), 2 * j + reach + int(rng.integers(0, 2))
            row.append([x * height + y for x in range(cx - reach, cx + reach + 1)
                        for y in range(cy - reach, cy + reach + 1)])
        covers.append(row)
    prior = priors.build_prior({"kind": "poisson", "mean": mean})
    coverage = cov.Coverage.build(covers, [prior] * (width * height))
    point = priors.build_prior({"kind": "poisson", "mean": mean * (2 * reach + 1) ** 2})
    problem = Problem.build(passengers, np.ones((carriers, stages), dtype=bool), coverage.overlaps(stages), point,
                            coverage=coverage)
    counts = cov.sample_counts(coverage, rng)
    return problem, cov.observations(coverage, counts, problem.valid), counts


def coverage_bound_times(argv=None) -> None:
    """``python -m planner.coverage_bounds``: the coverage clairvoyant's method, time and gap on
    lattice instances (:func:`_lattice_coverage`) of growing R."""
    from planner import coverage_bounds

    parser = argparse.ArgumentParser(prog="python -m planner.coverage_bounds", description=coverage_bound_times.__doc__)
    parser.add_argument("--carriers", default="4,8,16,32,64", help="comma-separated R values")
    parser.add_argument("--instances", type=int, default=3)
    parser.add_argument("--passengers", type=int, default=3)
    parser.add_argument("--stages", type=int, default=10)
    parser.add_argument("--reach", type=int, default=2)
    parser.add_argument("--mean", type=float, default=0.3)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    print("| R | columns | nonzeros | method | exact | gap mean (max) | ms mean (max) |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for carriers in (int(v) for v in args.carriers.split(",")):
        rng = np.random.default_rng(np.random.SeedSequence(args.seed, spawn_key=(carriers,)))
        times, gaps, exact, sizes, methods = [], [], 0, [], set()
        for _ in range(args.instances):
            problem, x, counts = _lattice_coverage(rng, carriers, args.passengers, args.stages, args.reach, args.mean)
            sizes.append(coverage_bounds.model_size(problem, problem.valid))
            start = time.perf_counter()
            result = coverage_bounds.solve(problem, x, counts)
            times.append((time.perf_counter() - start) * 1e3)
            gaps.append(result.gap)
            exact += result.exact
            methods.add(result.method)
        print(f"| {carriers} | {max(s.columns for s in sizes):,} | {max(s.nonzeros for s in sizes):,} | "
              f"{'/'.join(sorted(methods))} | {exact}/{args.instances} | {np.mean(gaps):.4f} ({np.max(gaps):.4f}) | "
              f"{np.mean(times):.0f} ({np.max(times):.0f}) |", flush=True)
