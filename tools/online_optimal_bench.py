"""The exact online optimum's speed: the solver against its previous version, and its time
estimate against the measured time.

    python -m tools.online_optimal_bench                     # the four sizes below, reference 943efbd
    python -m tools.online_optimal_bench --reference REV     # the previous solver from another commit
    python -m tools.online_optimal_bench --no-reference      # the current solver only
    python -m tools.online_optimal_bench --estimates 40      # estimate vs measured on 40 random instances
    python -m tools.online_optimal_bench --no-sizes --admission 40   # admission against the plain expectimax

For each size (random instances of :func:`planner.instance.random_instance`, Poisson(3): 19
atoms) it prints the previous solver's time (``planner/online_optimal.py`` as it was at the
reference commit, read with ``git show`` and run with its limits lifted: the plain memoised
expectimax over ``(stage, passengers left, open points with their x)``), the current solver's
time (CPU seconds of the process), their ratio measured in the same run, the current solver's estimate (:func:`estimate`,
O(R·N·D²)) and whether both agree on ``V*`` (to 1e-9 relative). ``--estimates K`` adds K seeded
random instances of 2 to 5 carriers, 4 to 9 stages and 1 to 3 passengers, the estimate against
the measured time of each (those estimated within ``--budget`` seconds) and of the work the solve
counted (:class:`planner.online_optimal.OnlineValue` ``counted_seconds``, the admission's unit).
``--admission K`` runs the solver at its default limits and the plain memoised expectimax (the
reference solver, limits lifted, capped at 60 s of CPU by an interval timer) on the first K
instances of a seeded sweep and on the sweep's instances the previous limit accepted and the time
estimate refuses, and prints how many the plain one solves within 60 s that the solver refuses
(target 0; exit status 1 otherwise).

Wall-clock figures depend on the machine's load; the load average is printed with them.
"""
from __future__ import annotations

