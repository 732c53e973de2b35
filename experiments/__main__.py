"""``python -m experiments``: see :mod:`experiments.run`."""
from experiments.run import main

raise SystemExit(main())
