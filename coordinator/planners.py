"""Online planners by name: ``random``, ``ssap``, ``mcts-random``, ``mcts-ssap`` and later additions.

Every planner follows :class:`coordinator.problem.Planner`: ``decide(view, rng) -> bool[R]`` reads
only the causal :class:`~coordinator.problem.StageView` of the current stage and the stage's random
stream, and keeps no state across stages (a recovered coordinator continues exactly).
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from coordinator import ssap
from coordinator.problem import Problem, StageView


class RandomPlanner:
    """Each carrier deploys at D uniformly random valid stages.

    Stateless form: a carrier with ``d`` passengers left and ``n`` valid stages left (this one
    included) deploys now with probability ``d / n``. Over a schedule without surprises this picks
    ``min(D, valid stages)`` stages uniformly at random among all such subsets. ``d >= n`` gives
    probability 1, which is exactly the forced deployment rule.
    """

    name = "random"

    def decide(self, view: StageView, rng: np.random.Generator) -> np.ndarray:
        d = view.passengers_left
        n = view.stages_left
        # One uniform per carrier, always drawn, so carrier r's draw does not depend on the others.
        u = rng.random(view.problem.n_carriers)
        prob = np.divide(d, n, out=np.zeros(len(d)), where=n > 0)
        return view.can_deploy & (u < prob)


class SSAPPlanner:
    """Single-robot SSAP: each carrier applies its own DLR thresholds and ignores conflicts.

    Deterministic (the random stream is unused): carrier r deploys iff its observation exceeds
    ``a[n, n - d]`` for its ``n`` valid stages left and ``d`` passengers left, or it must deploy.
    """

    name = "ssap"

    def warm_up(self, problem: Problem) -> None:
        """Compute (and cache) the threshold table before the first timed decision."""
        ssap.table_for(problem)

    def decide(self, view: StageView, rng: np.random.Generator) -> np.ndarray:
        table = ssap.table_for(view.problem)
        x = view.observations[:, view.stage]
        d = view.passengers_left
        n = view.stages_left
        can = view.can_deploy
        out = np.zeros(view.problem.n_carriers, dtype=bool)
        for r in np.flatnonzero(can):
            out[r] = ssap.decide(table, float(x[r]), int(n[r]), int(d[r]))
        return out


# ----------------------------------------------------------------------------- registry

#: name -> factory(**options) -> Planner. Options not used by a planner are ignored by it.
_REGISTRY: dict[str, Callable[..., object]] = {}

#: The options :func:`make_planner` understands (others raise ValueError).
OPTIONS = ("iterations", "plan_ms", "exploration", "samples")


def register(name: str, factory: Callable[..., object]) -> None:
    """Make ``make_planner(name, **options)`` return ``factory(**options)``.

    ``factory`` receives only the options the caller gave (not None). Re-registering a name
    replaces it.
    """
    if not isinstance(name, str) or not name:
        raise ValueError(f"planner name must be a non-empty string, got {name!r}")
    _REGISTRY[name] = factory


def planner_names() -> tuple[str, ...]:
    """Registered planner names, sorted."""
    return tuple(sorted(_REGISTRY))


def make_planner(name: str, **options) -> object:
    """Build a planner by name.

    Args:
        name: one of :func:`planner_names` (``random``, ``ssap``, ``mcts-random``, ``mcts-ssap``
            and any planner added with :func:`register`).
        **options: ``iterations`` (MCTS iterations per stage), ``plan_ms`` (MCTS time budget per
            stage, milliseconds), ``exploration`` (UCT constant c), ``samples`` (Monte Carlo
            samples per rollout). ``None`` values are dropped; ``random`` and ``ssap`` ignore them.

    Raises:
        ValueError: unknown name (the message lists the valid names) or unknown option.
    """
    factory = _REGISTRY.get(name)
    if factory is None:
        raise ValueError(f"unknown planner {name!r}; expected one of: {', '.join(planner_names())}")
    unknown = sorted(set(options) - set(OPTIONS))
    if unknown:
        raise ValueError(f"unknown planner option(s) {unknown}; expected some of: {', '.join(OPTIONS)}")
    return factory(**{k: v for k, v in options.items() if v is not None})


def _mcts_factory(rollout: str) -> Callable[..., object]:
    def factory(**options):
        # Imported lazily: the MCTS module may compile numba code on import.
        from coordinator.mcts import MCTSPlanner

        return MCTSPlanner(rollout=rollout, **options)

    return factory


register("random", lambda **_: RandomPlanner())
register("ssap", lambda **_: SSAPPlanner())
register("mcts-random", _mcts_factory("random"))
register("mcts-ssap", _mcts_factory("ssap"))


def _closed_loop_factory(**options):
    # Imported lazily (numba kernels); see coordinator/closedloop.py and docs/results.md.
    from coordinator.closedloop import ClosedLoopPlanner

    return ClosedLoopPlanner(**options)


register("closed-loop", _closed_loop_factory)
