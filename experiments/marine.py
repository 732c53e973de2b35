"""``python -m experiments marine`` (issue 36, item 5): the planners on the marine family, with
perfect links and over the acoustic links the geometry predicts.

Worlds: two families of world/marine.py (``FAMILIES``) — the default survey (3 vessels, 2.4 x
1.6 km, ambient noise 98 dB) and a wider, noisier one (4 vessels, 3.2 x 2 km, 101 dB) whose far
corners fall out of the base's reach — each at ``trials`` generator seeds (a new hotspot layout
and current per seed; the mission's world seed is the generator's). Arms, on the same world,
observations and planner seed:

* ``perfect``: centralised closed-loop with perfect links (the reference);
* ``acoustic``: centralised closed-loop over the acoustic links: every message delivered, late
  or lost as the links' prediction says (world/linkplan.py, planner/comms.py ``LinkComms``); a
  carrier whose decision is lost deploys only when forced;
* ``hybrid``: the same with the fleet's hybrid carriers: a carrier whose decision is lost decides
  alone with dec-closed-loop on what it heard (``run_comms(..., fallback=)``);
* ``dec``: dec-closed-loop over the acoustic links (no coordinator);
* ``ssap`` (needs no messages) and the clairvoyant bound.

A result row's ``planner`` column names the arm (``algorithm`` the planner it runs).

Streams: generator seed of family f, trial t ``seed_of(seed, (1003, f, t))`` (also the world
seed); planner seed ``(1003, f, t, 1)``.
"""
from __future__ import annotations

import time
from collections import defaultdict
from functools import lru_cache
from pathlib import Path

import numpy as np

from experiments.report import read_csv, write_csv
from experiments.trials import CLAIRVOYANT, Task, _planner, encode, seed_of

#: (label, MarineSettings overrides) of each family.
FAMILIES = (("survey, 3 vessels, 98 dB", {}),
            ("wide, 4 vessels, 101 dB", {"vessels": 4, "width": 3200.0, "height": 2000.0, "noise_level_db": 101.0}))
#: Arms: (name, planner); the links are perfect for "perfect" and "ssap", the predicted acoustic ones for the others.
ARMS = (("perfect", "closed-loop"), ("acoustic", "closed-loop"), ("hybrid", "closed-loop"),
        ("dec", "dec-closed-loop"), ("ssap", "ssap"), (CLAIRVOYANT, CLAIRVOYANT))
LABELS = {"perfect": "closed-loop, perfect links", "acoustic": "closed-loop, acoustic",
          "hybrid": "closed-loop, acoustic, hybrid carriers", "dec": "dec-closed-loop, acoustic",
          "ssap": "SSAP", CLAIRVOYANT: "clairvoyant bound"}
DEFAULT_TRIALS, DEFAULT_ITERATIONS = 10, 2000
#: Prior fit of each generated world: seeds simulated (world/marine.py's ``prior_seeds``).
PRIOR_SEEDS = 8
FIELDS = ("sweep", "level", "family", "trial", "planner", "algorithm", "world_seed", "planner_seed", "iterations",
          "carriers", "stages", "link_mean", "link_least", "reward", "features", "wall_s", "deployed")


def build_tasks(settings: dict) -> list[Task]:
    return [Task("marine", f, t, arm, settings["seed"], settings["iterations"])
            for f in range(len(FAMILIES)) for t in range(settings["trials"]) for arm, _ in ARMS]


@lru_cache(maxsize=4)
def world(seed: int, family: int, trial: int):
    """``(scenario, problem, x, comms, world seed, planner seed)`` of one generated world (cached
    per process: every arm of a world rebuilds it)."""
    import world as w
    from world.linkplan import link_comms
    from world.marine import MarineSettings, marine_document
    from world.scenario import parse_scenario

    gen = seed_of(seed, (1003, family, trial)) % 2**31
    st = MarineSettings(name=f"marine-{family}-{trial}", seed=gen, prior_seeds=PRIOR_SEEDS, **FAMILIES[family][1])
    scenario = parse_scenario(marine_document(st), f"<marine family {family}, seed {gen}>")
    problem = w.build_problem(scenario)
    x = w.observe_all(scenario, seed=gen)
    return scenario, problem, x, link_comms(scenario), gen, seed_of(seed, (1003, family, trial, 1))


def run_task(task: Task) -> dict:
    from planner import clairvoyant
    from planner.decentralised import run_comms
    from planner.online import run_online
    from world.linkplan import summary

    scenario, problem, x, comms, gen, planner_seed = world(task.seed, task.level, task.trial)
    name = dict(ARMS)[task.planner]
    links = summary(comms)
    t0 = time.perf_counter()
    if name == CLAIRVOYANT:
        result = clairvoyant.solve(problem, x)
    else:
        planner = _planner(name, task.iterations)
        if task.planner in ("perfect", "ssap"):
            result = run_online(problem, x, planner, planner_seed)
        else:
            fallback = _planner("dec-closed-loop", task.iterations) if task.planner == "hybrid" else None
            result = run_comms(problem, x, planner, planner_seed, comms, fallback=fallback)
    return {"sweep": "marine", "level": task.level, "family": FAMILIES[task.level][0], "trial": task.trial,
            "planner": task.planner, "algorithm": name, "world_seed": gen, "planner_seed": planner_seed,
            "iterations": task.iterations, "carriers": problem.n_carriers, "stages": problem.n_stages,
            "link_mean": links["mean"], "link_least": links["least"], "reward": float(result.reward),
            "features": float(result.features), "wall_s": time.perf_counter() - t0,
            "deployed": encode(result.deployed)}


