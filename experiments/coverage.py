"""``python -m experiments coverage`` (issue 35 item 6): how much reward the paper's 1/p penalty
loses against the true coverage reward, on the same worlds.

Worlds (:func:`planner.instance.random_coverage_instance`):
R carriers (``--carriers``, default 4, 8, 16, 32, 64), D = 3, N = 10, two own regions per point,
Poisson(1.5) each; overlap level k (``--overlaps``, the paper's Fig. 2 levels 0, 4, ..., 20) puts
``k * R / 4`` lenses (regions shared by 2 or 3 decision points, Poisson(1.5)) among the R·N
points: at R = 4 as many as the paper's k overlap groups, at larger R the same number of lenses
per decision point.

Per world and planner one row holds both plans, made with the same planner seed:

* **coverage-planned**: ``run_online(problem, x, planner, seed, counts)`` on the coverage problem;
* **penalty-planned**: ``run_online`` on the penalty problem of the same world (its overlap
  groups ``coverage.overlaps(N)``, the same observations x, prior and normalisation scale), its
  deployments then valued under true coverage with ``evaluate(problem, deployed, x, counts=counts)``.
  The row also keeps the 1/p model's own value of that plan (``penalty_model_reward``): never
  above the true one, since a region covered by q deployments has each of them penalised by p >= q.

A planner that cannot yet decide under coverage (it raises ValueError or NotImplementedError)
keeps its penalty-planned result; its coverage columns stay empty and ``error`` says why (the
tables mark it *pending*). The clairvoyant coverage bound is a row per world when
:func:`coverage_clairvoyant` finds it; otherwise its rows and the fraction columns are left out.

Streams: world (R, k, t) from ``SeedSequence(seed, spawn_key=(1000, t))`` (level k's lenses are
the first k·R/4 of level k + 4's); planner seed ``(1000, t, 1)``, as the other random sweeps.
"""
from __future__ import annotations

import inspect
import math
import textwrap
import time
from collections import defaultdict
from functools import lru_cache
from pathlib import Path

import numpy as np

from experiments.report import STYLE, planner_order, read_csv, sem, write_csv
from experiments.trials import CLAIRVOYANT, Task, _planner, encode, seed_of
from planner.guard import PlannerFault

#: Fleet sizes and the planners of the full experiment; --quick's fleet sizes.
CARRIER_LEVELS = (4, 8, 16, 32, 64)
QUICK_CARRIERS = (4, 8)
DEFAULT_PLANNERS = ("closed-loop", "dec-closed-loop", "mcts-ssap", "ssap", "random")
#: Errors that mean "this planner cannot plan under coverage yet" (anything else is a bug and stops the run).
PENDING_ERRORS = (ValueError, NotImplementedError)

FIELDS = ("sweep", "config", "level", "trial", "planner", "carriers", "overlaps", "regions", "iterations", "seed",
          "planner_seed", "coverage_reward", "coverage_features", "penalty_reward", "penalty_features",
          "penalty_model_reward", "diff", "same_deployed", "exact", "error", "decision_ms_coverage",
          "decision_ms_penalty", "wall_s", "deployed_coverage", "deployed_penalty")
NUMBERS = ("coverage_reward", "coverage_features", "penalty_reward", "penalty_features", "penalty_model_reward",
           "diff", "decision_ms_coverage", "decision_ms_penalty", "wall_s")


def lenses(level: int, carriers: int) -> int:
    """The lenses (shared regions) of overlap level ``level`` at R = ``carriers``: k per 4 carriers."""
    return int(round(level * carriers / 4))


def coverage_clairvoyant():
    """The coverage clairvoyant ``(problem, x, counts) -> ClairvoyantResult`` (issue 35 item 5:
    exact maximum coverage knowing every count), or None where ``planner.clairvoyant.solve`` does
    not take the region counts yet."""
    from planner import clairvoyant

    if "counts" not in inspect.signature(clairvoyant.solve).parameters:
        return None
    return lambda problem, x, counts: clairvoyant.solve(problem, x, counts=counts)


def build_tasks(settings: dict) -> list[Task]:
    """Every (R, level, trial, planner) task; the clairvoyant when :func:`coverage_clairvoyant` exists."""
    names = (*settings["planners"], *((CLAIRVOYANT,) if coverage_clairvoyant() is not None else ()))
    return [Task("coverage", level, t, name, settings["seed"], settings["iterations"], carriers=carriers,
                 overlaps=lenses(level, carriers))
            for carriers in settings["carriers"] for level in settings["overlaps"]
            for t in range(settings["trials"]) for name in names]


