"""Where the gap to the bound is, on instances small enough for the exact V*: the bound's share
(bound − V*) and the planners' (V* − planner), for both families of ``tools.gated_search``.

    python -m tools.tiny_split --family dense --trials 0-11
    python -m tools.tiny_split --family paper --trials 0-11 --out paper_tiny.csv
    python -m tools.tiny_split --plot split.png --rows paper_tiny.csv dense_tiny.csv

Trial t of a family is its instance (``tools.gated_search.family_problem``: Poisson(3) for
``paper``, the negative binomial (n = 2, p = 0.4) for ``dense``) at R = ``--carriers`` (default 2),
N = 6, D = 2, with the family's density of overlap groups per decision point (``DENSITY``: 0.5 and
0.8, the families' 5 R and 8 R groups over their 10 R points; ``--density`` changes it), drawn
from stream ``(9100 + f, t, a)`` (f = 0 paper, 1 dense) for the first a = 0, 1, ... whose exact
solve the solver admits (``planner.online_optimal.estimate`` within its ``MAX_SECONDS``). Per trial:

* V*, the exact value of the best online policy (``planner.online_optimal.online_value``);
* the bound, ``planner.duality.upper_bound`` with its defaults for an instance this small (exact
  inner maxima, the adaptive penalty, its strength chosen on a discarded pilot), ``--bound-samples``
  matrices from stream ``(9200 + f, t)``;
* each planner (closed-loop, closed-loop-gated; ``--iterations`` per decision) and the optimal
  policy itself (``online-optimal``) flown on the same ``--obs`` observation matrices (stream
  ``(9300 + f, t, k)``, planner seed ``(9400 + f, t, k)``): the planner's fraction of V* is
  ``1 + mean(planner − optimal) / V*``, a paired estimate whose error is that of the difference
  only (V* is exact), ± its SEM.

It prints one line per trial and a summary: the bound's mean excess over V*, each planner's mean
fraction of V* and of the bound, over trials (± SEM over trials). The split of a planner's gap to
the bound, ``1 − planner / bound``, is then ``1 − V* / bound`` (the bound's) plus ``(V* − planner)
/ bound`` (the planner's).
"""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from experiments.report import sem
from tools.base_policy import parse_trials, run_trials
from tools.gated_search import FAMILIES, family_problem

#: The planners measured against the optimal policy: (column, registered name).
PLANNERS = (("closed_loop", "closed-loop"), ("gated", "closed-loop-gated"))
STAGES = 6
PASSENGERS = 2
#: Overlap groups per decision point of each family at N = 10 (5 R and 8 R groups over 10 R points).
DENSITY = {"paper": 0.5, "dense": 0.8}
#: The planners' target fraction of the bound (docs/planner.md), drawn for reference.
TARGET = 0.975
ATTEMPTS = 100


def _stream(seed: int, *key: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=key))


def tiny_problem(family: str, carriers: int, trial: int, seed: int = 0, density: float | None = None):
    """Trial ``trial``'s instance (module docstring): the first draw the exact solver admits."""
    from planner import online_optimal

    f = FAMILIES.index(family)
    groups = max(1, round((DENSITY[family] if density is None else density) * carriers * STAGES))
    for attempt in range(ATTEMPTS):
        problem, _ = family_problem(family, _stream(seed, 9100 + f, trial, attempt), carriers, PASSENGERS, STAGES,
                                    groups=groups)
        try:
            online_optimal.estimate(problem)
        except online_optimal.TooLarge:
            continue
        return problem
    raise ValueError(f"{family} trial {trial}: no draw of {ATTEMPTS} within the exact solver's limits at R = {carriers}")


