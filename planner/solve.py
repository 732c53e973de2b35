"""Run one planner online over one instance file: what ``python -m planner.cli.solve`` prints.

Pure: reads the instance file, runs :func:`planner.online.run_online` and the clairvoyant bound,
returns a JSON-ready dict. The command line (argparse, exit codes) is in :mod:`planner.cli.solve`.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from planner.instance import InstanceError, load_instance_counts
from planner.online import run_online


def solve_instance(path: str | Path, planner, planner_name: str, seed: int, clairvoyant: bool = True,
                   online_optimum: bool = True, comms=None, upper_bound: bool = True) -> dict:
    """Load the instance at ``path``, run ``planner`` online with root seed ``seed``, evaluate.

    Returns:
        ``{"planner", "seed", "deployments" [[stage, ...] per carrier], "reward", "features",
        "decision_ms" [ms per stage], "observations" [[x or None]], "observations_sampled",
        "clairvoyant" {"reward", "features", "exact"} (with ``clairvoyant``),
        "online_optimum" {"expected_reward", "exact", "atoms"[, "planner_expected_reward"]} (with
        ``online_optimum``, when ``planner`` is ``online-optimal`` or the instance is within
        :func:`planner.online_optimal.auto_admit`),
        "upper_bound" {"expected_reward", "stderr", "method", "samples"} (with ``upper_bound``, when
        it fits :data:`planner.duality.DEFAULT_BUDGET_S`; :func:`planner.duality.seeded_bound`),
        "comms" {"loss", "delay", "groups"} (only with ``comms``), "released" [[passenger index per
        deployment, in stage order] per carrier] (only for an instance with ``passenger_values``)}``.
        A ``reward: coverage`` instance reports its own bounds (:func:`_coverage_bounds`), each
        with the planner's ``fraction`` of it.

    ``comms``: a :class:`planner.comms.CommsSpec`; None (the default) runs
    :func:`planner.online.run_online` exactly as before, otherwise
    :func:`planner.decentralised.run_comms` under that communication model.

    Raises:
        planner.instance.InstanceError: a bad instance file (one line).
        planner.online_optimal.TooLarge: ``planner`` is ``online-optimal`` and the instance is
            beyond its limits (one line).
    """
    (problem, x), counts, sampled = load_instance_counts(path, seed=seed)
    if comms is None:
        result = run_online(problem, x, planner, seed, counts, getattr(planner, "plan_ms", None))
    else:
        from planner.decentralised import run_comms

        try:
            comms.check(problem.n_carriers)
        except ValueError:
            raise InstanceError(str(path), "--groups", f"carrier indices 0..{problem.n_carriers - 1}",
                                repr([list(g) for g in comms.groups])) from None
        result = run_comms(problem, x, planner, seed, comms, counts)
    out = {
        "planner": planner_name,
        "seed": seed,
        "deployments": [np.flatnonzero(row).tolist() for row in result.deployed],
        "reward": result.reward,
        "features": result.features,
        "decision_ms": [round(t, 3) for t in result.decision_ms],
        "observations": [[None if np.isnan(v) else float(v) for v in row] for row in x],
        "observations_sampled": sampled,
    }
    if problem.weights is not None:
        # Passenger types: the passenger index of each deployment, in stage order.
        out["released"] = [[int(result.released[r, j]) for j in np.flatnonzero(row)]
                           for r, row in enumerate(result.deployed)]
    if comms is not None:
        out["comms"] = {"loss": comms.loss, "delay": comms.delay, "groups": [list(g) for g in comms.groups]}
    if problem.coverage is not None:
        out.update(_coverage_bounds(problem, x, counts, result.reward, seed, clairvoyant, online_optimum,
                                    upper_bound))
        return out
    if clairvoyant:
        from planner import clairvoyant as bound_mod  # numba: loaded only when needed

        bound = bound_mod.solve(problem, x)
        out["clairvoyant"] = {"reward": bound.reward, "features": bound.features, "exact": bound.exact}
    # The exact online recursion knows no passenger values: no V* for a weighted instance.
    if online_optimum and problem.weights is None:
        # A planner that learns its prior is no longer the policy the exact recursion weighs.
        optimum = _online_optimum(problem, "" if getattr(planner, "learn_prior", False) else planner_name)
        if optimum is not None:
            out["online_optimum"] = optimum
    if upper_bound and problem.weights is None:
        bound = _upper_bound(problem, seed)
        if bound is not None:
            out["upper_bound"] = bound
    return out


def _fraction(reward: float, bound: float) -> float | None:
    """The planner's reward as a fraction of a bound (None when the bound is 0)."""
    return reward / bound if bound > 0 else None


