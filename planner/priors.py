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


class Poisson:
    """The Poisson prior of mean ``mu``: what the frozen ``scipy.stats.poisson(mu)`` gives, to the
    bit, for what the planner and the fleet ask of a prior (``pmf``, ``cdf``, ``sf``, ``ppf``,
    ``support``, ``mean``, ``var``, ``std``, and ``rvs`` drawn from a numpy Generator or
    RandomState), by scipy's own formulas over ``scipy.special``, without importing
    ``scipy.stats``. That import is 1-2 s of CPU, and every fleet process (each carrier's
    on-board planner, the coordinator, the report) builds the problem's prior, Poisson by default
    (a scenario's derived prior). Whatever else is asked (``expect``, ``interval``, ...) comes
    from ``scipy.stats.poisson(mu)``, built on first use. tests/test_priors.py holds the two
    equal."""

    def __init__(self, mu):
        self.args, self.kwds, self.dist = (mu,), {}, POISSON_FAMILY
        self.mu = mu

    def __reduce__(self):
        return Poisson, self.args

    def __repr__(self) -> str:
        return f"Poisson({self.mu!r})"

    def __getattr__(self, name: str):
        if name.startswith("_"):
            raise AttributeError(name)
        return getattr(self._frozen(), name)

    def _frozen(self):
        """``scipy.stats.poisson(mu)``, built once."""
        if "_scipy" not in self.__dict__:
            self.__dict__["_scipy"] = _stats().poisson(*self.args)
        return self.__dict__["_scipy"]

    @staticmethod
    def _out(output: np.ndarray):
        return output[()] if output.ndim == 0 else output

    def pmf(self, k):
        from scipy import special

        k = np.asarray(k)
        cond = (k >= 0) & (k <= np.inf) & (np.floor(k) == k)
        output = np.zeros(np.shape(cond), "d")
        np.place(output, np.isnan(k), np.nan)
        if np.any(cond):
            good = np.extract(cond, k)
            np.place(output, cond, np.clip(np.exp(special.xlogy(good, self.mu) - special.gammaln(good + 1) - self.mu),
                                           0, 1))
        return self._out(output)

    def _tail(self, k, upper: bool):
        from scipy import special

        k = np.asarray(k)
        cond = (k >= 0) & (k < np.inf) & np.isfinite(k)
        output = np.zeros(np.shape(cond), "d")
        if upper:
            np.place(output, np.isnan(k), np.nan)
            np.place(output, (k < 0) | np.isneginf(k), 1.0)
        else:
            np.place(output, k >= np.inf, 1.0)
            np.place(output, np.isneginf(k), 0.0)
            np.place(output, np.isnan(k), np.nan)
        if np.any(cond):
            good = np.floor(np.extract(cond, k))
            np.place(output, cond, np.clip((special.pdtrc if upper else special.pdtr)(good, self.mu), 0, 1))
        return self._out(output)

    def cdf(self, k):
        return self._tail(k, upper=False)

    def sf(self, k):
        return self._tail(k, upper=True)

    def ppf(self, q):
        from scipy import special

        q = np.asarray(q)
        cond = (q > 0) & (q < 1)
        output = np.full(np.shape(cond), fill_value=np.nan, dtype="d")
        np.place(output, q == 0, -1)
        np.place(output, q == 1, np.inf)
        if np.any(cond):
            good = np.extract(cond, q)
            vals = np.ceil(special.pdtrik(good, self.mu))
            vals1 = np.maximum(vals - 1, 0)
            np.place(output, cond, np.where(special.pdtr(vals1, self.mu) >= good, vals1, vals) + 0)
        return self._out(output)

    def support(self):
        return np.int64(0), np.float64(np.inf)

    def mean(self):
        return np.float64(self.mu)

    def var(self):
        return np.float64(self.mu)

    def std(self):
        return np.sqrt(self.var())

    def rvs(self, size=None, random_state=None):
        if not isinstance(random_state, (np.random.Generator, np.random.RandomState)):
            return self._frozen().rvs(size=size, random_state=random_state)
        shape = () if size is None else tuple(size) if np.iterable(size) else (int(size),)
        vals = random_state.poisson(np.asarray(self.mu), shape) * 1 + 0
        return int(vals) if shape == () else vals.astype(np.int64)


class _PoissonFamily:
    """What :class:`Poisson`'s ``dist`` says of its family (the checks read ``name`` and
    whether it has a ``pmf``)."""

    name = "poisson"

    @staticmethod
    def pmf(k, mu):
        return Poisson(mu).pmf(k)


POISSON_FAMILY = _PoissonFamily()


#: kind -> ({parameter: (check, "expected ..." text)}, builder(spec) -> frozen distribution).
PRIOR_KINDS: dict[str, tuple[dict[str, tuple[Callable[[Any], bool], str]], Callable[[dict], Any]]] = {
    "poisson": ({"mean": (is_positive, "a number > 0")}, lambda p: Poisson(p["mean"])),
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
    prior = Poisson(mean)
    points = np.arange(0.0, prior.ppf(1.0 - tail) + 1.0)
    mass = prior.pmf(points)
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
