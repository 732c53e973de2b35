"""Operator actions on the mission's Zenoh key (docs/protocol.md, section 12): a real fleet
mission answers each action on the sender's answer key, taken or refused with a reason
([P-12.2] the credential, [P-12.4] every action answered, a decided stage refused); and under the
fleet's access control only an operator's certificate can put an action, a carrier's cannot
([P-12.1]; real mutual-TLS sessions on loopback)."""
from __future__ import annotations

import json
import signal
import subprocess
import sys
import threading
import time

import pytest
import zenoh

from fleet_helpers import ROOT, TINY
from test_security import Inbox, deliver, open_session, wait_connected
from tools import gen_certs
from wire import keys
from wire.messages import OperatorAction, OperatorAnswer, decode, encode
from wire.zconfig import free_port

MISSION = "m"


def test_a_carriers_certificate_cannot_send_an_operator_action(tmp_path):
    """[P-12.1] The coordinator's access control takes an action only from the operator's
    certificate: a carrier's put on any operator key is dropped on ingress, the operator's arrives."""
    certs = gen_certs.generate_fleet_certs(tmp_path, ["c0"], operator_ids=["ops"])
    port = free_port()
    coord_conf = {"scouting": {"multicast": {"enabled": False}},
                  "transport": {"link": {"protocols": ["tls"],
                                         "tls": gen_certs.tls_section(certs.ca, certs.coordinator)}},
                  "access_control": gen_certs.coordinator_acl(["c0"], operator_ids=["ops"])}

    def client(identity):
        return {"scouting": {"multicast": {"enabled": False}},
                "transport": {"link": {"protocols": ["tls"], "tls": gen_certs.tls_section(certs.ca, identity)}},
                "access_control": gen_certs.carrier_acl()}

    action = encode(OperatorAction(MISSION, "ops", 1, 0, "force", "c0", "secret"))
    with open_session(coord_conf, port, "listen") as coord:
        inbox = Inbox()
        coord.declare_subscriber(f"marsupial/{MISSION}/**", inbox)
        with open_session(client(certs.carriers["c0"]), port, "connect") as carrier:
            assert wait_connected(carrier, 10)
            forged = [(keys.operator_action_key(MISSION, "ops"), action),
                      (keys.operator_action_key(MISSION, "c0"), action)]
            marker = (keys.carrier_key(MISSION, "c0", "progress"), b"marker")
            deliver(carrier, inbox, forged, marker)
            assert not any("/operator/" in key for key, _ in inbox.items), inbox.items
        with open_session(client(certs.operators["ops"]), port, "connect") as console:
            assert wait_connected(console, 10)
            key = keys.operator_action_key(MISSION, "ops")
            deadline = time.monotonic() + 10
            while not inbox.wait_for((key, action), timeout=0.2):
                console.put(key, action)
                assert time.monotonic() < deadline, "the operator's action never arrived"
            # The operator cannot put anything else: not a decision, not a carrier's message.
            forged = [(keys.decision_key(MISSION), b"forged"), (keys.carrier_key(MISSION, "c0", "obs"), b"forged")]
            marker = (key, encode(OperatorAction(MISSION, "ops", 2, 0, "approve")))
            deliver(console, inbox, forged, marker)
            assert (keys.decision_key(MISSION), b"forged") not in inbox.items
            assert (keys.carrier_key(MISSION, "c0", "obs"), b"forged") not in inbox.items


class Answers:
    """The answers on an operator's answer key, decoded (the callback only appends)."""

    def __init__(self):
        self.items: list[OperatorAnswer] = []
        self.cond = threading.Condition()

    def __call__(self, sample):
        with self.cond:
            self.items.append(decode(sample.payload.to_bytes(), OperatorAnswer))
            self.cond.notify_all()

    def of(self, seq: int, timeout_s: float = 60) -> OperatorAnswer:
        with self.cond:
            assert self.cond.wait_for(lambda: any(a.seq == seq for a in self.items), timeout_s), self.items
            return next(a for a in self.items if a.seq == seq)


