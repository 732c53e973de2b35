"""Planner names, their options, defaults and validation: the one home for planner settings.

Scenario files (``planner:`` block), the solve command, ``run_fleet.py`` and the experiments all
take names and options from here:

* :func:`planner_names` — every registered planner; :func:`register` adds one;
* :data:`OPTIONS` — every option with its type, range, default and help text
  (their defaults and choice lists are defined once in :mod:`planner.settings`);
* :func:`check_settings` — validates a name and an options mapping, returning
  :class:`SettingProblem` entries with field paths (``layout``, ``iterations``, ...) that callers
  turn into their own one-line errors; :func:`parse_option` reads ``KEY=VALUE`` text;
* :func:`make_planner` — builds a planner (heavy modules are imported lazily, on first use).

Every planner follows :class:`planner.problem.Planner`. A planner uses only the options listed
in its :class:`PlannerEntry`; the others are accepted and ignored (a scenario may switch planner
without editing its budget). The :data:`GENERIC_OPTIONS` (``learn_prior``) apply to every
planner: :func:`make_planner` wraps the planner it built.
"""
from __future__ import annotations

import difflib
import math
from dataclasses import dataclass
from typing import Any, Callable, Mapping

# The defaults are defined in planner.settings (below the planners); DEFAULT_PLANNER and the others
# stay importable from here for the registry's callers.
from planner.settings import DEFAULT_EXPLORATION, DEFAULT_ITERATIONS, DEFAULT_PLANNER, DEFAULT_SAMPLES, LAYOUTS  # noqa: F401

#: Command-line spellings of a ``bool`` option's values.
_BOOL_TEXT = {"true": True, "false": False, "1": True, "0": False, "yes": True, "no": False}


@dataclass(frozen=True)
class Option:
    """One planner option.

    Attributes:
        name: keyword of :func:`make_planner` (``plan_ms`` on the command line is ``--plan-ms``).
        kind: ``int``, ``float``, ``str`` or ``bool``.
        default: value used when the option is not given (``None``: "not set", e.g. ``plan_ms``).
        minimum, maximum: inclusive range for numbers (``exclusive``: minimum excluded).
        choices: allowed values of a ``str`` option.
        help: one line, with units.
    """

    name: str
    kind: type
    default: Any
    help: str
    minimum: float | None = None
    exclusive: bool = False
    maximum: float | None = None
    choices: tuple[str, ...] = ()

    def expected(self) -> str:
        """The "expected ..." text of an error about this option."""
        if self.choices:
            return f"one of {', '.join(self.choices)}"
        if self.kind is bool:
            return "true or false"
        text = "an integer" if self.kind is int else "a number"
        if self.minimum is not None:
            text += f" {'>' if self.exclusive else '>='} {self.minimum:g}"
        if self.maximum is not None:
            text += f"{' and' if self.minimum is not None else ''} <= {self.maximum:g}"
        return text

    def parse(self, text: str) -> Any:
        """Command-line text -> checked value (``true``/``false``, ``1``/``0``, ``yes``/``no``
        for a ``bool`` option); raises ValueError with :meth:`expected`."""
        value: Any = text.strip()
        if self.kind is bool:
            value = _BOOL_TEXT.get(value.lower(), value)
        elif self.kind in (int, float):
            try:
                value = self.kind(value)
            except ValueError:
                raise ValueError(self.expected()) from None
        return self.check(value)

    def check(self, value: Any) -> Any:
        """The value normalised (ints as int, numbers as float); raises ValueError with
        :meth:`expected` when it is out of type or range."""
        if self.choices:
            if not isinstance(value, str) or value not in self.choices:
                raise ValueError(self.expected())
            return value
        if self.kind is bool:
            if not isinstance(value, bool):
                raise ValueError(self.expected())
            return value
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ValueError(self.expected())
        if self.kind is int and not float(value).is_integer():
            raise ValueError(self.expected())
        if self.minimum is not None and (value <= self.minimum if self.exclusive else value < self.minimum):
            raise ValueError(self.expected())
        if self.maximum is not None and value > self.maximum:
            raise ValueError(self.expected())
        return int(value) if self.kind is int else float(value)


