"""How close to optimal at scale: the information-relaxation bound (planner/duality.py) against
V* where V* is computable, and every planner as a fraction of it from R = 4 to R = 256.

Two parts:

* **tiny** (sweep ``bound-tiny``): random instances small enough for the exact online optimum V*
  (R = 2 or 3, N = 6, D = 2, Poisson(3), 2 to 4 overlap groups). Per instance: V*, the new bound
  (``exact`` inner maxima, the adaptive penalty), the fixed-penalty bound (as the bound was before
  the adaptive penalty), the DLR-penalty bound and the clairvoyant mean on the *same* sampled
  observation matrices, each with its standard error; their excess over V*. Then one tiny instance per prior kind the
  exact solver takes (``TINY_PRIORS``: every kind of planner.priors; a continuous prior through
  V*'s 12-atom stand-in, the prior whose value V* is exactly, and every bound under the same
  stand-in) — level 1 of the sweep.
* **scale** (sweep ``bound``): random paper-style instances (D = 3, N = 10, Poisson(3)) at the
  configurations of :data:`CONFIGS` (R = 4 with 0 to 20 overlaps, R = 6, and R = 32, 128, 256 at
  the paper's density of five overlap groups per carrier). Per trial: every planner's reward on
  the trial's observations (the experiments' common random numbers), the clairvoyant bound of the
  same observations and the new bound of the instance (an expectation over the prior, from its own
  samples: by ``mixed``, the adaptive penalty with exact or MIP inner maxima, up to R = 128 with
  every MIP solved (or stopped by its time limit) and beyond with every MIP stopped after its root
  node (``--bound-method mixed-root``, the default; ``mixed``: the LP relaxation beyond R = 128, the
  default before 2026-12-07; ``lp``: the LP relaxation everywhere, looser and faster). A
  planner's fraction of the bound is
  its reward over the bound, per trial, averaged over trials (± SEM).

Streams: trial t's instance and observations ``(1000, t)`` and planner seed ``(1000, t, 1)`` as the
other random sweeps; the bound's samples ``(1000, t, 2)``; tiny instance k ``(1002, k, a)`` (the first a within V*'s limits);
the tiny instance of prior kind number i ``(1003, i, a)``.

Profiles: the defaults (:data:`CONFIGS`' trial and sample counts, 10 Poisson tiny instances of 400
samples, 11 prior kinds of 200) are the full experiment, about 30 minutes with one worker on a
shared 2-core host (docs/results.md); ``--quick`` is a smoke test (no clairvoyant search beyond
R = 6); ``--trials N`` sets every configuration's trials to N.
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
    ("R = 4, 0 overlaps", 4, 0, 40, 30), ("R = 4, 4 overlaps", 4, 4, 40, 30), ("R = 4, 8 overlaps", 4, 8, 40, 30),
    ("R = 4, 12 overlaps", 4, 12, 40, 30), ("R = 4, 16 overlaps", 4, 16, 40, 30),
    ("R = 4, 20 overlaps", 4, 20, 40, 30), ("R = 6, 10 overlaps", 6, 10, 40, 30),
    ("R = 32, 160 overlaps", 32, 160, 12, 12), ("R = 128, 640 overlaps", 128, 640, 16, 6),
    ("R = 256, 1280 overlaps", 256, 1280, 16, 4),
)
#: Planners of the comparison; dec-closed-loop (every carrier runs closed-loop) only up to this R.
DEFAULT_PLANNERS = ("closed-loop", "closed-loop-gated", "mcts-ssap", "ssap", "dec-closed-loop")
DEC_MAX_CARRIERS = 32
#: The clairvoyant bound runs up to this R (beyond, its exact search stops at its node limit and it
#: is the conflict-free bound, seconds per trial for a number the scaling docs already give).
CLAIRVOYANT_MAX_CARRIERS = 32
#: Tiny instances and samples per tiny instance.
TINY_INSTANCES, TINY_SAMPLES = 10, 400
#: One prior per kind of planner.priors.PRIOR_KINDS (small supports so V* stays quick), and the
#: samples of each prior kind's tiny instance.
TINY_PRIORS = {
    "poisson": {"kind": "poisson", "mean": 2.0},
    "binomial": {"kind": "binomial", "n": 6, "p": 0.5},
    "geometric": {"kind": "geometric", "p": 0.4},
    "negative_binomial": {"kind": "negative_binomial", "n": 2, "p": 0.5},
    "discrete_uniform": {"kind": "discrete_uniform", "low": 0, "high": 6},
    "table": {"kind": "table", "values": [0, 2.5, 5], "probabilities": [0.3, 0.4, 0.3]},
    "gamma": {"kind": "gamma", "shape": 2.0, "scale": 1.5},
    "exponential": {"kind": "exponential", "mean": 3.0},
    "lognormal": {"kind": "lognormal", "mu": 1.0, "sigma": 0.5},
    "normal": {"kind": "normal", "mean": 1.0, "std": 2.0},  # negative observations too
    "uniform": {"kind": "uniform", "low": 0.0, "high": 6.0},
}
TINY_PRIOR_SAMPLES = 200
#: Planning budget of the comparison (iterations per decision).
DEFAULT_ITERATIONS = 2000
QUICK = {"configs": (0, 5, 7), "trials": 2, "samples": 4, "tiny": 2, "tiny_samples": 40,
         "priors": ("binomial", "gamma"), "clairvoyant_max_carriers": 6, "mixed_max_carriers": 6}
#: The targets of the comparison (docs/results.md): the bound never below V* by more than
#: ``VALID_SE`` standard errors; its mean excess over V* at most ``EXCESS_RATIO`` of clairvoyance's;
#: our centralised planners (``OURS``) at least ``FRACTION_TARGET`` of the bound from R = 4 on.
VALID_SE, EXCESS_RATIO, FRACTION_TARGET, FRACTION_MIN_CARRIERS = 3.0, 1 / 3, 0.975, 4
OURS = ("closed-loop", "closed-loop-gated")
#: The bound's mean excess over V* on the tiny instances it aims at, percent.
EXCESS_TARGET_PCT = 1.0
#: ``--bound-method mixed`` and ``mixed-root``: the scale rows' bound by
#: ``duality.upper_bound(method="mixed")`` (exact per component where it fits, else the MIP; the
#: adaptive penalty) up to this R; beyond it ``mixed`` takes the LP (at R = 256 one adaptive MIP
#: does not finish in 400 s, and a MIP stopped by its time limit has a dual bound that depends on
#: the machine's speed) and ``mixed-root`` the same ``mixed`` with every MIP stopped after
#: :data:`ROOT_NODES` node (its root: 60 to 140 s a sample at R = 256, 1.1 % below the LP, and the
#: same bound on every machine, tools.bound_nodes); one MIP's time limit,
#: seconds (R = 128's finish in 25 to 45 s); the strength pilot's inner maxima (the adaptive LP:
#: 2 s at R = 128 where the MIP takes 30 s; the pilot only picks the strength, every strength's
#: bound is valid).
MIXED_MAX_CARRIERS = 128
ROOT_NODES = 1
#: One root-node MIP's time limit, seconds: far above its time (at most 141 s seen at R = 256),
#: so that the node limit, not the machine's speed, stops it.
ROOT_TIME_LIMIT_S = 3600.0
#: ``--bound-method`` choices (``mixed-root`` the default; run_info.json records the one a run used).
BOUND_METHODS = ("mixed-root", "mixed", "lp")
MIXED_MIP_TIME_LIMIT_S = 300.0
MIXED_PILOT_METHOD = "lp"
#: Fleet sizes of the split table (best bound, best planner, the gap between them).
SPLIT_CARRIERS = (32, 128, 256)

FIELDS = ("sweep", "level", "config", "trial", "planner", "prior", "reward", "stderr", "samples", "method", "strength",
          "dlr_bound", "dlr_stderr", "fixed_bound", "fixed_stderr", "fixed_strength", "exact",
          "v_star", "clairvoyant_mean", "clairvoyant_stderr", "carriers", "overlaps", "iterations", "seed",
          "planner_seed", "decision_ms_mean", "wall_s")


def build_tasks(settings: dict) -> list[Task]:
    quick = settings.get("quick", False)
    tasks = [Task("bound-tiny", 0, k, TINY, settings["seed"], 0,
                  samples=QUICK["tiny_samples"] if quick else TINY_SAMPLES)
             for k in range(QUICK["tiny"] if quick else TINY_INSTANCES)]
    tasks += [Task("bound-tiny", 1, i, TINY, settings["seed"], 0, variant=kind,
                   samples=QUICK["tiny_samples"] if quick else TINY_PRIOR_SAMPLES)
              for i, kind in enumerate(TINY_PRIORS) if not quick or kind in QUICK["priors"]]
    levels = QUICK["configs"] if quick else range(len(CONFIGS))
    # --quick leaves out R = 32's clairvoyant search (seconds per trial at its node limit) and its
    # adaptive MIPs (seconds per sample)
    clairvoyant_max = QUICK["clairvoyant_max_carriers"] if quick else CLAIRVOYANT_MAX_CARRIERS
    mixed_max = QUICK["mixed_max_carriers"] if quick else MIXED_MAX_CARRIERS
    for level in levels:
        _, carriers, overlaps, trials, samples = CONFIGS[level]
        trials = QUICK["trials"] if quick else (settings.get("bound_trials") or trials)
        samples = QUICK["samples"] if quick else samples
        for t in range(trials):
            names = [p for p in settings["planners"] if not (p.startswith("dec-") and carriers > DEC_MAX_CARRIERS)]
            for name in (*names, *((CLAIRVOYANT,) if carriers <= clairvoyant_max else ())):
                tasks.append(Task("bound", level, t, name, settings["seed"], settings["iterations"], carriers=carriers,
                                  overlaps=overlaps))
            tasks.append(Task("bound", level, t, UPPER_BOUND, settings["seed"], 0, carriers=carriers,
                              overlaps=overlaps, samples=samples,
                              variant=bound_variant(settings.get("bound_method", "lp"), carriers, mixed_max)))
    return tasks


def bound_variant(method: str, carriers: int, mixed_max: int) -> str:
    """How a scale row's bound task of ``carriers`` computes its bound under ``--bound-method
    method`` (its ``variant``): ``mixed`` (every MIP solved), ``mixed-root`` (every MIP stopped after
    :data:`ROOT_NODES`) or ``""`` (the LP relaxation)."""
    if method in ("mixed", "mixed-root") and carriers <= mixed_max:
        return "mixed"
    return "mixed-root" if method == "mixed-root" else ""


def _config_columns(task: Task, extra: dict, result) -> dict:
    return {"config": CONFIGS[task.level][0]}


#: How experiments.trials.run_trial runs this sweep's planner and clairvoyant tasks.
SWEEP = Sweep(columns=_config_columns)


def scale_bound(problem, rng: np.random.Generator, samples: int, method: str, mip_max_nodes: int | None = None):
    """The scale rows' bound of ``problem`` by ``method`` (``lp``, ``mixed`` or ``mixed-root``:
    ``mixed`` with :data:`ROOT_NODES`): ``samples`` matrices after a pilot of half as many (at least
    2), one MIP's limit :data:`MIXED_MIP_TIME_LIMIT_S` (with a node limit, ``mip_max_nodes`` of
    tools.bound_nodes or ``mixed-root``'s: that many nodes, and :data:`ROOT_TIME_LIMIT_S`), and
    under ``mixed`` the pilot by :data:`MIXED_PILOT_METHOD`."""
    from planner import duality

    if method == "mixed-root":
        method, mip_max_nodes = "mixed", ROOT_NODES
    return duality.upper_bound(problem, rng, samples=samples, method=method, pilot=max(2, samples // 2),
                               mip_time_limit_s=MIXED_MIP_TIME_LIMIT_S if mip_max_nodes is None else ROOT_TIME_LIMIT_S,
                               pilot_method=MIXED_PILOT_METHOD if method == "mixed" else None,
                               mip_max_nodes=mip_max_nodes)


def bound_rng(seed: int, trial: int) -> np.random.Generator:
    """The observation stream of trial ``trial``'s bound (``(1000, trial, 2)`` of the root seed)."""
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(1000, trial, 2)))


