"""The closed-loop planners' rollout loop, shared against written out: decision time of both.

    python -m tools.rollout_bench --reps 7 --candidate f95fab9 --reference 6275f1f   # docs/planner.md's figures
    python -m tools.rollout_bench --candidate REV     # the kernels of commit REV against --reference
    python -m tools.rollout_bench --sizes 12 --reps 9 --iterations 4000

``closed-loop``'s ``_evaluate`` and ``dec-closed-loop``'s ``_evaluate_imputed`` each write out
the rollout of the sampled futures. Commit f95fab9 shared it (one numba function inlined into
both, dec-closed-loop passing the base rule of 0 rounds, DLR's thresholds); it made
dec-closed-loop slower (docs/planner.md, *closed-loop*, has the figures), so the loops stay written
out and only the anytime sampling loop
(:func:`planner.joint.sampled_mean`) is shared. This script loads ``planner/closedloop.py``
and ``planner/decentralised.py`` of ``--candidate`` (default: the working tree) and of
``--reference`` (``git show``), compiles both in this process alike, and for each fleet size R
(D = 3, N = 10, 10 overlap groups, Poisson(3), an instance of
:func:`planner.instance.random_instance` and one sampled observation matrix) times, in
alternating order, ``--reps`` rounds of

* closed-loop: ``decide`` at stages 0, 3 and 6 (no past deployments) at ``--iterations``;
* dec-closed-loop: ``partial_scores`` of every carrier with a choice at stage 3, each knowing
  its own row and the others' up to stage 1 only (so the imputed kernel runs);

checks that both versions return the same decisions and scores (bit for bit), and prints the
CPU seconds (``time.process_time``: one thread, less sensitive than wall time to a loaded host)
of the fastest round of each version (the least disturbed by other work on the host), their ratio,
and the ratio candidate / reference ("shared / fused") per round (median, min, max). Sharing is
kept only where it costs at most 1 % (docs/planner.md, *closed-loop*).
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

from planner import decentralised
from planner.instance import random_instance
from planner.problem import make_view, sample_observations
from world.paths import REPO_ROOT as REPO

#: The last commit whose kernels had the rollout loop written out in each.
REFERENCE = "6275f1fa4c2a4da15e1b38be455cfe1b0479e9c3"
SIZES = (12, 32)
#: Stages closed-loop decides in each round.
STAGES = (0, 3, 6)
#: The stage of dec-closed-loop's partial decisions, and the stage through which the others'
#: observations and deployments are known (exclusive).
PARTIAL_STAGE = 3
PARTIAL_KNOWN = 1


def _module(rev: str | None, path: str, name: str):
    """``path`` of commit ``rev`` (None: of the working tree) as module ``name``, compiled in this
    process (numba caches it in a temporary directory), so that both versions are built alike."""
    if rev is None:
        source = (REPO / path).read_text()
    else:
        source = subprocess.run(["git", "show", f"{rev}:{path}"], cwd=REPO, check=True, capture_output=True,
                                text=True).stdout
    file = Path(tempfile.mkdtemp()) / f"{name}.py"
    file.write_text(source)
    spec = importlib.util.spec_from_file_location(name, file)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def _partial_views(problem, x, j: int, known: int):
    """A LocalView per carrier with a choice at stage ``j`` that knows its own row through ``j``
    and the others' observations and deployments before stage ``known`` only."""
    R, N = problem.valid.shape
    deployed = np.zeros((R, N), dtype=bool)
    out = []
    for r in range(R):
        seen = np.full(R, known, dtype=np.int64)
        record = np.full(R, known, dtype=np.int64)
        seen[r], record[r] = j + 1, j
        obs = np.where(np.arange(N)[None, :] < seen[:, None], x, np.nan)
        local = decentralised.LocalView(problem, r, j, 0, obs, deployed, seen, record, (None,) * R)
        can, must, _, _ = local.own()
        if can and not must:
            out.append(local)
    return out


def _round(closed, dec, views, locals_, iterations: int):
    """CPU seconds of one round of each planner and what it returned."""
    start = time.process_time()
    decisions = [closed.decide(view, np.random.default_rng(11)).tobytes() for view in views]
    closed_s = time.process_time() - start
    start = time.process_time()
    scores = []
    for local in locals_:
        scored = dec.partial_scores(local, np.random.default_rng(12))
        scores.append(None if scored is None else scored[1].tobytes())
    dec_s = time.process_time() - start
    return closed_s, dec_s, decisions, scores


