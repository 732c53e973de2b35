"""One carrier process: its own pymunk body and a thin loop around ``mission.carrier``.

The carrier builds the same world as every other process from the scenario (deterministic from
its seed) but simulates only its own body (carriers never collide with each other, so its
motion equals ``world.observe_all``'s). The handshake rules (which stage it is at, decisions
handled at most once, late / idle / already, resynchronisation) live in mission/carrier.py; this
module drives the physics, keeps the clocks (pacing, decision and coordinator timeouts) and
moves bytes. Per stage j (docs/protocol.md, "Stage handshake"):

1. advance the physics at fixed steps to t_j (paced at ``realtime`` × wall time when > 0);
2. publish the Observation of j (x = features sensed, or None when not scheduled at j);
3. wait for the Decision of j: the wait only counts while the coordinator's liveliness token is
   present, and ends after ``decision_timeout_s`` (then the carrier goes on without deploying);
   while the coordinator is absent the carrier holds, and exits after ``coordinator_timeout_s``;
4. deploy if selected (the passenger appears in the world) and publish a Confirm.

Stopping: :meth:`Carrier.stop` (what SIGINT/SIGTERM call) only sets a request honoured between
steps; the carrier then says Bye (``stopped``).
"""
from __future__ import annotations

import os
import socket
import threading
import time
from dataclasses import dataclass

import numpy as np

import world
from mission import carrier as mc
from mission.timeouts import DEFAULTS
from wire import keys
from wire.messages import (
    Bye, Confirm, Decision, End, Hello, Observation, ProtocolError, Refusal, State, decode, scenario_fingerprint,
)
from wire.messages import Pose

#: Trail points per Observation at most (the protocol's limit).
MAX_TRAIL = 512
#: Longest sleep (s) of a carrier waiting for a message (a decision, End): any message, and a
#: stop request (:meth:`Carrier.stop`, :func:`run_carriers`), wakes it at once, so this only sets
#: how often it looks at its timers. Polls cost CPU in proportion to the wait: with hundreds of
#: carriers per process and stages of seconds, 50 ms polls were a third of the carriers' CPU time,
#: and 0.25 s polls most of it when stages took a minute (R = 1,024).
IDLE_POLL_S = 2.0
#: Sim-time chunk (s) between pacing sleeps when ``realtime > 0``.
PACE_CHUNK_S = 0.5
#: Default interval between two Pose messages, seconds of simulated time (docs/protocol.md, "Pose").
POSE_INTERVAL_S = 1.0

#: Exit reasons and the process exit code each maps to.
EXIT_CODES = {"end": 0, "finished": 0, "stopped": 130, "coordinator-lost": 1, "world-mismatch": 2}


class DuplicateCarriers(RuntimeError):
    """Carriers of this process already have live liveliness tokens elsewhere (another process
    runs them): the process refuses to start, before any of its carriers flies."""

    def __init__(self, mission: str, ids):
        self.mission, self.ids = mission, tuple(ids)
        super().__init__(f"mission {mission} already has live carrier(s) {', '.join(self.ids)}; stop that "
                         f"process first, or use another --mission")


def live_duplicates(mission: str, ids, zconf, stop: threading.Event | None = None,
                    open_timeout_s: float = DEFAULTS.coordinator_s) -> list[str]:
    """Which of ``ids`` already have a live token on ``mission`` (one liveliness query over a
    short-lived session of its own; docs/fleet.md, "Split brain")."""
    from wire.transport import Node
    from wire.zconfig import OpenStopped

    try:
        probe = Node(zconf() if callable(zconf) else zconf, open_timeout_s=open_timeout_s, stop=stop)
    except OpenStopped:
        return []
    try:
        live = probe.live_tokens(keys.carrier_alive_pattern(mission), DEFAULTS.liveliness_check_s)
    finally:
        probe.close(DEFAULTS.close_s)
    wanted = {keys.carrier_alive(mission, cid): cid for cid in ids}
    return sorted(wanted[k] for k in live if k in wanted)


