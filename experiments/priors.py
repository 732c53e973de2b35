"""The priors sweep (issue 13 part B): each planner with the stated prior, the learned prior
(``learn_prior=true``, starting from the stated one) and an oracle prior, on world scenarios.

Cases: ``urban_alpha`` with its stated (derived Poisson) prior, and ``open_field`` with its derived
Poisson mean scaled ×0.5, ×1 and ×2 (a deliberately wrong stated prior at ×0.5 and ×2).

* **stated** — the planner plans with the stated prior;
* **learned** — ``make_planner(name, learn_prior=True)`` on the same problem (planner.learning);
* **oracle** — the prior fitted by moments to the world's true observation distribution: the
  pooled counts of :func:`world.report.prior_report` (what ``python -m world check`` prints) over
  :data:`ORACLE_SEEDS` world seeds (0..199, none of them a trial's seed but by chance), as a
  negative binomial (Poisson when the variance does not exceed the mean).

Every variant of a case plans in the same reward units (the stated prior's 90th percentile) and
is scored on the same observations: trial t uses world seed ``(1001, t)`` (trial 0: the
scenario's own seed, as in the urban run) and planner seed ``(1001, t, 1)`` for every planner and
variant, so comparisons are paired.
"""
from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import numpy as np

from experiments.report import STYLE, Variants, planner_order, read_csv, sem, variant_bars, write_csv
from experiments.trials import Sweep, Task, replace_prior, urban_trial
from planner.priors import Poisson
from world.paths import REPO_ROOT as ROOT

#: (label, scenario file, factor on the stated prior's mean).
CASES = (
    ("urban_alpha", "scenarios/urban_alpha.yaml", 1.0),
    ("open_field ×0.5", "scenarios/open_field.yaml", 0.5),
    ("open_field ×1", "scenarios/open_field.yaml", 1.0),
    ("open_field ×2", "scenarios/open_field.yaml", 2.0),
)
VARIANTS = ("stated", "learned", "oracle")
DEFAULT_PLANNERS = ("closed-loop", "ssap", "mcts-ssap")
#: World seeds of the oracle fit (as ``python -m world check``'s default).
ORACLE_SEEDS = 200
FIELDS = ("case", "level", "trial", "planner", "variant", "reward", "features", "scale", "stated_mean",
          "oracle_mean", "oracle_var", "iterations", "world_seed", "planner_seed", "decision_ms_mean", "wall_s",
          "deployed")


def oracle_moments(scenario_file: str, seeds: int = ORACLE_SEEDS) -> tuple[float, float]:
    """Mean and variance of the world's pooled observed counts over ``seeds`` seeds."""
    import world
    from world.report import prior_report

    rep = prior_report(world.load_scenario(ROOT / scenario_file), seeds=seeds)
    return rep.mean, rep.var


def oracle_prior(mean: float, var: float):
    """Negative binomial with this mean and variance by moments (Poisson when var <= mean)."""
    import scipy.stats

    if var <= mean:
        return Poisson(mean)
    return scipy.stats.nbinom(mean * mean / (var - mean), mean / var)


def trial(task: Task):
    """The urban-style world trial with the task's prior variant: the stated prior (the scenario's,
    its Poisson mean scaled by ``prior_factor``) for ``stated`` and ``learned``, the oracle for
    ``oracle``; every variant keeps the stated prior's normalisation scale."""
    problem, x, planner_seed, extra = urban_trial(task)
    if task.prior_factor != 1.0:
        stated = problem.prior
        if getattr(stated.dist, "name", None) != "poisson":
            raise ValueError(f"prior_factor needs a Poisson stated prior, found {stated.dist.name}")
        problem = replace_prior(problem, Poisson(float(stated.mean()) * task.prior_factor))
    extra = {**extra, "scale": problem.scale, "stated_mean": float(problem.prior.mean()),
             "oracle_mean": task.oracle[0], "oracle_var": task.oracle[1]}
    if task.variant == "oracle":
        problem = replace_prior(problem, oracle_prior(*task.oracle), problem.scale)
    return problem, x, planner_seed, extra


def columns(task: Task, extra: dict, result) -> dict:
    """The priors sweep's own columns of a result row."""
    return dict(case=CASES[task.level][0], variant=task.variant,
                **{k: extra[k] for k in ("scale", "stated_mean", "oracle_mean", "oracle_var")})


#: How experiments.trials.run_trial runs this sweep's tasks.
SWEEP = Sweep(trial, columns)


