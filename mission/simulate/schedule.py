"""A fault schedule as a file: the ``faults`` of a seed in ``python -m mission.simulate --json``,
what ``--schedule`` takes there and on ``run_fleet.py`` (docs/fleet.md, "Fault schedules on real
processes").

A schedule is a JSON list of faults, each an object with ``kind`` (one of :data:`FAULT_KINDS`),
``at`` and ``until`` (seconds of the simulated mission's true time, ``until >= at``), ``who``
(a carrier id or ``coordinator``; optional) and ``size`` (the kind's probability, factor or
seconds; optional). The simulator's report adds each fault's **mission points**: ``decided``,
the number of stages the simulated mission had decided when the fault struck, ``decided_until``,
when it ended, ``joined``, the carriers (ids, sorted) a coordinator had accepted when it struck,
and ``started``, the carriers whose process had started then (which tell "before the first
Decision" apart: who had joined, who was joining, who had not started yet). A real fleet strikes at the mission point, not at a wall time
(:mod:`launcher.faults`); both are optional when the simulator reads a schedule back.

Checked field by field: a bad file is one line naming the file, the fault's index and the field
(:class:`ScheduleError`).
"""
from __future__ import annotations

import json
import math

from .model import FAULT_KINDS, Fault

#: The mission points a report adds to each fault.
POINTS = ("decided", "decided_until", "joined", "started")


class ScheduleError(ValueError):
    """A schedule that cannot be read: one line naming the file, the fault and the field."""


def parse(data, source: str = "--schedule", ids=None) -> tuple[Fault, ...]:
    """The faults of a decoded schedule (``source`` names it in errors; ``ids``: the scenario's
    carrier ids, which a ``who`` must be one of when given)."""
    if not isinstance(data, list):
        raise ScheduleError(f"{source}: expected a JSON list of faults, found {type(data).__name__}")
    out = []
    for k, f in enumerate(data):
        where = f"{source}: fault {k}"
        if not isinstance(f, dict):
            raise ScheduleError(f"{where}: expected an object {{kind, at, until, who, size}}, found {type(f).__name__}")
        unknown = sorted(set(f) - {"kind", "at", "until", "who", "size", *POINTS})
        if unknown:
            raise ScheduleError(f"{where}: field {unknown[0]!r}: unknown (expected kind, at, until, who, size, "
                                f"{', '.join(POINTS)})")
        kind = f.get("kind")
        if kind not in FAULT_KINDS:
            raise ScheduleError(f"{where}: field 'kind': expected one of {', '.join(FAULT_KINDS)}, found {kind!r}")
        at, until = _number(f, "at", where), _number(f, "until", where)
        if until < at:
            raise ScheduleError(f"{where}: field 'until': expected a time >= at ({at:g}), found {until:g}")
        who = f.get("who", "")
        allowed = ("", "coordinator", *ids) if ids is not None else None
        if not isinstance(who, str) or allowed is not None and who not in allowed:
            raise ScheduleError(f"{where}: field 'who': expected a carrier id of the scenario or 'coordinator', "
                                f"found {who!r}")
        size = _number(f, "size", where) if "size" in f else 0.0
        for name in POINTS[:2]:
            if name in f and (not isinstance(f[name], int) or isinstance(f[name], bool) or f[name] < 0):
                raise ScheduleError(f"{where}: field {name!r}: expected an integer >= 0 (stages decided), "
                                    f"found {f[name]!r}")
        for name in POINTS[2:]:
            listed = f.get(name, [])
            if not isinstance(listed, list) or not all(isinstance(c, str) and (ids is None or c in ids) for c in listed):
                raise ScheduleError(f"{where}: field {name!r}: expected a list of the scenario's carrier ids, "
                                    f"found {listed!r}")
        out.append(Fault(kind, at, until, who, size))
    return tuple(out)


def _number(f: dict, name: str, where: str) -> float:
    if name not in f:
        raise ScheduleError(f"{where}: field {name!r}: missing (expected a number of seconds)")
    v = f[name]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
        raise ScheduleError(f"{where}: field {name!r}: expected a finite number >= 0, found {v!r}")
    return float(v)


def load(path, ids=None) -> tuple[Fault, ...]:
    """The faults of the schedule file ``path`` (:class:`ScheduleError` on any problem)."""
    try:
        text = open(path, encoding="utf-8").read()
    except OSError as exc:
        raise ScheduleError(f"{path}: cannot read the schedule ({exc.strerror or exc})") from None
    try:
        data = json.loads(text)
    except ValueError as exc:
        raise ScheduleError(f"{path}: not JSON ({exc})") from None
    return parse(data, str(path), ids)


def points(data) -> list[dict]:
    """The mission points of a decoded schedule, per fault: ``decided``/``decided_until`` when
    given (a schedule the simulator reported), else None."""
    return [{name: f.get(name) for name in POINTS} for f in data]


def with_points(faults, decided_at: dict, accepted_at: dict | None = None, started_at: dict | None = None
                ) -> list[dict]:
    """The report's ``faults``: each fault's JSON and its mission points, from the true times the
    simulated mission decided each stage first (``decided_at``: stage -> time), accepted each
    carrier first (``accepted_at``: carrier -> time) and started each carrier first
    (``started_at``)."""
    times = sorted(decided_at.values())
    accepted, started = accepted_at or {}, started_at or {}
    return [{**f.as_json(), "decided": sum(t < f.at for t in times), "decided_until": sum(t < f.until for t in times),
             "joined": sorted(c for c, t in accepted.items() if t < f.at),
             "started": sorted(c for c, t in started.items() if t < f.at)} for f in faults]
