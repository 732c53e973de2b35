"""How close to optimal at scale: the information-relaxation bound (planner/duality.py) against
V* where V* is computable, and every planner as a fraction of it from R = 4 to R = 256.

Two parts:

* **tiny** (sweep ``bound-tiny``): random instances small enough for the exact online optimum V*
  (R = 2 or 3, N = 6, D = 2, Poisson(3), 2 to 4 overlap groups). Per instance: V*, the new bound
  (``exact`` inner maxima) and the clairvoyant mean on the *same* sampled observation matrices,
  each with its standard error; their excess over V*.
* **scale** (sweep ``bound``): random paper-style instances (D = 3, N = 10, Poisson(3)) at the
  configurations of :data:`CONFIGS` (R = 4 with 0 to 20 overlaps, R = 6, and R = 32, 128, 256 at
  the paper's density of five overlap groups per carrier). Per trial: every planner's reward on
  the trial's observations (the experiments' common random numbers), the clairvoyant bound of the
  same observations and the new bound of the instance (an expectation over the prior, from its own
  samples, by the LP relaxation). A planner's fraction of the bound is its reward over the bound,
  per trial, averaged over trials (± SEM).

Streams: trial t's instance and observations ``(1000, t)`` and planner seed ``(1000, t, 1)`` as the
other random sweeps; the bound's samples ``(1000, t, 2)``; tiny instance k ``(1002, k, a)`` (the first a within V*'s limits).
"""
from __future__ import annotations

import time
from collections import defaultdict
from pathlib import Path

import numpy as np

from experiments.report import STYLE, planner_order, read_csv, sem, write_csv
from experiments.trials import CLAIRVOYANT, Sweep, Task, run_trial

#: Name of the bound task in result rows.
UPPER_BOUND = "upper-bound"
#: Name of a tiny-instance task (V*, bound and clairvoyant mean of one instance).
TINY = "tiny"
#: (label, carriers, overlaps, trials, bound samples) per configuration (the ``level`` indexes it).
CONFIGS = (
    ("R = 4, 0 overlaps", 4, 0, 16, 30), ("R = 4, 4 overlaps", 4, 4, 16, 30), ("R = 4, 8 overlaps", 4, 8, 16, 30),
    ("R = 4, 12 overlaps", 4, 12, 16, 30), ("R = 4, 16 overlaps", 4, 16, 16, 30),
    ("R = 4, 20 overlaps", 4, 20, 16, 30), ("R = 6, 10 overlaps", 6, 10, 16, 30),
    ("R = 32, 160 overlaps", 32, 160, 6, 12), ("R = 128, 640 overlaps", 128, 640, 3, 6),
    ("R = 256, 1280 overlaps", 256, 1280, 3, 4),
)
#: Planners of the comparison; dec-closed-loop (every carrier runs closed-loop) only up to this R.
DEFAULT_PLANNERS = ("closed-loop", "mcts-ssap", "ssap", "dec-closed-loop")
DEC_MAX_CARRIERS = 32
#: The clairvoyant bound runs up to this R (beyond, its exact search stops at its node limit and it
#: is the conflict-free bound, seconds per trial for a number the scaling docs already give).
CLAIRVOYANT_MAX_CARRIERS = 32
#: Tiny instances and samples per tiny instance.
TINY_INSTANCES, TINY_SAMPLES = 10, 400
#: Planning budget of the comparison (iterations per decision).
DEFAULT_ITERATIONS = 2000
QUICK = {"configs": (0, 5, 7), "trials": 2, "samples": 4, "tiny": 2, "tiny_samples": 40}

FIELDS = ("sweep", "level", "config", "trial", "planner", "reward", "stderr", "samples", "method", "exact",
          "v_star", "clairvoyant_mean", "clairvoyant_stderr", "carriers", "overlaps", "iterations", "seed",
          "planner_seed", "decision_ms_mean", "wall_s")