@pytest.mark.slow
def test_actions_on_the_key_during_a_real_mission(tmp_path):
    """A console of its own (plain zenoh and msgpack through wire/) vetoes at stage 0 on the key:
    without the credential refused ``not-authorised``; with it taken and the fleet follows;
    the same veto once stage 0 is decided refused ``stale-stage`` [P-12.2], [P-12.4]."""
    router, out = free_port(), tmp_path / "run"
    proc = subprocess.Popen(
        [sys.executable, str(ROOT / "run_fleet.py"), str(TINY), "--operator", "--operator-timeout", "20",
         "--operator-port", "0", "--out", str(out), "--no-map", "--no-record", "--mission", MISSION,
         "--listen", f"tcp/127.0.0.1:{router}"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=tmp_path)
    lines: list[str] = []
    threading.Thread(target=lambda: [lines.append(line) for line in proc.stdout], daemon=True).start()
    try:
        deadline = time.monotonic() + 120
        while not any("operator console at" in line for line in lines):
            assert proc.poll() is None and time.monotonic() < deadline, "".join(lines)[-3000:]
            time.sleep(0.2)
        token = (out / "operator.token").read_text().strip()
        conf = zenoh.Config.from_json5(json.dumps({
            "mode": "client", "connect": {"endpoints": [f"tcp/127.0.0.1:{router}"]},
            "scouting": {"multicast": {"enabled": False}}}))
        with zenoh.open(conf) as session:
            answers = Answers()
            session.declare_subscriber(keys.operator_answer_key(MISSION, "ops"), answers)
            time.sleep(1.0)
            key = keys.operator_action_key(MISSION, "ops")
            session.put(key, encode(OperatorAction(MISSION, "ops", 1, 0, "veto", "a", "wrong")))
            refused = answers.of(1)
            assert (refused.accepted, refused.reason) == (False, "not-authorised")
            session.put(key, encode(OperatorAction(MISSION, "ops", 2, 0, "veto", "a", token)))
            taken = answers.of(2)
            assert taken.accepted and taken.stage == 0, taken
            session.put(key, encode(OperatorAction(MISSION, "ops", 3, 0, "approve", None, token)))
            assert answers.of(3).accepted
            deadline = time.monotonic() + 60
            while not any("stage   1 of " in line for line in lines):
                assert time.monotonic() < deadline, "".join(lines)[-3000:]
                time.sleep(0.2)
            session.put(key, encode(OperatorAction(MISSION, "ops", 4, 0, "force", "a", token)))
            late = answers.of(4)
            assert (late.accepted, late.reason) == (False, "stale-stage") and "already decided" in late.detail
        assert proc.wait(240) == 0, "".join(lines)[-3000:]
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            proc.wait(30)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["decisions"][0] == []  # the veto held
    assert summary["operator"]["vetoes"] == 1 and summary["operator"]["approvals"] == 1
    assert [a["operator"] for a in summary["operator"]["actions"]] == ["ops", "ops"]


@pytest.mark.slow
def test_a_force_taken_mid_hold_survives_a_coordinator_restart(tmp_path):
    """Operator actions are mission events replayed on resume: with ``--operator-required`` the
    coordinator holds stage 0 for the operator; a force of carrier a on the key is taken (in
    mission.db), then the coordinator is SIGKILLed before the stage is decided. A new coordinator
    process on the same --out serves the console again under the same credential, shows the force
    in the stage's hold, and decides stage 0 with a deployed ``by`` the operator; the mission ends
    complete, the force counted once."""
    import urllib.request

    from test_faults import Fleet, _summary, faults_yaml

    scenario_file = tmp_path / "faults.yaml"
    scenario_file.write_text(faults_yaml(4))
    router = f"tcp/127.0.0.1:{free_port()}"
    fleet = Fleet(scenario_file, tmp_path / "run", router)
    mission = "faults"
    coordinator = ["--role", "coordinator", "--connect", router, "--out", str(fleet.out), "--no-map",
                   "--operator", "--operator-port", "0", "--stage-timeout", "120"]

    def console_url(name: str) -> str:
        log = fleet.logs / f"{name}.log"
        line = fleet.poll(f"{name}'s console", lambda: next(
            (ln for ln in log.read_text().splitlines() if "operator console at" in ln), None))
        return line.split("operator console at ")[1].split()[0]

    session = None
    try:
        fleet.start("router", ["--role", "router", "--listen", router])
        fleet.start("coordinator-1", coordinator + ["--operator-required"])
        for cid in ("a", "b"):
            fleet.carrier(cid, extra=["--no-autonomy"])
        console_url("coordinator-1")
        token = (fleet.out / "operator.token").read_text().strip()
        session = zenoh.open(zenoh.Config.from_json5(json.dumps({
            "mode": "client", "connect": {"endpoints": [router]}, "scouting": {"multicast": {"enabled": False}}})))
        answers = Answers()
        session.declare_subscriber(keys.operator_answer_key(mission, "ops"), answers)
        key = keys.operator_action_key(mission, "ops")
        time.sleep(1.0)
        session.put(key, encode(OperatorAction(mission, "ops", 1, 0, "force", "a", token)))
        taken = answers.of(1)
        assert taken.accepted and taken.stage == 0, taken
        fleet.poll("the force in mission.db", lambda: fleet.rows("SELECT seq FROM events WHERE kind='operator'"))
        assert fleet.decided() == -1  # mid-hold: --operator-required waits for the operator
        fleet.kill("coordinator-1")
        assert fleet.decided() == -1
        fleet.start("coordinator-2", coordinator + ["--operator-timeout", "1"])
        url = console_url("coordinator-2")
        assert (fleet.out / "operator.token").read_text().strip() == token

        def held_with_force():
            with urllib.request.urlopen(url + "state.json", timeout=5) as page:
                hold = json.loads(page.read())["hold"]
            return hold is not None and hold.get("stage") == 0 and hold.get("forced") == ["a"]

        seen = False
        while fleet.decided() < 0:
            try:
                seen = seen or held_with_force()
            except OSError:
                pass
            time.sleep(0.05)
        codes = {name: fleet.procs[name].wait(120) for name in ("coordinator-2", "a", "b")}
    finally:
        if session is not None:
            session.close()
        fleet.cleanup()
    assert codes == {"coordinator-2": 0, "a": 0, "b": 0}, (codes, fleet.output())
    summary = _summary(fleet)
    assert summary["resumed"] and summary["ended"] and summary["end_reason"] == "complete"
    assert "a" in summary["decisions"][0]
    a = next(c for c in summary["carriers"] if c["id"] == "a")
    assert [d["by"] for d in a["deployments"] if d["stage"] == 0] == ["operator"]
    assert summary["operator"]["forces"] == 1, summary["operator"]
    assert seen, "the restarted console never showed the replayed force in stage 0's hold"
