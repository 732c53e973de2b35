"""One unit of work of an experiment: one planner (or the clairvoyant bound) on one trial.

A trial is fully determined by ``(seed, trial index)`` and the sweep's settings, so every task of
a trial rebuilds the *same* instance and observations (common random numbers) in whichever worker
process runs it, and every planner gets the same planner seed. Tasks are plain frozen dataclasses
so they pickle cheaply to ``spawn`` workers.

Streams (``numpy.random.SeedSequence(seed, spawn_key=...)``):

* ``(1000, t)``: trial t's instance (validity, overlaps, observations) of a random sweep;
* ``(1000, t, 1)``: trial t's planner seed (the root seed handed to ``run_online``);
* ``(1001, t)``: urban trial t's world seed (the features) and ``(1001, t, 1)`` its planner seed.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

#: Name of the offline bound in result rows.
CLAIRVOYANT = "clairvoyant"


@dataclass(frozen=True)
class Task:
    """One planner on one trial.

    Attributes:
        sweep: ``overlap``, ``scaling`` or ``urban``.
        level: the sweep's x value (overlaps, carriers, or 0 for urban).
        trial: trial index t.
        planner: planner name, or :data:`CLAIRVOYANT`.
        seed: root seed of the experiment.
        iterations: MCTS-style budget per decision.
        carriers, passengers, stages, overlaps, mean: random-instance settings (R, D, N, number of
            overlap groups, Poisson mean); unused for urban.
        scenario: scenario file (urban and priors).
        loss, delay: the communication model (comms sweeps; the deliveries are drawn from the
            planner seed, so every planner of a trial meets the same ones).
        variant, prior_factor, oracle: priors sweep only (experiments.priors): ``stated``,
            ``learned`` or ``oracle``; factor on the stated (derived Poisson) prior's mean; the
            world's observed (mean, variance) the oracle prior is fitted to.
    """

    sweep: str
    level: int
    trial: int
    planner: str
    seed: int
    iterations: int
    carriers: int = 4
    passengers: int = 3
    stages: int = 10
    overlaps: int = 10
    mean: float = 3.0
    scenario: str = ""
    variant: str = ""
    prior_factor: float = 1.0
    oracle: tuple = ()
    loss: float = 0.0
    delay: int = 0

    @property
    def cost(self) -> float:
        """Rough relative run time, used to start the longest tasks first (load balance)."""
        if self.planner in ("random", "ssap"):
            return 0.01
        if self.planner == CLAIRVOYANT:
            return 0.05 * self.carriers
        scale = self.carriers * self.stages / 40.0
        if self.planner.startswith("dec-"):
            scale *= self.carriers
        return scale * self.iterations / 10_000


# ----------------------------------------------------------------------------- instances


def trial_instance(task: Task):
    """``(problem, observations, planner_seed, extra)`` of the task's trial (same for every planner)."""
    if task.sweep == "urban":
        return _urban_instance(task)
    if task.sweep == "priors":
        return _priors_instance(task)
    if task.sweep == "types":
        return _types_instance(task)
    # Comms sweeps: trial t is the same instance at every message-loss level (paired across P).
    from planner.instance import random_instance

    rng = np.random.default_rng(np.random.SeedSequence(task.seed, spawn_key=(1000, task.trial)))
    inst = random_instance(rng, task.carriers, task.passengers, task.stages, task.overlaps, task.mean)
    planner_seed = _seed_of(task.seed, (1000, task.trial, 1))
    return inst.problem, inst.observations, planner_seed, {}


def _seed_of(seed: int, key: tuple[int, ...]) -> int:
    return int(np.random.SeedSequence(seed, spawn_key=key).generate_state(1, np.uint32)[0])


_WORLD_CACHE: dict = {}


def urban_world_seed(seed: int, trial: int) -> int:
    """World (feature) seed of urban trial ``trial``."""
    return _seed_of(seed, (1001, trial))


def _urban_instance(task: Task):
    import world

    key = task.scenario
    if key not in _WORLD_CACHE:
        scenario = world.load_scenario(task.scenario)
        problem = world.build_problem(scenario)
        _WORLD_CACHE[key] = (scenario, problem)
    scenario, problem = _WORLD_CACHE[key]
    world_seed = scenario.seed if task.trial == 0 else urban_world_seed(task.seed, task.trial)
    x = world.observe_all(scenario, seed=world_seed)
    return problem, x, _seed_of(task.seed, (1001, task.trial, 1)), {"world_seed": world_seed}


def _priors_instance(task: Task):
    """The urban-style world trial with the task's prior variant: the stated prior (the scenario's,
    its Poisson mean scaled by ``prior_factor``) for ``stated`` and ``learned``, the oracle for
    ``oracle``; every variant keeps the stated prior's normalisation scale."""
    import scipy.stats

    from experiments.priors import oracle_prior

    problem, x, planner_seed, extra = _urban_instance(task)
    if task.prior_factor != 1.0:
        stated = problem.prior
        if getattr(stated.dist, "name", None) != "poisson":
            raise ValueError(f"prior_factor needs a Poisson stated prior, found {stated.dist.name}")
        problem = _replace_prior(problem, scipy.stats.poisson(float(stated.mean()) * task.prior_factor))
    extra = {**extra, "scale": problem.scale, "stated_mean": float(problem.prior.mean()),
             "oracle_mean": task.oracle[0], "oracle_var": task.oracle[1]}
    if task.variant == "oracle":
        problem = _replace_prior(problem, oracle_prior(*task.oracle), problem.scale)
    return problem, x, planner_seed, extra


