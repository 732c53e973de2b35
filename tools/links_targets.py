"""Issue 36's planner-level targets, seed by seed (figures, no assertions; docs/results.md):

    python -m tools.links_targets cut-off --seeds 20       # a carrier cut off vs SSAP alone
    python -m tools.links_targets cut-off --predict        # the same, the on-board planner predicting its peers
    python -m tools.links_targets loss --trials 10         # 50 % random loss vs the uninterrupted fleet

* ``cut-off``: scenarios/six_carriers.yaml, c1 cut off from everybody at stages 3 to 9 (a
  ``LinkComms`` cut), the coordinator's ``mcts-ssap``, the hybrid fallback ``dec-closed-loop``
  (tools.faults' carrier-cut-off, at the planner level): the mission's reward against the same
  mission with c1's deployments from stage 3 on replaced by SSAP's (``planner.ssap.alone``).
  ``--predict`` hands the on-board planner an uncoordinated view (it then predicts its peers by
  their thresholds: the rule before issue 36).
* ``loss``: random paper-style instances (R = 4, 20 overlaps; R = 6, 10 overlaps), every message
  lost with probability 0.5: hybrid closed-loop (fallback dec-closed-loop) and dec-closed-loop
  against closed-loop with perfect links on the same instance and planner seed.
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import replace

import numpy as np


class Uncoordinated:
    """An on-board planner that is never told its fleet is coordinated."""

    def __init__(self, planner):
        self.planner = planner

    def decide_local(self, local, rng):
        return self.planner.decide_local(replace(local, coordinated=False), rng)


def cut_off(seeds: int, iterations: int, predict: bool) -> None:
    import world
    from planner import ssap
    from planner.comms import LinkComms
    from planner.decentralised import run_comms
    from planner.problem import evaluate
    from planner.registry import make_planner
    from world.paths import REPO_ROOT

    scenario = world.load_scenario(REPO_ROOT / "scenarios" / "six_carriers.yaml")
    problem = world.build_problem(scenario)
    R, N = problem.valid.shape
    p = np.ones((N, R + 1, R + 1))
    p[3:10, 1, :] = p[3:10, :, 1] = 0.0
    central, onboard = make_planner("mcts-ssap", iterations=iterations), make_planner("dec-closed-loop")
    central.warm_up(problem)
    onboard.warm_up(problem)
    fallback = Uncoordinated(onboard) if predict else onboard
    diffs = []
    print("| world seed | reward | c1 by SSAP alone | difference |\n| --- | --- | --- | --- |")
    for seed in range(1, seeds + 1):
        x = world.observe_all(scenario, seed=seed)
        res = run_comms(problem, x, central, seed, LinkComms(p), fallback=fallback)
        xs = np.where(problem.valid, x, np.nan)
        alone = float(evaluate(problem, ssap.alone(problem, xs, res.deployed, 0, 3), xs)[0])
        diffs.append(res.reward - alone)
        print(f"| {seed} | {res.reward:.3f} | {alone:.3f} | {diffs[-1]:+.3f} |", flush=True)
    d = np.asarray(diffs)
    print(f"mean difference {d.mean():+.3f} ± {d.std(ddof=1) / np.sqrt(len(d)) if len(d) > 1 else 0:.3f} (SEM); "
          f"below SSAP alone on {(d < -1e-9).sum()} of {len(d)} seeds")


def loss(trials: int, iterations: int, level: float = 0.5) -> None:
    from planner.comms import CommsSpec
    from planner.decentralised import run_comms
    from planner.instance import random_instance
    from planner.online import run_online
    from planner.registry import make_planner

    central = make_planner("closed-loop", iterations=iterations)
    dec = make_planner("dec-closed-loop", iterations=iterations)
    for R, overlaps in ((4, 20), (6, 10)):
        print(f"\nR = {R}, {overlaps} overlaps, loss {level:g}\n")
        print("| trial | perfect | hybrid | dec-closed-loop |\n| --- | --- | --- | --- |")
        kept = {"hybrid": [], "dec": []}
        for t in range(trials):
            rng = np.random.default_rng(np.random.SeedSequence(36, spawn_key=(R, t)))
            inst = random_instance(rng, R, 3, 10, overlaps, 3.0)
            seed = int(rng.integers(2**31))
            base = run_online(inst.problem, inst.observations, central, seed).reward
            hyb = run_comms(inst.problem, inst.observations, central, seed, CommsSpec(loss=level), fallback=dec).reward
            de = run_comms(inst.problem, inst.observations, dec, seed, CommsSpec(loss=level)).reward
            kept["hybrid"].append(hyb / base)
            kept["dec"].append(de / base)
            print(f"| {t} | {base:.3f} | {hyb:.3f} ({hyb / base * 100:.1f} %) | {de:.3f} ({de / base * 100:.1f} %) |",
                  flush=True)
        print("\nmean kept: " + ", ".join(f"{k} {np.mean(v) * 100:.1f} % (min {np.min(v) * 100:.1f} %)"
                                         for k, v in kept.items()))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m tools.links_targets", description=__doc__.split("\n\n")[0])
    p.add_argument("what", choices=("cut-off", "loss"))
    p.add_argument("--seeds", type=int, default=20, help="cut-off: world seeds 1..N (default %(default)s)")
    p.add_argument("--trials", type=int, default=10, help="loss: instances per configuration (default %(default)s)")
    p.add_argument("--iterations", type=int, default=2000, help="planning budget per decision (default %(default)s)")
    p.add_argument("--predict", action="store_true", help="cut-off: the on-board planner predicts its peers")
    args = p.parse_args(argv)
    if min(args.seeds, args.trials, args.iterations) < 1:
        print("--seeds, --trials, --iterations: expected integers >= 1", file=sys.stderr)
        return 2
    if args.what == "cut-off":
        cut_off(args.seeds, args.iterations, args.predict)
    else:
        loss(args.trials, args.iterations)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
