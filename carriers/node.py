"""One carrier process: its own pymunk body and a thin loop around ``mission.carrier``.

The carrier builds the same world as every other process from the scenario (deterministic from
its seed) but simulates only its own body (carriers never collide with each other, so its
motion equals ``world.observe_all``'s). The handshake rules (which stage it is at, decisions
handled at most once, late / idle / already, resynchronisation) live in mission/carrier.py; this
module feeds its machines their messages and clock ticks and dispatches their effects: the I/O
among them by carriers/effects.py, a stage's work by carriers/stage.py, the physics by
carriers/motion.py, the run's opening and closing by carriers/opening.py.
Per stage j (docs/protocol.md, "Stage handshake"):

1. advance the physics at fixed steps to t_j (paced at ``realtime`` × wall time when > 0),
   sending Progress at least every ``progress_s`` of wall time on the sim clock;
2. publish the Observation of j (x = features sensed, or None when not scheduled at j);
3. wait for the Decision of j while the coordinator's liveliness token is present: on the
   ``sim`` clock as long as it takes (asking State every ``decision_timeout_s`` for a Decision
   lost on the way), on the ``wall`` clock at most ``decision_timeout_s``;
4. deploy if selected (the passenger appears in the world) and publish a Confirm; or, when no
   decision came in time or the coordinator is gone (mode ``hybrid``, the default), or always
   (mode ``decentralised``: no coordinator at all), decide the stage itself: wait (sim clock:
   while they send Progress; wall clock: at most ``peer_timeout_s``) for the Observations of j
   of the other live carriers, run the on-board
   planner (``dec-closed-loop``) on what it heard (:class:`mission.peers.PeerBook`), deploy or
   not and publish an Own message. Mode ``coordinated`` never decides alone: it holds while the
   coordinator is absent and exits after ``coordinator_timeout_s``.

Every observation and every outcome is written to the carrier's durable log
(storage/carrierlog.py, ``<out>/carriers/<id>.db``) before the carrier acts on it. Started with no
coordinator answering (decentralised, or a hybrid carrier whose coordinator is gone), a carrier
resumes from its own log.

Stopping: :meth:`Carrier.stop` (what SIGINT/SIGTERM call) only sets a request honoured between
steps; the carrier then says Bye (``stopped``).
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Any

import world
from carriers import opening
from carriers.alone import Alone
from carriers.effects import CarrierEffects
from carriers.exits import EXIT_CODES, Exit, refused_exit
from carriers.inbound import Follow, Inbound, Rejoin
from carriers.joining import PATHS, Joining, StateQueries
from carriers import ONBOARD_LOADS
from carriers.motion import Motion, Moving
from carriers.onboard import Onboard
from carriers.who import Who
from carriers.shared import PhysicsThread, SharedWorld, StageGate
from carriers.stage import WORK, StageWork
from mission import carrier as mc
from mission import carrier_life as cl
from mission import joins
from mission import timers as tm
from mission.peers import PeerBook, Presence
from mission.timeouts import CLOCKS, DEFAULTS, POSE_INTERVAL_S
from wire.messages import ProtocolError, SharedDecoder
from mission.modes import MODES, Mode

#: Longest sleep (s) of a carrier waiting for a message (a decision, End): any message, and a
#: stop request (:meth:`Carrier.stop`, :func:`run_carriers`), wakes it at once, so this only sets
#: how often it looks at its timers. Polls cost CPU in proportion to the wait, so with many
#: carriers per process short polls were most of an idle carrier's CPU (docs/performance.md, "Costs behind the fleet's constants").
IDLE_POLL_S = 2.0
#: How often a carrier deciding alone looks for the peers' observations it waits for (s): the
#: peers' messages do not wake it.
PEER_POLL_S = 0.02


@dataclass(frozen=True)
class CarrierConfig:
    """Settings of one carrier process.

    Attributes:
        carrier: this carrier's id (must be in the scenario).
        mission: mission id; the scenario name by default.
        seed: overrides the scenario's root seed (must match the coordinator's).
        realtime: 0 = as fast as possible; F > 0 = simulated time runs at F × wall time.
        clock: ``sim`` (a simulated mission: never decide alone because someone is slow) or
            ``wall`` (a real-time mission: the decision and peer timeouts are deadlines);
            :data:`mission.timeouts.CLOCKS`.
        decision_timeout_s: wall clock: longest wait (s, coordinator present) for one stage's
            decision, then the carrier decides it itself. Sim clock: how often (s) it asks the
            coordinator's State again while it waits (a lost decision is recovered).
        coordinator_timeout_s: exit when the coordinator has been absent this long (s).
        end_timeout_s: after the last stage, wait this long (s) for End.
        log: callable taking one line.
        pose_interval_s: publish a Pose every this many seconds of simulated time (rounded to
            whole seconds, the physics trace's spacing); 0 = no poses.
        mode: one of :data:`MODES`.
        out_dir: where the durable log goes (``<out_dir>/carriers/<id>.db``); None: no log.
        peer_timeout_s: deciding alone, wall clock: wait this long for the other carriers'
            observations.
        silence_timeout_s: deciding alone, sim clock: wait for a live peer's observation until
            nothing (not even Progress) came from it for this long (s).
            ``clock``, ``silence_timeout_s`` and ``realtime`` hold until the coordinator's Accepted
            tells the mission's (revision 4): the carrier then follows it (:attr:`Carrier.timers`).
        join_timeout_s: decentralised: before the first stage, wait this long for every
            carrier's liveliness token.
        hello_timeout_s: its latest Hello unanswered this long (the coordinator's token
            present), it says Hello again, the interval doubling ([P-5.14]).
        planner_options: options of the on-board planner (iterations, plan_ms).
        log_sync: how the durable log commits (:data:`storage.carrierlog.SYNC_MODES`).
        onboard_load: when the on-board planner is loaded (:data:`carriers.ONBOARD_LOADS`;
            None: see there).
        ros2: ROS 2 settings (``ros2.publisher.Ros2Settings``: ``--ros2``, ``--ros2-robot``); None:
            off, and nothing of ros2/ is imported.
    """

    carrier: str
    mission: str | None = None
    seed: int | None = None
    realtime: float = 0.0
    clock: str = "sim"
    decision_timeout_s: float = DEFAULTS.decision_s
    coordinator_timeout_s: float = DEFAULTS.coordinator_s
    end_timeout_s: float = DEFAULTS.end_s
    log: object = None
    pose_interval_s: float = POSE_INTERVAL_S
    mode: str = Mode.HYBRID
    out_dir: str | None = None
    peer_timeout_s: float = DEFAULTS.peer_s
    silence_timeout_s: float = DEFAULTS.silence_s
    join_timeout_s: float = DEFAULTS.join_s
    hello_timeout_s: float = DEFAULTS.hello_s
    planner_options: tuple = ()
    log_sync: str = "full"
    onboard_load: str | None = None
    ros2: object = None


def check_config(config: CarrierConfig) -> None:
    """A ``ValueError`` naming the first setting of ``config`` out of its choices."""
    if config.mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, found {config.mode!r}")
    if config.clock not in CLOCKS:
        raise ValueError(f"clock must be one of {CLOCKS}, found {config.clock!r}")
    if (config.onboard_load or "start") not in ONBOARD_LOADS:
        raise ValueError(f"onboard_load must be one of {ONBOARD_LOADS}, found {config.onboard_load!r}")


def _print(line: str) -> None:
    print(line, flush=True)


@dataclass(frozen=True)
class Parts:
    """What a carrier shares with the other carriers of its process (carriers/process.py): its Zenoh
    config, the process's session (None: one of its own), the world derived once
    (:class:`carriers.shared.SharedWorld`, None: its own) and the stage gate."""

    zconf: Any
    session: Any
    shared: Any
    gate: StageGate


def waits_of(config: CarrierConfig):
    """The waits of :mod:`mission.carrier_life` a carrier of ``config`` times by
    (:class:`mission.timeouts.Timeouts`)."""
    import dataclasses

    return dataclasses.replace(DEFAULTS, decision_s=float(config.decision_timeout_s),
                               coordinator_s=float(config.coordinator_timeout_s), end_s=float(config.end_timeout_s),
                               peer_s=float(config.peer_timeout_s), join_s=float(config.join_timeout_s),
                               hello_s=float(config.hello_timeout_s))


class Carrier:
    """One carrier. ``run()`` returns its exit reason (a key of :data:`EXIT_CODES`).

    An I/O loop around two pure machines: its lifecycle (``self.life``, :mod:`mission.carrier_life`,
    changed only by :meth:`step`) and its stage handshake (``self.machine``,
    :class:`mission.carrier.Handshake`, changed only by :meth:`apply`). :meth:`fly` feeds the
    lifecycle its ``clock`` (monotonic s; a test hands in its own) and takes the inbox between
    its waits; the effects of both machines are dispatched here, their I/O carried out by its
    hands (:class:`carriers.effects.CarrierEffects`). Its collaborators
    (:class:`carriers.inbound.Inbound`, :class:`carriers.joining.Joining`,
    :class:`carriers.motion.Motion`, :class:`carriers.alone.Alone`,
    :class:`carriers.stage.StageWork`, its run's opening and closing :mod:`carriers.opening`) are
    given what they need and call nothing back: they return what they read, or yield what they
    ask of it (:meth:`_asked`).
    """

    def __init__(self, scenario, config: CarrierConfig, zconf, stop: threading.Event | None = None,
                 shared: SharedWorld | None = None, onboard: Onboard | None = None, gate: StageGate | None = None,
                 broadcasts: SharedDecoder | None = None, session=None, physics: PhysicsThread | None = None,
                 clock=time.monotonic):
        if config.seed is not None and shared is None:
            scenario = scenario.with_seed(int(config.seed))
        check_config(config)
        self.config = config
        valid = scenario.valid() if shared is None else shared.valid  # every carrier's schedule [R, N]
        self.who = Who.of(scenario, config.carrier, config.mission, valid,
                          None if shared is None else shared.fingerprint)
        cid, r = self.who.cid, self.who.r
        # what it shares with the other carriers of its process (carriers/process.py)
        self.parts = Parts(zconf, session, shared, gate if gate is not None else StageGate())
        self.machine = mc.initial(cid, self.valid, scenario.stage_times(), scenario.carriers[r].passengers)
        self._stop = stop if stop is not None else threading.Event()
        self.node = None
        self.clock = clock  # the one clock its lifecycle is fed, once per look (mission.timers rules decide)
        self.motion = Motion(self.mission, cid, config.pose_interval_s, self._stop, physics, self.clock())
        onboard = onboard if onboard is not None else Onboard(scenario, config.planner_options)
        book = PeerBook(scenario.carrier_ids, valid)  # what it heard of every carrier's stages
        # What it receives and the books it feeds: who is there, the answer to its latest Hello, the
        # passenger each Decision named for it (docs/protocol.md, Decision).
        self.inbound = Inbound(self.mission, cid, config.mode, onboard,
                               broadcasts if broadcasts is not None else SharedDecoder(),  # the process's Decisions
                               book, Presence(self.clock()), mc.HelloAnswer(self.fingerprint),
                               mc.Releases(scenario.carriers[r].passengers), self.motion.position, self.log)
        self.alone = Alone(cid, book, onboard, scenario.seed, self.log)
        self.work = StageWork(self.who, self.motion, self.parts.gate, self.alone)  # sense, pass, move on, decide alone
        self.joining = Joining(self.fingerprint, config, StateQueries(self.mission, cid, self.log), self.motion.counts,
                               self.inbound, self.log)
        # Its hands on the world: what it sends, logs and releases for its machines' effects.
        self.effects = CarrierEffects(self.who, self.motion, self.inbound, self.clock, self.log)
        # What it times its waits by: its own settings until the coordinator's Accepted tells it
        # the mission's (docs/protocol.md, [P-10.2]; :func:`mission.carrier.follow`).
        self.timers = mc.Timers(config.clock, float(config.silence_timeout_s), float(config.realtime))
        # Its lifecycle (:mod:`mission.carrier_life`): the phase it is in and every wait it keeps.
        self.life = cl.initial(config.mode, waits_of(config))

    # ------------------------------------------------------------------ its parts, by name
    scenario = property(lambda self: self.who.scenario)
    cid = property(lambda self: self.who.cid)
    mission = property(lambda self: self.who.mission)
    fingerprint = property(lambda self: self.who.fingerprint)
    valid = property(lambda self: self.who.valid)
    presence = property(lambda self: self.inbound.presence)  # the coordinator's and the peers' tokens
    answer = property(lambda self: self.inbound.answer)      # the coordinator's answer to its latest Hello
    book = property(lambda self: self.inbound.book)          # what it heard of every carrier's stages
    store = property(lambda self: self.effects.store)        # its durable log, open while running
    ros2 = property(lambda self: self.effects.ros2)          # its ROS 2 node while running with config.ros2
    reason = property(lambda self: self.life.reason or "finished")  # why it ended (carriers/exits.py)

    def log(self, line: str) -> None:
        (self.config.log or _print)(f"carrier {self.cid}: {line}")

    def stop(self) -> None:
        self._stop.set()
        node = self.node
        if node is not None:
            node.wake()

    # ------------------------------------------------------------------ the one way state changes
    def apply(self, event) -> None:
        """Step the carrier machine, then carry out its effects in order."""
        self.machine, effects = mc.step(self.machine, event)
        for effect in effects:
            self.execute(effect)

    def execute(self, effect) -> None:
        """Carry out one effect of the carrier machine: a resynchronisation or the mission's
        timers here, its I/O by its hands (:meth:`carriers.effects.CarrierEffects.carry_out`)."""
        if isinstance(effect, mc.AskState):  # a Decision came without an earlier one
            tm.drive(self.joining.resync(self.machine, self.node, gap=effect.stage), self._asked)
        elif isinstance(effect, Rejoin):  # the coordinator is back
            tm.drive(self.joining.resync(self.machine, self.node), self._asked)
        elif isinstance(effect, Follow):  # the mission's timers (a robot keeps its own pace)
            self.timers, lines = mc.follow(self.timers, effect.timers, getattr(self.ros2, "robot", None) is None)
            for line in lines:
                self.log(line)
        else:
            self.effects.carry_out(effect, self.node, self.machine)

    def _check_refused(self) -> None:
        refused_exit(self.answer.refused, self.fingerprint, self.log)

    def pump(self, timeout_s: float) -> None:
        """Take what arrived, waiting up to ``timeout_s`` for the inbox's first item
        (:meth:`carriers.inbound.Inbound.arrivals`), each read against its machine then
        (:meth:`carriers.inbound.Inbound.read`): an event applied, an effect carried out, one it
        cannot read rejected."""
        for item in self.inbound.arrivals(self.node, timeout_s):
            try:
                heard = self.inbound.read(item, self.machine)
            except ProtocolError as exc:
                self.node.reject(exc.reason, exc.detail, self.log)
                continue
            if isinstance(heard, (mc.DecisionHeard, mc.EndHeard)):
                self.apply(heard)
            elif heard is not None:
                self.execute(heard)

    def _asked(self, step):
        """What a join path asks (:mod:`mission.joins`), carried out; what it is answered."""
        if isinstance(step, joins.Drive):
            self.advance(self.scenario.stage_time(step.stage), paced=False)
        if isinstance(step, (joins.Drive, joins.Here)):
            return self.motion.position()
        if isinstance(step, joins.Apply):
            self.apply(step.event)
            return self.machine
        if isinstance(step, joins.Execute):
            self.execute(step.effect)
        elif isinstance(step, joins.Release):
            self.motion.body.deploy(self.cid)
        return None

    def _moving(self) -> Moving:
        """What its motion reads of the carrier now (:class:`carriers.motion.Moving`)."""
        return Moving(self.node, self.ros2, self.clock, self.timers, self.machine.stage, self.machine.passengers_left)

    def advance(self, t: float, paced: bool = True) -> None:
        """Its body to mission time ``t`` (:meth:`carriers.motion.Motion.advance`); while it paces,
        its messages are handled (a refused Hello ends it) and the motion told what it is then."""
        tm.drive(self.motion.advance(t, paced, self._moving()), self._paced)

    def _paced(self, wait_s: float) -> Moving:
        self.pump(wait_s)
        self._check_refused()
        return self._moving()

    # ------------------------------------------------------------------ its lifecycle
    def step(self, event) -> float | None:
        """Step its lifecycle with ``event`` and carry out the effects: the time to wait until
        (the :class:`mission.timers.Wait`), None when it is to be stepped again at once."""
        view = self.inbound.view(self.machine, self.timers, self.node.revision)  # what it reads now
        self.life, effects = cl.step(self.life, event, view)
        until = None
        for effect in effects:
            if isinstance(effect, tm.Wait):
                until = effect.until
            else:
                self.run_effect(effect)
        return until

    def fly(self, until=None) -> None:
        """Its lifecycle from where it is until it is done (or ``until(life)`` holds): the clock
        fed to the machine as ticks, what arrives in between taken (:meth:`pump`). A stop request
        ends it with Bye ``stopped``."""
        while self.life.phase is not cl.Phase.DONE and not (until is not None and until(self.life)):
            now = self.clock()
            if self._stop.is_set():
                self.step(cl.Stopped(now))
                break
            self._check_refused()
            wake = self.step(cl.Tick(now))
            if wake is None:
                continue
            poll = PEER_POLL_S if self.life.phase is cl.Phase.ALONE else IDLE_POLL_S
            self.pump(max(0.0, min(poll, wake - now)))

    def run_effect(self, effect) -> None:
        """Carry out one effect of its lifecycle machine: its body driven to a stage, Progress,
        a join path (:meth:`carriers.joining.Joining.path`) and a stage's work
        (:meth:`carriers.stage.StageWork.steps`) carried out, the rest by its hands
        (:meth:`carriers.effects.CarrierEffects.life`)."""
        if isinstance(effect, cl.Drive):
            j = effect.stage
            self.advance(self.scenario.stage_time(j), paced=effect.paced)
            self.motion.publish_poses(self._moving())
            if not self._stop.is_set():
                self.step(cl.Arrived(j, self.clock()))
        elif isinstance(effect, cl.SendProgress):
            self.motion.send_progress(self._moving())
        elif isinstance(effect, PATHS):
            if tm.drive(self.joining.path(effect, self.machine, self.node, self.store), self._asked):
                self.step(cl.Answered(self.clock()))  # a State answered its Query: it joined
        elif isinstance(effect, WORK):
            tm.drive(self.work.steps(effect, self.node, self.machine), self._asked)
        else:  # its Observation again, its peers listened to, a note; Finish (its reason: :attr:`reason`)
            self.effects.life(effect, self.node, self.machine)

    def run(self) -> str:
        """Its run from its session's opening to its Bye (:mod:`carriers.opening`): its exit reason."""
        from wire.zconfig import OpenStopped

        reason = "finished"
        self.motion.body = world.Simulation(self.scenario, carriers=[self.cid],
                                            features=None if self.parts.shared is None else self.parts.shared.features)
        try:
            self.node = opening.open_node(self.parts, self.config, self.who, self.motion.position, self._stop,
                                          self.clock)
        except OpenStopped:
            return "stopped"
        try:
            self.effects.ros2 = opening.attach_ros2(self.config, self.node, self.who, self.motion, self._stop, self.log)
            self.effects.store = opening.open_log(self.config, self.who, self.log)
            opening.announce(self.config, self.node, self.who, self.inbound, self.alone.onboard)
            self.step(cl.Start(self.clock()))  # it joins: State asked, or (decentralised) its log
            self.fly()
            reason = "stopped" if self._stop.is_set() else self.reason
        except Exit as exc:
            reason = exc.reason
        except Exception as exc:  # a body that names its exit reason (a robot of another ROS 2 format)
            reason = getattr(exc, "exit_reason", None)
            if reason not in EXIT_CODES:
                raise
            self.log(str(exc))
        finally:
            opening.close(self.config, self.node, self.who, self.machine, self.answer, reason, self.ros2, self.store)
        return reason
