"""``python -m experiments``: see :mod:`experiments.run`; ``python -m experiments check``: see
:mod:`experiments.check`."""
import sys

if sys.argv[1:2] == ["check"]:
    from experiments.check import main

    raise SystemExit(main(sys.argv[2:]))
from experiments.run import main

raise SystemExit(main())