@lru_cache(maxsize=8)
def world(seed: int, trial: int, carriers: int, overlaps: int, passengers: int, stages: int, mean: float):
    """``((problem, x, counts), planner seed)`` of a world (module docstring: streams); cached per
    process, since every planner of a world rebuilds it."""
    from planner.instance import random_coverage_instance

    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(1000, trial)))
    (problem, x), counts = random_coverage_instance(rng, carriers, passengers, stages, overlaps, mean)
    return (problem, x, counts), seed_of(seed, (1000, trial, 1))


def run_task(task: Task) -> dict:
    """One planner (or the clairvoyant) on one world, planned both ways; one row of :data:`FIELDS`."""
    from planner.instance import penalty_twin
    from planner.online import run_online
    from planner.problem import evaluate

    inst, planner_seed = world(task.seed, task.trial, task.carriers, task.overlaps, task.passengers, task.stages,
                               task.mean)
    problem, x, counts = inst
    row = {"sweep": task.sweep, "config": f"R = {task.carriers}", "level": task.level, "trial": task.trial,
           "planner": task.planner, "carriers": problem.n_carriers, "overlaps": task.overlaps,
           "regions": problem.coverage.n_regions, "iterations": task.iterations, "seed": task.seed,
           "planner_seed": planner_seed}
    t0 = time.perf_counter()
    if task.planner == CLAIRVOYANT:
        result = coverage_clairvoyant()(problem, x, counts)
        row.update(coverage_reward=result.reward, coverage_features=result.features, exact=int(result.exact),
                   deployed_coverage=encode(result.deployed), wall_s=time.perf_counter() - t0)
        return row
    planner = _planner(task.planner, task.iterations)
    planned = run_online(penalty_twin(problem), x, planner, planner_seed)
    reward, features = evaluate(problem, planned.deployed, x, planned.released, counts=counts)
    row.update(penalty_reward=reward, penalty_features=features, penalty_model_reward=planned.reward,
               deployed_penalty=encode(planned.deployed), decision_ms_penalty=float(np.mean(planned.decision_ms)))
    try:
        covered = run_online(problem, x, planner, planner_seed, counts)
    except PlannerFault as fault:  # the guard names what the planner raised: pending if it cannot plan here
        err = fault.__cause__
        if fault.rule != "raises" or not isinstance(err, PENDING_ERRORS):
            raise
        row["error"] = f"{type(err).__name__}: {str(err).splitlines()[0] if str(err) else ''}"
    else:
        row.update(coverage_reward=covered.reward, coverage_features=covered.features,
                   diff=covered.reward - reward, same_deployed=int(np.array_equal(covered.deployed, planned.deployed)),
                   deployed_coverage=encode(covered.deployed), decision_ms_coverage=float(np.mean(covered.decision_ms)))
    row["wall_s"] = time.perf_counter() - t0
    return row


# ----------------------------------------------------------------------------- report


def write_trials(rows: list[dict], path: Path) -> None:
    write_csv(sorted(rows, key=lambda r: (r["carriers"], r["level"], r["trial"], planner_order(r["planner"]))), path,
              FIELDS)


def read_trials(path: Path) -> list[dict]:
    rows = read_csv(path, ("level", "trial", "carriers", "overlaps", "regions", "iterations", "seed"), ())
    for row in rows:
        for k in NUMBERS:
            row[k] = float(row[k]) if row.get(k, "") != "" else float("nan")
    return rows


def _present(rows: list[dict], key: str) -> list[dict]:
    return [r for r in rows if r.get(key, "") != "" and not (isinstance(r[key], float) and math.isnan(r[key]))]


def ci95(values) -> float:
    """Half-width of the 95 % Student-t confidence interval of the mean (NaN for fewer than two values)."""
    from scipy import stats

    return float(stats.t.ppf(0.975, len(values) - 1) * sem(values)) if len(values) > 1 else float("nan")


