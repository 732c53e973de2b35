"""How many bytes each message kind takes on the wire for a scenario's fleet, and whether the
messages a stage needs fit an acoustic modem's frame (docs/scenario.md, "Links").

Each size is the real codec's (:func:`wire.messages.encode`, newest revision) on the largest
message of the kind this fleet can send: the longest carrier id, the last stage and its time,
the largest count the wire admits (``x``), every carrier deploying (Decision), positions as
float64. The mission id is the default one, derived from the scenario's name (``--mission``
may name a longer one). A fresh mission's epoch (1, left off the wire) is assumed.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from planner.limits import MAX_TRAIL
from validation import Found, Flaw
from world.grid import simplify_mask

from . import messages as wm
from .keys import mission_id_from_name, state_selector

#: The largest feature count an Observation or Own carries on the wire.
_MAX_X = 10**9 - 1
#: The message kinds every stage of a mission sends (an Own only when a carrier decides alone).
STAGE_KINDS = ("obs", "decision", "confirm", "own")
#: The kinds the frame check skips: ``obs+trail`` is sent fitted to the frame on acoustic links
#: (:func:`fit_trail`), and ``obs+fitted`` fits whenever ``obs`` does; Poses are viewers' traffic,
#: not carried over the links (wire/link_filter.py).
UNCHECKED_KINDS = ("obs+trail", "obs+fitted", "pose")
#: First Douglas-Peucker tolerance (m) :func:`fit_trail` tries; it doubles until the trail fits.
TRAIL_TOLERANCE_M = 0.5


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
        ("query", state_selector(mission, cid, wm.REVISION), "a State query's selector (a Zenoh get)"),
    ]


def _size(message) -> int:
    return len(message.encode()) if isinstance(message, str) else len(wm.encode(message))


def fit_trail(message: wm.Observation, frame_bytes: int) -> wm.Observation:
    """``message`` with its trail thinned until the whole Observation fits ``frame_bytes``
    (acoustic links; unchanged when it fits already). The trail is informative (docs/protocol.md,
    Observation ``trail``): a subset of the positions driven through is still one, so this is no
    change of the wire. Douglas-Peucker at :data:`TRAIL_TOLERANCE_M`, doubled until it fits;
    a trail still too long after that keeps evenly spaced points; at worst it is empty (the
    record still draws the straight line between the stages' positions)."""
    if len(wm.encode(message)) <= frame_bytes or not message.trail:
        return message
    line = np.asarray(message.trail, dtype=float)
    tol = TRAIL_TOLERANCE_M
    while tol < 1e6:
        kept = line if len(line) <= 2 else line[simplify_mask(line, tol)]
        fitted = dataclasses.replace(message, trail=tuple((float(a), float(b)) for a, b in kept))
        if len(wm.encode(fitted)) <= frame_bytes:
            return fitted
        if len(kept) <= 2:
            break
        tol *= 2
    for k in range(min(len(line), 2), -1, -1):  # the ends, the last point, or nothing
        kept = line[np.linspace(0, len(line) - 1, k).astype(int)] if k else line[:0]
        fitted = dataclasses.replace(message, trail=tuple((float(a), float(b)) for a, b in kept))
        if len(wm.encode(fitted)) <= frame_bytes:
            return fitted
    return fitted


def message_sizes(scenario) -> list[Size]:
    """The size of every message kind for ``scenario``'s fleet (see the module's note)."""
    out = [Size(kind, _size(message), kind in STAGE_KINDS, note) for kind, message, note in _messages(scenario)]
    if scenario.links.model == "acoustic":  # what the carriers send: the trail fitted to the frame
        full = next(m for k, m, _ in _messages(scenario) if k == "obs+trail")
        fitted = fit_trail(full, scenario.links.frame_bytes)
        out.append(Size("obs+fitted", len(wm.encode(fitted)), True,
                        f"as carriers send it on acoustic links: the trail fitted ({len(fitted.trail)} points)"))
    return out


def fit_to_links(message: wm.Observation, links) -> wm.Observation:
    """An Observation as a carrier sends it on the scenario's ``links``: its trail fitted to the
    frame under ``acoustic`` (:func:`fit_trail`), as it is otherwise."""
    return fit_trail(message, links.frame_bytes) if links.model == "acoustic" else message


def link_sizes(scenario) -> dict:
    """kind -> bytes of what crosses the links: the Observation as the carriers send it (its
    trail fitted under acoustic links) under ``obs``."""
    sizes = {s.kind: s.size for s in message_sizes(scenario)}
    sizes["obs"] = sizes.get("obs+fitted", sizes["obs+trail"])
    return sizes


def frame_problems(scenario) -> list[Flaw]:
    """Under ``links.model: acoustic``: ``links.frame_bytes`` must hold every message that crosses
    the links (all but :data:`UNCHECKED_KINDS`); one problem per
    kind that does not fit, naming its size, or one saying the frame holds no message at all.
    Nothing for the other models."""
    if scenario.links.model != "acoustic":
        return []
    frame = scenario.links.frame_bytes
    sizes = message_sizes(scenario)
    smallest = min((s for s in sizes if s.kind not in UNCHECKED_KINDS), key=lambda s: s.size)
    if frame < smallest.size:
        return [Flaw("links.frame_bytes", f"at least {smallest.size} bytes (the smallest message of this fleet, "
                        f"{smallest.kind}, takes {smallest.size}; a stage needs up to "
                        f"{max(s.size for s in sizes if s.stage and s.kind not in UNCHECKED_KINDS)})", Found(f"{frame} bytes: no message fits"))]
    return [Flaw("links.frame_bytes", f"at least {s.size} bytes: "
                    + (f"every stage sends the {s.kind} message, " if s.stage else f"the fleet sends the {s.kind} message, ")
                    + f"{s.size} bytes for this fleet ({s.note})", Found(f"{frame} bytes"))
            for s in sizes if s.kind not in UNCHECKED_KINDS and s.size > frame]