def build_tasks(settings: dict) -> list[Task]:
    quick = settings.get("quick", False)
    tasks = [Task("bound-tiny", 0, k, TINY, settings["seed"], 0,
                  samples=QUICK["tiny_samples"] if quick else TINY_SAMPLES)
             for k in range(QUICK["tiny"] if quick else TINY_INSTANCES)]
    levels = QUICK["configs"] if quick else range(len(CONFIGS))
    for level in levels:
        _, carriers, overlaps, trials, samples = CONFIGS[level]
        trials = QUICK["trials"] if quick else (settings.get("bound_trials") or trials)
        samples = QUICK["samples"] if quick else samples
        for t in range(trials):
            names = [p for p in settings["planners"] if not (p.startswith("dec-") and carriers > DEC_MAX_CARRIERS)]
            for name in (*names, *((CLAIRVOYANT,) if carriers <= CLAIRVOYANT_MAX_CARRIERS else ())):
                tasks.append(Task("bound", level, t, name, settings["seed"], settings["iterations"], carriers=carriers,
                                  overlaps=overlaps))
            tasks.append(Task("bound", level, t, UPPER_BOUND, settings["seed"], 0, carriers=carriers,
                              overlaps=overlaps, samples=samples))
    return tasks


def _config_columns(task: Task, extra: dict, result) -> dict:
    return {"config": CONFIGS[task.level][0]}


#: How experiments.trials.run_trial runs this sweep's planner and clairvoyant tasks.
SWEEP = Sweep(columns=_config_columns)


def run_task(task: Task) -> dict:
    """One task of either part (see the module docstring); planners through ``run_trial``."""
    if task.planner == TINY:
        return _tiny(task)
    if task.planner != UPPER_BOUND:
        return run_trial(task, SWEEP)
    from experiments.trials import random_trial
    from planner import duality

    problem, _, planner_seed, _ = random_trial(task)
    t0 = time.perf_counter()
    rng = np.random.default_rng(np.random.SeedSequence(task.seed, spawn_key=(1000, task.trial, 2)))
    bound = duality.upper_bound(problem, rng, samples=task.samples, method="lp")
    return {"sweep": task.sweep, "level": task.level, "config": CONFIGS[task.level][0], "trial": task.trial,
            "planner": UPPER_BOUND, "reward": bound.expected_reward, "stderr": bound.stderr, "samples": bound.samples,
            "method": bound.method, "carriers": problem.n_carriers, "overlaps": len(problem.overlaps),
            "iterations": 0, "seed": task.seed, "planner_seed": planner_seed, "wall_s": time.perf_counter() - t0}


def tiny_instance(seed: int, k: int):
    """Tiny instance k: R = 2 + k % 2, N = 6, D = 2, Poisson(3), 2 to 4 overlap groups, and the
    generator its samples continue from: the first draw of streams ``(1002, k, a)``, a = 0, 1, ...,
    within the exact solver's automatic limit (``AUTO_WORK``, its quick size estimate)."""
    from planner import online_optimal
    from planner.instance import random_instance

    for attempt in range(100):
        rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(1002, k, attempt)))
        groups = int(rng.integers(2, 5))
        problem = random_instance(rng, carriers=2 + k % 2, passengers=2, stages=6, overlaps=groups).problem
        try:
            online_optimal.estimate(problem, max_work=online_optimal.AUTO_WORK)
        except online_optimal.TooLarge:
            continue
        return problem, rng
    raise ValueError(f"no tiny instance within the exact solver's limits for seed {seed}, k = {k}")


def _tiny(task: Task) -> dict:
    from planner import clairvoyant, duality, online_optimal
    from planner.problem import sample_observations

    t0 = time.perf_counter()
    problem, rng = tiny_instance(task.seed, task.trial)
    best = online_optimal.online_value(problem).expected_reward
    bound, offline = [], []
    for _ in range(task.samples):
        x = sample_observations(problem, rng)
        bound.append(duality.inner_maximum(problem, x, "exact") / problem.scale)
        offline.append(clairvoyant.solve(problem, x).reward)
    return {"sweep": task.sweep, "level": 0, "config": f"R = {problem.n_carriers}, {len(problem.overlaps)} groups",
            "trial": task.trial, "planner": UPPER_BOUND, "reward": float(np.mean(bound)), "stderr": sem(bound),
            "samples": len(bound), "method": "exact", "v_star": best, "clairvoyant_mean": float(np.mean(offline)),
            "clairvoyant_stderr": sem(offline), "carriers": problem.n_carriers, "overlaps": len(problem.overlaps),
            "iterations": 0, "seed": task.seed, "wall_s": time.perf_counter() - t0}


