"""The coordinator process: the stage clock, the stage handshake, planning and the mission log.

A thin adapter around the pure planner core: observations arrive over Zenoh (wire/), are
committed to mission.db (coordinator/store.py), the StageView is built with
``planner.problem.make_view`` exactly as ``run_online`` builds it, the planner decides with
``stage_rng(seed, j)``, the decision is committed and only then published.

Stage j (docs/protocol.md, "Stage handshake"):

1. (``realtime > 0`` only) wait until ``Δt / realtime`` after decision j-1 was published (the
   carriers pace their physics from the same moment);
2. wait until every *expected* carrier — live (liveliness token present), compatible (same
   world fingerprint) and scheduled at j — has sent its Observation of j, or ``stage_timeout_s``;
3. scheduled carriers without an observation are ∅ at j (recorded as ``missing``);
4. plan, commit the decision, publish it; Confirms are collected while the next stage waits.

Recovery: started on a results directory whose mission.db holds a mission, the coordinator
replays it, re-publishes the last decision (carriers treat repeats idempotently) and continues
at the first undecided stage. Planners are stateless, so the continuation is exactly the one
an uninterrupted coordinator would have produced from the same observations.
"""
from __future__ import annotations

import json
import math
import os
import socket
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import world
from planner.registry import make_planner
from planner.problem import Problem, enforce, evaluate, make_view, rewards, stage_rng
from coordinator.store import MissionStore
from wire import keys
from wire.messages import (
    Bye, CarrierState, Confirm, Decision, End, Hello, Observation, ProtocolError, State, decode,
    encode, scenario_fingerprint,
)
from wire.transport import Node

#: Which message type each carrier topic carries.
TOPIC_TYPES = {"hello": Hello, "obs": Observation, "confirm": Confirm, "bye": Bye}


@dataclass(frozen=True)
class CoordinatorConfig:
    """Settings of one coordinator run.

    Attributes:
        out_dir: results directory (mission.db, summary.json, map.png).
        mission: mission id (key-expression prefix); scenario name by default.
        planner, iterations, plan_ms: override the scenario's planner settings when not None.
        seed: overrides the scenario's root seed when not None (carriers must use the same).
        realtime: 0 = as fast as possible; F > 0 = stage j opens at wall time t_j / F.
        join_timeout_s: wait this long (s) for every carrier's liveliness before stage 0.
        stage_timeout_s: wait this long (s) per stage for the expected observations.
        confirm_timeout_s: after the last decision, wait this long (s) for its confirmations.
        bye_timeout_s: after End, wait this long (s) for carriers' Bye messages.
        render: draw map.png at the end.
        log: where progress lines go (a callable taking one string).
    """

    out_dir: str
    mission: str | None = None
    planner: str | None = None
    iterations: int | None = None
    plan_ms: float | None = None
    planner_options: tuple = ()  # (key, value) pairs of planner.registry.OPTIONS, override the scenario
    seed: int | None = None
    realtime: float = 0.0
    join_timeout_s: float = 20.0
    stage_timeout_s: float = 5.0
    confirm_timeout_s: float = 3.0
    bye_timeout_s: float = 2.0
    render: bool = True
    log: object = None


def build_problem(scenario, geometry=None) -> Problem:
    """The planner core's instance for a scenario: schedules, overlaps and prior from world/."""
    geometry = world.stage_geometry(scenario) if geometry is None else geometry
    return Problem.build(scenario.passengers, geometry.valid, geometry.overlaps, scenario.prior_distribution())


def planner_settings(scenario, name=None, iterations=None, plan_ms=None, extra=()) -> tuple[str, dict]:
    """(planner name, options for make_planner): the scenario's, overridden by non-None flags.

    An explicit ``iterations`` flag drops the scenario's ``plan_ms`` (which would take
    precedence), so ``--iterations`` always means an iteration budget.
    """
    spec = scenario.planner
    options = dict(spec.options())
    if iterations is not None:
        options["iterations"] = int(iterations)
        options.pop("plan_ms", None)
    if plan_ms is not None:
        options["plan_ms"] = float(plan_ms)
    options.update(dict(extra))  # --planner-option KEY=VALUE (checked by planner.registry)
    return (name or spec.name), options