def run_trial(family: str, carriers: int, trial: int, obs: int, iterations: int, bound_samples: int,
              seed: int = 0, density: float | None = None) -> dict:
    """One trial's V*, bound and the planners' paired rewards (module docstring)."""
    from experiments.trials import seed_of
    from planner import duality, online_optimal
    from planner.online import run_online
    from planner.problem import sample_observations
    from planner.registry import make_planner

    f = FAMILIES.index(family)
    t0 = time.perf_counter()
    problem = tiny_problem(family, carriers, trial, seed, density)
    v_star = online_optimal.online_value(problem).expected_reward
    bound = duality.upper_bound(problem, _stream(seed, 9200 + f, trial), bound_samples, method="exact")
    planners = {"optimal": make_planner("online-optimal")}
    planners.update({column: make_planner(name, iterations=iterations) for column, name in PLANNERS})
    rewards = {name: [] for name in planners}
    for k in range(obs):
        x = sample_observations(problem, _stream(seed, 9300 + f, trial, k))
        planner_seed = seed_of(seed, (9400 + f, trial, k))
        for name, planner in planners.items():
            rewards[name].append(run_online(problem, x, planner, planner_seed).reward)
    row = {"family": family, "carriers": carriers, "trial": trial, "groups": len(problem.overlaps), "obs": obs,
           "v_star": v_star, "bound": bound.expected_reward, "bound_stderr": bound.stderr,
           "strength": bound.strength, "optimal_mc": float(np.mean(rewards["optimal"]))}
    optimal = np.array(rewards["optimal"])
    for column, _ in PLANNERS:
        diff = np.array(rewards[column]) - optimal
        row[column] = float(np.mean(rewards[column]))
        row[column + "_fraction"] = 1.0 + float(diff.mean()) / v_star
        row[column + "_fraction_sem"] = sem(diff) / v_star
    row["wall_s"] = time.perf_counter() - t0
    return row


def summary(rows: list[dict]) -> list[str]:
    first = rows[0]
    excess = np.array([r["bound"] / r["v_star"] - 1.0 for r in rows])
    lines = [f"{first['family']}, R = {first['carriers']}, N = {STAGES}, D = {PASSENGERS}, {len(rows)} trials "
             f"({first['trial']}..{rows[-1]['trial']}), {first['obs']} observation matrices each:",
             f"  bound over V*: {100 * excess.mean():+.2f} % ± {100 * sem(excess):.2f} % "
             f"(V* / bound {np.mean([r['v_star'] / r['bound'] for r in rows]):.4f})"]
    for column, name in PLANNERS:
        of_v = np.array([r[column + "_fraction"] for r in rows])
        of_bound = np.array([r[column + "_fraction"] * r["v_star"] / r["bound"] for r in rows])
        lines.append(f"  {name:17s}: {of_v.mean():.4f} ± {sem(of_v):.4f} of V*, {of_bound.mean():.4f} ± "
                     f"{sem(of_bound):.4f} of the bound (gap to the bound {100 * (1 - of_bound.mean()):.2f} %: "
                     f"the bound's {100 * np.mean([1 - r['v_star'] / r['bound'] for r in rows]):.2f} %, the planner's "
                     f"{100 * np.mean([(1 - r[column + '_fraction']) * r['v_star'] / r['bound'] for r in rows]):.2f} %)")
    return lines


FLOATS = ("v_star", "bound", "bound_stderr") + tuple(f"{c}{s}" for c, _ in PLANNERS for s in ("_fraction", "_fraction_sem"))


