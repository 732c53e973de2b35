"""Bad input from the network: a fuzzer floods a running tiny mission and changes nothing.

A real fleet (`run_fleet.py --role ...`: one coordinator and two carrier processes over
tcp/127.0.0.1, the carriers started once this test's fuzzer, one more Zenoh client of the
coordinator, is connected) runs the tiny scenario while the fuzzer sends more than
10,000 random and broken messages (tests/fuzz_messages.py) at the coordinator's subscriptions
(`carrier/*/{hello,obs,confirm,bye}`) and at the carriers' (`coordinator/decision`,
`coordinator/end`), plus replays of the real observations, confirmations and decisions it
overhears (duplicate and stale stages), and liveliness tokens of carriers that do not exist.
The carriers hear each other (their `obs`, `own` and `confirm`, to decide alone if they must), so
what is sent at one carrier's keys reaches the other carrier as well. A clean run of the same
scenario and seed runs alongside.

Asserted: every process exits normally; the fuzzed mission's decisions, observations,
deployments and reward equal the clean run's; summary.json counts the rejected messages per
reason, at least one per message sent; each reason is logged once per process.
"""

from __future__ import annotations

import json
import queue
import re
import subprocess
import sys
import threading
import time
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
import zenoh

from fuzz_messages import carrier_fuzz, coordinator_fuzz
from localports import distinct_free_ports
from wire import keys, messages
from wire.zconfig import make_config, open_session

ROOT = Path(__file__).resolve().parents[1]
TINY = ROOT / "scenarios" / "tiny.yaml"
MISSION = "tiny"
CARRIERS = ["a", "b"]
STAGES = 4
SEED = 20261122  # the fuzzer's own stream (the mission keeps the scenario's seed)
N_COORDINATOR = 6_000  # generated messages at the coordinator's keys
N_CARRIERS = 5_000  # generated messages at the carriers' keys (each reaches both carriers)
REPLAYS_PER_MESSAGE = 10  # altered copies of every real message overheard
REPLAY_DELAY_S = 0.3  # a replay is sent this long after the original was overheard
REALTIME = 1.0  # simulated seconds per wall second in the fuzzed mission (it lasts ~15 s)
RUN_TIMEOUT_S = 180.0
GHOST_TOKENS = ("zz9", "ghost", "c-404")  # liveliness tokens under unknown carrier ids


def start(args: list[str], log: Path) -> tuple[subprocess.Popen, Path]:
    """Start `run_fleet.py TINY ARGS` with its output in `log`."""
    with open(log, "wb") as handle:
        proc = subprocess.Popen([sys.executable, str(ROOT / "run_fleet.py"), str(TINY), *args],
                                cwd=ROOT, stdout=handle, stderr=subprocess.STDOUT)
    return proc, log


def finish(proc: subprocess.Popen, log: Path) -> tuple[int, str]:
    """Exit code and output of a process started by `start` (killed after RUN_TIMEOUT_S)."""
    try:
        code = proc.wait(timeout=RUN_TIMEOUT_S)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return code, log.read_text(errors="replace")


def summary_of(out: Path) -> dict | None:
    path = out / "summary.json"
    return json.loads(path.read_text()) if path.exists() else None


