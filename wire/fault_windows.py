"""A fault schedule's message faults on a real fleet (``run_fleet.py --schedule``;
:mod:`launcher.faults`): each receiving process drops what a ``loss`` window or a carrier cut off
(``partition``) would lose, on top of the scenario's links (:mod:`wire.link_filter`).

The one-host launcher writes the windows in force to a small JSON file (``{"loss": [p, ...],
"cut": [id, ...], "jumps": {host: s, ...}}``, replaced atomically as faults strike and end) and
names it to its children in the environment (:data:`ENV`); :func:`wire.link_filter.link_filter`
then puts a :class:`FaultWindows` in front of the process's links, and the processes read their
clock through :func:`fault_clock`. Without it nothing changes.

A loss window drops each message it sees with its probability, from a Generator of the
receiver's own (the root seed, 5, the receiver's index: the coordinator's 0, carrier r's r + 1);
a carrier cut off hears nothing and is heard by nobody. Liveliness tokens are the session's
state, not messages: a cut carrier's token stays (a real partition's vanishes a lease later).

A clock jump (``clock-jump``) moves a host's clock forward: ``jumps`` holds each host's total
(s), and the clock its lifecycle and waits read (the ``clock`` a Carrier or Coordinator is
given) is ``time.monotonic()`` plus it — the simulator's ``Clock.jumped``. Everything else in the
process (Zenoh's leases, the physics) keeps the real clock, as in the simulator.
"""
from __future__ import annotations

import json
import os
import time

import numpy as np

from . import keys

#: The environment variable naming the windows' file.
ENV = "MARSUPIAL_FAULT_WINDOWS"
#: Message kinds never dropped (viewers' traffic: not carried over the links).
UNFILTERED = ("pose",)


def sender_of(mission: str, key: str) -> tuple[str, str]:
    """(sender, kind) of a key: a carrier's topic, or the coordinator's (``accepted`` and
    ``refusal`` end with the carrier's id)."""
    parsed = keys.parse_carrier_key(mission, key)
    if parsed is not None:
        return parsed
    parts = key.split("/")
    return "coordinator", parts[3] if len(parts) > 3 else parts[-1]


class _Windows:
    """The windows' file, read again whenever it changes: ``loss``, ``cut``, ``jumps``."""

    def __init__(self, path: str):
        self.path = path
        self.stamp = None
        self.loss: tuple = ()
        self.cut: frozenset = frozenset()
        self.jumps: dict = {}

    def read(self) -> "_Windows":
        try:
            stamp = os.stat(self.path).st_mtime_ns
        except OSError:
            return self
        if stamp == self.stamp:
            return self
        try:
            windows = json.loads(open(self.path, encoding="utf-8").read())
            self.loss = tuple(float(p) for p in windows.get("loss", ()))
            self.cut = frozenset(str(h) for h in windows.get("cut", ()))
            self.jumps = {str(h): float(s) for h, s in windows.get("jumps", {}).items()}
            self.stamp = stamp
        except (OSError, ValueError, TypeError, AttributeError):
            pass  # half-written by someone else: read again next time
        return self


class FaultWindows:
    """The windows in force, read from ``path`` whenever it changes, applied to what ``receiver``
    receives; ``inner``: the scenario's link filter (None on perfect links)."""

    def __init__(self, path: str, mission: str, receiver: str, ids, seed: int, inner=None):
        self.mission, self.receiver, self.inner = mission, receiver, inner
        self.windows = _Windows(path)
        index = 0 if receiver not in ids else 1 + list(ids).index(receiver)
        self.rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, 5, index])
        self.dropped = 0

    def delay(self, key: str, payload: bytes) -> float | None:
        """Wall seconds to hold the message received on ``key`` now, or None to drop it."""
        w = self.windows.read()
        sender, kind = sender_of(self.mission, key)
        if kind not in UNFILTERED and sender != self.receiver:
            if self.receiver in w.cut or sender in w.cut or any(self.rng.random() < p for p in w.loss):
                self.dropped += 1
                return None
        return 0.0 if self.inner is None else self.inner.delay(key, payload)


def fault_windows(scenario, mission: str, receiver: str, inner=None):
    """``inner`` behind the windows of :data:`ENV`'s file when the launcher names one, else
    ``inner`` itself."""
    path = os.environ.get(ENV)
    if not path:
        return inner
    return FaultWindows(path, mission, receiver, scenario.carrier_ids, scenario.seed, inner)


class JumpedClock:
    """``base()`` plus the jumps of ``host`` in the windows' file (read at most every
    ``every_s``): never earlier than it was, since a jump only adds."""

    def __init__(self, path: str, host: str, base=time.monotonic, every_s: float = 0.01):
        self.windows, self.host, self.base, self.every_s = _Windows(path), host, base, every_s
        self.jump = 0.0
        self._next = -float("inf")

    def __call__(self) -> float:
        now = self.base()
        if now >= self._next:
            self._next = now + self.every_s
            self.jump = max(self.jump, self.windows.read().jumps.get(self.host, 0.0))
        return now + self.jump


def fault_clock(host: str, base=time.monotonic):
    """The clock ``host``'s process feeds its lifecycle: ``base`` plus the schedule's clock jumps
    of ``host`` when the launcher names a windows' file (:data:`ENV`), else ``base`` itself."""
    path = os.environ.get(ENV)
    return base if not path else JumpedClock(path, host, base)