@dataclass(frozen=True)
class CarrierConfig:
    """Settings of one carrier process.

    Attributes:
        carrier: this carrier's id (must be in the scenario).
        mission: mission id; the scenario name by default.
        seed: overrides the scenario's root seed (must match the coordinator's).
        realtime: 0 = as fast as possible; F > 0 = simulated time runs at F × wall time.
        decision_timeout_s: longest wait (s, coordinator present) for one stage's decision.
        coordinator_timeout_s: exit when the coordinator has been absent this long (s).
        end_timeout_s: after the last stage, wait this long (s) for End.
        log: callable taking one line.
        pose_interval_s: publish a Pose every this many seconds of simulated time (rounded to
            whole seconds, the physics trace's spacing); 0 = no poses.
    """

    carrier: str
    mission: str | None = None
    seed: int | None = None
    realtime: float = 0.0
    decision_timeout_s: float = DEFAULTS.decision_s
    coordinator_timeout_s: float = DEFAULTS.coordinator_s
    end_timeout_s: float = DEFAULTS.end_s
    log: object = None
    pose_interval_s: float = POSE_INTERVAL_S


@dataclass(frozen=True)
class SharedWorld:
    """What every carrier of one process derives identically from the scenario, computed once
    per process (:func:`shared_world`) when it simulates several carriers.

    Attributes:
        valid: bool ``[R, N]``, carrier r scheduled at stage j.
        fingerprint: the scenario fingerprint.
        features: float ``[F, 2]`` feature positions (m), sorted by x.
    """

    valid: np.ndarray
    fingerprint: str
    features: np.ndarray


def shared_world(scenario) -> SharedWorld:
    from world import sample_features

    features = sample_features(scenario)
    features = features[np.argsort(features[:, 0], kind="stable")]  # sorted by x: see Simulation.sense
    return SharedWorld(scenario.valid(), scenario_fingerprint(scenario), features)


class _Exit(Exception):
    """Leave the run loop with an exit reason (a key of :data:`EXIT_CODES`)."""

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


