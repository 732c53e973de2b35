"""The planner's command lines: the one place in planner/ with argparse and exit codes.

* ``python -m planner.cli.solve``    one planner online over an instance file, as one JSON object;
* ``python -m planner.cli.bench``    the MCTS benchmark;
* ``python -m planner.cli.compile``  the planner's kernels compiled for this machine ahead of a first run;
* :mod:`planner.cli.measure`         ``python -m planner.online_optimal`` and ``python -m
  planner.clairvoyant`` (their modules' ``__main__`` blocks forward here);
* :mod:`planner.cli.conformance`     ``python -m planner.conformance`` (the kit is
  :mod:`planner.conformance`).

Each module imports the planner core and the standard library only (numpy included, as the core
does); nothing of planner/ imports these modules. The earlier spellings ``python -m
coordinator.solve`` and ``python -m coordinator.bench`` forward here.
"""
from __future__ import annotations

import argparse

#: Exit status of a usage error (bad arguments, unreadable input), with one line on stderr.
EXIT_USAGE = 2


class OneLineParser(argparse.ArgumentParser):
    """argparse whose usage errors are one line on stderr and exit :data:`EXIT_USAGE`."""

    def error(self, message: str):  # noqa: D401 - argparse hook
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message}\n")


def integer_at_least(minimum: int, unit: str = ""):
    """An argparse type for an integer >= ``minimum`` (``unit`` is named in the message)."""
    expected = f"an integer >= {minimum}" + (f" ({unit})" if unit else "")

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = minimum - 1
        if value < minimum:
            raise argparse.ArgumentTypeError(f"expected {expected}, found {text!r}")
        return value

    return parse