import argparse
import importlib.util
import math
import os
import signal
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
    print(f"\n{count} random instances (seed 7), those estimated within {budget:g} s; counted s: the work the "
          f"solve counted, at the counted rates:")
    print("| R | N | D | groups | components | estimate s | counted s | measured s | measured / estimate "
          "| measured / counted | estimate / counted |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    rng = np.random.default_rng(7)
    ratios, counted_ratios, slack = [], [], []
    for _ in range(count):
        carriers, stages = int(rng.integers(2, 6)), int(rng.integers(4, 10))
        passengers, groups = int(rng.integers(1, 4)), int(rng.integers(1, 3 * carriers))
        problem = random_instance(rng, carriers=carriers, passengers=passengers, stages=stages, overlaps=groups).problem
        try:
            estimate = online_optimal.estimate(problem, max_seconds=budget)
        except online_optimal.TooLarge:
            continue
        value, seconds = _timed(lambda: online_optimal.online_value(problem, max_seconds=math.inf))
        counted = value.counted_seconds
        ratios.append(seconds / estimate.seconds)
        counted_ratios.append(seconds / counted)
        slack.append(estimate.seconds / counted)
        print(f"| {carriers} | {stages} | {passengers} | {groups} | {estimate.components} | {estimate.seconds:.3f} "
              f"| {counted:.3f} | {seconds:.3f} | {ratios[-1]:.2f} | {counted_ratios[-1]:.2f} | {slack[-1]:.1f} |",
              flush=True)
    if ratios:
        print(f"\nover {len(ratios)} instances: measured / estimate median {np.median(ratios):.2f}, "
              f"max {np.max(ratios):.2f}, min {np.min(ratios):.3f}; measured / counted median "
              f"{np.median(counted_ratios):.2f}, max {np.max(counted_ratios):.2f}, min {np.min(counted_ratios):.3f}; "
              f"estimate / counted max {np.max(slack):.1f} (ESTIMATE_SLACK = {online_optimal.ESTIMATE_SLACK:g})")


# ----------------------------------------------------------------------------- admission

#: The admission sweep: random instances of 1 to 5 carriers, 2 to 10 stages, 1 to 3 passengers and
#: 1 to 3R overlap groups (Poisson(3), 19 atoms), drawn from this seed.
SWEEP_SEED = 2026
#: Instances of the sweep searched for those the previous limit (the reference solver's, 1e9 of its
#: operations and 500,000 states) accepted and the 60 s time estimate refuses.
SWEEP_SIZE = 3000
#: The plain expectimax's time limit (CPU seconds): what it solves within this, the solver must take.
PLAIN_SECONDS = 60.0
#: CPU seconds per memoised state below the plain expectimax's fastest measured (about 2e-4: each
#: state is a Python call that builds its joint actions' arrays): an instance with more states
#: than ``PLAIN_SECONDS / PLAIN_STATE_SECONDS`` (enumerated exactly by the plain solver's own
#: ``estimate``) cannot be solved within the limit and is not run (the table prints the fastest
#: rate of the run, to check this).
PLAIN_STATE_SECONDS = 2e-5


class _Stop(Exception):
    """The CPU-time cap of a plain solve passed (SIGPROF)."""


def _capped(fn, seconds: float):
    """``(fn(), CPU seconds)``, or ``(None, CPU seconds)`` once ``seconds`` of the process's CPU time
    have passed (an interval timer on CPU time: a loaded host does not shorten it)."""
    def stop(*_):
        raise _Stop()

    previous = signal.signal(signal.SIGPROF, stop)
    start = time.process_time()
    signal.setitimer(signal.ITIMER_PROF, seconds)
    try:
        out = fn()
    except _Stop:
        out = None
    finally:
        signal.setitimer(signal.ITIMER_PROF, 0)
        signal.signal(signal.SIGPROF, previous)
    return out, time.process_time() - start


def _sweep():
    """The admission sweep's instances: ``(index, R, N, D, groups, problem)``, in draw order."""
    rng = np.random.default_rng(SWEEP_SEED)
    for index in range(SWEEP_SIZE):
        carriers, stages = int(rng.integers(1, 6)), int(rng.integers(2, 11))
        passengers, groups = int(rng.integers(1, 4)), int(rng.integers(1, 3 * carriers + 1))
        seed = int(rng.integers(2**31))
        problem = random_instance(np.random.default_rng(seed), carriers=carriers, passengers=passengers,
                                  stages=stages, overlaps=groups).problem
        yield index, carriers, stages, passengers, groups, problem


def _previously_refused(reference) -> list[int]:
    """Indices of the sweep the previous limit accepted and the 60 s time estimate refuses."""
    out = []
    for index, *_, problem in _sweep():
        try:
            online_optimal.estimate(problem)
            continue
        except online_optimal.TooLarge:
            pass
        try:
            reference.estimate(problem)
        except reference.TooLarge:
            continue
        out.append(index)
    return out


def admission_table(count: int, reference) -> int:
    """The solver's admission against the plain memoised expectimax (the reference solver, limits
    lifted, capped at :data:`PLAIN_SECONDS` of CPU) on the sweep's first ``count`` instances and
    every instance of the sweep the previous limit accepted and the time estimate refused. Prints
    a row per instance that either takes over a second or refuses, then the counts; returns the
    number of instances the plain expectimax solves within the limit and the solver refuses."""
    earlier = _previously_refused(reference)
    chosen = set(range(count)) | set(earlier)
    print(f"\nadmission: sweep seed {SWEEP_SEED}, its first {count} instances and the {len(earlier)} of its "
          f"{SWEEP_SIZE} the previous limit accepted and the 60 s estimate refuses (*); the solver at its default "
          f"limits, the plain memoised expectimax capped at {PLAIN_SECONDS:g} s of CPU; rows: over 1 s or refused")
    print("| # | R | N | D | groups | estimate s | solver | counted s | solver s | plain states | plain s "
          "| plain / solver | same V* |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    tally = {"solved": 0, "refused early": 0, "refused counted": 0}
    plain_solved = plain_capped = plain_skipped = missed = 0
    rates, ratios = [], []
    slowest = 0.0
    for index, carriers, stages, passengers, groups, problem in _sweep():
        if index not in chosen:
            continue
        estimate = online_optimal.estimate(problem, max_seconds=math.inf, max_states=math.inf).seconds
        verdict = "solved"
        start = time.process_time()
        try:
            mine = online_optimal.online_value(problem)
        except online_optimal.TooLarge as err:
            mine = None
            verdict = "refused counted" if "stopped" in str(err) else "refused early"
        mine_s = time.process_time() - start
        tally[verdict] += 1
        counted = mine.counted_seconds if mine is not None else math.nan
        if mine is not None:
            slowest = max(slowest, mine_s)
        most = int(PLAIN_SECONDS / PLAIN_STATE_SECONDS)
        try:
            states = reference.estimate(problem, max_states=most, max_work=math.inf).states
        except reference.TooLarge:
            states = math.inf
        plain_cell, same = "not run", "-"
        plain = None
        if states <= most:
            plain, plain_s = _capped(lambda: reference.online_value(problem, max_states=10**12, max_work=math.inf),
                                     PLAIN_SECONDS)
            if plain is None:
                plain_capped += 1
                plain_cell = f"> {PLAIN_SECONDS:g}"
            else:
                plain_solved += 1
                plain_cell = f"{plain_s:.2f}"
                if mine is None:
                    missed += 1
                elif plain_s > 1.0:  # below, both are noise
                    rates.append(plain_s / states)
                    ratios.append(plain_s / max(mine_s, 1e-9))
                    same = "yes" if abs(plain.expected_reward - mine.expected_reward) <= 1e-9 * abs(mine.expected_reward) else "NO"
        else:
            plain_skipped += 1
        if mine is None or mine_s > 1.0 or index in earlier:
            star = "*" if index in earlier else ""
            print(f"| {index}{star} | {carriers} | {stages} | {passengers} | {groups} | {estimate:.3g} | {verdict} "
                  f"| {counted:.3g} | {mine_s:.2f} | {states:.3g} | {plain_cell} "
                  f"| {plain_s / max(mine_s, 1e-9) if mine is not None and plain is not None else math.nan:.1f} | {same} |",
                  flush=True)
    print(f"\n{len(chosen)} instances: solver {tally['solved']} solved (slowest {slowest:.2f} s of CPU), "
          f"{tally['refused early']} refused early (estimate above {online_optimal.ESTIMATE_SLACK:g} x the limit, "
          f"or its floor above the limit), {tally['refused counted']} refused by counted work")
    print(f"plain expectimax: {plain_solved} solved within {PLAIN_SECONDS:g} s, {plain_capped} stopped at "
          f"{PLAIN_SECONDS:g} s, {plain_skipped} not run (its exact state count above "
          f"{PLAIN_SECONDS / PLAIN_STATE_SECONDS:.2g}); fastest {min(rates, default=math.nan):.3g} s per state "
          f"(the not-run rule assumes at least {PLAIN_STATE_SECONDS:.2g}); plain / solver time where the plain one "
          f"took over 1 s: median {np.median(ratios) if ratios else math.nan:.1f}, min "
          f"{min(ratios, default=math.nan):.1f}")
    print(f"solved by the plain expectimax within {PLAIN_SECONDS:g} s and refused by the solver: {missed} (target 0)")
    return missed


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tools.online_optimal_bench", description=__doc__.split("\n\n")[0])
    parser.add_argument("--reference", default=REFERENCE, help="commit of the previous solver (default: %(default)s)")
    parser.add_argument("--no-reference", action="store_true", help="time the current solver only")
    parser.add_argument("--estimates", type=int, default=0, help="random instances for the estimate table")
    parser.add_argument("--budget", type=float, default=10.0, help="seconds: the estimate table's largest instance")
    parser.add_argument("--admission", type=int, default=0, metavar="K",
                        help="the admission table: the sweep's first K instances and those the previous limit "
                             "accepted and the time estimate refused, against the plain expectimax (needs the reference)")
    parser.add_argument("--no-sizes", action="store_true", help="skip the table of four sizes")
    args = parser.parse_args(argv)
    print(f"# tools.online_optimal_bench  cpus={os.cpu_count()}  load average at start {os.getloadavg()[0]:.2f}")
    reference = None if args.no_reference else _reference_module(args.reference)
    if not args.no_sizes:
        sizes_table(reference)
    if args.estimates:
        estimates_table(args.estimates, args.budget)
    missed = 0
    if args.admission:
        if reference is None:
            parser.error("--admission needs the reference solver (drop --no-reference)")
        missed = admission_table(args.admission, reference)
    print(f"\nload average at end {os.getloadavg()[0]:.2f}")
    return 1 if missed else 0


if __name__ == "__main__":
    sys.exit(main())
