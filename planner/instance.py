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
          "valid", "observations", "passenger_values", "reward", "regions", "covers", "counts")

#: The reward models an instance may name (``reward``); the first is the default.
REWARDS = ("penalty", "coverage")
#: Fields of the coverage reward only (``reward: coverage``).
COVERAGE_FIELDS = ("regions", "covers", "counts")


class Instance(NamedTuple):
    """A problem and its realised observations ``x[R, N]`` (float, NaN = ∅)."""

    problem: Problem
    observations: np.ndarray


class InstanceError(ValueError):
    """A bad instance. ``str(err)`` is one line: ``source: field: expected ..., found ...``."""

    def __init__(self, source: str, field: str, expected: str, found: str):
        """``found``: the offending value already shown (:func:`_show`) or a description."""
        self.source, self.field, self.expected, self.found = source, field, expected, found
        self.problem = validation.Flaw(field, expected, validation.Found(found))
        super().__init__(self.problem.line(source))

    @classmethod
    def of(cls, source: str, problem: validation.Flaw) -> InstanceError:
        """The error of a :class:`validation.Flaw` (its found value shown as JSON)."""
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
    """Validate a decoded JSON instance; :func:`parse_instance_counts` without the region counts."""
    instance, _, sampled = parse_instance_counts(data, source, seed)
    return instance, sampled


def parse_instance_counts(data: Any, source: str = "<instance>", seed: int = 0) -> tuple[Instance, np.ndarray | None, bool]:
    """Validate a decoded JSON instance.

    Args:
        data: the decoded JSON value.
        source: name used in error messages (the file name).
        seed: root seed; when the instance has no ``observations`` they are drawn from the prior
            with ``SeedSequence(seed, spawn_key=OBSERVATION_SPAWN_KEY)`` at the valid stages (a
            coverage instance without ``counts`` draws its region counts from that stream).

    Returns:
        (instance, counts, sampled): ``counts`` float ``[M]`` the realised region counts of a
        ``reward: coverage`` instance (None for the penalty reward; the observations are then
        their sums, :func:`planner.coverage.observations`); ``sampled`` tells whether the
        observations (or counts) were drawn.

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
    if data.get("reward", REWARDS[0]) != REWARDS[0]:
        return _parse_coverage(data, source, seed, passengers, weights, normalize, valid)
    for key in COVERAGE_FIELDS:
        if key in data:
            raise InstanceError(source, key, 'only with "reward": "coverage"', "a penalty instance")
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
        return Instance(problem, sample_observations(problem, _observation_rng(seed))), None, True
    return Instance(problem, np.where(valid, x, np.nan)), None, False


def _observation_rng(seed: int) -> np.random.Generator:
    """The stream drawing what an instance file omits (observations, or a coverage instance's counts)."""
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=OBSERVATION_SPAWN_KEY))


# ----------------------------------------------------------------------------- the coverage reward