def percentile(values, q) -> float | None:
    return float(np.percentile(values, q)) if len(values) else None


class Coordinator:
    """One coordinator: owns the Zenoh node, the store and the mission state.

    Args:
        scenario: the loaded scenario (its seed is replaced by ``config.seed`` when given).
        config: :class:`CoordinatorConfig`.
        zconf: the zenoh config (wire.zconfig.make_config).
        scenario_path: shown in summary.json.
    """

    def __init__(self, scenario, config: CoordinatorConfig, zconf, scenario_path: str = ""):
        if config.seed is not None:
            scenario = scenario.with_seed(int(config.seed))
        self.scenario = scenario
        self.config = config
        self.zconf = zconf
        self.scenario_path = scenario_path or scenario.source
        self.seed = int(scenario.seed)
        self.mission = keys.check_id(config.mission or keys.mission_id_from_name(scenario.name), "mission")
        self.ids = scenario.carrier_ids
        self.index = {cid: r for r, cid in enumerate(self.ids)}
        self.geometry = world.stage_geometry(scenario)
        self.problem = build_problem(scenario, self.geometry)
        self.n_stages = self.problem.n_stages
        self.planner_name, self.planner_options = planner_settings(
            scenario, config.planner, config.iterations, config.plan_ms, config.planner_options)
        self.planner = make_planner(self.planner_name, **self.planner_options)
        self.fingerprint = scenario_fingerprint(scenario)
        self._log = config.log or (lambda line: print(line, flush=True))
        # Mission state (all derived from the store's content plus live events).
        shape = self.problem.valid.shape
        self.x = np.full(shape, np.nan)          # realised observations, NaN = ∅ / not yet
        self.reported = {}                       # (cid, j) -> x or None, first report wins
        self.positions = {}                      # (cid, j) -> (x, y) metres
        self.trails = {cid: [] for cid in self.ids}
        self.decided = np.zeros(shape, dtype=bool)   # decisions taken
        self.refuted = np.zeros(shape, dtype=bool)   # decided but a Confirm says not deployed
        self.confirmed = {}                      # (cid, j) -> Confirm
        self.decisions: dict[int, Decision] = {}
        self.published_at: dict[int, float] = {}    # stage -> monotonic time of publication
        self.latencies_ms: list[float] = []
        self.next_stage = 0
        self.live: set[str] = set()
        self.incompatible: set[str] = set()
        self.info = {cid: {"pid": None, "host": None} for cid in self.ids}
        self.carrier_rejected: dict[str, dict] = {}
        self.byes: set[str] = set()
        self.ended = False
        self.end_reason = None
        self._state_bytes = b""
        self._stop = threading.Event()
        self.node: Node | None = None
        self.store: MissionStore | None = None
        self.resumed = False

    # ------------------------------------------------------------------ helpers
    def log(self, line: str) -> None:
        self._log(line)

    def stop(self) -> None:
        """Ask the run loop to finish early (publishes End ``stopped``)."""
        self._stop.set()

    def deployed(self) -> np.ndarray:
        """bool ``[R, N]``: decisions not refuted by a Confirm (the planner's view of the past)."""
        return self.decided & ~self.refuted

    def passengers_left(self) -> np.ndarray:
        return self.problem.passengers - self.deployed().sum(axis=1)

    def _refresh_state(self) -> None:
        left = self.passengers_left()
        dep = self.deployed()
        carriers = tuple(
            (cid, CarrierState(int(left[r]), tuple(int(j) for j in np.flatnonzero(dep[r])), cid in self.live))
            for r, cid in enumerate(self.ids)
        )
        last = self.decisions.get(self.next_stage - 1)
        state = State(mission=self.mission, next_stage=self.next_stage, stages=self.n_stages,
                      fingerprint=self.fingerprint, ended=self.ended, carriers=tuple(sorted(carriers)),
                      last_decision=last)
        self._state_bytes = encode(state)

    # ------------------------------------------------------------------ inbound
    def _reject(self, reason: str, detail: str) -> None:
        first = reason not in self.node.rejected
        self.node.reject(reason, detail, lambda line: self.log(f"coordinator: {line}"))
        if first:
            self.store.event("rejected", reason=reason, detail=detail[:200])

    def pump(self, timeout_s: float) -> None:
        """Wait up to ``timeout_s`` seconds for inbox items, then handle every queued one."""
        item = self.node.next(max(0.0, timeout_s))
        while item is not None:
            try:
                self._handle(item)
            except ProtocolError as exc:
                self._reject(exc.reason, exc.detail)
            item = self.node.next(0.0)

    def _handle(self, item) -> None:
        if item.kind in ("alive", "gone"):
            if item.key == keys.coordinator_alive(self.mission):
                return
            parsed = keys.parse_carrier_key(self.mission, item.key)
            if parsed is None or parsed[1] != "alive":
                raise ProtocolError("bad-key", f"liveliness token on {item.key[:80]}")
            cid = parsed[0]
            if cid not in self.index:
                raise ProtocolError("unknown-carrier", f"liveliness token of carrier {cid!r}")
            if item.kind == "alive" and cid not in self.live:
                self.live.add(cid)
                self.store.event("alive", cid, self.next_stage)
                self.log(f"coordinator: carrier {cid} is live")
            elif item.kind == "gone" and cid in self.live:
                self.live.discard(cid)
                self.store.event("dead", cid, self.next_stage)
                self.log(f"coordinator: carrier {cid} is gone (liveliness token vanished)")
            self._refresh_state()
            return
        parsed = keys.parse_carrier_key(self.mission, item.key)
        if parsed is None or parsed[1] not in TOPIC_TYPES:
            raise ProtocolError("bad-key", f"message on {item.key[:80]}")
        cid, topic = parsed
        if cid not in self.index:
            raise ProtocolError("unknown-carrier", f"message from carrier {cid!r}")
        msg = decode(item.payload, TOPIC_TYPES[topic])
        if msg.mission != self.mission:
            raise ProtocolError("wrong-mission", f"mission {msg.mission!r} on {self.mission!r}")
        if msg.carrier != cid:
            raise ProtocolError("key-mismatch", f"carrier {msg.carrier!r} on the key of {cid!r}")
        getattr(self, f"_on_{topic}")(cid, msg, item.received)

    def _on_hello(self, cid: str, msg: Hello, received: float) -> None:
        if msg.fingerprint != self.fingerprint:
            if cid not in self.incompatible:
                self.incompatible.add(cid)
                self.store.event("hello", cid, None, pid=msg.pid, host=msg.host, compatible=False)
                self.log(f"coordinator: carrier {cid} built another world (scenario/seed fingerprint "
                         f"{msg.fingerprint} != {self.fingerprint}); its observations are ignored")
            raise ProtocolError("world-mismatch", f"carrier {cid} fingerprint {msg.fingerprint}")
        self.incompatible.discard(cid)
        self.byes.discard(cid)  # a restarted carrier: its earlier Bye is history
        self.info[cid] = {"pid": msg.pid, "host": msg.host}
        self.store.event("hello", cid, msg.next_stage, pid=msg.pid, host=msg.host,
                         passengers_left=msg.passengers_left, compatible=True)

    def _on_obs(self, cid: str, msg: Observation, received: float) -> None:
        if cid in self.incompatible:
            raise ProtocolError("world-mismatch", f"observation from incompatible carrier {cid}")
        j = msg.stage
        if j >= self.n_stages:
            raise ProtocolError("out-of-range", f"stage {j} >= {self.n_stages}")
        if j < self.next_stage:  # checked first: a late observation of a stage made ∅ is stale
            if msg.x is None and not self.problem.valid[self.index[cid], j]:
                # The per-stage ∅ of a stage the carrier is not scheduled at: nobody waited for
                # it (a carrier joining at its staggered start sends one for the stage in
                # progress); expected, so neither a problem nor worth counting.
                return
            raise ProtocolError("stale-stage", f"observation of carrier {cid} for decided stage {j}")
        if (cid, j) in self.reported:
            raise ProtocolError("duplicate", f"second observation of carrier {cid} at stage {j}")
        # Committed before any decision that reads it.
        self.store.observation(cid, j, msg.x, msg.position, t=msg.t, passengers_left=msg.passengers_left)
        self.reported[(cid, j)] = msg.x
        self.positions[(cid, j)] = msg.position
        self.trails[cid].extend(msg.trail)
        self.trails[cid].append(msg.position)

    def _on_confirm(self, cid: str, msg: Confirm, received: float) -> None:
        j = msg.stage
        if j >= self.next_stage:
            raise ProtocolError("stale-stage", f"confirmation of carrier {cid} for undecided stage {j}")
        if (cid, j) in self.confirmed:
            if msg.status == "already":
                return  # the answer to a re-published decision: expected, nothing new
            raise ProtocolError("duplicate", f"second confirmation of carrier {cid} at stage {j}")
        r = self.index[cid]
        latency = None
        if j in self.published_at:
            latency = (received - self.published_at[j]) * 1e3
        self.store.confirmation(cid, j, msg.deployed, msg.status, msg.position, latency)
        self.confirmed[(cid, j)] = msg
        if latency is not None and msg.status in ("deployed", "idle"):
            self.latencies_ms.append(latency)
        if self.decided[r, j] and not msg.deployed:
            self.refuted[r, j] = True
            self.log(f"coordinator: carrier {cid} did not deploy at stage {j} ({msg.status})")
        if msg.deployed and not self.decided[r, j]:
            self.log(f"coordinator: carrier {cid} reports an unrequested deployment at stage {j}")
        self._refresh_state()

    def _on_bye(self, cid: str, msg: Bye, received: float) -> None:
        self.byes.add(cid)
        self.carrier_rejected[cid] = dict(msg.rejected)
        self.store.event("bye", cid, None, reason=msg.reason, rejected=dict(msg.rejected),
                         deployments=list(msg.deployments))

    # ------------------------------------------------------------------ recovery
    def _recover(self) -> None:
        rec = self.store.replay()
        if rec.events <= 1:
            return
        self.resumed = True
        for (cid, j), x in rec.observations.items():
            if cid in self.index:
                self.reported[(cid, j)] = x
                if (cid, j) in rec.positions:
                    self.positions[(cid, j)] = rec.positions[(cid, j)]
        for (cid, j) in sorted(self.positions, key=lambda key: key[1]):
            self.trails[cid].append(self.positions[(cid, j)])  # the map's paths before the restart
        for j, (deploy, ms) in sorted(rec.decisions.items()):
            for cid in deploy:
                self.decided[self.index[cid], j] = True
            self.decisions[j] = Decision(self.mission, j, float(self.scenario.stage_time(j)), tuple(deploy), float(ms))
        for (cid, j), (deployed, status, position) in rec.confirmations.items():
            r = self.index[cid]
            if self.decided[r, j] and not deployed:
                self.refuted[r, j] = True
            self.confirmed[(cid, j)] = Confirm(self.mission, cid, j, deployed, status, position, 0)
        for cid, info in rec.carriers_info.items():
            if cid in self.info:
                self.info[cid] = info
        self.next_stage = rec.next_stage
        # A stopped mission (Ctrl-C) resumes; only a complete one is final.
        self.ended = rec.ended and rec.end_reason == "complete"
        self.end_reason = rec.end_reason if self.ended else None
        self.log(f"coordinator: resumed from {self.store.path}: {len(rec.decisions)} stage(s) decided, "
                 f"continuing at stage {self.next_stage}")

    # ------------------------------------------------------------------ the mission
    def _column(self, j: int) -> np.ndarray:
        """Observations of stage j as the planner sees them (NaN = ∅)."""
        col = np.full(len(self.ids), np.nan)
        for r, cid in enumerate(self.ids):
            value = self.reported.get((cid, j))
            if value is not None and self.problem.valid[r, j]:
                col[r] = float(value)
        return col

    def _expected(self, j: int) -> set[str]:
        return {cid for r, cid in enumerate(self.ids)
                if self.problem.valid[r, j] and cid in self.live and cid not in self.incompatible}

    def _wait_for_carriers(self) -> None:
        """Before the first stage: wait until every carrier's token is present (or the join
        timeout; on resume at most the stage timeout, since some carriers may be gone for good)."""
        wait_s = self.config.join_timeout_s
        if self.resumed:
            wait_s = min(wait_s, self.config.stage_timeout_s)
        deadline = time.monotonic() + wait_s
        while not self._stop.is_set() and time.monotonic() < deadline:
            if set(self.ids) <= self.live:
                return
            self.pump(0.05)
        missing = sorted(set(self.ids) - self.live)
        if missing:
            self.log(f"coordinator: starting without carrier(s) {', '.join(missing)} (not live after "
                     f"{wait_s:.0f} s); they can join late")

    def _decide(self, j: int) -> Decision:
        x_col = self._column(j)
        x = np.full(self.problem.valid.shape, np.nan)
        for jj in range(j + 1):
            x[:, jj] = self._column(jj)
        self.x = x
        view = make_view(self.problem, j, x, self.deployed())
        t0 = time.perf_counter()
        choice = enforce(view, self.planner.decide(view, stage_rng(self.seed, j)))
        planning_ms = (time.perf_counter() - t0) * 1e3
        deploy = tuple(sorted(self.ids[r] for r in np.flatnonzero(choice)))
        decision = Decision(self.mission, j, float(self.scenario.stage_time(j)), deploy, planning_ms)
        # Invariant: committed before published.
        self.store.decision(j, deploy, planning_ms,
                            observations={cid: (None if math.isnan(v) else v) for cid, v in zip(self.ids, x_col)})
        self.decided[:, j] = choice
        self.decisions[j] = decision
        self.next_stage = j + 1
        self._refresh_state()
        return decision

    def _publish_decision(self, decision: Decision) -> None:
        self.published_at[decision.stage] = time.monotonic()
        self.node.put(keys.decision_key(self.mission), decision)

    def _progress(self, decision: Decision, waited_ms: float) -> None:
        j = decision.stage
        obs = []
        for r, cid in enumerate(self.ids):
            value = self.reported.get((cid, j))
            if not self.problem.valid[r, j]:
                continue
            obs.append(f"{cid}={'∅' if value is None else value}")
        # Confirmations of the previous stage's deployments (stage numbers 1-based, as printed).
        confirmed = sorted(cid for (cid, jj), c in self.confirmed.items() if jj == j - 1 and c.deployed)
        self.log(
            f"stage {j + 1:>3}/{self.n_stages} t={decision.t:7.1f} s | obs {' '.join(obs) or '-'} | "
            f"deploy {' '.join(decision.deploy) or '-'} | plan {decision.planning_ms:7.1f} ms | "
            f"wait {waited_ms:6.0f} ms"
            + (f" | deployed@{j}: {' '.join(confirmed) or '-'}" if j > 0 else "")
        )

    def run(self) -> dict:
        """Run (or resume) the mission to its end; write summary.json and map.png.

        Returns:
            The summary dict.
        """
        out = Path(self.config.out_dir)
        out.mkdir(parents=True, exist_ok=True)
        meta = {"mission": self.mission, "scenario": self.scenario.name, "fingerprint": self.fingerprint,
                "seed": self.seed, "planner": self.planner_name, "planner_options": self.planner_options}
        self.store = MissionStore(out / "mission.db", meta)
        started = time.monotonic()
        try:
            self._recover()
            warm = getattr(self.planner, "warm_up", None)
            if callable(warm):
                warm(self.problem)
            self._refresh_state()
            self.node = Node(self.zconf)
            self.node.subscribe(f"{keys.prefix(self.mission)}/carrier/**")
            self.node.watch_liveliness(keys.carrier_alive_pattern(self.mission))
            self.node.serve(keys.state_key(self.mission), lambda: self._state_bytes)
            self.node.token(keys.coordinator_alive(self.mission))
            self.log(f"coordinator: mission {self.mission}, {len(self.ids)} carriers, {self.n_stages} stages, "
                     f"planner {self.planner_name} {self.planner_options}, seed {self.seed}")
            if self.next_stage > 0 and (self.next_stage - 1) in self.decisions:
                self._publish_decision(self.decisions[self.next_stage - 1])  # idempotent re-publication
            if not self.ended:
                self._wait_for_carriers()
                self._stages()
            self._finish()
        except KeyboardInterrupt:
            self._stop.set()
            self._end("stopped")
        finally:
            summary = self._summary(time.monotonic() - started)
            (out / "summary.json").write_text(json.dumps(summary, indent=2, default=_jsonable))
            if self.node is not None:
                self.node.close(3.0)
            if self.config.render:
                self._render(out / "map.png")
            self.store.close()
        return summary

    def _stages(self) -> None:
        last_published = None
        for j in range(self.next_stage, self.n_stages):
            if self._stop.is_set():
                self._end("stopped")
                return
            if self.config.realtime > 0 and last_published is not None:
                # Paced like the carriers: Δt / realtime after the previous decision went out.
                due = last_published + self.scenario.stage_interval / self.config.realtime
                while time.monotonic() < due and not self._stop.is_set():
                    self.pump(min(0.05, due - time.monotonic()))
            opened = time.monotonic()
            deadline = opened + self.config.stage_timeout_s
            while not self._stop.is_set():
                waiting = {cid for cid in self._expected(j) if (cid, j) not in self.reported}
                if not waiting or time.monotonic() >= deadline:
                    break
                self.pump(min(0.05, deadline - time.monotonic()))
            if self._stop.is_set():
                self._end("stopped")
                return
            missing = [cid for r, cid in enumerate(self.ids)
                       if self.problem.valid[r, j] and (cid, j) not in self.reported]
            if missing:
                self.store.missing(j, missing)
                for cid in missing:
                    self.reported[(cid, j)] = None
            decision = self._decide(j)
            self._publish_decision(decision)
            last_published = self.published_at[j]
            self._progress(decision, (time.monotonic() - opened) * 1e3 - decision.planning_ms)
            self.pump(0.0)

    def _finish(self) -> None:
        if self._stop.is_set():
            if not self.ended:
                self._end("stopped")
            return
        if self.ended:  # resumed a complete mission: only tell late carriers it is over
            self._end(self.end_reason or "complete")
            return
        last = self.n_stages - 1
        deadline = time.monotonic() + self.config.confirm_timeout_s
        while time.monotonic() < deadline and not self._stop.is_set():
            waiting = [cid for cid in self.live if (cid, last) not in self.confirmed]
            if not waiting:
                break
            self.pump(0.05)
        self._end("complete")

    def _end(self, reason: str) -> None:
        if self.store is None or self.node is None:
            return
        if not self.ended:
            self.store.event("end", None, self.next_stage, reason=reason)
            self.ended = True
            self.end_reason = reason
            self._refresh_state()
        end = End(self.mission, self.next_stage, reason)
        deadline = time.monotonic() + self.config.bye_timeout_s
        last_put = 0.0
        while time.monotonic() < deadline:
            if time.monotonic() - last_put > 0.5:
                self.node.put(keys.end_key(self.mission), end)  # repeated for carriers that missed it
                last_put = time.monotonic()
            if self.live <= self.byes:
                break
            self.pump(0.05)
        self.log(f"coordinator: mission {reason} after {self.next_stage} stage(s)")

    # ------------------------------------------------------------------ results
    def _summary(self, wall_s: float) -> dict:
        from planner import clairvoyant

        x = np.full(self.problem.valid.shape, np.nan)
        for j in range(self.n_stages):
            x[:, j] = self._column(j)
        actual = np.zeros(self.problem.valid.shape, dtype=bool)
        for (cid, j), c in self.confirmed.items():
            if c.deployed and self.decided[self.index[cid], j]:
                actual[self.index[cid], j] = True
        raw = rewards(self.problem, actual, x)
        total_reward, total_features = evaluate(self.problem, actual, x)
        try:
            bound = clairvoyant.solve(self.problem, np.where(self.problem.valid, x, np.nan))
            bound_d = {"reward": bound.reward, "features": bound.features, "exact": bool(bound.exact)}
            bound_d["fraction"] = (total_reward / bound.reward) if bound.reward > 0 else None
        except Exception as exc:  # the bound is a report, never a reason to lose the summary
            bound_d = {"error": f"{type(exc).__name__}: {exc}"}
        carriers = []
        for r, cid in enumerate(self.ids):
            deps = []
            for j in np.flatnonzero(actual[r]):
                c = self.confirmed[(cid, int(j))]
                deps.append({"stage": int(j), "t": float(self.scenario.stage_time(int(j))),
                             "x": None if math.isnan(x[r, j]) else float(x[r, j]),
                             "position": list(c.position),
                             "reward": float(raw[r, j] / self.problem.scale), "features": float(raw[r, j])})
            carriers.append({
                "id": cid, "pid": self.info[cid]["pid"], "host": self.info[cid]["host"],
                "passengers": int(self.problem.passengers[r]), "deployments": deps,
                "decided_stages": [int(j) for j in np.flatnonzero(self.decided[r])],
                "missing_stages": [j for j in range(self.n_stages)
                                   if self.problem.valid[r, j] and self.reported.get((cid, j)) is None
                                   and (cid, j) in self.reported],
                "live_at_end": cid in self.live,
                "rejected": self.carrier_rejected.get(cid, {}),
            })
        plan = [d.planning_ms for _, d in sorted(self.decisions.items())]
        return {
            "scenario": self.scenario.name, "scenario_file": str(self.scenario_path), "mission": self.mission,
            "planner": self.planner_name, "planner_options": self.planner_options, "seed": self.seed,
            "stages": self.n_stages, "stages_decided": len(self.decisions), "ended": self.ended,
            "end_reason": self.end_reason,
            "resumed": self.resumed,
            "coordinator": {"pid": os.getpid(), "host": socket.gethostname()},
            "carriers": carriers,
            "decisions": [list(self.decisions[j].deploy) if j in self.decisions else None
                          for j in range(self.n_stages)],
            "observations": [[None if math.isnan(v) else float(v) for v in row] for row in x],
            "total_reward": float(total_reward), "total_features": float(total_features),
            "clairvoyant": bound_d,
            "wall_time_s": float(wall_s),
            "latency_ms": {"p50": percentile(self.latencies_ms, 50), "p99": percentile(self.latencies_ms, 99),
                           "count": len(self.latencies_ms),
                           "meaning": "decision publication to carrier confirmation, coordinator clock"},
            "planning_ms": {"per_stage": plan, "mean": float(np.mean(plan)) if plan else None,
                            "max": float(np.max(plan)) if plan else None},
            "rejected": {"coordinator": dict(self.node.rejected) if self.node else {},
                         "carriers": {cid: self.carrier_rejected.get(cid, {}) for cid in self.ids}},
        }

    def _render(self, path: Path) -> None:
        deployments = []
        for (cid, j), c in sorted(self.confirmed.items(), key=lambda kv: (kv[0][1], kv[0][0])):
            if c.deployed:
                deployments.append(world.Deployment(cid, float(self.scenario.stage_time(j)), tuple(c.position)))
        trajectories = {cid: np.asarray(pts, dtype=float).reshape(-1, 2) for cid, pts in self.trails.items() if pts}
        try:
            world.render_map(self.scenario, str(path), deployments=deployments, trajectories=trajectories,
                             title=f"{self.scenario.name}: {self.planner_name}, seed {self.seed}")
        except Exception as exc:
            self.log(f"coordinator: map.png not drawn: {type(exc).__name__}: {exc}")


def _jsonable(value):
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (np.floating,)):
        return float(value)
    if isinstance(value, np.ndarray):
        return value.tolist()
    return str(value)
