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
3. plan with the offline loop's own stage step (``planner.online.stage_step``: the view
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

import os
import socket
import threading
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import world
from planner.registry import make_planner, planner_settings, used_options
from planner.online import stage_step
from coordinator.results import render_map, write_json as _write_json
from storage.missiondb import MissionStore, StoreBusy
from mission import events as ev
from mission import state as ms
from mission.peers import last_heard
from mission.summary import RunInfo, summary as mission_summary
from mission.timeouts import CLOCKS, DEFAULTS
from wire import keys
from wire.messages import (
    MAX_STATE_CARRIERS, REVISION, UNANNOUNCED_REVISION, Accepted, Bye, CarrierState, Confirm, Decision, End, Hello,
    Observation, Own, Pose, Progress, ProtocolError, State, announced, decode, defined_in, encode, refusal, scenario_fingerprint,
)
from wire.transport import Node

class DuplicateCoordinator(RuntimeError):
    """Another coordinator's liveliness token for this mission is live (and this one is no
    standby): refuse to start, before mission.db is touched."""

    def __init__(self, mission: str):
        super().__init__(f"mission {mission} already has a live coordinator; use --standby to wait for it, "
                         f"or another --mission")
        self.mission = mission


#: Which message type each carrier topic carries.
TOPIC_TYPES = {"hello": Hello, "obs": Observation, "confirm": Confirm, "own": Own, "bye": Bye,
               "progress": Progress}


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
        render: draw map.png at the end.
        log: where progress lines go (a callable taking one string).
        record: write mission.mcap as the mission runs (recording/live.py).
        record_profile: the recording's MCAP profile, ``foxglove`` (mission.mcap) or ``ros2`` (the
            rosbag2 bag ros2bag/: recording/live.py).
        ros2: publish the mission as ROS 2 topics (``ros2.publisher.Ros2Settings``; None: off,
            nothing of ros2/ is imported).
        standby: when another coordinator of this mission is live, wait until its liveliness
            token vanishes and take over (else refuse to start: :class:`DuplicateCoordinator`).
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
    render: bool = True
    log: object = None
    record: bool = True  # write mission.mcap (recording/live.py)
    record_profile: str = "foxglove"
    ros2: object = None
    standby: bool = False


def to_event(msg, at: float):
    """The mission event of a decoded carrier message received at ``at`` (s, epoch)."""
    if isinstance(msg, Hello):
        return ev.Hello(msg.carrier, msg.pid, msg.host, msg.passengers_left, msg.next_stage, msg.fingerprint, at,
                        msg.revision)
    if isinstance(msg, Observation):
        return ev.Observation(msg.carrier, msg.stage, msg.t, msg.x, msg.position, msg.passengers_left, msg.trail, at)
    if isinstance(msg, Confirm):
        return ev.Confirmed(msg.carrier, msg.stage, msg.deployed, msg.status, msg.position, msg.passengers_left, at,
                            msg.passenger)
    if isinstance(msg, Own):
        return ev.Accounted(msg.carrier, msg.stage, msg.t, msg.x, msg.deployed, msg.position, msg.passengers_left, at)
    if isinstance(msg, Bye):
        return ev.Bye(msg.carrier, msg.deployments, msg.rejected, msg.reason, at)
    raise TypeError(type(msg).__name__)