def run_task(task: Task) -> dict:
    """One task of either part (see the module docstring); planners through ``run_trial``."""
    if task.planner == TINY:
        return _tiny(task)
    if task.planner != UPPER_BOUND:
        return run_trial(task, SWEEP)
    from experiments.trials import random_trial

    problem, _, planner_seed, _ = random_trial(task)
    t0 = time.perf_counter()
    bound = scale_bound(problem, bound_rng(task.seed, task.trial), task.samples, task.variant or "lp")
    return {"sweep": task.sweep, "level": task.level, "config": CONFIGS[task.level][0], "trial": task.trial,
            "planner": UPPER_BOUND, "reward": bound.expected_reward, "stderr": bound.stderr, "samples": bound.samples,
            "method": task.variant or bound.method, "strength": bound.strength, "carriers": problem.n_carriers, "overlaps": len(problem.overlaps),
            "iterations": 0, "seed": task.seed, "planner_seed": planner_seed, "wall_s": time.perf_counter() - t0}


def stand_in(prior):
    """The prior whose value V* is exactly: the prior itself (discrete) or its
    :data:`planner.online_optimal.CONTINUOUS_ATOMS`-point stand-in (continuous)."""
    from scipy import stats

    from planner import online_optimal, priors

    if priors.is_discrete(prior):
        return prior
    atoms = online_optimal.discretise(prior)
    return stats.rv_discrete(values=(atoms.points, atoms.probs))()


