"""Run a marsupial fleet mission from a clone: ``python run_fleet.py scenarios/six_carriers.yaml``.

The launcher is the package launcher/ (``python -m launcher``, or ``marsupial-fleet run`` once
installed); this script is its entry point from a clone that may not be installed. See
docs/fleet.md and ``python run_fleet.py --help``.
"""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))  # the clone's packages, installed or not

from launcher.main import main  # noqa: E402  (after the path set-up)

if __name__ == "__main__":
    sys.exit(main())
