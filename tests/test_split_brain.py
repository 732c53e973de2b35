"""Split brain and duplicates, as real OS processes over real Zenoh (docs/fleet.md, "Split
brain"): a second coordinator of a live mission and a second process of a live carrier refuse to
start (one stderr line, exit code 2, nothing written); a standby coordinator takes over a
SIGKILLed primary on the same results directory with epoch 2, and a Decision and an End of the old epoch
(crafted here on a raw zenoh session) are ignored by the carriers (``deposed`` in their Bye)."""
from __future__ import annotations

import json
import queue
import subprocess
import sys
import time

import msgpack
import numpy as np
import pytest
import zenoh

import world
from fleet_helpers import ROOT, TINY, db_rows
from test_faults import Fleet, _check_at_most_once, _summary, faults_yaml
from wire.zconfig import free_port, make_config, open_session

RUN_FLEET = str(ROOT / "run_fleet.py")


def _raw_session(endpoint: str):
    return open_session(make_config("client", [], [endpoint]), 30.0)


def _wait_token(session, key: str, present: bool = True, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        found = [r for r in session.liveliness().get(key, timeout=1.0) if r.ok is not None]
        if bool(found) == present:
            return
        time.sleep(0.05)
    raise AssertionError(f"token {key} {'never appeared' if present else 'never vanished'}")


def _refused(argv: list[str]) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, RUN_FLEET, str(TINY), *argv], capture_output=True, text=True,
                          cwd=str(ROOT), timeout=60)


