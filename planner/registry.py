"""Planner names, their options, defaults and validation: the one home for planner settings.

Scenario files (``planner:`` block), the solve command, ``run_fleet.py`` and the experiments all
take names and options from here:

* :func:`planner_names` — every registered planner; :func:`register` adds one;
* :data:`OPTIONS` — every option with its type, range, default and help text
  (their defaults and choice lists are defined once in :mod:`planner.settings`);
* :func:`check_settings` — validates a name and an options mapping, returning
  :class:`validation.Flaw` entries with field paths (``layout``, ``iterations``, ...) that callers
  turn into their own one-line errors; :func:`parse_option` reads ``KEY=VALUE`` text;
* :func:`make_planner` — builds a planner (heavy modules are imported lazily, on first use).

Every planner follows :class:`planner.problem.Planner`. A planner uses only the options listed
in its :class:`PlannerEntry`; the others are accepted and ignored (a scenario may switch planner
without editing its budget). The :data:`GENERIC_OPTIONS` (``learn_prior``) apply to every
planner: :func:`make_planner` wraps the planner it built.

Plug-ins (docs/planner.md, "Writing a planner plug-in"): a name that is not registered is looked
up, on first use, as an entry point of the group :data:`ENTRY_POINT_GROUP` of the installed
packages, or imported when it has the form ``package.module:Factory``. The factory declares its
options in an ``options`` attribute: its own :class:`Option` entries and the names of the built-in
options it uses; the registry checks the declaration, the values, and names the plug-in in its
errors. Nothing of a plug-in (nor ``importlib.metadata``) is loaded until a name needs it.
"""
from __future__ import annotations

import keyword
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Mapping

# The defaults are defined in planner.settings (below the planners); DEFAULT_PLANNER and the others
# stay importable from here for the registry's callers.
from validation import Check, Choice, Flag, Number, Flaw, did_you_mean
from planner.settings import DEFAULT_EXPLORATION, DEFAULT_ITERATIONS, DEFAULT_PLANNER, DEFAULT_SAMPLES, LAYOUTS  # noqa: F401

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

    @property
    def spec(self) -> Check:
        """The option's declarative check (:mod:`validation`): its type, range or choices."""
        if self.choices:
            return Choice(self.choices)
        if self.kind is bool:
            return Flag()
        return Number(integer=self.kind is int, minimum=self.minimum, maximum=self.maximum, exclusive=self.exclusive)

    def expected(self) -> str:
        """The "expected ..." text of an error about this option."""
        return self.spec.expected()

    def parse(self, text: str) -> Any:
        """Command-line text -> checked value (``true``/``false``, ``1``/``0``, ``yes``/``no``
        for a ``bool`` option); raises ValueError (:class:`validation.Invalid`) with :meth:`expected`."""
        return self.spec.parse(text)

    def check(self, value: Any) -> Any:
        """The value normalised (ints as int, numbers as float); raises ValueError
        (:class:`validation.Invalid`) with :meth:`expected` when it is out of type or range."""
        return self.spec.check(value)


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


#: The entry-point group through which an installed package adds planners (pyproject.toml:
#: ``[project.entry-points."marsupial_fleet.planners"]`` ``NAME = "package.module:Factory"``).
ENTRY_POINT_GROUP = "marsupial_fleet.planners"
#: Option kinds a plug-in's own :class:`Option` may have.
OPTION_KINDS = (int, float, str, bool)


class PluginError(ValueError):
    """A planner plug-in that cannot be loaded, or declares its options wrongly. ``str(err)`` is
    one line naming the plug-in."""


class PluginNotFound(PluginError):
    """A plug-in name that does not load: a malformed dotted path, a module that does not import,
    a missing attribute, an entry point that fails to load."""


@dataclass(frozen=True)
class PlannerEntry:
    """A registered planner: ``factory(**options)`` receives only the ``options`` it uses.

    Attributes:
        name: the name callers give (a built-in's, an entry point's, or ``package.module:Factory``).
        factory: builds the planner.
        options: the built-in options (:data:`OPTIONS`) it uses.
        own: its own options (a plug-in's), each an :class:`Option`; the factory receives every one
            of them, the default where the caller gave none.
        plugin: loaded from outside the package (an entry point or a dotted path): errors about
            its options name it.
    """

    name: str
    factory: Callable[..., object]
    options: tuple[str, ...] = ()
    own: tuple[Option, ...] = ()
    plugin: bool = False

    def option(self, key: str) -> Option | None:
        """The option ``key`` as this planner knows it (a built-in or its own), or None."""
        return OPTIONS.get(key) or next((o for o in self.own if o.name == key), None)

    def known(self) -> tuple[str, ...]:
        """Every option name this planner accepts: the built-ins, then its own."""
        return (*OPTIONS, *(o.name for o in self.own))