def build_tasks(settings: dict) -> list[Task]:
    """Every (case, trial, planner, variant) task; oracle moments computed once per scenario."""
    moments = {}
    tasks = []
    for level, (_, path, factor) in enumerate(CASES):
        if path not in moments:
            moments[path] = oracle_moments(path)
        for t in range(settings["trials"]):
            for planner in settings["planners"]:
                for variant in VARIANTS:
                    tasks.append(Task("priors", level, t, planner, settings["seed"], settings["iterations"],
                                      scenario=str(ROOT / path), variant=variant, prior_factor=factor,
                                      oracle=moments[path]))
    return tasks


def write_trials(rows: list[dict], path: Path) -> None:
    write_csv(sorted(rows, key=lambda r: (r["level"], r["trial"], r["planner"], VARIANTS.index(r["variant"]))), path,
              FIELDS)


def read_trials(path: Path) -> list[dict]:
    return read_csv(path, ("level", "trial", "iterations"),
                    ("reward", "features", "scale", "stated_mean", "oracle_mean", "oracle_var", "decision_ms_mean",
                     "wall_s"))


def summarise(rows: list[dict]) -> list[dict]:
    """One row per (case, planner): mean ± SEM of each variant, ratios of means learned/oracle and
    learned/stated, and paired differences learned − oracle, learned − stated (± SEM)."""
    by = defaultdict(dict)
    for r in rows:
        by[(r["level"], r["planner"], r["trial"])][r["variant"]] = r
    groups = defaultdict(list)
    for (level, planner, _), d in by.items():
        if all(v in d for v in VARIANTS):
            groups[(level, planner)].append(d)
    out = []
    for (level, planner), ds in sorted(groups.items(), key=lambda kv: (kv[0][0], planner_order(kv[0][1]))):
        row = {"level": level, "case": CASES[level][0], "planner": planner, "n": len(ds)}
        vals = {v: np.array([d[v]["reward"] for d in ds]) for v in VARIANTS}
        for v in VARIANTS:
            row[f"{v}_mean"], row[f"{v}_sem"] = float(vals[v].mean()), sem(vals[v])
            row[f"{v}_features"] = float(np.mean([d[v]["features"] for d in ds]))
        for other in ("oracle", "stated"):
            diff = vals["learned"] - vals[other]
            row[f"learned_{other}_ratio"] = float(vals["learned"].mean() / vals[other].mean())
            row[f"learned_{other}_diff"], row[f"learned_{other}_diff_sem"] = float(diff.mean()), sem(diff)
            row[f"learned_{other}_wins"] = f"{int((diff > 1e-12).sum())}/{int((diff < -1e-12).sum())}"
        row["stated_oracle_ratio"] = float(vals["stated"].mean() / vals["oracle"].mean())
        row["decision_ms_learned"] = float(np.mean([d["learned"]["decision_ms_mean"] for d in ds]))
        row["decision_ms_stated"] = float(np.mean([d["stated"]["decision_ms_mean"] for d in ds]))
        out.append(row)
    return out


SUMMARY_FIELDS = ("case", "planner", "n", "stated_mean", "stated_sem", "learned_mean", "learned_sem", "oracle_mean",
                  "oracle_sem", "learned_oracle_ratio", "learned_stated_ratio", "stated_oracle_ratio",
                  "learned_oracle_diff", "learned_oracle_diff_sem", "learned_oracle_wins", "learned_stated_diff",
                  "learned_stated_diff_sem", "learned_stated_wins", "stated_features", "learned_features",
                  "oracle_features", "decision_ms_stated", "decision_ms_learned")


def write_summary(summary: list[dict], path: Path) -> None:
    write_csv(summary, path, SUMMARY_FIELDS)


def markdown(summary: list[dict], rows: list[dict]) -> str:
    """The table of docs/results.md."""
    stated_prior = {}
    for r in rows:
        stated_prior[r["level"]] = (r["stated_mean"], r["oracle_mean"], r["oracle_var"])
    lines = ["| case (stated mean; world mean, variance) | planner | stated | learned | oracle | learned / oracle "
             "| learned / stated | learned − oracle (wins/losses) |",
             "|---|---|---|---|---|---|---|---|"]
    for r in summary:
        sm, om, ov = stated_prior[r["level"]]
        label = STYLE.get(r["planner"], (r["planner"],))[0]
        lines.append(
            f"| {r['case']} ({sm:.2f}; {om:.2f}, {ov:.2f}) | {label} "
            f"| {r['stated_mean']:.3f} ± {r['stated_sem']:.3f} | {r['learned_mean']:.3f} ± {r['learned_sem']:.3f} "
            f"| {r['oracle_mean']:.3f} ± {r['oracle_sem']:.3f} | {100 * r['learned_oracle_ratio']:.1f}% "
            f"| {100 * r['learned_stated_ratio']:.1f}% "
            f"| {r['learned_oracle_diff']:+.3f} ± {r['learned_oracle_diff_sem']:.3f} ({r['learned_oracle_wins']}) |")
    return "\n".join(lines)