class Carrier:
    """One carrier. ``run()`` returns its exit reason (a key of :data:`EXIT_CODES`).

    ``self.machine`` is the :class:`mission.carrier.CarrierState`, changed only by :meth:`apply`.
    """

    def __init__(self, scenario, config: CarrierConfig, zconf, stop: threading.Event | None = None,
                 shared: SharedWorld | None = None):
        if config.seed is not None and shared is None:
            scenario = scenario.with_seed(int(config.seed))
        self.scenario = scenario
        self.shared = shared
        self.config = config
        self.zconf = zconf
        self.cid = keys.check_id(config.carrier, "carrier")
        self.r = scenario.carrier_index(self.cid)  # KeyError for an unknown id (checked by the CLI)
        self.mission = keys.check_id(config.mission or keys.mission_id_from_name(scenario.name), "mission")
        self.valid = (scenario.valid() if shared is None else shared.valid)[self.r]
        self.n_stages = scenario.stages
        self.fingerprint = scenario_fingerprint(scenario) if shared is None else shared.fingerprint
        self.machine = mc.initial(self.cid, self.valid, scenario.stage_times(), scenario.carriers[self.r].passengers)
        self._log = config.log or (lambda line: print(line, flush=True))
        self._stop = stop if stop is not None else threading.Event()
        self.sim: world.Simulation | None = None
        self.node = None
        self.coordinator_present = False
        self.coordinator_seen = False
        self.absent_since = time.monotonic()
        self.pending: Observation | None = None
        self._trail_from = 0
        self._pose_from = 0  # first trajectory sample not considered for a Pose yet
        self._heading = 0.0
        self._refused: Refusal | None = None

    # ------------------------------------------------------------------ views for tests and logs
    def log(self, line: str) -> None:
        self._log(f"carrier {self.cid}: {line}")

    def stop(self) -> None:
        self._stop.set()
        node = self.node
        if node is not None:
            node.wake()

    @property
    def stage(self) -> int:
        return self.machine.stage

    @property
    def handled(self) -> dict:
        """stage -> the first answer (:class:`mission.carrier.Answer`)."""
        return self.machine.handled

    @property
    def ended(self) -> bool:
        return self.machine.ended

    def _position(self) -> tuple[float, float]:
        return tuple(map(float, self.sim.position(self.cid)))

    # ------------------------------------------------------------------ the one way state changes
    def apply(self, event) -> None:
        """Step the carrier machine, then carry out its effects in order."""
        self.machine, effects = mc.step(self.machine, event)
        for effect in effects:
            if isinstance(effect, mc.Deploy):
                self.sim.deploy(self.cid)
            elif isinstance(effect, mc.SendConfirm):
                self.node.put(keys.carrier_key(self.mission, self.cid, "confirm"), Confirm(
                    self.mission, self.cid, effect.stage, effect.deployed, effect.status, effect.position,
                    effect.passengers_left))
            elif isinstance(effect, mc.SendHello):
                self._hello(effect.next_stage)
            elif isinstance(effect, mc.ResendObservation):
                if self.pending is not None and self.pending.stage == effect.stage:
                    self.node.put(keys.carrier_key(self.mission, self.cid, "obs"), self.pending)
            elif isinstance(effect, mc.Reject):
                self.node.reject(effect.reason, effect.detail, self.log)
            elif isinstance(effect, mc.Log):
                self.log(effect.line)

    def _hello(self, next_stage: int) -> None:
        self.node.put(keys.carrier_key(self.mission, self.cid, "hello"), Hello(
            self.mission, self.cid, os.getpid(), socket.gethostname()[:255], self.machine.passengers_left,
            next_stage, self.fingerprint, max(1, self.machine.epoch)))

    # ------------------------------------------------------------------ inbound
    def _pump(self, timeout_s: float) -> None:
        item = self.node.next(timeout_s)
        while item is not None:
            try:
                self._handle(item)
            except ProtocolError as exc:
                self.node.reject(exc.reason, exc.detail, self.log)
            item = self.node.next(0.0)

    def _handle(self, item) -> None:
        if item.kind == "wake":
            return
        if item.kind in ("alive", "gone"):
            if item.key != keys.coordinator_alive(self.mission):
                raise ProtocolError("bad-key", f"liveliness token on {item.key[:80]}")
            if item.kind == "alive":
                returned = self.coordinator_seen and not self.coordinator_present
                self.coordinator_present = self.coordinator_seen = True
                if returned:
                    self.apply(mc.Resync(self._state_seen(self._query_once()), self._position()))
            else:
                self.coordinator_present = False
                self.absent_since = time.monotonic()
                self.log("coordinator's liveliness token vanished; holding")
            return
        if item.key == keys.end_key(self.mission):
            msg = decode(item.payload, End)
            if msg.mission != self.mission:
                raise ProtocolError("wrong-mission", f"mission {msg.mission!r}")
            self.apply(mc.EndHeard())
            return
        if item.key == keys.refusal_key(self.mission, self.cid):
            msg = decode(item.payload, Refusal)
            if msg.mission != self.mission or msg.carrier != self.cid:
                raise ProtocolError("wrong-mission", f"refusal for {msg.mission!r}/{msg.carrier!r}")
            if msg.fingerprint == self.fingerprint:  # else someone else spoke with our id
                self._refused = msg
            return
        if item.key != keys.decision_key(self.mission):
            raise ProtocolError("bad-key", f"message on {item.key[:80]}")
        msg = decode(item.payload, Decision)
        if msg.mission != self.mission:
            raise ProtocolError("wrong-mission", f"mission {msg.mission!r}")
        self.apply(mc.DecisionHeard(msg.stage, msg.t, msg.deploy, self._position(), msg.epoch))

    def _query_once(self) -> State | None:
        """The State reply of the highest epoch (two coordinators may answer across a split)."""
        best = None
        for payload in self.node.query(keys.state_selector(self.mission, self.cid), timeout_s=DEFAULTS.state_query_s):
            try:
                state = decode(payload, State)
            except ProtocolError as exc:
                self.node.reject(exc.reason, exc.detail, self.log)
                continue
            if state.mission == self.mission and (best is None or state.epoch > best.epoch):
                best = state
        return best

    def _query_state(self) -> State | None:
        """Ask the coordinator for the mission state, retrying until coordinator_timeout_s."""
        deadline = time.monotonic() + self.config.coordinator_timeout_s
        while not self._stop.is_set() and time.monotonic() < deadline:
            state = self._query_once()
            if state is not None:
                return state
            self._pump(0.2)
        return None

    def _state_seen(self, state: State | None) -> mc.StateSeen | None:
        if state is None:
            return None
        mine = state.carrier(self.cid)
        last = state.last_decision
        return mc.StateSeen(state.next_stage, tuple(mine.deployments) if mine else (),
                            None if last is None else (last.stage, last.t, tuple(last.deploy)), state.ended,
                            state.epoch)

    # ------------------------------------------------------------------ physics
    def _advance(self, t: float) -> None:
        """Physics to mission time ``t`` (s) at fixed steps, paced when realtime > 0."""
        if self.config.realtime <= 0:
            self.sim.advance_to(t)
            return
        wall0, t0 = time.monotonic(), self.sim.time
        while self.sim.time < t - 1e-9 and not self._stop.is_set():
            target = min(t, self.sim.time + PACE_CHUNK_S)
            self.sim.advance_to(target)
            self._publish_poses()
            due = wall0 + (self.sim.time - t0) / self.config.realtime
            while time.monotonic() < due and not self._stop.is_set():
                self._pump(min(0.05, due - time.monotonic()))
                self._check_refused()

    def _trail(self) -> tuple:
        samples = self.sim.trajectory(self.cid)
        new = samples[self._trail_from:, 1:3]
        self._trail_from = len(samples)
        if len(new) > MAX_TRAIL:
            new = new[np.linspace(0, len(new) - 1, MAX_TRAIL).astype(int)]
        return tuple((float(a), float(b)) for a, b in new)

    def _publish_poses(self) -> None:
        """A Pose for every pose tick the physics passed since the last call: the trajectory
        samples (one per second of simulated time) whose time is a multiple of the interval."""
        every = self.config.pose_interval_s
        if every <= 0 or self.node is None:
            return
        samples = self.sim.trajectory(self.cid)
        step = max(1, int(round(every)))
        for k in range(self._pose_from, len(samples)):
            if k > 0:
                dx, dy = samples[k, 1] - samples[k - 1, 1], samples[k, 2] - samples[k - 1, 2]
                if dx * dx + dy * dy > 1e-12:
                    self._heading = float(np.arctan2(dy, dx))
            if k % step == 0:
                self.node.put(keys.carrier_key(self.mission, self.cid, "pose"), Pose(
                    self.mission, self.cid, float(samples[k, 0]), (float(samples[k, 1]), float(samples[k, 2])),
                    self._heading, self.machine.passengers_left))
        self._pose_from = len(samples)

    def _check_refused(self) -> None:
        if self._refused is not None:
            self.log(f"the coordinator refused our Hello ({self._refused.reason}: fingerprint {self.fingerprint}, "
                     f"the coordinator's {self._refused.expected}): use the same scenario file and --seed")
            raise _Exit("world-mismatch")

    # ------------------------------------------------------------------ the stages
    def _join(self) -> None:
        state = self._query_state()
        if state is None:
            raise _Exit("stopped" if self._stop.is_set() else "coordinator-lost")
        if state.fingerprint != self.fingerprint:
            self.log(f"the coordinator runs another world (fingerprint {state.fingerprint}, ours "
                     f"{self.fingerprint}): use the same scenario file and --seed")
            raise _Exit("world-mismatch")
        if not state.ended:
            mine = state.carrier(self.cid)
            for j in mc.replay_plan(self.machine, state.next_stage, mine.deployments if mine else ()):
                self.sim.advance_to(self.scenario.stage_time(j))
                self.apply(mc.Replayed(j, self._position()))
                self.sim.deploy(self.cid)
        self.apply(mc.Joined(state.next_stage, state.ended, state.epoch))
        self._hello(self.machine.hello_stage())

    def _wait_decision(self, j: int) -> None:
        """Until stage j is resolved (answered, or the coordinator moved on), the decision
        timeout (coordinator present), End, or a stop request."""
        waited = 0.0
        last = time.monotonic()
        while not self._stop.is_set() and not self.machine.ended and not self.machine.resolved(j):
            self._check_refused()
            now = time.monotonic()
            if self.coordinator_present:
                waited += now - last
                if waited >= self.config.decision_timeout_s:
                    self.log(f"no decision for stage {j} within {self.config.decision_timeout_s:.0f} s; going on")
                    return
            elif now - self.absent_since >= self.config.coordinator_timeout_s:
                self.log(f"coordinator absent for {self.config.coordinator_timeout_s:.0f} s; exiting")
                raise _Exit("coordinator-lost")
            last = now
            self._pump(IDLE_POLL_S)

    def _fly(self) -> None:
        at_once = True  # the first stage after joining is reached at once, not paced
        j = self.machine.stage
        while j < self.n_stages and not self.machine.ended and not self._stop.is_set():
            t_j = self.scenario.stage_time(j)
            if at_once or self.machine.behind(j):
                self.sim.advance_to(t_j)  # joining, or catching up with stages decided without us
            else:
                self._advance(t_j)
            self._publish_poses()
            if self._stop.is_set():
                break
            if self.machine.behind(j):
                # Decided without our observation (we were cut off, or too slow): ∅ for us.
                # Publishing it would only be rejected as stale; answer its decision if it
                # reached us; go on at once.
                self.apply(mc.Passed(j, self._position()))
                at_once = True
                j += 1
                continue
            at_once = False
            x = self.sim.sense(self.cid) if self.valid[j] else None
            self.pending = Observation(
                self.mission, self.cid, j, float(t_j), x, self._position(), self.machine.passengers_left,
                self._trail())
            self.apply(mc.Observed(j))
            self.node.put(keys.carrier_key(self.mission, self.cid, "obs"), self.pending)
            self._wait_decision(j)
            self.apply(mc.MovedOn(j))
            self.pending = None
            j += 1

    def run(self) -> str:
        from wire.transport import Node
        from wire.zconfig import OpenStopped

        reason = "finished"
        self.sim = world.Simulation(self.scenario, carriers=[self.cid],
                                    features=None if self.shared is None else self.shared.features)
        try:
            self.node = Node(self.zconf, open_timeout_s=self.config.coordinator_timeout_s, stop=self._stop)
        except OpenStopped:
            return "stopped"
        try:
            self.node.subscribe(keys.decision_key(self.mission))
            self.node.subscribe(keys.end_key(self.mission))
            self.node.subscribe(keys.refusal_key(self.mission, self.cid))
            self.node.watch_liveliness(keys.coordinator_alive(self.mission))
            self.node.token(keys.carrier_alive(self.mission, self.cid))
            self._join()
            self._fly()
            deadline = time.monotonic() + self.config.end_timeout_s
            while not self.machine.ended and not self._stop.is_set() and time.monotonic() < deadline:
                self._check_refused()
                self._pump(IDLE_POLL_S)
            reason = "stopped" if self._stop.is_set() else ("end" if self.machine.ended else "finished")
        except _Exit as exc:
            reason = exc.reason
        finally:
            try:
                self.node.put(keys.carrier_key(self.mission, self.cid, "bye"), Bye(
                    self.mission, self.cid, self.machine.deployments(),
                    tuple(sorted(self.node.rejected.items())), reason))
            except Exception:
                pass
            self.node.close(DEFAULTS.close_s)
        return reason


