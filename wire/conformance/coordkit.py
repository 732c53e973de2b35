"""The kit for replacement coordinators (``python -m wire.conformance coordinator``): its
flights (:mod:`wire.conformance.coordflight`) judged by its rules
(:mod:`wire.conformance.coordrules`)."""
from __future__ import annotations

import gc
import shlex
import sys
import tempfile
import time
from pathlib import Path
from typing import Callable

from .coordflight import EXIT_S, FAULTS, Flight, Router, Seen
from .kit import CLOSE_SETTLE_S
from .coordrules import evaluate
from .fleet import World
from .rules import Result


class CoordinatorKit:
    """One conformance run of a coordinator (see the module docstring).

    Args:
        scenario_path: the scenario file.
        command: COMMAND and its ARGS, with ``{placeholder}`` (:data:`PLACEHOLDERS`).
        seed: root seed, overriding the scenario's.
        faults: the faults to make (a subset of :data:`FAULTS`).
        timeout_s: the longest flight, seconds.
        workdir: where COMMAND's files go (``DIR/<flight>``); default: a new temporary directory.
        log: where progress lines go (default: stderr).
    """

    def __init__(self, scenario_path: str, command: list[str], seed: int | None = None,
                 faults: tuple[str, ...] = FAULTS, timeout_s: float = 180.0, workdir: str | None = None,
                 log: Callable[[str], None] | None = None):
        self.world = World.load(scenario_path, seed)
        self.command = list(command)
        self.faults = tuple(faults)
        self.timeout_s = float(timeout_s)
        self.workdir = Path(workdir or tempfile.mkdtemp(prefix="conformance-coordinator-"))
        self.log = log or (lambda line: print(line, file=sys.stderr, flush=True))
        self.flights: list[Seen] = []

    def run(self) -> list[Result]:
        """Fly the main flight (and the takeover flight when asked for), then judge them."""
        main = tuple(f for f in self.faults if f != "takeover")
        self.flights = [self._flight("main", main)]
        if "takeover" in self.faults:
            self.flights.append(self._flight("takeover", ("takeover",)))
        return evaluate(self.world, self.flights)

    def _flight(self, name: str, faults: tuple[str, ...]) -> Seen:
        seen = Seen(name)
        with Router(self.world, self.workdir / name) as router:
            command = router.expand(self.command)
            self.log(f"conformance: flight {name}, mission {self.world.mission} on {router.endpoint}; "
                     f"coordinator: {shlex.join(command)}")
            router.start(command)
            flight = Flight(self.world, router, seen, faults, time.monotonic() + self.timeout_s)
            flight.fly()
            seen.exit_code, seen.output = router.finish(EXIT_S if seen.faults.get("takeover") is None else 0.1)
            seen.exited_at = time.monotonic()
            for played in flight.played.values():
                played.token = None  # the kit's carriers' tokens go with the router's session
        # zenoh releases a closed session's callbacks on its own threads, taking the GIL: let
        # that happen now, not during the interpreter's finalisation (which aborts the process).
        gc.collect()
        time.sleep(CLOSE_SETTLE_S)
        return seen