def plot(tables: list[list[dict]], path) -> None:
    """One panel per family: per trial (sorted by the bound's excess) the bound, closed-loop-gated and
    closed-loop as fractions of V*, ± 2 SEM."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    fig, axes = plt.subplots(1, len(tables), figsize=(6.2 * len(tables), 4.4), sharey=True, squeeze=False)
    for ax, rows in zip(axes[0], tables):
        rows = sorted(rows, key=lambda r: r["bound"] / r["v_star"])
        t = np.arange(len(rows))
        bound = np.array([r["bound"] / r["v_star"] for r in rows])
        ax.errorbar(t, bound, yerr=2 * np.array([r["bound_stderr"] / r["v_star"] for r in rows]), fmt="^",
                    color="tab:red", ms=4, lw=0.8, label=f"bound (mean {bound.mean():.3f})")
        for (column, name), colour, marker in zip(PLANNERS, ("tab:gray", "tab:blue"), ("x", "o")):
            y = np.array([r[column + "_fraction"] for r in rows])
            ax.errorbar(t + (0.2 if column == "gated" else -0.2), y, yerr=2 * np.array([r[column + "_fraction_sem"] for r in rows]),
                        fmt=marker, color=colour, ms=4, lw=0.8, label=f"{name} (mean {y.mean():.4f})")
        ax.axhline(1.0, color="black", lw=0.8)
        target = TARGET * bound.mean()
        ax.axhline(target, color="tab:red", lw=0.8, ls="--", label=f"{TARGET} of the mean bound ({target:.3f})")
        first = rows[0]
        ax.set_title(f"{first['family']}: R = {first['carriers']}, {first['groups']} overlap groups, "
                     f"{len(rows)} instances")
        ax.set_xlabel("instance (sorted by the bound's excess over V*)")
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="upper left")
    axes[0][0].set_ylabel("value / V* (exact online optimum)")
    fig.suptitle("Where the gap to the bound is: the bound above V*, the planners below it (± 2 SEM)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tools.tiny_split", description=__doc__.split("\n\n")[0])
    parser.add_argument("--family", default="dense", choices=FAMILIES, help="instance family (default dense)")
    parser.add_argument("--carriers", type=int, default=2, help="R (default 2; 3 is mostly beyond the exact solver)")
    parser.add_argument("--trials", default="0-11", help="trial indices, e.g. 0-11 or 0,2 (default 0-11)")
    parser.add_argument("--obs", type=int, default=400, help="observation matrices per trial (default 400)")
    parser.add_argument("--iterations", type=int, default=2000, help="iterations per decision (default 2000)")
    parser.add_argument("--bound-samples", type=int, default=400, help="the bound's matrices (default 400)")
    parser.add_argument("--density", type=float, default=None,
                        help="overlap groups per decision point (default: the family's, 0.5 paper, 0.8 dense)")
    parser.add_argument("--seed", type=int, default=0, help="root seed of the trials (default 0)")
    parser.add_argument("--out", default=None, help="also write the per-trial rows to this CSV")
    parser.add_argument("--plot", default=None, help="draw the rows of --rows to this PNG (no measurement)")
    parser.add_argument("--rows", nargs="+", default=(), help="CSVs written by --out, one panel each (with --plot)")
    args = parser.parse_args(argv)
    if args.plot:
        from experiments.report import read_csv

        if not args.rows:
            parser.error("--plot: expected the CSVs to draw after --rows")
        tables = []
        for path in args.rows:
            try:
                tables.append(read_csv(path, ("carriers", "trial", "groups", "obs"), FLOATS))
            except (OSError, KeyError, ValueError) as err:
                parser.error(f"--rows {path}: expected a CSV written by --out ({err})")
            if not tables[-1]:
                parser.error(f"--rows {path}: no rows")
        plot(tables, args.plot)
        print(f"wrote {args.plot}")
        return 0
    if args.carriers < 2 or args.iterations < 1 or args.obs < 2 or args.bound_samples < 2:
        parser.error("--carriers, --obs and --bound-samples must be at least 2, --iterations at least 1")
    if args.density is not None and not 0 < args.density <= 4:
        parser.error(f"--density: expected groups per decision point in (0, 4], found {args.density:g}")
    try:
        trials = parse_trials(args.trials)
    except ValueError:
        parser.error(f"--trials: expected indices like 0-11 or 0,2, found {args.trials!r}")
    try:
        run_trials(trials, lambda t: run_trial(args.family, args.carriers, t, args.obs, args.iterations,
                                               args.bound_samples, args.seed, args.density),
                   lambda row: f"{row['groups']} groups  V* {row['v_star']:.4f}  bound {row['bound']:.4f} ± "
                               f"{row['bound_stderr']:.4f} ({100 * (row['bound'] / row['v_star'] - 1):+.2f} %)  "
                               + "  ".join(f"{name} {row[c + '_fraction']:.4f} ± {row[c + '_fraction_sem']:.4f} of V*"
                                           for c, name in PLANNERS) + f"  ({row['wall_s']:.0f} s)",
                   summary, args.out)
    except ValueError as err:  # a trial with no instance the exact solver admits
        print(err, file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
