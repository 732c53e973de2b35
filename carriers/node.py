"""One carrier process: its own pymunk body, the stage handshake and catch-up over Zenoh.

The carrier builds the same world as every other process from the scenario (deterministic from
its seed) but simulates only its own body (carriers never collide with each other, so its
motion equals ``world.observe_all``'s). Per stage j (docs/protocol.md, "Stage handshake"):

1. advance the physics at fixed steps to t_j (paced at ``realtime`` × wall time when > 0);
2. publish the Observation of j (x = features sensed, or None when not scheduled at j);
3. wait for the Decision of j: the wait only counts while the coordinator's liveliness token is
   present, and ends after ``decision_timeout_s`` (then the carrier goes on without deploying);
   while the coordinator is absent the carrier holds, and exits after ``coordinator_timeout_s``;
4. deploy if selected (the passenger appears in the world) and publish a Confirm.

A carrier that starts late, or restarts, first queries ``coordinator/state``: it replays its
recorded deployments, skips the decided stages and joins at the first undecided one. A carrier
that finds the coordinator ahead of it (a partition healed, the coordinator came back, its
decisions arrived in a burst) does the same: stages already decided are ∅ for it, reached at once
without publishing a stale observation, and the first undecided stage is reached unpaced.
Decisions are handled at most once per stage (a repeated one gets its first answer again), and
a carrier never deploys more passengers than it carries: no double deployment.
"""
from __future__ import annotations

import os
import socket
import time
from dataclasses import dataclass

import numpy as np

import world
from wire import keys
from wire.messages import (
    Bye, Confirm, Decision, End, Hello, Observation, ProtocolError, State, decode, scenario_fingerprint,
)

#: Trail points per Observation at most (the protocol's limit).
MAX_TRAIL = 512
#: Sim-time chunk (s) between pacing sleeps when ``realtime > 0``.
PACE_CHUNK_S = 0.5