def plot(summary: list[dict], path: Path, title: str) -> None:
    """Grouped bars: each case × planner, the three variants as % of the oracle's mean, ±1 SEM."""
    variant_bars(
        summary, Variants(VARIANTS, "oracle_mean", {"stated": "#e7298a", "learned": "#1b9e77", "oracle": "#666666"},
                          {v: v for v in VARIANTS}), [f"{r['case']}\n{STYLE.get(r['planner'], (r['planner'],))[0]}" for r in summary],
        path, title, "mean reward, % of the oracle prior's (±1 SEM)", lines=(100, 95), legend_title="prior")


def write(rows: list[dict], out: Path, settings: dict, seconds: float, jobs: int) -> dict:
    """CSVs, table, plot and ``priors.md`` under ``out``; returns the run-info entry."""
    write_trials(rows, out / "priors_trials.csv")
    summary = summarise(rows)
    write_summary(summary, out / "priors_summary.csv")
    title = (f"Priors sweep: stated, learned and oracle priors, {settings['trials']} world seeds, "
             f"{settings['iterations']} iterations")
    plot(summary, out / "priors.png", title)
    text = ["## Priors sweep", "",
            f"{settings['trials']} world seeds per case, {settings['iterations']} iterations per decision "
            "(MCTS-SSAP, closed-loop). Mean normalised reward ± SEM (units: the stated prior's 90th "
            "percentile, the same for all three variants of a case); ratios of the means; paired "
            "difference learned − oracle on the same seeds.", "",
            markdown(summary, rows), "",
            f"Wall time: {seconds:.1f} s with {jobs} worker process(es) for {len(rows)} tasks."]
    (out / "priors.md").write_text("\n".join(text) + "\n")
    return {"sweep": "priors", "seconds": round(seconds, 1), "tasks": len(rows), "jobs": jobs}


def ablate_weight(planner: str, trials: int, weights: tuple[float, ...], seed: int = 1,
                  iterations: int = 2000) -> list[str]:
    """Learned/oracle and learned/stated reward ratios of ``planner`` for each prior weight n0
    (planner.learning.PRIOR_WEIGHT candidates), on world seeds of root seed ``seed`` (the sweep
    uses 0: use another to choose n0 on seeds the sweep does not score). One line per case."""
    from planner.learning import LearnedPriorPlanner
    from planner.online import run_online
    from planner.registry import make_planner

    moments, lines = {}, []
    for level, (label, path, factor) in enumerate(CASES):
        if path not in moments:
            moments[path] = oracle_moments(path)
        learned = {w: [] for w in weights}
        stated, oracle = [], []
        inner = make_planner(planner, iterations=iterations)
        for t in range(trials):
            def task(variant):
                return Task("priors", level, t, planner, seed, iterations, scenario=str(ROOT / path),
                            variant=variant, prior_factor=factor, oracle=moments[path])

            problem, x, planner_seed, _ = trial(task("stated"))
            oracle_problem = trial(task("oracle"))[0]
            stated.append(run_online(problem, x, inner, planner_seed).reward)
            oracle.append(run_online(oracle_problem, x, inner, planner_seed).reward)
            for w in weights:
                learned[w].append(run_online(problem, x, LearnedPriorPlanner(inner, weight=w), planner_seed).reward)
        o, s = float(np.mean(oracle)), float(np.mean(stated))
        lines.append(f"{label}, {planner}: stated/oracle {100 * s / o:.1f}%; " + "; ".join(
            f"n0 = {w:g}: learned/oracle {100 * np.mean(r) / o:.1f}%, learned/stated {100 * np.mean(r) / s:.1f}%"
            for w, r in learned.items()))
    return lines


if __name__ == "__main__":
    # python -m experiments.priors PLANNER TRIALS N0,N0,... [SEED]: the prior-weight ablation.
    import sys

    args = sys.argv[1:]
    for line in ablate_weight(args[0], int(args[1]), tuple(float(w) for w in args[2].split(",")),
                              int(args[3]) if len(args) > 3 else 1):
        print(line, flush=True)
