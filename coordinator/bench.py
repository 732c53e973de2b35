"""``python -m coordinator.bench``: the MCTS benchmark, a thin entry point for
:mod:`planner.bench` (where the measurements and their documentation live)."""
from __future__ import annotations

import sys

from planner.bench import main

if __name__ == "__main__":
    sys.exit(main())