#: Every planner option, in the order they are documented.
OPTIONS: dict[str, Option] = {o.name: o for o in (
    Option("iterations", int, DEFAULT_ITERATIONS, "iterations (full-fleet rollouts) per decision",
           minimum=1, maximum=1e9),
    Option("plan_ms", float, None, "time budget per decision, milliseconds (anytime; replaces iterations)",
           minimum=0, exclusive=True),
    Option("exploration", float, DEFAULT_EXPLORATION, "UCT constant c on normalised rewards (default 0.05*sqrt(2))",
           minimum=0),
    Option("samples", int, DEFAULT_SAMPLES, "Monte Carlo rollouts per iteration", minimum=1, maximum=1e6),
    Option("layout", str, LAYOUTS[0], "MCTS tree: auto (joint up to 8 carriers), joint or binary", choices=LAYOUTS),
    Option("learn_prior", bool, False, "learn the prior online from the observations so far (planner.learning); "
           "applies to every planner"),
)}
#: Options every planner takes, applied by :func:`make_planner` around the planner it builds
#: (``learn_prior``: :class:`planner.learning.LearnedPriorPlanner`).
GENERIC_OPTIONS = ("learn_prior",)


@dataclass(frozen=True)
class PlannerEntry:
    """A registered planner: ``factory(**options)`` receives only the ``options`` it uses."""

    name: str
    factory: Callable[..., object]
    options: tuple[str, ...] = ()


#: name -> entry. Filled by :func:`register` below and by other modules.
_REGISTRY: dict[str, PlannerEntry] = {}


def register(name: str, factory: Callable[..., object], options: tuple[str, ...] | None = None) -> None:
    """Make ``make_planner(name, **options)`` return ``factory(**used)``.

    ``options``: the option names the planner uses (all of :data:`OPTIONS` when None); ``used``
    holds those the caller gave (not None). Re-registering a name replaces it.
    """
    if not isinstance(name, str) or not name:
        raise ValueError(f"planner name must be a non-empty string, got {name!r}")
    used = tuple(o for o in OPTIONS if o not in GENERIC_OPTIONS) if options is None else tuple(options)
    unknown = sorted(set(used) - set(OPTIONS))
    if unknown:
        raise ValueError(f"unknown planner option(s) {unknown}; expected some of: {', '.join(OPTIONS)}")
    _REGISTRY[name] = PlannerEntry(name, factory, used)


def planner_names() -> tuple[str, ...]:
    """Registered planner names, sorted."""
    return tuple(sorted(_REGISTRY))


def defaults() -> dict[str, Any]:
    """Every option's default (``plan_ms``: None)."""
    return {name: opt.default for name, opt in OPTIONS.items()}


@dataclass(frozen=True)
class SettingProblem:
    """One thing wrong with planner settings: ``field`` is ``"name"`` or an option name."""

    field: str
    expected: str
    found: Any


def check_settings(name: Any, options: Mapping[str, Any]) -> list[SettingProblem]:
    """Everything wrong with a planner name and its options (``None`` values mean "default");
    empty when they are fine."""
    problems = []
    names = tuple(_REGISTRY)  # registration order: the paper's planners first
    if not isinstance(name, str) or name not in names:
        close = difflib.get_close_matches(str(name), names, n=1, cutoff=0.5)
        hint = f" (did you mean '{close[0]}'?)" if close else ""
        problems.append(SettingProblem("name", f"one of {', '.join(names)}{hint}", name))
    for key, value in options.items():
        opt = OPTIONS.get(key)
        if opt is None:
            problems.append(SettingProblem(key, f"a planner option ({', '.join(OPTIONS)})", value))
            continue
        if value is None:
            continue
        try:
            opt.check(value)
        except ValueError as err:
            problems.append(SettingProblem(key, str(err), value))
    return problems


def parse_option(text: str) -> tuple[str, Any]:
    """``KEY=VALUE`` (command-line ``--planner-option``) -> (key, checked value).

    Raises:
        ValueError: one line, e.g. ``layout: expected one of auto, joint, binary, found 'tree'``.
    """
    key, sep, raw = text.partition("=")
    key = key.strip().replace("-", "_")
    if not sep or key not in OPTIONS:
        raise ValueError(f"expected KEY=VALUE with KEY one of {', '.join(OPTIONS)}, found {text!r}")
    try:
        return key, OPTIONS[key].parse(raw)
    except ValueError as err:
        raise ValueError(f"{key}: expected {err}, found {raw!r}") from None


