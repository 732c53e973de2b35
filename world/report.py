"""What ``python -m world check`` reports beyond validation: the prior against the world
(observed counts over many seeds next to the prior's moments) and the links."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from planner import links as ch
from world.links import LinkModel
from world.relays import fleet_relays, route_to_base
from world.scenario import Scenario
from world.sim import simulate_mission


@dataclass(frozen=True)
class PriorReport:
    """Moments of a valid stage's feature count x.

    Attributes:
        seeds: number of seeds simulated (root seeds ``first_seed .. first_seed + seeds - 1``).
        samples: number of observed counts pooled (valid stages × seeds).
        prior_mean, prior_var, prior_q90: the scenario prior's mean, variance, 90th percentile.
        mean, var, q90: the same for the pooled observed counts (q90 as the prior's ppf: the smallest
            observed value with empirical CDF >= 0.9).
        per_carrier_mean: observed mean per carrier, ``[R]`` as a tuple.
    """

    seeds: int
    samples: int
    prior_mean: float
    prior_var: float
    prior_q90: float
    mean: float
    var: float
    q90: float
    per_carrier_mean: tuple[float, ...]


def prior_report(scenario, seeds: int = 200, first_seed: int = 0) -> PriorReport:
    """Simulate ``seeds`` feature draws (the physics is computed once) and pool the observed
    counts at every valid stage."""
    xs = np.stack([simulate_mission(scenario, seed=first_seed + s).x for s in range(seeds)])  # [S, R, N]
    pooled = xs[~np.isnan(xs)]
    prior = scenario.prior_distribution()
    with np.errstate(invalid="ignore"):
        per_carrier = tuple(float(v) for v in np.nanmean(xs.transpose(1, 0, 2).reshape(scenario.n_carriers, -1), axis=1))
    return PriorReport(
        seeds=seeds, samples=int(pooled.size),
        prior_mean=float(prior.mean()), prior_var=float(prior.var()), prior_q90=float(prior.ppf(0.9)),
        mean=float(pooled.mean()) if pooled.size else float("nan"),
        var=float(pooled.var(ddof=1)) if pooled.size > 1 else float("nan"),
        q90=float(np.quantile(pooled, 0.9, method="inverted_cdf")) if pooled.size else float("nan"),
        per_carrier_mean=per_carrier,
    )


def describe_links(scenario: Scenario) -> list[str]:
    """The lines ``python -m world check`` prints about the links: the model and its parameters,
    its range in the open, the relays dropped and how many decision points reach the base."""
    spec = scenario.links
    if spec.model == "perfect":
        return ["links: perfect (every message arrives at once)"]
    model = LinkModel(scenario)
    params = ", ".join(f"{k} {v:g}" for k, v in spec.params)
    lines = [f"links: {spec.model} ({params}); base {list(model.base)}; "
             f"range in the open {ch.open_range_m(spec):.0f} m (margin 0)"]
    if spec.model == "acoustic":
        lines.append(f"  a full frame ({spec.frame_bytes} bytes) occupies the channel "
                     f"{ch.airtime_s(spec, spec.frame_bytes):.3g} s; sound crosses the map's diagonal in "
                     f"{math.hypot(*np.subtract(scenario.map.bounds[2:], scenario.map.bounds[:2])) / spec.sound_speed_mps:.3g} s")
    relays = fleet_relays(model)
    if spec.relays.total:
        per = ", ".join(f"{cid} {sum(r.carrier == cid for r in relays)}/{n}" for cid, n in spec.relays.counts)
        lines.append(f"  relays dropped (of carried): {per}; drop below {spec.relays.drop_margin_db:g} dB margin")
    valid = scenario.valid()
    reach = total = 0
    for r, c in enumerate(scenario.carriers):
        for j in np.flatnonzero(valid[r]):
            t = float(scenario.stage_time(int(j)))
            total += 1
            reach += route_to_base(model, relays, c.position_at(t), t)[1] >= 0.9
    lines.append(f"  decision points reaching the base with probability >= 0.9 (planned positions): {reach} of {total}")
    return lines