def _coverage_bounds(problem, x, counts, reward: float, seed: int, clairvoyant: bool, online_optimum: bool,
                     upper_bound: bool) -> dict:
    """The bounds of a coverage instance (:mod:`planner.coverage_bounds`), each with the planner's
    ``fraction`` of it: ``clairvoyant`` {"reward", "features", "exact", "method"[, "gap"]} (the
    realised counts; exact by integer programming within its size, else a bound with its gap),
    ``upper_bound`` (the information-relaxation bound on the expected reward, when it fits
    :data:`planner.duality.DEFAULT_BUDGET_S`; its fraction is this one realisation's reward over
    an expectation) and ``online_optimum`` {"expected_reward", "exact", "truncation_error"} (V* of
    the counts' truncated supports on tiny instances, within
    :data:`planner.coverage_optimal.AUTO_NODES`: :func:`planner.coverage_optimal.online_value`;
    ``exact`` when nothing was truncated)."""
    out: dict = {}
    if clairvoyant:
        from planner import coverage_bounds

        bound = coverage_bounds.solve(problem, x, counts)
        out["clairvoyant"] = {"reward": bound.reward, "features": bound.features, "exact": bound.exact,
                              "method": bound.method}
        if not bound.exact:
            out["clairvoyant"]["gap"] = bound.gap
        out["clairvoyant"]["fraction"] = _fraction(reward, bound.reward)
    if upper_bound and problem.weights is None:
        from planner import coverage_bounds, duality

        try:
            bound = coverage_bounds.seeded_bound(problem, seed)
        except duality.BoundTooLarge:
            bound = None
        if bound is not None:
            out["upper_bound"] = {"expected_reward": bound.expected_reward, "stderr": bound.stderr,
                                  "method": bound.method, "samples": bound.samples,
                                  "fraction": _fraction(reward, bound.expected_reward)}
    if online_optimum:
        from planner import coverage_optimal

        try:
            best = coverage_optimal.online_value(problem, coverage_optimal.AUTO_TAIL, coverage_optimal.AUTO_NODES)
        except coverage_optimal.TooLarge:
            best = None
        if best is not None:
            out["online_optimum"] = {"expected_reward": best.expected_reward, "exact": best.truncation_error == 0,
                                     "truncation_error": best.truncation_error,
                                     "fraction": _fraction(reward, best.expected_reward)}
    return out


def _upper_bound(problem, seed: int) -> dict | None:
    """The information-relaxation bound (:func:`planner.duality.seeded_bound`), or None when it
    would not fit :data:`planner.duality.DEFAULT_BUDGET_S` (decided from the sizes, quickly)."""
    from planner import duality

    try:
        bound = duality.seeded_bound(problem, seed)
    except duality.BoundTooLarge:
        return None
    return {"expected_reward": bound.expected_reward, "stderr": bound.stderr, "method": bound.method,
            "samples": bound.samples, "strength": bound.strength, "adaptive": bound.adaptive}


def _online_optimum(problem, planner_name: str) -> dict | None:
    """V* (and the planner's own exact value when the recursion can weigh its actions), or None
    when the instance is beyond the automatic limit (:func:`planner.online_optimal.auto_admit`:
    O(R·N·D²), at the rates the solver counts; the admitted solve runs under the solver's own
    budget). After ``online-optimal`` ran, its V* is read from the solver's memo: no second solve,
    and no admission to refuse what the planner solved."""
    from planner import online_optimal

    best = online_optimal.known_value(problem) if planner_name == "online-optimal" else None
    try:
        if best is None:
            online_optimal.auto_admit(problem)
            best = online_optimal.online_value(problem, "optimal")
    except online_optimal.TooLarge:
        return None
    out = {"expected_reward": best.expected_reward, "exact": best.exact, "atoms": best.atoms}
    if planner_name == "online-optimal":
        out["planner_expected_reward"] = best.expected_reward
    elif planner_name in ("ssap", "random"):
        try:
            own = online_optimal.online_value(problem, planner_name)
        except online_optimal.TooLarge:
            return out
        out["planner_expected_reward"] = own.expected_reward
    return out