def read_trials(path: Path) -> list[dict]:
    return read_csv(path, ("level", "trial", "world_seed", "planner_seed", "iterations", "carriers", "stages"),
                    ("link_mean", "link_least", "reward", "features", "wall_s"))


def _kept(rows: list[dict]) -> dict:
    """(level, trial) -> arm -> reward as a fraction of the perfect-links arm."""
    by = defaultdict(dict)
    for r in rows:
        by[r["level"], r["trial"]][r["planner"]] = r
    return {k: {a: v["reward"] / arms["perfect"]["reward"] for a, v in arms.items()}
            for k, arms in by.items() if "perfect" in arms and arms["perfect"]["reward"] > 0}


def plot(rows: list[dict], path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    kept = _kept(rows)
    arms = [a for a, _ in ARMS if a != "perfect"]
    fig, axes = plt.subplots(1, len(FAMILIES), figsize=(6 * len(FAMILIES), 4.2), sharey=True, squeeze=False)
    for f, ax in enumerate(axes[0]):
        trials = sorted(t for (lv, t) in kept if lv == f)
        width = 0.8 / len(arms)
        for k, arm in enumerate(arms):
            ys = [kept[f, t].get(arm, np.nan) * 100 for t in trials]
            ax.bar(np.arange(len(trials)) + (k - len(arms) / 2 + 0.5) * width, ys, width, label=LABELS[arm])
        ax.axhline(100, color="black", lw=0.8)
        ax.axhline(90, color="tab:red", lw=0.8, ls="--")
        ax.set_xticks(range(len(trials)), [str(t) for t in trials])
        ax.set_xlabel("world (trial)")
        ax.set_title(FAMILIES[f][0], fontsize=10)
        ax.set_ylim(0, 170)
    axes[0][0].set_ylabel("reward, % of closed-loop with perfect links")
    handles, names = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, names, loc="lower center", ncol=len(arms), fontsize=8, frameon=False)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_trials(rows: list[dict], path: Path) -> None:
    """One row per (family, world, arm); ``planner`` names the arm, ``algorithm`` its planner."""
    write_csv(sorted(rows, key=lambda r: (r["level"], r["trial"], [a for a, _ in ARMS].index(r["planner"]))),
              path, FIELDS)


def write(rows: list[dict], out: Path, settings: dict, seconds: float, jobs: int) -> dict:
    """``marine_trials.csv``, ``marine.png`` and ``marine.md`` under ``out``; the run-info entry."""
    write_trials(rows, out / "marine_trials.csv")
    rows = read_trials(out / "marine_trials.csv")
    kept = _kept(rows)
    plot(rows, out / "marine.png", f"Marine family: {settings['trials']} generated worlds per family, "
                                   f"{settings['iterations']} iterations per decision; dashed: 90 %")
    arms = [a for a, _ in ARMS]
    text = ["## Marine family (acoustic links)", "",
            "Generated by `python -m experiments marine` (experiments/marine.py): two families of "
            "world/marine.py, each world a new generator seed (hotspots, current, fitted prior) and its "
            f"mission; {settings['iterations']} iterations per decision (per carrier for dec-closed-loop). "
            "Links: the acoustic model's prediction per stage (world/linkplan.py). Reward (normalised), "
            "and in brackets as % of centralised closed-loop with perfect links; `link` is the mean / "
            "least predicted delivery probability between the base and the vessels.", ""]
    for f, (label, _) in enumerate(FAMILIES):
        sub = sorted((r for r in rows if r["level"] == f), key=lambda r: r["trial"])
        if not sub:
            continue
        text += [f"### {label}", "", "| seed (world) | link | " + " | ".join(LABELS[a] for a in arms) + " |",
                 "|---" * (len(arms) + 2) + "|"]
        for t in sorted({r["trial"] for r in sub}):
            got = {r["planner"]: r for r in sub if r["trial"] == t}
            first = next(iter(got.values()))
            cells = []
            for a in arms:
                if a not in got:
                    cells.append("–")
                    continue
                frac = kept.get((f, t), {}).get(a)
                cells.append(f"{got[a]['reward']:.2f}" + (f" ({frac * 100:.1f} %)" if frac is not None and a != "perfect" else ""))
            text.append(f"| {t} ({first['world_seed']}) | {first['link_mean']:.2f} / {first['link_least']:.2f} | "
                        + " | ".join(cells) + " |")
        means = {a: np.mean([kept[f, t][a] for t in {r["trial"] for r in sub} if a in kept.get((f, t), {})])
                 for a in arms if a not in ("perfect",)}
        text += ["", "Mean kept: " + ", ".join(f"{LABELS[a]} {v * 100:.1f} %" for a, v in means.items()) + ".", ""]
    text += ["![Marine family](marine.png)", "",
             f"Wall time: {seconds:.1f} s with {jobs} worker process(es) for {len(rows)} tasks."]
    (out / "marine.md").write_text("\n".join(text) + "\n")
    return {"sweep": "marine", "seconds": round(seconds, 1), "tasks": len(rows), "jobs": jobs}