#: Exit reasons and the process exit code each maps to.
EXIT_CODES = {"end": 0, "finished": 0, "stopped": 130, "coordinator-lost": 1, "world-mismatch": 2}


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
    """

    carrier: str
    mission: str | None = None
    seed: int | None = None
    realtime: float = 0.0
    decision_timeout_s: float = 30.0
    coordinator_timeout_s: float = 30.0
    end_timeout_s: float = 10.0
    log: object = None


class Carrier:
    """One carrier. ``run()`` returns its exit reason (a key of :data:`EXIT_CODES`)."""

    def __init__(self, scenario, config: CarrierConfig, zconf):
        if config.seed is not None:
            scenario = scenario.with_seed(int(config.seed))
        self.scenario = scenario
        self.config = config
        self.zconf = zconf
        self.cid = keys.check_id(config.carrier, "carrier")
        self.r = scenario.carrier_index(self.cid)  # KeyError for an unknown id (checked by the CLI)
        self.mission = keys.check_id(config.mission or keys.mission_id_from_name(scenario.name), "mission")
        self.valid = scenario.valid()[self.r]
        self.n_stages = scenario.stages
        self.fingerprint = scenario_fingerprint(scenario)
        self._log = config.log or (lambda line: print(line, flush=True))
        self.sim: world.Simulation | None = None
        self.node = None
        self.handled: dict[int, Confirm] = {}      # stage -> our (first) answer
        self.buffered: dict[int, Decision] = {}    # decisions for stages we have not reached
        self.latest_decided = -1
        self.state_next = 0        # the coordinator's next_stage, as last learnt from State
        self.ended = False
        self.coordinator_present = False
        self.coordinator_seen = False
        self.absent_since = time.monotonic()
        self.pending: Observation | None = None
        self.stage = 0
        self.joined = 0            # first stage this process handles itself (State.next_stage at join)
        self._trail_from = 0
        self._stop = False

    def log(self, line: str) -> None:
        self._log(f"carrier {self.cid}: {line}")

    def stop(self) -> None:
        self._stop = True

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
        if item.kind in ("alive", "gone"):
            if item.key != keys.coordinator_alive(self.mission):
                raise ProtocolError("bad-key", f"liveliness token on {item.key[:80]}")
            if item.kind == "alive":
                returned = self.coordinator_seen and not self.coordinator_present
                self.coordinator_present = self.coordinator_seen = True
                if returned:
                    self._resync()
            else:
                self.coordinator_present = False
                self.absent_since = time.monotonic()
                self.log("coordinator's liveliness token vanished; holding")
            return
        if item.key == keys.end_key(self.mission):
            msg = decode(item.payload, End)
            if msg.mission != self.mission:
                raise ProtocolError("wrong-mission", f"mission {msg.mission!r}")
            self.ended = True
            return
        if item.key != keys.decision_key(self.mission):
            raise ProtocolError("bad-key", f"message on {item.key[:80]}")
        self._on_decision(decode(item.payload, Decision))

    def _on_decision(self, msg: Decision) -> None:
        if msg.mission != self.mission:
            raise ProtocolError("wrong-mission", f"mission {msg.mission!r}")
        if msg.stage >= self.n_stages:
            raise ProtocolError("out-of-range", f"decision for stage {msg.stage} >= {self.n_stages}")
        if msg.stage < self.joined and msg.stage not in self.handled:
            return  # decided before this process joined: the mission log has its outcome
        if msg.stage in self.handled:
            first = self.handled[msg.stage]
            self._confirm(Confirm(self.mission, self.cid, msg.stage, first.deployed, "already",
                                  first.position, first.passengers_left))
            return
        if msg.stage < self.stage:
            # We gave up on this stage and moved on: too late to deploy there.
            self._answer(msg, allow=False)
            return
        if msg.stage in self.buffered:
            raise ProtocolError("duplicate", f"second decision for stage {msg.stage}")
        self.buffered[msg.stage] = msg
        self.latest_decided = max(self.latest_decided, msg.stage)

    def _resync(self) -> None:
        """The coordinator came back (restarted, or a partition healed): announce ourselves again,
        learn from the mission state how far the mission got, take its last decision (the
        re-publication may have raced our reconnection), re-send the pending observation if its
        stage is still open, and repeat our answers (``already``) so a coordinator that lost
        Confirms in flight has every outcome on record."""
        self.log("coordinator is back; re-sending hello and the pending observation")
        state = None
        for payload in self.node.query(keys.state_key(self.mission), timeout_s=2.0):
            try:
                candidate = decode(payload, State)
            except ProtocolError as exc:
                self.node.reject(exc.reason, exc.detail, self.log)
                continue
            if candidate.mission == self.mission:
                state = candidate
                break
        if state is not None:
            self.state_next = max(self.state_next, state.next_stage)
        self._hello()  # after the state query: next_stage says where we go on from
        if state is not None:
            mine = state.carrier(self.cid)
            last = state.last_decision
            for j in (mine.deployments if mine else ()):
                if (j < state.next_stage and j <= self.stage and j not in self.handled
                        and j not in self.buffered and (last is None or j != last.stage)):
                    # Decided for us while we were cut off and never received: we did not deploy
                    # there. Saying so lets the coordinator count the passenger as still on board.
                    self._answer(Decision(self.mission, j, float(self.scenario.stage_time(j)), (self.cid,), 0.0),
                                 allow=False)
            if last is not None and last.stage not in self.handled and last.stage not in self.buffered:
                self._on_decision(last)
            if state.ended:
                self.ended = True
        if self.pending is not None and self.pending.stage >= self.state_next:
            self.node.put(keys.carrier_key(self.mission, self.cid, "obs"), self.pending)
        for j, first in sorted(self.handled.items()):
            if j >= self.joined:
                self._confirm(Confirm(self.mission, self.cid, j, first.deployed, "already",
                                      first.position, first.passengers_left))

    def decided_upto(self) -> int:
        """Stages known to be decided already (0..N): the carrier is behind the coordinator at
        every stage below this (after a partition, or a coordinator that went on without it)."""
        return max(self.latest_decided + 1, self.state_next)

    # ------------------------------------------------------------------ actions
    def _hello(self) -> None:
        self.node.put(keys.carrier_key(self.mission, self.cid, "hello"), Hello(
            self.mission, self.cid, os.getpid(), socket.gethostname()[:255],
            self.sim.passengers_left(self.cid), min(max(self.stage, self.state_next), self.n_stages),
            self.fingerprint))

    def _confirm(self, confirm: Confirm) -> None:
        self.node.put(keys.carrier_key(self.mission, self.cid, "confirm"), confirm)

    def _answer(self, decision: Decision, allow: bool) -> Confirm:
        """Execute (or decline) one decision and confirm it. Called at most once per stage."""
        j = decision.stage
        position = self.sim.position(self.cid)
        selected = self.cid in decision.deploy
        if not selected:
            status, deployed = "idle", False
        elif not allow:
            status, deployed = "late", False
        elif self.sim.passengers_left(self.cid) <= 0 or not self.valid[j]:
            status, deployed = "refused", False
        else:
            position = tuple(self.sim.deploy(self.cid).position)
            status, deployed = "deployed", True
            self.log(f"deployed a passenger at stage {j} at ({position[0]:.1f}, {position[1]:.1f}) m")
        confirm = Confirm(self.mission, self.cid, j, deployed, status,
                          (float(position[0]), float(position[1])), self.sim.passengers_left(self.cid))
        self.handled[j] = confirm
        self._confirm(confirm)
        return confirm

    def _advance(self, t: float) -> None:
        """Physics to mission time ``t`` (s) at fixed steps, paced when realtime > 0."""
        if self.config.realtime <= 0:
            self.sim.advance_to(t)
            return
        wall0, t0 = time.monotonic(), self.sim.time
        while self.sim.time < t - 1e-9 and not self._stop:
            target = min(t, self.sim.time + PACE_CHUNK_S)
            self.sim.advance_to(target)
            due = wall0 + (self.sim.time - t0) / self.config.realtime
            while time.monotonic() < due and not self._stop:
                self._pump(min(0.05, due - time.monotonic()))

    def _trail(self) -> tuple:
        samples = self.sim.trajectory(self.cid)
        new = samples[self._trail_from:, 1:3]
        self._trail_from = len(samples)
        if len(new) > MAX_TRAIL:
            new = new[np.linspace(0, len(new) - 1, MAX_TRAIL).astype(int)]
        return tuple((float(a), float(b)) for a, b in new)

    def _query_state(self) -> State | None:
        """Ask the coordinator for the mission state, retrying until coordinator_timeout_s."""
        deadline = time.monotonic() + self.config.coordinator_timeout_s
        while not self._stop and time.monotonic() < deadline:
            for payload in self.node.query(keys.state_key(self.mission), timeout_s=2.0):
                try:
                    state = decode(payload, State)
                except ProtocolError as exc:
                    self.node.reject(exc.reason, exc.detail, self.log)
                    continue
                if state.mission == self.mission:
                    return state
            self._pump(0.2)
        return None

    def _catch_up(self, state: State) -> None:
        """Replay our recorded deployments and move to the first undecided stage."""
        mine = state.carrier(self.cid)
        past = sorted(mine.deployments) if mine else []
        for j in past:
            if j < state.next_stage and self.sim.passengers_left(self.cid) > 0:
                self.sim.advance_to(self.scenario.stage_time(j))
                dep = self.sim.deploy(self.cid)
                self.handled[j] = Confirm(self.mission, self.cid, j, True, "deployed",
                                          tuple(map(float, dep.position)), self.sim.passengers_left(self.cid))
        self.stage = self.joined = state.next_stage
        self.state_next = max(self.state_next, state.next_stage)
        if state.next_stage > 0:
            self.log(f"joined at stage {state.next_stage} ({len(past)} deployment(s) on record)")

    def _wait_decision(self, j: int) -> Decision | None:
        waited = 0.0
        last = time.monotonic()
        while not self._stop and not self.ended:
            if j in self.handled:
                return None  # answered already (as late, while resynchronising)
            if j in self.buffered:
                return self.buffered.pop(j)
            if self.latest_decided > j or self.state_next > j:
                return None  # the coordinator moved on: our decision was lost
            now = time.monotonic()
            if self.coordinator_present:
                waited += now - last
                if waited >= self.config.decision_timeout_s:
                    self.log(f"no decision for stage {j} within {self.config.decision_timeout_s:.0f} s; going on")
                    return None
            elif now - self.absent_since >= self.config.coordinator_timeout_s:
                raise _CoordinatorLost()
            last = now
            self._pump(0.05)
        return None

    # ------------------------------------------------------------------ main loop
    def run(self) -> str:
        from wire.transport import Node

        reason = "finished"
        self.sim = world.Simulation(self.scenario, carriers=[self.cid])
        self.node = Node(self.zconf, open_timeout_s=self.config.coordinator_timeout_s)
        try:
            self.node.subscribe(keys.decision_key(self.mission))
            self.node.subscribe(keys.end_key(self.mission))
            self.node.watch_liveliness(keys.coordinator_alive(self.mission))
            self.node.token(keys.carrier_alive(self.mission, self.cid))
            state = self._query_state()
            if state is None:
                raise _CoordinatorLost()
            if state.fingerprint != self.fingerprint:
                self.log(f"the coordinator runs another world (fingerprint {state.fingerprint}, ours "
                         f"{self.fingerprint}): use the same scenario file and --seed")
                return "world-mismatch"
            if state.ended:
                self.ended = True
            else:
                self._catch_up(state)
            self._hello()
            at_once = True  # the first stage after joining is reached at once, not paced
            j = self.stage
            while j < self.n_stages and not self.ended and not self._stop:
                self.stage = j
                t_j = self.scenario.stage_time(j)
                if at_once or j < self.decided_upto():
                    self.sim.advance_to(t_j)  # joining, or catching up with stages decided without us
                else:
                    self._advance(t_j)
                if j < self.decided_upto():
                    # The coordinator decided j without our observation (we were cut off, or too
                    # slow): it is ∅ for us. Publishing it would only be rejected as stale; answer
                    # its decision if it reached us; go on at once.
                    decision = self.buffered.pop(j, None)
                    if decision is not None and j not in self.handled:
                        self._answer(decision, allow=True)
                    at_once = True
                    j += 1
                    continue
                at_once = False
                x = self.sim.sense(self.cid) if self.valid[j] else None
                self.pending = Observation(
                    self.mission, self.cid, j, float(t_j), x,
                    tuple(map(float, self.sim.position(self.cid))), self.sim.passengers_left(self.cid),
                    self._trail())
                self.node.put(keys.carrier_key(self.mission, self.cid, "obs"), self.pending)
                decision = self._wait_decision(j)
                self.pending = None
                if decision is not None:
                    self._answer(decision, allow=True)
                j += 1
            self.stage = j
            deadline = time.monotonic() + self.config.end_timeout_s
            while not self.ended and not self._stop and time.monotonic() < deadline:
                self._pump(0.05)
            reason = "stopped" if self._stop else ("end" if self.ended else "finished")
        except _CoordinatorLost:
            self.log(f"coordinator absent for {self.config.coordinator_timeout_s:.0f} s; exiting")
            reason = "coordinator-lost"
        except KeyboardInterrupt:
            reason = "stopped"
        finally:
            try:
                deployments = tuple(sorted(j for j, c in self.handled.items() if c.deployed))
                self.node.put(keys.carrier_key(self.mission, self.cid, "bye"), Bye(
                    self.mission, self.cid, deployments, tuple(sorted(self.node.rejected.items())), reason))
            except Exception:
                pass
            self.node.close(3.0)
        return reason


class _CoordinatorLost(Exception):
    pass
