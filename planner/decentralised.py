"""Planning under a communication model: the comms-aware online loop, the per-carrier view, and
``dec-closed-loop``, our decentralised planner.

Two kinds of planner run under :func:`run_comms`:

* **centralised** (:class:`planner.problem.Planner`, ``decide(view, rng)``): the coordinator plans
  from what reached it (:func:`coordinator_view`); carriers execute what reaches them in time,
  else fall back (no deployment unless forced);
* **decentralised** (``decide_local(local, rng) -> LocalDecision``): every carrier decides its own
  action from a :class:`LocalView` — its own observations and deployments, everything known in
  advance (schedules, overlaps, passengers, prior, the mission seed), and the messages it has
  received — and publishes an :class:`Intent` for the others. This is the interface a carrier
  process runs on board (issue 12): the runner here only simulates the message passing.

The truth used for evaluation and for the carriers' own rules is what the carriers actually did.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np
from numba import njit

from planner import coverage as cov
from planner import ssap
from planner.closedloop import (BLOCK, Candidates, ClosedLoopPlanner, Net,
                                Selection, base_action, block_halo, conflict_components, grow_block,
                                marginal_gain, select_point, undo_selection)
from planner.comms import CommsSpec, Deliveries, LinkComms, contact, realise
from planner.compiled import compile_problem
from planner.joint import ENUMERATE_MAX, SAMPLES_MAX, SAMPLES_MIN, every_combination, sampled_mean
from planner.jitcache import cache_follows_sources
from planner.kernels import deploys
from planner.problem import (OnlineResult, Problem, StageView, enforce, evaluate, make_view,
                             stage_rng, start_online, valid_stages_left, warm_up_problem)
from planner.settings import check_budget


# ----------------------------------------------------------------------------- messages and views


@dataclass(frozen=True, eq=False)
class Intent:
    """A carrier's published plan: candidate deployment sequences and their probabilities.

    Attributes:
        stage: the stage after whose decision it was published.
        sequences: bool ``[k, N]``: deployment stages of each candidate over the whole mission
            (at stages ``<= stage`` the sender's actual deployments).
        probs: float ``[k]``: probability of each candidate (sums to 1).
    """

    stage: int
    sequences: np.ndarray
    probs: np.ndarray


@dataclass(frozen=True)
class LocalDecision:
    """What a carrier's planner returns: whether to deploy now, and the intent to publish."""

    deploy: bool
    intent: Intent | None = None

    @staticmethod
    def of(out) -> "LocalDecision":
        """A planner's ``decide_local`` result as a LocalDecision (a plain bool is accepted: no
        intent)."""
        return out if isinstance(out, LocalDecision) else LocalDecision(bool(out))


@dataclass(frozen=True, eq=False)
class LocalView:
    """What carrier ``carrier`` knows when deciding stage ``stage``.

    Attributes:
        problem: the instance (schedules, overlaps, passengers, prior: known in advance).
        carrier: this carrier's index r.
        stage: the stage j being decided.
        seed: the mission's root seed (known in advance to all).
        observations: float ``[R, N]``: ``x[b, t]`` for ``t < seen[b]`` (NaN there means ∅),
            NaN where unknown; own row through j.
        deployed: bool ``[R, N]``: known deployments, ``t < record[b]``; own row through j - 1.
        seen: int64 ``[R]``: b's observations are known at stages ``t < seen[b]`` (own: j + 1).
        record: int64 ``[R]``: b's deployments are known at stages ``t < record[b]`` (own: j).
        intents: tuple of the latest :class:`Intent` received from each carrier (None if none;
            own entry None).

        released: int64 ``[R, N]`` or None: the passengers of the known deployments (-1 where
            unknown; None: index order), for a problem with passenger values.
        counts: float ``[M]`` or None: under the coverage reward, the region counts this carrier
            knows (those its known observations reveal, :func:`planner.coverage.revealed`; NaN
            elsewhere); None for the penalty reward.
        contact: float ``[N, R + 1, R + 1]`` or None: the links' prediction, known before the
            mission, of who hears whom at each stage (:func:`planner.comms.contact`: index 0 the
            coordinator, 1 + r carrier r); None: no prediction (everyone is assumed to hear
            everyone from the next stage on).
        coordinated: the other carriers are decided by a coordinator (a hybrid fleet: this carrier
            decides alone because no decision reached it); False: every carrier decides on board.
    """

    problem: Problem
    carrier: int
    stage: int
    seed: int
    observations: np.ndarray
    deployed: np.ndarray
    seen: np.ndarray
    record: np.ndarray
    intents: tuple
    released: np.ndarray | None = None
    counts: np.ndarray | None = None
    contact: np.ndarray | None = None
    coordinated: bool = False

    @property
    def valid(self) -> np.ndarray:
        """bool ``[R, N]``: scheduled validity, with the ∅ this carrier knows of."""
        v = self.problem.valid.copy()
        known = np.arange(self.problem.n_stages)[None, :] < self.seen[:, None]
        v &= ~(known & np.isnan(self.observations))
        return v

    @property
    def complete(self) -> bool:
        """Whether this carrier knows everything the coordinator would (all observations through
        j, all deployments before j)."""
        return bool((self.seen >= self.stage + 1).all() and (self.record >= self.stage).all())

    def stage_view(self) -> StageView:
        """The central :class:`StageView` of this knowledge (exact when :attr:`complete`)."""
        return make_view(self.problem, self.stage, self.observations, self.deployed, self.released, self.counts)

    def own(self) -> tuple[bool, bool, int, int]:
        """(can deploy, must deploy, valid stages left n, passengers left d) of this carrier."""
        r, j = self.carrier, self.stage
        valid = self.problem.valid[r].copy()
        valid[: j + 1] &= ~np.isnan(self.observations[r, : j + 1])
        n = int(valid[j:].sum())
        d = int(self.problem.passengers[r] - self.deployed[r, :j].sum())
        can = bool(valid[j]) and d > 0
        return can, can and n <= d, n, d


# ----------------------------------------------------------------------------- the comms-aware loop


def local_views(view: StageView, seed: int = 0) -> list[LocalView]:
    """Every carrier's :class:`LocalView` when it knows everything in ``view`` (perfect links, no
    intents): what a central process can use to run a decentralised planner for the fleet."""
    problem, j = view.problem, view.stage
    R = problem.n_carriers
    seen = np.full(R, j + 1, dtype=np.int64)
    record = np.full(R, j, dtype=np.int64)
    return [LocalView(problem, r, j, int(seed), view.observations, view.deployed, seen, record, (None,) * R,
                      view.released, view.counts) for r in range(R)]


def decide_all(planner, view: StageView, rng: np.random.Generator) -> np.ndarray:
    """bool ``[R]``: every carrier's ``decide_local`` on full information, each with its own copy
    of ``rng``'s state (the planners' :meth:`decide` for a central caller such as the fleet's
    coordinator)."""
    state = rng.bit_generator.state
    out = np.zeros(view.problem.n_carriers, dtype=bool)
    for r, local in enumerate(local_views(view)):
        copy = np.random.default_rng()
        copy.bit_generator.state = state
        res = planner.decide_local(local, copy)
        out[r] = res.deploy if isinstance(res, LocalDecision) else bool(res)
    return out


def coordinator_view(problem: Problem, stage: int, x: np.ndarray, heard: np.ndarray,
                     belief: np.ndarray, released: np.ndarray | None = None,
                     counts: np.ndarray | None = None) -> StageView:
    """The coordinator's view at ``stage``: observations it received (``heard[r]``: carrier r's
    observations are known at stages ``< heard[r]``); a carrier whose stage-j observation did not
    arrive is planned as unable to deploy now (its stage looks ∅, so it is not forced by the
    coordinator either: the carrier applies the forced rule itself); ``belief`` the deployments it
    believes happened (the truth up to each carrier's last delivered observation, its own
    decisions after). ``counts``: a coverage problem's realised region counts (the view keeps
    those the received observations reveal)."""
    known = np.where(np.arange(problem.n_stages)[None, :] < heard[:, None], x, np.nan)
    return make_view(problem, stage, known, belief, released, counts)


def _forced_truth(problem: Problem, x: np.ndarray, deployed: np.ndarray, j: int) -> tuple[np.ndarray, np.ndarray]:
    """(can, must) bool ``[R]`` of the carriers' own rules at stage j from the truth."""
    valid = problem.valid.copy()
    valid[:, : j + 1] &= ~np.isnan(x[:, : j + 1])
    n = valid_stages_left(valid)[:, j]
    d = problem.passengers - deployed[:, :j].sum(axis=1)
    can = valid[:, j] & (d > 0)
    return can, can & (n <= d)


def run_comms(problem: Problem, x: np.ndarray, planner, seed: int, comms: CommsSpec | LinkComms | None = None,
              counts: np.ndarray | None = None, fallback=None) -> OnlineResult:
    """Run ``planner`` stage by stage with the messages of ``comms`` realised from ``seed``.

    Stage j's planning stream is :func:`planner.problem.stage_rng` ``(seed, j)`` (each carrier of a
    decentralised planner gets its own copy of it). With ``comms`` None or perfect, a centralised
    planner gives exactly :func:`planner.online.run_online`'s result.

    ``decision_ms``: per stage, the coordinator's decision time (centralised) or the slowest
    carrier's (decentralised: they plan in parallel). ``counts``: the realised region counts of
    a coverage problem (:func:`planner.online.run_online`).

    ``comms``: a :class:`~planner.comms.CommsSpec` or the links' :class:`~planner.comms.LinkComms`;
    every carrier's view carries the model's prediction (:func:`planner.comms.contact`) when the
    model is not perfect. ``fallback``: for a centralised planner, the on-board planner
    (``decide_local``) a carrier runs on what it heard when its decision did not arrive in time,
    or arrived but planned it as ∅ (its observation had not reached the coordinator) — the
    fleet's hybrid carriers; None: it deploys only when forced.
    """
    comms = CommsSpec() if comms is None else comms
    comms.check(problem.n_carriers)
    x, released = start_online(problem, x, planner)
    deliveries = realise(comms, problem.n_carriers, problem.n_stages, seed)
    predicted = None if comms.perfect else contact(comms, problem.n_carriers, problem.n_stages)
    if callable(getattr(planner, "decide_local", None)):
        deployed, times = _run_decentralised(problem, x, planner, seed, deliveries, released, counts, predicted)
    else:
        deployed, times = _run_centralised(problem, x, planner, seed, deliveries, released, counts, fallback,
                                           predicted)
    reward, features = evaluate(problem, deployed, x, released, counts=counts)
    return OnlineResult(deployed, reward, features, tuple(times), released)


def _release(problem: Problem, x: np.ndarray, deployed: np.ndarray, released: np.ndarray | None,
             planner, j: int, counts: np.ndarray | None = None) -> None:
    """Fill ``released[:, j]``: the passenger each stage-j deployment released. A carrier picks it
    on board from what it always knows itself (its observation, its valid stages left, who is
    still aboard) by the planner's passenger rule (:func:`planner.passengers.release`), so the
    choice needs no message. Nothing to do without passenger values (``released`` None)."""
    if released is None:
        return
    from planner.passengers import release

    released[:, j] = release(planner, make_view(problem, j, x, deployed, released, counts), deployed[:, j])


def _run_centralised(problem, x, planner, seed, dl: Deliveries, released=None, counts=None, fallback=None,
                     predicted=None):
    R, N = problem.valid.shape
    deployed = np.zeros((R, N), dtype=bool)   # the truth (carrier side)
    decided = np.zeros((R, N), dtype=bool)    # the coordinator's decisions
    times = []
    for j in range(N):
        # Latest observation message of each carrier at the coordinator: heard[r] = s + 1.
        arrived = dl.observation[:, R, : j + 1] <= j
        heard = np.where(arrived.any(axis=1), j + 1 - np.argmax(arrived[:, ::-1], axis=1), 0)
        # Truth before each carrier's last delivered observation, the coordinator's decisions after.
        before = np.arange(N)[None, :] < np.maximum(heard - 1, 0)[:, None]
        belief = np.where(before, deployed, decided)
        belief[:, j:] = False
        view = coordinator_view(problem, j, x, heard, belief,
                                None if released is None else np.where(belief & deployed, released, -1), counts)
        t0 = time.perf_counter()
        decision = planner.decide(view, stage_rng(seed, j))
        times.append((time.perf_counter() - t0) * 1e3)
        decision = enforce(view, decision)
        decided[:, j] = decision
        can, must = _forced_truth(problem, x, deployed, j)
        told = dl.decision[:, j] <= j
        if fallback is not None:
            # A decision that planned a carrier as ∅ (its observation did not arrive) is none for it.
            told &= heard > j
        deployed[:, j] = (told & decision & can) | must
        if fallback is not None:
            for r in np.flatnonzero(~told & can & ~must):
                local = replace(heard_view(problem, x, deployed, released, counts, dl, r, j, seed, predicted),
                                coordinated=True)
                deployed[r, j] = LocalDecision.of(fallback.decide_local(local, stage_rng(seed, j))).deploy
        _release(problem, x, deployed, released, planner, j, counts)
    return deployed, times


def heard_view(problem, x, deployed, released, counts, dl: Deliveries, r: int, j: int, seed: int,
               predicted=None, sent=None) -> LocalView:
    """Carrier r's :class:`LocalView` of stage j from the observation messages (x <= s,
    deployments < s) and intent messages (x, deployments <= s, intent) that reached it by stage j
    (``sent[b][s]``: the intents published; None: none)."""
    R, N = problem.valid.shape
    stages = np.arange(N)
    obs_ok = dl.observation[:, r, : j + 1] <= j            # [R, j + 1]
    int_ok = dl.intent[:, r, : j + 1] <= j
    last_obs = np.where(obs_ok.any(axis=1), j - np.argmax(obs_ok[:, ::-1], axis=1), -1)
    last_int = np.where(int_ok.any(axis=1), j - np.argmax(int_ok[:, ::-1], axis=1), -1)
    seen = np.maximum(last_obs, last_int) + 1
    record = np.maximum(np.maximum(last_obs, last_int + 1), 0)
    seen[r], record[r] = j + 1, j
    obs = np.where(stages[None, :] < seen[:, None], x, np.nan)
    dep = deployed & (stages[None, :] < record[:, None])
    intents = tuple(sent[b][last_int[b]] if sent is not None and b != r and last_int[b] >= 0 else None
                    for b in range(R))
    return LocalView(problem, r, j, int(seed), obs, dep, seen.astype(np.int64), record.astype(np.int64), intents,
                     None if released is None else np.where(dep, released, -1),
                     None if problem.coverage is None else cov.revealed(problem.coverage, obs, counts), predicted)


def _run_decentralised(problem, x, planner, seed, dl: Deliveries, released=None, counts=None, predicted=None):
    R, N = problem.valid.shape
    deployed = np.zeros((R, N), dtype=bool)
    sent: list[list] = [[None] * N for _ in range(R)]  # intents published, [carrier][stage]
    times = []
    for j in range(N):
        decision = np.zeros(R, dtype=bool)
        slowest = 0.0
        can, must = _forced_truth(problem, x, deployed, j)
        for r in range(R):
            local = heard_view(problem, x, deployed, released, counts, dl, r, j, seed, predicted, sent)
            t0 = time.perf_counter()
            out = LocalDecision.of(planner.decide_local(local, stage_rng(seed, j)))
            slowest = max(slowest, (time.perf_counter() - t0) * 1e3)
            if out.deploy and not can[r]:
                raise AssertionError(f"stage {j}: carrier {r} cannot deploy")
            if must[r] and not out.deploy:
                raise AssertionError(f"stage {j}: carrier {r} must deploy")
            decision[r] = out.deploy
            sent[r][j] = out.intent
        deployed[:, j] = decision
        _release(problem, x, deployed, released, planner, j, counts)
        times.append(slowest)
    return deployed, times


# ----------------------------------------------------------------------------- dec-closed-loop


class Unknown(NamedTuple):
    """What a carrier does not know of the members of its component: ``known`` bool ``[m]`` (the
    member's stage-j state is known), ``start`` int64 ``[m]`` (first stage of an unknown member
    whose deployment is unknown), ``left_start`` int64 ``[m]`` (its passengers left there),
    ``xobs`` float ``[R, N]`` the known observations (NaN unknown), and ``aware`` bool ``[m, N]``:
    the member is predicted to hear the others at stage t (it then weighs conflicts; else it
    follows its plain thresholds, as a carrier cut off does)."""

    known: np.ndarray
    start: np.ndarray
    left_start: np.ndarray
    xobs: np.ndarray
    aware: np.ndarray


# The rollout loop below is closed-loop's, written out: see the note above
# planner.closedloop._evaluate (sharing it made dec-closed-loop slower).
@njit(cache=True)
def _evaluate_imputed(cand, unknown, stage, n_stages, net, selection, past, samples, out):
    """Per-sample values of every candidate when some members' recent past is unknown.

    Args:
        cand: :class:`planner.closedloop.Candidates` (actions at ``stage`` read for known members
            only; ``xnow`` and ``left0`` are the known members' stage-j observations and passengers).
        unknown: :class:`Unknown`.
        net: :class:`planner.closedloop.Net` (scheduled validity with the known ∅).
        selection: :class:`planner.closedloop.Selection` of the known past deployments, restored on return.
        past: float ``[S, N, m]`` draws for the unknown stages of unknown members (stages
            ``start..stage``, where the observation is not known); samples: float ``[S, N - stage
            - 1, m]`` draws of the future.
        out: float ``[K, S]``: conflict-aware total minus plain independent SSAP future (raw units).

    Unknown members follow their known default policy (SSAP thresholds) on sampled observations
    through ``stage``; then every member follows the conflict-aware SSAP rollout.
    """
    actions, members, xnow, left0 = cand
    known, start, left_start, xobs, aware = unknown
    valid, nleft, table, nbr_ptr, nbr_idx = net
    sel, p, xv = selection
    n_cand = actions.shape[0]
    m = members.shape[0]
    n_samples = samples.shape[0]
    left = np.empty(m, np.int64)
    lefti = np.empty(m, np.int64)
    log = np.empty(sel.shape[0] + nbr_idx.shape[0] + 1, np.int64)
    for k in range(n_cand):
        for s in range(n_samples):
            nlog = np.int64(0)  # not a literal 0 (one compilation of undo_selection)
            total = 0.0
            plain = 0.0
            for i in range(m):
                r = members[i]
                if known[i]:
                    left[i] = left0[i]
                    if actions[k, i]:
                        q = r * n_stages + stage
                        total += marginal_gain(q, xnow[i], sel, p, xv, nbr_ptr, nbr_idx)
                        nlog = select_point(q, xnow[i], sel, p, xv, nbr_ptr, nbr_idx, log, nlog)
                        left[i] -= 1
                else:
                    d = left_start[i]
                    for t in range(start[i], stage + 1):
                        if not valid[r, t] or d <= 0:
                            continue
                        xs = xobs[r, t]
                        if xs != xs:
                            xs = past[s, t, i]
                        if deploys(table, xs, nleft[r, t], d):
                            q = r * n_stages + t
                            total += marginal_gain(q, xs, sel, p, xv, nbr_ptr, nbr_idx)
                            nlog = select_point(q, xs, sel, p, xv, nbr_ptr, nbr_idx, log, nlog)
                            d -= 1
                    left[i] = d
                lefti[i] = left[i]
            for t in range(stage + 1, n_stages):
                for i in range(m):
                    r = members[i]
                    if not valid[r, t]:
                        continue
                    n = nleft[r, t]
                    xs = samples[s, t - stage - 1, i]
                    d = left[i]
                    if d > 0:
                        q = r * n_stages + t
                        g = marginal_gain(q, xs, sel, p, xv, nbr_ptr, nbr_idx)
                        if deploys(table, g if aware[i, t] else xs, n, d):
                            total += g
                            nlog = select_point(q, xs, sel, p, xv, nbr_ptr, nbr_idx, log, nlog)
                            left[i] = d - 1
                    d = lefti[i]
                    if d > 0 and deploys(table, xs, n, d):
                        plain += xs
                        lefti[i] = d - 1
            undo_selection(sel, p, log, nlog)
            out[k, s] = total - plain


def predicted_aware(local: LocalView, comp: np.ndarray) -> np.ndarray:
    """bool ``[m, N]``: in a coordinated fleet, whether member ``comp[i]`` is predicted to hear,
    at stage t, the coordinator or another member with probability at least 1/2
    (:attr:`LocalView.contact`): one that hears nobody decides by its thresholds (the rule of a
    carrier cut off). All True without a prediction, and in a fleet without a coordinator,
    where a carrier that hears nobody still predicts its peers."""
    N = local.problem.n_stages
    if local.contact is None or not local.coordinated:
        return np.ones((len(comp), N), dtype=bool)
    senders = np.append(1 + np.asarray(comp), 0)
    heard = local.contact[:, senders][:, :, 1 + np.asarray(comp)]        # [N, senders, m]
    heard[:, np.arange(len(comp)), np.arange(len(comp))] = 0.0            # not itself
    return np.ascontiguousarray((heard >= 0.5).any(axis=1).T)


class DecClosedLoopPlanner:
    """``dec-closed-loop``: every carrier runs the closed-loop evaluation itself.

    Carrier r at stage j:

    * knows everything (all observations of stage j and all deployments before it reached it):
      it computes centralised closed-loop's joint action from the same view with the same stage
      stream — the joint action every fully informed carrier computes — and executes its own part.
      With perfect communication this *is* ``closed-loop``, decision for decision;
    * otherwise it searches its own conflict component: candidates are the joint actions of the
      members it knows (all ``2^k`` up to :data:`~planner.joint.ENUMERATE_MAX`, else its own
      two choices with the others at the conflict-aware SSAP action), and every carrier it has
      not heard from is *predicted by its known policy*: from its last known deployment on it
      follows its SSAP thresholds on observations drawn from the prior (its own where received).
      The sampled futures then run the conflict-aware SSAP rollout for all, with the plain-SSAP
      control variate, as in closed-loop. So a carrier that hears nobody still expects the
      others to deploy where their thresholds make it likely, and avoids the overlaps those
      deployments would crowd, instead of acting like plain SSAP. In a coordinated fleet, where
      the links predict that a member will hear nobody at a future stage
      (:attr:`LocalView.contact`), the sampled futures have it follow its plain thresholds there
      (the rule of a carrier cut off, below).
      A component of more than
      ``block`` carriers (default :data:`~planner.closedloop.BLOCK`) is cut down to the carrier's
      own block — the ``block`` carriers nearest it, breadth-first — and that block's halo, with
      the budget of the carriers searched (``iterations`` rollouts of them), so an on-board
      decision costs the same whatever the fleet's size.

    A component without conflicts is decided by SSAP (optimal there), and so is a carrier of a
    coordinated fleet (:attr:`LocalView.coordinated`) that knows the stage of none of its
    component's other members: cut off, it earns what SSAP alone would. Budget as closed-loop's:
    ``iterations`` full-fleet rollouts per decision, per carrier, or ``plan_ms`` milliseconds
    per carrier (sampled futures in batches until the time is spent; not bit-reproducible, and
    fully informed carriers then no longer share one joint action by construction). Publishes no intent (its policy
    is known in advance); it reads the histories that messages carry.
    """

    name = "dec-closed-loop"
    decentralised = True

    def __init__(self, iterations: int | None = None, plan_ms: float | None = None, block: int = BLOCK,
                 **_ignored):
        self.iterations, self.plan_ms = check_budget(iterations, plan_ms)
        self.block = int(block)
        self._central = ClosedLoopPlanner(iterations=self.iterations, plan_ms=self.plan_ms, block=self.block)
        self._memo = None  # (key, joint decision): fully informed carriers compute the same thing

    def warm_up(self, problem: Problem) -> None:
        self._central.warm_up(problem)
        tiny = warm_up_problem()
        xs = np.full((2, 3), 3.0)
        local = LocalView(tiny, 0, 1, 0, np.where([[1, 1, 0], [0, 0, 0]], xs, np.nan), np.zeros((2, 3), bool),
                          np.array([2, 0]), np.array([1, 0]), (None, None))
        self.decide_local(local, np.random.default_rng(0))

    def decide(self, view: StageView, rng: np.random.Generator) -> np.ndarray:
        """With full information: closed-loop's joint action."""
        return self._central.decide(view, rng)

    def decide_local(self, local: LocalView, rng: np.random.Generator) -> LocalDecision:
        can, must, n, d = local.own()
        if not can or must:
            return LocalDecision(bool(must))
        r, j = local.carrier, local.stage
        if local.problem.coverage is not None and not local.complete:
            # Coverage, partial information: closed-loop's coverage search on what this carrier
            # knows (carriers it has not heard from at stage j cannot act in its candidates; their
            # unheard deployments count as absent) and its own part of the best joint action.
            from planner.closedloop_cover import decide_cover

            return LocalDecision(bool(decide_cover(self._central, local.stage_view(), rng)[r]))
        if local.complete:
            view = local.stage_view()
            key = (id(local.problem), j, view.observations.tobytes(), view.deployed.tobytes(),
                   str(rng.bit_generator.state))
            if self._memo is None or self._memo[0] != key:
                self._memo = (key, enforce(view, self._central.decide(view, rng)))
            return LocalDecision(bool(self._memo[1][r]))
        scored = self.partial_scores(local, rng)
        if scored is None:  # no conflict can touch it (SSAP is optimal), or cut off from a coordinated fleet
            return LocalDecision(ssap.decide(compile_problem(local.problem).table, float(local.observations[r, j]),
                                             n, d))
        actions, score, me = scored
        return LocalDecision(bool(actions[int(np.argmax(score)), me]))

    def partial_scores(self, local: LocalView, rng):
        """The search behind a decision from partial information: ``(actions, score, me)`` —
        candidate joint actions ``[K, m]`` of the carriers searched, their estimated values
        (up to a common constant) and this carrier's column; None when no conflict can touch it."""
        problem = local.problem
        prep = compile_problem(problem)
        R, N = problem.valid.shape
        r, j = local.carrier, local.stage
        valid = np.ascontiguousarray(local.valid)
        nleft = valid_stages_left(valid)
        known = (local.seen >= j + 1) & (local.record >= j)
        start = np.where(known, j, local.record).astype(np.int64)
        left = (problem.passengers - local.deployed.sum(axis=1)).astype(np.int64)
        # Open points: from each carrier's first undecided (or unknown) stage on.
        open_ = valid & (left > 0)[:, None] & (np.arange(N)[None, :] >= start[:, None])
        past = local.deployed.ravel()
        flat = open_.ravel()
        adjacency = prep.links(flat, past)
        linked = adjacency | np.eye(R, dtype=bool)
        comp = next(c for c in conflict_components(linked) if r in c)
        if not adjacency[np.ix_(comp, comp)].any():
            return None
        if local.coordinated and not known[comp[comp != r]].any():
            # Cut off from a coordinated fleet: the coordinator plans a carrier it did not hear
            # as absent, so the peers' deployments ignore this carrier's, and it learns none of
            # them: they are not its SSAP-following peers of the search below. SSAP (the
            # dominance guarantee, docs/planner.md, "A carrier cut off").
            return None
        budget = R  # single-carrier trajectories: iterations x budget
        if self.block > 0 and len(comp) > self.block:
            # A large component: this carrier's block (the carriers nearest it) and its halo, with
            # the budget of the carriers it simulates, so the cost does not grow with the fleet.
            within = np.zeros(R, dtype=bool)
            within[comp] = True
            comp = block_halo(grow_block(r, adjacency, within, self.block), adjacency, within)
            budget = len(comp)

        xnow_all = np.nan_to_num(local.observations[:, j], nan=0.0)
        can_all = known & valid[:, j] & (left > 0)
        must_all = can_all & (nleft[:, j] <= left)
        free = can_all & ~must_all
        sel = past.copy()
        p = prep.penalties(sel)
        xpast = np.zeros((R, N))
        xpast[:, :j] = np.nan_to_num(local.observations[:, :j], nan=0.0)
        xv = np.where(local.deployed, xpast, 0.0).ravel()
        base = base_action(comp, j, prep, (sel, p, xv), nleft, left, xnow_all, must_all, free)
        free_idx = np.flatnonzero(free[comp])
        me = int(np.flatnonzero(comp == r)[0])
        k = len(free_idx)
        if k <= ENUMERATE_MAX:
            actions = every_combination(base, free_idx)
        else:
            actions = np.repeat(base[None, :], 2, axis=0)
            actions[1, me] = not actions[1, me]
        samples = int(np.clip(self.iterations * budget // max(len(comp) * len(actions), 1), SAMPLES_MIN,
                              SAMPLES_MAX))
        m = len(comp)
        deadline = None if self.plan_ms is None else time.perf_counter() + self.plan_ms / 1e3
        cand = Candidates(actions, comp, xnow_all[comp], left[comp])
        unknown = Unknown(known[comp], start[comp], left[comp], np.ascontiguousarray(local.observations),
                          predicted_aware(local, comp))
        net = Net(valid, nleft, prep.table, prep.indptr, prep.nbr)
        selection = Selection(sel, p, xv)

        def evaluate(batch):
            past_draws = prep.sampler.sample(rng, (batch, N, m))
            future = prep.sampler.sample(rng, (batch, N - j - 1, m))
            out = np.empty((len(actions), batch))
            _evaluate_imputed(cand, unknown, j, N, net, selection, past_draws, future, out)
            return out

        mean = sampled_mean(len(actions), samples, deadline, evaluate)
        # Exact plain-SSAP future of the known members after each candidate (the control
        # variate's expectation; the unknown members' is common to all candidates).
        kn = known[comp]
        d_after = np.minimum(left[comp][None, :] - actions.astype(np.int64), N)
        exact = (prep.slot_value[nleft[comp, j + 1][None, :], np.maximum(d_after, 0)] * kn[None, :]).sum(axis=1)
        return actions, mean + exact, me


cache_follows_sources(globals())  # the on-disk cache follows every planner source
