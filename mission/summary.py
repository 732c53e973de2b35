"""summary.json as a function of the mission state (docs/fleet.md, "Results directory").

:func:`summary` reads nothing but its arguments: the :class:`~mission.state.MissionState`, the
planner core's problem (for the penalty rule and the clairvoyant bound) and :class:`RunInfo`,
what the process knows about itself (ids, pid, host, wall time, its rejection counts).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from planner.problem import evaluate, fill_releases, point_weights, rewards

from .coverage import revealed_counts, summary_fields
from .operator_rules import summary_block
from .state import MissionState

#: About how long (s) the summary's clairvoyant bound may search, turned into a node limit
#: (planner.clairvoyant.node_limit) so that the bound does not depend on the host; a small
#: fleet's search finishes well within it, a large one's rarely finishes at all.
BOUND_SEARCH_S = 1.0
#: The information-relaxation bound's budget (s), computed only where the clairvoyant bound is loose
UPPER_BOUND_S = 3.0


#: What summary.json's ``wall_time_s`` measures (written beside it).
WALL_TIME_MEANING = ("seconds from the coordinator's start to its summary: the mission as the coordinator saw it; "
                     "the one-host launcher's 'wall' also counts starting the processes, the carriers' exit and "
                     "the report")


@dataclass(frozen=True)
class RunInfo:
    """The coordinator process's own facts for summary.json.

    Attributes:
        scenario, scenario_file, mission, planner, planner_options, seed: identify the run.
        pid, host: the coordinator process.
        wall_time_s: seconds from the start of the run to the summary.
        rejected: the coordinator's rejection counts, reason -> n.
    """

    scenario: str
    scenario_file: str
    mission: str
    planner: str
    planner_options: dict
    seed: int
    pid: int | None = None
    host: str | None = None
    wall_time_s: float = 0.0
    rejected: dict = field(default_factory=dict)
    passenger_types: tuple = ()  # per carrier, its passengers' type names (passenger types)


def percentile(values, q) -> float | None:
    return float(np.percentile(values, q)) if len(values) else None


def clairvoyant_bound(problem, x: np.ndarray, total_reward: float, counts: np.ndarray | None = None,
                      max_nodes: int | None = None) -> dict:
    """The offline optimum for the realised observations (``{"error": ...}`` if it fails: the
    bound is a report, never a reason to lose the summary). Its search gets about
    :data:`BOUND_SEARCH_S` of work (:func:`planner.clairvoyant.node_limit`, or ``max_nodes``);
    past it the conflict-free upper bound stands, ``exact: false``. Under the coverage reward
    ``counts`` are the revealed region counts (every region a feasible deployment explores was
    revealed by that point's observation) and the bound is maximum coverage
    (:mod:`planner.coverage_bounds`: exact integer programme, or its relaxation with ``gap``
    beyond the documented size).

    ``fraction`` is the run's reward over the bound's; ``percent`` is the same in percent only
    when the bound is exact (the offline optimum itself), else None with ``loose`` saying why:
    a percentage of a loose bound makes every planner look broken."""
    from planner import clairvoyant

    try:
        limit = clairvoyant.node_limit(problem, BOUND_SEARCH_S) if max_nodes is None else int(max_nodes)
        bound = clairvoyant.solve(problem, np.where(problem.valid, x, np.nan), max_nodes=limit, counts=counts)
    except Exception as exc:
        return {"error": f"{type(exc).__name__}: {exc}"}
    fraction = (total_reward / bound.reward) if bound.reward > 0 else None
    out = {"reward": bound.reward, "features": bound.features, "exact": bool(bound.exact), "fraction": fraction,
           "percent": 100.0 * fraction if bound.exact and fraction is not None else None}
    if problem.coverage is not None:
        out.update(method=bound.method, gap=float(bound.gap))
    if not bound.exact:
        out["loose"] = (f"maximum coverage by its {bound.method} relaxation, up to {100 * float(bound.gap):.0f} % "
                        f"above the optimum" if problem.coverage is not None else
                        "the search for the offline optimum stopped at its node limit: this is the conflict-free "
                        "bound (every deployment valued as if it shared no overlap), loose where deployments overlap")
    return out


def online_upper_bound(problem, seed: int, total_reward: float, budget_s: float = UPPER_BOUND_S) -> dict:
    """The information-relaxation bound on the expected reward of every online planner
    (:func:`planner.duality.seeded_bound`, planned within ``budget_s`` from the instance's sizes,
    so it does not depend on the host; its pilot, which chooses the penalty's strength, is part of
    that budget): ``{expected_reward, stderr, method, samples, percent}``,
    ``percent`` = this run's reward over it (one run: its reward varies with what was observed),
    or ``{"error": ...}`` where it does not apply (passenger types, coverage) or does not fit."""
    from planner import duality

    if problem.coverage is not None:
        return {"error": "the information-relaxation bound is for the penalty reward"}
    try:
        ub = duality.seeded_bound(problem, int(seed), budget_s=budget_s)
    except Exception as exc:  # BoundTooLarge, passenger values: a report, never a lost summary
        return {"error": f"{type(exc).__name__}: {exc}"}
    return {"expected_reward": ub.expected_reward, "stderr": ub.stderr, "method": ub.method, "samples": ub.samples,
            "percent": 100.0 * total_reward / ub.expected_reward if ub.expected_reward > 0 else None}


def bound_text(summary: dict, short: bool = False) -> str:
    """How the console and map.png (``short``: without the reason) state the run against its
    bound: a percentage only against the exact offline optimum, or against the
    information-relaxation bound when the offline search stopped; otherwise the bound and why
    it is loose, with no percentage."""
    bound = summary.get("clairvoyant") or {}
    if not bound or "error" in bound:
        return "clairvoyant bound not computed" + (f" ({bound['error']})" if bound.get("error") else "")
    if bound.get("exact"):
        pct = bound.get("percent", (bound.get("fraction") or 0) * 100)
        return f"clairvoyant optimum {bound['reward']:.3f}" + ("" if pct is None else f" ({pct:.0f}%)")
    why = "" if short else f": {bound.get('loose', 'not exact')}"
    text = f"clairvoyant bound {bound['reward']:.3f} (loose, no percentage{why})"
    upper = summary.get("upper_bound") or {}
    if upper.get("percent") is not None:
        text += (f"; online bound {upper['expected_reward']:.3f}, this run {upper['percent']:.0f}%" if short else
                 f"; any online planner expects at most {upper['expected_reward']:.3f} ± {upper['stderr']:.3f} "
                 f"(information-relaxation bound): this run {upper['percent']:.0f}%")
    return text


def summary(state: MissionState, problem, run: RunInfo, bound: bool = True) -> dict:
    """The summary.json dict of a mission in ``state``.

    ``bound=False`` leaves ``"clairvoyant"`` as None (the bound can take seconds when its
    kernels are not compiled yet; a stopping coordinator writes the summary without it first).
    """
    spec = state.spec
    x = state.observations()
    actual = state.confirmed_deployments()
    typed = problem.weights is not None
    released = fill_releases(problem.passengers, actual, state.releases()) if typed else None
    raw = rewards(problem, actual, np.nan_to_num(x) * point_weights(problem, released) if typed else x)
    if problem.coverage is not None:  # the features in the union of the discs, each region once
        revealed = revealed_counts(state, problem.coverage)
        cov = summary_fields(problem, actual, released, x, revealed)
        total_reward, total_features = cov["total_reward"], cov["covered_features"]
    else:
        total_reward, total_features = evaluate(problem, actual, x, released)
    decided = state.decided()
    carriers = []
    for r, cid in enumerate(spec.carriers):
        deps = []
        for j in np.flatnonzero(actual[r]):
            deps.append({"stage": int(j), "t": spec.stage_times[int(j)],
                         "x": None if math.isnan(x[r, j]) else float(x[r, j]),
                         "position": list(state.deployment_position(cid, int(j))),
                         "by": _by(state, cid, int(j)),
                         "reward": float(raw[r, j] / problem.scale), "features": float(raw[r, j]),
                         "features_over_p": float(raw[r, j])})
            if typed:  # passenger types: which passenger (index, type name, value) went here
                i = int(released[r, j])
                names = run.passenger_types[r] if r < len(run.passenger_types) else ()
                deps[-1].update(passenger=i, type=names[i] if 0 <= i < len(names) else "",
                                value=float(problem.weights[r, i]) if i >= 0 else None)
        info = state.accepted.get(cid)
        carriers.append({
            "id": cid, "pid": info.pid if info else None, "host": info.host if info else None,
            "passengers": spec.passengers[r], "deployments": deps,
            "decided_stages": [int(j) for j in np.flatnonzero(decided[r])],
            "own_stages": state.own_stages(cid),
            "missing_stages": state.missing_stages(cid),
            "live_at_end": cid in state.live,
            "rejected": dict(state.carrier_rejected.get(cid, {})),
        })
    plan = [state.decisions[j].planning_ms for j in sorted(state.decisions)]
    clair = clairvoyant_bound(problem, x, float(total_reward), None if problem.coverage is None
                              else np.nan_to_num(revealed)) if bound else None
    # where the offline optimum is only bounded loosely, the bound on every online planner
    upper = online_upper_bound(problem, run.seed, float(total_reward)) \
        if clair is not None and clair.get("exact") is False else None
    latencies = state.latencies_ms()
    operator = summary_block(state)
    return {
        "scenario": run.scenario, "scenario_file": run.scenario_file, "mission": run.mission,
        "planner": run.planner, "planner_options": run.planner_options, "seed": run.seed,
        "stages": spec.n_stages, "stages_decided": len(state.decisions), "ended": state.ended,
        "end_reason": state.end_reason,
        "resumed": state.resumed,
        "coordinator": {"pid": run.pid, "host": run.host},
        "carriers": carriers,
        "decisions": [list(state.decisions[j].deploy) if j in state.decisions else None
                      for j in range(spec.n_stages)],
        "observations": [[None if math.isnan(v) else float(v) for v in row] for row in x],
        "total_reward": float(total_reward), "total_features": float(total_features),
        "reward": problem.reward,
        **({} if problem.coverage is None else {"coverage": cov}),
        "clairvoyant": clair,
        **({} if upper is None else {"upper_bound": upper}),
        "wall_time_s": float(run.wall_time_s),
        "wall_time_meaning": WALL_TIME_MEANING,
        "latency_ms": {"p50": percentile(latencies, 50), "p99": percentile(latencies, 99),
                       "count": len(latencies),
                       "meaning": "decision publication to carrier confirmation, coordinator clock"},
        "planning_ms": {"per_stage": plan, "mean": float(np.mean(plan)) if plan else None,
                        "max": float(np.max(plan)) if plan else None},
        "rejected": {"coordinator": dict(run.rejected),
                     "carriers": {cid: dict(state.carrier_rejected.get(cid, {})) for cid in spec.carriers}},
        **({} if operator is None else {"operator": operator}),
    }


def _by(state: MissionState, cid: str, j: int) -> str:
    """Who decided carrier ``cid``'s deployment at stage j: ``carrier`` (its own account),
    ``operator`` (forced at the console), else ``coordinator``."""
    if (cid, j) in state.accounts:
        return "carrier"
    d = state.decisions.get(j)
    return "operator" if d is not None and cid in d.forced else "coordinator"
