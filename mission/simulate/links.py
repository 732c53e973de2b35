"""The scenario's link model on the simulated network (docs/fleet.md, "Links in the simulator"):
every message between two participants is delivered, delayed or lost by
:func:`planner.links.transmit`, from a Generator of its own derived from the mission's seed.

The geometry is the caller's (``Fleet.links``, a :class:`world.fleet_links.FleetLinks` built by
:mod:`launcher.simulate`): this module asks it for the hops between two participants where they
are now — a carrier at the planned position of the stage it is at, a coordinator at the base,
the relays dropped by then — and the size of a message kind, so mission/ imports nothing of
pymunk. ``perfect`` links build no :class:`LinkLayer` at all: the network and its draws are
exactly those of a mission without a link model.

Acoustic: one shared half-duplex channel for the whole fleet. A message waits until the channel
is free, occupies it for its airtime and arrives distance / sound speed after its last bit; a
message sent to several receivers at once (a Decision, a message to both coordinators) is one
transmission, each receiver drawing its own fate; so is a carrier's Observation, Own or Progress
and the copy its listening peers get (one publication on the wire).

Liveliness tokens are not messages: they are the Zenoh session's state and the link model does
not touch them (as in the real fleet, whose filter acts on samples only).
"""
from __future__ import annotations

import numpy as np

from planner import links as ch


class LinkLayer:
    """One mission's link state: its Generator, the acoustic channel, the transmission in
    progress (a message to several receivers is sent once)."""

    def __init__(self, sim, links, seed: int):
        self.sim, self.links = sim, links
        self.spec: ch.LinkSpec = links.spec
        self.rng = np.random.default_rng([int(sim.fleet.seed) & 0xFFFFFFFF, int(seed), 3])
        self.channel = ch.Channel()
        self._sending: tuple | None = None    # ((src, wire kind, stage, send time), start of its transmission)
        self.sent = self.lost = 0

    def stages(self) -> dict:
        """carrier -> the stage it is at (0 before its process started)."""
        return {cid: (d.machine.stage if getattr(d, "machine", None) is not None else 0)
                for cid, d in self.sim.carriers.items()}

    def delay(self, src: str, dst: str, m) -> float | None:
        """Seconds the link adds to ``m`` from ``src`` to ``dst`` sent now, or None when it is lost."""
        sim = self.sim
        stages = self.stages()
        alive = [cid for cid, d in sim.carriers.items() if d.alive]
        hops = self.links.between(src, dst, stages, alive)
        size = self.links.size(m.kind)
        # one put reaches the coordinators and the listening peers alike (an Observation and its
        # peers' copy are one publication on the wire): one transmission, whatever the receivers
        sending = (src, self.links.wire_kind(m.kind), m.get("stage"), sim.t)
        if self._sending is not None and self._sending[0] == sending:
            # another receiver of the same transmission: its start and airtime, its own fate
            fate = ch.transmit(self.spec, hops, size, self._sending[1], self.rng)
        else:
            fate = ch.transmit(self.spec, hops, size, sim.t, self.rng, self.channel)
            if fate.channel is not None:
                self.channel = fate.channel
            self._sending = (sending, fate.start)
        self.sent += 1
        if not fate.delivered:
            self.lost += 1
            return None
        return fate.time - sim.t
