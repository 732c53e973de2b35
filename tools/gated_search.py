"""closed-loop-gated against closed-loop, on paired trials of two instance families.

    python -m tools.gated_search --family paper --carriers 128 --trials 20-35 --obs 4
    python -m tools.gated_search --family dense --carriers 32 --trials 20-39 --obs 8 --out dense32.csv

``previous`` is ``closed-loop`` (the candidate with the largest estimate; the base action in
carrier index order), ``new`` is ``closed-loop-gated`` (:data:`planner.closedloop.GATE`, the base
action by margin; docs/planner.md, "closed-loop-gated"), both built by the registry with
``--iterations`` per decision, on the same instances, observations and planner seeds.

Families (D = 3, N = 10):

* ``paper``: the upper-bound experiment's instances (``python -m experiments bound``): trial t's
  instance and observations are stream ``(1000, t)`` of ``random_instance`` with 5 R overlap
  groups (20 at R < 6), Poisson(3); its bound's samples ``(1000, t, 2)``.
* ``dense``: denser overlaps and another prior: 8 R overlap groups drawn by ``random_instance`` from
  stream ``(5000, t)``, the prior replaced by the negative binomial (n = 2, p = 0.4: mean 3,
  variance 7.5, normalised by its q90) and the observations drawn from it on the same stream;
  its bound's samples ``(5000, t, 2)``.

Observation matrix k of trial t: k = 0 the trial's own, k >= 1 stream ``(7000, t, k, f)`` (f = 0
paper, 1 dense); planner seed ``(1000, t, 1, k)``. Per trial the planners' rewards are averaged
over ``--obs`` matrices, and the bound of the instance (``planner.duality.upper_bound``, LP
relaxation or ``--bound-method mixed``, ``BOUND_SAMPLES`` samples) divides them. It prints one line per trial and the summary:
the paired difference new - previous as mean ± SEM over trials with wins and losses, each
planner's fraction of the bound (mean ± SEM over trials) and its mean decision time (one
process; the times are the machine's, and only comparable when nothing else runs on its core).
"""
from __future__ import annotations

import argparse
import sys

import numpy as np

from experiments.report import sem
from tools.base_policy import parse_trials, run_trials

#: Bound samples per trial by R (experiments.bound.CONFIGS); 6 for other sizes.
BOUND_SAMPLES = {4: 30, 6: 30, 32: 12, 128: 6, 256: 4}
FAMILIES = ("paper", "dense")
#: The two planners: (column, registered name).
PLANNERS = (("previous", "closed-loop"), ("new", "closed-loop-gated"))


def family_problem(family: str, rng: np.random.Generator, carriers: int, passengers: int = 3, stages: int = 10,
                   groups: int | None = None):
    """``(problem, observations)``: one instance of ``family`` (module docstring) drawn from ``rng``
    (the instance, then its observations, on the same stream), with ``passengers`` per carrier,
    ``stages`` stages and ``groups`` overlap groups (None: the family's, 5 R or 8 R)."""
    from scipy import stats

    from planner.instance import random_instance
    from planner.problem import Problem, sample_observations

    if family == "paper":
        groups = groups or (5 * carriers if carriers >= 6 else 20)
        inst = random_instance(rng, carriers, passengers, stages, groups, 3.0)
        return inst.problem, inst.observations
    if family == "dense":
        base = random_instance(rng, carriers, passengers, stages, groups or 8 * carriers, 3.0).problem
        problem = Problem.build(base.passengers, base.valid, base.overlaps, stats.nbinom(2, 0.4))
        return problem, sample_observations(problem, rng)
    raise ValueError(f"family: expected one of {', '.join(FAMILIES)}, found {family!r}")


def instance(family: str, carriers: int, trial: int, seed: int = 0):
    """``(problem, observations)`` of trial ``trial`` of ``family`` (module docstring)."""
    if family not in FAMILIES:
        raise ValueError(f"family: expected one of {', '.join(FAMILIES)}, found {family!r}")
    key = (1000, trial) if family == "paper" else (5000, trial)
    return family_problem(family, np.random.default_rng(np.random.SeedSequence(seed, spawn_key=key)), carriers)


def observations(family: str, problem, x0: np.ndarray, trial: int, k: int, seed: int = 0) -> np.ndarray:
    """Observation matrix ``k`` of the trial (k = 0: its own, ``x0``)."""
    from planner.problem import sample_observations

    if k == 0:
        return x0
    key = (7000, trial, k, FAMILIES.index(family))
    return sample_observations(problem, np.random.default_rng(np.random.SeedSequence(seed, spawn_key=key)))


