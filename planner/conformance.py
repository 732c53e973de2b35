"""Conformance kit of a planner plug-in: named checks on generated instances, each returning a
:class:`Check` with a named reason when it fails (docs/planner.md, "Writing a planner plug-in").

Pure: no command line (``python -m planner.conformance`` forwards to
:mod:`planner.cli.conformance`). :func:`check_planner` runs, in order:

* ``declaration``: the registry loads the plug-in and accepts its ``options`` declaration
  (``bad-declaration``);
* ``builds``: ``make_planner`` builds it with the given options (``raises``);
* ``feasible``: every decision of :func:`planner.online.run_online` on every instance of every
  family (:data:`FAMILIES`, seeded) is a bool ``[R]`` the rules allow: ``deploys-twice`` (a count
  of 2 or more for one carrier at a stage), ``beyond-passengers`` (a carrier with no passenger
  left), ``infeasible`` (wrong shape or values, an ∅ stage, a forced deployment left out),
  ``raises`` (an exception);
* ``deterministic``: the same seeds give the same decisions when the missions are flown again by
  the same planner object in the reverse order, with the global ``numpy.random`` and ``random``
  states moved (``nondeterministic``: state kept across decisions, or randomness other than the
  ``rng`` passed in);
* ``budget``: with ``plan_ms`` (when it uses it) every decision within :data:`BUDGET_FACTOR`
  times the budget plus :data:`BUDGET_SLACK_MS`; with ``iterations`` (when it uses it and shows
  ``last_iterations``) never more iterations than given (``over-budget``);
* ``options``: values outside each declared option's type or range, and an unknown option, are
  refused by the registry with a ValueError naming the plug-in and the option
  (``bad-option-accepted``);
* ``onboard``: when it offers ``decide_local``: every carrier's decision under a lossy, late
  communication model (:func:`planner.decentralised.run_comms`) follows the carrier's own rules,
  its intents are well formed, the same twice (``beyond-passengers``, ``infeasible``,
  ``bad-intent``, ``nondeterministic``, ``raises``).

The only randomness is the instances' (``SeedSequence(seed, spawn_key=(CONFORMANCE_SPAWN_KEY, f,
i))`` for family f's instance i) and the planner's stage streams (``stage_rng(seed, j)``).
"""
from __future__ import annotations

if __name__ == "__main__":  # a forward, first: this file's body runs once, under its own name
    from planner.cli.conformance import main

    raise SystemExit(main())

import contextlib
import math
import random
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

import numpy as np

from planner import registry
from planner.guard import (  # noqa: F401 (the kit's names)
    BUDGET_FACTOR, BUDGET_SLACK_MS, PlannerFault, Violation, budget_limit_ms, classify,
)
from planner.instance import Instance, random_instance

#: Spawn key of the kit's instances (family f, instance i: ``(CONFORMANCE_SPAWN_KEY, f, i)``).
CONFORMANCE_SPAWN_KEY = 4000
#: Budget of the ``plan_ms`` check, milliseconds per decision.
PLAN_MS = 20.0
#: Iterations of the ``iterations`` check.
ITERATIONS = 64
#: Every reason a check can fail with.
REASONS = ("bad-declaration", "raises", "infeasible", "deploys-twice", "beyond-passengers", "nondeterministic",
           "over-budget", "bad-option-accepted", "bad-intent")
#: Outcomes of a check.
PASS, FAIL, NOT_APPLICABLE = "pass", "fail", "not-applicable"


def _paper(rng: np.random.Generator) -> Instance:
    """The paper's size: R = 4, D = 3, N = 10, 20 overlap groups, Poisson(3)."""
    return random_instance(rng, carriers=4, passengers=3, stages=10, overlaps=20)


def _surprises(rng: np.random.Generator) -> Instance:
    """Uneven passengers (1, 2, 3), a quarter of the stages ∅ in advance, a tenth of the others ∅
    as online surprises (the planner learns them at the stage), sparse overlaps, self-conflicts."""
    inst = random_instance(rng, carriers=3, passengers=[1, 2, 3], stages=8, overlaps=6, invalid_fraction=0.25)
    x = inst.observations.copy()
    x[inst.problem.valid & (rng.random(x.shape) < 0.1)] = np.nan
    return Instance(inst.problem, x)


def _values(rng: np.random.Generator) -> Instance:
    """Passenger values (the released passenger matters): R = 3, D = 2, N = 6, 8 groups."""
    return random_instance(rng, carriers=3, passengers=2, stages=6, overlaps=8, weights=[[2.0, 1.0], [1.0, 1.0],
                                                                                          [3.0, 0.5]])


