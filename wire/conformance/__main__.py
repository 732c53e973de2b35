"""``python -m wire.conformance``: the kit's command line (wire.conformance.cli)."""
import sys

from .cli import main

sys.exit(main())
