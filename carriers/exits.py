"""How a carrier's run ends: its exit reasons and the process exit code each maps to."""
from __future__ import annotations

from mission.exits import STOPPED

#: Exit reasons and the process exit code each maps to.
EXIT_CODES = {"end": 0, "finished": 0, "stopped": STOPPED, "coordinator-lost": 1, "world-mismatch": 2, "refused": 2,
              "log-mismatch": 2, "ros2-mismatch": 2}


class Exit(Exception):
    """Leave the run loop with an exit reason (a key of :data:`EXIT_CODES`)."""

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason
