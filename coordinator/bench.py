"""``python -m coordinator.bench``: the earlier spelling of ``python -m planner.cli.bench`` (the
planner's command lines live in planner/cli/; this forward keeps the documented command and
``coordinator.bench.instance`` working)."""
from __future__ import annotations

import sys

from planner.cli.bench import instance, main  # noqa: F401

if __name__ == "__main__":
    sys.exit(main(prog="python -m coordinator.bench"))
