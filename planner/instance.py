"""Problem instances as JSON files, prior specifications, and random paper-style instances.

The JSON format is documented field by field in ``docs/planner.md``. Loading validates everything
and raises :class:`InstanceError` whose message is one line: ``FILE: field.path: expected ...,
found ...``.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Callable, NamedTuple

import numpy as np

import validation
from planner import priors
from planner.priors import is_integer as _int, is_number as _num, is_positive as _positive
from planner.problem import Problem, normalisation_scale, sample_observations

#: Spawn key of the observation stream when an instance file omits its observations.
OBSERVATION_SPAWN_KEY = (2000, 0)

#: Default prior when an instance omits one.
DEFAULT_PRIOR = {"kind": "poisson", "mean": 3.0}

#: Top-level fields of an instance file.
FIELDS = ("name", "comment", "carriers", "passengers", "stages", "prior", "normalize", "overlaps",
          "valid", "observations", "passenger_values")


class Instance(NamedTuple):
    """A problem and its realised observations ``x[R, N]`` (float, NaN = ∅)."""

    problem: Problem
    observations: np.ndarray


class InstanceError(ValueError):
    """A bad instance. ``str(err)`` is one line: ``source: field: expected ..., found ...``."""

    def __init__(self, source: str, field: str, expected: str, found: str):
        """``found``: the offending value already shown (:func:`_show`) or a description."""
        self.source, self.field, self.expected, self.found = source, field, expected, found
        self.problem = validation.Problem(field, expected, validation.Found(found))
        super().__init__(self.problem.line(source))

    @classmethod
    def of(cls, source: str, problem: validation.Problem) -> InstanceError:
        """The error of a :class:`validation.Problem` (its found value shown as JSON)."""
        return cls(source, problem.field, problem.expected, validation.show(problem.found, "json"))


# ----------------------------------------------------------------------------- priors

#: The prior kinds an instance may name (the table is shared with scenario files).
PRIOR_KINDS = priors.PRIOR_KINDS


def make_prior(spec: Any, source: str = "<prior>", field: str = "prior") -> object:
    """A frozen scipy.stats distribution from a prior specification ``{"kind": ..., params}``.

    Raises:
        InstanceError: unknown kind, missing/unknown/bad parameter (the first problem found).
    """
    if not isinstance(spec, dict):
        raise InstanceError(source, field, 'an object like {"kind": "poisson", "mean": 3.0}', _show(spec))
    for problem in priors.prior_problems(spec):
        raise InstanceError.of(source, problem.within(field))
    return priors.build_prior(spec)


# ----------------------------------------------------------------------------- loading

def _show(v: Any) -> str:
    return validation.show(v, "json")


def _matrix(data: Any, source: str, field: str, shape: tuple[int, int], cell_ok: Callable[[Any], bool],
            cell_expected: str) -> list[list[Any]]:
    n_rows, n_cols = shape
    if not isinstance(data, list) or len(data) != n_rows:
        found = f"a list of {len(data)} rows" if isinstance(data, list) else _show(data)
        raise InstanceError(source, field, f"a list of {n_rows} rows (one per carrier)", found)
    for r, row in enumerate(data):
        if not isinstance(row, list) or len(row) != n_cols:
            found = f"{len(row)} entries" if isinstance(row, list) else _show(row)
            raise InstanceError(source, f"{field}[{r}]", f"a list of {n_cols} entries (one per stage)", found)
        for j, cell in enumerate(row):
            if not cell_ok(cell):
                raise InstanceError(source, f"{field}[{r}][{j}]", cell_expected, _show(cell))
    return data


def _in_support(prior, value: float) -> bool:
    lo, hi = prior.support()
    if not lo <= value <= hi:
        return False
    if hasattr(prior.dist, "pmf"):
        return bool(prior.pmf(value) > 0)
    return True


def _passenger_values(data: dict, source: str, n_carriers: int, passengers) -> list | None:
    """The optional ``passenger_values`` field: one list of weights > 0 per carrier, as long as its
    passengers. None when absent (every passenger weighs 1: the unweighted problem)."""
    if "passenger_values" not in data:
        return None
    values = data["passenger_values"]
    counts = passengers if isinstance(passengers, list) else [passengers] * n_carriers
    if not isinstance(values, list) or len(values) != n_carriers:
        found = f"a list of {len(values)}" if isinstance(values, list) else _show(values)
        raise InstanceError(source, "passenger_values", f"a list of {n_carriers} lists (one per carrier)", found)
    for r, row in enumerate(values):
        if not isinstance(row, list) or len(row) != counts[r]:
            found = f"a list of {len(row)}" if isinstance(row, list) else _show(row)
            raise InstanceError(source, f"passenger_values[{r}]",
                                f"a list of {counts[r]} numbers > 0 (one per passenger of carrier {r})", found)
        for i, w in enumerate(row):
            if not _positive(w):
                raise InstanceError(source, f"passenger_values[{r}][{i}]", "a number > 0", _show(w))
    return [[float(w) for w in row] for row in values]


def parse_instance(data: Any, source: str = "<instance>", seed: int = 0) -> tuple[Instance, bool]:
    """Validate a decoded JSON instance.

    Args:
        data: the decoded JSON value.
        source: name used in error messages (the file name).
        seed: root seed; when the instance has no ``observations`` they are drawn from the prior
            with ``SeedSequence(seed, spawn_key=OBSERVATION_SPAWN_KEY)`` at the valid stages.

    Returns:
        (instance, sampled): ``sampled`` tells whether the observations were drawn.

    Raises:
        InstanceError: the first problem found, as one line.
    """
    if not isinstance(data, dict):
        raise InstanceError(source, "(top level)", "a JSON object", type(data).__name__ if data is not None else "null")
    for key in data:
        if key not in FIELDS:
            raise InstanceError(source, key, f"only the fields {', '.join(FIELDS)}{validation.did_you_mean(key, FIELDS)}",
                                "an unknown field")
    for key in ("carriers", "passengers", "stages"):
        if key not in data:
            raise InstanceError(source, key, "a required field", "nothing (missing)")
    n_carriers, n_stages = data["carriers"], data["stages"]
    if not _int(n_carriers) or n_carriers < 1:
        raise InstanceError(source, "carriers", "an integer >= 1", _show(n_carriers))
    if not _int(n_stages) or n_stages < 1:
        raise InstanceError(source, "stages", "an integer >= 1", _show(n_stages))
    passengers = data["passengers"]
    if isinstance(passengers, list):
        if len(passengers) != n_carriers:
            raise InstanceError(source, "passengers", f"one integer >= 0 or a list of {n_carriers} (one per carrier)",
                                f"a list of {len(passengers)}")
        for r, d in enumerate(passengers):
            if not _int(d) or d < 0:
                raise InstanceError(source, f"passengers[{r}]", "an integer >= 0", _show(d))
    elif not _int(passengers) or passengers < 0:
        raise InstanceError(source, "passengers", "an integer >= 0 or a list of them", _show(passengers))

    weights = _passenger_values(data, source, n_carriers, passengers)

    normalize = data.get("normalize", "q90")
    if not (isinstance(normalize, str) or _positive(normalize)):
        raise InstanceError(source, "normalize", '"q90", "qNN", "none" or a number > 0', _show(normalize))

    overlaps = data.get("overlaps", [])
    if not isinstance(overlaps, list):
        raise InstanceError(source, "overlaps", "a list of overlaps, each a list of [carrier, stage] pairs",
                            _show(overlaps))
    for k, group in enumerate(overlaps):
        if not isinstance(group, list) or not group:
            raise InstanceError(source, f"overlaps[{k}]", "a non-empty list of [carrier, stage] pairs", _show(group))
        for m, pair in enumerate(group):
            field = f"overlaps[{k}][{m}]"
            if not (isinstance(pair, list) and len(pair) == 2 and all(_int(v) for v in pair)):
                raise InstanceError(source, field, "a [carrier, stage] pair of integers", _show(pair))
            if not 0 <= pair[0] < n_carriers:
                raise InstanceError(source, f"{field}[0]", f"a carrier index in 0..{n_carriers - 1}", _show(pair[0]))
            if not 0 <= pair[1] < n_stages:
                raise InstanceError(source, f"{field}[1]", f"a stage index in 0..{n_stages - 1}", _show(pair[1]))

    shape = (n_carriers, n_stages)
    valid = None
    if "valid" in data:
        valid = np.array(_matrix(data["valid"], source, "valid", shape, lambda v: isinstance(v, bool),
                                 "true or false"), dtype=bool)
    observations = data.get("observations")
    if observations is not None:
        _matrix(observations, source, "observations", shape, lambda v: v is None or _num(v),
                "a finite number or null (∅)")
    # The prior last: building it loads scipy.stats, so structural errors are reported quickly.
    prior = make_prior(data.get("prior", DEFAULT_PRIOR), source)
    try:
        normalisation_scale(prior, normalize)
    except ValueError as err:
        raise InstanceError(source, "normalize", '"q90", "qNN", "none" or a number > 0 giving a positive scale',
                            f"{_show(normalize)} ({err})") from None
    if observations is not None:
        x = np.array([[np.nan if v is None else float(v) for v in row] for row in observations])
        lo, hi = prior.support()
        for r, j in zip(*np.nonzero(~np.isnan(x))):
            if valid is not None and not valid[r, j]:
                raise InstanceError(source, f"observations[{r}][{j}]", "null at a stage marked false in valid",
                                    _show(observations[r][j]))
            if not _in_support(prior, x[r, j]):
                raise InstanceError(source, f"observations[{r}][{j}]",
                                    f"a value the prior can produce (support {lo:g}..{hi:g})",
                                    _show(observations[r][j]))
        if valid is None:
            valid = ~np.isnan(x)
    if valid is None:
        valid = np.ones(shape, dtype=bool)
    problem = Problem.build(passengers, valid, overlaps, prior, normalize, weights)
    if observations is None:
        rng = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=OBSERVATION_SPAWN_KEY))
        return Instance(problem, sample_observations(problem, rng)), True
    return Instance(problem, np.where(valid, x, np.nan)), False


def load_instance(path: str | Path, seed: int = 0) -> tuple[Instance, bool]:
    """Read and validate an instance file; see :func:`parse_instance`.

    Raises:
        InstanceError: unreadable file, invalid JSON, or any field problem (one line).
    """
    source = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        raise InstanceError(source, "(file)", "a readable UTF-8 JSON file", f"{type(err).__name__}: {err}") from None

    def reject_constant(name: str):
        raise ValueError(f"{name} is not allowed")

    try:
        data = json.loads(text, parse_constant=reject_constant)
    except ValueError as err:
        raise InstanceError(source, "(file)", "valid JSON", str(err).splitlines()[0]) from None
    return parse_instance(data, source, seed)


def instance_dict(instance: Instance, prior: dict | None = None, normalize: str | float = "q90") -> dict:
    """The JSON object of an instance (observations with null for ∅, validity written out).

    Args:
        instance: problem and observations.
        prior: the prior specification to write (the problem's prior object cannot be turned back
            into one); ``{"kind": "poisson", "mean": 3.0}`` when omitted.
        normalize: the normalisation to write.
    """
    problem, x = instance
    d = problem.passengers.tolist()
    out = {
        "carriers": problem.n_carriers,
        "passengers": d[0] if len(set(d)) == 1 else d,
        "stages": problem.n_stages,
        "prior": dict(prior or DEFAULT_PRIOR),
        "normalize": normalize,
        "overlaps": [group.tolist() for group in problem.overlaps],
        "valid": problem.valid.tolist(),
        "observations": [[None if np.isnan(v) else (int(v) if float(v).is_integer() else float(v)) for v in row]
                         for row in x],
    }
    if problem.weights is not None:
        out["passenger_values"] = [problem.weights[r, :k].tolist() for r, k in enumerate(d)]
    return out


# ----------------------------------------------------------------------------- random instances

def random_instance(
    rng: np.random.Generator,
    carriers: int = 4,
    passengers: int | list[int] = 3,
    stages: int = 10,
    overlaps: int = 20,
    mean: float = 3.0,
    invalid_fraction: float = 0.0,
    weights=None,
) -> Instance:
    """A paper-style random instance with Poisson(``mean``) observations.

    * Each of the ``overlaps`` groups holds 2 or 3 (equally likely) distinct decision points drawn
      uniformly from all ``carriers * stages`` points; two points of one carrier in one group make
      that carrier conflict with itself.
    * Each decision point is invalid (∅, known in advance) independently with probability
      ``invalid_fraction``.
    * Observations are drawn from the prior at valid stages (NaN elsewhere).
    * ``weights``: None (no passenger values) or one list of passenger weights per carrier
      (``Problem.weights``); it draws nothing, so the same seed gives the same instance either way.

    Draw order (fixed, so a seed gives one instance): validity, overlaps, observations.
    """
    n_points = carriers * stages
    valid = rng.random((carriers, stages)) >= invalid_fraction
    groups = []
    for _ in range(overlaps):
        size = min(int(rng.integers(2, 4)), n_points)
        flat = rng.choice(n_points, size=size, replace=False)
        groups.append([[int(a) // stages, int(a) % stages] for a in flat])
    problem = Problem.build(passengers, valid, groups, priors.build_prior({"kind": "poisson", "mean": mean}),
                            weights=weights)
    return Instance(problem, sample_observations(problem, rng))