# ----------------------------------------------------------------------------- report


def read_trials(path: Path) -> list[dict]:
    rows = read_csv(path, ("level", "trial", "carriers", "overlaps", "iterations", "seed"), ())
    for row in rows:
        for k in ("reward", "stderr", "v_star", "clairvoyant_mean", "clairvoyant_stderr", "wall_s", "decision_ms_mean"):
            row[k] = float(row[k]) if row.get(k, "") != "" else float("nan")
    return rows


def tiny_table(rows: list[dict]) -> tuple[str, dict]:
    """The tiny part as markdown, and its aggregate figures."""
    tiny = sorted((r for r in rows if r["sweep"] == "bound-tiny"), key=lambda r: r["trial"])
    lines = ["| instance | V* | new bound (± SE) | excess over V* | clairvoyant mean (± SE) | excess over V* | "
             "excess ratio | valid (bound ≥ V* − 3 SE) |", "|---|---|---|---|---|---|---|---|"]
    bound_ex, clair_ex, valid = [], [], []
    for r in tiny:
        v = r["v_star"]
        be, ce = 100 * (r["reward"] / v - 1), 100 * (r["clairvoyant_mean"] / v - 1)
        ok = r["reward"] >= v - 3 * r["stderr"]
        bound_ex.append(be)
        clair_ex.append(ce)
        valid.append(ok)
        lines.append(f"| #{r['trial']} {r['config']} | {v:.4f} | {r['reward']:.4f} ± {r['stderr']:.4f} | {be:+.2f} % | "
                     f"{r['clairvoyant_mean']:.4f} ± {r['clairvoyant_stderr']:.4f} | {ce:+.2f} % | "
                     f"{be / ce:.2f} | {'yes' if ok else 'NO'} |")
    agg = {"bound_excess_pct": float(np.mean(bound_ex)) if tiny else float("nan"),
           "clairvoyant_excess_pct": float(np.mean(clair_ex)) if tiny else float("nan"),
           "valid": f"{sum(valid)}/{len(valid)}"}
    if tiny:
        agg["ratio"] = agg["bound_excess_pct"] / agg["clairvoyant_excess_pct"]
        lines.append(f"| mean over instances | | | {agg['bound_excess_pct']:+.2f} % | | {agg['clairvoyant_excess_pct']:+.2f} % "
                     f"| {agg['ratio']:.2f} | {agg['valid']} |")
    return "\n".join(lines), agg


def summarise(rows: list[dict]) -> list[dict]:
    """Per configuration and planner: mean reward ± SEM and the mean per-trial fraction of the new
    bound ± SEM (the clairvoyant row: its fraction too, > 1 where the new bound is tighter)."""
    scale = [r for r in rows if r["sweep"] == "bound"]
    bound = {(r["level"], r["trial"]): r for r in scale if r["planner"] == UPPER_BOUND}
    by = defaultdict(list)
    for r in scale:
        by[(r["level"], r["planner"])].append(r)
    out = []
    for (level, planner), rs in sorted(by.items(), key=lambda kv: (kv[0][0], planner_order(kv[0][1]))):
        rewards = [r["reward"] for r in rs]
        fractions = [r["reward"] / bound[(level, r["trial"])]["reward"] for r in rs
                     if (level, r["trial"]) in bound and bound[(level, r["trial"])]["reward"] > 0]
        out.append({"level": level, "config": CONFIGS[level][0], "carriers": CONFIGS[level][1], "planner": planner,
                    "n": len(rs), "reward_mean": float(np.mean(rewards)), "reward_sem": sem(rewards),
                    "fraction_mean": float(np.mean(fractions)) if fractions else float("nan"),
                    "fraction_sem": sem(fractions) if fractions else float("nan"),
                    "stderr_mean": float(np.mean([r["stderr"] for r in rs])) if planner == UPPER_BOUND else "",
                    "decision_ms_mean": float(np.nanmean([r.get("decision_ms_mean", np.nan) for r in rs]))
                    if planner not in (UPPER_BOUND, CLAIRVOYANT) else ""})
    return out


SUMMARY_FIELDS = ("level", "config", "carriers", "planner", "n", "reward_mean", "reward_sem", "fraction_mean",
                  "fraction_sem", "stderr_mean", "decision_ms_mean")