#: name -> entry. Filled by :func:`register` below and by other modules.
_REGISTRY: dict[str, PlannerEntry] = {}
#: name -> entry of the plug-ins loaded so far (entry points and dotted paths), on first use.
_PLUGINS: dict[str, PlannerEntry] = {}


def declared_options(who: str, items: Iterable[Any]) -> tuple[tuple[str, ...], tuple[Option, ...]]:
    """A planner's option declaration, checked: ``(built-in names it uses, its own options)``.

    ``items``: built-in option names (``"iterations"``, ``"plan_ms"``, ...) and :class:`Option`
    entries of its own (a name that is not a built-in's, a kind of :data:`OPTION_KINDS`, a
    default its own check accepts, or None).

    Raises:
        PluginError: one line naming ``who`` and the item (``options[i]``).
    """
    if isinstance(items, (str, Option)) or not isinstance(items, Iterable):
        raise PluginError(f"planner {who!r}: options: expected a sequence of built-in option names and "
                          f"Option entries, found {items!r}")
    builtin: list[str] = []
    own: list[Option] = []
    for i, item in enumerate(items):
        where = f"planner {who!r}: options[{i}]"
        if isinstance(item, str):
            if item not in OPTIONS:
                raise PluginError(f"{where}: expected a built-in option name ({', '.join(OPTIONS)}) or an "
                                  f"Option, found {item!r}")
            if item not in builtin and item not in GENERIC_OPTIONS:
                builtin.append(item)
            continue
        if not isinstance(item, Option):
            raise PluginError(f"{where}: expected a built-in option name ({', '.join(OPTIONS)}) or an "
                              f"Option of planner.registry, found {item!r}")
        if not isinstance(item.name, str) or not item.name.isidentifier() or keyword.iskeyword(item.name):
            raise PluginError(f"{where}: expected an option name that is a Python identifier, found {item.name!r}")
        if item.name in OPTIONS or item.name == "name" or any(o.name == item.name for o in own):
            raise PluginError(f"{where}: expected a new option name (not 'name', a built-in's or a "
                              f"repeated one), found {item.name!r}")
        if item.kind not in OPTION_KINDS:
            raise PluginError(f"{where} ({item.name}): expected a kind among int, float, str, bool, "
                              f"found {item.kind!r}")
        if item.kind is str and not item.choices:
            raise PluginError(f"{where} ({item.name}): expected choices for a str option, found none")
        if item.default is not None:
            try:
                item.check(item.default)
            except ValueError as err:
                raise PluginError(f"{where} ({item.name}): default {item.default!r} is not {err}") from None
        own.append(item)
    return tuple(builtin), tuple(own)


def register(name: str, factory: Callable[..., object], options: Iterable[Any] | None = None) -> None:
    """Make ``make_planner(name, **options)`` return ``factory(**used)``.

    ``options``: the option names the planner uses (all of :data:`OPTIONS` when None) and
    :class:`Option` entries of its own (see :func:`declared_options`); ``used`` holds the built-in
    ones the caller gave (not None) and every own option (its default when not given).
    Re-registering a name replaces it.
    """
    if not isinstance(name, str) or not name:
        raise ValueError(f"planner name must be a non-empty string, got {name!r}")
    if options is None:
        options = tuple(o for o in OPTIONS if o not in GENERIC_OPTIONS)
    unknown = sorted(o for o in options if isinstance(o, str) and o not in OPTIONS)
    if unknown:
        raise ValueError(f"unknown planner option(s) {unknown}; expected some of: {', '.join(OPTIONS)}")
    used, own = declared_options(name, options)
    _REGISTRY[name] = PlannerEntry(name, factory, used, own)


def _entry_points() -> dict[str, Any]:
    """Name -> entry point of :data:`ENTRY_POINT_GROUP` among the installed distributions (read
    from their metadata when called: importlib.metadata is not loaded with the registry)."""
    from importlib.metadata import entry_points

    return {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}


def _load_factory(name: str) -> Callable[..., object]:
    """The factory of a plug-in name: ``package.module:Factory`` imported, or an entry point loaded.

    Raises:
        PluginNotFound: a malformed dotted path, or an import that fails (one line).
        PluginError: the target is not callable.
        KeyError: no entry point of that name (the caller reports the known names).
    """
    import importlib

    if ":" in name:
        module, _, attr = name.partition(":")
        if not all(part.isidentifier() for part in module.split(".")) or not all(
                part.isidentifier() for part in attr.split(".")):
            raise PluginNotFound(f"planner {name!r}: expected package.module:Factory (dotted names), found {name!r}")
        try:
            target: Any = importlib.import_module(module)
        except Exception as err:  # the plug-in's own import errors too: one line either way
            raise PluginNotFound(f"planner {name!r}: cannot import {module}: {type(err).__name__}: {err}") from None
        for part in attr.split("."):
            if not hasattr(target, part):
                raise PluginNotFound(f"planner {name!r}: module {module} has no attribute {attr!r}")
            target = getattr(target, part)
    else:
        point = _entry_points()[name]
        try:
            target = point.load()
        except Exception as err:
            raise PluginNotFound(f"planner {name!r}: cannot load entry point {point.value} of "
                              f"{ENTRY_POINT_GROUP}: {type(err).__name__}: {err}") from None
    if not callable(target):
        raise PluginError(f"planner {name!r}: expected a callable factory, found {type(target).__name__}")
    return target