@pytest.mark.slow
def test_a_second_coordinator_and_a_second_carrier_process_refuse_to_start(tmp_path):
    """[P-2.5] one liveliness token per role and id. Primary coordinator and carrier a live (the coordinator waits for b before stage 0): a
    second coordinator exits 2 with one stderr line and creates nothing in its --out; a process
    for carriers a,b exits 2 naming a, before b ever shows up (no token of b reaches the
    coordinator's mission.db); so does one for a alone."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    procs = []
    session = None
    try:
        procs.append(subprocess.Popen(
            [sys.executable, RUN_FLEET, str(TINY), "--role", "coordinator", "--listen", endpoint,
             "--out", str(tmp_path / "primary"), "--no-map", "--no-record", "--join-timeout", "60"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=str(ROOT)))
        session = _raw_session(endpoint)
        _wait_token(session, "marsupial/tiny/coordinator/alive")
        second = _refused(["--role", "coordinator", "--connect", endpoint, "--out", str(tmp_path / "second"),
                           "--no-map"])
        assert second.returncode == 2, second
        assert second.stderr.splitlines() == [
            "run_fleet.py: mission tiny already has a live coordinator; use --standby to wait for it, "
            "or another --mission"], second.stderr
        assert not (tmp_path / "second").exists()

        procs.append(subprocess.Popen(
            [sys.executable, RUN_FLEET, str(TINY), "--role", "carrier", "--carrier", "a", "--connect", endpoint,
             "--quiet"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=str(ROOT)))
        _wait_token(session, "marsupial/tiny/carrier/a/alive")
        for ids in ("a,b", "a"):
            dup = _refused(["--role", "carrier", "--carrier", ids, "--connect", endpoint])
            assert dup.returncode == 2, dup
            assert dup.stderr.splitlines() == [
                "run_fleet.py: mission tiny already has live carrier(s) a; stop that process first, "
                "or use another --mission"], dup.stderr
        # b never flew: the coordinator never saw its token.
        alive = db_rows(tmp_path / "primary" / "mission.db", "SELECT DISTINCT carrier FROM events WHERE kind='alive'")
        assert alive == [("a",)]
        assert all(p.poll() is None for p in procs)  # the originals were not disturbed
    finally:
        if session is not None:
            session.close()
        for p in procs:
            p.kill()
            p.wait(10)


@pytest.mark.slow
def test_standby_takes_over_a_killed_primary_with_a_higher_epoch(tmp_path):
    """[P-7.6] a standby serves nothing while the primary lives (one State reply, one token).
    A router, a primary coordinator and a ``--standby`` coordinator on the same --out, two
    carriers; SIGKILL the primary after stage 2: the standby takes over with epoch 2 and
    finishes the mission; every stage is decided exactly once, nothing is deployed twice, and a
    Decision of epoch 1 published afterwards on a raw session is rejected by both carriers
    (``deposed``) and deploys nothing."""
    scenario_file = tmp_path / "faults.yaml"
    scenario_file.write_text(faults_yaml(10))
    scenario = world.load_scenario(scenario_file)
    router = f"tcp/127.0.0.1:{free_port()}"
    fleet = Fleet(scenario_file, tmp_path / "run", router)
    session = None
    try:
        fleet.start("router", ["--role", "router", "--listen", router])
        session = _raw_session(router)
        heard: "queue.Queue[dict]" = queue.Queue()
        sub = session.declare_subscriber("marsupial/faults/coordinator/decision",
                                         lambda s: heard.put(msgpack.unpackb(s.payload.to_bytes())))
        coordinator = ["--role", "coordinator", "--connect", router, "--out", str(fleet.out), "--no-map",
                       "--join-timeout", "60"]
        fleet.start("primary", coordinator)
        _wait_token(session, "marsupial/faults/coordinator/alive")
        fleet.start("standby", coordinator + ["--standby"])
        fleet.poll("the standby waiting", lambda: "standby:" in (fleet.logs / "standby.log").read_text())
        for cid in scenario.carrier_ids:
            fleet.carrier(cid)
        fleet.poll("stage 2 decided", lambda: fleet.decided() >= 2)
        # [P-7.6] while the primary lives the standby answers no State query and declares no token.
        states = [r for r in session.get("marsupial/faults/coordinator/state", timeout=2.0) if r.ok is not None]
        tokens = [r for r in session.liveliness().get("marsupial/faults/coordinator/alive", timeout=2.0)
                  if r.ok is not None]
        assert len(states) == 1 and len(tokens) == 1, (len(states), len(tokens))
        assert msgpack.unpackb(states[0].ok.payload.to_bytes()).get("epoch", 1) == 1
        fleet.kill("primary")
        k = fleet.decided()
        assert 2 <= k < scenario.stages - 2
        fleet.poll("the standby took over", lambda: len(fleet.rows("SELECT seq FROM events WHERE kind='open'")) >= 2)
        fleet.poll("a decision of epoch 2", lambda: fleet.decided() > k + 1)
        stale = {"v": 1, "type": "decision", "mission": "faults", "stage": scenario.stages - 1,
                 "t": 5.0 * (scenario.stages - 1), "deploy": ["a", "b"], "planning_ms": 0.0}  # epoch absent: 1
        session.declare_publisher("marsupial/faults/coordinator/decision", reliability=zenoh.Reliability.RELIABLE,
                                  congestion_control=zenoh.CongestionControl.BLOCK).put(msgpack.packb(stale))
        # [P-7.4] an End of epoch 1 (the deposed primary's, as a coordinator that missed its
        # deposition would send it): rejected, the carriers fly on to the standby's End.
        stale_end = {"v": 1, "type": "end", "mission": "faults", "stages": k, "reason": "complete", "epoch": 1}
        session.declare_publisher("marsupial/faults/coordinator/end", reliability=zenoh.Reliability.RELIABLE,
                                  congestion_control=zenoh.CongestionControl.BLOCK).put(msgpack.packb(stale_end))
        codes = {name: fleet.procs[name].wait(90) for name in ("standby", "a", "b")}  # the router runs on
        sub.undeclare()
    finally:
        if session is not None:
            session.close()
        fleet.cleanup()
    assert codes["standby"] == 0 and codes["a"] == 0 and codes["b"] == 0, (codes, fleet.output())
    summary = _summary(fleet)
    assert summary["ended"] and summary["end_reason"] == "complete" and summary["resumed"]
    assert summary["stages_decided"] == scenario.stages and summary["epoch"] == 2
    opens = [json.loads(p)["epoch"] for (p,) in fleet.rows("SELECT payload FROM events WHERE kind='open' ORDER BY seq")]
    assert opens == [1, 2]
    decisions = []
    while not heard.empty():
        decisions.append(heard.get())
    epochs = {}
    for d in decisions:
        if d != stale:
            epochs.setdefault(d["stage"], set()).add(d.get("epoch", 1))
    assert sorted(epochs) == list(range(scenario.stages))
    assert all(epochs[j] == {2} for j in range(k + 1, scenario.stages)), epochs
    _check_at_most_once(fleet, scenario, summary)
    for cid in scenario.carrier_ids:  # both the stale Decision and the stale End were rejected
        assert summary["rejected"]["carriers"][cid].get("deposed", 0) >= 2, summary["rejected"]
    # The stale decision deployed nobody: every deployment is one of the coordinators' decisions.
    for r, carrier in enumerate(summary["carriers"]):
        for dep in carrier["deployments"]:
            assert carrier["id"] in summary["decisions"][dep["stage"]]
    assert np.isfinite(summary["total_reward"])


def test_a_coordinator_that_hears_a_higher_epoch_stops_without_end(tmp_path):
    """A Decision of epoch 5 on the mission's decision key (another coordinator took over, as a
    healed partition would show it): the coordinator (epoch 1) logs one line and exits 3 at once,
    publishes no End and writes no summary.json; mission.db has no end event."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    out = tmp_path / "out"
    proc = subprocess.Popen(
        [sys.executable, RUN_FLEET, str(TINY), "--role", "coordinator", "--listen", endpoint, "--out", str(out),
         "--no-map", "--no-record", "--join-timeout", "60"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=str(ROOT))
    session = None
    try:
        session = _raw_session(endpoint)
        ends: "queue.Queue[bytes]" = queue.Queue()
        sub = session.declare_subscriber("marsupial/tiny/coordinator/end", lambda s: ends.put(s.payload.to_bytes()))
        _wait_token(session, "marsupial/tiny/coordinator/alive")
        newer = {"v": 1, "type": "decision", "mission": "tiny", "stage": 0, "t": 0.0, "deploy": [],
                 "planning_ms": 0.0, "epoch": 5}
        session.declare_publisher("marsupial/tiny/coordinator/decision", reliability=zenoh.Reliability.RELIABLE,
                                  congestion_control=zenoh.CongestionControl.BLOCK).put(msgpack.packb(newer))
        output, _ = proc.communicate(timeout=30)
        time.sleep(0.5)
        sub.undeclare()
    finally:
        if session is not None:
            session.close()
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    assert proc.returncode == 3, output
    assert [line for line in output.splitlines() if "deposed" in line] == [
        "coordinator: deposed: a coordinator of epoch 5 took over mission tiny (it decides; this one has "
        "epoch 1); stopping without End"], output
    assert ends.empty()
    assert not (out / "summary.json").exists()
    assert db_rows(out / "mission.db", "SELECT COUNT(*) FROM events WHERE kind='end'") == [(0,)]


def test_the_one_host_launcher_through_a_router_refuses_a_live_mission(tmp_path):
    """``run_fleet.py S.yaml --connect ROUTER`` while a coordinator of the same mission is live
    behind that router: the launcher starts nothing (its carriers would join the live mission),
    prints the coordinator's one line and exits 2."""
    router = f"tcp/127.0.0.1:{free_port()}"
    procs = []
    session = None
    try:
        procs.append(subprocess.Popen([sys.executable, RUN_FLEET, "--role", "router", "--listen", router],
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=str(ROOT)))
        procs.append(subprocess.Popen(
            [sys.executable, RUN_FLEET, str(TINY), "--role", "coordinator", "--connect", router,
             "--out", str(tmp_path / "primary"), "--no-map", "--no-record", "--join-timeout", "60"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=str(ROOT)))
        session = _raw_session(router)
        _wait_token(session, "marsupial/tiny/coordinator/alive")
        launcher = _refused(["--connect", router, "--out", str(tmp_path / "second"), "--no-map"])
        assert launcher.returncode == 2, launcher
        assert launcher.stderr.splitlines() == [
            "run_fleet.py: mission tiny already has a live coordinator; use --standby to wait for it, "
            "or another --mission"], launcher.stderr
        assert not (tmp_path / "second").exists()
        alive = db_rows(tmp_path / "primary" / "mission.db", "SELECT COUNT(*) FROM events WHERE kind='alive'")
        assert alive == [(0,)]  # no carrier of the launcher joined the live mission
    finally:
        if session is not None:
            session.close()
        for p in procs:
            p.kill()
            p.wait(10)


def test_a_coordinator_on_a_fresh_out_keeps_its_epoch_whatever_a_hello_reports(tmp_path):
    """[P-7.3] a carrier's Hello never changes who decides: a coordinator on an empty --out
    (epoch 1) gets a Hello reporting epoch 4 before stage 0; it keeps epoch 1 (in mission.db too),
    logs the claim once, and the mission runs with epoch-1 decisions that fresh carriers accept."""
    from fleet_helpers import InProcessFleet
    from wire.messages import Hello
    from wire.transport import Node

    tiny = world.load_scenario(TINY)
    fleet = InProcessFleet(tiny, tmp_path, planner="ssap", join_timeout_s=30.0)
    fleet.start_coordinator()
    coordinator = fleet.coordinator
    deadline = time.monotonic() + 60
    while coordinator.node is None and time.monotonic() < deadline:
        time.sleep(0.05)
    heard: "queue.Queue[dict]" = queue.Queue()
    other = Node(make_config("client", [], [fleet.endpoint]), open_timeout_s=30)
    try:
        other.session.declare_subscriber("marsupial/tiny/coordinator/decision",
                                         lambda s: heard.put(msgpack.unpackb(s.payload.to_bytes())))
        while not other.query("marsupial/tiny/coordinator/state") and time.monotonic() < deadline:
            time.sleep(0.05)
        other.put("marsupial/tiny/carrier/a/hello",
                  Hello("tiny", "a", 1, "elsewhere", 2, 0, coordinator.setup.fingerprint, epoch=4))
        while "a" not in coordinator.crew.epochs.claims and time.monotonic() < deadline:
            time.sleep(0.05)
        assert coordinator.crew.epochs.claims == {"a": 4} and coordinator.crew.epochs.epoch == 1
        for cid in tiny.carrier_ids:
            fleet.start_carrier(cid)
        summary = fleet.join()
    finally:
        other.close()
    assert summary["ended"] and summary["end_reason"] == "complete" and summary["epoch"] == 1
    assert summary["stages_decided"] == tiny.stages
    epochs = set()
    while not heard.empty():
        epochs.add(heard.get().get("epoch", 1))
    assert epochs == {1}
    assert all("deposed" not in counts for counts in summary["rejected"]["carriers"].values()), summary["rejected"]
    from storage.missiondb import highest_epoch
    assert highest_epoch(tmp_path / "mission.db") == 1
    assert [(d["sender"], d["rule"], d["value"]) for d in summary["denials"]] == [("a", "P-7.3", 4)]


@pytest.mark.slow
def test_a_frozen_primary_that_comes_back_is_deposed(tmp_path):
    """The primary is frozen (SIGSTOP) after stage 2, long enough for Zenoh's lease (3 s here)
    to expire: the standby takes over with epoch 2 and carries on; when the primary runs again
    (SIGCONT) it learns it was deposed (a newer epoch in mission.db or on the decision key,
    whichever comes first; never from a carrier's Hello) and exits 3 without deciding again; the mission
    completes under the standby, every stage decided once."""
    import signal

    scenario_file = tmp_path / "faults.yaml"
    scenario_file.write_text(faults_yaml(10))
    scenario = world.load_scenario(scenario_file)
    zconf = tmp_path / "lease.json5"
    zconf.write_text("{ transport: { link: { tx: { lease: 3000, keep_alive: 4 } } },\n"
                     "  connect: { retry: { period_init_ms: 250, period_max_ms: 1000, period_increase_factor: 2 } } }\n")
    lease = ["--zenoh-config", str(zconf)]
    router = f"tcp/127.0.0.1:{free_port()}"
    fleet = Fleet(scenario_file, tmp_path / "run", router)
    session = None
    try:
        fleet.start("router", ["--role", "router", "--listen", router, *lease])
        session = _raw_session(router)
        coordinator = ["--role", "coordinator", "--connect", router, "--out", str(fleet.out), "--no-map",
                       "--join-timeout", "60", *lease]
        fleet.start("primary", coordinator)
        _wait_token(session, "marsupial/faults/coordinator/alive")
        fleet.start("standby", coordinator + ["--standby"])
        fleet.poll("the standby waiting", lambda: "standby:" in (fleet.logs / "standby.log").read_text())
        for cid in scenario.carrier_ids:
            fleet.carrier(cid, extra=lease)
        fleet.poll("stage 2 decided", lambda: fleet.decided() >= 2)
        fleet.killed.add("primary")  # it is expected to exit 3
        fleet.procs["primary"].send_signal(signal.SIGSTOP)
        # The primary may be frozen in the middle of a mission.db write: the standby then waits
        # for the lock, so the primary runs again as soon as the standby has seen its token vanish.
        fleet.poll("the standby taking over", lambda: "taking over" in (fleet.logs / "standby.log").read_text())
        time.sleep(1.0)
        fleet.procs["primary"].send_signal(signal.SIGCONT)
        codes = {name: fleet.procs[name].wait(90) for name in ("primary", "standby", "a", "b")}
    finally:
        if session is not None:
            session.close()
        for proc in fleet.procs.values():
            if proc.poll() is None:
                proc.send_signal(signal.SIGCONT)
        fleet.cleanup()
    assert codes == {"primary": 3, "standby": 0, "a": 0, "b": 0}, (codes, fleet.output())
    deposed = [line for line in (fleet.logs / "primary.log").read_text().splitlines() if "deposed" in line]
    assert len(deposed) == 1 and "epoch 2" in deposed[0], fleet.output()
    summary = _summary(fleet)
    assert summary["ended"] and summary["end_reason"] == "complete" and summary["epoch"] == 2
    assert summary["stages_decided"] == scenario.stages
    _check_at_most_once(fleet, scenario, summary)


@pytest.mark.slow
def test_a_primary_restarted_on_a_stale_disk_after_the_standbys_death_is_outranked(tmp_path):
    """Ballots (docs/protocol.md [P-7.1], [P-7.2]; docs/fleet.md, "Split brain"). A primary
    (``coordinator``, disk A) and a standby on its own disk (``standby``, disk B); the primary is
    killed after stage 2, the standby takes over with epoch 2, decides, and is killed in turn;
    the primary restarts on A, which knows nothing of the standby, and takes epoch 2 again. Its
    ballot (2, coordinator) is below the standby's (2, standby): both carriers reject its
    Decisions ``deposed``, confirm none of them, take it as absent and finish deciding on board.
    Before ballots (epochs compared alone) they took the restarted primary's Decisions, decided
    from a record without the standby's stages, as the standby's successors."""
    scenario_file = tmp_path / "faults.yaml"
    scenario_file.write_text(faults_yaml(16))
    scenario = world.load_scenario(scenario_file)
    router = f"tcp/127.0.0.1:{free_port()}"
    fleet = Fleet(scenario_file, tmp_path / "a", router)
    disk_b = tmp_path / "b"
    session = None
    try:
        fleet.start("router", ["--role", "router", "--listen", router])
        session = _raw_session(router)
        heard: "queue.Queue[dict]" = queue.Queue()
        sub = session.declare_subscriber("marsupial/faults/coordinator/decision",
                                         lambda s: heard.put(msgpack.unpackb(s.payload.to_bytes())))
        primary = ["--role", "coordinator", "--connect", router, "--out", str(fleet.out), "--no-map",
                   "--join-timeout", "60", "--coordinator-id", "coordinator"]
        fleet.start("primary", primary)
        _wait_token(session, "marsupial/faults/coordinator/alive")
        fleet.start("standby", ["--role", "coordinator", "--connect", router, "--out", str(disk_b), "--no-map",
                                "--join-timeout", "60", "--standby", "--coordinator-id", "standby"])
        fleet.poll("the standby waiting", lambda: "standby:" in (fleet.logs / "standby.log").read_text())
        for cid in scenario.carrier_ids:
            fleet.carrier(cid)
        fleet.poll("stage 2 decided", lambda: fleet.decided() >= 2)
        fleet.kill("primary")
        k = fleet.decided()

        def b_decided() -> int:
            try:
                return db_rows(disk_b / "mission.db", "SELECT MAX(stage) FROM decisions")[0][0] or -1
            except Exception:  # not created yet, or its schema not written yet
                return -1

        fleet.poll("the standby decided two stages past the primary's", lambda: b_decided() >= k + 2)
        fleet.kill("standby")
        m = b_decided()
        assert m < scenario.stages - 3, (k, m)  # stages left for the restarted primary
        fleet.start("restarted", primary)
        fleet.poll("the primary reopened", lambda: len(fleet.rows("SELECT seq FROM events WHERE kind='open'")) >= 2)
        codes = {name: fleet.procs[name].wait(120) for name in ("restarted", *scenario.carrier_ids)}
        sub.undeclare()
    finally:
        if session is not None:
            session.close()
        fleet.cleanup()
    assert all(code == 0 for code in codes.values()), (codes, fleet.output())
    opens = [json.loads(p) for (p,) in fleet.rows("SELECT payload FROM events WHERE kind='open' ORDER BY seq")]
    assert [(o["epoch"], o["coordinator"]) for o in opens] == [(1, "coordinator"), (2, "coordinator")]
    b_opens = [json.loads(p) for (p,) in db_rows(disk_b / "mission.db", "SELECT payload FROM events WHERE kind='open'")]
    assert [(o["epoch"], o["coordinator"]) for o in b_opens] == [(2, "standby")]
    decisions = []
    while not heard.empty():
        decisions.append(heard.get())
    stale = [d for d in decisions if d.get("epoch", 1) == 2 and d.get("coordinator") == "coordinator"]
    assert stale, "the restarted primary published no Decision"
    assert any(d.get("coordinator") == "standby" and d["stage"] > k for d in decisions)
    # No carrier confirmed a deployment to the restarted primary: its Decisions were rejected.
    reopened = fleet.rows("SELECT MAX(seq) FROM events WHERE kind='open'")[0][0]
    fresh = fleet.rows(f"SELECT carrier, stage, payload FROM events WHERE kind='confirm' AND seq > {reopened}")
    assert all(json.loads(p).get("status") != "deployed" for _, _, p in fresh), fresh
    summary = _summary(fleet)
    for cid in scenario.carrier_ids:
        assert summary["rejected"]["carriers"][cid].get("deposed", 0) >= 1, summary["rejected"]
        for own in (json.loads(p)["deployments"] for (p,) in
                    fleet.rows(f"SELECT payload FROM events WHERE kind='bye' AND carrier='{cid}'")):
            spec = next(c for c in scenario.carriers if c.id == cid)
            assert len(own) == len(set(own)) <= spec.passengers, (cid, own)