def tiny_instance(seed: int, k: int, kind: str = ""):
    """Tiny instance k: R = 2 + k % 2, N = 6, D = 2, 2 to 4 overlap groups, Poisson(3) (``kind``
    empty) or the stand-in of ``TINY_PRIORS[kind]``, and the generator its samples continue from:
    the first draw of streams ``(1002, k, a)`` (``(1003, k, a)`` with a kind), a = 0, 1, ...,
    within the exact solver's automatic limit (``AUTO_SECONDS``, its O(R·N) time estimate)."""
    from planner import online_optimal, priors
    from planner.instance import random_instance
    from planner.problem import Problem

    prior = stand_in(priors.build_prior(TINY_PRIORS[kind])) if kind else None
    for attempt in range(100):
        rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(1003 if kind else 1002, k, attempt)))
        groups = int(rng.integers(2, 5))
        problem = random_instance(rng, carriers=2 + k % 2, passengers=2, stages=6, overlaps=groups).problem
        if prior is not None:
            problem = Problem.build(problem.passengers, problem.valid, problem.overlaps, prior)
        try:
            online_optimal.estimate(problem, max_seconds=online_optimal.AUTO_SECONDS)
        except online_optimal.TooLarge:
            continue
        return problem, rng
    raise ValueError(f"no tiny instance within the exact solver's limits for seed {seed}, k = {k} {kind}")


