"""The passenger-types sweep (issue 13 part A): type-aware planners against type-blind ones.

Every carrier carries passengers of two types, listed in a fixed order: one aerial scout (value
weight 1.0) and small rovers (0.4; two on a carrier of three). Even carriers list the scout first, odd carriers
last, so that a fixed release order is not by chance the good one.

* **aware** — the planner as registered: it decides with the passenger values (closed-loop's
  rollouts and control variate, the clairvoyant bound) and releases, at each deployment, the
  passenger of the observation's DLR rank (:mod:`planner.passengers`);
* **choice** — :class:`planner.passengers.UnweightedSearch`: the planner decides *whether* to
  deploy as if every passenger weighed 1, and the passenger is chosen by the rank rule (what the
  values are worth inside a planner's search: aware − choice);
* **blind** — :class:`planner.passengers.TypeBlind`: the same planner deciding as if every
  passenger weighed 1, releasing passengers in the listed order.

Both are scored with the passenger values on the same observations (paired), with the same planner
seed; the clairvoyant bound (with values) is the reference. Cases (``level``):

0. random paper-style instances, R = 4, D = 3, N = 10, no overlaps (SSAP is optimal here);
1. the same with 20 overlap groups;
2. ``scenarios/urban_types.yaml``: the ``urban_alpha`` world (R = 3, D = 3, 3, 2, N = 19) with the
   passengers its file lists (a scout 1.0 and rovers 0.4 per carrier; the scout first on alpha
   and charlie, last on bravo).

Streams as the other sweeps (:mod:`experiments.trials`): trial t's instance ``(1000, t)`` (random
cases) or world seed ``(1001, t)`` (urban), planner seed ``(1000|1001, t, 1)``.
"""
from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import numpy as np

from experiments.report import STYLE, Variants, planner_order, read_csv, sem, variant_bars, write_csv
from experiments.trials import CLAIRVOYANT, Sweep, Task, encode_released, seed_of, urban_trial
from world.paths import REPO_ROOT as ROOT

SCOUT, ROVER = 1.0, 0.4
#: (label, overlaps or None for the urban world).
CASES = (("random, 0 overlaps", 0), ("random, 20 overlaps", 20), ("urban_types", None))
VARIANTS = ("aware", "choice", "blind")
DEFAULT_PLANNERS = ("closed-loop", "ssap", "mcts-ssap", "random")
URBAN = ROOT / "scenarios" / "urban_types.yaml"


def fleet_values(passengers) -> tuple[tuple[float, ...], ...]:
    """Per carrier (``passengers[r]`` passengers), its passengers' weights in listed order: one
    scout and rovers, the scout first on even carriers and last on odd ones."""
    out = []
    for r, d in enumerate(passengers):
        row = [ROVER] * int(d)
        if d:
            row[0 if r % 2 == 0 else -1] = SCOUT
        out.append(tuple(row))
    return tuple(out)


def trial(task: Task):
    """A trial of the passenger-types sweep: the random or urban instance with every carrier's
    passenger values."""
    from planner.instance import random_instance
    from planner.problem import Problem

    if task.scenario:
        problem, x, planner_seed, extra = urban_trial(task)
        if problem.weights is None:  # a scenario without passenger types: the sweep's two types
            problem = Problem.build(problem.passengers, problem.valid, problem.overlaps, problem.prior,
                                    weights=fleet_values(problem.passengers))
        return problem, x, planner_seed, extra
    rng = np.random.default_rng(np.random.SeedSequence(task.seed, spawn_key=(1000, task.trial)))
    inst = random_instance(rng, task.carriers, task.passengers, task.stages, task.overlaps, task.mean,
                           weights=fleet_values([task.passengers] * task.carriers))
    return inst.problem, inst.observations, seed_of(task.seed, (1000, task.trial, 1)), {}


def columns(task: Task, extra: dict, result) -> dict:
    """The types sweep's own columns of a result row."""
    return dict(case=CASES[task.level][0], variant=task.variant, released=encode_released(result.released))


def wrap(task: Task, planner):
    """The task's variant of ``planner``: type-blind, or searching as if unweighted (``choice``)."""
    if task.variant not in ("blind", "choice"):
        return planner
    from planner.passengers import TypeBlind, UnweightedSearch

    return (TypeBlind if task.variant == "blind" else UnweightedSearch)(planner)


#: How experiments.trials.run_trial runs this sweep's tasks.
SWEEP = Sweep(trial, columns, wrap)


def build_tasks(settings: dict) -> list[Task]:
    tasks = []
    for level, (_, overlaps) in enumerate(CASES):
        for t in range(settings["trials"]):
            common = dict(sweep="types", level=level, trial=t, seed=settings["seed"],
                          iterations=settings["iterations"])
            if overlaps is None:
                common.update(scenario=str(URBAN), carriers=3, stages=19)
            else:
                common.update(carriers=4, overlaps=overlaps)
            tasks.append(Task(planner=CLAIRVOYANT, variant="aware", **common))
            for planner in settings["planners"]:
                for variant in VARIANTS:
                    tasks.append(Task(planner=planner, variant=variant, **common))
    return tasks


FIELDS = ("case", "level", "trial", "planner", "variant", "reward", "features", "iterations", "world_seed",
          "planner_seed", "decision_ms_mean", "wall_s", "deployed", "released")


def write_trials(rows: list[dict], path: Path) -> None:
    write_csv(sorted(rows, key=lambda r: (r["level"], r["trial"], planner_order(r["planner"]), r["variant"])), path, FIELDS)


def read_trials(path: Path) -> list[dict]:
    return read_csv(path, ("level", "trial", "iterations"), ("reward", "features", "decision_ms_mean", "wall_s"))


