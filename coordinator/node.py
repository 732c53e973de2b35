"""The coordinator process: a thin loop around the mission state machine and the planner core.

receive (wire/) → decode → mission event → ``mission.state.step`` → persist (mission.db) →
effects (publish, refuse, log). The mission rules live in mission/state.py; this module feeds
the machines their messages and clock ticks and carries out their effects: the I/O among them by
coordinator/effects.py, the planner call by coordinator/planning.py, the mission's opening by
coordinator/opening.py, each collaborator built once by coordinator/crew.py.

Stage j (docs/protocol.md, "Stage handshake"):

1. (``realtime > 0`` only) wait until ``Δt / realtime`` after decision j-1 was published (the
   carriers pace their physics from the same moment);
2. wait until every *expected* carrier (``MissionState.expected``: live, Hello accepted,
   scheduled at j) has sent its Observation of j. On the ``sim`` clock (every simulated
   mission) a carrier stops being waited for only when it fails: its liveliness token vanishes
   (it died, or its link's lease expired) or nothing at all, not even Progress, came from it for
   ``silence_timeout_s`` (it is stuck); on the ``wall`` clock (real robots) also after
   ``stage_timeout_s``;
3. plan with the offline loop's own stage step, guarded (:func:`mission.decide.stage_decision`
   around ``planner.online.stage_step``: the view
   ``make_view(problem, j, x, deployed)``, the stream ``stage_rng(seed, j)``); the ``Decided``
   event records the decision (and the scheduled carriers without an observation as ∅) before
   it is published; Confirms are collected while the next stage waits.

Recovery: started on a results directory whose mission.db holds a mission, the coordinator folds
its stored events through the same ``step`` (the state equals the one the previous process had),
re-publishes the last decision (carriers treat repeats idempotently) and continues at the first
undecided stage. Planners are stateless, so the continuation is exactly the one an uninterrupted
coordinator would have produced from the same observations.

Stopping: :meth:`Coordinator.stop` (what SIGINT/SIGTERM call, through a ``threading.Event``)
only sets a request that the loop honours between steps; a store write or a message is never cut
in half.
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass

from coordinator import opening, planning
from coordinator.clock import POLL_S, waits_of
from coordinator.crew import Crew
from coordinator.inbound import Unreadable
from coordinator.setup import MissionSetup
from mission import coordinator_life as cl
from mission import events as ev
from mission import state as ms
from mission import timers as tm
from mission.timeouts import DEFAULTS


@dataclass(frozen=True)
class CoordinatorConfig:
    """Settings of one coordinator run.

    Attributes:
        out_dir: results directory (mission.db, summary.json, map.png).
        mission: mission id (key-expression prefix); scenario name by default.
        planner, iterations, plan_ms: override the scenario's planner settings when not None.
        seed: overrides the scenario's root seed when not None (carriers must use the same).
        realtime: 0 = as fast as possible; F > 0 = stage j opens at wall time t_j / F.
        clock: ``sim`` (a simulated mission: live carriers that make progress are waited for)
            or ``wall`` (a real-time mission: ``stage_timeout_s`` is a deadline);
            :data:`mission.timeouts.CLOCKS`.
        join_timeout_s: wait this long (s) for every carrier's token and Hello before stage 0
            (on the sim clock: this long after the last carrier joined).
        stage_timeout_s: wall clock: wait this long (s) per stage for the expected observations.
        silence_timeout_s: sim clock: a waited-for carrier from which nothing has arrived for
            this long (s) is taken as stalled (∅ at this stage).
        confirm_timeout_s: after the last decision, wait this long (s) for its confirmations.
        bye_timeout_s: after End, wait this long (s) for carriers' Bye messages.
        rejoin_timeout_s: resumed on a mission on record, its join wait (s); None: the smaller
            of the join and the stage timeout (:func:`mission.timeouts.resumed_join`).
        end_repeat_s, bye_grace_s: End's repetition and a Bye's grace after its token's end
            (:class:`mission.timeouts.Timeouts`).
        render: draw map.png at the end.
        log: where progress lines go (a callable taking one string).
        record: write mission.mcap as the mission runs (recording/live.py).
        record_profile: the recording's MCAP profile, ``foxglove`` (mission.mcap) or ``ros2`` (the
            rosbag2 bag ros2bag/: recording/live.py).
        ros2: publish the mission as ROS 2 topics (``ros2.publisher.Ros2Settings``; None: off,
            nothing of ros2/ is imported).
        standby: when another coordinator of this mission is live, wait until its liveliness
            token vanishes and take over (else refuse to start: :class:`coordinator.epochs.DuplicateCoordinator`).
        operator: operator mode (:class:`console.hold.OperatorSettings`; None: the planner
            decides alone): each stage's decision waits for the operator's console.
        coordinator_id: this coordinator's id, with its epoch its ballot (docs/protocol.md,
            "Epochs"); None: ``<host>-<pid>`` (:func:`coordinator.epochs.default_ident`).
    """

    out_dir: str
    mission: str | None = None
    planner: str | None = None
    iterations: int | None = None
    plan_ms: float | None = None
    planner_options: tuple = ()  # (key, value) pairs of planner.registry.OPTIONS, override the scenario
    seed: int | None = None
    realtime: float = 0.0
    clock: str = "sim"
    join_timeout_s: float = DEFAULTS.join_s
    stage_timeout_s: float = DEFAULTS.stage_s
    silence_timeout_s: float = DEFAULTS.silence_s
    confirm_timeout_s: float = DEFAULTS.confirm_s
    bye_timeout_s: float = DEFAULTS.bye_s
    rejoin_timeout_s: float | None = None
    end_repeat_s: float = DEFAULTS.end_repeat_s
    bye_grace_s: float = DEFAULTS.bye_grace_s
    render: bool = True
    log: object = None
    record: bool = True  # write mission.mcap (recording/live.py)
    record_profile: str = "foxglove"
    ros2: object = None
    standby: bool = False
    operator: object = None
    coordinator_id: str | None = None


class Coordinator:
    """One coordinator process: an I/O loop around two pure machines, its mission state
    (``self.state``, :class:`mission.state.MissionState`, changed only by :meth:`apply`) and its
    lifecycle (``self.life``, :mod:`mission.coordinator_life`, changed only by :meth:`step`).
    :meth:`fly` feeds the lifecycle its clock and takes the inbox between its waits; both
    machines' effects are carried out here, their I/O by its hands on the world
    (:class:`coordinator.effects.MissionEffects`). Its collaborators (``self.crew``,
    :class:`coordinator.crew.Crew`) are given what they need and return what they read or
    build, calling nothing back; so do the mission's opening (:mod:`coordinator.opening`), the
    planner call (:mod:`coordinator.planning`) and the operator's console (a stage's hold is a
    generator of waits and events: :meth:`_asked`).

    Args:
        scenario: the loaded scenario (its seed is replaced by ``config.seed`` when given).
        config: :class:`CoordinatorConfig`.
        zconf: the zenoh config (wire.zconfig.make_config).
        scenario_path: shown in summary.json.
        stop: the stop request (a ``threading.Event``; a new one by default), set by
            :meth:`stop` or by a signal handler.
        clock: what it feeds its lifecycle (monotonic s; a test hands in its own).
    """

    def __init__(self, scenario, config: CoordinatorConfig, zconf, scenario_path: str = "",
                 stop: threading.Event | None = None, clock=time.monotonic):
        self.setup = setup = MissionSetup.build(scenario, config, zconf, scenario_path)  # its config checked
        self.config, self.clock = config, clock
        self._stop = stop if stop is not None else threading.Event()
        self.crew = Crew.build(setup, config, self._stop, clock)
        self.state = ms.initial(setup.spec)
        self.crew.answers.serve(self.state)
        self.life = cl.initial(waits_of(config), config.clock, config.realtime, scenario.stage_interval)
        self.console = None  # operator mode: the console (console.run.Console), opened with the mission

    node = property(lambda self: self.crew.effects.node)    # its session, once the mission opens
    store = property(lambda self: self.crew.effects.store)  # mission.db, once the mission opens

    def stop(self) -> None:
        """Ask the run loop to finish early (publishes End ``stopped``)."""
        self._stop.set()

    # ------------------------------------------------------------------ its mission state
    def apply(self, event) -> None:
        """Step the mission state with one event, then carry out its effects in order (store
        before publish: :meth:`coordinator.effects.MissionEffects.carry_out`), an event that
        follows one (a Decision published) applied at once."""
        before = self.state
        self.state, effects = ms.step(self.state, event)
        for effect in effects:
            then = self.crew.effects.carry_out(effect, self.state, getattr(event, "carrier", None))
            if then is not None:
                self.apply(then)
        if self.state is not before:
            self.crew.answers.serve(self.state)

    def pump(self, timeout_s: float) -> None:
        """Take what arrived, waiting up to ``timeout_s`` for it, in one mission.db batch
        (:meth:`coordinator.inbound.Inbound.arrivals`): each item's mission event applied, or what
        it asks instead carried out (a rejection, a claim's answer: ``Inbound.take``)."""
        with self.store.batch():
            for heard in self.crew.inbound.arrivals(self.node, timeout_s, self.store):
                said = self.crew.inbound.take(heard, self.state)
                if isinstance(said, (Unreadable, ms.Accept)):
                    self.crew.effects.carry_out(said, self.state)
                elif said is not None:
                    self.apply(said)

    # ------------------------------------------------------------------ its lifecycle
    def fly(self, until=None) -> None:
        """Its lifecycle until it is done or deposed (or ``until(life)`` holds), the clock fed as
        ticks (a stop request as ``Stopped``) and the inbox taken in between. A rule's inputs are
        the mission state, the time and when carriers were heard, and hearing one only delays a
        wait's end: so a :class:`mission.timers.Wait` stands until its ``until`` or a new state
        (most drains apply no event: Progress, Poses, about a thousand a second at R = 1,024)."""
        wake, seen, stopped = None, None, False
        while self.life.phase not in (cl.Phase.DONE, cl.Phase.DEPOSED) and not (until and until(self.life)):
            now = self.clock()
            if self.crew.epochs.deposed_by is not None:  # deposed: the newer coordinator ends the mission
                self.step(cl.Deposed())
                break
            if self._stop.is_set() and not stopped:
                stopped, wake = True, None
                self.step(cl.Stopped(now))
            if wake is None or self.state is not seen or now >= wake:
                seen, wake = self.state, self.step(cl.Tick(now))
                if wake is None:
                    continue
            self.pump(max(0.0, min(POLL_S, wake - now)))

    def step(self, event) -> float | None:
        """Step its lifecycle and carry out the effects: the time to wait until, None when it is
        to be stepped again at once."""
        self.life, effects = cl.step(self.life, event, cl.View(self.state, self.crew.inbound.heard))
        until = None
        for effect in effects:
            if isinstance(effect, tm.Wait):
                until = effect.until
            elif isinstance(effect, cl.Decide):
                decided = self.decide(effect.stage)  # recorded, then published (None: deposed)
                self.step(decided or cl.Deposed())
                if decided is not None:
                    self.pump(0.0)
            elif isinstance(effect, cl.RecordEnd):
                self.apply(ev.Ended(effect.reason, time.time()))
                self.crew.effects.end_recorded(self.state, effect.reason, self.crew.epochs)
            else:  # the stage's line, End published, a note
                self.crew.effects.life(effect, self.state)
        return until

    def decide(self, j: int) -> cl.Decided | None:
        """Plan stage j (:func:`coordinator.planning.deciding`: in operator mode the decision waits
        for the operator's console), record and publish its Decision: the lifecycle's ``Decided``
        with its planning ms (None: deposed, Epochs.fencing)."""
        decided = tm.drive(planning.deciding(self.setup, self.store, j, self.state, self.console), self._asked)
        with self.crew.epochs.fencing():
            self.apply(decided)  # records, then publishes
        return cl.Decided(j, self.clock(), decided.planning_ms) if self.crew.epochs.deposed_by is None else None

    def _asked(self, request) -> ms.MissionState:
        """What the stage's decision asks (the operator's hold: :meth:`console.hold.OperatorHold.decide`)
        and the planner's warm-up: a :class:`mission.timers.Wait` (the inbox taken until then, for
        a poll at most) or an event applied; the mission state after it."""
        if isinstance(request, tm.Wait):
            self.pump(max(0.0, min(POLL_S, request.until - self.clock())))
        else:
            self.apply(request.event)
        return self.state

    # ------------------------------------------------------------------ its run
    def run(self) -> dict:
        """Run (or resume) the mission to its end (:mod:`coordinator.opening`); write summary.json
        and map.png (:meth:`coordinator.results.Results.finish`): the summary dict."""
        opened = opening.open_mission(self.setup, self.config, self.crew, self._stop, self.clock)
        if opened is None:
            return {"ended": False, "standby": True}
        self.crew.effects.open(opened.node, opened.store)
        try:
            self._serve()
        finally:
            summary = self.crew.results.finish(self.clock() - opened.started, self.state, self.node, self.store)
            self.console and self.console.close()
        return summary

    def _serve(self) -> None:
        """Recover the state, then serve the mission to its end (or record that it was stopped
        before the session opened: nothing to tell anyone, but on record)."""
        self.state = opening.recovered(self.setup, self.store, self.crew)  # State answers from it
        if self.node is None or self._stop.is_set():
            self.apply(ev.Ended("stopped", time.time()))
            return
        self.console = opening.serve(self.node, self.setup, self.config, self.crew, self.store, self.clock, self._stop)
        tm.drive(opening.warming(self.setup, self.clock, self._stop), self._asked)  # Hellos answered meanwhile
        if self.state.next_stage > 0:  # idempotent re-publication
            self.apply(self.crew.effects.publish_decision(self.state, self.state.next_stage - 1))
        # The carriers' join, the stages, the last Confirms, End (not when deposed: the newer
        # coordinator ends the mission); a resumed complete mission only tells late carriers it is over.
        self.step(cl.Opened(self.clock()))
        self.fly()
