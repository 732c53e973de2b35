"""Authority comes from coordinators only: a carrier's credential cannot change who decides.

Real processes over mutual TLS with per-carrier access control (tools/gen_certs.py), and an
attacker holding carrier c1's real credential: a Zenoh session opened with c1's own config, which
the access lists allow to publish on c1's keys. What it publishes is a well-formed Hello on c1's
own key, the one message kind a carrier may use to tell a coordinator an epoch
(docs/security.md, "Checks by role"; docs/protocol.md [P-7.3]):

* **deposition**: epoch 2 and ``next_stage`` one past the stage being decided, after a stage was
  decided (before revision 6 the coordinator took it as a newer coordinator and stopped, exit 3);
* **overflow**: epoch 2³¹ − 1 before stage 0 (before revision 6 the coordinator took 2³¹, which
  no message can carry).

The mission must earn what it earns undisturbed (13.583 on six_carriers), every process exit 0,
and the coordinator's epoch stay 1 (in summary.json and in mission.db).
"""
from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from pathlib import Path

import msgpack
import pytest
import zenoh

from tools import gen_certs
from wire import keys
from wire.messages import Confirm, Hello, Observation, Own, State, decode, encode
from wire.zconfig import free_port

ROOT = Path(__file__).resolve().parents[1]
SIX = ROOT / "scenarios" / "six_carriers.yaml"
MISSION = "six_carriers"
UNDISTURBED_REWARD = 13.583  # six_carriers' reward with every process on its own (docs/results.md)
FLEET_TIMEOUT_S = 400.0
EPOCH_MAX = 2**31 - 1  # the highest epoch the wire carries (docs/protocol.md [P-7.1])


def launch(tmp: Path, scenario: Path, port: int, certs, join_timeout_s: float = 60.0) -> dict:
    """The coordinator and one process per carrier of ``scenario``, each with its own generated
    config over tls/127.0.0.1:PORT (docs/security.md, "Quick start")."""
    out = tmp / "run"
    out.mkdir()
    base = [sys.executable, str(ROOT / "run_fleet.py"), str(scenario)]
    logs, procs = {}, {}

    def start(role: str, args: list[str]) -> None:
        logs[role] = out / f"{role}.log"
        with open(logs[role], "wb") as log:
            procs[role] = subprocess.Popen(base + args, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT)

    coord = gen_certs.write_json5(out / "coordinator.json5", gen_certs.coordinator_config(certs))
    start("coordinator", ["--role", "coordinator", "--zenoh-config", str(coord), "--listen", f"tls/127.0.0.1:{port}",
                          "--out", str(out / "results"), "--join-timeout", str(join_timeout_s), "--no-map",
                          "--no-record"])
    for cid in certs.carriers:
        conf = gen_certs.write_json5(out / f"carrier-{cid}.json5", gen_certs.carrier_config(certs, cid))
        start(cid, ["--role", "carrier", "--carrier", cid, "--zenoh-config", str(conf),
                    "--connect", f"tls/127.0.0.1:{port}", "--coordinator-timeout", "60", "--quiet"])
    return {"procs": procs, "logs": logs, "out": out}


def wait_fleet(fleet: dict) -> dict:
    deadline = time.monotonic() + FLEET_TIMEOUT_S
    codes = {}
    try:
        for role, proc in fleet["procs"].items():
            codes[role] = proc.wait(timeout=max(1.0, deadline - time.monotonic()))
    finally:
        for proc in fleet["procs"].values():
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    path = fleet["out"] / "results" / "summary.json"
    return {"codes": codes, "summary": json.loads(path.read_text()) if path.exists() else None, "out": fleet["out"],
            "logs": {role: p.read_text(errors="replace") for role, p in fleet["logs"].items()}}


class Attacker:
    """A Zenoh session holding carrier ``cid``'s credential (its own generated config), connected
    to the coordinator as the carrier would be: it reads the Decisions and State, and publishes
    only what c1's access list allows."""

    def __init__(self, certs, cid: str, port: int):
        conf = gen_certs.carrier_config(certs, cid)
        conf["mode"] = "client"
        conf["connect"] = {"endpoints": [f"tls/127.0.0.1:{port}"]}
        self.cid = cid
        self.decided: list[int] = []
        self._cond = threading.Condition()
        deadline = time.monotonic() + 60
        while True:
            try:
                self.session = zenoh.open(zenoh.Config.from_json5(json.dumps(conf)))
                break
            except zenoh.ZError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.3)
        self.session.declare_subscriber(keys.decision_key(MISSION), self._decision)

    def _decision(self, sample) -> None:
        body = msgpack.unpackb(sample.payload.to_bytes())
        with self._cond:
            self.decided.append(int(body["stage"]))
            self._cond.notify_all()

    def wait_decided(self, stage: int, timeout_s: float = 300.0) -> None:
        with self._cond:
            assert self._cond.wait_for(lambda: stage in self.decided, timeout_s), f"stage {stage} never decided"

    def state(self, timeout_s: float = 120.0) -> State:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            for reply in self.session.get(keys.state_key(MISSION) + f"?carrier={self.cid}", timeout=2.0):
                if reply.ok is not None:
                    return decode(reply.ok.payload.to_bytes(), State)
            time.sleep(0.3)
        raise AssertionError("no State")

    def hello(self, epoch: int, next_stage: int, fingerprint: str) -> None:
        msg = Hello(MISSION, self.cid, 4242, "attacker", 2, next_stage, fingerprint, epoch=epoch, revision=5)
        self.session.put(keys.carrier_key(MISSION, self.cid, "hello"), encode(msg))

    def put(self, kind: str, msg) -> None:
        """``msg`` on c1's own ``kind`` key (what its access list allows)."""
        self.session.put(keys.carrier_key(MISSION, self.cid, kind), encode(msg))

    def close(self) -> None:
        self.session.close()


