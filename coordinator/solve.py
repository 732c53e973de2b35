"""``python -m coordinator.solve``: the earlier spelling of ``python -m planner.cli.solve`` (the
planner's command lines live in planner/cli/; this forward keeps the documented command working)."""
from __future__ import annotations

import sys

from planner.cli.solve import EXIT_INPUT, EXIT_OK, EXIT_PLANNER, build_parser, main  # noqa: F401

PROG = "python -m coordinator.solve"

if __name__ == "__main__":
    sys.exit(main(prog=PROG))
