"""The deployment problem, exactly: carriers, stages, overlaps, the prior and the penalty rule.

Everything here is pure numpy/scipy. Indices are 0-based: carrier ``r`` in ``0..R-1``,
stage ``j`` in ``0..N-1``. A decision point ``(r, j)`` is flattened to ``r * N + j`` where a
flat index is needed.

Conventions shared by every planner and by the fleet:

* observations are a float array ``x[R, N]``; ``NaN`` marks an invalid (∅) stage or one not
  observed yet;
* decisions are a bool array ``deployed[R, N]``; with passenger values (types) the passenger each
  deployment released is ``released[R, N]`` (int64, the passenger's index on its carrier, -1 where
  nothing was released);
* validity ``valid[R, N]`` is the schedule known in advance; online surprises (a carrier that did
  not report, or crashed) turn a stage ∅ in the realised observations.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, Protocol, Sequence

import numpy as np

from planner.priors import Poisson

#: Quantile of the prior whose value normalises rewards for planning (the paper's 90th percentile).
NORMALIZE_QUANTILE = 0.9


def _conflict_matrix(n_carriers: int, n_stages: int, overlaps: Sequence[np.ndarray]) -> np.ndarray:
    """``C[a, b]`` is true when flat decision points ``a != b`` share at least one overlap."""
    size = n_carriers * n_stages
    conflict = np.zeros((size, size), dtype=bool)
    for group in overlaps:
        flat = np.unique(group[:, 0] * n_stages + group[:, 1])
        conflict[np.ix_(flat, flat)] = True
    np.fill_diagonal(conflict, False)
    return conflict


def normalisation_scale(prior: Any, normalize: str | float | None = "q90") -> float:
    """The number rewards are divided by for planning.

    Args:
        prior: frozen scipy.stats distribution.
        normalize: ``"q90"`` (the prior's 90th percentile, the paper's choice), ``"qNN"`` (the
            NN-th percentile, 0 < NN < 100), ``"none"`` / ``None`` (1.0) or a positive number.

    Raises:
        ValueError: unknown spelling, or a scale that is not a positive finite number (e.g. the
            90th percentile of a prior concentrated at 0).
    """
    if normalize in ("none", None):
        scale = 1.0
    elif isinstance(normalize, str):
        text = normalize.strip().lower()
        try:
            if not text.startswith("q"):
                raise ValueError
            quantile = float(text[1:]) / 100.0
        except ValueError:
            raise ValueError(f'normalize must be "q90", "qNN", "none" or a positive number, got {normalize!r}') from None
        if not 0.0 < quantile < 1.0:
            raise ValueError(f"normalize quantile must be strictly between q0 and q100, got {normalize!r}")
        scale = float(prior.ppf(quantile))
    else:
        scale = float(normalize)
    if not np.isfinite(scale) or scale <= 0:
        raise ValueError(f"normalisation scale must be a positive number, got {scale} from normalize={normalize!r}")
    return scale


@dataclass(frozen=True, eq=False)
class Problem:
    """One deployment problem instance (everything known before the mission starts).

    Attributes:
        passengers: int64 ``[R]``, passengers D_r each carrier must deploy.
        valid: bool ``[R, N]``, stages at which the carrier is scheduled to be running.
        overlaps: tuple of int64 ``[k, 2]`` arrays of ``(carrier, stage)`` pairs; a group of
            decision points in close proximity. A carrier may appear twice in one group.
        prior: frozen ``scipy.stats`` distribution of the feature count ``x`` at a valid stage.
        scale: rewards are divided by this for planning (the prior's 90th percentile by default).
        conflict: bool ``[R*N, R*N]``, derived: flat points sharing an overlap (zero diagonal).
        weights: float64 ``[R, max D]`` or None: ``weights[r, i] > 0`` is the value weight of
            carrier r's passenger i (``i < D_r``; 0.0 pads the rows). Releasing passenger i at an
            observation x earns ``w_i * x / p``. None (no passenger values) is exactly the
            unweighted problem: every passenger weighs 1 and passengers are interchangeable.
        coverage: a :class:`planner.coverage.Coverage` (the regions each point explores) for a
            ``reward: coverage`` problem, None for the paper's penalty reward (:attr:`reward`).
    """

    passengers: np.ndarray
    valid: np.ndarray
    overlaps: tuple[np.ndarray, ...]
    prior: Any  # a frozen scipy.stats distribution or planner.priors.Poisson (scipy ships no types)
    scale: float
    conflict: np.ndarray = field(repr=False)
    weights: np.ndarray | None = field(default=None, repr=False)
    coverage: Any = field(default=None, repr=False)

    @staticmethod
    def build(
        passengers: int | Sequence[int],
        valid: np.ndarray,
        overlaps: Sequence[Sequence[Sequence[int]]] = (),
        prior: Any = None,
        normalize: str | float = "q90",
        weights: Sequence[Sequence[float]] | None = None,
        coverage: Any = None,
    ) -> "Problem":
        """Validate and assemble a problem.

        Args:
            passengers: D for every carrier, or one D per carrier.
            valid: bool ``[R, N]`` schedule validity.
            overlaps: groups of ``(carrier, stage)`` pairs.
            prior: frozen scipy.stats distribution; Poisson(3) when omitted.
            normalize: see :func:`normalisation_scale`.
            weights: None, or one list per carrier of its passengers' value weights (``D_r``
                numbers > 0 each; ``passengers`` must then match the list lengths).
            coverage: None (the penalty reward) or a :class:`planner.coverage.Coverage` of R * N
                points (the coverage reward).

        Raises:
            ValueError: with a message naming what is wrong.
        """
        valid = np.array(valid, dtype=bool)
        if valid.ndim != 2 or valid.shape[0] < 1 or valid.shape[1] < 1:
            raise ValueError(f"valid must be a non-empty [carriers, stages] array, got shape {valid.shape}")
        n_carriers, n_stages = valid.shape
        d = np.asarray(passengers, dtype=np.int64)
        if d.ndim > 1 or (d.ndim == 1 and len(d) != n_carriers):
            raise ValueError(f"passengers must be one number or one per carrier ({n_carriers}), got {d.tolist()}")
        d = np.broadcast_to(d, (n_carriers,)).copy()
        if (d < 0).any():
            raise ValueError(f"passengers must be >= 0, got {d.tolist()}")
        groups = []
        for k, group in enumerate(overlaps):
            arr = np.array(group, dtype=np.int64).reshape(-1, 2)
            if len(arr) and (
                (arr[:, 0] < 0).any() or (arr[:, 0] >= n_carriers).any()
                or (arr[:, 1] < 0).any() or (arr[:, 1] >= n_stages).any()
            ):
                raise ValueError(
                    f"overlaps[{k}] has a (carrier, stage) pair outside 0..{n_carriers - 1} x 0..{n_stages - 1}"
                )
            groups.append(arr)
        w = None if weights is None else _weight_matrix(weights, d)
        prior = Poisson(3.0) if prior is None else prior
        scale = normalisation_scale(prior, normalize)
        conflict = _conflict_matrix(n_carriers, n_stages, groups)
        # Instances are shared between planners and caches: make their arrays immutable.
        for arr in (d, valid, conflict, *groups) + (() if w is None else (w,)):
            arr.setflags(write=False)
        if coverage is not None and len(coverage.ptr) != valid.size + 1:
            raise ValueError(f"coverage must list the regions of {valid.size} points, got {len(coverage.ptr) - 1}")
        return Problem(d, valid, tuple(groups), prior, scale, conflict, w, coverage)

    @property
    def reward(self) -> str:
        """``"penalty"`` (the paper's 1/p rule) or ``"coverage"`` (:mod:`planner.coverage`)."""
        return "penalty" if self.coverage is None else "coverage"

    @property
    def n_carriers(self) -> int:
        return self.valid.shape[0]

    @property
    def n_stages(self) -> int:
        return self.valid.shape[1]


def _weight_matrix(weights: Sequence[Sequence[float]], passengers: np.ndarray) -> np.ndarray:
    """float64 ``[R, max D]`` of per-carrier passenger weights, 0.0-padded (see ``Problem.weights``)."""
    if len(weights) != len(passengers):
        raise ValueError(f"weights must hold one list per carrier ({len(passengers)}), got {len(weights)}")
    out = np.zeros((len(passengers), max(1, int(passengers.max(initial=0)))))
    for r, given in enumerate(weights):
        row = np.asarray(given, dtype=float).reshape(-1)
        if len(row) != passengers[r]:
            raise ValueError(f"weights[{r}] must hold {passengers[r]} values (one per passenger), got {len(row)}")
        if not (np.isfinite(row) & (row > 0)).all():
            raise ValueError(f"weights[{r}] must be finite numbers > 0, got {row.tolist()}")
        out[r, : len(row)] = row
    return out


def in_order(deployed: np.ndarray) -> np.ndarray:
    """int64 ``[R, N]`` releases of passengers in index order (a carrier's k-th deployment releases
    its passenger k), -1 where nothing is deployed: what type-blind carriers do, and the releases of
    a problem without passenger values."""
    deployed = np.asarray(deployed, dtype=bool)
    return np.where(deployed, np.cumsum(deployed, axis=1) - 1, -1).astype(np.int64)


def fill_releases(passengers: np.ndarray, deployed: np.ndarray, released: np.ndarray | None) -> np.ndarray:
    """int64 ``[R, N]``: ``released`` with every deployment whose passenger is unknown (-1) given
    the lowest index still aboard at that stage (what a carrier that was told no passenger
    releases); index order when ``released`` is None. ``passengers``: int ``[R]`` passengers
    per carrier (``Problem.passengers``)."""
    deployed = np.asarray(deployed, dtype=bool)
    if released is None:
        return in_order(deployed)
    out = np.where(deployed, np.asarray(released, dtype=np.int64), -1)
    for r in np.flatnonzero((deployed & (out < 0)).any(axis=1)):
        gone = set(out[r][out[r] >= 0].tolist())
        for j in np.flatnonzero(deployed[r] & (out[r] < 0)):
            free = next((i for i in range(int(passengers[r])) if i not in gone), None)
            if free is not None:
                out[r, j] = free
                gone.add(free)
    return out


def point_weights(problem: Problem, released: np.ndarray) -> np.ndarray:
    """float ``[R, N]``: the weight of the passenger released at each point (0.0 where none)."""
    released = np.asarray(released, dtype=np.int64)
    if problem.weights is None:
        return (released >= 0).astype(float)
    rows = np.arange(problem.n_carriers)[:, None]
    return np.where(released >= 0, problem.weights[rows, np.maximum(released, 0)], 0.0)


def penalties(problem: Problem, deployed: np.ndarray) -> np.ndarray:
    """p for every decision point: 1 + number of *other* selected points sharing an overlap.

    Returns int64 ``[R, N]`` (meaningful where ``deployed``).
    """
    sel = np.asarray(deployed, dtype=bool).ravel()
    # The selected rows, not columns: ``conflict`` is symmetric, and gathering a few contiguous
    # rows reads only those rows where gathering columns touches the whole matrix.
    p = 1 + problem.conflict[sel, :].sum(axis=0)
    return p.reshape(problem.valid.shape)


def rewards(problem: Problem, deployed: np.ndarray, x: np.ndarray, p: np.ndarray | None = None) -> np.ndarray:
    """Raw reward ``x / p`` of each selected deployment, 0 elsewhere. float ``[R, N]``.

    ``p``: :func:`penalties` of ``deployed`` when the caller keeps them (:class:`mission.records.Tally`
    adds a deployment's conflict row as it is confirmed); computed here otherwise."""
    deployed = np.asarray(deployed, dtype=bool)
    out = np.zeros(deployed.shape)
    xs = np.where(deployed, np.nan_to_num(x, nan=0.0), 0.0)
    np.divide(xs, penalties(problem, deployed) if p is None else p, out=out, where=deployed)
    return out


def evaluate(problem: Problem, deployed: np.ndarray, x: np.ndarray,
             released: np.ndarray | None = None, p: np.ndarray | None = None,
             counts: np.ndarray | None = None) -> tuple[float, float]:
    """Total (normalised reward, raw features) of a full set of deployments.

    Penalty reward: with passenger values (``problem.weights``) a deployment earns ``w * x / p``
    for the weight w of the passenger ``released[r, j]`` (index order, :func:`in_order`, when
    ``released`` is None; an unknown -1 is filled by :func:`fill_releases`); without, ``released``
    is ignored and this is ``sum x / p``. ``p``: as in :func:`rewards`.

    Coverage reward: :func:`planner.coverage.value` of the deployments over the realised region
    ``counts`` (required), each region worth the weight of the best passenger exploring it.
    """
    if problem.coverage is not None:
        from planner import coverage as cov

        deployed = np.asarray(deployed, dtype=bool)
        weights = None
        if problem.weights is not None:
            weights = point_weights(problem, fill_releases(problem.passengers, deployed, released))
        raw = cov.value(problem.coverage, deployed, _region_counts(problem, counts), weights)
        return raw / problem.scale, raw
    if problem.weights is not None:
        deployed = np.asarray(deployed, dtype=bool)
        released = fill_releases(problem.passengers, deployed, released)
        x = np.nan_to_num(np.asarray(x, dtype=float), nan=0.0) * point_weights(problem, released)
    raw = float(rewards(problem, deployed, x, p).sum())
    return raw / problem.scale, raw


def valid_stages_left(valid: np.ndarray) -> np.ndarray:
    """int64 ``[R, N + 1]``: ``out[r, k]`` = valid stages of carrier r from stage k (inclusive) to
    the end; ``out[:, N] = 0``. The one definition of "valid stages left" (the forced-deployment
    rule and the thresholds' ``n``)."""
    valid = np.asarray(valid, dtype=bool)
    out = np.zeros((valid.shape[0], valid.shape[1] + 1), dtype=np.int64)
    out[:, :-1] = np.cumsum(valid[:, ::-1], axis=1)[:, ::-1]
    return out


@dataclass(frozen=True, eq=False)
class StageView:
    """What an online planner may know when deciding stage ``stage``.

    Attributes:
        problem: the instance.
        stage: the stage j being decided.
        observations: float ``[R, N]``; real values at stages <= j, NaN at ∅ and at stages > j.
        valid: bool ``[R, N]``; realised validity at stages <= j (∅ observations are invalid),
            scheduled validity after j.
        deployed: bool ``[R, N]``; decisions taken at stages < j (False from j on).
        released: int64 ``[R, N]`` or None: the passenger released at each past deployment (-1
            elsewhere); None means index order (:func:`in_order` of ``deployed``), which is all a
            problem without passenger values needs.
        counts: float ``[M]`` or None: under the coverage reward, the region counts revealed by
            the observations so far (:func:`planner.coverage.revealed`), NaN for the others;
            None for the penalty reward.
    """

    problem: Problem
    stage: int
    observations: np.ndarray
    valid: np.ndarray
    deployed: np.ndarray
    released: np.ndarray | None = None
    counts: np.ndarray | None = None

    @property
    def passengers_left(self) -> np.ndarray:
        """int64 ``[R]``."""
        return self.problem.passengers - self.deployed.sum(axis=1)

    @cached_property
    def stages_left_table(self) -> np.ndarray:
        """int64 ``[R, N + 1]``: :func:`valid_stages_left` of this view's validity (realised up to
        j, scheduled after)."""
        return valid_stages_left(self.valid)

    @property
    def stages_left(self) -> np.ndarray:
        """int64 ``[R]``: valid stages from j (inclusive) to the end."""
        return self.stages_left_table[:, self.stage]

    @property
    def can_deploy(self) -> np.ndarray:
        """bool ``[R]``: carriers allowed to deploy now."""
        return self.valid[:, self.stage] & (self.passengers_left > 0)

    @property
    def must_deploy(self) -> np.ndarray:
        """bool ``[R]``: carriers forced to deploy now (remaining valid stages == passengers left)."""
        return self.can_deploy & (self.stages_left <= self.passengers_left)

    @cached_property
    def past_releases(self) -> np.ndarray:
        """int64 ``[R, N]``: ``released``, or index order when the view has none."""
        return in_order(self.deployed) if self.released is None else self.released

    @cached_property
    def aboard(self) -> np.ndarray:
        """bool ``[R, max D]``: passengers still aboard (not yet released); padding is False."""
        out = np.arange(self.problem.weights.shape[1] if self.problem.weights is not None
                        else max(1, int(self.problem.passengers.max(initial=0))))[None, :] \
            < self.problem.passengers[:, None]
        rel = fill_releases(self.problem.passengers, self.deployed, self.past_releases)
        r, j = np.nonzero(rel >= 0)
        out[r, rel[r, j]] = False
        return out


def make_view(
    problem: Problem, stage: int, x: np.ndarray, deployed: np.ndarray,
    released: np.ndarray | None = None, counts: np.ndarray | None = None,
) -> StageView:
    """The causal view of stage ``stage`` given the realised observations ``x`` (NaN = ∅).

    Only ``x[:, :stage + 1]`` is read; later columns are masked, so a planner cannot peek.
    ``released`` (passengers released at past deployments) is kept only for a problem with
    passenger values; None means index order. ``counts`` (float ``[M]``, the realised region
    counts) is required under the coverage reward, and only the counts the observations up to
    ``stage`` reveal are kept.

    Raises:
        ValueError: ``stage`` outside the problem, or a coverage problem without ``counts``.
    """
    if not 0 <= stage < problem.n_stages:
        raise ValueError(f"stage {stage} outside 0..{problem.n_stages - 1}")
    seen = np.full(problem.valid.shape, np.nan)
    seen[:, : stage + 1] = x[:, : stage + 1]
    valid = problem.valid.copy()
    valid[:, : stage + 1] &= ~np.isnan(seen[:, : stage + 1])
    past = np.zeros(problem.valid.shape, dtype=bool)
    past[:, :stage] = np.asarray(deployed, dtype=bool)[:, :stage]
    known = None
    if problem.coverage is not None:
        from planner import coverage as cov

        known = cov.revealed(problem.coverage, seen, _region_counts(problem, counts))
    rel = None
    if released is not None and problem.weights is not None:
        rel = np.full(problem.valid.shape, -1, dtype=np.int64)
        rel[:, :stage] = np.where(past[:, :stage], np.asarray(released, dtype=np.int64)[:, :stage], -1)
    return StageView(problem, stage, seen, valid, past, rel, known)


def _region_counts(problem: Problem, counts: np.ndarray | None) -> np.ndarray:
    """``counts`` as float ``[M]`` for a coverage problem (ValueError when absent or misshapen)."""
    if counts is None:
        raise ValueError("a coverage problem needs its region counts (counts=)")
    counts = np.asarray(counts, dtype=float).reshape(-1)
    if counts.shape != (problem.coverage.n_regions,):
        raise ValueError(f"counts must hold {problem.coverage.n_regions} region counts, got {counts.shape[0]}")
    return counts


class Planner(Protocol):
    """An online planner: decides which carriers deploy at the current stage.

    A planner may also offer ``warm_up(problem) -> None`` (compile or cache whatever the first
    decision would otherwise pay for); callers that time decisions call it first when present.
    """

    name: str

    def decide(self, view: StageView, rng: np.random.Generator) -> np.ndarray:
        """Return bool ``[R]``: carriers deploying at ``view.stage``. Must respect
        ``view.can_deploy`` and ``view.must_deploy``."""
        ...


def warm_up_problem() -> Problem:
    """The tiny instance a planner's ``warm_up`` (and the clairvoyant search's) decides once to load
    its compiled kernels: 2 carriers, 3 stages, 1 passenger each, carrier 0's stage 1 overlapping
    carrier 1's stage 2, so that at stage 0 both carriers have a choice and a conflict lies ahead."""
    return Problem.build(1, np.ones((2, 3), dtype=bool), [[[0, 1], [1, 2]]])


def warm_up_coverage_problem() -> Problem:
    """:func:`warm_up_problem` under the coverage reward: each point explores a region of its own
    and carrier 0's stage 1 and carrier 1's stage 2 share one more (the install step's instance
    for the coverage kernels, ``python -m planner.cli.compile``)."""
    from planner.coverage import Coverage, PoissonPriors

    covers = [[[0], [1, 6], [2]], [[3], [4], [5, 6]]]
    return Problem.build(1, np.ones((2, 3), dtype=bool), [[[0, 1], [1, 2]]],
                         coverage=Coverage.build(covers, PoissonPriors(np.full(7, 2.0))))


def stage_rng(seed: int, stage: int) -> np.random.Generator:
    """The planner's random stream for one stage of a mission with root seed ``seed``.

    Derived from (seed, stage) alone, so an offline run, the distributed coordinator and a
    coordinator recovered after a crash draw the same numbers at the same stage.
    """
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(int(stage),)))