@pytest.fixture(scope="module")
def certs_six(tmp_path_factory):
    return gen_certs.generate_fleet_certs(tmp_path_factory.mktemp("certs-six"), gen_certs.scenario_carrier_ids(SIX))


def _attacked(tmp: Path, certs, attack) -> dict:
    port = free_port()
    fleet = launch(tmp, SIX, port, certs)
    attacker = None
    try:
        attacker = Attacker(certs, "c1", port)
        attack(attacker)
    finally:
        run = wait_fleet(fleet)
        if attacker is not None:
            attacker.close()
    return run


def _kept(run: dict) -> None:
    assert run["codes"] == {role: 0 for role in run["codes"]}, (run["codes"], run["logs"]["coordinator"][-3000:])
    summary = run["summary"]
    assert summary["ended"] and summary["end_reason"] == "complete", summary
    assert summary["stages_decided"] == summary["stages"]
    assert round(summary["total_reward"], 3) == UNDISTURBED_REWARD, summary["total_reward"]
    assert summary["epoch"] == 1
    assert "deposed" not in run["logs"]["coordinator"]
    from storage.missiondb import highest_epoch
    assert highest_epoch(run["out"] / "results" / "mission.db") == 1


@pytest.mark.slow
def test_a_carriers_hello_of_a_newer_epoch_after_a_decision_does_not_depose_the_coordinator(tmp_path, certs_six):
    """[P-7.3], [P-13.1] the deposition attack: after stage 1's Decision, c1's credential says Hello with
    epoch 2 and next_stage 3 (one past the stage being decided)."""
    def attack(attacker: Attacker) -> None:
        fingerprint = attacker.state().fingerprint
        attacker.wait_decided(1)
        attacker.hello(2, 3, fingerprint)

    run = _attacked(tmp_path, certs_six, attack)
    _kept(run)
    assert "reports epoch 2" in run["logs"]["coordinator"]  # the claim is on record, not adopted
    assert run["summary"]["denials"] == [{"sender": "c1", "rule": "P-7.3", "what": "epoch claimed in a Hello",
                                          "value": 2}]


@pytest.mark.slow
def test_a_carriers_hello_of_the_highest_epoch_before_stage_0_does_not_overflow_the_coordinator(tmp_path, certs_six):
    """[P-7.3], [P-1.6] the overflow attack: before stage 0, c1's credential says Hello with epoch
    2³¹ − 1 (the highest the wire carries)."""
    def attack(attacker: Attacker) -> None:
        fingerprint = attacker.state().fingerprint
        attacker.hello(EPOCH_MAX, 0, fingerprint)

    run = _attacked(tmp_path, certs_six, attack)
    _kept(run)
    assert f"reports epoch {EPOCH_MAX}" in run["logs"]["coordinator"]
    assert [(d["sender"], d["value"]) for d in run["summary"]["denials"]] == [("c1", EPOCH_MAX)]


@pytest.mark.slow
def test_a_carriers_messages_out_of_range_change_nothing_and_are_counted(tmp_path, certs_six):
    """[P-13.2] after stage 1's Decision, c1's credential puts, on c1's own keys, messages the
    codec accepts and the mission's rules refuse: an Observation of a stage past the end, one of
    stage 2 at a time that is not t_2, an Own past the end, a Confirm of the highest stage the codec carries.
    Each is refused ``out-of-range``; the mission earns what it earns undisturbed; summary.json
    counts them against c1."""
    lies = []

    def attack(attacker: Attacker) -> None:
        n = attacker.state().stages
        attacker.wait_decided(1)
        lies.extend([
            ("obs", Observation(MISSION, "c1", n + 2, 0.0, 7, [0.0, 0.0], 3, [])),
            ("obs", Observation(MISSION, "c1", 2, 12345.0, 7, [0.0, 0.0], 3, [])),
            ("own", Own(MISSION, "c1", n + 5, 0.0, 9, True, [0.0, 0.0], 0)),
            ("confirm", Confirm(MISSION, "c1", 99_999, True, "deployed", [0.0, 0.0], 0)),
        ])
        for kind, msg in lies:
            attacker.put(kind, msg)

    run = _attacked(tmp_path, certs_six, attack)
    _kept(run)
    denied = [d for d in run["summary"]["denials"] if d["sender"] == "c1" and d["what"] == "out-of-range"]
    assert len(denied) == 1 and denied[0]["rule"] == "P-13.2" and denied[0]["count"] == len(lies), \
        run["summary"]["denials"]
    assert run["summary"]["rejected"]["coordinator"].get("out-of-range", 0) >= len(lies)