def summarise(rows: list[dict]) -> list[dict]:
    """One row per (case, planner): aware and blind mean ± SEM, both as % of the clairvoyant mean,
    and the paired difference aware − blind (± SEM, wins/losses)."""
    bound = defaultdict(dict)
    for r in rows:
        if r["planner"] == CLAIRVOYANT:
            bound[r["level"]][r["trial"]] = r["reward"]
    by = defaultdict(dict)
    for r in rows:
        if r["planner"] != CLAIRVOYANT:
            by[(r["level"], r["planner"], r["trial"])][r["variant"]] = r["reward"]
    groups = defaultdict(list)
    for (level, planner, trial), d in by.items():
        if all(v in d for v in VARIANTS):
            groups[(level, planner)].append((trial, d))
    out = []
    for (level, planner), items in sorted(groups.items(), key=lambda kv: (kv[0][0], planner_order(kv[0][1]))):
        aware = np.array([d["aware"] for _, d in items])
        choice = np.array([d["choice"] for _, d in items])
        blind = np.array([d["blind"] for _, d in items])
        search = aware - choice
        clair = np.array([bound[level].get(t, np.nan) for t, _ in items])
        diff = aware - blind
        out.append({"level": level, "case": CASES[level][0], "planner": planner, "n": len(items),
                    "aware_mean": float(aware.mean()), "aware_sem": sem(aware),
                    "blind_mean": float(blind.mean()), "blind_sem": sem(blind),
                    "choice_mean": float(choice.mean()), "choice_sem": sem(choice),
                    "search_mean": float(search.mean()), "search_sem": sem(search),
                    "search_wins": f"{int((search > 1e-12).sum())}/{int((search < -1e-12).sum())}",
                    "clairvoyant_mean": float(np.nanmean(clair)),
                    "aware_pct": float(100 * aware.mean() / np.nanmean(clair)),
                    "blind_pct": float(100 * blind.mean() / np.nanmean(clair)),
                    "diff_mean": float(diff.mean()), "diff_sem": sem(diff),
                    "gain_pct": float(100 * (aware.mean() / blind.mean() - 1)),
                    "wins": f"{int((diff > 1e-12).sum())}/{int((diff < -1e-12).sum())}"})
    return out


SUMMARY_FIELDS = ("case", "planner", "n", "aware_mean", "aware_sem", "choice_mean", "choice_sem", "blind_mean",
                  "blind_sem", "search_mean", "search_sem", "search_wins", "clairvoyant_mean",
                  "aware_pct", "blind_pct", "diff_mean", "diff_sem", "gain_pct", "wins")


def markdown(summary: list[dict]) -> str:
    lines = ["| case | planner | type-aware | unweighted search | type-blind | aware − blind (wins/losses) "
             "| aware / blind | aware − unweighted search (wins/losses) | aware, % of clairvoyant "
             "| blind, % of clairvoyant |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in summary:
        label = STYLE.get(r["planner"], (r["planner"],))[0]
        lines.append(f"| {r['case']} | {label} | {r['aware_mean']:.3f} ± {r['aware_sem']:.3f} "
                     f"| {r['choice_mean']:.3f} ± {r['choice_sem']:.3f} "
                     f"| {r['blind_mean']:.3f} ± {r['blind_sem']:.3f} "
                     f"| {r['diff_mean']:+.3f} ± {r['diff_sem']:.3f} ({r['wins']}) | {r['gain_pct']:+.1f}% "
                     f"| {r['search_mean']:+.3f} ± {r['search_sem']:.3f} ({r['search_wins']}) "
                     f"| {r['aware_pct']:.1f}% | {r['blind_pct']:.1f}% |")
    return "\n".join(lines)


def plot(summary: list[dict], path: Path, title: str) -> None:
    """Grouped bars: each case × planner, aware and blind as % of the clairvoyant mean, ±1 SEM."""
    variant_bars(
        summary, Variants(VARIANTS, "clairvoyant_mean", {"aware": "#1b9e77", "choice": "#7570b3", "blind": "#999999"},
                          {"aware": "type-aware", "choice": "unweighted search, rank-rule passenger",
                           "blind": "type-blind"}),
        [f"{r['case'].replace('random, ', '')}\n{STYLE.get(r['planner'], (r['planner'],))[0]}" for r in summary],
        path, title, "mean reward, % of the clairvoyant bound (±1 SEM)", figsize=(11, 4.6), label_size=6.5,
        rotation=20)


def write(rows: list[dict], out: Path, settings: dict, seconds: float, jobs: int) -> dict:
    """CSVs, table, plot and ``types.md`` under ``out``; returns the run-info entry."""
    write_trials(rows, out / "types_trials.csv")
    summary = summarise(rows)
    write_csv(summary, out / "types_summary.csv", SUMMARY_FIELDS)
    title = (f"Passenger types: type-aware vs type-blind (scout {SCOUT}, two rovers {ROVER}), "
             f"{settings['trials']} trials, {settings['iterations']} iterations")
    plot(summary, out / "types.png", title)
    text = ["## Passenger types sweep", "",
            f"{settings['trials']} trials per case, {settings['iterations']} iterations per decision "
            f"(MCTS-SSAP, closed-loop). Each carrier: a scout (weight {SCOUT}) and two rovers ({ROVER}). "
            "Mean normalised reward with the passenger values ± SEM; paired difference on the same "
            "observations and planner seeds.", "", markdown(summary), "",
            f"Wall time: {seconds:.1f} s with {jobs} worker process(es) for {len(rows)} tasks."]
    (out / "types.md").write_text("\n".join(text) + "\n")
    return {"sweep": "types", "seconds": round(seconds, 1), "tasks": len(rows), "jobs": jobs}