def entry(name: Any) -> PlannerEntry:
    """The :class:`PlannerEntry` of a name: a registered planner, else a plug-in (loaded and its
    declaration checked on first use, then kept).

    Raises:
        PluginError: a plug-in that cannot be loaded or declares its options wrongly (one line).
        ValueError: an unknown name; the message lists the known names.
    """
    if isinstance(name, str):
        found = _REGISTRY.get(name) or _PLUGINS.get(name)
        if found is not None:
            return found
    if not isinstance(name, str) or not name or (":" not in name and name not in _entry_points()):
        names = sorted(known_names())
        raise ValueError(f"unknown planner {name!r}{did_you_mean(name, names, cutoff=0.5)}; expected one of: "
                         f"{', '.join(names)} (or package.module:Factory)")
    factory = _load_factory(name)
    used, own = declared_options(name, getattr(factory, "options", ()))
    found = _PLUGINS[name] = PlannerEntry(name, factory, used, own, plugin=True)
    return found


def is_planner(name: Any) -> bool:
    """Whether :func:`make_planner` takes ``name``: registered, or a plug-in that loads."""
    try:
        entry(name)
    except ValueError:
        return False
    return True


def known_names() -> tuple[str, ...]:
    """The registered planners (registration order) and the installed plug-ins' entry-point names
    (sorted): every name but a dotted path that :func:`make_planner` accepts."""
    return (*_REGISTRY, *sorted(set(_entry_points()) - set(_REGISTRY)))


def planner_names() -> tuple[str, ...]:
    """Registered planner names, sorted."""
    return tuple(sorted(_REGISTRY))


def defaults() -> dict[str, Any]:
    """Every option's default (``plan_ms``: None)."""
    return {name: opt.default for name, opt in OPTIONS.items()}


def check_settings(name: Any, options: Mapping[str, Any]) -> list[Flaw]:
    """Everything wrong with a planner name and its options (``None`` values mean "default");
    empty when they are fine. A plug-in's name is loaded to know its options; a plug-in's
    problems name it."""
    problems = []
    found = None
    try:
        found = entry(name)
    except PluginError as err:
        problems.append(Flaw("name", f"a loadable planner plug-in ({err})", name))
    except ValueError:
        names = known_names()
        problems.append(Flaw("name", f"one of {', '.join(names)}{did_you_mean(name, names, cutoff=0.5)}", name))
    whose = f" (an option of planner {name!r})" if found is not None and found.plugin else ""
    for key, value in options.items():
        opt = OPTIONS.get(key) if found is None else found.option(key)
        if opt is None:
            known = OPTIONS if found is None else found.known()
            problems.append(Flaw(key, f"a planner option ({', '.join(known)}){whose}{did_you_mean(key, known)}",
                                    value))
            continue
        if value is None:
            continue
        try:
            opt.check(value)
        except ValueError as err:
            problems.append(Flaw(key, f"{err}{whose}", value))
    return problems


def parse_option(text: str, name: str | None = None) -> tuple[str, Any]:
    """``KEY=VALUE`` (command-line ``--planner-option``) -> (key, checked value). With ``name``,
    the options of that planner (a plug-in's own ones included) are accepted.

    Raises:
        ValueError: one line, e.g. ``layout: expected one of auto, joint, binary, found 'tree'``.
    """
    key, sep, raw = text.partition("=")
    key = key.strip().replace("-", "_")
    found = None if name is None else entry(name)
    opt = OPTIONS.get(key) if found is None else found.option(key)
    if not sep or opt is None:
        known = OPTIONS if found is None else found.known()
        hint = did_you_mean(key, known) if sep else ""
        raise ValueError(f"expected KEY=VALUE with KEY one of {', '.join(known)}, found {text!r}{hint}")
    try:
        return key, opt.parse(raw)
    except ValueError as err:
        whose = f" (an option of planner {name!r})" if found is not None and found.plugin else ""
        raise ValueError(f"{key}: expected {err}{whose}, found {raw!r}") from None