class Fuzzer:
    """A Zenoh client of the coordinator that overhears the mission and sends the fuzz."""

    def __init__(self, port: int):
        conf = make_config("client", [], [f"tcp/127.0.0.1:{port}"])
        self.session = open_session(conf, timeout_s=90.0)  # retried until the coordinator listens
        self.overheard: "queue.Queue[tuple[float, str, bytes]]" = queue.Queue()
        self.live: set[str] = set()
        self.decided: set[int] = set()  # stages whose genuine decision the fuzzer overheard
        self.sent_replays: set[bytes] = set()
        self.confirmed: set[tuple[str, int]] = set()  # (carrier, stage) confirmations overheard
        self._lock = threading.Lock()
        self._publishers: dict[str, zenoh.Publisher] = {}
        for topic in ("obs", "confirm"):
            self.session.declare_subscriber(keys.carrier_topic_pattern(MISSION, topic), self._on_sample)
        self.session.declare_subscriber(keys.decision_key(MISSION), self._on_sample)
        self.session.liveliness().declare_subscriber(
            keys.carrier_alive_pattern(MISSION), self._on_token, history=True)
        self.session.liveliness().declare_subscriber(
            keys.coordinator_alive(MISSION), self._on_token, history=True)

    def _on_sample(self, sample) -> None:  # zenoh callback: copy and enqueue only
        self.overheard.put((time.monotonic(), str(sample.key_expr), sample.payload.to_bytes()))

    def _on_token(self, sample) -> None:
        if sample.kind == zenoh.SampleKind.PUT:
            with self._lock:
                key = str(sample.key_expr)
                self.live.add("coordinator" if key == keys.coordinator_alive(MISSION) else key.split("/")[-2])

    def wait_live(self, names: set[str], timeout_s: float) -> bool:
        """Wait until the liveliness tokens of `names` ("coordinator", carrier ids) are seen."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with self._lock:
                if self.live >= names:
                    return True
            time.sleep(0.05)
        return False

    def put(self, key: str, payload: bytes) -> None:
        pub = self._publishers.get(key)
        if pub is None:
            # Blocking congestion control: nothing the fuzzer sends is dropped on the way.
            pub = self.session.declare_publisher(
                key, congestion_control=zenoh.CongestionControl.BLOCK, reliability=zenoh.Reliability.RELIABLE)
            self._publishers[key] = pub
        pub.put(payload)

    def _genuine(self, key: str, payload: bytes):
        """The decoded message if it is one the fleet itself sent (a valid message of this mission
        on its own key, not one of the fuzzer's own replays heard back), else None."""
        if payload in self.sent_replays:
            return None
        try:
            msg = messages.decode(payload)
        except messages.ProtocolError:
            return None
        if msg.mission != MISSION or getattr(msg, "stage", STAGES) >= STAGES:
            return None
        if isinstance(msg, messages.Decision):
            return msg if key == keys.decision_key(MISSION) else None
        parsed = keys.parse_carrier_key(MISSION, key)
        if parsed is None or parsed[0] not in CARRIERS or parsed[0] != getattr(msg, "carrier", None):
            return None
        return msg

    def drain(self, pending: list) -> None:
        """Move overheard genuine messages into `pending` (heard_at, key, message)."""
        while True:
            try:
                heard_at, key, payload = self.overheard.get_nowait()
            except queue.Empty:
                return
            msg = self._genuine(key, payload)
            if msg is not None:
                pending.append((heard_at, key, msg))
                if isinstance(msg, messages.Decision):
                    self.decided.add(msg.stage)
                elif isinstance(msg, messages.Confirm):
                    self.confirmed.add((msg.carrier, msg.stage))

    def replays(self, rng: np.random.Generator, pending: list, now: float) -> list[tuple[str, str, bytes]]:
        """Altered copies of overheard genuine messages at least REPLAY_DELAY_S old:
        (target, key, payload). The original reached its receiver before the fuzzer heard it, so
        each copy is a duplicate or a stale stage there."""
        self.drain(pending)
        out, keep = [], []
        for heard_at, key, msg in pending:
            if now - heard_at < REPLAY_DELAY_S:
                keep.append((heard_at, key, msg))
                continue
            for _ in range(REPLAYS_PER_MESSAGE):
                if isinstance(msg, messages.Observation):
                    copy = messages.Observation(msg.mission, msg.carrier, msg.stage, msg.t,
                                                int(rng.integers(0, 50)), msg.position, msg.passengers_left, ())
                    target = "coordinator"
                elif isinstance(msg, messages.Confirm):
                    deployed = bool(rng.integers(2))
                    copy = messages.Confirm(msg.mission, msg.carrier, msg.stage, deployed,
                                            "deployed" if deployed else "idle", msg.position, msg.passengers_left)
                    target = "coordinator"
                elif isinstance(msg, messages.Decision):
                    deploy = tuple(CARRIERS[: int(rng.integers(0, len(CARRIERS) + 1))])
                    copy = messages.Decision(msg.mission, msg.stage, msg.t, deploy, msg.planning_ms)
                    target = "carriers"
                else:
                    break
                payload = messages.encode(copy)
                self.sent_replays.add(payload)
                out.append((target, key, payload))
        pending[:] = keep
        return out

    def close(self) -> None:
        for pub in self._publishers.values():
            pub.undeclare()
        self.session.close()


def test_every_generated_message_fails_the_receivers_checks():
    """The generator's promise, checked without a network: no message it builds passes decoding
    plus the identity and stage checks a receiver applies before acting on a message."""
    rng = np.random.default_rng(SEED + 1)
    topic_types = {"hello": messages.Hello, "obs": messages.Observation,
                   "confirm": messages.Confirm, "bye": messages.Bye}
    for f in coordinator_fuzz(rng, MISSION, CARRIERS, STAGES, 3_000):
        cid, topic = keys.parse_carrier_key(MISSION, f.key)
        with pytest.raises(messages.ProtocolError):
            if cid not in CARRIERS:
                raise messages.ProtocolError("unknown-carrier")
            msg = messages.decode(f.payload, topic_types[topic])
            if msg.mission != MISSION or msg.carrier != cid:
                raise messages.ProtocolError("wrong-mission or key-mismatch")
            if topic in ("obs", "confirm") and msg.stage >= STAGES:
                raise messages.ProtocolError("out-of-range")
            print(f)  # accepted: shown in the failure report
    for f in carrier_fuzz(rng, MISSION, CARRIERS, STAGES, 3_000):
        with pytest.raises(messages.ProtocolError):
            decision = f.key == keys.decision_key(MISSION)
            msg = messages.decode(f.payload, messages.Decision if decision else messages.End)
            if msg.mission != MISSION:
                raise messages.ProtocolError("wrong-mission")
            if decision and msg.stage >= STAGES:
                raise messages.ProtocolError("out-of-range")
            print(f)


def _peer_key(key: str, cid: str) -> bool:
    """Whether carrier ``cid`` hears ``key``: another carrier's obs, own or confirm."""
    parsed = keys.parse_carrier_key(MISSION, key)
    return parsed is not None and parsed[0] in CARRIERS and parsed[0] != cid and parsed[1] in ("obs", "own", "confirm")


def rejections_logged(log: str) -> Counter:
    """(process, reason) -> how many 'rejected a message (reason)' lines it printed."""
    return Counter(re.findall(r"^(coordinator|carrier \w+): .*?rejected a message \(([\w-]+)\)", log, re.M))


@pytest.mark.slow
def test_fuzzed_mission_is_unchanged_and_every_bad_message_is_counted(tmp_path):
    rng = np.random.default_rng(SEED)
    to_coordinator = coordinator_fuzz(rng, MISSION, CARRIERS, STAGES, N_COORDINATOR)
    to_carriers = carrier_fuzz(rng, MISSION, CARRIERS, STAGES, N_CARRIERS)
    # Interleave the two streams in a seeded order.
    fuzz = to_coordinator + to_carriers
    order = rng.permutation(len(fuzz))

    clean_out, fuzzed_out = tmp_path / "clean", tmp_path / "fuzzed"
    fuzzed_port, clean_port = distinct_free_ports(2)
    endpoint = f"tcp/127.0.0.1:{fuzzed_port}"
    timing = ["--realtime", str(REALTIME)]
    # The fuzzed fleet is started role by role: the coordinator, then the fuzzer connects, then
    # the carriers, so the fuzzer overhears the mission from its first stage. The clean run is
    # the one-command fleet, alongside.
    procs = {"coordinator": start(["--role", "coordinator", "--listen", endpoint, "--out", str(fuzzed_out),
                                   "--no-map", "--join-timeout", "60", *timing], tmp_path / "coordinator.log")}
    clean = start(["--out", str(clean_out), "--no-map", "--listen", f"tcp/127.0.0.1:{clean_port}"],
                  tmp_path / "clean.log")
    fuzzer = None
    sent = Counter()
    try:
        fuzzer = Fuzzer(fuzzed_port)
        assert fuzzer.wait_live({"coordinator"}, 60.0), "the fuzzer never saw the coordinator"
        for cid in CARRIERS:
            procs[cid] = start(["--role", "carrier", "--carrier", cid, "--connect", endpoint, *timing],
                               tmp_path / f"carrier-{cid}.log")
        if not fuzzer.wait_live(set(CARRIERS), 90.0):
            raise AssertionError("the fuzzed fleet's carriers never became live:\n"
                                 + "\n".join(log.read_text(errors="replace")[-1500:] for _, log in procs.values()))
        pending: list = []
        started = time.monotonic()

        def replay_round(now: float) -> None:
            for target, key, payload in fuzzer.replays(rng, pending, now):
                fuzzer.put(key, payload)
                sent[f"{target}-replay"] += 1

        def until(condition, timeout_s: float = 60.0) -> None:
            deadline = time.monotonic() + timeout_s
            while not condition():
                assert time.monotonic() < deadline, "the fuzzed mission stopped making progress"
                time.sleep(0.05)
                replay_round(time.monotonic())

        # Three waves: before stage 0's decision, after it, after stage 1's confirmations, so
        # the fuzz meets the mission in several states and the replays cover decided stages.
        waves = np.array_split(order, 3)
        gates = [lambda: True,
                 lambda: max(fuzzer.decided, default=-1) >= 0,
                 lambda: max(fuzzer.decided, default=-1) >= 1 and any(j >= 1 for _, j in fuzzer.confirmed)]
        # Liveliness tokens of carriers the scenario does not have, alive during the fuzz.
        tokens = [fuzzer.session.liveliness().declare_token(keys.carrier_alive(MISSION, ghost))
                  for ghost in GHOST_TOKENS]
        for wave, gate in zip(waves, gates):
            until(gate)
            for n, i in enumerate(wave):
                f = fuzz[i]
                fuzzer.put(f.key, f.payload)
                sent[f.target] += 1
                if n % 250 == 0:
                    replay_round(time.monotonic())
        for token in tokens:
            token.undeclare()
        # Replays of what was overheard while fuzzing, then stop: the mission runs on undisturbed.
        time.sleep(REPLAY_DELAY_S)
        replay_round(time.monotonic() + REPLAY_DELAY_S)
        fuzz_s = time.monotonic() - started
        fuzzer.drain(pending)
        decided_while_fuzzing = set(fuzzer.decided)
    finally:
        results = {role: finish(*proc) for role, proc in procs.items()}
        clean_code, clean_log = finish(*clean)
        if fuzzer is not None:
            fuzzer.close()

    summary, clean_summary = summary_of(fuzzed_out), summary_of(clean_out)
    log = "\n".join(text for _, text in results.values())
    print(f"fuzz: sent {dict(sent)} in {fuzz_s:.1f} s; stages decided meanwhile {sorted(decided_while_fuzzing)}")
    assert clean_code == 0 and clean_summary is not None, clean_log[-2000:]
    # No process crashed: the coordinator and both carriers ended normally.
    assert {role: code for role, (code, _) in results.items()} == {"coordinator": 0, "a": 0, "b": 0}, log[-3000:]
    assert summary is not None and "Traceback" not in log, log[-3000:]
    assert summary["ended"] and summary["stages_decided"] == STAGES
    # The fuzz was over before the last stage was decided, so every message met a live mission.
    assert STAGES - 1 not in decided_while_fuzzing, "fuzzing outlasted the mission; lower REALTIME's speed"

    # The mission result is unchanged.
    assert summary["decisions"] == clean_summary["decisions"]
    assert summary["observations"] == clean_summary["observations"]
    assert summary["total_reward"] == pytest.approx(clean_summary["total_reward"])
    deployments = {c["id"]: [(d["stage"], d["x"]) for d in c["deployments"]] for c in summary["carriers"]}
    clean_deployments = {c["id"]: [(d["stage"], d["x"]) for d in c["deployments"]] for c in clean_summary["carriers"]}
    assert deployments == clean_deployments

    # Every bad message was counted in summary.json, by reason.
    rejected = summary["rejected"]
    print(f"fuzz: rejected (summary.json) {json.dumps(rejected)}")
    coordinator = Counter(rejected["coordinator"])
    clean_coordinator = sum(clean_summary["rejected"]["coordinator"].values())
    assert sent["coordinator"] == N_COORDINATOR and sent["carriers"] == N_CARRIERS
    assert sent["coordinator-replay"] > 0 and sent["carriers-replay"] > 0
    # At least one rejection per generated message; at most one more per replay (a replay may
    # also be absorbed as an idempotent answer) and what a clean run rejects (late joiners).
    # Each ghost token is rejected when it appears and when it vanishes (liveliness history may
    # report an appearance twice).
    assert sent["coordinator"] + 2 * len(GHOST_TOKENS) <= sum(coordinator.values()) <= (
        sent["coordinator"] + sent["coordinator-replay"] + sent["carriers-replay"] * len(CARRIERS)
        + 3 * len(GHOST_TOKENS) + clean_coordinator + 4)
    for reason in ("malformed", "not-a-map", "oversized", "version", "unknown-type", "missing-field",
                   "unknown-field", "wrong-type", "out-of-range", "unknown-carrier", "wrong-mission",
                   "key-mismatch", "duplicate", "stale-stage"):
        assert coordinator[reason] > 0, f"coordinator counted no {reason!r}: {dict(coordinator)}"
    for cid in CARRIERS:
        counted = Counter(rejected["carriers"][cid])
        # Plus what it overhears at the other carriers' keys: the fuzz and the replays sent there.
        overheard = sum(1 for f in to_coordinator if _peer_key(f.key, cid))
        assert sent["carriers"] <= sum(counted.values()) <= (
            sent["carriers"] + sent["carriers-replay"] + overheard + sent["coordinator-replay"]), (cid, dict(counted))
        for reason in ("malformed", "oversized", "version", "unknown-type", "missing-field", "wrong-type",
                       "out-of-range", "wrong-mission"):
            assert counted[reason] > 0, f"carrier {cid} counted no {reason!r}: {dict(counted)}"

    # Each reason is logged once per process, however many messages it covers.
    logged = rejections_logged(log)
    assert logged, "no rejection was logged"
    assert max(logged.values()) == 1, {k: v for k, v in logged.items() if v > 1}
    assert {r for (p, r) in logged if p == "coordinator"} == set(coordinator)