def summarise(rows: list[dict]) -> list[dict]:
    """Per (R, level, planner): both plans' true coverage reward (mean ± SEM), the paired difference
    coverage − penalty (mean, 95 % CI, wins/losses), identical plans, the 1/p model's value of its
    plan as a % of the true one, and fractions of the coverage clairvoyant where it ran."""
    bound = {(r["carriers"], r["level"], r["trial"]): r["coverage_reward"]
             for r in _present(rows, "coverage_reward") if r["planner"] == CLAIRVOYANT}
    groups = defaultdict(list)
    for r in rows:
        groups[(r["carriers"], r["level"], r["planner"])].append(r)
    out = []
    for (carriers, level, planner), rs in sorted(groups.items(), key=lambda kv: (*kv[0][:2], planner_order(kv[0][2]))):
        cov, pen = _present(rs, "coverage_reward"), _present(rs, "penalty_reward")
        diff = [r["diff"] for r in _present(rs, "diff")]
        row = {"carriers": carriers, "level": level, "overlaps": rs[0]["overlaps"], "planner": planner, "n": len(rs),
               "coverage_n": len(cov), "error": next((r["error"] for r in rs if r.get("error")), "")}
        for name, part in (("coverage", cov), ("penalty", pen)):
            values = [r[f"{name}_reward"] for r in part]
            fractions = [r[f"{name}_reward"] / bound[k] for r in part
                         if bound.get(k := (carriers, level, r["trial"]), 0) > 0]
            row.update({f"{name}_mean": float(np.mean(values)) if values else float("nan"),
                        f"{name}_sem": sem(values) if values else float("nan"),
                        f"{name}_fraction": float(np.mean(fractions)) if fractions else float("nan")})
        model = [r["penalty_model_reward"] / r["penalty_reward"] for r in pen if r["penalty_reward"] > 0]
        planned = cov if planner != CLAIRVOYANT else []  # the clairvoyant's time is not a decision time
        row.update(diff_mean=float(np.mean(diff)) if diff else float("nan"), diff_ci=ci95(diff),
                   wins=int(np.sum(np.asarray(diff) > 1e-12)), losses=int(np.sum(np.asarray(diff) < -1e-12)),
                   same=sum(int(r["same_deployed"]) for r in rs if str(r.get("same_deployed", "")) in ("0", "1")),
                   exact=sum(str(r.get("exact", "")) in ("1", "True") for r in rs),
                   model_pct=100 * float(np.mean(model)) if model else float("nan"),
                   decision_ms_coverage=float(np.mean([r["decision_ms_coverage"] for r in planned])) if planned
                   else float("nan"),
                   decision_ms_penalty=float(np.mean([r["decision_ms_penalty"] for r in pen])) if pen else float("nan"))
        out.append(row)
    return out


SUMMARY_FIELDS = ("carriers", "level", "overlaps", "planner", "n", "coverage_n", "coverage_mean", "coverage_sem",
                  "penalty_mean", "penalty_sem", "diff_mean", "diff_ci", "wins", "losses", "same", "exact", "model_pct",
                  "coverage_fraction", "penalty_fraction", "decision_ms_coverage", "decision_ms_penalty", "error")


def _label(planner: str) -> str:
    return STYLE.get(planner, (planner,))[0]


