"""The operator in the loop, measured: the planner deciding alone against simulated operators
who overrule it through the same constraints the console sends (docs/results.md, "The operator
in the loop").

    python -m experiments operator [--trials 30] [--urban-trials 10] [--iterations 1000] [--seed 0]
        [--scenario [NAME=]S.yaml]... [--only-scenarios] [--quick] [--out DIR]

Operators (:data:`OPERATORS`), each a function of what the console shows at a stage:

* ``autonomous``: approves every recommendation;
* ``manual-trigger``: triggers deployments by hand as SubT operators did: a carrier deploys when
  its count looks high (at least the prior's 75th percentile) or when it must, blind to conflicts
  and to the future; the planner's recommendation is ignored (every other carrier vetoed);
* ``random-veto``: vetoes each recommended deployment with probability 0.3 (a drone needed
  elsewhere, a spot judged unsafe), never one that must happen;
* ``force-high``: approves the planner but forces every carrier whose count reaches the prior's
  90th percentile.

Each stage runs :func:`planner.online.stage_step` as the coordinator does: the recommendation,
then the operator's constraints, then the planner's decision of the rest under them; the
planner's estimate of each override's gain (:func:`planner.advice.override_gain`) is summed per
trial beside the reward actually gained over the autonomous run of the same trial. Worlds: the
paper's overlap sweep (4 carriers, 3 passengers, 10 stages, Poisson(3), 0..20 overlap groups),
the Urban Circuit run (scenarios/urban_alpha.yaml, a world seed per trial) and each ``--scenario``
given (a team's own run as ``python -m world import`` wrote it, named by ``NAME`` or by the file's
stem), as the urban run is: ``--urban-trials`` world seeds, the first the scenario's own (a run
imported with ``--replay`` is one world: its trials differ in the planner's and the operator's
random streams only). ``--only-scenarios`` measures the given runs alone.
"""
from __future__ import annotations

import argparse
import csv
import math
import time
from pathlib import Path

import numpy as np

from planner.advice import override_gain
from planner.constraints import Constraints
from planner.online import stage_step
from planner.problem import evaluate, make_view, stage_rng, start_online
from planner.registry import make_planner

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "results" / "operator"
URBAN = ROOT / "scenarios" / "urban_alpha.yaml"
OPERATORS = ("autonomous", "manual-trigger", "random-veto", "force-high")
OVERLAPS = (0, 4, 8, 12, 16, 20)
#: How the plot names a run world (others by their own name).
RUN_LABELS = {"urban": "Urban Circuit\n(urban_alpha)"}
#: Probability that the random-veto operator vetoes a recommended deployment.
VETO_P = 0.3


def operator_constraints(name: str, view, recommended: np.ndarray, rng: np.random.Generator) -> Constraints:
    """What operator ``name`` does with the stage the view shows and the planner's recommendation."""
    can, must = view.can_deploy, view.must_deploy
    x = view.observations[:, view.stage]
    if name == "autonomous":
        return Constraints()
    if name == "manual-trigger":
        high = float(view.problem.prior.ppf(0.75))
        deploy = can & ((x >= high) | must)
        return Constraints(frozenset(np.flatnonzero(deploy)), frozenset(np.flatnonzero(can & ~deploy)))
    if name == "random-veto":
        draws = rng.random(len(x))  # one per carrier, always drawn: the stream does not depend on the plan
        return Constraints(vetoed=frozenset(np.flatnonzero(recommended & ~must & (draws < VETO_P))))
    if name == "force-high":
        high = float(view.problem.prior.ppf(0.9))
        return Constraints(forced=frozenset(np.flatnonzero(can & ~recommended & (x >= high))))
    raise ValueError(f"unknown operator {name!r}")


def run_with_operator(problem, x: np.ndarray, planner, seed: int, name: str) -> dict:
    """One mission offline with operator ``name``: reward, features, overrides and the planner's
    summed estimate of what they gained."""
    x, released = start_online(problem, x, planner)
    deployed = np.zeros(problem.valid.shape, dtype=bool)
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(45,)))
    overrides, estimate = 0, 0.0
    for j in range(problem.n_stages):
        first = stage_step(problem, x, deployed, planner, seed, j)
        view = make_view(problem, j, x, deployed)
        constraints = operator_constraints(name, view, first.deploy, rng)
        step = stage_step(problem, x, deployed, planner, seed, j, constraints=constraints) if constraints else first
        if not np.array_equal(step.deploy, first.deploy):
            overrides += 1
            gain = override_gain(view, first.deploy, step.deploy, stage_rng(seed + 1, j))
            estimate += 0.0 if gain is None else gain
        deployed[:, j] = step.deploy
    reward, features = evaluate(problem, deployed, x)
    return {"reward": float(reward), "features": float(features), "overrides": overrides, "estimate": float(estimate),
            "deployments": int(deployed.sum())}


