"""How much the adaptive MIP stopped after a number of branch-and-bound nodes gives up against
``python -m experiments bound --bound-method mixed``'s scale rows (or, beyond R = 128, where that
takes the LP relaxation, how much it tightens them), paired on the experiment's own trials and samples.

    python -m tools.bound_nodes --carriers 256 --trials 0-3 [--nodes 1] [--seed 0] [--out FILE]

For each trial t of the experiment's configuration with ``--carriers`` carriers
(``experiments.bound.CONFIGS``: its overlaps and samples): the instance of
``experiments.trials.random_trial`` and two bounds from the same observation stream
(``experiments.bound.bound_rng``: the same pilot and sample matrices):

* ``mixed``: ``experiments.bound.scale_bound`` as ``--bound-method mixed`` computes it (``mixed``,
  every MIP solved or stopped by its time limit, up to ``MIXED_MAX_CARRIERS``; the fixed-penalty
  LP beyond);
* ``nodes``: the same by ``mixed`` with every HiGHS branch and bound stopped after ``--nodes``
  nodes (``planner.duality.inner_maximum``'s ``mip_max_nodes``; 1: the root node with its cuts:
  what ``--bound-method mixed-root``, the default, computes beyond ``MIXED_MAX_CARRIERS``). Its
  dual bound is valid whatever the node count, and, unlike a search stopped by its time limit,
  the same on every machine while the time limit (``MIXED_MIP_TIME_LIMIT_S``) is not reached.

It prints one line per trial (both bounds, their ratio, the seconds) and the summary: the ratio
``nodes / mixed`` as mean ± SEM over trials, and, where ``docs/results/bound_trials.csv`` has
the planners' rewards of those trials, each planner's fraction of either bound (mean ± SEM over
the trials measured). ``--out`` writes the rows as CSV.
"""
from __future__ import annotations

import argparse
import csv
import sys
import time
from pathlib import Path

import numpy as np

from experiments.report import sem
from tools.base_policy import parse_trials, write_rows

ROOT = Path(__file__).resolve().parents[1]
SHIPPED_TRIALS = ROOT / "docs" / "results" / "bound_trials.csv"


def measure(carriers: int, trial: int, nodes: int, seed: int) -> dict:
    """Both bounds of one trial (module docstring)."""
    from experiments import bound as eb
    from experiments.trials import Task, random_trial

    level = next((k for k, c in enumerate(eb.CONFIGS) if c[1] == carriers), None)
    if level is None:
        raise SystemExit(f"tools.bound_nodes: --carriers: expected one of the experiment's sizes "
                         f"{sorted({c[1] for c in eb.CONFIGS})}, found {carriers}")
    name, _, overlaps, _, samples = eb.CONFIGS[level]
    task = Task("bound", level, trial, eb.UPPER_BOUND, seed, 0, carriers=carriers, overlaps=overlaps, samples=samples)
    problem, _, _, _ = random_trial(task)
    mixed_method = "mixed" if carriers <= eb.MIXED_MAX_CARRIERS else "lp"
    row = {"config": name, "trial": trial, "samples": samples, "node_limit": nodes, "mixed_method": mixed_method}
    for key, method, limit in (("mixed", mixed_method, None), ("nodes", "mixed", nodes)):
        t0 = time.perf_counter()
        b = eb.scale_bound(problem, eb.bound_rng(seed, trial), samples, method, mip_max_nodes=limit)
        row.update({key: b.expected_reward, f"{key}_stderr": b.stderr, f"{key}_strength": b.strength,
                    f"{key}_s": time.perf_counter() - t0})
    row["ratio"] = row["nodes"] / row["mixed"]
    return row


def shipped_rewards(config: str, path: Path = SHIPPED_TRIALS) -> dict[tuple[str, int], float]:
    """``(planner, trial) -> reward`` of the shipped run's planners on ``config`` (docs/results)."""
    if not path.exists():
        return {}
    with path.open() as f:
        return {(r["planner"], int(r["trial"])): float(r["reward"]) for r in csv.DictReader(f)
                if r["config"] == config and r["planner"] not in ("upper-bound", "clairvoyant")}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--carriers", type=int, default=256, help="the experiment's configuration by its R (default 256)")
    ap.add_argument("--trials", default="0-3", help="trial indices, e.g. 0-3 or 0,2,5-7 (default 0-3)")
    ap.add_argument("--nodes", type=int, default=1, help="branch-and-bound nodes of one MIP (default 1: the root)")
    ap.add_argument("--seed", type=int, default=0, help="the experiment's root seed (default 0)")
    ap.add_argument("--out", type=Path, help="write the rows here (CSV)")
    args = ap.parse_args(argv)
    if args.nodes < 1:
        ap.error(f"--nodes: expected an integer >= 1, found {args.nodes}")
    rows = []
    for t in parse_trials(args.trials):
        row = measure(args.carriers, t, args.nodes, args.seed)
        rows.append(row)
        print(f"trial {t}: mixed ({row['mixed_method']}) {row['mixed']:.3f} ± {row['mixed_stderr']:.3f} "
              f"in {row['mixed_s']:.0f} s; adaptive MIP at {args.nodes} node(s) {row['nodes']:.3f} ± "
              f"{row['nodes_stderr']:.3f} in {row['nodes_s']:.0f} s; ratio {row['ratio']:.4f}", flush=True)
    ratios = np.array([r["ratio"] for r in rows])
    print(f"\n{rows[0]['config']}, {len(rows)} trial(s), {rows[0]['samples']} samples each: bound at "
          f"{args.nodes} node(s) / mixed bound = {ratios.mean():.4f} ± {sem(ratios):.4f}")
    rewards = shipped_rewards(rows[0]["config"])
    for planner in sorted({p for p, _ in rewards}):
        got = [(rewards[(planner, r["trial"])], r) for r in rows if (planner, r["trial"]) in rewards]
        if len(got) < len(rows):
            continue
        old = np.array([w / r["mixed"] for w, r in got])
        new = np.array([w / r["nodes"] for w, r in got])
        print(f"  {planner:18} fraction of the mixed bound {old.mean():.4f} ± {sem(old):.4f}, "
              f"of the bound at {args.nodes} node(s) {new.mean():.4f} ± {sem(new):.4f}")
    if args.out:
        write_rows(rows, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
