"""The one validation toolkit: problems with field paths, a collector, declarative checks.

Every input the project reads — scenario files, instance files, planner options, launcher flags
and wire messages — is checked with these parts, so that every error reads the same way::

    SOURCE: field.path[3]: expected WHAT, found WHAT-IT-WAS

* :class:`Flaw` — one thing wrong: ``field`` (a path such as ``carriers[2].speed``; ``""`` is
  the top level), ``expected`` and ``found`` (the offending value, or a :class:`Found` text
  shown verbatim);
* :class:`Flaws` — the collector: ``add``, ``unknown_keys`` (with a "did you mean" hint),
  ``missing``, then ``lines(source)`` or ``raise_first``;
* declarative checks :class:`Number`, :class:`Choice`, :class:`Flag` and :class:`Text`: each
  says what it expects (``expected()``) and normalises a value or raises :class:`Invalid`;
* :func:`show` renders a found value in the style of the input (``"yaml"`` for scenario files
  and flags, ``"json"`` for JSON instances).

Standard library only: it sits below every other package (docs/architecture.md).
"""
from __future__ import annotations

import difflib
import json
import math
from dataclasses import dataclass
from typing import Any, Iterable, Iterator, Literal

Style = Literal["yaml", "json"]


class Found(str):
    """A "found" description shown verbatim (not a value from the input), e.g. ``"3 carriers"``."""


#: The found text of a required field that is not there.
MISSING = Found("nothing (missing)")


def show(value: Any, style: Style = "yaml") -> str:
    """``value`` as the "found" part of an error: a :class:`Found` verbatim; otherwise YAML-ish
    (``'text'``, ``nothing (null)``, ``a mapping``; lists up to 60 characters) or JSON (``"text"``,
    ``null``, cut at 60 characters)."""
    if isinstance(value, Found):
        return str(value)
    if style == "json":
        text = json.dumps(value) if not isinstance(value, float) or math.isfinite(value) else str(value)
        return text if len(text) <= 60 else text[:57] + "..."
    if isinstance(value, dict):
        return "a mapping"
    if isinstance(value, (list, tuple)):
        text = repr(list(value))
        return text if len(text) <= 60 else f"a list of {len(value)} items"
    if value is None:
        return "nothing (null)"
    return repr(value)


def join(path: str, key: Any) -> str:
    """The path of ``key`` inside ``path`` (``a.b``; ``b`` at the top level)."""
    return f"{path}.{key}" if path else str(key)


def did_you_mean(word: Any, choices: Iterable[str], cutoff: float = 0.6) -> str:
    """`` (did you mean 'x'?)`` for the choice closest to ``word``, or ``""``."""
    close = difflib.get_close_matches(str(word), list(choices), n=1, cutoff=cutoff)
    return f" (did you mean '{close[0]}'?)" if close else ""


@dataclass(frozen=True)
class Flaw:
    """One thing wrong with an input.

    Attributes:
        field: path of the field (``planner.layout``, ``observations[2][5]``, ``--plan-ms``);
            ``""`` for the input as a whole.
        expected: what the field should hold ("an integer >= 1").
        found: the offending value, or a :class:`Found` description. ``None`` with ``text``
            set: a problem that is not an expected/found pair (``text`` is the whole message).
        text: a whole message after the path, used instead of "expected ..., found ...".
    """

    field: str
    expected: str
    found: Any
    text: str | None = None

    def message(self, style: Style = "yaml") -> str:
        """``expected E, found F`` (or the problem's own text)."""
        return self.text if self.text is not None else f"expected {self.expected}, found {show(self.found, style)}"

    def line(self, source: str | None = None, style: Style = "yaml") -> str:
        """One line: ``[SOURCE: ]field: expected E, found F`` (``(top level)`` for no field)."""
        head = f"{source}: " if source else ""
        return f"{head}{self.field or '(top level)'}: {self.message(style)}"

    def within(self, path: str) -> Flaw:
        """The same problem with its field under ``path`` (``prior`` + ``mean`` -> ``prior.mean``)."""
        return Flaw(join(path, self.field) if self.field else path, self.expected, self.found, self.text)