def run_trial(family: str, carriers: int, trial: int, obs: int, iterations: int, seed: int,
              bound_samples: int, bound_method: str = "lp") -> dict:
    """One trial: both planners' mean rewards over ``obs`` observation matrices, their decision
    times, and the instance's bound."""
    from experiments.bound import scale_bound
    from experiments.trials import seed_of
    from planner.online import run_online
    from planner.registry import make_planner

    problem, x0 = instance(family, carriers, trial, seed)
    row = {"family": family, "carriers": carriers, "trial": trial, "obs": obs}
    planners = {column: make_planner(name, iterations=iterations) for column, name in PLANNERS}
    rewards = {name: [] for name in planners}
    times = {name: [] for name in planners}
    for k in range(obs):
        x = observations(family, problem, x0, trial, k, seed)
        planner_seed = seed_of(seed, (1000, trial, 1, k))
        for name, planner in planners.items():
            result = run_online(problem, x, planner, planner_seed)  # warms the planner up first
            rewards[name].append(result.reward)
            times[name].extend(result.decision_ms)
    for name in planners:
        row[name] = float(np.mean(rewards[name]))
        row[name + "_ms"] = float(np.mean(times[name]))
        row[name + "_ms_median"] = float(np.median(times[name]))
    key = (1000, trial, 2) if family == "paper" else (5000, trial, 2)
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=key))
    bound = scale_bound(problem, rng, bound_samples, bound_method)
    row["bound"] = bound.expected_reward
    row["bound_stderr"] = bound.stderr
    return row


def summary(rows: list[dict]) -> list[str]:
    diff = np.array([r["new"] - r["previous"] for r in rows])
    first = rows[0]
    lines = [f"{first['family']}, R = {first['carriers']}, {len(rows)} trials ({first['trial']}..{rows[-1]['trial']}), "
             f"{first['obs']} observation matrices each:",
             f"  paired difference new - previous: {diff.mean():+.3f} ± {sem(diff):.3f} per trial "
             f"({diff.mean() / np.mean([r['previous'] for r in rows]) * 100:+.2f} %), "
             f"{int((diff > 0).sum())} wins, {int((diff < 0).sum())} losses, {int((diff == 0).sum())} ties"]
    for name, _ in PLANNERS:
        frac = np.array([r[name] / r["bound"] for r in rows])
        lines.append(f"  {name:8s}: reward {np.mean([r[name] for r in rows]):.3f}, fraction of the bound "
                     f"{frac.mean():.4f} ± {sem(frac):.4f}, decision {np.mean([r[name + '_ms'] for r in rows]):.1f} ms "
                     f"(median over trials of the per-trial median {np.median([r[name + '_ms_median'] for r in rows]):.1f} ms)")
    lines.append(f"  bound   : {np.mean([r['bound'] for r in rows]):.3f}")
    return lines


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tools.gated_search", description=__doc__.split("\n\n")[0])
    parser.add_argument("--family", default="paper", choices=FAMILIES, help="instance family (default paper)")
    parser.add_argument("--carriers", type=int, default=32, help="R (default 32)")
    parser.add_argument("--trials", default="20-39", help="trial indices, e.g. 20-39 or 20,22 (default 20-39)")
    parser.add_argument("--obs", type=int, default=4, help="observation matrices per trial (default 4)")
    parser.add_argument("--iterations", type=int, default=2000, help="iterations per decision (default 2000)")
    parser.add_argument("--seed", type=int, default=0, help="root seed of the trials (default 0)")
    parser.add_argument("--bound-samples", type=int, default=None,
                        help="sampled observation matrices of the bound (default: the experiment's)")
    parser.add_argument("--bound-method", default="lp", choices=("lp", "mixed", "mixed-root"),
                        help="inner maxima of the bound: lp (the LP relaxation, fixed penalty; default), mixed "
                             "(the adaptive penalty, exact or MIP per component, its strength by an LP pilot: "
                             "experiments bound's method up to R = 128) or mixed-root (the same with every MIP "
                             "stopped after its root node: experiments bound's method beyond R = 128)")
    parser.add_argument("--out", default=None, help="also write the per-trial rows to this CSV")
    args = parser.parse_args(argv)
    if args.carriers < 2 or args.iterations < 1 or args.obs < 1:
        parser.error("--carriers must be at least 2, --iterations and --obs at least 1")
    try:
        trials = parse_trials(args.trials)
    except ValueError:
        parser.error(f"--trials: expected indices like 20-39 or 20,22, found {args.trials!r}")
    samples = args.bound_samples or BOUND_SAMPLES.get(args.carriers, 6)
    run_trials(trials, lambda t: run_trial(args.family, args.carriers, t, args.obs, args.iterations, args.seed, samples,
                                           args.bound_method),
               lambda row: f"previous {row['previous']:.3f}  new {row['new']:.3f}  difference "
                           f"{row['new'] - row['previous']:+.3f}  bound {row['bound']:.2f} ± {row['bound_stderr']:.2f}",
               summary, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