def run_carriers(scenario, configs, zconf, stop: threading.Event | None = None) -> dict:
    """Run several carriers in this process, one thread and one Zenoh session each (the protocol
    and the coordinator cannot tell them from carriers in processes of their own); the world
    (schedules, fingerprint, features) is derived once and shared.

    Args:
        scenario: the loaded scenario (every config must name the same ``seed``).
        configs: one :class:`CarrierConfig` per carrier.
        zconf: a zenoh config, or a callable returning a fresh one (one per session).
        stop: the process's stop request, shared by all carriers.

    Returns:
        carrier id -> its exit reason (a key of :data:`EXIT_CODES`).

    Raises:
        DuplicateCarriers: some of these carriers are live elsewhere (checked before any flies).
    """
    stop = stop if stop is not None else threading.Event()
    configs = list(configs)
    if configs:
        mission = configs[0].mission or keys.mission_id_from_name(scenario.name)
        taken = live_duplicates(mission, [c.carrier for c in configs], zconf, stop,
                                configs[0].coordinator_timeout_s)
        if taken:
            raise DuplicateCarriers(mission, taken)
    shared = None
    if len(configs) > 1:
        seeds = {c.seed for c in configs}
        if len(seeds) != 1:
            raise ValueError("carriers of one process must share the seed")
        seed = seeds.pop()
        if seed is not None:
            scenario = scenario.with_seed(int(seed))
        shared = shared_world(scenario)
    carriers = [Carrier(scenario, c, zconf() if callable(zconf) else zconf, stop=stop, shared=shared)
                for c in configs]
    reasons: dict = {}

    def body(carrier):
        try:
            reasons[carrier.cid] = carrier.run()
        except Exception:  # one carrier's bug must not take its neighbours down
            import sys
            import traceback

            print(f"carrier {carrier.cid}: crashed\n{traceback.format_exc()}", file=sys.stderr, flush=True)
            reasons[carrier.cid] = "crashed"

    threads = [threading.Thread(target=body, args=(c,), name=f"carrier-{c.cid}", daemon=True) for c in carriers]
    for thread in threads:
        thread.start()
    woken = False
    for thread in threads:
        while thread.is_alive():
            thread.join(0.2)
            if stop.is_set() and not woken:  # a signal: wake every carrier from its wait
                woken = True
                for c in carriers:
                    c.stop()
    return {c.cid: reasons.get(c.cid, "crashed") for c in carriers}
