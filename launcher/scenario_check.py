"""``python -m world``, with the checks of the layers above world/: world/__main__.py's
``__main__`` block forwards here (docs/architecture.md), so that ``python -m world check``
also checks that the messages a stage needs fit the scenario's acoustic frames
(:func:`wire.sizes.frame_problems`), which world/ cannot import."""
from __future__ import annotations

import sys

from wire.sizes import frame_problems
from world.__main__ import main

#: What ``check`` runs on a loaded scenario besides world/'s own validation.
CHECKS = (frame_problems,)


def world_command(argv: list[str] | None = None) -> int:
    """``python -m world`` (and ``marsupial-fleet world``) with :data:`CHECKS`."""
    return main(sys.argv[1:] if argv is None else argv, checks=CHECKS)
