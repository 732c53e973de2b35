"""Decision time against fleet size, offline: the planners alone, on the scale benchmark's grids.

    python -m tools.decision_scale                                  # R = 32, 64, 128, 256, 1024
    python -m tools.decision_scale --sizes 32,128 --probes 8 --out docs/results/decision_scale.json \\
        --plot docs/results/decision_scale.png

For each R it builds ``tools.scale.grid_scenario(R, seed)`` (the fleet benchmark's scenarios),
observes it once (``world.observe_all``) and runs, stage by stage on one thread:

* ``closed-loop`` as the coordinator runs it (blocks of ``BLOCK`` carriers), and the same
  planner searching whole conflict components (``block = 0``, the previous planner) as the
  baseline, for R up to ``--baseline-max``: decision time per stage (mean, max), per carrier,
  and the mission's reward;
* ``dec-closed-loop`` on board: at every stage, ``--probes`` carriers drawn from those with a
  choice decide alone from what they would hear in a fleet run (their own row and the carriers
  ``mission.peers.listened`` names, fed through a ``PeerBook``), on the states closed-loop's
  mission passes through; time per carrier decision (mean, max), with blocks and without.

Timed with ``time.perf_counter`` around each decision after a warm-up; figures are for the
machine it runs on, ratios are against the baseline measured in the same run.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

DEFAULT_SIZES = (32, 64, 128, 256, 1024)


def _onboard_times(problem, x, dep, j, probes, planners, seed, rng):
    """Seconds per on-board decision of each planner in ``planners`` for ``probes`` carriers with
    a choice at stage ``j``, each seeing only what it hears (``listened``)."""
    from mission.peers import PeerBook, listened
    from planner.problem import stage_rng

    R, N = problem.valid.shape
    left = problem.passengers - dep[:, :j].sum(axis=1)
    stages_left = problem.valid[:, j:].sum(axis=1)
    choice = np.flatnonzero(problem.valid[:, j] & (left > 0) & (stages_left > left))
    if len(choice) == 0:
        return {name: [] for name in planners}
    picked = rng.choice(choice, size=min(probes, len(choice)), replace=False)
    ids = [str(r) for r in range(R)]
    out = {name: [] for name in planners}
    for r in sorted(int(c) for c in picked):
        book = PeerBook(ids, problem.valid)
        for b in [r, *listened(problem, r)]:
            for t in range(j + 1):
                if problem.valid[b, t]:
                    book.observation(ids[b], t, None if np.isnan(x[b, t]) else float(x[b, t]))
            for t in range(j):
                book.outcome(ids[b], t, bool(dep[b, t]))
        local = book.local_view(problem, ids[r], j, seed)
        for name, planner in planners.items():
            t0 = time.perf_counter()
            planner.decide_local(local, stage_rng(seed, j))
            out[name].append(time.perf_counter() - t0)
    return out


def measure(n_carriers: int, seed: int, probes: int, baseline: bool, iterations: int, log=print) -> dict:
    """The figures of one fleet size (see the module docstring)."""
    import world
    from planner.closedloop import ClosedLoopPlanner
    from planner.decentralised import DecClosedLoopPlanner
    from planner.online import run_online
    from tools.scale import write_scenario

    with tempfile.TemporaryDirectory() as tmp:
        scenario = world.load_scenario(write_scenario(n_carriers, Path(tmp) / "grid.yaml", seed=seed))
    problem = world.build_problem(scenario)
    x = world.observe_all(scenario)
    row = {"R": n_carriers, "seed": seed, "iterations": iterations}

    variants = {"blocks": {}}
    if baseline:
        variants["whole"] = {"block": 0}
    deployed = None
    for name, opts in variants.items():
        log(f"  R={n_carriers} closed-loop ({name}) ...")
        result = run_online(problem, x, ClosedLoopPlanner(iterations=iterations, **opts), seed)  # warms up first
        times = np.asarray(result.decision_ms)
        row[f"closed_loop_{name}_mean_ms"] = float(times.mean())
        row[f"closed_loop_{name}_max_ms"] = float(times.max())
        row[f"closed_loop_{name}_per_carrier_ms"] = float(times.mean() / n_carriers)
        row[f"closed_loop_{name}_reward"] = float(result.reward)
        if name == "blocks":
            deployed = result.deployed  # the states of the mission the coordinator runs
    if probes > 0:
        onboard = {name: DecClosedLoopPlanner(iterations=iterations, **opts) for name, opts in variants.items()}
        for planner in onboard.values():
            planner.warm_up(problem)
        probe_rng = np.random.default_rng(np.random.SeedSequence([seed, n_carriers, 7]))
        onboard_s = {name: [] for name in variants}
        for j in range(problem.n_stages):
            log(f"  R={n_carriers} dec-closed-loop on board: stage {j} of 0..{problem.n_stages - 1}")
            for key, values in _onboard_times(problem, x, deployed, j, probes, onboard, seed, probe_rng).items():
                onboard_s[key].extend(values)
        for name, values in onboard_s.items():
            if values:
                row[f"onboard_{name}_mean_ms"] = float(np.mean(values) * 1e3)
                row[f"onboard_{name}_max_ms"] = float(np.max(values) * 1e3)
                row[f"onboard_{name}_decisions"] = len(values)
    if baseline:
        row["closed_loop_speedup"] = row["closed_loop_whole_mean_ms"] / row["closed_loop_blocks_mean_ms"]
        row["reward_ratio"] = row["closed_loop_blocks_reward"] / row["closed_loop_whole_reward"]
    return row


COLUMNS = (
    ("R", "R", "{}"),
    ("closed_loop_blocks_mean_ms", "closed-loop ms", "{:.0f}"),
    ("closed_loop_blocks_max_ms", "max ms", "{:.0f}"),
    ("closed_loop_blocks_per_carrier_ms", "ms/carrier", "{:.2f}"),
    ("closed_loop_whole_mean_ms", "whole comps ms", "{:.0f}"),
    ("closed_loop_speedup", "speed-up", "{:.2f}x"),
    ("closed_loop_blocks_reward", "reward", "{:.1f}"),
    ("closed_loop_whole_reward", "whole reward", "{:.1f}"),
    ("onboard_blocks_mean_ms", "on-board ms", "{:.1f}"),
    ("onboard_blocks_max_ms", "on-board max", "{:.1f}"),
    ("onboard_whole_mean_ms", "whole on-board ms", "{:.1f}"),
)


def table(rows) -> str:
    """The rows as a Markdown table ("–" where a figure was not measured)."""
    lines = ["| " + " | ".join(title for _, title, _ in COLUMNS) + " |",
             "|" + "---|" * len(COLUMNS)]
    for row in rows:
        cells = [fmt.format(row[key]) if key in row else "–" for key, _, fmt in COLUMNS]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def plot(rows, path: Path) -> None:
    """Decision time against R (log-log) with a line of slope 1 through the smallest R."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    rs = np.array([row["R"] for row in rows], dtype=float)
    for key, label, style in (("closed_loop_blocks_mean_ms", "closed-loop, blocks (per stage)", "o-"),
                              ("closed_loop_whole_mean_ms", "closed-loop, whole components (before)", "s--"),
                              ("onboard_blocks_mean_ms", "dec-closed-loop on board, blocks (per carrier)", "^-"),
                              ("onboard_whole_mean_ms", "dec-closed-loop on board, whole components", "v--")):
        pts = [(row["R"], row[key]) for row in rows if key in row]
        if pts:
            ax.plot(*zip(*pts), style, label=label)
    first = rows[0].get("closed_loop_blocks_mean_ms")
    if first:
        ax.plot(rs, first * rs / rs[0], ":", color="grey", label="linear in R")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("carriers R")
    ax.set_ylabel("decision time (ms)")
    ax.set_title("Planner decision time against fleet size (grid scenarios)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    from planner.settings import DEFAULT_ITERATIONS

    ap = argparse.ArgumentParser(prog="python -m tools.decision_scale", description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default=",".join(map(str, DEFAULT_SIZES)), help="fleet sizes, comma-separated")
    ap.add_argument("--seed", type=int, default=1, help="scenario seed (default 1, as tools.scale)")
    ap.add_argument("--iterations", type=int, default=DEFAULT_ITERATIONS, help="planner budget (default %(default)s)")
    ap.add_argument("--probes", type=int, default=8, help="on-board decisions timed per stage (default 8)")
    ap.add_argument("--baseline-max", type=int, default=256,
                    help="largest R also run with whole components (default 256)")
    ap.add_argument("--out", type=Path, help="write the rows as JSON here")
    ap.add_argument("--plot", type=Path, help="write the plot (PNG) here")
    args = ap.parse_args(argv)
    try:
        sizes = [int(s) for s in args.sizes.split(",") if s.strip()]
    except ValueError:
        print(f"--sizes: expected comma-separated integers, got {args.sizes!r}", file=sys.stderr)
        return 2
    if not sizes or min(sizes) < 2:
        print(f"--sizes: expected fleet sizes of at least 2, got {args.sizes!r}", file=sys.stderr)
        return 2
    rows = []
    for n in sizes:
        print(f"R = {n} ...", file=sys.stderr, flush=True)
        rows.append(measure(n, args.seed, args.probes, n <= args.baseline_max, args.iterations,
                            log=lambda line: print(line, file=sys.stderr, flush=True)))
        print(table(rows[-1:]).splitlines()[-1], file=sys.stderr, flush=True)
    print(table(rows))
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(rows, indent=1) + "\n")
    if args.plot is not None:
        plot(rows, args.plot)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
