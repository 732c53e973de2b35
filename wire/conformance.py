"""The conformance kit: fly a third-party carrier with the project's coordinator and check it
against docs/protocol.md, rule by rule.

    python -m wire.conformance SCENARIO --carrier ID [options] -- COMMAND [ARGS...]

The kit is the mission's zenoh router (mode ``router``, ``tcp/127.0.0.1:<free port>``,
multicast scouting off) and a passive observer of every message of the mission. It starts the
project's coordinator (``run_fleet.py --role coordinator``, a client of the router) and the
scenario's other carriers (``run_fleet.py --role carrier --no-autonomy``, one process), then
COMMAND, the carrier under test, told where and who it is by environment variables and by
placeholders in ARGS (docs/protocol.md, "Conformance kit"):

    MARSUPIAL_ENDPOINT  {endpoint}   the endpoint to connect to (zenoh client mode)
    MARSUPIAL_CARRIER   {carrier}    the carrier id it flies as
    MARSUPIAL_SCENARIO  {scenario}   the scenario file (absolute path)
    MARSUPIAL_MISSION   {mission}    the mission id (key prefix marsupial/<mission>/)
    MARSUPIAL_SEED      {seed}       the root seed (the fingerprint's)
    MARSUPIAL_WORKDIR   {workdir}    a directory of its own for files it writes (logs)

During the mission it makes deliberate faults (``--faults``, all by default): ``late`` (the
coordinator is frozen, SIGSTOP, for ``--late`` seconds once the carrier has sent its Observation of
stage 1: that Decision comes late), ``duplicate`` (the Decision of stage 0 is published again once
the carrier has answered it), ``restart`` (the coordinator is killed, SIGKILL, once the carrier
has answered stage 1, and restarted on its mission.db: epoch 2), ``deposed`` (after the restart,
a Decision of epoch 1 for the stage the carrier waits at, selecting it, while the coordinator is
frozen; published only when no real Decision of that stage arrives within ``SETTLE_S`` of the
freeze, else tried at a later stage, so the fake one always comes first). Then it prints one
line per rule: how many times the carrier was exercised on it, pass or fail, and the first
message that broke it. Exit status 0 only when every exercised rule passes (1 otherwise, 2 for a
usage error).

The rules are :data:`RULES`; each names the section of docs/protocol.md it comes from.
"""
from __future__ import annotations

import argparse
import json
import os
import shlex
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import msgpack

from . import keys
from . import messages as wm

#: Every rule the kit checks: (id, section of docs/protocol.md, what it says).
RULES = (
    ("decode", "Conventions", "every message it sends decodes, with the fields of the revision it announced"),
    ("hello-first", "Hello", "a Hello comes before its first Observation, Confirm, Own or Bye"),
    ("fingerprint", "Fingerprint", "its Hello carries the coordinator's fingerprint (no Refusal)"),
    ("observation-stage", "Stage handshake", "an Observation is of the stage being collected (not a later or a decided one)"),
    ("observation-time", "Conventions", "an Observation's t is t_j of its stage (±0.001 s), stage < N"),
    ("observation-world", "Where observations come from", "x is the world's: features in sight at t_j, nil where not scheduled"),
    ("passengers", "Messages", "passengers_left starts at the scenario's count and drops by one per deployment"),
    ("confirm", "Confirm", "every Decision of a stage it joined for is answered (Confirm, or Own of that stage)"),
    ("confirm-outcome", "Stage handshake", "the first answer follows the Decision: deployed / idle / refused / late"),
    ("duplicate", "Stage handshake", "a repeated Decision is answered already, with the first outcome, nothing twice"),
    ("late", "Stage handshake", "a Decision that comes late is still answered, once"),
    ("restart", "Joining late, restarting, resynchronising", "when the coordinator's token reappears it says Hello again"),
    ("epochs", "Epochs", "a Decision of a lower epoch than it heard is not answered (deposed)"),
    ("bye", "Bye", "after End: Bye with reason end and its deployments, then the process exits 0"),
    ("coordinator-rejections", "Rejections", "the coordinator rejected none of its messages (State, CarrierState.rejected)"),
)
FAULTS = ("late", "duplicate", "restart", "deposed")
CARRIER_TOPICS = ("hello", "obs", "confirm", "own", "bye", "pose", "progress")
SETTLE_S = 0.3  # loopback delivers a Decision already published well within this (deposed fault)