def trials(args) -> list[dict]:
    """Every (world, level, trial, operator) row."""
    from experiments.trials import Task, random_trial, urban_trial

    planner = make_planner("mcts-ssap", iterations=args.iterations)
    planner.warm_up(None)
    rows = []
    worlds = [("overlap", level, str(URBAN)) for level in (() if args.only_scenarios else args.overlaps)]
    worlds += [(name, 0, str(path)) for name, path in args.scenarios]
    for world, level, scenario in worlds:
        for t in range(args.trials if world == "overlap" else args.urban_trials):
            task = Task(world, level, t, "mcts-ssap", args.seed, args.iterations, overlaps=level, scenario=scenario)
            problem, x, seed, _ = (random_trial if world == "overlap" else urban_trial)(task)
            base = None
            for name in OPERATORS:
                out = run_with_operator(problem, x, planner, seed, name)
                base = out["reward"] if name == "autonomous" else base
                rows.append({"world": world, "level": level, "trial": t, "operator": name, **out,
                             "gained": out["reward"] - base})
    return rows


def summarise(rows: list[dict]) -> list[dict]:
    out = []
    for key in dict.fromkeys((r["world"], r["level"]) for r in rows):  # in the order the worlds ran
        for name in OPERATORS:
            sel = [r for r in rows if (r["world"], r["level"]) == key and r["operator"] == name]
            rewards = np.array([r["reward"] for r in sel])
            base = np.array([r["reward"] for r in rows if (r["world"], r["level"]) == key
                             and r["operator"] == "autonomous"])
            out.append({"world": key[0], "level": key[1], "operator": name, "trials": len(sel),
                        "reward": float(rewards.mean()),
                        "se": float(rewards.std(ddof=1) / math.sqrt(len(sel))) if len(sel) > 1 else 0.0,
                        "kept": float(rewards.sum() / base.sum()) if base.sum() > 0 else float("nan"),
                        "overrides": float(np.mean([r["overrides"] for r in sel])),
                        "estimated_gain": float(np.mean([r["estimate"] for r in sel])),
                        "realised_gain": float(np.mean([r["gained"] for r in sel]))})
    return out


