"""One conformance run: the target, the harness, the observer, the faults and the rules put
together, and the loop that flies the mission."""
from __future__ import annotations

import gc
import shlex
import sys
import tempfile
import time
from pathlib import Path
from typing import Callable

from .. import messages as wm
from .faults import FAULTS, Faults
from .flight import CARRIER_TOPICS, UNANSWERED, Flight, Observer, Target
from .harness import Harness
from .rules import Result, evaluate
from .scripted import ScriptedCoordinator

#: After End, how long the carrier under test has to exit before the kit stops watching, seconds.
END_GRACE_S = 15.0
#: After the carrier under test exits, how long the kit still collects what it sent last, seconds.
EXIT_GRACE_S = 1.0
#: After the kit's sessions are closed, how long zenoh's threads are given to release them, seconds.
CLOSE_SETTLE_S = 0.5
#: How often the kit asks the coordinator for its rejection counts, seconds.
STATE_PERIOD_S = 1.0
#: The pace of the progress flight, simulated seconds per wall second.
PROGRESS_REALTIME = 2.0
#: The flights (``--flight``): who the coordinator is and what it does (the help prints these).
FLIGHT_TEXT = {
    "project": "the project's coordinator and the scenario's other carriers, with the faults of --faults",
    "scripted": "the kit is the coordinator (revision --revision, epoch 1): Accepted, a Decision as soon as "
                "the carrier has observed, the passenger to release named (the last on board), End",
    "progress": f"as scripted, on a paced mission (realtime {PROGRESS_REALTIME:g}, announced in Accepted, revision 4; "
                "give a carrier that does not read it the same pace in COMMAND): each stage takes its "
                "interval / realtime in wall time, long enough that Progress must come",
    "refusal": "the kit is the coordinator and refuses the carrier's Hello: first a Refusal naming another "
               "fingerprint (to be ignored), a second later one naming the carrier's (it must stop)",
    "older": "as scripted, the kit's coordinator speaking revision --revision (default 1 here): its State "
             "announces no revision, the carrier must speak revision 1 to it",
    "gap": "as scripted, with the Decision of stage 1 lost on its way: stage 2 is decided without the carrier "
           "and published while it waits at 1",
    "two-coordinators": "two coordinators of the kit, both live: epoch 2 truthful, epoch 1 deposed, publishing "
                        "a contradicting Decision of each stage from 1 on first and (revision 4) an End half-way",
    "two-ballots": "as two-coordinators, both of epoch 2 (revision 6, ballots): id kit-b truthful, id kit-a "
                   "deposed (its ballot is the lower); at a --revision below 6 the ids are not sent and the "
                   "flight is not run",
    "unanswered": f"as scripted, the carrier's first {UNANSWERED - 1} Hellos lost on their way (a lossy link): the "
                  f"kit answers the Hello said again {UNANSWERED - 1} times (it must be, [P-5.14]) and reads no "
                  "Observation before it",
}
FLIGHTS = tuple(FLIGHT_TEXT)