@dataclass
class Result:
    """One rule's outcome: how often the carrier was exercised on it and the first failure."""

    rule: str
    exercised: int = 0
    failure: str | None = None

    def check(self, ok: bool, message: str = "") -> None:
        self.exercised += 1
        if not ok and self.failure is None:
            self.failure = message[:300]

    @property
    def status(self) -> str:
        return "-" if self.exercised == 0 else ("pass" if self.failure is None else "FAIL")


@dataclass
class Seen:
    """A message the kit saw: when (monotonic s), on which topic, its payload, decoded or not."""

    at: float
    topic: str
    payload: bytes
    message: object = None
    error: str | None = None
    fake: bool = False  # published by the kit (a fault), not by the coordinator

    def show(self) -> str:
        try:
            return json.dumps(msgpack.unpackb(self.payload), default=str)[:240]
        except Exception:
            return repr(self.payload[:80])


@dataclass
class Flight:
    """Everything the kit saw of one mission, in order."""

    carrier: list = field(default_factory=list)  # Seen of the carrier under test
    decisions: list = field(default_factory=list)  # Seen of Decisions (the coordinator's and fakes)
    refusals: list = field(default_factory=list)
    ends: list = field(default_factory=list)
    coordinator_back: list = field(default_factory=list)  # times its token reappeared after a restart
    faults: dict = field(default_factory=dict)  # fault -> (stage, time or window)
    rejected: Counter = field(default_factory=Counter)  # coordinator's counts for the carrier
    exit_code: int | None = None
    output: str = ""