def _table(summary: list[dict], cell, planners: list[str]) -> str:
    """Markdown: one row per (R, level), one column per planner, ``cell(summary row)`` in each."""
    at = {(r["carriers"], r["level"], r["planner"]): r for r in summary}
    lines = ["| R | level (lenses) | " + " | ".join(_label(p) for p in planners) + " |",
             "|---|---|" + "---|" * len(planners)]
    for carriers, level in sorted({(r["carriers"], r["level"]) for r in summary}):
        some = next(r for r in summary if (r["carriers"], r["level"]) == (carriers, level))
        cells = [cell(at[(carriers, level, p)]) if (carriers, level, p) in at else "" for p in planners]
        lines.append(f"| {carriers} | {level} ({some['overlaps']}) | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _both(r: dict) -> str:
    pen = f"{r['penalty_mean']:.2f} ± {r['penalty_sem']:.2f}"
    cov = "pending" if not r["coverage_n"] else f"{r['coverage_mean']:.2f} ± {r['coverage_sem']:.2f}"
    return f"{cov} / {pen}"


def _diff(r: dict) -> str:
    if not r["coverage_n"]:
        return "pending"
    return (f"{r['diff_mean']:+.3f} [{r['diff_mean'] - r['diff_ci']:+.3f}, {r['diff_mean'] + r['diff_ci']:+.3f}] "
            f"({r['wins']}/{r['losses']}; same plan {r['same']}/{r['coverage_n']})")


def _fractions(r: dict) -> str:
    cov = "pending" if not r["coverage_n"] else f"{100 * r['coverage_fraction']:.1f} %"
    return f"{cov} / {100 * r['penalty_fraction']:.1f} %"


def markdown(summary: list[dict]) -> list[str]:
    """The tables of ``coverage.md`` (a fraction table only where the coverage clairvoyant ran)."""
    planners = sorted({r["planner"] for r in summary} - {CLAIRVOYANT}, key=planner_order)
    pending = sorted({r["planner"] for r in summary if r["error"]} - {CLAIRVOYANT}, key=planner_order)
    text = ["Mean normalised reward under true coverage ± SEM: planned with coverage / planned with the 1/p "
            "penalty:", "", _table(summary, _both, planners), "",
            "Paired difference, coverage-planned − penalty-planned, on the same worlds and planner seeds: mean "
            "[95 % t confidence interval] (wins/losses; trials where both plans are the same):", "",
            _table(summary, _diff, planners), "",
            "The 1/p model's value of its own plan as a % of the plan's true coverage value (how much the "
            "heuristic undervalues what it deploys):", "",
            _table(summary, lambda r: f"{r['model_pct']:.1f} %", planners)]
    if any(r["planner"] == CLAIRVOYANT for r in summary):
        bound = [r for r in summary if r["planner"] == CLAIRVOYANT]
        text += ["", "Mean per-trial fraction of the clairvoyant coverage bound (exact maximum coverage in "
                 f"{sum(r['exact'] for r in bound)} of {sum(r['n'] for r in bound)} worlds, an upper bound in the "
                 "others): planned with coverage / with the 1/p penalty:", "", _table(summary, _fractions, planners)]
    else:
        text += ["", "No clairvoyant coverage bound: `planner.clairvoyant.solve` takes no region counts on this "
                 "revision (experiments.coverage.coverage_clairvoyant), so the fraction-of-bound columns are left out."]
    lenses_rows = [r for r in summary if r["overlaps"] > 0 and r["coverage_n"] and r["planner"] != CLAIRVOYANT]
    unchanged = [p for p in planners if any(r["planner"] == p for r in lenses_rows)
                 and all(r["same"] == r["coverage_n"] for r in lenses_rows if r["planner"] == p)]
    if unchanged:
        text += ["", "Planners whose coverage plan is their penalty plan in every world with lenses (they do not decide "
                 "by coverage: SSAP and Random by design, as they ignore overlap): "
                 + ", ".join(_label(p) for p in unchanged) + "."]
    if pending:
        errors = {r["planner"]: r["error"] for r in reversed(summary) if r["error"]}  # each planner's first error
        text += ["", "*pending*: planners that cannot plan under coverage on this revision (penalty-planned results "
                 "only): " + "; ".join(f"{_label(p)}: `{errors[p]}`" for p in pending) + "."]
    text += ["", "Mean decision time per stage, ms, planning with coverage / with the penalty:", "",
             _table(summary, lambda r: ("pending" if not r["coverage_n"] else f"{r['decision_ms_coverage']:.1f}")
                    + f" / {r['decision_ms_penalty']:.1f}", planners)]
    return text


def versus(rows: list[dict], a: str, b: str) -> str:
    """Markdown: planner ``a`` − planner ``b``, both planned with the 1/p penalty, per (R, level):
    the paired difference under true coverage and as the 1/p model values the same plans (mean
    [95 % CI]); empty when either planner is missing."""
    by = defaultdict(dict)
    for r in _present(rows, "penalty_reward"):
        by[(r["carriers"], r["level"], r["trial"])][r["planner"]] = r
    diffs = defaultdict(lambda: ([], []))
    for (carriers, level, _), d in by.items():
        if a in d and b in d:
            diffs[(carriers, level)][0].append(d[a]["penalty_reward"] - d[b]["penalty_reward"])
            diffs[(carriers, level)][1].append(d[a]["penalty_model_reward"] - d[b]["penalty_model_reward"])
    if not diffs:
        return ""

    def cell(v):
        return f"{np.mean(v):+.2f} [{np.mean(v) - ci95(v):+.2f}, {np.mean(v) + ci95(v):+.2f}]"

    lines = [f"| R | level | {_label(a)} − {_label(b)} under true coverage | as the 1/p model values them |",
             "|---|---|---|---|"]
    lines += [f"| {c} | {k} | {cell(true)} | {cell(model)} |" for (c, k), (true, model) in sorted(diffs.items())]
    return "\n".join(lines)


def plot(summary: list[dict], path: Path, title: str) -> None:
    """Per R two panels: true coverage reward against the overlap level (solid: planned with
    coverage, dashed: with the penalty; ±1 SEM), and the paired difference with its 95 % CI."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fleets = sorted({r["carriers"] for r in summary})
    planners = sorted({r["planner"] for r in summary}, key=planner_order)
    fig, axes = plt.subplots(2, len(fleets), figsize=(4 * len(fleets) + 1, 7.5), squeeze=False)
    for i, carriers in enumerate(fleets):
        top, bottom = axes[0, i], axes[1, i]
        for k, p in enumerate(planners):
            label, colour, marker, _ = STYLE.get(p, (p, None, "x", "-"))
            rs = sorted((r for r in summary if r["carriers"] == carriers and r["planner"] == p), key=lambda r: r["level"])
            xs = np.array([r["level"] for r in rs], dtype=float)
            cov = [r for r in rs if r["coverage_n"]]
            if cov:
                top.errorbar([r["level"] for r in cov], [r["coverage_mean"] for r in cov],
                             yerr=[r["coverage_sem"] for r in cov], color=colour, marker=marker or None, ls="-",
                             capsize=2, ms=4, label=f"{label}, coverage" if i == 0 else None)
            if p != CLAIRVOYANT:
                top.errorbar(xs, [r["penalty_mean"] for r in rs], yerr=[r["penalty_sem"] for r in rs], color=colour,
                             marker=marker, ls="--", capsize=2, ms=4, mfc="none",
                             label=f"{label}, 1/p penalty" if i == 0 else None)
            if cov and p != CLAIRVOYANT:
                bottom.errorbar(np.array([r["level"] for r in cov]) + 0.25 * (k - len(planners) / 2),
                                [r["diff_mean"] for r in cov], yerr=[np.nan_to_num(r["diff_ci"]) for r in cov],
                                color=colour, marker=marker, ls="-", capsize=2, ms=4)
        bottom.axhline(0.0, color="grey", lw=0.8)
        top.set_title(f"R = {carriers}", fontsize=10)
        top.set_ylabel("reward under true coverage (±1 SEM)" if i == 0 else "")
        bottom.set_ylabel("coverage − penalty planned (95 % CI)" if i == 0 else "")
        bottom.set_xlabel("overlap level k (k·R/4 lenses)")
        for ax in (top, bottom):
            ax.grid(alpha=0.3)
    fig.legend(loc="lower center", ncol=min(5, len(planners)), fontsize=7)
    fig.suptitle(textwrap.fill(title, 110), fontsize=10)
    fig.tight_layout(rect=(0, 0.1, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write(rows: list[dict], out: Path, settings: dict, seconds: float, jobs: int) -> dict:
    """``coverage_trials.csv``, ``coverage_summary.csv``, ``coverage.png`` and ``coverage.md``
    under ``out``; returns the run-info entry."""
    write_trials(rows, out / "coverage_trials.csv")
    rows = read_trials(out / "coverage_trials.csv")  # the report: a function of the CSV alone (--report-only)
    summary = summarise(rows)
    write_csv(summary, out / "coverage_summary.csv", SUMMARY_FIELDS)
    setting = (f"D = 3, N = 10, {settings['trials']} worlds per (R, level), {settings['iterations']} iterations "
               "per decision")
    plot(summary, out / "coverage.png", f"Coverage against the 1/p penalty on the same worlds ({setting})")
    worker = defaultdict(float)
    for r in rows:
        worker[r["planner"]] += float(r["wall_s"])
    text = ["## Coverage against the 1/p penalty", "",
            f"Random coverage worlds (planner.instance.random_coverage_instance), {setting}; each planner plans every world "
            "with the coverage reward and with the 1/p penalty (the world's lenses as overlap groups), both plans "
            "valued under true coverage.", "", *markdown(summary), "", "![coverage against penalty](coverage.png)", ""]
    for a, b in (("closed-loop", "ssap"), ("closed-loop", "mcts-ssap")):
        table = versus(rows, a, b)
        if table:
            text += ["How the 1/p model misjudges the planners' differences: both planned with the penalty, paired on "
                     "the same worlds, mean [95 % CI]:", "", table, ""]
    text.append(f"Wall time: {seconds:.1f} s with {jobs} worker process(es) for {len(rows)} tasks; worker seconds: "
                + ", ".join(f"{_label(k)} {v:.0f} s" for k, v in sorted(worker.items(), key=lambda kv: planner_order(kv[0])))
                + ".")
    (out / "coverage.md").write_text("\n".join(text) + "\n")
    return {"sweep": "coverage", "seconds": round(seconds, 1), "tasks": len(rows), "jobs": jobs}