class Kit:
    """One conformance run (see the package docstring).

    Args:
        scenario_path: the scenario file.
        carrier: the id the carrier under test flies as.
        command: COMMAND and its ARGS, with ``{placeholder}`` (harness.PLACEHOLDERS).
        seed: root seed, overriding the scenario's.
        faults: the faults to make (a subset of :data:`FAULTS`).
        late_s: how long the late Decision is late, seconds.
        timeout_s: the longest mission, seconds.
        workdir: where the results and logs go (default: a new temporary directory).
        log: where progress lines go (default: stderr).
        flight: one of :data:`FLIGHTS` (the faults are the ``project`` flight's).
        revision: the revision the kit's own coordinator speaks (the other flights; default:
            this code's, 1 for ``older``).

    Raises:
        ValueError: the scenario has no such carrier (one line naming ``--carrier``).
    """

    def __init__(self, scenario_path: str, carrier: str, command: list[str], seed: int | None = None,
                 faults: tuple[str, ...] = FAULTS, late_s: float = 3.0, timeout_s: float = 120.0,
                 workdir: str | None = None, log: Callable[[str], None] | None = None, flight: str = "project",
                 revision: int | None = None):
        if flight not in FLIGHTS:
            raise ValueError(f"--flight: unknown flight {flight!r} (one of {', '.join(FLIGHTS)})")
        revision = revision if revision is not None else (1 if flight == "older" else wm.REVISION)
        if not 1 <= revision <= wm.REVISION or (flight == "older" and revision >= 3) or \
                (flight == "two-ballots" and revision < 6):
            raise ValueError(f"--revision: {revision} (1..{wm.REVISION}; below 3 for the older flight, 6 or later "
                             f"for two-ballots)")
        self.target = Target.load(scenario_path, carrier, seed)
        self.command = list(command)
        self.faults = tuple(faults)
        self.late_s = float(late_s)
        self.timeout_s = float(timeout_s)
        self.workdir = Path(workdir or tempfile.mkdtemp(prefix="conformance-"))
        self.log = log or (lambda line: print(line, file=sys.stderr, flush=True))
        self.flight = Flight(name=flight, revision=None if flight == "project" else revision)

    def run(self) -> list[Result]:
        """Fly the mission with the carrier under test, then judge it (:meth:`evaluate`)."""
        t = self.target
        with Harness(t, self.workdir) as harness:
            observer = Observer(t, self.flight, harness.node)
            scripted = self._coordinators(harness)
            if not scripted:
                harness.start_coordinator()
                harness.start_other_carriers()
            command = harness.expand(self.command)
            self.log(f"conformance: flight {self.flight.name}, mission {t.mission} on {harness.endpoint}; "
                     f"carrier {t.cid}: {shlex.join(command)}")
            under_test = harness.start_under_test(command)
            enabled = self.faults if not scripted else ()
            try:
                self._fly(harness, observer, Faults(t, self.flight, harness, observer, enabled, self.late_s),
                          under_test, scripted)
            finally:
                for coordinator in scripted:
                    coordinator.node.close(3.0)
                scripted.clear()
        # zenoh releases a closed session's callbacks on its own threads, taking the GIL: let
        # that happen now, not during the interpreter's finalisation (which aborts the process).
        gc.collect()
        time.sleep(CLOSE_SETTLE_S)
        return self.evaluate()

    def _coordinators(self, harness: Harness) -> list[ScriptedCoordinator]:
        """The kit's own coordinators of this flight (none for ``project``), each on a client
        session of the router."""
        from ..transport import Node
        from ..zconfig import make_config

        f, revision = self.flight, self.flight.revision
        if f.name == "project":
            return []

        def session():
            return Node(make_config("client", connect=[harness.endpoint]))

        hold = {j: 0.3 for j in range(self.target.n)}
        if f.name == "two-coordinators":
            return [ScriptedCoordinator(self.target, f, session(), 1, revision, deposed=True),
                    ScriptedCoordinator(self.target, f, session(), 2, revision, hold=hold)]
        if f.name == "two-ballots":
            return [ScriptedCoordinator(self.target, f, session(), 2, revision, deposed=True).named("kit-a"),
                    ScriptedCoordinator(self.target, f, session(), 2, revision, hold=hold).named("kit-b")]
        return [ScriptedCoordinator(self.target, f, session(), 1, revision, refuse=f.name == "refusal",
                                    realtime=PROGRESS_REALTIME if f.name == "progress" else 0.0,
                                    lose=1 if f.name == "gap" else None,
                                    answer_from=UNANSWERED if f.name == "unanswered" else 1)]

    def _fly(self, harness: Harness, observer: Observer, faults: Faults, under_test,
             scripted: list[ScriptedCoordinator]) -> None:
        """Watch the mission until the carrier under test has exited (and what it sent last is in),
        End came and it did not exit, or the timeout; faults are made as their triggers arrive."""
        deadline = time.monotonic() + self.timeout_s
        ended_at = exited_at = None
        last_state_query = 0.0
        while time.monotonic() < deadline:
            now = time.monotonic()
            harness.thaw_if_due(now)
            for coordinator in scripted:
                coordinator.step(now)
            if under_test.poll() is not None:
                exited_at = exited_at or now
                if now - exited_at > EXIT_GRACE_S:
                    break
            if ended_at is not None and now - ended_at > END_GRACE_S:
                break
            if now - last_state_query > STATE_PERIOD_S and not harness.frozen and not observer.gone:
                last_state_query = now
                observer.poll_rejections()
            item = harness.node.next(0.05)
            while item is not None:
                seen = observer.take(item)
                if seen is not None and seen.topic == "end" and ended_at is None:
                    ended_at = time.monotonic()
                    observer.poll_rejections()
                if (seen is not None and seen.topic in CARRIER_TOPICS
                        and isinstance(seen.message, (wm.Observation, wm.Confirm))):
                    faults.react(seen)
                item = harness.node.next(0.0)
        observer.bank_rejections()
        harness.thaw()
        self.flight.exit_code, self.flight.output = harness.finish(
            under_test, max(1.0, deadline - time.monotonic()))

    def evaluate(self) -> list[Result]:
        """Every rule judged on :attr:`flight`."""
        return evaluate(self.target, self.flight)