def _tiny(task: Task) -> dict:
    """V*, the bound (adaptive penalty, its strength chosen on a discarded pilot), the fixed-penalty
    bound (its strength chosen by its own pilot on the same pilot matrices), the DLR-penalty bound
    and the clairvoyant mean, all on the same observation matrices."""
    import copy

    from planner import clairvoyant, duality, online_optimal
    from planner.problem import sample_observations

    t0 = time.perf_counter()
    problem, rng = tiny_instance(task.seed, task.trial, task.variant)
    best = online_optimal.online_value(problem).expected_reward
    # The fixed penalty's strength as the bound chose it before the adaptive penalty (its own pilot
    # of PILOT_SAMPLES matrices, the first of the same stream); the pilots' matrices are discarded.
    fixed_strength = duality.choose_strength(problem, copy.deepcopy(rng), "exact", duality.PILOT_SAMPLES)
    strength = duality.choose_strength(problem, rng, "exact", adaptive=True)
    discount = duality.conflict_discount(problem, strength, adaptive=True)
    fixed_discount = duality.conflict_discount(problem, fixed_strength)
    bound, fixed, dlr, offline = [], [], [], []
    for _ in range(task.samples):
        x = sample_observations(problem, rng)
        bound.append(duality.inner_maximum(problem, x, "exact", discount=discount, adaptive=True) / problem.scale)
        fixed.append(duality.inner_maximum(problem, x, "exact", discount=fixed_discount) / problem.scale)
        dlr.append(duality.inner_maximum(problem, x, "exact") / problem.scale)
        offline.append(clairvoyant.solve(problem, x).reward)
    return {"sweep": task.sweep, "level": task.level, "config": f"R = {problem.n_carriers}, {len(problem.overlaps)} groups",
            "trial": task.trial, "planner": UPPER_BOUND, "prior": task.variant or "poisson(3)",
            "reward": float(np.mean(bound)), "stderr": sem(bound),
            "samples": len(bound), "method": "exact", "strength": strength, "dlr_bound": float(np.mean(dlr)),
            "dlr_stderr": sem(dlr), "fixed_bound": float(np.mean(fixed)), "fixed_stderr": sem(fixed),
            "fixed_strength": fixed_strength, "v_star": best, "clairvoyant_mean": float(np.mean(offline)),
            "clairvoyant_stderr": sem(offline), "carriers": problem.n_carriers, "overlaps": len(problem.overlaps),
            "iterations": 0, "seed": task.seed, "wall_s": time.perf_counter() - t0}


