"""The scenario's link model applied to a real fleet's Zenoh messages (docs/fleet.md, "Links in
a real fleet"): a receive-side filter in each process (:class:`LinkFilter`, set on a
:class:`wire.transport.Node` as ``node.links``) that delivers, delays or drops each message it
receives by :func:`planner.links.transmit`, from the sender's and the receiver's latest known
positions.

Positions: a coordinator is at the base (``links.base``, else the first carrier's first
waypoint: :class:`world.links.LinkModel`); the receiving carrier is where its body is (the
``here`` callback); a sending carrier is where its latest message with a ``position`` (an
Observation, a Confirm, an Own, a Pose) put it, and before any at the start of its planned path.
Radio messages take the best path through the base, the other carriers' latest positions and
the relays dropped by then (:class:`world.fleet_links.FleetLinks`).

What it does not model: the acoustic channel is the one this receiver hears (the messages it
receives; a real modem also hears the others'), and liveliness tokens and Poses pass untouched
(tokens are the session's state, Poses are for viewers on the vessels' own network). Delays are
the model's seconds of mission time: divided by ``realtime`` when the mission is paced, as
they are when it is not (a modem's seconds).

``perfect`` links build no filter (:func:`link_filter` returns None): the real network is
untouched. Randomness: one Generator per receiver, derived from the root seed and the
receiver's index (the coordinator's is 0, carrier r's is r + 1).
"""
from __future__ import annotations

import time

import msgpack
import numpy as np

from planner import links as ch
from world.fleet_links import FleetLinks

from .fault_windows import fault_windows, sender_of
from .sizes import link_sizes

#: Message kinds that are not carried over the links (viewers' traffic).
UNFILTERED = ("pose",)


class LinkFilter:
    """One receiving process's view of the links.

    Args:
        scenario: the mission's scenario (``links`` not ``perfect``).
        mission: the mission id (to read the keys).
        receiver: ``coordinator`` or a carrier id.
        here: the receiver's position now (m), for a carrier; None for a coordinator (the base).
        realtime: the mission's pace (simulated s per wall s; 0 unpaced).
    """

    def __init__(self, scenario, mission: str, receiver: str, here=None, realtime: float = 0.0):
        self.links = FleetLinks(scenario, link_sizes(scenario))
        self.spec: ch.LinkSpec = scenario.links
        self.mission, self.receiver, self.here = mission, receiver, here
        self.pace = float(realtime) if realtime and realtime > 0 else 1.0
        index = 0 if receiver not in self.links.ids else 1 + self.links.ids.index(receiver)
        self.rng = np.random.default_rng([int(scenario.seed) & 0xFFFFFFFF, 4, index])
        self.positions = {cid: tuple(map(float, c.waypoints[0])) for cid, c in zip(self.links.ids, scenario.carriers)}
        self.stage = 0
        self.channel = ch.Channel()
        self.t0 = time.monotonic()
        self.sent = self.lost = self.oversized = 0

    # -------------------------------------------------------------- what a message says
    def _sender(self, key: str) -> tuple[str, str]:
        """(sender, kind) of a key (:func:`wire.fault_windows.sender_of`)."""
        return sender_of(self.mission, key)

    def _learn(self, sender: str, payload: bytes) -> None:
        try:
            body = msgpack.unpackb(payload, raw=False, strict_map_key=False)
        except Exception:
            return
        if not isinstance(body, dict):
            return
        pos = body.get("position")
        if sender in self.positions and isinstance(pos, (list, tuple)) and len(pos) == 2:
            try:
                self.positions[sender] = (float(pos[0]), float(pos[1]))
            except (TypeError, ValueError):
                pass
        stage = body.get("stage")
        if isinstance(stage, int) and not isinstance(stage, bool):
            self.stage = max(self.stage, stage)

    def where(self, name: str) -> tuple[float, float]:
        if name == self.receiver and self.here is not None:
            return tuple(map(float, self.here()))
        return self.links.model.base if name not in self.positions else self.positions[name]

    # -------------------------------------------------------------- the fate of one message
    def delay(self, key: str, payload: bytes) -> float | None:
        """Wall seconds to hold the message received on ``key`` now, or None to drop it."""
        sender, kind = self._sender(key)
        self._learn(sender, payload)
        if kind in UNFILTERED or sender == self.receiver:
            return 0.0
        a, b = self.where(sender), self.where(self.receiver)
        hops = self.links.path(a, b, (p for c, p in self.positions.items() if c not in (sender, self.receiver)),
                               dict.fromkeys(self.links.ids, self.stage))
        now = (time.monotonic() - self.t0) * self.pace
        size = len(payload)
        if self.spec.model == "acoustic" and size > self.spec.frame_bytes:
            # the scenario check bounds every kind; one longer (a State of the whole fleet) is
            # counted and sent as a frame's worth, not refused: it is not the model's to refuse
            self.oversized += 1
            size = self.spec.frame_bytes
        fate = ch.transmit(self.spec, hops, size, now, self.rng, self.channel)
        if fate.channel is not None:
            self.channel = fate.channel
        self.sent += 1
        if not fate.delivered:
            self.lost += 1
            return None
        return max(0.0, fate.time - now) / self.pace


def link_filter(scenario, mission: str, receiver: str, here=None, realtime: float = 0.0) -> LinkFilter | None:
    """The receive filter of ``receiver`` on the scenario's links; None on ``perfect`` links (the
    network untouched). A fault schedule's message faults go in front of it when the one-host
    launcher flies one (:func:`wire.fault_windows.fault_windows`)."""
    inner = None if scenario.links.model == "perfect" else LinkFilter(scenario, mission, receiver, here, realtime)
    return fault_windows(scenario, mission, receiver, inner)