def enforce(view: StageView, decision: np.ndarray) -> np.ndarray:
    """Check a planner's decision against the feasibility rules; return it as bool ``[R]``.

    Raises:
        AssertionError: when a planner breaks a rule (a bug in that planner).
    """
    # Explicit raises, not assert statements: the checks must survive ``python -O``.
    decision = np.asarray(decision, dtype=bool).reshape(-1)
    if decision.shape != (view.problem.n_carriers,):
        raise AssertionError(f"stage {view.stage}: decision shape {decision.shape}, expected ({view.problem.n_carriers},)")
    bad = decision & ~view.can_deploy
    if bad.any():
        raise AssertionError(f"stage {view.stage}: carriers {np.flatnonzero(bad).tolist()} cannot deploy")
    missing = view.must_deploy & ~decision
    if missing.any():
        raise AssertionError(f"stage {view.stage}: carriers {np.flatnonzero(missing).tolist()} must deploy")
    return decision


@dataclass(frozen=True)
class OnlineResult:
    """Outcome of one online run.

    Attributes:
        deployed: bool ``[R, N]``.
        reward: normalised total reward with the penalty rule.
        features: raw total (sum of x / p).
        decision_ms: wall time of each stage's decision, milliseconds.
        released: int64 ``[R, N]``: the passenger each deployment released (-1 elsewhere); index
            order (:func:`in_order`) for a problem without passenger values.
    """

    deployed: np.ndarray
    reward: float
    features: float
    decision_ms: tuple[float, ...]
    released: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.released is None:
            object.__setattr__(self, "released", in_order(self.deployed))


