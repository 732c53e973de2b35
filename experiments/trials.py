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
from typing import Callable

import numpy as np

from planner.settings import DEFAULT_ITERATIONS

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
            world's observed (mean, variance) the oracle prior is fitted to. Bound sweep
            (experiments.bound): ``variant`` is a tiny instance's prior kind, or ``mixed`` for an
            upper-bound task by that method.
        samples: sampled observation matrices of a bound task (experiments.bound).
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
    samples: int = 0

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
        return scale * self.iterations / DEFAULT_ITERATIONS


# ----------------------------------------------------------------------------- instances


def random_trial(task: Task):
    """``(problem, observations, planner_seed, extra)`` of a random-instance trial (the overlap,
    scaling and comms sweeps; the same for every planner). Comms sweeps: trial t is the same
    instance at every message-loss level (paired across P)."""
    from planner.instance import random_instance

    rng = np.random.default_rng(np.random.SeedSequence(task.seed, spawn_key=(1000, task.trial)))
    inst = random_instance(rng, task.carriers, task.passengers, task.stages, task.overlaps, task.mean)
    planner_seed = seed_of(task.seed, (1000, task.trial, 1))
    return inst.problem, inst.observations, planner_seed, {}


def seed_of(seed: int, key: tuple[int, ...]) -> int:
    """The 32-bit seed of stream ``SeedSequence(seed, spawn_key=key)``."""
    return int(np.random.SeedSequence(seed, spawn_key=key).generate_state(1, np.uint32)[0])


_WORLD_CACHE: dict = {}


def urban_world_seed(seed: int, trial: int) -> int:
    """World (feature) seed of urban trial ``trial``."""
    return seed_of(seed, (1001, trial))


def urban_trial(task: Task):
    """``(problem, observations, planner_seed, extra)`` of an urban (world scenario) trial."""
    import world

    key = task.scenario
    if key not in _WORLD_CACHE:
        scenario = world.load_scenario(task.scenario)
        problem = world.build_problem(scenario)
        _WORLD_CACHE[key] = (scenario, problem)
    scenario, problem = _WORLD_CACHE[key]
    world_seed = scenario.seed if task.trial == 0 else urban_world_seed(task.seed, task.trial)
    x = world.observe_all(scenario, seed=world_seed)
    return problem, x, seed_of(task.seed, (1001, task.trial, 1)), {"world_seed": world_seed}


def replace_prior(problem, prior, scale=None):
    """The problem with another prior (normalised by its q90, or by ``scale``)."""
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


@dataclass(frozen=True)
class Sweep:
    """How :func:`run_trial` runs the tasks of one sweep. The hooks are module-level functions, so
    a sweep pickles (by reference) to ``spawn`` and cluster workers with its task.

    Attributes:
        instance: the trial builder, ``task -> (problem, observations, planner_seed, extra)``; a
            builder of coverage trials puts the realised region counts in ``extra["counts"]``
            (the planners and the clairvoyant read them there).
        columns: the sweep's own columns of a result row, ``(task, extra, result) -> dict``.
        wrap: ``(task, planner) -> planner``: the planner variant a task runs.
        comms: run under the task's communication model (``loss``, ``delay``) with ``run_comms``.
    """

    instance: Callable = random_trial
    columns: Callable | None = None
    wrap: Callable | None = None
    comms: bool = False


def run_trial(task: Task, sweep: Sweep = Sweep()) -> dict:
    """Run one task of ``sweep``; returns one result row (a flat dict, see
    :data:`experiments.report.TRIAL_FIELDS`). ``experiments.run.run_task`` picks the sweep."""
    from planner import clairvoyant
    from planner.online import run_online

    problem, x, planner_seed, extra = sweep.instance(task)
    counts = extra.get("counts")  # a coverage trial's realised region counts (None for the penalty)
    row = {
        "sweep": task.sweep, "level": task.level, "trial": task.trial, "planner": task.planner,
        "carriers": problem.n_carriers, "passengers": int(problem.passengers.max()),
        "stages": problem.n_stages, "overlaps": len(problem.overlaps), "iterations": task.iterations,
        "seed": task.seed, "planner_seed": planner_seed, "world_seed": extra.get("world_seed", ""),
    }
    t0 = time.perf_counter()
    if task.planner == CLAIRVOYANT:
        # Under coverage the clairvoyant is planner.coverage_bounds.solve (exact by integer
        # programming within its size, else a bound: ``exact`` 0).
        result = clairvoyant.solve(problem, x, counts=counts)
        elapsed = time.perf_counter() - t0
        row.update(reward=result.reward, features=result.features, exact=int(result.exact),
                   decision_ms_mean=elapsed * 1e3, decision_ms_max=elapsed * 1e3, wall_s=elapsed,
                   deployed=encode(result.deployed))
    else:
        planner = _planner(task.planner, task.iterations, task.variant == "learned")
        if sweep.wrap is not None:
            planner = sweep.wrap(task, planner)
        if sweep.comms:
            from planner.comms import CommsSpec
            from planner.decentralised import run_comms

            result = run_comms(problem, x, planner, planner_seed, CommsSpec(task.loss, task.delay), counts)
        else:
            result = run_online(problem, x, planner, planner_seed, counts)
        elapsed = time.perf_counter() - t0
        ms = np.asarray(result.decision_ms)
        row.update(reward=result.reward, features=result.features, exact="",
                   decision_ms_mean=float(ms.mean()), decision_ms_max=float(ms.max()), wall_s=elapsed,
                   deployed=encode(result.deployed))
    if sweep.columns is not None:
        row.update(sweep.columns(task, extra, result))
    return row


def encode_released(released: np.ndarray) -> str:
    """Passenger index of each deployment in stage order (carriers separated by ``|``)."""
    return "|".join(" ".join(str(int(i)) for i in row if i >= 0) for row in np.asarray(released))


def encode(deployed: np.ndarray) -> str:
    """Deployments as ``stage stage|stage ...`` (carriers separated by ``|``), for the CSV."""
    return "|".join(" ".join(str(j) for j in np.flatnonzero(row)) for row in np.asarray(deployed))


def decode(text: str, n_carriers: int, n_stages: int) -> np.ndarray:
    """Inverse of :func:`encode`: bool ``[R, N]``."""
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
    from planner.registry import is_planner, make_planner, planner_names

    inst = random_instance(np.random.default_rng(0), 2, 1, 3, 1, 3.0)
    for name in planner_names() if names is None else [n for n in names if is_planner(n)]:
        planner = make_planner(name, iterations=16)
        warm = getattr(planner, "warm_up", None)
        if callable(warm):
            warm(inst.problem)
