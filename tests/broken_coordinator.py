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

from coordinator.effects import MissionEffects  # noqa: E402


def _patch(owner, name: str, value) -> None:
    """``owner.name = value``; what a break replaces must exist (a renamed hook would leave the
    coordinator unbroken and its test passing for the wrong reason)."""
    if not hasattr(owner, name):
        raise SystemExit(f"broken_coordinator: {owner.__name__} has no {name!r} to break")
    setattr(owner, name, value)


def no_accepted() -> None:
    """[P-5] Hellos go unanswered: no Accepted (Refusals still go out)."""
    answer = MissionEffects.answer_hello

    def answer_hello(self, state, cid, revision, refused=None):
        if refused is not None:
            answer(self, state, cid, revision, refused)

    _patch(MissionEffects, "answer_hello", answer_hello)


def select_all() -> None:
    """[P-6] every Decision selects every carrier, observed or not, with passengers or not."""
    import time

    import coordinator.planning as planning
    from mission import events as ev

    _patch(planning, "planned", lambda setup, store, j, st: ev.Decided(j, tuple(sorted(setup.ids)), 0.0, time.time(), ()))


def ignore_takeover() -> None:
    """[P-7] a newer epoch's Decision on its key is ignored: it goes on deciding and ends the mission."""
    from coordinator.epochs import Epochs

    _patch(Epochs, "decision_heard", lambda self, payload: None)


def no_token() -> None:
    """[P-2.5] it declares no liveliness token (its duplicate probe still runs)."""
    from wire.transport import Node

    declare = Node.token
    _patch(Node, "token", lambda self, key: None if key.endswith("/coordinator/alive") else declare(self, key))


BREAKS = {"no-accepted": no_accepted, "select-all": select_all, "ignore-takeover": ignore_takeover,
          "no-token": no_token}

if __name__ == "__main__":
    BREAKS[sys.argv[1]]()
    from launcher.main import main

    sys.exit(main(sys.argv[2:], prog="broken_coordinator"))