class Kit:
    """One conformance run (see the module docstring)."""

    def __init__(self, scenario_path: str, carrier: str, command: list[str], seed: int | None = None,
                 faults=FAULTS, late_s: float = 3.0, timeout_s: float = 120.0, workdir: str | None = None,
                 log=None):
        import world

        self.scenario_path = str(Path(scenario_path).resolve())
        self.scenario = world.load_scenario(self.scenario_path)
        if seed is not None:
            self.scenario = self.scenario.with_seed(int(seed))
        self.seed = int(self.scenario.seed)
        if carrier not in self.scenario.carrier_ids:
            raise ValueError(f"--carrier: {carrier!r} is not a carrier of {scenario_path} "
                             f"({', '.join(self.scenario.carrier_ids)})")
        self.cid = carrier
        self.r = self.scenario.carrier_index(carrier)
        self.command = list(command)
        self.faults = tuple(faults)
        self.late_s = float(late_s)
        self.timeout_s = float(timeout_s)
        self.mission = keys.mission_id_from_name(self.scenario.name)
        self.n = self.scenario.stages
        self.times = [float(t) for t in self.scenario.stage_times()]
        self.valid = self.scenario.valid()[self.r]
        self.x = world.observe_all(self.scenario)[self.r]
        self.passengers = int(self.scenario.carriers[self.r].passengers)
        self.fingerprint = wm.scenario_fingerprint(self.scenario)
        self.workdir = Path(workdir or tempfile.mkdtemp(prefix="conformance-"))
        self.log = log or (lambda line: print(line, file=sys.stderr, flush=True))
        self.endpoint = ""
        self.flight = Flight()

    # ------------------------------------------------------------------ processes
    def _run_fleet(self, *args) -> list[str]:
        root = Path(__file__).resolve().parents[1]
        return [sys.executable, str(root / "run_fleet.py"), self.scenario_path, "--seed", str(self.seed),
                "--mission", self.mission, "--connect", self.endpoint, *args]

    def _coordinator(self) -> subprocess.Popen:
        return subprocess.Popen(self._run_fleet(
            "--role", "coordinator", "--out", str(self.workdir / "run"), "--no-map", "--no-record",
            "--join-timeout", "60", "--stage-timeout", "20", "--quiet"),
            stdout=subprocess.DEVNULL, stderr=open(self.workdir / "coordinator.log", "ab"))

    def _env(self) -> dict:
        return {"MARSUPIAL_ENDPOINT": self.endpoint, "MARSUPIAL_CARRIER": self.cid,
                "MARSUPIAL_SCENARIO": self.scenario_path, "MARSUPIAL_MISSION": self.mission,
                "MARSUPIAL_SEED": str(self.seed), "MARSUPIAL_WORKDIR": str(self.workdir / "carrier")}

    def _command(self) -> list[str]:
        values = {"endpoint": self.endpoint, "carrier": self.cid, "scenario": self.scenario_path,
                  "mission": self.mission, "seed": str(self.seed), "workdir": str(self.workdir / "carrier")}
        out = []
        for arg in self.command:
            for name, value in values.items():
                arg = arg.replace("{" + name + "}", value)
            out.append(arg)
        return out

    # ------------------------------------------------------------------ the flight
    def run(self) -> list[Result]:
        from .transport import Node
        from .zconfig import free_port, make_config

        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        (self.workdir / "carrier").mkdir(parents=True, exist_ok=True)
        node = Node(make_config("router", [self.endpoint]))
        procs: list[subprocess.Popen] = []
        try:
            prefix = keys.prefix(self.mission)
            node.subscribe(f"{prefix}/**")
            node.watch_liveliness(keys.coordinator_alive(self.mission))
            coordinator = self._coordinator()
            procs.append(coordinator)
            others = [c for c in self.scenario.carrier_ids if c != self.cid]
            if others:
                procs.append(subprocess.Popen(self._run_fleet(
                    "--role", "carrier", "--carrier", ",".join(others), "--no-autonomy", "--quiet",
                    "--out", str(self.workdir / "run")), stdout=subprocess.DEVNULL,
                    stderr=open(self.workdir / "carriers.log", "ab")))
            self.log(f"conformance: mission {self.mission} on {self.endpoint}; carrier {self.cid}: "
                     f"{shlex.join(self._command())}")
            under_test = subprocess.Popen(self._command(), env={**os.environ, **self._env()},
                                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
            procs.append(under_test)
            self._fly(node, coordinator, under_test, procs)
        finally:
            for proc in procs:
                if proc.poll() is None:
                    try:
                        os.kill(proc.pid, signal.SIGCONT)
                    except OSError:
                        pass
                    proc.terminate()
                    try:
                        proc.wait(10)
                    except subprocess.TimeoutExpired:
                        proc.kill()
            node.close(3.0)
        return self.evaluate()

    def _fly(self, node, coordinator, under_test, procs) -> None:
        f = self.flight
        deadline = time.monotonic() + self.timeout_s
        frozen_until = None  # SIGCONT the coordinator then
        restarted = False
        gone = False
        ended_at = exited_at = None
        last_state_query = 0.0
        rejected_now: Counter = Counter()  # the current coordinator process's counts
        while time.monotonic() < deadline:
            now = time.monotonic()
            if frozen_until is not None and now >= frozen_until:
                os.kill(coordinator.pid, signal.SIGCONT)
                frozen_until = None
            if under_test.poll() is not None:  # it exited: collect what it sent last, then stop
                exited_at = exited_at or now
                if now - exited_at > 1.0:
                    break
            if ended_at is not None and now - ended_at > 15.0:
                break  # End came and the carrier under test did not exit
            if now - last_state_query > 1.0 and frozen_until is None and not gone:
                last_state_query = now
                counts = self._rejected(node)
                if counts is not None:
                    rejected_now = counts
            item = node.next(0.05)
            while item is not None:
                if item.kind in ("alive", "gone"):
                    if item.kind == "gone":
                        gone = True
                    elif gone:
                        gone = False
                        f.coordinator_back.append(item.received)
                    item = node.next(0.0)
                    continue
                seen = self._record(item)
                if seen is not None and seen.topic == "end" and ended_at is None:
                    ended_at = time.monotonic()
                    rejected_now = self._rejected(node) or rejected_now
                # ---- faults, each once, triggered by what the carrier just did
                if seen is not None and seen in f.carrier and isinstance(seen.message, (wm.Observation, wm.Confirm)):
                    msg = seen.message
                    if ("late" in self.faults and "late" not in f.faults and isinstance(msg, wm.Observation)
                            and msg.stage == 1 and self.n > 1 and not self._decided(1)):
                        os.kill(coordinator.pid, signal.SIGSTOP)
                        frozen_until = time.monotonic() + self.late_s
                        f.faults["late"] = (1, time.monotonic())
                    elif ("duplicate" in self.faults and "duplicate" not in f.faults and isinstance(msg, wm.Confirm)
                          and msg.stage == 0 and self._decided(0)):
                        original = next(d for d in f.decisions if d.message.stage == 0 and not d.fake)
                        node.put_raw(keys.decision_key(self.mission), original.payload)
                        f.faults["duplicate"] = (0, time.monotonic())
                    elif ("restart" in self.faults and "restart" not in f.faults and isinstance(msg, wm.Confirm)
                          and msg.stage == 1 and self.n > 2 and frozen_until is None and msg.status != "already"):
                        coordinator.kill()
                        coordinator.wait(10)
                        rejected_now, f.rejected = Counter(), f.rejected + rejected_now
                        coordinator = self._coordinator()
                        procs.append(coordinator)
                        restarted = True
                        f.faults["restart"] = (1, time.monotonic())
                    elif ("deposed" in self.faults and restarted and "deposed" not in f.faults and f.coordinator_back
                          and isinstance(msg, wm.Observation) and seen.at > f.coordinator_back[0]
                          and frozen_until is None and self._heard_epoch(2)):
                        stage = msg.stage
                        if not self._decided(stage):
                            os.kill(coordinator.pid, signal.SIGSTOP)
                            self._settle(node, SETTLE_S)
                            if self._decided(stage):  # sent before the stop: try again at a later stage
                                os.kill(coordinator.pid, signal.SIGCONT)
                            else:
                                fake = wm.Decision(self.mission, stage, self.times[stage], (self.cid,), 0.0, epoch=1)
                                payload = wm.encode(fake, 1)
                                f.decisions.append(Seen(time.monotonic(), "decision", payload, fake, fake=True))
                                node.put_raw(keys.decision_key(self.mission), payload)
                                frozen_until = time.monotonic() + 1.5
                                f.faults["deposed"] = (stage, (time.monotonic(), frozen_until))
                item = node.next(0.0)
        f.rejected += rejected_now
        if frozen_until is not None:
            os.kill(coordinator.pid, signal.SIGCONT)
        try:
            out, _ = under_test.communicate(timeout=max(1.0, deadline - time.monotonic()))
            f.output = (out or b"").decode(errors="replace")[-4000:]
        except subprocess.TimeoutExpired:
            under_test.kill()
            out, _ = under_test.communicate()
            f.output = (out or b"").decode(errors="replace")[-4000:]
        f.exit_code = under_test.returncode

    def _settle(self, node, seconds: float) -> None:
        """Record what arrives for ``seconds`` while the coordinator is stopped: a Decision it
        published just before the stop arrives here, not after the kit's fake one."""
        until = time.monotonic() + seconds
        while (left := until - time.monotonic()) > 0:
            item = node.next(left)
            if item is not None and item.kind not in ("alive", "gone"):
                self._record(item)

    def _decided(self, stage: int) -> bool:
        return any(d.message.stage == stage and not d.fake for d in self.flight.decisions)

    def _heard_epoch(self, epoch: int) -> bool:
        """The carrier shows it heard ``epoch``: a Hello of that epoch, or an answer to a Decision of
        that epoch (a Confirm of its stage after it went out)."""
        f = self.flight
        if any(isinstance(s.message, wm.Hello) and s.message.epoch >= epoch for s in f.carrier):
            return True
        heard = [(d.at, d.message.stage) for d in f.decisions if not d.fake and d.message.epoch >= epoch]
        return any(isinstance(s.message, wm.Confirm) and s.message.stage == stage and s.at >= at
                   for at, stage in heard for s in f.carrier)

    def _rejected(self, node) -> Counter | None:
        selector = keys.state_selector(self.mission, self.cid, wm.REVISION)
        for payload in node.query(selector, timeout_s=0.5):
            try:
                state = wm.decode(payload, wm.State)
            except wm.ProtocolError:
                continue
            mine = state.carrier(self.cid)
            if mine is not None:
                return Counter(dict(mine.rejected))
        return None

    def _record(self, item) -> Seen | None:
        parsed = keys.parse_carrier_key(self.mission, item.key)
        f = self.flight
        if parsed is not None:
            cid, topic = parsed
            if cid != self.cid or topic not in CARRIER_TOPICS:
                return None
            seen = Seen(item.received, topic, item.payload)
            try:
                seen.message = wm.decode(item.payload)
            except wm.ProtocolError as exc:
                seen.error = f"{exc.reason}: {exc.detail}"
            f.carrier.append(seen)
            return seen
        if item.key == keys.decision_key(self.mission):
            if any(d.fake and d.payload == item.payload for d in f.decisions):
                return None  # our own fault, already on record
            seen = Seen(item.received, "decision", item.payload)
            try:
                seen.message = wm.decode(item.payload, wm.Decision)
            except wm.ProtocolError:
                return None
            duplicate = "duplicate" in f.faults and any(d.payload == item.payload for d in f.decisions)
            seen.fake = duplicate and f.faults["duplicate"][1] <= item.received
            f.decisions.append(seen)
            return seen
        if item.key == keys.refusal_key(self.mission, self.cid):
            seen = Seen(item.received, "refusal", item.payload)
            f.refusals.append(seen)
            return seen
        if item.key == keys.end_key(self.mission):
            seen = Seen(item.received, "end", item.payload)
            f.ends.append(seen)
            return seen
        return None

    # ------------------------------------------------------------------ the rules
    def evaluate(self) -> list[Result]:
        f = self.flight
        results = {rule: Result(rule) for rule, _, _ in RULES}
        msgs = [s for s in f.carrier if s.message is not None]
        revision = next((s.message.revision for s in msgs if isinstance(s.message, wm.Hello)), 1)
        for s in f.carrier:
            ok = s.error is None
            detail = f"{s.error}: {s.show()}" if s.error else ""
            if ok:
                try:
                    wm.decode(s.payload, revision=revision)
                except wm.ProtocolError as exc:
                    ok, detail = False, f"{exc.reason} in revision {revision}: {exc.detail}: {s.show()}"
            results["decode"].check(ok, detail)
        hello_at = next((s.at for s in msgs if isinstance(s.message, wm.Hello)), None)
        for s in msgs:
            if isinstance(s.message, (wm.Observation, wm.Confirm, wm.Own, wm.Bye)):
                results["hello-first"].check(hello_at is not None and s.at >= hello_at,
                                             f"before any Hello: {s.show()}")
                break
        for s in msgs:
            if isinstance(s.message, wm.Hello):
                results["fingerprint"].check(s.message.fingerprint == self.fingerprint,
                                             f"fingerprint {s.message.fingerprint}, the world's {self.fingerprint}: {s.show()}")
        for s in f.refusals:
            results["fingerprint"].check(False, f"refused: {s.show()}")
        real = [d for d in f.decisions if not d.fake]
        self._observations(results, msgs, real)
        self._answers(results, msgs, real)
        return [results[rule] for rule, _, _ in RULES]

    def _observations(self, results, msgs, real) -> None:
        deployed_before = 0
        answers = self._first_answers(msgs)
        for s in msgs:
            m = s.message
            if not isinstance(m, wm.Observation):
                continue
            decided = [d.message.stage for d in real if d.at <= s.at]
            collecting = max(decided, default=-1) + 1
            # stages it decided itself before this Observation: it may go on past them
            own_before = {x.message.stage for x in msgs if isinstance(x.message, wm.Own) and x.at <= s.at}
            results["observation-stage"].check(
                m.stage == collecting or (m.stage < collecting and m.x is None and not self.valid[min(m.stage, self.n - 1)])
                or (m.stage < collecting and self._resent(s, m.stage))
                or (m.stage > collecting and set(range(collecting, m.stage)) <= own_before),
                f"stage {m.stage} while stage {collecting} was collected: {s.show()}")
            in_range = m.stage < self.n and abs(m.t - self.times[m.stage]) <= 1e-3
            results["observation-time"].check(in_range, f"t {m.t} for stage {m.stage}: {s.show()}")
            if m.stage < self.n:
                world_x = None if not self.valid[m.stage] else int(self.x[m.stage])
                results["observation-world"].check(m.x == world_x, f"x {m.x}, the world's {world_x}: {s.show()}")
                deployed_before = sum(1 for j, a in answers.items() if j < m.stage and a.deployed)
                results["passengers"].check(m.passengers_left == self.passengers - deployed_before,
                                            f"passengers_left {m.passengers_left}, expected "
                                            f"{self.passengers - deployed_before}: {s.show()}")

    def _resent(self, seen: Seen, stage: int) -> bool:
        """An Observation of a stage decided in the meantime, re-sent at a resynchronisation."""
        return bool(self.flight.coordinator_back) and any(
            abs(seen.at - back) < 10.0 for back in self.flight.coordinator_back)

    @staticmethod
    def _first_answers(msgs) -> dict:
        """stage -> the carrier's first Confirm or Own of it."""
        out = {}
        for s in msgs:
            m = s.message
            if isinstance(m, (wm.Confirm, wm.Own)) and m.stage not in out:
                out[m.stage] = m
        return out

    def _answers(self, results, msgs, real) -> None:
        f = self.flight
        answers = self._first_answers(msgs)
        left = self.passengers
        for j in range(self.n):
            decision = next((d for d in real if d.message.stage == j), None)
            if decision is None:
                continue
            first = answers.get(j)
            results["confirm"].check(first is not None, f"no Confirm or Own of stage {j}; its Decision: {decision.show()}")
            if first is None or isinstance(first, wm.Own):
                if isinstance(first, wm.Own):
                    left -= int(first.deployed)
                continue
            d = decision.message
            selected = self.cid in d.deploy
            expected = {"deployed": selected and self.valid[j] and left > 0, "idle": not selected,
                        "refused": selected and (not self.valid[j] or left == 0), "late": selected}
            results["confirm-outcome"].check(expected.get(first.status, False),
                                             f"status {first.status!r} for a Decision "
                                             f"{'selecting' if selected else 'not selecting'} it at stage {j} "
                                             f"({left} passenger(s) left): {decision.show()}")
            left -= int(first.deployed)
            results["passengers"].check(first.passengers_left == left,
                                        f"passengers_left {first.passengers_left} after stage {j}, expected {left}")
        confirms = [s for s in msgs if isinstance(s.message, wm.Confirm)]
        if "duplicate" in f.faults:
            stage, at = f.faults["duplicate"]
            again = [s.message for s in confirms if s.message.stage == stage and s.at > at]
            first = answers.get(stage)
            ok = bool(again) and all(c.status == "already" and first is not None and c.deployed == first.deployed
                                     for c in again)
            results["duplicate"].check(ok, f"answers to the repeated Decision of stage {stage}: "
                                           f"{[(c.status, c.deployed) for c in again] or 'none'}")
        if "late" in f.faults:
            stage, _ = f.faults["late"]
            n_first = sum(1 for s in confirms if s.message.stage == stage and s.message.status != "already")
            results["late"].check(n_first == 1, f"{n_first} first answer(s) to the late Decision of stage {stage}")
        if "restart" in f.faults:
            back = f.coordinator_back[0] if f.coordinator_back else None
            hello = back is not None and any(isinstance(s.message, wm.Hello) and s.at > back for s in msgs)
            results["restart"].check(hello, "no Hello after the coordinator's token reappeared"
                                     if back is not None else "the coordinator did not come back")
        if "deposed" in f.faults:
            stage, (start, _) = f.faults["deposed"]
            real_at = next((d.at for d in real if d.message.stage == stage), float("inf"))
            wrong = [s for s in confirms if s.message.stage == stage and start <= s.at < real_at]
            results["epochs"].check(not wrong, f"answered a Decision of epoch 1 after hearing epoch 2: "
                                               f"{wrong[0].show() if wrong else ''}")
        if f.ends:
            byes = [s for s in msgs if isinstance(s.message, wm.Bye)]
            deployments = tuple(sorted(j for j, a in answers.items() if a.deployed))
            bye = byes[-1].message if byes else None
            results["bye"].check(bye is not None and bye.reason == "end" and tuple(bye.deployments) == deployments
                                 and f.exit_code == 0,
                                 f"Bye {byes[-1].show() if byes else 'missing'} (deployments {list(deployments)}), "
                                 f"exit code {f.exit_code}")
        # Stage rejections are judged above (observation-stage): a carrier that decided a stage
        # itself legitimately sends a later stage's Observation the coordinator rejects.
        other = {k: v for k, v in f.rejected.items() if k not in ("future-stage", "stale-stage")}
        results["coordinator-rejections"].check(not other, f"the coordinator rejected: {dict(f.rejected)}")


def table(results: list[Result]) -> str:
    sections = {rule: (section, text) for rule, section, text in RULES}
    lines = [f"{'rule':<24} {'n':>4}  result  detail", "-" * 78]
    for r in results:
        section, text = sections[r.rule]
        lines.append(f"{r.rule:<24} {r.exercised:>4}  {r.status:<6}  {r.failure or text + ' (' + section + ')'}")
    return "\n".join(lines)


def passed(results: list[Result]) -> bool:
    return all(r.failure is None for r in results) and any(r.exercised for r in results)


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if "--" not in argv:
        print("usage: python -m wire.conformance SCENARIO --carrier ID [options] -- COMMAND [ARGS...]", file=sys.stderr)
        return 2
    split = argv.index("--")
    own, command = argv[:split], argv[split + 1:]
    parser = argparse.ArgumentParser(prog="python -m wire.conformance", description=__doc__.splitlines()[0])
    parser.add_argument("scenario", help="scenario YAML file")
    parser.add_argument("--carrier", required=True, help="the id the carrier under test flies as")
    parser.add_argument("--seed", type=int, help="root seed (overrides the scenario's)")
    parser.add_argument("--faults", default=",".join(FAULTS),
                        help=f"comma-separated faults to make (default all: {','.join(FAULTS)}; 'none' for none)")
    parser.add_argument("--late", type=float, default=3.0, help="seconds the late Decision is late (default 3)")
    parser.add_argument("--timeout", type=float, default=180.0, help="longest mission, seconds (default 180)")
    parser.add_argument("--workdir", help="where the coordinator's results and logs go (default: a temporary dir)")
    args = parser.parse_args(own)
    if not command:
        parser.error("no COMMAND after --")
    faults = () if args.faults == "none" else tuple(x for x in args.faults.split(",") if x)
    bad = [x for x in faults if x not in FAULTS]
    if bad:
        parser.error(f"--faults: unknown fault {bad[0]!r} (one of {', '.join(FAULTS)})")
    if not Path(args.scenario).is_file():
        parser.error(f"scenario: no such file: {args.scenario}")
    try:
        kit = Kit(args.scenario, args.carrier, command, args.seed, faults, args.late, args.timeout, args.workdir)
    except ValueError as exc:
        parser.error(str(exc))
    results = kit.run()
    print(table(results), flush=True)
    ok = passed(results)
    print(f"conformance: {'PASS' if ok else 'FAIL'} (carrier {args.carrier}, exit code {kit.flight.exit_code}; "
          f"logs in {kit.workdir})", flush=True)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