#: Instance families: name -> generator of one instance from a seeded generator.
FAMILIES: dict[str, Callable[[np.random.Generator], Instance]] = {
    "paper": _paper, "surprises": _surprises, "values": _values}


@dataclass(frozen=True)
class Check:
    """One named check's result: ``outcome`` pass, fail or not-applicable; ``reason`` one of
    :data:`REASONS` when it fails (else empty); ``detail`` one line."""

    name: str
    outcome: str
    reason: str = ""
    detail: str = ""

    def to_dict(self) -> dict:
        return {"name": self.name, "outcome": self.outcome, "reason": self.reason, "detail": self.detail}


@dataclass(frozen=True)
class Report:
    """Every check of one planner: ``passed`` when none failed."""

    planner: str
    options: Mapping[str, Any]
    seed: int
    instances: int
    checks: tuple[Check, ...] = field(default=())

    @property
    def passed(self) -> bool:
        return all(c.outcome != FAIL for c in self.checks)

    @property
    def failures(self) -> tuple[Check, ...]:
        return tuple(c for c in self.checks if c.outcome == FAIL)

    def to_dict(self) -> dict:
        return {"planner": self.planner, "options": dict(self.options), "seed": self.seed,
                "instances": self.instances, "families": list(FAMILIES), "passed": self.passed,
                "checks": [c.to_dict() for c in self.checks]}


def instances(seed: int, count: int) -> list[tuple[str, int, Instance]]:
    """``count`` instances of every family, ``(family, index, instance)``, from ``seed``."""
    out = []
    for f, (name, make) in enumerate(FAMILIES.items()):
        for i in range(count):
            rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(CONFORMANCE_SPAWN_KEY, f, i)))
            out.append((name, i, make(rng)))
    return out


class Recorder:
    """A planner seen through the kit: ``decide`` checked by :func:`classify` and timed, its
    ``last_iterations`` read after each decision; every other attribute is the planner's, but
    ``decide_local`` (so :func:`planner.online.run_online` runs it centrally)."""

    def __init__(self, planner):
        self._planner = planner
        self.decision_ms: list[float] = []
        self.iterations: list[int] = []

    def __getattr__(self, name: str):
        if name == "decide_local":
            raise AttributeError(name)
        return getattr(self._planner, name)

    def decide(self, view, rng):
        start = time.perf_counter()
        decision = self._planner.decide(view, rng)
        self.decision_ms.append((time.perf_counter() - start) * 1e3)
        count = getattr(self._planner, "last_iterations", None)
        if isinstance(count, (int, np.integer)):
            self.iterations.append(int(count))
        return classify(decision, view)


class LocalRecorder:
    """A decentralised planner seen through the kit: each ``decide_local`` checked against the
    carrier's own rules (:meth:`planner.decentralised.LocalView.own`) and its intent's shape."""

    def __init__(self, planner):
        self._planner = planner

    def __getattr__(self, name: str):
        return getattr(self._planner, name)

    def decide_local(self, local, rng):
        from planner.decentralised import Intent, LocalDecision

        out = self._planner.decide_local(local, rng)
        if not isinstance(out, (LocalDecision, bool, np.bool_)):
            raise Violation("infeasible", f"stage {local.stage}: carrier {local.carrier}'s decide_local returned "
                                          f"{type(out).__name__}, expected a LocalDecision or a bool")
        decision = LocalDecision.of(out)
        can, must, _, left = local.own()
        where = f"stage {local.stage}: carrier {local.carrier}"
        if decision.deploy and left <= 0:
            raise Violation("beyond-passengers", f"{where} deploys on board with no passenger left")
        if decision.deploy and not can:
            raise Violation("infeasible", f"{where} deploys on board at an empty (∅) stage")
        if must and not decision.deploy:
            raise Violation("infeasible", f"{where} must deploy on board and does not")
        intent = decision.intent
        if intent is not None:
            n_stages = local.problem.n_stages
            ok = isinstance(intent, Intent)
            if ok:
                seqs, probs = np.asarray(intent.sequences), np.asarray(intent.probs, dtype=float)
                ok = (seqs.ndim == 2 and seqs.shape[1] == n_stages and seqs.dtype == bool
                      and probs.shape == (seqs.shape[0],) and bool((probs >= 0).all())
                      and math.isclose(float(probs.sum()), 1.0, rel_tol=1e-9, abs_tol=1e-9))
            if not ok:
                raise Violation("bad-intent", f"{where}: expected an Intent with sequences bool [k, {n_stages}] "
                                              f"and probs [k] summing to 1")
        return decision


