"""Prior kinds f(x) shared by the planner's instance files and the world's scenario files.

One table, so a prior reads the same in a JSON instance and in a YAML scenario. Pure scipy:
both the planner core and world/ import it (it imports neither). :func:`support` gives a
discrete prior's support points and masses, the one enumeration read by the thresholds
(:mod:`planner.ssap`) and the sampler (:mod:`planner.compiled`). Every kind and parameter is
documented in docs/planner.md.

A spec is a mapping ``{"kind": KIND, PARAM: VALUE, ...}``. :func:`prior_problems` lists what is
wrong with one (empty when it is fine); :func:`build_prior` turns a checked spec into a frozen
``scipy.stats`` distribution.
"""
from __future__ import annotations

import functools
import math
from typing import Any, Callable

import numpy as np

from validation import MISSING, Found, Flaw


def _stats():
    import scipy.stats  # loaded on first use: a bad file is reported without the scipy import cost

    return scipy.stats


def is_number(v: Any) -> bool:
    """A finite int or float (not a bool)."""
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def is_integer(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def is_positive(v: Any) -> bool:
    return is_number(v) and v > 0


def is_probability(v: Any) -> bool:
    return is_number(v) and 0 < v <= 1


def is_numbers(v: Any) -> bool:
    return isinstance(v, list) and len(v) > 0 and all(is_number(e) for e in v)


def _table(p: dict) -> Any:
    return _stats().rv_discrete(values=(np.asarray(p["values"], float), np.asarray(p["probabilities"], float)))()


#: kind -> ({parameter: (check, "expected ..." text)}, builder(spec) -> frozen distribution).
PRIOR_KINDS: dict[str, tuple[dict[str, tuple[Callable[[Any], bool], str]], Callable[[dict], Any]]] = {
    "poisson": ({"mean": (is_positive, "a number > 0")}, lambda p: _stats().poisson(p["mean"])),
    "binomial": ({"n": (lambda v: is_integer(v) and v >= 1, "an integer >= 1"), "p": (is_probability, "a number in (0, 1]")},
                 lambda p: _stats().binom(p["n"], p["p"])),
    # failures before the first success: support 0, 1, 2, ...
    "geometric": ({"p": (is_probability, "a number in (0, 1]")}, lambda p: _stats().geom(p["p"], loc=-1)),
    "negative_binomial": ({"n": (is_positive, "a number > 0"), "p": (is_probability, "a number in (0, 1]")},
                          lambda p: _stats().nbinom(p["n"], p["p"])),
    # integers low..high inclusive
    "discrete_uniform": ({"low": (is_integer, "an integer"), "high": (is_integer, "an integer")},
                         lambda p: _stats().randint(p["low"], p["high"] + 1)),
    "table": ({"values": (is_numbers, "a non-empty list of numbers"),
               "probabilities": (lambda v: is_numbers(v) and all(e >= 0 for e in v), "a non-empty list of numbers >= 0")},
              _table),
    "gamma": ({"shape": (is_positive, "a number > 0"), "scale": (is_positive, "a number > 0")},
              lambda p: _stats().gamma(p["shape"], scale=p["scale"])),
    "exponential": ({"mean": (is_positive, "a number > 0")}, lambda p: _stats().expon(scale=p["mean"])),
    # log X ~ Normal(mu, sigma)
    "lognormal": ({"mu": (is_number, "a number"), "sigma": (is_positive, "a number > 0")},
                  lambda p: _stats().lognorm(p["sigma"], scale=math.exp(p["mu"]))),
    "normal": ({"mean": (is_number, "a number"), "std": (is_positive, "a number > 0")},
               lambda p: _stats().norm(p["mean"], p["std"])),
    "uniform": ({"low": (is_number, "a number"), "high": (is_number, "a number")},
                lambda p: _stats().uniform(p["low"], p["high"] - p["low"])),
}




def prior_problems(spec: dict, unknown: bool = True) -> list[Flaw]:
    """Everything wrong with the prior spec ``spec`` (a mapping with a ``kind``); empty if fine.

    An unknown kind is reported alone; otherwise missing, malformed and (with ``unknown``) unknown
    parameters are all reported, then the cross-parameter rules (ranges, table lengths and sums).
    """
    kind = spec.get("kind", MISSING)
    if not isinstance(kind, str) or kind not in PRIOR_KINDS:
        return [Flaw("kind", f"one of {', '.join(PRIOR_KINDS)}", kind)]
    params, _ = PRIOR_KINDS[kind]
    problems = []
    for name, (check, expected) in params.items():
        if name not in spec:
            problems.append(Flaw(name, f"{expected} ({kind} prior)", MISSING))
        elif not check(spec[name]):
            problems.append(Flaw(name, expected, spec[name]))
    for name in spec if unknown else ():
        if name != "kind" and name not in params:
            problems.append(Flaw(name, f"only {', '.join(['kind', *params])} for a {kind} prior",
                                    Found("an unknown parameter")))
    if problems:
        return problems
    if kind == "discrete_uniform" and spec["high"] < spec["low"]:
        problems.append(Flaw("high", f"an integer >= low ({spec['low']})", spec["high"]))
    if kind == "uniform" and spec["high"] <= spec["low"]:
        problems.append(Flaw("high", f"a number > low ({spec['low']})", spec["high"]))
    if kind == "table":
        values, probs = spec["values"], spec["probabilities"]
        if len(probs) != len(values):
            problems.append(Flaw("probabilities", f"{len(values)} entries (one per value)", Found(str(len(probs)))))
        elif abs(sum(probs) - 1.0) > 1e-9:
            problems.append(Flaw("probabilities", "probabilities summing to 1", Found(f"sum {sum(probs):g}")))
        if len(set(values)) != len(values):
            problems.append(Flaw("values", "distinct values", values))
    return problems


def build_prior(spec: dict) -> Any:
    """The frozen ``scipy.stats`` distribution of a spec for which :func:`prior_problems` is empty."""
    _, build = PRIOR_KINDS[spec["kind"]]
    return build(spec)


#: Tail mass ignored when enumerating an unbounded discrete support.
TAIL = 1e-15


@functools.lru_cache(maxsize=16384)  # a few MB: the ~6,000 distinct sums of a 256-carrier grid fit
def poisson_support(mean: float, tail: float = TAIL) -> tuple[np.ndarray, np.ndarray]:
    """:func:`support` of a Poisson prior of ``mean``, the same numbers without freezing a
    distribution (a frozen scipy.stats distribution builds its docstrings: ~6 ms each, most of a
    coverage planner's warm-up over thousands of regions); cached, read-only arrays."""
    stats = _stats()
    points = np.arange(0.0, stats.poisson.ppf(1.0 - tail, mean) + 1.0)
    mass = stats.poisson.pmf(points, mean)
    points.setflags(write=False)
    mass.setflags(write=False)
    return points, mass


def is_discrete(prior) -> bool:
    """Whether a frozen scipy.stats distribution is discrete (has a pmf)."""
    return hasattr(prior.dist, "pmf")


def support(prior, tail: float = TAIL) -> tuple[np.ndarray, np.ndarray]:
    """Support points float ``[K]`` (ascending) and their probabilities float ``[K]`` of a
    discrete prior.

    Unbounded supports are truncated where the tail mass is below ``tail`` (:data:`TAIL` by
    default; the masses then sum to slightly less than 1). Table priors (``scipy.stats.rv_discrete(values=...)``) give
    their own, possibly non-integer, points; other discrete priors live on the integers.
    """
    if hasattr(prior.dist, "xk"):
        # A table prior (scipy.stats.rv_discrete(values=(xk, pk))): arbitrary support points.
        kwds = prior.kwds
        loc, scale = kwds.get("loc", 0.0), kwds.get("scale", 1.0)
        points = np.asarray(prior.dist.xk, dtype=float) * scale + loc
        return points, np.asarray(prior.dist.pk, dtype=float)
    lo, hi = prior.support()
    if not np.isfinite(lo):
        lo = prior.ppf(tail)
    if not np.isfinite(hi):
        hi = prior.ppf(1.0 - tail)
    points = np.arange(lo, hi + 1, dtype=float)
    return points, prior.pmf(points)