class Flaws:
    """Collects :class:`Flaw` entries; checks add to it and return the value or None."""

    def __init__(self) -> None:
        self.items: list[Flaw] = []

    def add(self, field: str, expected: str, found: Any) -> None:
        self.items.append(Flaw(field, expected, found))

    def note(self, field: str, text: str) -> None:
        """A problem that is a whole sentence (``field: TEXT``)."""
        self.items.append(Flaw(field, "", None, text))

    def extend(self, problems: Iterable[Flaw], within: str = "") -> None:
        self.items.extend(p.within(within) if within else p for p in problems)

    def check(self, spec: Check, value: Any, field: str) -> Any:
        """``spec.check(value)``, or None with the problem recorded."""
        try:
            return spec.check(value)
        except Invalid as err:
            self.add(field, err.expected, value)
            return None

    def unknown_keys(self, node: dict, path: str, allowed: tuple[str, ...], cutoff: float = 0.6) -> None:
        """A problem per key of ``node`` not in ``allowed``, with the closest allowed key as a hint
        (or the whole list when none is close)."""
        for key in node:
            if key not in allowed:
                hint = did_you_mean(key, allowed, cutoff) or f" (one of: {', '.join(allowed)})"
                self.add(join(path, key), f"a known key{hint}", Found(f"unknown key '{key}'"))

    def missing(self, node: dict, path: str, required: tuple[str, ...]) -> None:
        for key in required:
            if key not in node:
                self.add(join(path, key), "a value", MISSING)

    def lines(self, source: str | None = None, style: Style = "yaml") -> list[str]:
        return [p.line(source, style) for p in self.items]

    def __len__(self) -> int:
        return len(self.items)

    def __bool__(self) -> bool:
        return bool(self.items)

    def __iter__(self) -> Iterator[Flaw]:
        return iter(self.items)


class Invalid(ValueError):
    """A value a :class:`Check` refuses; ``expected`` is the check's :meth:`expected` text."""

    def __init__(self, expected: str):
        super().__init__(expected)
        self.expected = expected


def _finite_number(value: Any) -> bool:
    return not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value)


@dataclass(frozen=True)
class Number:
    """A finite number (``integer``: a whole one, returned as int; else returned as float) within
    an inclusive range (``exclusive``: the minimum itself refused). ``noun`` names it in the
    expected text in place of "an integer" / "a number" (``seconds`` -> "seconds > 0")."""

    integer: bool = False
    minimum: float | None = None
    maximum: float | None = None
    exclusive: bool = False
    noun: str | None = None

    def expected(self) -> str:
        text = self.noun or ("an integer" if self.integer else "a number")
        if self.minimum is not None:
            text += f" {'>' if self.exclusive else '>='} {self.minimum:g}"
        if self.maximum is not None:
            text += f"{' and' if self.minimum is not None else ''} <= {self.maximum:g}"
        return text

    def check(self, value: Any) -> int | float:
        if not _finite_number(value) or (self.integer and not float(value).is_integer()):
            raise Invalid(self.expected())
        if self.minimum is not None and (value <= self.minimum if self.exclusive else value < self.minimum):
            raise Invalid(self.expected())
        if self.maximum is not None and value > self.maximum:
            raise Invalid(self.expected())
        return int(value) if self.integer else float(value)

    def parse(self, text: str) -> int | float:
        """Command-line text -> checked value."""
        try:
            value = (int if self.integer else float)(text.strip())
        except ValueError:
            raise Invalid(self.expected()) from None
        return self.check(value)


@dataclass(frozen=True)
class Choice:
    """One of a fixed tuple of strings."""

    values: tuple[str, ...]

    def expected(self) -> str:
        return f"one of {', '.join(self.values)}"

    def check(self, value: Any) -> str:
        if not isinstance(value, str) or value not in self.values:
            raise Invalid(self.expected())
        return value

    def parse(self, text: str) -> str:
        return self.check(text.strip())


#: Command-line spellings of a boolean's values.
BOOL_TEXT = {"true": True, "false": False, "1": True, "0": False, "yes": True, "no": False}


@dataclass(frozen=True)
class Flag:
    """A boolean (on the command line: true/false, 1/0, yes/no)."""

    def expected(self) -> str:
        return "true or false"

    def check(self, value: Any) -> bool:
        if not isinstance(value, bool):
            raise Invalid(self.expected())
        return value

    def parse(self, text: str) -> bool:
        return self.check(BOOL_TEXT.get(text.strip().lower(), text))


@dataclass(frozen=True)
class Text:
    """A string, non-empty (not only blanks) unless ``empty``, at most ``max_len`` characters."""

    max_len: int | None = None
    empty: bool = False

    def expected(self) -> str:
        text = "a string" if self.empty else "a non-empty string"
        return text if self.max_len is None else f"{text} of at most {self.max_len} characters"

    def check(self, value: Any) -> str:
        if not isinstance(value, str) or (not self.empty and not value.strip()):
            raise Invalid(self.expected())
        if self.max_len is not None and len(value) > self.max_len:
            raise Invalid(self.expected())
        return value

    def parse(self, text: str) -> str:
        return self.check(text)


#: Any of the declarative checks.
Check = Number | Choice | Flag | Text

__all__ = ["BOOL_TEXT", "Check", "Choice", "Flag", "Found", "Invalid", "MISSING", "Number", "Flaw",
           "Flaws", "Style", "Text", "did_you_mean", "join", "show"]