def _fly(planner, cases, seed: int, onboard: bool = False) -> list[np.ndarray]:
    """The deployments of every case, flown by ``planner`` (through the kit's recorders).

    Raises:
        Violation: a rule broken (``raises`` for an exception of the planner), naming the case.
    """
    from planner.online import run_online

    out = []
    for family, i, inst in cases:
        try:
            if onboard:
                from planner.comms import CommsSpec
                from planner.decentralised import run_comms

                result = run_comms(inst.problem, inst.observations, planner, seed, CommsSpec(loss=0.3, delay=1))
            else:
                result = run_online(inst.problem, inst.observations, planner, seed)
        except Violation as err:
            raise Violation(err.reason, f"{family} #{i}, {err.detail}") from None
        except PlannerFault as err:  # stage_step's check: the same rules, the same reasons
            text = err.detail if err.rule != "raises" else err.detail or "(no message)"
            raise Violation(err.rule, f"{family} #{i}, {text}") from None
        except Exception as err:  # the planner's own failure: named, one line
            text = " ".join(str(err).split()) or "(no message)"
            raise Violation("raises", f"{family} #{i}: {type(err).__name__}: {text}") from None
        out.append(result.deployed)
    return out


@contextlib.contextmanager
def _global_random(seed: int):
    """The global ``numpy.random`` and ``random`` states set from ``seed`` for the block, restored
    after it: a planner drawing from them (not from its ``rng``) decides differently per flight."""
    saved = np.random.get_state(), random.getstate()
    np.random.seed(seed)
    random.seed(seed)
    try:
        yield
    finally:
        np.random.set_state(saved[0])
        random.setstate(saved[1])


def _same(first: list[np.ndarray], second: list[np.ndarray], cases) -> str:
    """Where two flights of the cases first differ ("" when they do not)."""
    for (family, i, _), a, b in zip(cases, first, second):
        if not np.array_equal(a, b):
            stage = int(np.flatnonzero((a != b).any(axis=0))[0])
            return f"{family} #{i}: different decisions at stage {stage} for the same seed"
    return ""


def _bad_values(option: registry.Option) -> list[Any]:
    """Values outside an option's declared type or range."""
    if option.choices:
        return ["not-a-choice", 3]
    if option.kind is bool:
        return ["maybe", 2]
    out: list[Any] = ["text", float("nan"), True]
    if option.kind is int:
        out.append(1.5)
    if option.minimum is not None:
        out.append(option.minimum if option.exclusive else option.minimum - 1)
    if option.maximum is not None:
        out.append(option.maximum + 1)
    return out


def _check_options(name: str, entry: registry.PlannerEntry, options: Mapping[str, Any]) -> Check:
    used = [registry.OPTIONS[o] for o in entry.options] + list(entry.own)
    tried = 0
    for option in used:
        for value in _bad_values(option):
            tried += 1
            try:
                registry.make_planner(name, **{**options, option.name: value})
            except ValueError as err:
                text = str(err)
                if entry.plugin and (name not in text or option.name not in text):
                    return Check("options", FAIL, "bad-option-accepted",
                                 f"{option.name}={value!r} refused without naming the plug-in and the option: {text}")
                continue
            except Exception as err:
                return Check("options", FAIL, "bad-option-accepted",
                             f"{option.name}={value!r} reached the factory, which raised {type(err).__name__}")
            return Check("options", FAIL, "bad-option-accepted",
                         f"{option.name}={value!r} accepted (expected {option.expected()})")
    try:
        registry.make_planner(name, **{**options, "no_such_option": 1})
    except ValueError:
        pass
    else:
        return Check("options", FAIL, "bad-option-accepted", "an unknown option 'no_such_option' accepted")
    if not used:
        return Check("options", PASS, detail="no options declared; an unknown option refused")
    return Check("options", PASS, detail=f"{tried} bad values of {len(used)} options and an unknown option refused")


