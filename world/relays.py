"""Relay nodes ("breadcrumbs"): where each carrier drops its relays, by the documented rule, and
the network they make with the base and the carriers (docs/scenario.md, "links").

Rule: a carrier with relays left checks its radio link to its last node — its last dropped
relay, or the base before the first — every ``links.relays.step_m`` metres along its planned
path. At the first check where the mean margin (no fading: the rule uses what the model
predicts, so it is deterministic) falls below ``drop_margin_db``, it drops a relay at the last
check point where the margin was still at or above the threshold (at the point itself when that
is its last node), and that relay becomes its last node. Each carrier keeps its own chain; a
dropped relay is a node of the radio model for every message from its drop time on.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from planner.links import best_path
from world import geometry
from world.links import LinkModel
from world.scenario import CarrierSpec


@dataclass(frozen=True)
class Relay:
    """A dropped relay: its ``carrier``, its ``index`` in that carrier's drops, ``position`` (m),
    the arc length along the path where it was dropped (``distance``, m) and the planned mission
    ``time`` of the drop (s)."""

    carrier: str
    index: int
    position: tuple[float, float]
    distance: float
    time: float


def relay_drops(model: LinkModel, carrier: CarrierSpec, count: int, drop_margin_db: float,
                step_m: float) -> tuple[Relay, ...]:
    """The relays ``carrier`` drops along its planned path by the rule above (at most
    ``count``), in order."""
    if count <= 0:
        return ()
    pts = np.asarray(carrier.waypoints, dtype=float)
    cum = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(pts, axis=0).T))])
    end = carrier.distance_at(carrier.stop_time)  # where its planned path ends
    checks = np.append(np.arange(0.0, end, step_m), end)
    anchor: tuple[float, float] = model.base
    anchor_s = -1.0
    last_good: tuple[float, float, float] | None = None  # (x, y, s) of the last check at or above
    out: list[Relay] = []
    for s in checks:
        p = geometry.point_along(carrier.waypoints, cum, float(s))
        if model.margin(anchor, p) >= drop_margin_db:
            last_good = (p[0], p[1], float(s))
            continue
        x, y, at = last_good if last_good is not None and last_good[2] > anchor_s else (p[0], p[1], float(s))
        out.append(Relay(carrier.id, len(out), (float(x), float(y)), at, carrier.start_time + at / carrier.speed))
        if len(out) == count:
            break
        anchor, anchor_s, last_good = (float(x), float(y)), at, None
        if model.margin(anchor, p) >= drop_margin_db:
            last_good = (p[0], p[1], float(s))
    return tuple(out)


def fleet_relays(model: LinkModel) -> tuple[Relay, ...]:
    """Every relay of the scenario's fleet (``links.relays``), carrier by carrier in index
    order; none unless the model is ``radio``."""
    spec = model.spec
    if spec.model != "radio" or spec.relays.total == 0:
        return ()
    out: list[Relay] = []
    for c in model.scenario.carriers:
        out += relay_drops(model, c, spec.relays.count(c.id), spec.relays.drop_margin_db, spec.relays.step_m)
    return tuple(out)


def nodes_at(model: LinkModel, relays: tuple[Relay, ...], t: float) -> np.ndarray:
    """float ``[1 + K, 2]``: the base, then the positions of the relays dropped by time ``t`` (s)
    — the fixed nodes of the radio graph at ``t``."""
    pts = [model.base] + [r.position for r in relays if r.time <= t + 1e-9]
    return np.asarray(pts, dtype=float)


def route_to_base(model: LinkModel, relays: tuple[Relay, ...], position, t: float) -> tuple[tuple[int, ...], float]:
    """Best path from a carrier at ``position`` to the base at time ``t`` through the relays
    dropped by then: (node indices into [carrier, base, relays...], probability)."""
    nodes = np.vstack([np.asarray(position, dtype=float).reshape(1, 2), nodes_at(model, relays, t)])
    if not math.isfinite(float(nodes[0, 0])):
        return (), 0.0
    return model.route(nodes, 0, 1)


def stage_connectivity(model: LinkModel, relays: tuple[Relay, ...] = ()) -> np.ndarray:
    """float ``[N, R + 1, R + 1]``: at each stage time, the delivery probability of the best path
    between every two participants — index 0 the base, 1 + r carrier r at its planned position
    — through every node then in place (the base, the valid carriers, the relays dropped by
    then: carriers forward messages too). NaN for a carrier not valid at the stage; 1 on the
    diagonal. The geometry's prediction of who can hear whom, before the mission."""
    s = model.scenario
    valid = s.valid()
    n_r = s.n_carriers
    out = np.full((s.stages, n_r + 1, n_r + 1), np.nan)
    for j in range(s.stages):
        t = float(s.stage_time(j))
        here = [r for r in range(n_r) if valid[r, j]]
        carriers = np.asarray([s.carriers[r].position_at(t) for r in here], dtype=float).reshape(-1, 2)
        nodes = np.vstack([np.asarray([model.base], dtype=float), carriers, nodes_at(model, relays, t)[1:]])
        prob = model.graph(nodes)
        index = [0] + [1 + r for r in here]  # participant index of node k < 1 + len(here)
        for a in range(len(index)):
            out[j, index[a], index[a]] = 1.0
            for b in range(a + 1, len(index)):
                out[j, index[a], index[b]] = out[j, index[b], index[a]] = best_path(prob, a, b)[1]
    return out