# ----------------------------------------------------------------------------- report


def read_trials(path: Path) -> list[dict]:
    rows = read_csv(path, ("level", "trial", "carriers", "overlaps", "iterations", "seed"), ())
    for row in rows:
        for k in ("reward", "stderr", "v_star", "clairvoyant_mean", "clairvoyant_stderr", "wall_s", "decision_ms_mean",
                  "strength", "dlr_bound", "dlr_stderr", "fixed_bound", "fixed_stderr", "fixed_strength"):
            row[k] = float(row[k]) if row.get(k, "") != "" else float("nan")
    return rows


def _tiny_lines(tiny: list[dict]) -> tuple[list[str], dict]:
    """Table rows of tiny-instance results and their aggregate (mean excesses, their ratio, validity)."""
    lines, bound_ex, fixed_ex, dlr_ex, clair_ex, valid = [], [], [], [], [], []
    for r in tiny:
        v = r["v_star"]
        be, ce = 100 * (r["reward"] / v - 1), 100 * (r["clairvoyant_mean"] / v - 1)
        de, fe = 100 * (r["dlr_bound"] / v - 1), 100 * (r.get("fixed_bound", float("nan")) / v - 1)
        dlr_ex.append(de)
        fixed_ex.append(fe)
        ok = r["reward"] >= v - VALID_SE * r["stderr"]
        bound_ex.append(be)
        clair_ex.append(ce)
        valid.append(ok)
        lines.append(f"| #{r['trial']} {r['config']} | {r.get('prior') or 'poisson(3)'} | {v:.4f} | "
                     f"{r['reward']:.4f} ± {r['stderr']:.4f} (c = {r['strength']:g}) | {be:+.2f} % | "
                     f"{fe:+.2f} % (c = {r.get('fixed_strength', float('nan')):g}) | {de:+.2f} % | "
                     f"{r['clairvoyant_mean']:.4f} ± {r['clairvoyant_stderr']:.4f} | {ce:+.2f} % | "
                     f"{be / ce:.2f} | {'yes' if ok else 'NO'} |")
    agg = {"bound_excess_pct": float(np.mean(bound_ex)) if tiny else float("nan"),
           "clairvoyant_excess_pct": float(np.mean(clair_ex)) if tiny else float("nan"),
           "dlr_excess_pct": float(np.mean(dlr_ex)) if tiny else float("nan"),
           "fixed_excess_pct": float(np.mean(fixed_ex)) if tiny else float("nan"),
           "valid": f"{sum(valid)}/{len(valid)}", "all_valid": all(valid)}
    if tiny:
        agg["ratio"] = agg["bound_excess_pct"] / agg["clairvoyant_excess_pct"]
        lines.append(f"| mean over instances | | | | {agg['bound_excess_pct']:+.2f} % | {agg['fixed_excess_pct']:+.2f} % | "
                     f"{agg['dlr_excess_pct']:+.2f} % | | "
                     f"{agg['clairvoyant_excess_pct']:+.2f} % | {agg['ratio']:.2f} | {agg['valid']} |")
    return lines, agg