@dataclass(frozen=True, eq=False)
class ClairvoyantResult:
    """Offline optimum (or upper bound) of one instance.

    Attributes:
        deployed: bool ``[R, N]``: the optimal deployments when ``exact``; the conflict-free
            choice (each carrier's largest observations) otherwise.
        reward: normalised total (raw / problem.scale): the optimum when ``exact``, otherwise an
            upper bound on it (the conflict-free total).
        features: raw total (sum of x / p), same meaning as ``reward``.
        exact: whether ``reward`` is the optimum (True) or only an upper bound (False).
        nodes: search nodes visited (0 when the search was not attempted).
        released: int64 ``[R, N]``: the passenger of each deployment (-1 elsewhere), the best
            assignment :func:`planner.passengers.best_assignment` (index order without values).
        gap: when not ``exact``, (features - value of the best feasible set found) / features
            (the coverage reward's bound, :mod:`planner.coverage_bounds`; 0.0 otherwise).
        method: how a coverage bound was found (``ilp``, ``lp``, ``union``); "" for the penalty.
    """

    deployed: np.ndarray
    reward: float
    features: float
    exact: bool
    nodes: int = 0
    released: np.ndarray | None = None
    gap: float = 0.0
    method: str = ""


def start_online(problem: Problem, x: np.ndarray, planner: Planner) -> tuple[np.ndarray, np.ndarray | None]:
    """What every online loop does before its first stage: check ``x`` against the problem's
    shape, blank unscheduled stages (NaN), call the planner's ``warm_up(problem)`` when it has one
    (so no timed decision pays for compilation), and allocate ``released`` (int64 ``[R, N]`` of -1)
    when passengers are told apart (passenger values, or a planner with its own
    ``release_passengers``), else None. Returns ``(x, released)``."""
    x = np.asarray(x, dtype=float)
    if x.shape != problem.valid.shape:
        raise ValueError(f"observations shape {x.shape} != problem shape {problem.valid.shape}")
    x = np.where(problem.valid, x, np.nan)
    warm_up = getattr(planner, "warm_up", None)
    if callable(warm_up):
        warm_up(problem)
    typed = problem.weights is not None or hasattr(planner, "release_passengers")
    released = np.full(problem.valid.shape, -1, dtype=np.int64) if typed else None
    return x, released


def sample_observations(problem: Problem, rng: np.random.Generator) -> np.ndarray:
    """Draw ``x[R, N]`` from the prior at scheduled stages; NaN elsewhere."""
    x = np.asarray(problem.prior.rvs(size=problem.valid.shape, random_state=rng), dtype=float)
    return np.where(problem.valid, x, np.nan)
