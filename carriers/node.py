"""One carrier process: its own pymunk body and a thin loop around ``mission.carrier``.

The carrier builds the same world as every other process from the scenario (deterministic from
its seed) but simulates only its own body (carriers never collide with each other, so its
motion equals ``world.observe_all``'s). The handshake rules (which stage it is at, decisions
handled at most once, late / idle / already, resynchronisation) live in mission/carrier.py; this
module feeds its machines their messages and clock ticks and dispatches their effects: the I/O
among them by carriers/effects.py, a stage's work by carriers/stage.py, the physics by
carriers/motion.py, the run's opening and closing by carriers/opening.py, each collaborator
built once by carriers/crew.py.
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

from carriers import ONBOARD_LOADS, opening
from carriers.crew import Crew
from carriers.exits import EXIT_CODES, exit_reason  # EXIT_CODES: the keys run() returns (the launcher's)
from carriers.inbound import Follow
from carriers.joining import PATHS, RESYNCS
from carriers.motion import Moving
from carriers.onboard import Onboard
from carriers.shared import PhysicsThread, SharedWorld, StageGate
from carriers.stage import WORK
from mission import carrier as mc
from mission import carrier_life as cl
from mission import joins
from mission import timers as tm
from mission.modes import MODES, Mode
from mission.timeouts import CLOCKS, DEFAULTS, POSE_INTERVAL_S
from wire.messages import SharedDecoder

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
    its waits; the effects of both machines are dispatched here (:meth:`execute`), their I/O
    carried out by its hands (:class:`carriers.effects.CarrierEffects`). Its collaborators
    (``self.crew``, :class:`carriers.crew.Crew`) and its run's opening and closing
    (:mod:`carriers.opening`) are given what they need and call nothing back: they return what
    they read, or yield what they ask of it (:meth:`_asked`).
    """

    def __init__(self, scenario, config: CarrierConfig, zconf, stop: threading.Event | None = None,
                 shared: SharedWorld | None = None, onboard: Onboard | None = None, gate: StageGate | None = None,
                 broadcasts: SharedDecoder | None = None, session=None, physics: PhysicsThread | None = None,
                 clock=time.monotonic):
        check_config(config)
        self.config = config
        self.clock = clock  # the one clock its lifecycle is fed, once per look (mission.timers rules decide)
        self._stop = stop if stop is not None else threading.Event()
        self.parts = Parts(zconf, session, shared, gate if gate is not None else StageGate())  # shared in its process
        self.crew = Crew.build(scenario, config, self.parts, onboard, broadcasts, physics, self._stop, clock, self.log)
        self.machine = self.crew.who.handshake()
        self.node = None
        # What it times its waits by: its own settings until the coordinator's Accepted tells it
        # the mission's (docs/protocol.md, [P-10.2]; :func:`mission.carrier.follow`).
        self.timers = mc.Timers(config.clock, float(config.silence_timeout_s), float(config.realtime))
        # Its lifecycle (:mod:`mission.carrier_life`): the phase it is in and every wait it keeps.
        self.life = cl.initial(config.mode, waits_of(config))

    # ------------------------------------------------------------------ its parts, by name
    cid = property(lambda self: self.crew.who.cid)
    ros2 = property(lambda self: self.crew.effects.ros2)  # its ROS 2 node while running with config.ros2
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

    def pump(self, timeout_s: float) -> None:
        """Take what arrived (:meth:`carriers.inbound.Inbound.arrivals`, waiting up to ``timeout_s``
        for the inbox's first item), each read against its machine then (``Inbound.read``): an
        event applied, an effect carried out (one it cannot read rejected)."""
        for item in self.crew.inbound.arrivals(self.node, timeout_s):
            heard = self.crew.inbound.read(item, self.machine)
            if isinstance(heard, (mc.DecisionHeard, mc.EndHeard)):
                self.apply(heard)
            elif heard is not None:
                self.execute(heard)

    def _asked(self, step):
        """What a join path asks (:mod:`mission.joins`), carried out: an event applied (answered
        with the machine then), an effect carried out, the rest asked of its body
        (:meth:`carriers.motion.Motion.asked`); what it is answered."""
        if isinstance(step, joins.Apply):
            self.apply(step.event)
            return self.machine
        if isinstance(step, joins.Execute):
            self.execute(step.effect)
            return None
        return self.crew.motion.asked(step, self.crew.who, self._moving())

    def _moving(self) -> Moving:
        """What its motion reads of the carrier now (:class:`carriers.motion.Moving`)."""
        return Moving(self.node, self.ros2, self.clock, self.timers, self.machine.stage, self.machine.passengers_left)

    def _paced(self, wait_s: float) -> Moving:
        self.pump(wait_s)
        self.crew.inbound.check_refused()
        return self._moving()

    # ------------------------------------------------------------------ its lifecycle
    def step(self, event) -> float | None:
        """Step its lifecycle with ``event`` and carry out the effects: the time to wait until
        (the :class:`mission.timers.Wait`), None when it is to be stepped again at once."""
        view = self.crew.inbound.view(self.machine, self.timers, self.node.revision)  # what it reads now
        self.life, effects = cl.step(self.life, event, view)
        until = None
        for effect in effects:
            if isinstance(effect, tm.Wait):
                until = effect.until
            else:
                self.execute(effect)
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
            self.crew.inbound.check_refused()
            wake = self.step(cl.Tick(now))
            if wake is None:
                continue
            poll = PEER_POLL_S if self.life.phase is cl.Phase.ALONE else IDLE_POLL_S
            self.pump(max(0.0, min(poll, wake - now)))

    def execute(self, effect) -> None:
        """Carry out one effect of either machine: its body driven to a stage and its Poses
        (:meth:`carriers.motion.Motion.drive`; paced, its messages handled on the way and a
        refused Hello ending it: :meth:`_paced`), Progress, a join or resynchronisation path
        (:meth:`carriers.joining.Joining.path`), a stage's work
        (:meth:`carriers.stage.StageWork.steps`), the mission's timers followed; the rest, I/O, by
        its hands (:meth:`carriers.effects.CarrierEffects.carry_out`; Finish: its reason is
        :attr:`reason`)."""
        if isinstance(effect, cl.Drive):
            tm.drive(self.crew.motion.drive(effect.stage, self.crew.who, effect.paced, self._moving()), self._paced)
            if not self._stop.is_set():
                self.step(cl.Arrived(effect.stage, self.clock()))
        elif isinstance(effect, cl.SendProgress):
            self.crew.motion.send_progress(self._moving())
        elif isinstance(effect, (*PATHS, *RESYNCS)):
            if tm.drive(self.crew.joining.path(effect, self.machine, self.node, self.crew.effects.store), self._asked):
                self.step(cl.Answered(self.clock()))  # a State answered its Query: it joined
        elif isinstance(effect, WORK):
            tm.drive(self.crew.work.steps(effect, self.node, self.machine), self._asked)
        elif isinstance(effect, Follow):  # the mission's timers (a robot keeps its own pace)
            self.timers, lines = mc.follow(self.timers, effect.timers, getattr(self.ros2, "robot", None) is None)
            for line in lines:
                self.log(line)
        else:
            self.crew.effects.carry_out(effect, self.node, self.machine)

    def run(self) -> str:
        """Its run from its session's opening to its Bye (:mod:`carriers.opening`): its exit reason."""
        crew, reason = self.crew, "finished"
        crew.motion.body = opening.simulated_body(crew.who, self.parts)
        self.node = opening.open_node(self.parts, self.config, crew.who, crew.motion.position, self._stop, self.clock)
        if self.node is None:  # stopped while its session opened
            return "stopped"
        try:
            opening.begin(self.config, self.node, crew, self._stop, self.log)  # its ROS 2 node, log, token
            self.step(cl.Start(self.clock()))  # it joins: State asked, or (decentralised) its log
            self.fly()
            reason = "stopped" if self._stop.is_set() else self.reason
        except Exception as exc:  # an Exit, or a body that names its exit reason (carriers/exits.py)
            reason = exit_reason(exc, self.log)
        finally:
            opening.close(self.config, self.node, crew, self.machine, reason)
        return reason
