"""Closed-loop's rollout base policy against the previous one, on paired trials.

    python -m tools.base_policy --carriers 128 --trials 60-71
    python -m tools.base_policy --carriers 256 --trials 60-67 --out base_policy_256.csv

Trial t is ``experiments.trials.random_trial`` of the upper-bound experiment's configuration with
``--carriers`` R (D = 3, N = 10, Poisson(3), 5 R overlap groups; ``python -m experiments bound``
runs trials 0 to 15): the same instance, observations and planner seed for both planners. Per
trial it runs ``closed-loop`` as it is (:data:`planner.closedloop.RULE_ROUNDS` rounds of
``conflict_values`` behind its rollouts) and the previous closed-loop (``rule_rounds = 0``: the
conflict-aware SSAP rule with DLR's thresholds), both with ``--iterations`` per decision, and the
information-relaxation bound of the instance (``planner.duality.upper_bound``, LP relaxation, the
experiment's samples and stream ``(1000, t, 2)``). It prints one line per trial and the summary:
the paired difference (new - previous) as mean ± SEM over trials with wins and losses, each
planner's fraction of the bound (reward / bound per trial, mean ± SEM) and its mean decision
time. One process, so the figures are the machine's.
"""
from __future__ import annotations

import argparse
import csv
import sys
import time

import numpy as np

from experiments.report import sem

#: Bound samples per trial by R (experiments.bound.CONFIGS); 6 for other sizes.
BOUND_SAMPLES = {32: 12, 128: 6, 256: 4}


def parse_trials(text: str) -> list[int]:
    """``"60-71"`` or ``"50,52,60-63"``: trial indices, in order."""
    out = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        out.extend(range(int(lo), int(hi or lo) + 1))
    return out


def write_rows(rows: list[dict], path) -> None:
    """The per-trial rows as CSV, their first row's keys as the header (the measuring tools' ``--out``)."""
    with open(path, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def run_trials(trials: list[int], run, line, summary, out=None) -> list[dict]:
    """The measuring tools' loop: each trial's row ``run(t)``, printed as ``trial t: line(row)`` as
    it comes, then the lines of ``summary(rows)``, the wall time and, with ``out``, the rows as CSV
    (:func:`write_rows`)."""
    rows = []
    t0 = time.perf_counter()
    for t in trials:
        row = run(t)
        rows.append(row)
        print(f"trial {t}: {line(row)}", flush=True)
    print("\n".join(summary(rows)))
    print(f"  ({time.perf_counter() - t0:.0f} s)")
    if out:
        write_rows(rows, out)
    return rows


def run_pair(carriers: int, trial: int, iterations: int, seed: int, bound_samples: int) -> dict:
    """One trial: rewards and decision times of both planners, and the bound."""
    from experiments.bound import bound_rng
    from experiments.trials import Task, random_trial
    from planner import duality
    from planner.closedloop import ClosedLoopPlanner
    from planner.online import run_online

    task = Task("bound", 0, trial, "closed-loop", seed, iterations, carriers=carriers, overlaps=5 * carriers)
    problem, x, planner_seed, _ = random_trial(task)
    row = {"carriers": carriers, "trial": trial}
    for name, options in (("previous", {"rule_rounds": 0}), ("new", {})):
        planner = ClosedLoopPlanner(iterations=iterations, **options)
        result = run_online(problem, x, planner, planner_seed)  # warms the planner up first
        row[name] = result.reward
        row[name + "_ms"] = float(np.mean(result.decision_ms))
    bound = duality.upper_bound(problem, bound_rng(seed, trial), samples=bound_samples, method="lp")
    row["bound"] = bound.expected_reward
    row["bound_stderr"] = bound.stderr
    return row


def summary(rows: list[dict]) -> list[str]:
    diff = np.array([r["new"] - r["previous"] for r in rows])
    lines = [f"R = {rows[0]['carriers']}, {len(rows)} trials ({rows[0]['trial']}..{rows[-1]['trial']}):",
             f"  paired difference new - previous: {diff.mean():+.2f} ± {sem(diff):.2f} per trial "
             f"({diff.mean() / np.mean([r['previous'] for r in rows]) * 100:+.2f} %), "
             f"{int((diff > 0).sum())} wins, {int((diff < 0).sum())} losses, {int((diff == 0).sum())} ties"]
    for name in ("previous", "new"):
        frac = np.array([r[name] / r["bound"] for r in rows])
        lines.append(f"  {name:8s}: reward {np.mean([r[name] for r in rows]):.2f}, fraction of the bound "
                     f"{frac.mean():.4f} ± {sem(frac):.4f}, decision {np.mean([r[name + '_ms'] for r in rows]):.1f} ms")
    lines.append(f"  bound   : {np.mean([r['bound'] for r in rows]):.2f}")
    return lines


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tools.base_policy", description=__doc__.split("\n\n")[0])
    parser.add_argument("--carriers", type=int, default=128, help="R (default 128)")
    parser.add_argument("--trials", default="60-65", help="trial indices, e.g. 60-71 or 50,52 (default 60-65)")
    parser.add_argument("--iterations", type=int, default=2000, help="iterations per decision (default 2000)")
    parser.add_argument("--seed", type=int, default=0, help="root seed of the trials (default 0)")
    parser.add_argument("--bound-samples", type=int, default=None,
                        help="sampled observation matrices of the bound (default: the experiment's)")
    parser.add_argument("--out", default=None, help="also write the per-trial rows to this CSV")
    args = parser.parse_args(argv)
    if args.carriers < 2 or args.iterations < 1:
        parser.error("--carriers must be at least 2 and --iterations at least 1")
    try:
        trials = parse_trials(args.trials)
    except ValueError:
        parser.error(f"--trials: expected indices like 60-71 or 50,52, found {args.trials!r}")
    samples = args.bound_samples or BOUND_SAMPLES.get(args.carriers, 6)
    run_trials(trials, lambda t: run_pair(args.carriers, t, args.iterations, args.seed, samples),
               lambda row: f"previous {row['previous']:.2f}  new {row['new']:.2f}  difference "
                           f"{row['new'] - row['previous']:+.2f}  bound {row['bound']:.2f} ± {row['bound_stderr']:.2f}",
               summary, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