def make_planner(name: str, **options) -> object:
    """Build a planner by name.

    Args:
        name: one of :func:`planner_names`.
        **options: any of :data:`OPTIONS`; ``None`` values mean "default". Options the planner
            does not use are ignored.

    Raises:
        ValueError: unknown name (the message lists the valid names), unknown option, or a value
            out of type or range (one line naming the option).
    """
    used = used_options(name, options)
    learn = used.pop("learn_prior", False)
    planner = _REGISTRY[name].factory(**used)
    if learn:
        from planner.learning import LearnedPriorPlanner

        planner = LearnedPriorPlanner(planner)
    return planner


def planner_settings(scenario, name=None, iterations=None, plan_ms=None, extra=()) -> tuple[str, dict]:
    """(planner name, options for make_planner): the scenario's (``scenario.planner``), overridden
    by non-None flags.

    An explicit ``iterations`` flag drops the scenario's ``plan_ms`` (which would take
    precedence), so ``--iterations`` always means an iteration budget.
    """
    spec = scenario.planner
    options = dict(spec.options())
    if iterations is not None:
        options["iterations"] = int(iterations)
        options.pop("plan_ms", None)
    if plan_ms is not None:
        options["plan_ms"] = float(plan_ms)
    options.update(dict(extra))  # --planner-option KEY=VALUE (checked by planner.registry)
    return (name or spec.name), options


def used_options(name: str, options: Mapping[str, Any]) -> dict[str, Any]:
    """The options planner ``name`` uses, checked: the others, and ``None`` values, are dropped.

    Raises:
        ValueError: unknown name or option, or a value out of type or range (one line).
    """
    entry = _REGISTRY.get(name)
    if entry is None:
        raise ValueError(f"unknown planner {name!r}; expected one of: {', '.join(planner_names())}")
    unknown = sorted(set(options) - set(OPTIONS))
    if unknown:
        raise ValueError(f"unknown planner option(s) {unknown}; expected some of: {', '.join(OPTIONS)}")
    used = {}
    for key, value in options.items():
        if value is None or (key not in entry.options and key not in GENERIC_OPTIONS):
            continue
        try:
            used[key] = OPTIONS[key].check(value)
        except ValueError as err:
            raise ValueError(f"{key} must be {err}, got {value!r}") from None
    if used.get("learn_prior") is False:
        used.pop("learn_prior")  # the default: today's planner exactly, and today's recorded options
    return used


# ----------------------------------------------------------------------------- the planners
# Factories import their modules lazily: the MCTS and closed-loop modules load numba kernels.


def _random(**_):
    from planner.policies import RandomPlanner

    return RandomPlanner()


def _ssap(**_):
    from planner.policies import SSAPPlanner

    return SSAPPlanner()


def _mcts(rollout: str) -> Callable[..., object]:
    def factory(**options):
        from planner.mcts.fast import MCTSPlanner

        return MCTSPlanner(rollout=rollout, **options)

    return factory


def _closed_loop(**options):
    from planner.closedloop import ClosedLoopPlanner  # see docs/results.md

    return ClosedLoopPlanner(**options)


def _dec_mcts(**options):
    from planner.decmcts import DecMCTSPlanner  # decentralised: see planner/decentralised.py

    return DecMCTSPlanner(**options)


def _dec_closed_loop(**options):
    from planner.decentralised import DecClosedLoopPlanner

    return DecClosedLoopPlanner(**options)


def _online_optimal(**_):
    # The exact Bayes-optimal policy for small instances; budget options do not apply to it.
    from planner.online_optimal import OnlineOptimalPlanner

    return OnlineOptimalPlanner()


_MCTS_OPTIONS = ("iterations", "plan_ms", "exploration", "samples", "layout")
register("random", _random, options=())
register("ssap", _ssap, options=())
register("mcts-random", _mcts("random"), options=_MCTS_OPTIONS)
register("mcts-ssap", _mcts("ssap"), options=_MCTS_OPTIONS)
register("closed-loop", _closed_loop, options=("iterations", "plan_ms"))
register("online-optimal", _online_optimal, options=())
# Decentralised planners (each carrier decides on board; ``decide_local``): run them under a
# communication model with planner.decentralised.run_comms (run_online does so with perfect links).
register("dec-mcts", _dec_mcts, options=("iterations", "plan_ms", "exploration"))
register("dec-closed-loop", _dec_closed_loop, options=("iterations", "plan_ms"))