def _types_instance(task: Task):
    """A trial of the passenger-types sweep (experiments.types): the random or urban instance with
    every carrier's passenger values."""
    from experiments.types import fleet_values
    from planner.instance import random_instance
    from planner.problem import Problem

    if task.scenario:
        problem, x, planner_seed, extra = _urban_instance(task)
        if problem.weights is None:  # a scenario without passenger types: the sweep's two types
            problem = Problem.build(problem.passengers, problem.valid, problem.overlaps, problem.prior,
                                    weights=fleet_values(problem.passengers))
        return problem, x, planner_seed, extra
    rng = np.random.default_rng(np.random.SeedSequence(task.seed, spawn_key=(1000, task.trial)))
    inst = random_instance(rng, task.carriers, task.passengers, task.stages, task.overlaps, task.mean,
                           weights=fleet_values([task.passengers] * task.carriers))
    return inst.problem, inst.observations, _seed_of(task.seed, (1000, task.trial, 1)), {}


def _replace_prior(problem, prior, scale=None):
    from planner.problem import Problem

    return Problem.build(problem.passengers, problem.valid, problem.overlaps, prior,
                         normalize="q90" if scale is None else scale)


# ----------------------------------------------------------------------------- running

_PLANNERS: dict = {}


def _planner(name: str, iterations: int, learn_prior: bool = False):
    key = (name, iterations, learn_prior)
    if key not in _PLANNERS:
        from planner.registry import make_planner

        _PLANNERS[key] = make_planner(name, iterations=iterations, learn_prior=learn_prior)
    return _PLANNERS[key]


def run_task(task: Task) -> dict:
    """Run one task; returns one result row (a flat dict, see :data:`experiments.report.TRIAL_FIELDS`)."""
    from planner import clairvoyant
    from planner.online import run_online

    problem, x, planner_seed, extra = trial_instance(task)
    row = {
        "sweep": task.sweep, "level": task.level, "trial": task.trial, "planner": task.planner,
        "carriers": problem.n_carriers, "passengers": int(problem.passengers.max()),
        "stages": problem.n_stages, "overlaps": len(problem.overlaps), "iterations": task.iterations,
        "seed": task.seed, "planner_seed": planner_seed, "world_seed": extra.get("world_seed", ""),
    }
    if task.sweep == "priors":
        from experiments.priors import CASES

        row.update(case=CASES[task.level][0], variant=task.variant, **{k: extra[k] for k in (
            "scale", "stated_mean", "oracle_mean", "oracle_var")})
    t0 = time.perf_counter()
    if task.planner == CLAIRVOYANT:
        result = clairvoyant.solve(problem, x)
        elapsed = time.perf_counter() - t0
        row.update(reward=result.reward, features=result.features, exact=int(result.exact),
                   decision_ms_mean=elapsed * 1e3, decision_ms_max=elapsed * 1e3, wall_s=elapsed,
                   deployed=_encode(result.deployed))
        if task.sweep == "types":
            row.update(case=_types_case(task), variant=task.variant, released=_encode_released(result.released))
        return row
    planner = _planner(task.planner, task.iterations, task.variant == "learned")
    if task.sweep == "types" and task.variant in ("blind", "choice"):
        from planner.passengers import TypeBlind, UnweightedSearch

        planner = (TypeBlind if task.variant == "blind" else UnweightedSearch)(planner)
    if task.sweep.startswith("comms"):
        from planner.comms import CommsSpec
        from planner.decentralised import run_comms

        result = run_comms(problem, x, planner, planner_seed, CommsSpec(task.loss, task.delay))
    else:
        result = run_online(problem, x, planner, planner_seed)
    elapsed = time.perf_counter() - t0
    ms = np.asarray(result.decision_ms)
    row.update(reward=result.reward, features=result.features, exact="",
               decision_ms_mean=float(ms.mean()), decision_ms_max=float(ms.max()), wall_s=elapsed,
               deployed=_encode(result.deployed))
    if task.sweep == "types":
        row.update(case=_types_case(task), variant=task.variant, released=_encode_released(result.released))
    return row


def _types_case(task: Task) -> str:
    from experiments.types import CASES

    return CASES[task.level][0]


def _encode_released(released: np.ndarray) -> str:
    """Passenger index of each deployment in stage order (carriers separated by ``|``)."""
    return "|".join(" ".join(str(int(i)) for i in row if i >= 0) for row in np.asarray(released))


def _encode(deployed: np.ndarray) -> str:
    """Deployments as ``stage stage|stage ...`` (carriers separated by ``|``), for the CSV."""
    return "|".join(" ".join(str(j) for j in np.flatnonzero(row)) for row in np.asarray(deployed))


def decode(text: str, n_carriers: int, n_stages: int) -> np.ndarray:
    """Inverse of :func:`_encode`: bool ``[R, N]``."""
    out = np.zeros((n_carriers, n_stages), dtype=bool)
    for r, part in enumerate(str(text).split("|")):
        for j in part.split():
            out[r, int(j)] = True
    return out


def warm_up_worker(names: tuple[str, ...] | None = None) -> None:
    """Load (or compile) the numba kernels once per worker process before any timed decision:
    those of the planners ``names`` (every registered planner when None)."""
    import warnings

    warnings.filterwarnings("ignore", category=RuntimeWarning)
    from planner import clairvoyant

    clairvoyant.warm_up()
    from planner.instance import random_instance
    from planner.registry import make_planner, planner_names

    inst = random_instance(np.random.default_rng(0), 2, 1, 3, 1, 3.0)
    for name in planner_names() if names is None else [n for n in names if n in planner_names()]:
        planner = make_planner(name, iterations=16)
        warm = getattr(planner, "warm_up", None)
        if callable(warm):
            warm(inst.problem)
