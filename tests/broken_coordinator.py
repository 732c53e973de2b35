"""The project's coordinator with one rule of docs/protocol.md broken on purpose, for the
coordinator conformance kit's tests (tests/test_conformance.py): each break must fail the kit on
its named rule.

    python tests/broken_coordinator.py BREAK SCENARIO --role coordinator [launcher flags...]

BREAK is one of :data:`BREAKS`; the rest is the launcher's command line (python -m launcher).
"""
from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from coordinator.node import Coordinator  # noqa: E402


def no_accepted() -> None:
    """[P-5] Hellos go unanswered: no Accepted (Refusals still go out)."""
    answer = Coordinator._answer_hello

    def _answer_hello(self, cid, revision, refused=None):
        if refused is not None:
            answer(self, cid, revision, refused)

    Coordinator._answer_hello = _answer_hello


def select_all() -> None:
    """[P-6] every Decision selects every carrier, observed or not, with passengers or not."""

    def _plan(self, j):
        return tuple(sorted(self.ids)), 0.0, ()

    Coordinator._plan = _plan


def ignore_takeover() -> None:
    """[P-7] a newer epoch's Decision on its key is ignored: it goes on deciding and ends the mission."""
    from coordinator.epochs import Epochs

    Epochs.decision_heard = lambda self, payload: None


def no_token() -> None:
    """[P-2.5] it declares no liveliness token (its duplicate probe still runs)."""
    from wire.transport import Node

    declare = Node.token
    Node.token = lambda self, key: None if key.endswith("/coordinator/alive") else declare(self, key)


BREAKS = {"no-accepted": no_accepted, "select-all": select_all, "ignore-takeover": ignore_takeover,
          "no-token": no_token}

if __name__ == "__main__":
    BREAKS[sys.argv[1]]()
    from launcher.main import main

    sys.exit(main(sys.argv[2:], prog="broken_coordinator"))