def make_planner(name: str, **options: Any) -> object:
    """Build a planner by name.

    Args:
        name: one of :func:`known_names`, or a plug-in's ``package.module:Factory``.
        **options: any of :data:`OPTIONS` and the planner's own options; ``None`` values mean
            "default". Built-in options the planner does not use are ignored.

    Raises:
        PluginError: a plug-in that cannot be loaded or declares its options wrongly (one line).
        ValueError: unknown name (the message lists the valid names), unknown option, or a value
            out of type or range (one line naming the option, and the plug-in for a plug-in).
    """
    used = used_options(name, options)
    learn = used.pop("learn_prior", False)
    found = entry(name)
    for opt in found.own:  # a plug-in's own options always reach it: the declared default when not given
        used.setdefault(opt.name, opt.default)
    planner = found.factory(**used)
    if learn:
        from planner.learning import LearnedPriorPlanner

        planner = LearnedPriorPlanner(planner)
    return planner


def planner_settings(scenario: Any, name: str | None = None, iterations: int | None = None,
                     plan_ms: float | None = None, extra: Iterable[tuple[str, Any]] = ()) -> tuple[str, dict]:
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
    """The options planner ``name`` uses, checked: the others, and ``None`` values, are dropped; a
    plug-in's own options that were not given are there with their defaults, so that a run's
    recorded options (summary.json's ``planner_options``, mission.db) reproduce it.

    Raises:
        ValueError: unknown name or option, or a value out of type or range (one line).
    """
    found = entry(name)
    whose = f"planner {name!r}: " if found.plugin else ""
    unknown = sorted(set(options) - set(found.known()))
    if unknown:
        raise ValueError(f"{whose}unknown planner option(s) {unknown}; expected some of: {', '.join(found.known())}")
    own = {o.name for o in found.own}
    used = {}
    for key, value in options.items():
        if value is None or (key not in found.options and key not in own and key not in GENERIC_OPTIONS):
            continue
        option = found.option(key)
        assert option is not None  # unknown options were refused above
        try:
            used[key] = option.check(value)
        except ValueError as err:
            raise ValueError(f"{whose}{key} must be {err}, got {value!r}") from None
    for option in found.own:  # a plug-in's own options it was not given: their defaults, recorded
        if used.get(option.name) is None and option.default is not None:
            used[option.name] = option.default
    if used.get("learn_prior") is False:
        used.pop("learn_prior")  # the default: today's planner exactly, and today's recorded options
    return used


# ----------------------------------------------------------------------------- the planners
# Factories import their modules lazily: the MCTS and closed-loop modules load numba kernels.


def _random(**_: Any) -> object:
    from planner.policies import RandomPlanner

    return RandomPlanner()


def _ssap(**_: Any) -> object:
    from planner.policies import SSAPPlanner

    return SSAPPlanner()


def _mcts(rollout: str) -> Callable[..., object]:
    def factory(**options: Any) -> object:
        from planner.mcts.fast import MCTSPlanner

        return MCTSPlanner(rollout=rollout, **options)

    return factory


def _closed_loop(**options: Any) -> object:
    from planner.closedloop import ClosedLoopPlanner  # see docs/results.md

    return ClosedLoopPlanner(**options)


def _closed_loop_gated(**options: Any) -> object:
    from planner.closedloop import GatedClosedLoopPlanner  # see docs/planner.md, "closed-loop-gated"

    return GatedClosedLoopPlanner(**options)


def _dec_mcts(**options: Any) -> object:
    from planner.decmcts import DecMCTSPlanner  # decentralised: see planner/decentralised.py

    return DecMCTSPlanner(**options)


def _dec_closed_loop(**options: Any) -> object:
    from planner.decentralised import DecClosedLoopPlanner

    return DecClosedLoopPlanner(**options)


def _online_optimal(**_: Any) -> object:
    # The exact Bayes-optimal policy for small instances; budget options do not apply to it.
    from planner.online_optimal import OnlineOptimalPlanner

    return OnlineOptimalPlanner()


_MCTS_OPTIONS = ("iterations", "plan_ms", "exploration", "samples", "layout")
register("random", _random, options=())
register("ssap", _ssap, options=())
register("mcts-random", _mcts("random"), options=_MCTS_OPTIONS)
register("mcts-ssap", _mcts("ssap"), options=_MCTS_OPTIONS)
register("closed-loop", _closed_loop, options=("iterations", "plan_ms"))
register("closed-loop-gated", _closed_loop_gated, options=("iterations", "plan_ms"))
register("online-optimal", _online_optimal, options=())
# Decentralised planners (each carrier decides on board; ``decide_local``): run them under a
# communication model with planner.decentralised.run_comms (run_online does so with perfect links).
register("dec-mcts", _dec_mcts, options=("iterations", "plan_ms", "exploration"))
register("dec-closed-loop", _dec_closed_loop, options=("iterations", "plan_ms"))
