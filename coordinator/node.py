"""The coordinator process: a thin loop around the mission state machine and the planner core.

receive (wire/) → decode → mission event → ``mission.state.step`` → persist (mission.db) →
effects (publish, refuse, log). The mission rules live in mission/state.py; this module keeps
the stage clock and timers, calls the planner, and moves bytes.

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
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mission.decide import FALLBACK_PLANNER, stage_decision
from coordinator.clock import StageClock
from coordinator.epochs import Epochs, default_ident
from coordinator.inbound import Inbound
from coordinator.recorder import Recording, start as start_recording
from coordinator.results import results_for
from coordinator.setup import MissionSetup
from storage.missiondb import MissionStore
from mission import events as ev
from mission import state as ms
from mission.timeouts import CLOCKS, DEFAULTS
from wire import keys
from wire.messages import (
    ACCEPTED_MAX, MAX_STATE_CARRIERS, REVISION, UNANNOUNCED_REVISION, Accepted, CarrierState, Decision, End, State,
    defined_in, encode, refusal,
)
from wire.link_filter import link_filter
from wire.transport import Node

def warm_up(planner: tuple, problem, log) -> None:
    """The planner's ``warm_up(problem)`` if it has one; a plug-in's that raises is logged (its
    decisions are guarded one by one: :func:`plan_step`)."""
    planner, name = planner
    warm = getattr(planner, "warm_up", None)
    if callable(warm):
        try:
            warm(problem)
        except Exception as exc:
            log(f"coordinator: planner {name!r} warm_up raised {type(exc).__name__}: {exc}")


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


@dataclass
class Told:
    """What State tells each carrier of what this process refused or rejected of it
    (docs/protocol.md, "Rejections"): per carrier, counts per reason (``counts``; a new Counter
    at every change: State reads it from another thread) and its last Hello's refusal."""

    counts: dict = field(default_factory=dict)
    refusals: dict = field(default_factory=dict)

    @classmethod
    def of(cls, ids) -> "Told":
        return cls({cid: Counter() for cid in ids})


def plan_step(c: "Coordinator", j: int, constraints=None):
    """Stage j's step on coordinator ``c``'s mission state (:func:`mission.decide.stage_decision`:
    guarded, within the planner's ``plan_ms`` budget), under the operator's ``constraints``
    (:class:`planner.constraints.Constraints`; None: none). A planner fault is logged and
    recorded in mission.db (``planner-fault``: summary.json ``planner_faults``); the stage is
    decided by :data:`mission.decide.FALLBACK_PLANNER`."""

    def fault(f) -> None:
        c.log(f"coordinator: {f.line(c.setup.planner_name)}; stage {f.stage} decided by {FALLBACK_PLANNER}")
        c.store.event("planner-fault", None, f.stage, rule=f.rule, detail=f.detail, planner=c.setup.planner_name,
                      fallback=FALLBACK_PLANNER)

    return stage_decision(c.setup.problem, c.state, j, c.setup.planner, c.setup.seed, constraints,
                          getattr(c.setup.planner, "plan_ms", None), fault)


def _planned(c: "Coordinator", j: int) -> ev.Decided:
    """Stage j's decision by the planner alone (deploying ids sorted, with their passengers)."""
    step = plan_step(c, j)
    rs = sorted(np.flatnonzero(step.deploy), key=lambda r: c.setup.ids[r])
    return ev.Decided(j, tuple(c.setup.ids[r] for r in rs), step.decision_ms, time.time(),
                      tuple(int(step.passengers[r]) for r in rs))