def measure(carriers: int, reps: int, iterations: int, shared, fused) -> dict:
    rng = np.random.default_rng(np.random.SeedSequence(77, spawn_key=(carriers,)))
    problem = random_instance(rng, carriers=carriers, passengers=3, stages=10, overlaps=10).problem
    x = sample_observations(problem, rng)
    views = [make_view(problem, j, x, np.zeros(problem.valid.shape, dtype=bool)) for j in STAGES]
    locals_ = _partial_views(problem, x, PARTIAL_STAGE, PARTIAL_KNOWN)
    versions = {
        "shared": (shared[0].ClosedLoopPlanner(iterations=iterations),
                   shared[1].DecClosedLoopPlanner(iterations=iterations)),
        "fused": (fused[0].ClosedLoopPlanner(iterations=iterations),
                  fused[1].DecClosedLoopPlanner(iterations=iterations)),
    }
    for closed, dec in versions.values():
        closed.warm_up(problem)
        dec.warm_up(problem)
    times = {name: ([], []) for name in versions}
    outputs = {}
    for rep in range(reps):
        order = ("shared", "fused") if rep % 2 == 0 else ("fused", "shared")
        for name in order:
            closed_s, dec_s, decisions, scores = _round(*versions[name], views, locals_, iterations)
            times[name][0].append(closed_s)
            times[name][1].append(dec_s)
            outputs.setdefault(name, (decisions, scores))
    same = outputs["shared"] == outputs["fused"]
    closed_ratio = np.array(times["shared"][0]) / np.array(times["fused"][0])
    dec_ratio = np.array(times["shared"][1]) / np.array(times["fused"][1]) if locals_ else np.array([np.nan])
    return {"R": carriers, "partial": len(locals_), "same": same,
            "closed": (np.min(times["fused"][0]), np.min(times["shared"][0]), closed_ratio),
            "dec": (np.min(times["fused"][1]), np.min(times["shared"][1]), dec_ratio)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tools.rollout_bench", description=__doc__.split("\n\n")[0])
    parser.add_argument("--reference", default=REFERENCE, help="commit of the fused kernels (default: %(default)s)")
    parser.add_argument("--candidate", default=None,
                        help="commit of the shared kernels (default: the working tree)")
    parser.add_argument("--sizes", default=",".join(map(str, SIZES)), help="fleet sizes R, comma-separated")
    parser.add_argument("--reps", type=int, default=7, help="alternating rounds per version")
    parser.add_argument("--iterations", type=int, default=20000, help="rollout iterations per decision")
    args = parser.parse_args(argv)
    print(f"# tools.rollout_bench  cpus={os.cpu_count()}  load average at start {os.getloadavg()[0]:.2f}  "
          f"candidate {(args.candidate or 'working tree')[:12]}  reference {args.reference[:7]}  "
          f"iterations {args.iterations}  reps {args.reps}")
    shared = (_module(args.candidate, "planner/closedloop.py", "closedloop_shared"),
              _module(args.candidate, "planner/decentralised.py", "decentralised_shared"))
    fused = (_module(args.reference, "planner/closedloop.py", "closedloop_fused"),
             _module(args.reference, "planner/decentralised.py", "decentralised_fused"))
    print("| R | planner | decisions | fused s (fastest round) | shared s (fastest round) | fastest shared / fastest "
          "fused | shared / fused per round (median, min, max) | same output |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    all_ratios = {"closed-loop": [], "dec-closed-loop": []}
    for carriers in (int(v) for v in args.sizes.split(",")):
        row = measure(carriers, args.reps, args.iterations, shared, fused)
        for label, key, count in (("closed-loop", "closed", len(STAGES)), ("dec-closed-loop", "dec", row["partial"])):
            fused_s, shared_s, ratio = row[key]
            all_ratios[label].extend(ratio.tolist())
            print(f"| {carriers} | {label} | {count} | {fused_s:.3f} | {shared_s:.3f} | {shared_s / fused_s:.4f} "
                  f"| {np.median(ratio):.4f} "
                  f"({np.min(ratio):.4f}, {np.max(ratio):.4f}) | {'yes' if row['same'] else 'NO'} |", flush=True)
    for label, ratios in all_ratios.items():
        ratios = [v for v in ratios if np.isfinite(v)]
        if ratios:
            print(f"{label}: shared / fused over {len(ratios)} rounds: median {np.median(ratios):.4f}")
    print(f"load average at end {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
