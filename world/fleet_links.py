"""The link model between a fleet's participants (docs/scenario.md, "Links in a mission"): where
each one is — a carrier at the planned position of the stage it is at, a coordinator at the base,
the relays dropped by then — and the hops a message takes between two of them.

Radio: the best path (highest delivery probability, :func:`planner.links.best_path`) through
every node then in place: the base, the relays dropped by then, the other live carriers (carriers
forward messages, as in :func:`world.relays.stage_connectivity`). Acoustic: one direct hop (a
modem hears its peer or not; no relays). Perfect: no hop is ever asked for.

The simulator (mission/simulate/links.py) and the real fleet's receive filter
(:mod:`wire.link_filter`) both ask this object; it caches the walls and paths per position,
so a campaign of missions over the same world computes each once.
"""
from __future__ import annotations

import numpy as np

from planner import links as ch
from world.links import LinkModel
from world.relays import Relay, fleet_relays
from world.scenario import Scenario

#: The participants placed at the base: the coordinator and its standby.
BASE_NAMES = ("coordinator", "standby")


class FleetLinks:
    """A scenario's link model over its fleet's participants.

    Attributes:
        spec: the scenario's :class:`planner.links.LinkSpec`.
        relays: the relays the fleet drops (:func:`world.relays.fleet_relays`), in order.
        sizes: message kind -> bytes on the wire (:func:`wire.sizes.message_sizes`, given by
            the caller: world/ does not import wire/).
    """

    def __init__(self, scenario: Scenario, sizes: dict | None = None):
        self.model = LinkModel(scenario)
        self.spec = scenario.links
        self.scenario = scenario
        self.ids = tuple(scenario.carrier_ids)
        self.times = tuple(float(t) for t in scenario.stage_times())
        self.relays: tuple[Relay, ...] = fleet_relays(self.model)
        self.sizes = dict(sizes or {})
        self._hop: dict = {}
        self._paths: dict = {}

    # -------------------------------------------------------------- where
    def carrier_position(self, cid: str, stage: int) -> tuple[float, float]:
        """Carrier ``cid``'s planned position at stage ``stage``'s time (clamped to the mission's
        stages: before the first it is at the first's, after the last at the last's)."""
        j = min(max(int(stage), 0), len(self.times) - 1)
        return tuple(map(float, self.scenario.carriers[self.ids.index(cid)].position_at(self.times[j])))

    def position(self, name: str, stage: int = 0) -> tuple[float, float]:
        """A participant's position: the base for a coordinator, else the carrier's at ``stage``."""
        return self.model.base if name in BASE_NAMES else self.carrier_position(name, stage)

    def relays_at(self, stages: dict) -> tuple[Relay, ...]:
        """The relays dropped by now: those whose carrier's stage (``stages``: carrier -> stage)
        has reached the relay's planned drop time."""
        return tuple(r for r in self.relays
                     if self.times[min(max(stages.get(r.carrier, 0), 0), len(self.times) - 1)] >= r.time - 1e-9)

    # -------------------------------------------------------------- hops
    def hop(self, a, b) -> tuple[float, int]:
        """(distance m, walls crossed) between two positions, cached."""
        key = (a, b) if a <= b else (b, a)
        hit = self._hop.get(key)
        if hit is None:
            hit = self._hop[key] = self.model.hop(*key)
        return hit

    def path(self, src, dst, carriers=(), stages=None) -> tuple[tuple[float, int], ...]:
        """The hops of a message from position ``src`` to ``dst`` now: direct unless the links
        are radio; radio: the best path through the base, the positions ``carriers`` (the other
        live carriers; only iterated on radio links) and the relays dropped by ``stages``
        (carrier -> the stage it is at, :meth:`relays_at`)."""
        src, dst = tuple(map(float, src)), tuple(map(float, dst))
        if self.spec.model != "radio":
            return (self.hop(src, dst),)
        relays = self.relays_at(stages or {})
        extra = tuple(sorted({tuple(map(float, p)) for p in (self.model.base, *carriers)}
                             | {r.position for r in relays} - {src, dst}))
        key = (src, dst, extra)
        hit = self._paths.get(key)
        if hit is None:
            nodes = [src, dst, *extra]
            k = len(nodes)
            distances, walls = np.zeros((k, k)), np.zeros((k, k), dtype=np.int64)
            for i in range(k):
                for j in range(i + 1, k):
                    distances[i, j], walls[i, j] = self.hop(nodes[i], nodes[j])
            route, _ = ch.best_path(ch.hop_probabilities(self.spec, distances, walls), 0, 1)
            if not route:  # no path above probability 0: the direct hop, which will fail
                route = (0, 1)
            hit = self._paths[key] = tuple(self.hop(nodes[a], nodes[b]) for a, b in zip(route[:-1], route[1:]))
        return hit

    def between(self, src: str, dst: str, stages: dict, alive=()) -> tuple[tuple[float, int], ...]:
        """The hops from participant ``src`` to ``dst`` now: ``stages`` carrier -> the stage it is
        at; ``alive``: the carriers whose radios run (forwarders besides the base)."""
        a, b = self.position(src, stages.get(src, 0)), self.position(dst, stages.get(dst, 0))
        return self.path(a, b, (self.carrier_position(c, stages.get(c, 0)) for c in alive if c not in (src, dst)),
                         stages)

    def size(self, kind: str) -> int:
        """Bytes of a message of ``kind`` (the simulator's kinds map onto the wire's)."""
        return int(self.sizes[self.wire_kind(kind)])

    @staticmethod
    def wire_kind(kind: str) -> str:
        """The wire kind of the simulator's message ``kind`` (a peer's copy is the message itself), or
        the one whose size it takes (:data:`SIM_KINDS`)."""
        return SIM_KINDS.get(kind, kind)


#: One stage's frames on the shared acoustic channel: each carrier's (its Observation, Progress and
#: Confirm) and the coordinator's (the Decision); what a message may queue behind.
STAGE_FRAMES = (("obs", "progress", "confirm"), ("decision",))


def latency_bound(scenario: Scenario, sizes: dict) -> float:
    """The link model's worst one-way latency of a message between two participants, seconds
    (docs/fleet.md, "Waits over slow links"). Acoustic: the channel time of one stage's frames
    (:data:`STAGE_FRAMES`, the fleet's carriers each sending theirs: a message may wait for all of
    them on the one channel) plus the propagation across the mission's extent (the diagonal of
    the box that holds every waypoint and the base: no two participants are farther apart) at
    ``sound_speed_mps``. Perfect and radio: 0 (a radio hop's ``latency_s`` is milliseconds; the
    waits' defaults hold it). ``sizes``: bytes per message kind (:func:`wire.sizes.link_sizes`)."""
    spec = scenario.links
    if spec.model != "acoustic":
        return 0.0
    per_carrier, once = STAGE_FRAMES
    frames = len(scenario.carriers) * sum(int(sizes[k]) for k in per_carrier) + sum(int(sizes[k]) for k in once)
    points = np.array([p for c in scenario.carriers for p in c.waypoints] + [LinkModel(scenario).base], dtype=float)
    extent = float(np.hypot(*(points.max(axis=0) - points.min(axis=0))))
    return ch.airtime_s(spec, frames) + extent / spec.sound_speed_mps


#: The simulator's message kinds -> the wire kind whose size they take (a peer's copy of an
#: Observation or Own is the same message; a Refusal is about an Accepted's size).
SIM_KINDS = {"peer-obs": "obs", "peer-own": "own", "refusal": "accepted"}

