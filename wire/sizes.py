"""How many bytes each message kind takes on the wire for a scenario's fleet, and whether the
messages a stage needs fit an acoustic modem's frame (docs/scenario.md, "Links").

Each size is the real codec's (:func:`wire.messages.encode`, newest revision) on the largest
message of the kind this fleet can send: the longest carrier id, the last stage and its time,
the largest count the wire admits (``x``), every carrier deploying (Decision), positions as
float64. The mission id is the default one, derived from the scenario's name (``--mission``
may name a longer one). A fresh mission's epoch (1, left off the wire) is assumed.
"""
from __future__ import annotations

from dataclasses import dataclass

from planner.limits import MAX_TRAIL
from validation import Found, Problem

from . import messages as wm
from .keys import mission_id_from_name

#: The largest feature count an Observation or Own carries on the wire.
_MAX_X = 10**9 - 1
#: The message kinds every stage of a mission sends (an Own only when a carrier decides alone).
STAGE_KINDS = ("obs", "decision", "confirm", "own")


@dataclass(frozen=True)
class Size:
    """One message kind's size: ``kind`` (its wire type, ``obs+trail`` for an Observation with
    the trail a carrier sends today), ``size`` (bytes), whether every stage needs it
    (``stage``), and what was assumed (``note``)."""

    kind: str
    size: int
    stage: bool
    note: str


def _messages(scenario) -> list[tuple[str, object, str]]:
    mission = mission_id_from_name(scenario.name)
    cid = max(scenario.carrier_ids, key=len)
    ids = tuple(sorted(scenario.carrier_ids))
    n = scenario.stages
    j, t = n - 1, float(scenario.stage_time(n - 1)) + 0.123456789
    pos = (1234.56789, -987.654321)
    d = int(max(scenario.passengers))
    typed = scenario.passenger_values() is not None
    trail_n = min(MAX_TRAIL, int(scenario.stage_interval))  # a trajectory sample per second
    trail = tuple((100.0 + k + 0.5, 200.0 - k - 0.25) for k in range(trail_n))
    deployments = tuple(range(n - d, n)) if d else ()
    return [
        ("obs", wm.Observation(mission, cid, j, t, _MAX_X, pos, d, ()), "no trail (maps only)"),
        ("decision", wm.Decision(mission, j, t, ids, 12.345678, 1, tuple(max(d - 1, 0) for _ in ids) if typed else ()),
         f"all {len(ids)} carriers deploy" + (", passengers named" if typed else "")),
        ("confirm", wm.Confirm(mission, cid, j, True, "deployed", pos, max(d - 1, 0), max(d - 1, 0) if typed else None),
         "a release"),
        ("own", wm.Own(mission, cid, j, t, _MAX_X, True, pos, max(d - 1, 0)), "a carrier deciding alone"),
        ("obs+trail", wm.Observation(mission, cid, j, t, _MAX_X, pos, d, trail),
         f"as carriers send it today: {trail_n} trail points"),
        ("hello", wm.Hello(mission, cid, 2**31 - 1, "h" * 64, d, j, "f" * 16, 1, wm.REVISION), "host name of 64"),
        ("accepted", wm.Accepted(mission, cid, "f" * 16, j, j, wm.REVISION), "at start"),
        ("state", wm.State(mission, j, n, "f" * 16, False,
                           ((cid, wm.CarrierState(d, deployments, True)),), None, 1, wm.REVISION), "one carrier's"),
        ("pose", wm.Pose(mission, cid, t, pos, 3.14159, d), "viewers only"),
        ("progress", wm.Progress(mission, cid, n, t), "liveness"),
        ("bye", wm.Bye(mission, cid, deployments, (), "end"), "at the end"),
        ("end", wm.End(mission, n, "complete"), "at the end"),
    ]


def message_sizes(scenario) -> list[Size]:
    """The size of every message kind for ``scenario``'s fleet (see the module's note)."""
    return [Size(kind, len(wm.encode(message)), kind in STAGE_KINDS, note)
            for kind, message, note in _messages(scenario)]


def frame_problems(scenario) -> list[Problem]:
    """Under ``links.model: acoustic``: ``links.frame_bytes`` must hold every message a stage
    needs (:data:`STAGE_KINDS`); one problem per kind that does not fit, naming its size, or one
    saying the frame holds no message at all. Nothing for the other models."""
    if scenario.links.model != "acoustic":
        return []
    frame = scenario.links.frame_bytes
    sizes = message_sizes(scenario)
    smallest = min(sizes, key=lambda s: s.size)
    if frame < smallest.size:
        return [Problem("links.frame_bytes", f"at least {smallest.size} bytes (the smallest message of this fleet, "
                        f"{smallest.kind}, takes {smallest.size}; a stage needs up to "
                        f"{max(s.size for s in sizes if s.stage)})", Found(f"{frame} bytes: no message fits"))]
    return [Problem("links.frame_bytes", f"at least {s.size} bytes: every stage sends the {s.kind} message, "
                    f"{s.size} bytes for this fleet ({s.note})", Found(f"{frame} bytes"))
            for s in sizes if s.stage and s.size > frame]
