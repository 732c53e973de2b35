"""Exit statuses of the fleet's processes (run_fleet.py's roles, the viewer): part of the command
line contract, defined once."""
from __future__ import annotations

#: Stopped before the mission ended (SIGINT/SIGTERM, or a stop request): 128 + SIGINT, the shell's
#: convention for a process ended by Ctrl-C.
STOPPED = 130