def _parse_coverage(data: dict, source: str, seed: int, passengers, weights, normalize,
                    valid: np.ndarray | None) -> tuple[Instance, np.ndarray, bool]:
    """The rest of :func:`parse_instance_counts` for ``"reward": "coverage"`` (docs/planner.md,
    "Coverage reward"): regions, covers and counts, checked structurally before any prior is built."""
    from planner import coverage as cov

    if data["reward"] not in REWARDS:
        raise InstanceError(source, "reward", f"one of {', '.join(REWARDS)}", _show(data.get("reward")))
    for key in ("observations", "overlaps"):
        if key in data:
            raise InstanceError(source, key, "absent in a coverage instance (derived from covers and counts)",
                                "a value")
    for key in ("regions", "covers"):
        if key not in data:
            raise InstanceError(source, key, "a required field of a coverage instance", "nothing (missing)")
    n_carriers, n_stages = data["carriers"], data["stages"]
    regions = data["regions"]
    if not isinstance(regions, list) or not regions:
        raise InstanceError(source, "regions", 'a non-empty list of regions like {"mean": 2.0}', _show(regions))
    for m, region in enumerate(regions):
        if not (isinstance(region, dict) and len(region) == 1 and ("mean" in region or "prior" in region)):
            raise InstanceError(source, f"regions[{m}]", 'an object {"mean": MU} or {"prior": {...}}', _show(region))
        if "mean" in region and not _positive(region["mean"]):
            raise InstanceError(source, f"regions[{m}].mean", "a number > 0", _show(region["mean"]))
    n_regions = len(regions)
    covers = data["covers"]

    def cell_ok(cell) -> bool:
        return cell is None or (isinstance(cell, list) and all(_int(m) for m in cell))

    _matrix(covers, source, "covers", (n_carriers, n_stages), cell_ok, "a list of region indices or null")
    for r, row in enumerate(covers):
        for j, cell in enumerate(row):
            if valid is not None and valid[r][j] != (cell is not None):
                raise InstanceError(source, f"covers[{r}][{j}]",
                                    "null at a stage marked false in valid" if cell is not None
                                    else "a list of region indices at a stage marked true in valid",
                                    _show(cell))
            for k, m in enumerate(cell or ()):
                if not 0 <= m < n_regions:
                    raise InstanceError(source, f"covers[{r}][{j}][{k}]", f"a region index in 0..{n_regions - 1}",
                                        _show(m))
    if valid is None:
        valid = np.array([[cell is not None for cell in row] for row in covers], dtype=bool)
    counts = data.get("counts")
    if counts is not None:
        if not isinstance(counts, list) or len(counts) != n_regions:
            found = f"a list of {len(counts)}" if isinstance(counts, list) else _show(counts)
            raise InstanceError(source, "counts", f"a list of {n_regions} counts >= 0 (one per region)", found)
        for m, c in enumerate(counts):
            if not (_num(c) and c >= 0):
                raise InstanceError(source, f"counts[{m}]", "a count >= 0", _show(c))
    # The priors last: building them loads scipy.stats.
    region_priors = [_region_prior(region, source, f"regions[{m}]") for m, region in enumerate(regions)]
    if counts is not None:
        for m, (c, prior) in enumerate(zip(counts, region_priors)):
            if not _in_support(prior, c):
                lo, hi = prior.support()
                raise InstanceError(source, f"counts[{m}]", f"a count region {m}'s prior can produce "
                                    f"(support {lo:g}..{hi:g})", _show(c))
    coverage = cov.Coverage.build(covers, region_priors)
    prior = make_prior(data["prior"] if "prior" in data else point_prior_spec(coverage, valid), source)
    try:
        normalisation_scale(prior, normalize)
    except ValueError as err:
        raise InstanceError(source, "normalize", '"q90", "qNN", "none" or a number > 0 giving a positive scale',
                            f"{_show(normalize)} ({err})") from None
    problem = Problem.build(passengers, valid, coverage.overlaps(n_stages), prior, normalize, weights, coverage)
    sampled = counts is None
    realised = cov.sample_counts(coverage, _observation_rng(seed)) if sampled else np.array(counts, dtype=float)
    return Instance(problem, cov.observations(coverage, realised, valid)), realised, sampled


def point_prior_spec(coverage, valid: np.ndarray) -> dict:
    """The pooled prior of a coverage problem's observations (``Problem.prior``: its scale, and the
    prior of planners that read one prior for every point): Poisson of the mean, over the valid
    points, of the sum of a point's region means; the default prior when no point explores any."""
    sums = np.diff(np.concatenate([[0.0], np.cumsum(coverage.means[coverage.idx])])[coverage.ptr])
    point_mean = float(sums[np.asarray(valid).ravel()].mean()) if np.any(valid) else 0.0
    return {"kind": "poisson", "mean": point_mean} if point_mean > 0 else dict(DEFAULT_PRIOR)


def _region_prior(region: dict, source: str, field: str):
    """A region's count prior: Poisson(``mean``), or its ``prior`` object, which must be discrete on
    counts >= 0 (a feature count is never negative nor continuous)."""
    if "mean" in region:
        return priors.build_prior({"kind": "poisson", "mean": region["mean"]})
    prior = make_prior(region["prior"], source, f"{field}.prior")
    if not priors.is_discrete(prior) or prior.support()[0] < 0:
        raise InstanceError(source, f"{field}.prior", "a discrete prior on counts >= 0 (a region's feature count)",
                            _show(region["prior"]))
    return prior


def _read(path: str | Path) -> Any:
    """The decoded JSON of an instance file (constants such as NaN rejected)."""
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
    return data


def load_instance(path: str | Path, seed: int = 0) -> tuple[Instance, bool]:
    """Read and validate an instance file; see :func:`parse_instance`.

    Raises:
        InstanceError: unreadable file, invalid JSON, or any field problem (one line).
    """
    return parse_instance(_read(path), str(path), seed)


