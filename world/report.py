"""The prior against the world: observed counts over many seeds next to the prior's moments."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

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
