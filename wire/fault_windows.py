"""A fault schedule's message faults on a real fleet (``run_fleet.py --schedule``;
:mod:`launcher.faults`): each receiving process drops what a ``loss`` window or a carrier cut off
(``partition``) would lose, on top of the scenario's links (:mod:`wire.link_filter`).

The one-host launcher writes the windows in force to a small JSON file (``{"loss": [p, ...],
"cut": [id, ...]}``, replaced atomically as faults strike and end) and names it to its children
in the environment (:data:`ENV`); :func:`wire.link_filter.link_filter` then puts a
:class:`FaultWindows` in front of the process's links. Without it nothing changes.

A loss window drops each message it sees with its probability, from a Generator of the
receiver's own (the root seed, 5, the receiver's index: the coordinator's 0, carrier r's r + 1);
a carrier cut off hears nothing and is heard by nobody. Liveliness tokens are the session's
state, not messages: a cut carrier's token stays (a real partition's vanishes a lease later).
"""
from __future__ import annotations

import json
import os

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


class FaultWindows:
    """The windows in force, read from ``path`` whenever it changes, applied to what ``receiver``
    receives; ``inner``: the scenario's link filter (None on perfect links)."""

    def __init__(self, path: str, mission: str, receiver: str, ids, seed: int, inner=None):
        self.path, self.mission, self.receiver, self.inner = path, mission, receiver, inner
        index = 0 if receiver not in ids else 1 + list(ids).index(receiver)
        self.rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, 5, index])
        self.stamp = None
        self.loss: tuple = ()
        self.cut: frozenset = frozenset()
        self.dropped = 0

    def _read(self) -> None:
        try:
            stamp = os.stat(self.path).st_mtime_ns
        except OSError:
            return
        if stamp == self.stamp:
            return
        try:
            windows = json.loads(open(self.path, encoding="utf-8").read())
            self.loss = tuple(float(p) for p in windows.get("loss", ()))
            self.cut = frozenset(str(h) for h in windows.get("cut", ()))
            self.stamp = stamp
        except (OSError, ValueError, TypeError, AttributeError):
            pass  # half-written by someone else: read again next time

    def delay(self, key: str, payload: bytes) -> float | None:
        """Wall seconds to hold the message received on ``key`` now, or None to drop it."""
        self._read()
        sender, kind = sender_of(self.mission, key)
        if kind not in UNFILTERED and sender != self.receiver:
            if self.receiver in self.cut or sender in self.cut or any(self.rng.random() < p for p in self.loss):
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