def tiny_table(rows: list[dict]) -> tuple[str, dict]:
    """The tiny part as markdown (the Poisson(3) instances, then one per prior kind), and the
    aggregate figures of each (``poisson``, ``priors``) and of both (``all``)."""
    head = ["| instance | prior | V* | bound (± SE, strength) | excess over V* | fixed-penalty bound's excess | "
            "DLR-penalty bound's excess | clairvoyant mean (± SE) | excess over V* | "
            f"excess ratio | valid (bound ≥ V* − {VALID_SE:g} SE) |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    tiny = sorted((r for r in rows if r["sweep"] == "bound-tiny"), key=lambda r: (r["level"], r["trial"]))
    parts = {"poisson": [r for r in tiny if r["level"] == 0], "priors": [r for r in tiny if r["level"] == 1]}
    text, agg = [], {}
    for name, part in parts.items():
        if not part:
            continue
        lines, agg[name] = _tiny_lines(part)
        text += (["", "One tiny instance per prior kind (continuous kinds: V*'s 12-atom stand-in):", ""]
                 if name == "priors" else []) + head + lines
    if tiny:
        agg["all"] = _tiny_lines(tiny)[1]
    return "\n".join(text), agg


def targets(summary: list[dict], tiny: dict) -> list[str]:
    """The comparison's targets, each marked met or not, with the figures that decide it."""
    out = []
    if "all" in tiny:
        a = tiny["all"]
        out.append(f"* valid (never below V* by more than {VALID_SE:g} SE): {a['valid']} tiny instances — "
                   f"{'met' if a['all_valid'] else 'NOT MET'}")
        for name, label in (("poisson", "Poisson(3) instances"), ("priors", "prior-kind instances"), ("all", "all")):
            if name in tiny:
                t = tiny[name]
                ok = t["ratio"] <= EXCESS_RATIO
                out.append(f"* mean excess over V*, {label}: {t['bound_excess_pct']:+.2f} % (fixed penalty "
                           f"{t.get('fixed_excess_pct', float('nan')):+.2f} %, DLR penalty alone "
                           f"{t['dlr_excess_pct']:+.2f} %; target ≤ {EXCESS_TARGET_PCT:g} %) — "
                           f"{'met' if t['bound_excess_pct'] <= EXCESS_TARGET_PCT else 'NOT MET'}")
                out.append(f"* mean excess over V*, {label}: {t['bound_excess_pct']:+.2f} % against clairvoyance's "
                           f"{t['clairvoyant_excess_pct']:+.2f} %, ratio {t['ratio']:.2f} (target ≤ {EXCESS_RATIO:.2f}) — "
                           f"{'met' if ok else 'NOT MET'}")
    for r in summary:
        if r["planner"] in OURS and r["carriers"] >= FRACTION_MIN_CARRIERS and r["config"] != "R = 4, 0 overlaps":
            ok = r["fraction_mean"] >= FRACTION_TARGET
            out.append(f"* {r['planner']} at {r['config']}: {r['fraction_mean']:.3f} ± {r['fraction_sem']:.3f} of the "
                       f"bound ({r['n']} trials; target ≥ {FRACTION_TARGET}) — {'met' if ok else 'NOT MET'}")
    return out


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


def split_table(summary: list[dict]) -> str:
    """For each configuration of :data:`SPLIT_CARRIERS`: the best bound (the upper bound's mean), the
    best planner (largest mean fraction) and the gap between them, split into what the bound's
    own noise explains (its mean standard error over the bound) and the rest."""
    lines = ["| configuration | best bound (mean ± SEM over trials) | its Monte Carlo SE | best planner | "
             "its fraction of the bound | gap to the bound |", "|---|---|---|---|---|---|"]
    for level in sorted({r["level"] for r in summary}):
        if CONFIGS[level][1] not in SPLIT_CARRIERS:
            continue
        rows = [r for r in summary if r["level"] == level]
        bound = next((r for r in rows if r["planner"] == UPPER_BOUND), None)
        planners = [r for r in rows if r["planner"] not in (UPPER_BOUND, CLAIRVOYANT)]
        if bound is None or not planners:
            continue
        best = max(planners, key=lambda r: r["fraction_mean"])
        lines.append(f"| {CONFIGS[level][0]} | {bound['reward_mean']:.3f} ± {bound['reward_sem']:.3f} | "
                     f"{bound['stderr_mean']:.3f} | {STYLE.get(best['planner'], (best['planner'],))[0]} | "
                     f"{best['fraction_mean']:.3f} ± {best['fraction_sem']:.3f} | "
                     f"{100 * (1 - best['fraction_mean']):.1f} % |")
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
    ax.axhline(FRACTION_TARGET, color="grey", linewidth=0.8, linestyle=":")
    ax.set_xticks(xs, [CONFIGS[lv][0].replace(", ", "\n") for lv in levels], fontsize=8)
    ax.set_ylabel("fraction of the new upper bound (± SEM)")
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def write_trials(rows: list[dict], path: Path) -> None:
    write_csv(sorted(rows, key=lambda r: (r["sweep"], r["level"], r["trial"], planner_order(r["planner"]))), path,
              FIELDS)


def _method_text(settings: dict) -> str:
    """How the scale rows' bound was computed, for bound.md (``--bound-method``)."""
    method = settings.get("bound_method", "lp")
    if method == "lp":
        return "the LP relaxation"
    limit = QUICK["mixed_max_carriers"] if settings.get("quick") else MIXED_MAX_CARRIERS
    beyond = ("the same with every MIP stopped after its root node beyond (method mixed-root)," if method == "mixed-root"
              else "the LP relaxation beyond,")
    return f"method mixed (the adaptive penalty; exact or MIP inner maxima) up to R = {limit}, {beyond}"


def write(rows: list[dict], out: Path, settings: dict, seconds: float, jobs: int) -> dict:
    write_trials(rows, out / "bound_trials.csv")
    summary = summarise(rows)
    write_csv(summary, out / "bound_summary.csv", SUMMARY_FIELDS)
    iterations = settings["iterations"]
    title = f"Planners as fractions of the information-relaxation bound (D = 3, N = 10, {iterations} iterations)"
    plot(summary, out / "bound.png", title)
    tiny, agg = tiny_table(rows)
    text = ["## Upper bound", "",
            "### Tiny instances: the new bound and the clairvoyant bound against V*", "",
            "R = 2 or 3, N = 6, D = 2, 2 to 4 overlap groups, Poisson(3) or one prior per kind; every bound on "
            "the same sampled observation matrices (exact inner maxima; the bound: the adaptive penalty, the "
            "fixed-penalty bound: as before it, the DLR-penalty bound: strength 0); excess = mean / V* − 1.", "",
            tiny, "",
            "### Planners as fractions of the new bound", "",
            f"Random instances, D = 3, N = 10, Poisson(3), {iterations} iterations per decision; the bound by "
            + _method_text(settings) + " from its own samples; fraction = reward / bound per trial, mean ± SEM "
            "(the clairvoyant column: the clairvoyant bound over the new one, the conflict-free bound where "
            f"its exact search stops). dec-closed-loop and the clairvoyant bound run up to R = {DEC_MAX_CARRIERS}.", "", scale_table(summary), "", "![fractions of the bound](bound.png)", "",
            "### Where the gap is", "", split_table(summary), "", "### Targets", "",
            *targets(summary, agg)]
    worker = defaultdict(float)
    for r in rows:
        worker[r["planner"]] += float(r["wall_s"])
    text += ["", f"Wall time: {seconds:.1f} s with {jobs} worker process(es) for {len(rows)} tasks; worker seconds: "
             + ", ".join(f"{k} {v:.0f} s" for k, v in sorted(worker.items())) + "."]
    (out / "bound.md").write_text("\n".join(text) + "\n")
    return {"sweep": "bound", "seconds": round(seconds, 1), "tasks": len(rows), "jobs": jobs, "tiny": agg}