def plot(summary: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colours = {"autonomous": "#222222", "manual-trigger": "#b3261e", "random-veto": "#b36b00", "force-high": "#1f4fbf"}
    sweep = any(s["world"] == "overlap" for s in summary)
    if sweep:
        fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 4.2), gridspec_kw={"width_ratios": [2.2, 1]})
        for name in OPERATORS:
            sel = [s for s in summary if s["world"] == "overlap" and s["operator"] == name]
            ax.errorbar([s["level"] for s in sel], [s["reward"] for s in sel], yerr=[s["se"] for s in sel],
                        label=name, color=colours[name], marker="o", capsize=3)
        ax.set_xlabel("overlap groups")
        ax.set_ylabel("mean normalised reward (MCTS-SSAP + operator)")
        ax.set_title("Overlap sweep (R = 4, D = 3, N = 10)")
        ax.legend(frameon=False)
    else:  # --only-scenarios
        fig, bx = plt.subplots(figsize=(5.5, 4.2))
    runs = list(dict.fromkeys(s["world"] for s in summary if s["world"] != "overlap"))
    width = 0.8 / len(OPERATORS)
    base = [next(s for s in summary if s["world"] == run and s["operator"] == "autonomous")["reward"] for run in runs]
    for k, name in enumerate(OPERATORS):
        sel = [next(s for s in summary if s["world"] == run and s["operator"] == name) for run in runs]
        bx.bar(np.arange(len(runs)) + (k - (len(OPERATORS) - 1) / 2) * width, [100 * s["kept"] for s in sel],
               width, yerr=[100 * s["se"] / b if b > 0 else 0.0 for s, b in zip(sel, base)], color=colours[name],
               capsize=2)
    bx.axhline(100, color="#888888", lw=0.8, ls=":")
    bx.set_xticks(range(len(runs)), [RUN_LABELS.get(run, run) for run in runs])
    bx.set_title("Runs: reward kept against autonomous")
    bx.set_ylabel("% of the autonomous planner's reward")
    if not sweep:
        bx.legend([plt.Rectangle((0, 0), 1, 1, color=colours[n]) for n in OPERATORS], OPERATORS, frameon=False,
                  loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write(rows, summary, out: Path, args, seconds: float) -> None:
    out.mkdir(parents=True, exist_ok=True)
    for name, table in (("operator_trials.csv", rows), ("operator_summary.csv", summary)):
        with open(out / name, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(table[0]))
            w.writeheader()
            w.writerows(table)
    plot(summary, out / "operator.png")
    given = "".join(f" --scenario {name}={path}" for name, path in args.scenarios if path != URBAN)
    given += " --only-scenarios" if args.only_scenarios else ""
    lines = [f"# The operator in the loop (`python -m experiments operator --trials {args.trials} --urban-trials "
             f"{args.urban_trials} --iterations {args.iterations} --seed {args.seed}{given}`, {seconds:.0f} s)", "",
             "| world | overlaps | operator | trials | reward | ± se | kept vs autonomous | overrides / mission "
             "| planner's estimated gain | realised gain |", "| --- | ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for s in summary:
        lines.append(f"| {s['world']} | {s['level'] if s['world'] == 'overlap' else '–'} | {s['operator']} | "
                     f"{s['trials']} | {s['reward']:.3f} | {s['se']:.3f} | {100 * s['kept']:.1f} % | "
                     f"{s['overrides']:.1f} | {s['estimated_gain']:+.3f} | {s['realised_gain']:+.3f} |")
    (out / "operator.md").write_text("\n".join(lines) + "\n")


def _scenario_problem(path: Path) -> str:
    """Why the scenario file at ``path`` cannot be measured ('' when it can), in one line."""
    import world

    if not path.is_file():
        return f"expected a scenario file, found {'a folder' if path.exists() else 'nothing'} at {path}"
    try:
        world.load_scenario(str(path))
    except (world.ScenarioError, OSError) as e:
        return str(e).splitlines()[0]
    return ""


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m experiments operator", description=__doc__.split("\n\n")[0])
    p.add_argument("--trials", type=int, default=30, help="trials per overlap level (default 30; quick 3)")
    p.add_argument("--urban-trials", type=int, default=10,
                   help="world seeds of the urban run and of each --scenario (default 10; quick 2)")
    p.add_argument("--scenario", action="append", default=[], metavar="[NAME=]S.yaml",
                   help="a run of your own (a scenario file, e.g. as `python -m world import` wrote it) measured "
                        "as the urban run is, named NAME or by the file's stem; repeatable")
    p.add_argument("--iterations", type=int, default=1000, help="MCTS-SSAP iterations per decision (default 1000)")
    p.add_argument("--seed", type=int, default=0, help="root seed (default 0)")
    p.add_argument("--quick", action="store_true", help="tiny settings for a smoke test")
    p.add_argument("--out", type=Path, default=None, help=f"output directory (default {OUT.relative_to(ROOT)})")
    p.add_argument("--only-scenarios", action="store_true",
                   help="measure the --scenario runs alone (not the overlap sweep and the urban run)")
    args = p.parse_args(argv)
    for flag in ("trials", "urban_trials", "iterations"):
        if getattr(args, flag) < 1:
            p.exit(2, f"python -m experiments operator: --{flag.replace('_', '-')}: expected an integer >= 1, "
                      f"found {getattr(args, flag)}\n")
    if args.quick:
        args.trials, args.urban_trials, args.iterations = 3, 2, 200
    if args.only_scenarios and not args.scenario:
        p.exit(2, "python -m experiments operator: --only-scenarios: expected at least one --scenario, found none\n")
    args.scenarios = [] if args.only_scenarios else [("urban", URBAN)]
    for given in args.scenario:
        name, _, path = given.rpartition("=") if "=" in given else ("", "", given)
        path = Path(path)
        name = name or path.stem
        problem = _scenario_problem(path)
        if problem:
            p.exit(2, f"python -m experiments operator: --scenario {given}: {problem}\n")
        if name == "overlap" or name in dict(args.scenarios):
            p.exit(2, f"python -m experiments operator: --scenario {given}: expected a name not yet used "
                      f"(overlap, {', '.join(dict(args.scenarios))}), found {name!r}; name it NAME=S.yaml\n")
        args.scenarios.append((name, path))
    args.overlaps = (0, 10, 20) if args.quick else OVERLAPS
    out = args.out or (Path("runs/operator-quick") if args.quick else OUT)
    started = time.perf_counter()
    rows = trials(args)
    summary = summarise(rows)
    write(rows, summary, out, args, time.perf_counter() - started)
    print((out / "operator.md").read_text())
    print(f"wrote {out}/operator.md, operator.png, operator_trials.csv, operator_summary.csv")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