def load_instance_counts(path: str | Path, seed: int = 0) -> tuple[Instance, np.ndarray | None, bool]:
    """Read and validate an instance file, keeping a coverage instance's region counts; see
    :func:`parse_instance_counts`."""
    return parse_instance_counts(_read(path), str(path), seed)


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


def random_coverage_instance(
    rng: np.random.Generator,
    carriers: int = 4,
    passengers: int | list[int] = 3,
    stages: int = 10,
    overlaps: int = 20,
    mean: float = 3.0,
    own: int = 2,
    reach: int | None = None,
    invalid_fraction: float = 0.0,
    weights=None,
) -> tuple[Instance, np.ndarray]:
    """A random ``reward: coverage`` instance and its realised region counts (issue 35).

    Combinatorial (no geometry), the coverage twin of :func:`random_instance`:

    * Each decision point is invalid (∅, known in advance) independently with probability
      ``invalid_fraction``.
    * Every valid point's disc has ``own`` regions nobody else explores, each with prior
      Poisson(``mean / own``): a point that shares nothing observes Poisson(``mean``), as in
      :func:`random_instance`.
    * ``overlaps`` shared regions (the overlap level, as :func:`random_instance`'s overlap groups
      and the paper's Fig. 2), each explored by 2 or 3 (equally likely) distinct valid points and
      with prior Poisson(``mean / own``) (a lens between discs about the size of one own cell). The
      first point is drawn uniformly among the valid points; the others uniformly among the valid
      points within ``reach`` stages of it (any carrier), or among all valid points when ``reach``
      is None (the paper's uniform overlaps). A point drawn twice leaves the region smaller.
    * The counts are drawn from the region priors; the observations are their sums.
    * ``weights``: None or one list of passenger weights per carrier (``Problem.weights``); it
      draws nothing.

    Draw order (fixed, so a seed gives one instance): validity, shared regions, counts.

    Returns:
        ``(Instance(problem, x), counts)``: ``problem.coverage`` the regions (own regions first,
        point by point, then the shared ones), ``problem.overlaps`` the penalty model's view of the
        same world (one group per shared region, :meth:`planner.coverage.Coverage.overlaps`), so
        one world can be planned under both models; ``problem.prior`` the pooled prior
        (:func:`point_prior_spec`); ``counts`` float ``[M]``.
    """
    from planner import coverage as cov

    if own < 1:
        raise ValueError(f"own must be >= 1 (regions of a point's own disc), got {own}")
    valid = rng.random((carriers, stages)) >= invalid_fraction
    points = np.flatnonzero(valid.ravel())
    covers: list[list[int]] = [[] for _ in range(carriers * stages)]
    for i, a in enumerate(points):
        covers[a] = list(range(i * own, (i + 1) * own))
    n_own = own * len(points)
    for k in range(overlaps if len(points) >= 2 else 0):
        first = int(rng.choice(points))
        near = points if reach is None else points[np.abs(points % stages - first % stages) <= reach]
        near = near[near != first]
        size = min(int(rng.integers(2, 4)) - 1, len(near))
        for a in [first, *rng.choice(near, size=size, replace=False).tolist()] if size else [first]:
            covers[a].append(n_own + k)
    n_regions = n_own + (overlaps if len(points) >= 2 else 0)
    region_prior = priors.build_prior({"kind": "poisson", "mean": mean / own})
    grid = [[covers[r * stages + j] if valid[r, j] else None for j in range(stages)] for r in range(carriers)]
    coverage = cov.Coverage.build(grid, [region_prior] * n_regions)
    problem = Problem.build(passengers, valid, coverage.overlaps(stages),
                            priors.build_prior(point_prior_spec(coverage, valid)), weights=weights, coverage=coverage)
    counts = cov.sample_counts(coverage, rng)
    return Instance(problem, cov.observations(coverage, counts, valid)), counts


def penalty_twin(problem: Problem) -> Problem:
    """The penalty model's problem of a coverage problem's world: the same passengers, schedule,
    prior (so the same scale), normalisation and passenger values, with one overlap group per
    region explored from two or more points (:meth:`planner.coverage.Coverage.overlaps`) and the
    1/p reward. Its planners read the same observations (the sums of the counts); their
    deployments are then scored by true coverage (:func:`planner.problem.evaluate` on the coverage
    problem)."""
    return Problem(problem.passengers, problem.valid, problem.overlaps, problem.prior, problem.scale,
                   problem.conflict, problem.weights)