def _check_budget(name: str, entry: registry.PlannerEntry, options: Mapping[str, Any], cases, seed: int) -> Check:
    timed = cases[::max(1, len(cases) // len(FAMILIES))][: len(FAMILIES)]  # one instance per family
    notes = []
    if "plan_ms" in entry.options:
        recorder = Recorder(registry.make_planner(name, **{**options, "plan_ms": PLAN_MS}))
        try:
            _fly(recorder, timed, seed)
        except Violation as err:
            return Check("budget", FAIL, err.reason, f"under plan_ms={PLAN_MS:g}: {err.detail}")
        worst = max(recorder.decision_ms)
        limit = budget_limit_ms(PLAN_MS)
        if worst > limit:
            return Check("budget", FAIL, "over-budget", f"plan_ms={PLAN_MS:g}: a decision took {worst:.1f} ms, more "
                                                        f"than {BUDGET_FACTOR:g} x the budget + {BUDGET_SLACK_MS:g} ms")
        notes.append(f"plan_ms={PLAN_MS:g}: slowest decision {worst:.1f} ms of {limit:g}")
    if "iterations" in entry.options:
        recorder = Recorder(registry.make_planner(name, **{**{k: v for k, v in options.items() if k != "plan_ms"},
                                                          "iterations": ITERATIONS}))
        try:
            _fly(recorder, timed, seed)
        except Violation as err:
            return Check("budget", FAIL, err.reason, f"under iterations={ITERATIONS}: {err.detail}")
        if recorder.iterations:
            most = max(recorder.iterations)
            if most > ITERATIONS:
                return Check("budget", FAIL, "over-budget", f"iterations={ITERATIONS}: a decision ran {most} iterations")
            notes.append(f"iterations={ITERATIONS}: at most {most} per decision")
        else:
            notes.append("iterations: not observable (no last_iterations)")
    if not notes:
        return Check("budget", NOT_APPLICABLE, detail="uses neither plan_ms nor iterations")
    return Check("budget", PASS, detail="; ".join(notes))


def check_planner(name: str, options: Mapping[str, Any] | None = None, seed: int = 0, count: int = 2) -> Report:
    """Every check of the planner ``name`` (a plug-in's entry-point name or
    ``package.module:Factory``, or a built-in) built with ``options``, on ``count`` instances of
    each family from ``seed``.

    Raises:
        planner.registry.PluginNotFound: the name does not load (the caller's usage error).
        ValueError: an unknown name, or ``options`` the registry refuses (the caller's usage error).
    """
    options = dict(options or {})
    try:
        entry = registry.entry(name)
    except registry.PluginNotFound:
        raise
    except registry.PluginError as err:
        return Report(name, options, seed, count, (Check("declaration", FAIL, "bad-declaration", str(err)),))
    checks = [Check("declaration", PASS, detail=f"options {', '.join(entry.options + tuple(o.name for o in entry.own)) or '(none)'}")]
    registry.used_options(name, options)  # a bad option given to the kit: the caller's ValueError
    try:
        planner = registry.make_planner(name, **options)
    except Exception as err:
        checks.append(Check("builds", FAIL, "raises", f"{type(err).__name__}: {' '.join(str(err).split())}"))
        return Report(name, options, seed, count, tuple(checks))
    checks.append(Check("builds", PASS, detail=f"{type(planner).__name__}"))
    cases = instances(seed, count)
    recorder = Recorder(planner)
    try:
        with _global_random(seed + 1):
            first = _fly(recorder, cases, seed)
    except Violation as err:
        checks.append(Check("feasible", FAIL, err.reason, err.detail))
        return Report(name, options, seed, count, tuple(checks))
    checks.append(Check("feasible", PASS, detail=f"{len(cases)} missions ({', '.join(FAMILIES)}), "
                                                 f"{len(recorder.decision_ms)} decisions"))
    try:
        # Flown again in the reverse order by the same object: state carried from one decision or
        # mission to the next shows, as does randomness drawn from the global states.
        with _global_random(seed + 2):
            again = _fly(recorder, cases[::-1], seed)[::-1]
        where = _same(first, again, cases)
    except Violation as err:
        where = f"flown again: {err.detail}"
    checks.append(Check("deterministic", FAIL, "nondeterministic", where) if where
                  else Check("deterministic", PASS, detail="the same decisions flown again in the reverse order, "
                                                           "global random states moved"))
    checks.append(_check_budget(name, entry, options, cases, seed))
    checks.append(_check_options(name, entry, options))
    checks.append(_check_onboard(planner, cases, seed))
    return Report(name, options, seed, count, tuple(checks))


def _check_onboard(planner, cases, seed: int) -> Check:
    if not callable(getattr(planner, "decide_local", None)):
        return Check("onboard", NOT_APPLICABLE, detail="no decide_local: a carrier deciding alone runs "
                                                       "planner.settings.ONBOARD_PLANNER")
    recorder = LocalRecorder(planner)
    try:
        first = _fly(recorder, cases, seed, onboard=True)
        again = _fly(recorder, cases, seed, onboard=True)
    except Violation as err:
        return Check("onboard", FAIL, err.reason, f"on board: {err.detail}")
    where = _same(first, again, cases)
    if where:
        return Check("onboard", FAIL, "nondeterministic", f"on board: {where}")
    return Check("onboard", PASS, detail=f"{len(cases)} missions under loss 0.3 and delay 1: carriers' rules kept")
