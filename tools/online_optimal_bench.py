"""The exact online optimum's speed: the solver against its previous version, and its time
estimate against the measured time.

    python -m tools.online_optimal_bench                     # the four sizes below, reference 943efbd
    python -m tools.online_optimal_bench --reference REV     # the previous solver from another commit
    python -m tools.online_optimal_bench --no-reference      # the current solver only
    python -m tools.online_optimal_bench --estimates 40      # estimate vs measured on 40 random instances

For each size (random instances of :func:`planner.instance.random_instance`, Poisson(3): 19
atoms) it prints the previous solver's time (``planner/online_optimal.py`` as it was at the
reference commit, read with ``git show`` and run with its limits lifted: the plain memoised
expectimax over ``(stage, passengers left, open points with their x)``), the current solver's
time (CPU seconds of the process), their ratio measured in the same run, the current solver's estimate (:func:`estimate`,
O(R·N·D²)) and whether both agree on ``V*`` (to 1e-9 relative). ``--estimates K`` adds K seeded
random instances of 2 to 5 carriers, 4 to 9 stages and 1 to 3 passengers, the estimate against
the measured time of each (those estimated within ``--budget`` seconds).

Wall-clock figures depend on the machine's load; the load average is printed with them.
"""
from __future__ import annotations

import argparse
import importlib.util
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from planner import online_optimal
from planner.instance import random_instance
from world.paths import REPO_ROOT as REPO

#: (name, carriers, passengers, stages, overlap groups, seed).
SIZES = (
    ("R=2 N=6 D=2, 3 groups", 2, 2, 6, 3, 16),
    ("R=3 N=6 D=2, 4 groups", 3, 2, 6, 4, 2),
    ("R=3 N=6 D=2, 4 groups, one component", 3, 2, 6, 4, 1),
    ("R=4 N=6 D=2, 4 groups", 4, 2, 6, 4, 4),
)
#: The previous solver runs only where its own estimate is below this many of its operations
#: (it did 2e7 to 5e7 a second).
REFERENCE_MAX_WORK = 4e9
#: The solver before it was vectorised and split by conflict components.
REFERENCE = "943efbdda004d41a08bf7c8762e922d387572bb0"


def _reference_module(rev: str):
    """``planner/online_optimal.py`` of commit ``rev`` as a module, or None without git."""
    try:
        source = subprocess.run(["git", "show", f"{rev}:planner/online_optimal.py"], cwd=REPO, check=True,
                                capture_output=True, text=True).stdout
    except (OSError, subprocess.CalledProcessError) as exc:
        print(f"(no reference solver: {exc})", file=sys.stderr)
        return None
    path = Path(tempfile.mkdtemp()) / "online_optimal_reference.py"
    path.write_text(source)
    spec = importlib.util.spec_from_file_location("online_optimal_reference", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def _timed(fn):
    """``fn()`` and the CPU seconds it took (the process's: the budget's unit, less sensitive than
    wall time to a loaded host)."""
    start = time.process_time()
    out = fn()
    return out, time.process_time() - start


def sizes_table(reference) -> None:
    print("| instance | states before | before s | after s | before / after | estimate s | V* | same V* |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for name, carriers, passengers, stages, groups, seed in SIZES:
        problem = random_instance(np.random.default_rng(seed), carriers=carriers, passengers=passengers,
                                  stages=stages, overlaps=groups).problem
        estimate = online_optimal.estimate(problem, max_seconds=float("inf"), max_states=float("inf"))
        after, after_s = _timed(lambda: online_optimal.online_value(problem, max_seconds=float("inf"),
                                                                    max_states=float("inf")))
        before_cells = "| - | - | - "
        same = "-"
        if reference is not None:
            size = reference.estimate(problem, max_states=10**12, max_work=float("inf"))
            refused = "" if size.work <= reference.MAX_WORK and size.states <= reference.MAX_STATES else " (refused)"
            if size.work > REFERENCE_MAX_WORK:
                before_cells = f"| {size.states:,}{refused} | not run ({size.work:.2g} operations) | {after_s:.3f} | - "
            else:
                before, before_s = _timed(lambda: reference.online_value(problem, max_states=10**12,
                                                                         max_work=float("inf")))
                before_cells = (f"| {before.states:,}{refused} | {before_s:.2f} | {after_s:.3f} "
                                f"| {before_s / after_s:.0f}x ")
                same = "yes" if abs(before.expected_reward - after.expected_reward) <= 1e-9 * abs(after.expected_reward) else "NO"
        else:
            before_cells = f"| - | - | {after_s:.3f} | - "
        print(f"| {name} {before_cells}| {estimate.seconds:.3f} | {after.expected_reward:.6f} | {same} |", flush=True)


def estimates_table(count: int, budget: float) -> None:
    print(f"\n{count} random instances (seed 7), those estimated within {budget:g} s:")
    print("| R | N | D | groups | components | estimate s | measured s | measured / estimate |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    rng = np.random.default_rng(7)
    ratios = []
    for _ in range(count):
        carriers, stages = int(rng.integers(2, 6)), int(rng.integers(4, 10))
        passengers, groups = int(rng.integers(1, 4)), int(rng.integers(1, 3 * carriers))
        problem = random_instance(rng, carriers=carriers, passengers=passengers, stages=stages, overlaps=groups).problem
        try:
            estimate = online_optimal.estimate(problem, max_seconds=budget)
        except online_optimal.TooLarge:
            continue
        _, seconds = _timed(lambda: online_optimal.online_value(problem, max_seconds=budget))
        ratios.append(seconds / estimate.seconds)
        print(f"| {carriers} | {stages} | {passengers} | {groups} | {estimate.components} | {estimate.seconds:.3f} "
              f"| {seconds:.3f} | {seconds / estimate.seconds:.2f} |", flush=True)
    if ratios:
        print(f"\nmeasured / estimate over {len(ratios)} instances: median {np.median(ratios):.2f}, "
              f"max {np.max(ratios):.2f}, min {np.min(ratios):.3f}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tools.online_optimal_bench", description=__doc__.split("\n\n")[0])
    parser.add_argument("--reference", default=REFERENCE, help="commit of the previous solver (default: %(default)s)")
    parser.add_argument("--no-reference", action="store_true", help="time the current solver only")
    parser.add_argument("--estimates", type=int, default=0, help="random instances for the estimate table")
    parser.add_argument("--budget", type=float, default=10.0, help="seconds: the estimate table's largest instance")
    args = parser.parse_args(argv)
    print(f"# tools.online_optimal_bench  cpus={os.cpu_count()}  load average at start {os.getloadavg()[0]:.2f}")
    reference = None if args.no_reference else _reference_module(args.reference)
    sizes_table(reference)
    if args.estimates:
        estimates_table(args.estimates, args.budget)
    print(f"\nload average at end {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