class Coordinator:
    """One coordinator process: the Zenoh node, the store, the stage clock, and the mission state
    (``self.state``, a :class:`mission.state.MissionState` changed only by :meth:`apply`).

    Args:
        scenario: the loaded scenario (its seed is replaced by ``config.seed`` when given).
        config: :class:`CoordinatorConfig`.
        zconf: the zenoh config (wire.zconfig.make_config).
        scenario_path: shown in summary.json.
        stop: the stop request (a ``threading.Event``; a new one by default), set by
            :meth:`stop` or by a signal handler.
    """

    def __init__(self, scenario, config: CoordinatorConfig, zconf, scenario_path: str = "",
                 stop: threading.Event | None = None):
        if config.seed is not None:
            scenario = scenario.with_seed(int(config.seed))
        self.scenario = scenario
        self.config = config
        self.zconf = zconf
        self.scenario_path = scenario_path or scenario.source
        self.seed = int(scenario.seed)
        self.mission = keys.check_id(config.mission or keys.mission_id_from_name(scenario.name), "mission")
        self.ids = scenario.carrier_ids
        self.problem = world.build_problem(scenario)
        self.n_stages = self.problem.n_stages
        self.planner_name, options = planner_settings(
            scenario, config.planner, config.iterations, config.plan_ms, config.planner_options)
        # Only the options this planner uses are kept (logged, stored in mission.db, summarised).
        self.planner_options = used_options(self.planner_name, options)
        self.planner = make_planner(self.planner_name, **self.planner_options)
        self.fingerprint = scenario_fingerprint(scenario)
        self.spec = ms.MissionSpec.build(self.ids, self.problem.valid, self.problem.passengers,
                                         scenario.stage_times(), self.fingerprint)
        self.state = ms.initial(self.spec)
        self._log = config.log or (lambda line: print(line, flush=True))
        self._served = self.state  # what State queries answer from: stored already
        self._stop = stop if stop is not None else threading.Event()
        self.node: Node | None = None
        self.store: MissionStore | None = None
        self.recorder = None  # recording.live.LiveRecorder while mission.mcap is written
        # Split brain (docs/fleet.md): this process's epoch (set when it opens mission.db), the
        # highest epoch a live primary reported while this one stood by, and the epoch of a
        # newer coordinator that deposed this one (None while not deposed).
        self.epoch = 1
        self.known_epoch = 0
        self._first_stage = 0  # the first stage this process decides (a newer epoch is taken before it)
        self.deposed_by: int | None = None
        # What State tells each carrier of what this process refused or rejected of it
        # (docs/protocol.md, "Rejections"): counts per reason, and its last Hello's refusal.
        self.told: dict[str, Counter] = {cid: Counter() for cid in self.ids}
        self.refusals: dict[str, str] = {}
        if config.clock not in CLOCKS:
            raise ValueError(f"clock must be one of {CLOCKS}, found {config.clock!r}")
        # When something last arrived from each carrier (monotonic s): what tells a slow carrier
        # (it sends Progress) from a stuck one on the sim clock. Not a mission event: not stored.
        self.heard: dict[str, float] = {}

    # ------------------------------------------------------------------ views of the state
    def log(self, line: str) -> None:
        self._log(line)

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

    def _decision(self, j: int) -> Decision:
        d = self.state.decisions[j]
        return Decision(self.mission, j, self.spec.stage_times[j], d.deploy, d.planning_ms, self.epoch,
                        passengers=d.passengers)

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
            ids = [wanted] if wanted in self.spec.carriers else []
        else:
            ids = list(self.ids) if len(self.ids) <= MAX_STATE_CARRIERS else []
        carriers = tuple(sorted((cid, self._carrier_state(st, cid)) for cid in ids))
        last = None
        if (st.next_stage - 1) in st.decisions:
            d = st.decisions[st.next_stage - 1]
            last = Decision(self.mission, st.next_stage - 1, self.spec.stage_times[st.next_stage - 1], d.deploy,
                            d.planning_ms, self.epoch, passengers=d.passengers)
        return encode(State(
            mission=self.mission, next_stage=st.next_stage, stages=self.n_stages, fingerprint=self.fingerprint,
            ended=st.ended, carriers=carriers, last_decision=last, epoch=self.epoch, revision=REVISION), asked)

    def _carrier_state(self, st, cid: str) -> CarrierState:
        """One carrier's entry: its deployments as the planner sees them (its accounts, its
        Confirms, the decisions nobody answered)."""
        deployments = st.deployments_of(cid)
        left = self.spec.passengers[self.spec.index(cid)] - len(deployments)
        refused = None if cid in st.accepted else self.refusals.get(cid, "world-mismatch" if cid in st.refused else None)
        return CarrierState(int(left), tuple(deployments), cid in st.live, refused,
                            tuple(sorted(self.told[cid].items())))

    # ------------------------------------------------------------------ the one way state changes
    def apply(self, event) -> None:
        """Step the mission state with one event, persist what it says to record, then carry out
        the other effects in order (store before publish)."""
        before = self.state
        self.state, effects = ms.step(self.state, event)
        for effect in effects:
            if isinstance(effect, ms.Record):
                self.store.record(effect, self.state)
                if self.recorder is not None:
                    self.recorder.event(effect.event)  # after mission.db has it
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
        if cid in self.told:  # what State tells that carrier (docs/protocol.md, "Rejections")
            self.told[cid] = self.told[cid] + Counter({reason: 1})  # a new value: State reads it from another thread

    def _answer_hello(self, cid: str, revision: int, refused: ms.Refuse | None = None) -> None:
        """Every Hello is answered (docs/protocol.md, "Refusal", "Accepted"), in the revision it
        announced: a Refusal (to an earlier revision's carrier as ``world-mismatch``, the only
        reason it has), or Accepted (revision 3 and later; earlier ones learn it from Decisions)."""
        revision = min(revision, REVISION)
        if refused is not None:
            if cid in self.told and cid not in self.state.accepted:
                self.refusals[cid] = refused.reason
            self.node.put(keys.refusal_key(self.mission, cid), refusal(
                self.mission, cid, refused.reason, refused.fingerprint, self.fingerprint, refused.detail, revision),
                revision)
            return
        self.refusals.pop(cid, None)
        answer = Accepted(self.mission, cid, self.fingerprint, self.state.accepted[cid].next_stage,
                          self.state.next_stage, REVISION, self.epoch)
        if defined_in(answer, revision):
            self.node.put(keys.accepted_key(self.mission, cid), answer, revision)

    # ------------------------------------------------------------------ inbound
    def pump(self, timeout_s: float) -> None:
        """Wait up to ``timeout_s`` seconds for inbox items, then handle every queued one."""
        item = self.node.next(max(0.0, timeout_s))
        while item is not None:
            try:
                self._handle(item)
            except ProtocolError as exc:
                parsed = keys.parse_carrier_key(self.mission, item.key) if item.kind == "sample" else None
                self._reject(exc.reason, exc.detail, parsed[0] if parsed else None)
                if parsed is not None and parsed[1] == "hello":  # a Hello it could not read: answered too
                    revision, fp = announced(item.payload)
                    self._answer_hello(parsed[0], revision, ms.Refuse(parsed[0], fp, exc.reason, exc.detail))
            item = self.node.next(0.0)

    def _handle(self, item) -> None:
        """Decode one inbox item into a mission event and apply it (wire-level checks only here:
        key layout, decoding, mission id, the carrier id in the key)."""
        if item.kind in ("alive", "gone"):
            if item.key == keys.coordinator_alive(self.mission):
                return
            parsed = keys.parse_carrier_key(self.mission, item.key)
            if parsed is None or parsed[1] != "alive":
                raise ProtocolError("bad-key", f"liveliness token on {item.key[:80]}")
            self.apply(ev.LivelinessChanged(parsed[0], item.kind == "alive", item.wall))
            return
        if item.key == keys.decision_key(self.mission):
            self._heard_decision(item)
            return
        parsed = keys.parse_carrier_key(self.mission, item.key)
        if parsed is not None and parsed[1] == "pose":
            self._pose(parsed[0], item)
            return
        if parsed is None or parsed[1] not in TOPIC_TYPES:
            raise ProtocolError("bad-key", f"message on {item.key[:80]}")
        cid, topic = parsed
        if cid not in self.spec.carriers:
            raise ProtocolError("unknown-carrier", f"message from carrier {cid!r}")
        msg = decode(item.payload, TOPIC_TYPES[topic])
        if msg.mission != self.mission:
            raise ProtocolError("wrong-mission", f"mission {msg.mission!r} on {self.mission!r}")
        if msg.carrier != cid:
            raise ProtocolError("key-mismatch", f"carrier {msg.carrier!r} on the key of {cid!r}")
        self.heard[cid] = time.monotonic()
        if isinstance(msg, Progress):
            return
        if isinstance(msg, Hello) and msg.epoch > self.epoch and msg.fingerprint == self.fingerprint:
            self._carrier_epoch(cid, msg.epoch)
        self.apply(to_event(msg, item.wall))

    def _carrier_epoch(self, cid: str, epoch: int) -> None:
        """A carrier has heard a higher epoch than ours. Before this process decided a stage (it
        may have re-published the last decision) a coordinator that had that epoch is gone or out
        of our reach: take the next epoch (recorded, so a restart goes higher still) and
        re-publish. After it, a newer coordinator decides this mission: we are deposed."""
        if self.deposed_by is not None:
            return
        if self.state.next_stage > self._first_stage:
            self._deposed(epoch, f"carrier {cid} has heard it")
            return
        self.log(f"coordinator: carrier {cid} has heard epoch {epoch}; this coordinator takes epoch {epoch + 1}")
        self.epoch = epoch + 1
        self.store.raise_epoch(self.epoch)
        self._refresh_state()
        if self.state.next_stage > 0:
            self._publish_decision(self._decision(self.state.next_stage - 1))

    def _heard_decision(self, item) -> None:
        """A Decision on this mission's decision key (ours come back to us): one of a higher
        epoch means another coordinator took over (e.g. a partition healed after a standby
        took over): stop deciding, publish no End, exit (docs/fleet.md, "Split brain"). Anything
        else there is not addressed to this coordinator: ignored, not counted (carriers count it)."""
        try:
            msg = decode(item.payload, Decision)
        except ProtocolError:
            return
        if msg.mission == self.mission and msg.epoch > self.epoch:
            self._deposed(msg.epoch, "it decides")

    def _deposed(self, epoch: int, how: str) -> None:
        """Stop deciding: a coordinator of a higher epoch took over (no End, no summary.json)."""
        if self.deposed_by is not None:
            return
        self.deposed_by = epoch
        self.log(f"coordinator: deposed: a coordinator of epoch {epoch} took over mission {self.mission} ({how}; "
                 f"this one has epoch {self.epoch}); stopping without End")
        self._stop.set()

    def _claim(self) -> bool:
        """Before this coordinator declares its token: is another coordinator of the mission
        live? Not a standby: raise :class:`DuplicateCoordinator`. A standby waits while the
        primary's token is present, querying its State now and then for its epoch; returns
        False when stopped before the primary vanished, True when this process may go on."""
        alive = keys.coordinator_alive(self.mission)
        if not self.node.live_tokens(alive, DEFAULTS.liveliness_check_s):
            return True
        if not self.config.standby:
            raise DuplicateCoordinator(self.mission)
        self.known_epoch = max(self.known_epoch, 1)  # a primary lives: its epoch is 1 at least
        self.log(f"coordinator: standby: mission {self.mission} has a live coordinator; waiting for its "
                 f"liveliness token to vanish")
        asked = None
        while not self._stop.is_set():
            if asked is None or time.monotonic() - asked >= DEFAULTS.standby_state_s:
                self._learn_epoch()
                asked = time.monotonic()
            if not self.node.live_tokens(alive, DEFAULTS.liveliness_check_s):
                self.log(f"coordinator: the primary's liveliness token vanished; taking over mission "
                         f"{self.mission} (it had epoch {self.known_epoch or 'unknown'})")
                return True
            self._stop.wait(DEFAULTS.standby_poll_s)
        return False

    def _open_store(self, path: Path, meta: dict) -> MissionStore:
        """mission.db, waiting while another process holds its write lock (a standby taking over
        from a primary that hangs in the middle of a write on the same disk)."""
        logged = False
        while True:
            try:
                return MissionStore(path, meta, min_epoch=self.known_epoch + 1)
            except StoreBusy as exc:
                if not logged:
                    self.log(f"coordinator: {exc}; waiting for it")
                    logged = True
                if self._stop.wait(0.5):
                    raise

    def _learn_epoch(self) -> None:
        """The primary's epoch, from its State (and the last Decision in it)."""
        for payload in self.node.query(keys.state_key(self.mission), timeout_s=DEFAULTS.state_query_s):
            try:
                state = decode(payload, State)
            except ProtocolError:
                continue
            if state.mission == self.mission:
                last = state.last_decision.epoch if state.last_decision is not None else 0
                self.known_epoch = max(self.known_epoch, state.epoch, last)

    def _pose(self, cid: str, item) -> None:
        """A carrier's Pose: not a mission event and never a rejection (docs/protocol.md, "Pose");
        only the recorder looks at it, and quietly drops one it cannot use."""
        if self.recorder is None or cid not in self.spec.carriers:
            return
        try:
            msg = decode(item.payload, Pose)
        except ProtocolError:
            return
        if msg.mission == self.mission and msg.carrier == cid:
            self.recorder.message(msg)

    def _open_recorder(self, out: Path) -> None:
        """Start mission.mcap (recording/live.py), replaying the events already in mission.db
        (a resumed mission's past; a fresh mission's ``open``)."""
        ros2 = self.config.ros2 if self.node is not None else None
        if not self.config.record and ros2 is None:
            return
        try:
            from recording.live import LiveRecorder

            self.recorder = LiveRecorder(out, self.scenario, self.problem, metadata={
                "mission": self.mission, "scenario": self.scenario.name, "seed": self.seed,
                "planner": self.planner_name, "fingerprint": self.fingerprint}, log=self.log,
                profile=self.config.record_profile if self.config.record else None,
                sinks=() if ros2 is None else (ros2.coordinator_sink(self.node.session, self.problem, self.log),))
            for event in self.store.mission_events():
                self.recorder.event(event)
        except Exception as exc:
            self.log(f"coordinator: mission.mcap not recorded: {type(exc).__name__}: {exc}")
            self.recorder = None

    def _close_recorder(self) -> None:
        if self.recorder is not None:
            try:
                self.recorder.close()
            except Exception as exc:
                self.log(f"coordinator: mission.mcap not finalised: {type(exc).__name__}: {exc}")
            self.recorder = None

    # ------------------------------------------------------------------ the stage clock
    def _wait(self, seconds: float, done=lambda: False) -> None:
        """Handle inbound items for up to ``seconds`` or until ``done()`` or a stop request."""
        deadline = time.monotonic() + seconds
        while not self._stop.is_set() and not done():
            left = deadline - time.monotonic()
            if left <= 0:
                return
            self.pump(min(0.05, left))

    def _wait_stage(self, j: int, opened: float) -> None:
        """Until every expected carrier's Observation of j is in, or a stop request. Wall clock:
        at most ``stage_timeout_s``. Sim clock: as long as some carrier still waited for is
        making progress: one that nothing came from for ``silence_timeout_s`` (since the stage
        opened) is stalled and not waited for any more; a dead or cut-off one leaves
        ``expected`` by itself when its token vanishes."""
        if self.config.clock == "wall":
            self._wait(self.config.stage_timeout_s, lambda: self.state.stage_complete(j))
            return
        silence = self.config.silence_timeout_s

        def done() -> bool:
            waiting = self.state.waiting(j)
            if not waiting:
                return True
            return time.monotonic() - last_heard(self.heard, waiting, opened) >= silence

        while not self._stop.is_set() and not done():
            self.pump(0.05)
        stalled = sorted(self.state.waiting(j))
        if stalled and not self._stop.is_set():
            self.log(f"coordinator: stage {j}: nothing from {', '.join(stalled[:8])}"
                     f"{' ...' if len(stalled) > 8 else ''} for {silence:.0f} s (stalled); ∅ for them")

    def _wait_confirms(self, j: int) -> None:
        """After the last decision: wait for its Confirms from the live carriers. Wall clock: at
        most ``confirm_timeout_s``; sim clock: until nothing came from any carrier still
        unconfirmed for ``silence_timeout_s``."""
        if self.config.clock == "wall":
            self._wait(self.config.confirm_timeout_s, lambda: not self.state.unconfirmed(j))
            return
        opened = time.monotonic()
        while not self._stop.is_set():
            waiting = self.state.unconfirmed(j)
            if not waiting or time.monotonic() - last_heard(self.heard, waiting, opened) >= self.config.silence_timeout_s:
                return
            self.pump(0.05)

    def _wait_for_carriers(self) -> None:
        """Before the first stage: wait until every carrier is live with an accepted Hello (or the
        join timeout; on resume at most the stage timeout, since some carriers may be gone). On
        the sim clock the join timeout runs from the last carrier that joined: a fleet whose
        processes start slowly on a busy host is waited for while it keeps arriving."""
        wait_s = self.config.join_timeout_s
        if self.state.resumed:
            wait_s = min(wait_s, self.config.stage_timeout_s)
        def count() -> int:
            return sum(1 for cid in self.state.live if cid in self.state.accepted)

        joined = -1
        while not self._stop.is_set() and not self.state_all_joined() and count() > joined:
            joined = count()
            self._wait(wait_s, lambda: self.state_all_joined() or (self.config.clock == "sim" and count() > joined))
            if self.config.clock == "wall":
                break
        missing = sorted(cid for cid in self.ids if not (cid in self.state.live and cid in self.state.accepted))
        if missing and not self._stop.is_set():
            self.log(f"coordinator: starting without carrier(s) {', '.join(missing)} (not live with a Hello "
                     f"after {wait_s:.0f} s); they can join late")

    def state_all_joined(self) -> bool:
        return self.state.all_joined()

    def _plan(self, j: int) -> tuple[tuple[str, ...], float, tuple[int, ...]]:
        """(deploying carrier ids, sorted; planning time, ms; the passenger each releases, parallel):
        the offline loop's own stage step (:func:`planner.online.stage_step`) on the mission's view."""
        step = stage_step(self.problem, self.state.planning_observations(j), self.state.deployed(), self.planner,
                          self.seed, j, self.state.releases() if self.problem.weights is not None else None)
        rs = sorted(np.flatnonzero(step.deploy), key=lambda r: self.ids[r])
        return tuple(self.ids[r] for r in rs), step.decision_ms, tuple(int(step.passengers[r]) for r in rs)

    def _publish_decision(self, decision: Decision) -> None:
        # In the revision every carrier that said Hello reads (docs/protocol.md, "Compatibility").
        self.node.put(keys.decision_key(self.mission), decision, self.state.common_revision(REVISION))
        self.apply(ev.Published(decision.stage, time.time()))

    def _progress(self, j: int, waited_ms: float) -> None:
        st, d = self.state, self.state.decisions[j]
        obs = []
        for r, cid in enumerate(self.ids):
            if self.spec.valid[r][j]:
                value = st.reported.get((cid, j))
                obs.append(f"{cid}={'∅' if value is None else value}")
        # Confirmations of the previous stage's deployments (stage numbers 1-based, as printed).
        confirmed = sorted(cid for (cid, jj), c in st.confirms.items() if jj == j - 1 and c.deployed)
        self.log(
            f"stage {j + 1:>3}/{self.n_stages} t={self.spec.stage_times[j]:7.1f} s | obs {' '.join(obs) or '-'} | "
            f"deploy {' '.join(d.deploy) or '-'} | plan {d.planning_ms:7.1f} ms | "
            f"wait {waited_ms:6.0f} ms"
            + (f" | deployed@{j}: {' '.join(confirmed) or '-'}" if j > 0 else "")
        )

    def _stages(self) -> None:
        last_published = None
        for j in range(self.state.next_stage, self.n_stages):
            if self._stop.is_set():
                return
            if self.config.realtime > 0 and last_published is not None and not self.state.behind(j):
                # Paced like the carriers: Δt / realtime after the previous decision went out
                # (not when the carriers are past j already: then it catches up at once).
                self._wait(last_published + self.scenario.stage_interval / self.config.realtime - time.monotonic())
            if j > 0 and not self.state.live:
                # Nobody to decide for (cut off, or every carrier gone): deciding now would only
                # record empty stages the carriers decide themselves. Hold until one is back (its
                # Hello says where it is), at most the join timeout.
                self.log(f"coordinator: no carrier is live; holding stage {j} (at most {self.config.join_timeout_s:.0f} s)")
                self._wait(self.config.join_timeout_s, lambda: bool(self.state.live))
            opened = time.monotonic()
            self._wait_stage(j, opened)
            if self._stop.is_set():
                return
            deploy, planning_ms, passengers = self._plan(j)
            newer = self.store.newer_epoch()  # a standby took over on our disk while we were cut off
            if newer is not None:
                self._deposed(newer, "mission.db records it")
                return
            self.apply(ev.Decided(j, deploy, planning_ms, time.time(), passengers))  # records, then publishes
            last_published = time.monotonic()
            self._progress(j, (last_published - opened) * 1e3 - planning_ms)
            self.pump(0.0)

    def _end(self, reason: str) -> None:
        """Record End (once), publish it every ``end_repeat_s`` and wait for the live carriers'
        Byes, at most ``bye_timeout_s``. Runs to its end even when a stop was requested."""
        self.apply(ev.Ended(reason, time.time()))
        end = End(self.mission, self.state.next_stage, self.state.end_reason or reason)
        deadline = time.monotonic() + self.config.bye_timeout_s
        last_put = None
        while time.monotonic() < deadline:
            if last_put is None or time.monotonic() - last_put >= DEFAULTS.end_repeat_s:
                self.node.put(keys.end_key(self.mission), end)  # repeated for carriers that missed it
                last_put = time.monotonic()
            if self.state.all_said_bye():
                break
            self.pump(0.05)
        self.log(f"coordinator: mission {self.state.end_reason} after {self.state.next_stage} stage(s)")

    def run(self) -> dict:
        """Run (or resume) the mission to its end; write summary.json and map.png.

        Returns:
            The summary dict.
        """
        from wire.zconfig import OpenStopped

        out = Path(self.config.out_dir)
        # The session first: a duplicate is refused (or waited for) before mission.db is touched.
        if not self._stop.is_set():
            try:
                self.node = Node(self.zconf, stop=self._stop)
            except OpenStopped:
                self.node = None
        if self.node is not None:
            try:
                claimed = self._claim()
            except BaseException:
                self.node.close(DEFAULTS.close_s)
                self.node = None
                raise
            if not claimed:  # a standby stopped while the primary lived: nothing of ours to record
                self.node.close(DEFAULTS.close_s)
                self.node = None
                self.log(f"coordinator: standby for mission {self.mission} stopped; it never took over")
                return {"ended": False, "standby": True}
        started = time.monotonic()  # the mission's wall time: a standby's wait is not part of it
        out.mkdir(parents=True, exist_ok=True)
        meta = {"mission": self.mission, "scenario": self.scenario.name, "fingerprint": self.fingerprint,
                "seed": self.seed, "planner": self.planner_name, "planner_options": self.planner_options}
        # Higher than every epoch used before for this mission: the ones in mission.db and the
        # one a primary reported while this process stood by; 1 for a fresh mission.
        try:
            self.store = self._open_store(out / "mission.db", meta)
        except BaseException:
            if self.node is not None:
                self.node.close(DEFAULTS.close_s)
            raise
        self.epoch = self.store.epoch
        self._open_recorder(out)
        try:
            # Recovery is the live fold over the stored events (the last one is this process's open).
            self.state = ms.fold(self.spec, self.store.mission_events())
            self._first_stage = self.state.next_stage
            if self.state.resumed:
                self.log(f"coordinator: resumed from {self.store.path}: {len(self.state.decisions)} stage(s) "
                         f"decided, continuing at stage {self.state.next_stage}")
            self._refresh_state()
            if self.node is not None and not self._stop.is_set():
                self.node.subscribe(f"{keys.prefix(self.mission)}/carrier/**")
                self.node.subscribe(keys.decision_key(self.mission))  # a newer epoch deposes us
                self.node.watch_liveliness(keys.carrier_alive_pattern(self.mission))
                self.node.serve(keys.state_key(self.mission), self.state_reply)
                self.node.token(keys.coordinator_alive(self.mission))
                self.log(f"coordinator: mission {self.mission}, {len(self.ids)} carriers, {self.n_stages} stages, "
                         f"planner {self.planner_name} {self.planner_options}, seed {self.seed}, epoch {self.epoch}, "
                         f"{self.config.clock} clock")
                # Warmed up once State answers and the token is out: carriers that start meanwhile
                # find a coordinator (compiling the planner takes seconds, more on a busy host).
                warm = getattr(self.planner, "warm_up", None)
                if callable(warm) and not self._stop.is_set():
                    warm(self.problem)
                if self.state.next_stage > 0:
                    self._publish_decision(self._decision(self.state.next_stage - 1))  # idempotent re-publication
                if self.state.ended:  # resumed a complete mission: only tell late carriers it is over
                    self._end(self.state.end_reason)
                else:
                    self._wait_for_carriers()
                    self._stages()
                    if not self._stop.is_set():
                        self._wait_confirms(self.n_stages - 1)
                    if self.deposed_by is None:  # deposed: the newer coordinator ends the mission
                        self._end("stopped" if self._stop.is_set() else "complete")
            else:  # stopped before the session opened: nothing to tell anyone, but on record
                self.apply(ev.Ended("stopped", time.time()))
        except Exception as exc:
            if not isinstance(exc, OpenStopped):
                raise
            self.apply(ev.Ended("stopped", time.time()))
        finally:
            # Twice: at once without the clairvoyant bound, then with it, each write atomic, so a
            # coordinator killed while the bound is computed (its launcher's grace after Ctrl-C is
            # a few seconds) still leaves a complete summary.json, and mission.mcap is finalised
            # in between.
            # A deposed coordinator writes no summary.json or map.png: the results are the newer
            # coordinator's (which may share this --out directory).
            wall_s = time.monotonic() - started
            deposed = self.deposed_by is not None
            if not deposed:
                _write_json(out / "summary.json", self.summary(wall_s, bound=False))
            self._close_recorder()
            summary = self.summary(wall_s, bound=not deposed)
            if not deposed:
                _write_json(out / "summary.json", summary)
            if self.node is not None:
                self.node.close(DEFAULTS.close_s)
            if self.config.render and not deposed:
                self._render(out / "map.png")
            self.store.close()
        return summary

    # ------------------------------------------------------------------ results
    def summary(self, wall_s: float, bound: bool = True) -> dict:
        out = mission_summary(self.state, self.problem, RunInfo(
            scenario=self.scenario.name, scenario_file=str(self.scenario_path), mission=self.mission,
            planner=self.planner_name, planner_options=self.planner_options, seed=self.seed,
            pid=os.getpid(), host=socket.gethostname(), wall_time_s=wall_s,
            rejected=dict(self.node.rejected) if self.node else {},
            passenger_types=tuple(c.passenger_types for c in self.scenario.carriers)), bound=bound)
        out["epoch"] = self.epoch  # of the coordinator that wrote this summary (docs/fleet.md)
        if self.deposed_by is not None:
            out["deposed_by"] = self.deposed_by
        return out

    def _render(self, path: Path) -> None:
        try:
            render_map(self.scenario, self.state, path, title=f"{self.scenario.name}: {self.planner_name}, seed {self.seed}")
        except Exception as exc:
            self.log(f"coordinator: map.png not drawn: {type(exc).__name__}: {exc}")
