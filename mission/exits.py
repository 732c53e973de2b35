"""Exit statuses of the fleet's processes (run_fleet.py's roles, the viewer): part of the command
line contract, defined once."""
from __future__ import annotations

#: Stopped before the mission ended (SIGINT/SIGTERM, or a stop request): 128 + SIGINT, the shell's
#: convention for a process ended by Ctrl-C.
STOPPED = 130
#: Bad user input (scenario, flags, config files), and a process that refuses to start because its
#: role and id are taken (a live coordinator of the mission without --standby, a live carrier of
#: the same id): docs/fleet.md, "Split brain".
EXIT_USAGE = 2
#: A coordinator deposed by a coordinator of a higher epoch (it stopped deciding and published no
#: End).
EXIT_DEPOSED = 3
