"""The link model on a scenario's world: the walls between two points (pymunk segment queries on
the map's wall shapes), and a scenario's link model as one object the simulators call.

The channel itself (margins, delivery probabilities, the acoustic channel, best paths) is
:mod:`planner.links`, pure; this module supplies the geometry: distance and walls crossed.
"""
from __future__ import annotations

import math
from functools import cached_property

import numpy as np
import pymunk

from planner import links as ch
from world.scenario import Scenario

#: Two wall hits closer than this along the segment are one crossing (m): a segment through the
#: joint of a polyline hits both of its pieces at the same point.
SAME_CROSSING_M = 1e-6


class Walls:
    """The map's walls as static pymunk segments, for counting the walls between two points.

    Args:
        segments: float ``[W, 4]`` wall segments (x1, y1, x2, y2) in m (``scenario.map.segments``).
    """

    def __init__(self, segments: np.ndarray):
        self.space = pymunk.Space()
        for x1, y1, x2, y2 in np.asarray(segments, dtype=float).reshape(-1, 4):
            self.space.add(pymunk.Segment(self.space.static_body, (float(x1), float(y1)), (float(x2), float(y2)), 0.0))
        self._filter = pymunk.ShapeFilter()

    def crossed(self, a, b) -> int:
        """Walls the straight segment from ``a`` to ``b`` (m) crosses: distinct crossing points
        (an obstacle's outline crossed in and out counts twice: two walls)."""
        a = (float(a[0]), float(a[1]))
        b = (float(b[0]), float(b[1]))
        length = math.hypot(b[0] - a[0], b[1] - a[1])
        if length == 0.0:
            return 0
        at = sorted(q.alpha * length for q in self.space.segment_query(a, b, 0.0, self._filter))
        return sum(1 for i, s in enumerate(at) if i == 0 or s - at[i - 1] > SAME_CROSSING_M)


class LinkModel:
    """A scenario's link model (``scenario.links``) on its world.

    Nodes are positions (m): carriers, relays, the base (``base``: the coordinator's antenna or
    modem, ``links.base`` or the first carrier's first waypoint).
    """

    def __init__(self, scenario: Scenario):
        self.spec: ch.LinkSpec = scenario.links
        self.scenario = scenario
        self.base: tuple[float, float] = scenario.links.base or tuple(map(float, scenario.carriers[0].waypoints[0]))

    @cached_property
    def walls(self) -> Walls:
        return Walls(self.scenario.map.segments if self.spec.model == "radio" else np.zeros((0, 4)))

    def hop(self, a, b) -> tuple[float, int]:
        """(distance m, walls crossed) from ``a`` to ``b``; acoustic and perfect links see no walls."""
        d = math.hypot(float(b[0]) - float(a[0]), float(b[1]) - float(a[1]))
        return d, (self.walls.crossed(a, b) if self.spec.model == "radio" else 0)

    def margin(self, a, b) -> float:
        """Mean margin (dB) of the direct hop from ``a`` to ``b``."""
        return ch.margin_db(self.spec, *self.hop(a, b))

    def probability(self, a, b) -> float:
        """Delivery probability of the direct hop from ``a`` to ``b``."""
        return ch.probability(self.spec, self.margin(a, b))

    def transmit(self, sender, receiver, size: int, send_time: float, rng: np.random.Generator,
                 channel: ch.Channel | None = None, via=()) -> ch.Delivery:
        """One message of ``size`` bytes from position ``sender`` to ``receiver`` at ``send_time``
        (s), through the relay positions ``via`` in order (radio); see
        :func:`planner.links.transmit` (one uniform per hop; none for ``perfect``)."""
        points = [sender, *via, receiver]
        hops = [self.hop(a, b) for a, b in zip(points[:-1], points[1:])]
        return ch.transmit(self.spec, hops, size, send_time, rng, channel)

    def graph(self, nodes) -> np.ndarray:
        """float ``[K, K]``: delivery probability of the direct hop between every two of the
        positions ``nodes`` ``[K, 2]`` (m)."""
        pts = np.asarray(nodes, dtype=float).reshape(-1, 2)
        k = len(pts)
        dist = np.hypot(pts[:, None, 0] - pts[None, :, 0], pts[:, None, 1] - pts[None, :, 1])
        walls = np.zeros((k, k), dtype=np.int64)
        if self.spec.model == "radio":
            for i in range(k):
                for j in range(i + 1, k):
                    walls[i, j] = walls[j, i] = self.walls.crossed(pts[i], pts[j])
        return ch.hop_probabilities(self.spec, dist, walls)

    def route(self, nodes, src: int, dst: int) -> tuple[tuple[int, ...], float]:
        """The best path (highest delivery probability) from node ``src`` to ``dst`` among the
        positions ``nodes``: (node indices, probability); see :func:`planner.links.best_path`."""
        return ch.best_path(self.graph(nodes), src, dst)