class Coordinator:
    """One coordinator process: the Zenoh node, the store, the stage clock, and the mission state
    (``self.state``, a :class:`mission.state.MissionState` changed only by :meth:`apply`).

    Its jobs live in collaborators it holds, each given what it needs: what it receives
    (:class:`coordinator.inbound.Inbound`, taken by :meth:`pump`), its waits and stage loop
    (:class:`coordinator.clock.StageClock`), split brain and its session
    (:class:`coordinator.epochs.Epochs`), the recorder (:class:`coordinator.recorder.Recording`),
    the results (:class:`coordinator.results.Results`); this class keeps the state, the answers
    (State, Accepted, Refusal), the planner call and the run's opening.

    Args:
        scenario: the loaded scenario (its seed is replaced by ``config.seed`` when given).
        config: :class:`CoordinatorConfig`.
        zconf: the zenoh config (wire.zconfig.make_config).
        scenario_path: shown in summary.json.
        stop: the stop request (a ``threading.Event``; a new one by default), set by
            :meth:`stop` or by a signal handler.
        clock: what its waits read (monotonic s; a test hands in its own).
    """

    def __init__(self, scenario, config: CoordinatorConfig, zconf, scenario_path: str = "",
                 stop: threading.Event | None = None, clock=time.monotonic):
        self.setup = setup = MissionSetup.build(scenario, config, zconf, scenario_path)
        self.config = config
        self.state = ms.initial(self.setup.spec)
        self._served = self.state  # what State queries answer from: stored already
        self._stop = stop if stop is not None else threading.Event()
        self.node: Node | None = None
        self.store: MissionStore | None = None
        self.recording = Recording(self.setup.mission, self.setup.spec.has, self.log)  # mission.mcap, the ROS 2 topics
        self.told = Told.of(setup.ids)  # what State tells each carrier of what this process refused of it
        if config.clock not in CLOCKS:
            raise ValueError(f"clock must be one of {CLOCKS}, found {config.clock!r}")
        self.clock = clock  # what its waits read (mission.timers decides); the inbox's clock
        self.epochs = Epochs(self.setup.mission, self.log, self._stop, self.clock,  # split brain (docs/fleet.md)
                             config.coordinator_id or default_ident())
        self.inbound = Inbound(self.setup.mission, self.setup.spec.has, self.setup.fingerprint, self.epochs, self.recording)
        self.stage_clock = StageClock(config, self.setup.spec, scenario.stage_interval, self.setup.mission, self.epochs, self._stop,
                                      self.clock, self.log)
        self.results = results_for(scenario, self.setup.scenario_path, self.setup.mission, self.setup.planner_name, self.setup.planner_options,
                                   self.setup.seed, (config.render, self.log, self.epochs, self.recording))
        self.console = None  # operator mode: the console (console.run.Console), opened with the mission

    # ------------------------------------------------------------------ views of the state
    def log(self, line: str) -> None:
        self.setup.log(line)

    def stop(self) -> None:
        """Ask the run loop to finish early (publishes End ``stopped``)."""
        self._stop.set()

    @property
    def next_stage(self) -> int:
        return self.state.next_stage

    @property
    def ended(self) -> bool:
        return self.state.ended

    @property
    def resumed(self) -> bool:
        return self.state.resumed

    def deployed(self) -> np.ndarray:
        """bool ``[R, N]``: the planner's view of the past (:meth:`mission.state.MissionState.deployed`)."""
        return self.state.deployed()

    def _decision(self, j: int, st: ms.MissionState | None = None) -> Decision:
        """The Decision of stage j as published: from ``st`` (the current state by default)."""
        d = (self.state if st is None else st).decisions[j]
        return Decision(self.setup.mission, j, self.setup.spec.stage_times[j], d.deploy, d.planning_ms, self.epochs.epoch,
                        passengers=d.passengers, coordinator=self.epochs.ident)

    def _refresh_state(self) -> None:
        """From now on State queries answer from the current state (it is stored). O(1): the
        reply is built when asked (:meth:`state_reply`), not at every event."""
        self._served = self.state

    def state_reply(self, parameters: dict | None = None) -> bytes:
        """The encoded State a query gets (docs/protocol.md, "State"): ``?carrier=<id>`` lists
        that carrier only; an unscoped query lists every carrier of a mission of at most
        MAX_STATE_CARRIERS carriers, none of a larger one. Runs in the queryable's thread on an
        immutable snapshot."""
        st = self._served
        asked = keys.asked_revision(parameters, REVISION, UNANNOUNCED_REVISION)
        wanted = (parameters or {}).get("carrier")
        if wanted is not None:
            ids = [wanted] if self.setup.spec.has(wanted) else []
        else:
            ids = list(self.setup.ids) if len(self.setup.ids) <= MAX_STATE_CARRIERS else []
        carriers = tuple(sorted((cid, self._carrier_state(st, cid)) for cid in ids))
        last = self._decision(st.next_stage - 1, st) if (st.next_stage - 1) in st.decisions else None
        return encode(State(
            mission=self.setup.mission, next_stage=st.next_stage, stages=self.setup.n_stages, fingerprint=self.setup.fingerprint,
            ended=st.ended, carriers=carriers, last_decision=last, epoch=self.epochs.epoch, revision=REVISION,
            coordinator=self.epochs.ident), asked)

    def _carrier_state(self, st, cid: str) -> CarrierState:
        """One carrier's entry: its deployments as the planner sees them (its accounts, its
        Confirms, the decisions nobody answered)."""
        deployments = st.deployments_of(cid)
        left = self.setup.spec.passengers[self.setup.spec.index(cid)] - len(deployments)
        refused = None if cid in st.accepted else self.told.refusals.get(cid, "world-mismatch" if cid in st.refused else None)
        return CarrierState(int(left), tuple(deployments), cid in st.live, refused,
                            tuple(sorted(self.told.counts[cid].items())))

    # ------------------------------------------------------------------ the one way state changes
    def apply(self, event) -> None:
        """Step the mission state with one event, persist what it says to record, then carry out
        the other effects in order (store before publish)."""
        before = self.state
        self.state, effects = ms.step(self.state, event)
        for effect in effects:
            if isinstance(effect, ms.Record):  # the recorder gets it once mission.db has it
                self.store.record(effect, self.state, self.recording.event)
            elif isinstance(effect, ms.Reject):
                self._reject(effect.reason, effect.detail, getattr(event, "carrier", None))
            elif isinstance(effect, ms.Refuse):
                self._answer_hello(effect.carrier, effect.revision, effect)
            elif isinstance(effect, ms.Accept):
                self._answer_hello(effect.carrier, effect.revision)
            elif isinstance(effect, ms.Publish):
                self._refresh_state()
                self._publish_decision(self._decision(effect.stage))
            elif isinstance(effect, ms.Log):
                self.log(effect.line)
        if self.state is not before:
            self._refresh_state()

    def _reject(self, reason: str, detail: str, cid: str | None = None) -> None:
        first = reason not in self.node.rejected
        self.node.reject(reason, detail, lambda line: self.log(f"coordinator: {line}"))
        if first:
            self.store.event("rejected", reason=reason, detail=detail[:200])
        if cid in self.told.counts:  # what State tells that carrier (docs/protocol.md, "Rejections")
            self.told.counts[cid] = self.told.counts[cid] + Counter({reason: 1})  # a new value: State reads it from another thread

    def _answer_hello(self, cid: str, revision: int, refused: ms.Refuse | None = None) -> None:
        """Every Hello is answered (docs/protocol.md, "Refusal", "Accepted"), in the revision it
        announced: a Refusal (to an earlier revision's carrier as ``world-mismatch``, the only
        reason it has), or Accepted (revision 3 and later; earlier ones learn it from Decisions)."""
        revision = min(revision, REVISION)
        self.store.flush()  # the Hello is on record before its answer goes out
        if refused is not None:
            if cid in self.told.counts and cid not in self.state.accepted:
                self.told.refusals[cid] = refused.reason
            self.node.put(keys.refusal_key(self.setup.mission, cid), refusal(
                self.setup.mission, cid, refused.reason, refused.fingerprint, self.setup.fingerprint, refused.detail, revision),
                revision)
            return
        self.told.refusals.pop(cid, None)
        # The mission's clock (revision 4): a carrier times its waits by the coordinator's.
        answer = Accepted(self.setup.mission, cid, self.setup.fingerprint, self.state.accepted[cid].next_stage,
                          self.state.next_stage, REVISION, self.epochs.epoch, self.config.clock,
                          min(float(self.config.silence_timeout_s), ACCEPTED_MAX),
                          min(float(self.config.realtime), ACCEPTED_MAX), coordinator=self.epochs.ident)
        if defined_in(answer, revision):
            self.node.put(keys.accepted_key(self.setup.mission, cid), answer, revision)

    # ------------------------------------------------------------------ what it receives
    def pump(self, timeout_s: float) -> None:
        """Take what arrived, waiting up to ``timeout_s`` for it (:meth:`coordinator.inbound.Inbound.pump`)."""
        self.inbound.pump(self.node, self.store, timeout_s, self._take, self._reject, self._answer_hello)

    def _take(self, heard) -> None:
        """What one inbox item says (:class:`coordinator.inbound.Heard`): when its carrier was heard,
        the higher epoch it claims (on record, never adopted [P-7.3]), its mission event."""
        if heard.carrier is not None and (heard.progress is None or heard.progress <= self.state.next_stage):
            self.inbound.heard[heard.carrier] = heard.at  # when it arrived [P-10.5] (see Heard.progress)
        if heard.epoch is not None:
            self.epochs.carrier_claimed(heard.carrier, heard.epoch)
            if heard.carrier in self.state.accepted:  # [P-7.3] answered, changes nothing held of it
                self._answer_hello(heard.carrier, heard.event.revision)
                return
        if heard.event is not None:
            self.apply(heard.event)

    # ------------------------------------------------------------------ the stage clock's calls
    def decide(self, j: int) -> float | None:
        """Plan stage j, record and publish its Decision: its planning ms (None: deposed, Epochs.fencing).
        In operator mode the decision waits for the operator's console (:mod:`console.hold`)."""
        decided = self.console.decided(j, self) if self.console is not None else _planned(self, j)
        with self.epochs.fencing():
            self.apply(decided)  # records, then publishes
        return decided.planning_ms if self.epochs.deposed_by is None else None

    def put_end(self, end: End) -> None:
        """End, in the revision every carrier that said Hello reads (as the Decisions are)."""
        self.node.put(keys.end_key(self.setup.mission), end, self.state.common_revision(REVISION))

    def _publish_decision(self, decision: Decision) -> None:
        # In the revision every carrier that said Hello reads (docs/protocol.md, "Compatibility").
        self.store.flush()
        self.node.put(keys.decision_key(self.setup.mission), decision, self.state.common_revision(REVISION))
        self.apply(ev.Published(decision.stage, time.time()))

    def run(self) -> dict:
        """Run (or resume) the mission to its end; write summary.json and map.png.

        Returns:
            The summary dict.
        """
        from wire.zconfig import OpenStopped

        out = Path(self.config.out_dir)
        # The session first: a duplicate is refused (or waited for) before mission.db is touched.
        links = link_filter(self.setup.scenario, self.setup.mission, "coordinator", realtime=self.config.realtime)
        self.node, claimed = self.epochs.session(lambda: Node(self.setup.zconf, stop=self._stop, links=links),
                                                 self.config.standby)
        if not claimed:  # a standby stopped while the primary lived: nothing of ours to record
            self.log(f"coordinator: standby for mission {self.setup.mission} stopped; it never took over")
            return {"ended": False, "standby": True}
        started = self.clock()  # the mission's wall time: a standby's wait is not part of it
        out.mkdir(parents=True, exist_ok=True)
        self._open_mission(out)
        try:
            self._mission()
        except Exception as exc:
            if not isinstance(exc, OpenStopped):
                raise
            self.apply(ev.Ended("stopped", time.time()))
        finally:
            summary = self.results.finish(out, self.clock() - started, self.state, self.setup.problem, self.node, self.store,
                                          self.told.counts)
            self.console and self.console.close(self)
        return summary

    def _open_mission(self, out: Path) -> None:
        """mission.db (this process's epoch with it) and the recorder."""
        meta = {"mission": self.setup.mission, "scenario": self.setup.scenario.name, "fingerprint": self.setup.fingerprint,
                "seed": self.setup.seed, "planner": self.setup.planner_name, "planner_options": self.setup.planner_options}
        # Higher than every epoch used before for this mission: the ones in mission.db and the
        # one a primary reported while this process stood by; 1 for a fresh mission.
        try:
            self.store = self.epochs.open_store(out / "mission.db", meta)
        except BaseException:
            if self.node is not None:
                self.node.close(DEFAULTS.close_s)
            raise
        start_recording(self.recording, self.config, self.node, out, self.setup.scenario, self.setup.problem,
                        {k: meta[k] for k in ("mission", "scenario", "seed", "planner", "fingerprint")},
                        self.store.mission_events)

    def _mission(self) -> None:
        """Recover the state, then serve the mission to its end (or record that it was stopped
        before the session opened: nothing to tell anyone, but on record)."""
        # Recovery is the live fold over the stored events (the last one is this process's open).
        self.state = ms.fold(self.setup.spec, self.store.mission_events())
        self.epochs.first_stage = self.state.next_stage
        if self.state.resumed:
            self.log(f"coordinator: resumed from {self.store.path}: {len(self.state.decisions)} stage(s) "
                     f"decided, continuing at stage {self.state.next_stage}")
        self._refresh_state()
        if self.node is None or self._stop.is_set():
            self.apply(ev.Ended("stopped", time.time()))
            return
        self._serve()
        if self.config.operator is not None:  # operator mode only: nothing of console/ loads otherwise
            from console.run import open_console

            self.console = open_console(self, Path(self.config.out_dir), lambda j, given: plan_step(self, j, given))
        # Warmed up once State answers and the token is out: carriers that start meanwhile
        # find a coordinator (compiling the planner takes seconds, more on a busy host).
        if not self._stop.is_set():
            warm_up((self.setup.planner, self.setup.planner_name), self.setup.problem, self.log)
        if self.state.next_stage > 0:
            self._publish_decision(self._decision(self.state.next_stage - 1))  # idempotent re-publication
        self.stage_clock.serve(self)  # the carriers' join, the stages, the last Confirms, End

    def _serve(self) -> None:
        """Subscribe, watch the carriers' tokens, answer State, declare this coordinator's token."""
        self.inbound.subscribe(self.node)
        self.node.serve(keys.state_key(self.setup.mission), self.state_reply)
        self.node.token(keys.coordinator_alive(self.setup.mission))
        self.log(f"coordinator: mission {self.setup.mission}, {len(self.setup.ids)} carriers, {self.setup.n_stages} stages, "
                 f"planner {self.setup.planner_name} {self.setup.planner_options}, seed {self.setup.seed}, epoch {self.epochs.epoch}, "
                 f"{self.config.clock} clock")