def scale_table(summary: list[dict]) -> str:
    planners = sorted({r["planner"] for r in summary} - {UPPER_BOUND}, key=planner_order)
    cell = {(r["level"], r["planner"]): r for r in summary}
    head = "| configuration | new bound (reward ± SEM over trials) | " + " | ".join(
        STYLE.get(p, (p,))[0] for p in planners) + " |"
    lines = [head, "|" + "---|" * (2 + len(planners))]
    for level in sorted({r["level"] for r in summary}):
        b = cell.get((level, UPPER_BOUND))
        parts = [CONFIGS[level][0], f"{b['reward_mean']:.3f} ± {b['reward_sem']:.3f} ({b['n']} trials)" if b else "–"]
        for p in planners:
            c = cell.get((level, p))
            parts.append(f"{c['fraction_mean']:.3f} ± {c['fraction_sem']:.3f}" if c else "–")
        lines.append("| " + " | ".join(parts) + " |")
    return "\n".join(lines)


def plot(summary: list[dict], path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    levels = sorted({r["level"] for r in summary})
    fig, ax = plt.subplots(figsize=(10, 4.8))
    xs = np.arange(len(levels))
    planners = sorted({r["planner"] for r in summary} - {UPPER_BOUND}, key=planner_order)
    for k, p in enumerate(planners):
        label, colour, marker, style = STYLE.get(p, (p, None, "o", "-"))
        pts = [(i, r) for i, lv in enumerate(levels) for r in summary if r["level"] == lv and r["planner"] == p]
        if not pts:
            continue
        ax.errorbar([i + 0.06 * (k - len(planners) / 2) for i, _ in pts], [r["fraction_mean"] for _, r in pts],
                    yerr=[r["fraction_sem"] for _, r in pts], label=label, color=colour, marker=marker or "_",
                    linestyle=style, capsize=3)
    ax.axhline(1.0, color="grey", linewidth=0.8)
    ax.axhline(0.9, color="grey", linewidth=0.8, linestyle=":")
    ax.set_xticks(xs, [CONFIGS[lv][0].replace(", ", "\n") for lv in levels], fontsize=8)
    ax.set_ylabel("fraction of the new upper bound (± SEM)")
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def write(rows: list[dict], out: Path, settings: dict, seconds: float, jobs: int) -> dict:
    write_csv(sorted(rows, key=lambda r: (r["sweep"], r["level"], r["trial"], planner_order(r["planner"]))),
              out / "bound_trials.csv", FIELDS)
    summary = summarise(rows)
    write_csv(summary, out / "bound_summary.csv", SUMMARY_FIELDS)
    iterations = settings["iterations"]
    title = f"Planners as fractions of the information-relaxation bound (D = 3, N = 10, {iterations} iterations)"
    plot(summary, out / "bound.png", title)
    tiny, agg = tiny_table(rows)
    text = ["## Upper bound", "",
            "### Tiny instances: the new bound and the clairvoyant bound against V*", "",
            "R = 2 or 3, N = 6, D = 2, Poisson(3), 2 to 4 overlap groups; both bounds on the same sampled "
            "observation matrices (exact inner maxima); excess = mean / V* − 1.", "", tiny, "",
            "### Planners as fractions of the new bound", "",
            f"Random instances, D = 3, N = 10, Poisson(3), {iterations} iterations per decision; the bound by "
            "the LP relaxation from its own samples; fraction = reward / bound per trial, mean ± SEM "
            "(the clairvoyant column: the clairvoyant bound over the new one, the conflict-free bound where "
            f"its exact search stops). dec-closed-loop and the clairvoyant bound run up to R = {DEC_MAX_CARRIERS}.", "", scale_table(summary), "", "![fractions of the bound](bound.png)"]
    worker = defaultdict(float)
    for r in rows:
        worker[r["planner"]] += float(r["wall_s"])
    text += ["", f"Wall time: {seconds:.1f} s with {jobs} worker process(es) for {len(rows)} tasks; worker seconds: "
             + ", ".join(f"{k} {v:.0f} s" for k, v in sorted(worker.items())) + "."]
    (out / "bound.md").write_text("\n".join(text) + "\n")
    return {"sweep": "bound", "seconds": round(seconds, 1), "tasks": len(rows), "jobs": jobs, "tiny": agg}
