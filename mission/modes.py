"""How a carrier gets its decisions (docs/fleet.md, "Without the coordinator"): the one home of
the mode names. A :class:`Mode` is a ``str``, so a mode read from a command line or a config
compares equal to its member."""
from __future__ import annotations

import enum


class Mode(str, enum.Enum):
    HYBRID = "hybrid"                # the coordinator decides; without it (or none in time), on board
    DECENTRALISED = "decentralised"  # no coordinator at all: every carrier decides on board
    COORDINATED = "coordinated"      # only the coordinator decides; without it a carrier holds, then exits

    def __str__(self) -> str:
        return self.value


#: The modes' names, the default first.
MODES = tuple(m.value for m in Mode)
