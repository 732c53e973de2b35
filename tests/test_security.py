"""Security of the fleet's Zenoh links: mutual TLS and access control by certificate common name.

Real Zenoh sessions on loopback (multicast scouting off, a free port per test) with certificates
generated at test time by tools/gen_certs.py. Negative checks are bounded: a forbidden message is
sent before an allowed marker on the same link, and links deliver in order, so once the marker
has arrived the forbidden message would have arrived too.
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import zenoh

from localports import distinct_free_ports
from tools import gen_certs
from tools.gen_certs import FleetCerts, Identity
from wire import keys
from wire.zconfig import free_port

ROOT = Path(__file__).resolve().parents[1]
TINY = ROOT / "scenarios" / "tiny.yaml"
MISSION = "m"
CARRIERS = ("c0", "c1")
WAIT_S = 10.0  # upper bound on waiting for something that must happen
NEVER_S = 2.0  # how long to watch for something that must not happen


@pytest.fixture(scope="module")
def certs(tmp_path_factory) -> FleetCerts:
    return gen_certs.generate_fleet_certs(tmp_path_factory.mktemp("certs"), CARRIERS)


@pytest.fixture(scope="module")
def strangers(tmp_path_factory, certs) -> dict[str, Identity]:
    """Identities that must not get in: a carrier CN signed by another CA, an unknown CN from the fleet CA."""
    out = tmp_path_factory.mktemp("strangers")
    other_ca = gen_certs.make_ca(out, cn="some-other-ca", stem="other-ca")
    fleet_ca = Identity(gen_certs.CA_CN, certs.ca, certs.ca.with_suffix(".key"))
    return {
        "other-ca": gen_certs.issue(other_ca, out, "forged-c0", gen_certs.carrier_cn("c0")),
        "unknown-cn": gen_certs.issue(fleet_ca, out, "c9", gen_certs.carrier_cn("c9")),
    }


def open_session(config: dict, port: int, role: str, mode: str | None = None) -> zenoh.Session:
    """Open a session from a generated config on tls/127.0.0.1:PORT: the listener is a peer (as the
    fleet's coordinator), a connecting session a client (as the fleet's carriers) unless `mode`."""
    config = json.loads(json.dumps(config))
    endpoint = f"tls/127.0.0.1:{port}"
    if role == "listen":
        config["mode"] = mode or "peer"
        config["listen"] = {"endpoints": [endpoint]}
    else:
        config["mode"] = mode or "client"
        config["connect"] = {"endpoints": [endpoint]}
        config["listen"] = {"endpoints": []}
    return zenoh.open(zenoh.Config.from_json5(json.dumps(config)))


def neighbours(session: zenoh.Session) -> list:
    """Zenoh ids of the sessions this one has a transport with (clients, peers, routers)."""
    return [t.zid for t in session.info.transports()]


def carrier_conf(certs: FleetCerts, identity: Identity | None, acl: bool = True) -> dict:
    conf = {
        "scouting": {"multicast": {"enabled": False}},
        "transport": {"link": {"protocols": ["tls"], "tls": gen_certs.tls_section(certs.ca, identity)}},
    }
    if acl:
        conf["access_control"] = gen_certs.carrier_acl()
    return conf


class Inbox:
    """Thread-safe list of (key, payload) received by a subscriber callback (which only appends)."""

    def __init__(self) -> None:
        self.items: list[tuple[str, bytes]] = []
        self._cond = threading.Condition()

    def __call__(self, sample: zenoh.Sample) -> None:
        with self._cond:
            self.items.append((str(sample.key_expr), sample.payload.to_bytes()))
            self._cond.notify_all()

    def wait_for(self, item: tuple[str, bytes], timeout: float = WAIT_S) -> bool:
        with self._cond:
            return self._cond.wait_for(lambda: item in self.items, timeout)


def wait_connected(session: zenoh.Session, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if neighbours(session):
            return True
        time.sleep(0.05)
    return False


def deliver(sender: zenoh.Session, inbox: Inbox, forbidden: list[tuple[str, bytes]], marker: tuple[str, bytes]) -> None:
    """Put the forbidden messages then the marker, repeatedly, until the marker arrives."""
    deadline = time.monotonic() + WAIT_S
    while time.monotonic() < deadline:
        for key, payload in forbidden:
            sender.put(key, payload)
        sender.put(*marker)
        if inbox.wait_for(marker, timeout=0.2):
            return
    raise AssertionError(f"allowed message {marker} never arrived")


def test_mutual_tls_sessions_exchange_messages(certs):
    port = free_port()
    coord_conf = gen_certs.coordinator_config(certs)
    del coord_conf["access_control"]
    with open_session(coord_conf, port, "listen") as coord:
        inbox = Inbox()
        coord.declare_subscriber(f"marsupial/{MISSION}/**", inbox)
        with open_session(carrier_conf(certs, certs.carriers["c0"], acl=False), port, "connect") as car:
            assert wait_connected(car, WAIT_S), "a carrier with a valid certificate did not connect"
            deliver(car, inbox, [], (f"marsupial/{MISSION}/carrier/c0/observation", b"hello"))


def intruder_conf(certs: FleetCerts, strangers: dict[str, Identity], who: str) -> dict:
    """A TLS client that trusts the fleet CA but presents no certificate, or a forged one."""
    if who == "no-certificate":
        conf = carrier_conf(certs, None, acl=False)
        conf["transport"]["link"]["tls"]["enable_mtls"] = False  # an ordinary server-auth TLS client
        return conf
    return carrier_conf(certs, strangers[who], acl=False)


def test_control_without_mtls_the_certificateless_client_connects(certs, strangers):
    """The rejection below is mutual TLS at work: with enable_mtls off on the listener, the same
    certificate-less client does get a session."""
    port = free_port()
    coord_conf = gen_certs.coordinator_config(certs)
    coord_conf["transport"]["link"]["tls"]["enable_mtls"] = False
    with open_session(coord_conf, port, "listen") as coord:
        with open_session(intruder_conf(certs, strangers, "no-certificate"), port, "connect"):
            assert wait_connected(coord, WAIT_S)


@pytest.mark.parametrize("who", ["no-certificate", "other-ca", "plain-tcp"])
@pytest.mark.parametrize("mode", ["client", "peer"])
def test_process_without_valid_certificate_cannot_connect_or_publish(certs, strangers, who, mode):
    """A client fails to open; a peer opens alone (peers start without neighbours) and nothing it
    publishes arrives."""
    port = free_port()
    coord_conf = gen_certs.coordinator_config(certs)
    with open_session(coord_conf, port, "listen") as coord:
        inbox = Inbox()
        coord.declare_subscriber(f"marsupial/{MISSION}/**", inbox)
        if who == "plain-tcp":
            conf = {"scouting": {"multicast": {"enabled": False}}, "mode": mode,
                    "connect": {"endpoints": [f"tcp/127.0.0.1:{port}"]}, "listen": {"endpoints": []}}
            config = zenoh.Config.from_json5(json.dumps(conf))
            opener = lambda: zenoh.open(config)  # noqa: E731
        else:
            opener = lambda: open_session(intruder_conf(certs, strangers, who), port, "connect", mode)  # noqa: E731
        if mode == "client":
            with pytest.raises(zenoh.ZError):
                opener().close()
            assert inbox.items == [] and not neighbours(coord)
            return
        with opener() as intruder:
            deadline = time.monotonic() + NEVER_S
            while time.monotonic() < deadline:
                intruder.put(f"marsupial/{MISSION}/carrier/c0/observation", b"intruder")
                time.sleep(0.05)
            assert not neighbours(coord), f"{who}: the coordinator accepted a session"
            assert not neighbours(intruder), f"{who}: the intruder reached a peer"
            assert inbox.items == [], f"{who}: a publication got through: {inbox.items}"


@pytest.mark.parametrize("verify_name", [True, False])
def test_carriers_check_the_coordinator_certificate_names_the_host_dialled(tmp_path, certs, verify_name):
    """A coordinator certificate issued for another host name is refused when carriers verify
    names (the default), accepted when `verify_name_on_connect` is off (chain still checked)."""
    fleet_ca = Identity(gen_certs.CA_CN, certs.ca, certs.ca.with_suffix(".key"))
    elsewhere = gen_certs.issue(fleet_ca, tmp_path, "coordinator-elsewhere", gen_certs.COORDINATOR_CN,
                                hosts=("coordinator.example",))
    coord_conf = gen_certs.coordinator_config(certs)
    coord_conf["transport"]["link"]["tls"] = gen_certs.tls_section(certs.ca, elsewhere)
    car_conf = carrier_conf(certs, certs.carriers["c0"])
    car_conf["transport"]["link"]["tls"]["verify_name_on_connect"] = verify_name
    port = free_port()
    with open_session(coord_conf, port, "listen") as coord:
        if verify_name:
            with pytest.raises(zenoh.ZError):
                open_session(car_conf, port, "connect").close()
            assert not neighbours(coord)
        else:
            with open_session(car_conf, port, "connect") as car:
                assert wait_connected(car, WAIT_S)


def test_acl_carrier_publishes_only_under_its_own_keys(certs):
    port = free_port()
    decision = keys.decision_key(MISSION)
    with open_session(gen_certs.coordinator_config(certs), port, "listen") as coord:
        inbox = Inbox()
        coord.declare_subscriber(f"marsupial/{MISSION}/**", inbox)
        tokens = Inbox()
        coord.liveliness().declare_subscriber(f"marsupial/{MISSION}/**", tokens, history=True)
        with open_session(carrier_conf(certs, certs.carriers["c0"]), port, "connect") as car:
            assert wait_connected(car, WAIT_S)
            car_inbox = Inbox()
            car.declare_subscriber(decision, car_inbox)
            forbidden = [(decision, b"forged decision"), (keys.carrier_key(MISSION, "c1", "obs"), b"spoof c1")]
            deliver(car, inbox, forbidden, (keys.carrier_key(MISSION, "c0", "obs"), b"own"))
            time.sleep(0.2)
            assert [item for item in forbidden if item in inbox.items] == []
            # Nor is the forged decision forwarded to another carrier (the coordinator routes for its
            # clients; the drop happens on ingress, before routing).
            with open_session(carrier_conf(certs, certs.carriers["c1"]), port, "connect") as other:
                assert wait_connected(other, WAIT_S)
                other_inbox = Inbox()
                other.declare_subscriber(f"marsupial/{MISSION}/**", other_inbox)
                deliver(car, other_inbox, forbidden, (keys.carrier_key(MISSION, "c0", "obs"), b"own 2"))
                time.sleep(0.2)
                assert [item for item in forbidden if item in other_inbox.items] == []
            # The coordinator's own decisions still reach the carrier (egress is allowed).
            deliver(coord, car_inbox, [], (decision, b"real decision"))
            # Liveliness: a token under the carrier's own keys is seen, one under the coordinator's is not.
            car.liveliness().declare_token(keys.coordinator_alive(MISSION))
            car.liveliness().declare_token(keys.carrier_alive(MISSION, "c0"))
            assert tokens.wait_for((keys.carrier_alive(MISSION, "c0"), b""))
            time.sleep(0.5)
            assert {k for k, _ in tokens.items} == {keys.carrier_alive(MISSION, "c0")}


def test_acl_control_without_access_control_the_forged_decision_arrives(certs):
    """The ACL test above can fail: the same forged decision is delivered when access control is off."""
    port = free_port()
    decision = keys.decision_key(MISSION)
    coord_conf = gen_certs.coordinator_config(certs)
    coord_conf["access_control"]["enabled"] = False
    with open_session(coord_conf, port, "listen") as coord:
        inbox = Inbox()
        coord.declare_subscriber(f"marsupial/{MISSION}/**", inbox)
        with open_session(carrier_conf(certs, certs.carriers["c0"]), port, "connect") as car:
            assert wait_connected(car, WAIT_S)
            deliver(car, inbox, [], (decision, b"forged decision"))


def test_acl_unknown_common_name_from_the_fleet_ca_gets_nothing_through(certs, strangers):
    port = free_port()
    with open_session(gen_certs.coordinator_config(certs), port, "listen") as coord:
        inbox = Inbox()
        coord.declare_subscriber(f"marsupial/{MISSION}/carrier/**", inbox)
        with open_session(carrier_conf(certs, strangers["unknown-cn"]), port, "connect") as car:
            # TLS succeeds (the fleet CA signed it) but no access-control policy names this CN.
            assert wait_connected(car, WAIT_S)
            car_inbox = Inbox()
            car.declare_subscriber(f"marsupial/{MISSION}/coordinator/**", car_inbox)
            deadline = time.monotonic() + NEVER_S
            while time.monotonic() < deadline:
                car.put(f"marsupial/{MISSION}/carrier/c9/observation", b"stranger")
                coord.put(f"marsupial/{MISSION}/coordinator/decision", b"decision")
                time.sleep(0.05)
            assert inbox.items == []
            assert car_inbox.items == []


def _zenoh_view(config: zenoh.Config, keys=("listen", "connect", "scouting/multicast/enabled",
                                          "transport/link/protocols", "transport/link/tls", "access_control")):
    return {key: json.loads(config.get_json(key)) for key in keys}


def test_config_examples_are_what_the_generator_writes():
    """config/*.json5 (for scenarios/tiny.yaml, relative cert paths) equal tools/gen_certs.py's output."""
    root = Path(__file__).resolve().parents[1]
    ids = gen_certs.scenario_carrier_ids(root / "scenarios" / "tiny.yaml")
    layout = gen_certs.fleet_layout(Path("certs"), ids)
    expected = {"coordinator.json5": gen_certs.coordinator_config(layout)}
    expected.update({f"carrier-{cid}.json5": gen_certs.carrier_config(layout, cid) for cid in ids})
    assert sorted(p.name for p in (root / "config").glob("*.json5")) == sorted(expected)
    for name, config in expected.items():
        example = zenoh.Config.from_file(str(root / "config" / name))
        assert _zenoh_view(example) == _zenoh_view(zenoh.Config.from_json5(json.dumps(config))), name


# --------------------------------------------------------------------------- whole fleets over TLS

FLEET_TIMEOUT_S = 150.0  # upper bound on one fleet run (a hang fails the test instead of blocking)


#: The TLS fleets' join wait (s): the forged fleet waits it out for the carrier it refuses, and on
#: a loaded host (the slow tier's two workers) the other carrier's start and TLS handshake took
#: more than 8 s once, so it joined after stage 0 and the decisions were not the offline ones.
JOIN_S = 20


def _launch_fleet(tmp: Path, name: str, port: int, certs: FleetCerts, carrier_confs: dict[str, Path]) -> dict:
    """Start the coordinator and one process per carrier of the tiny scenario, each with its own
    --zenoh-config, over tls/127.0.0.1:PORT. Returns the Popen objects and paths."""
    out = tmp / name
    out.mkdir()
    coord_conf = gen_certs.write_json5(out / "coordinator.json5", gen_certs.coordinator_config(certs))
    base = [sys.executable, str(ROOT / "run_fleet.py"), str(TINY)]
    logs = {}

    def start(role: str, args: list[str]) -> subprocess.Popen:
        logs[role] = out / f"{role}.log"
        with open(logs[role], "wb") as log:
            return subprocess.Popen(base + args, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT)

    procs = {"coordinator": start("coordinator", [
        "--role", "coordinator", "--zenoh-config", str(coord_conf), "--listen", f"tls/127.0.0.1:{port}",
        "--out", str(out / "results"), "--join-timeout", str(JOIN_S), "--no-map"])}
    for cid, conf in carrier_confs.items():
        procs[cid] = start(cid, ["--role", "carrier", "--carrier", cid, "--zenoh-config", str(conf),
                                 "--connect", f"tls/127.0.0.1:{port}", "--coordinator-timeout", str(JOIN_S)])
    return {"procs": procs, "logs": logs, "out": out}


def _wait_fleet(fleet: dict) -> dict:
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
    summary_path = fleet["out"] / "results" / "summary.json"
    summary = json.loads(summary_path.read_text()) if summary_path.exists() else None
    logs = {role: path.read_text(errors="replace") for role, path in fleet["logs"].items()}
    return {"codes": codes, "summary": summary, "logs": logs}


@pytest.fixture(scope="module")
def tls_fleets(tmp_path_factory, certs_tiny, strangers_tiny):
    """Two tiny missions over mutual TLS, run at the same time: every carrier with its own valid
    certificate ("valid"), and carrier b with a certificate for its name from another CA ("forged")."""
    tmp = tmp_path_factory.mktemp("fleets")
    confs = {cid: gen_certs.write_json5(tmp / f"carrier-{cid}.json5", gen_certs.carrier_config(certs_tiny, cid))
             for cid in certs_tiny.carriers}
    forged = gen_certs.carrier_config(certs_tiny, "b")
    forged["transport"]["link"]["tls"] = gen_certs.tls_section(certs_tiny.ca, strangers_tiny["forged-b"])
    forged_conf = gen_certs.write_json5(tmp / "forged-b.json5", forged)
    ports = distinct_free_ports(2)
    fleets = {
        "valid": _launch_fleet(tmp, "valid", ports[0], certs_tiny, confs),
        "forged": _launch_fleet(tmp, "forged", ports[1], certs_tiny, {"a": confs["a"], "b": forged_conf}),
    }
    return {name: _wait_fleet(fleet) for name, fleet in fleets.items()}


@pytest.fixture(scope="module")
def certs_tiny(tmp_path_factory) -> FleetCerts:
    return gen_certs.generate_fleet_certs(tmp_path_factory.mktemp("certs-tiny"), gen_certs.scenario_carrier_ids(TINY))


@pytest.fixture(scope="module")
def strangers_tiny(tmp_path_factory) -> dict[str, Identity]:
    out = tmp_path_factory.mktemp("strangers-tiny")
    other_ca = gen_certs.make_ca(out, cn="some-other-ca", stem="other-ca")
    return {"forged-b": gen_certs.issue(other_ca, out, "forged-b", gen_certs.carrier_cn("b"))}


def offline_decisions(x_override=None) -> tuple[list[list[str]], list]:
    """Per stage, the carriers the planner core deploys offline on the tiny scenario's
    observations (optionally with some replaced), with the scenario's seed."""
    import world

    scenario = world.load_scenario(str(TINY))
    result, x = world.offline_mission(scenario, x=x_override)
    ids = list(scenario.carrier_ids)
    return [[ids[r] for r in range(len(ids)) if result.deployed[r, j]] for j in range(scenario.stages)], x


@pytest.mark.slow
def test_tiny_mission_completes_over_mutual_tls(tls_fleets):
    run = tls_fleets["valid"]
    assert run["codes"] == {"coordinator": 0, "a": 0, "b": 0}, run["logs"]
    summary = run["summary"]
    assert summary["ended"] and summary["stages_decided"] == summary["stages"]
    expected, _ = offline_decisions()
    assert summary["decisions"] == expected
    deployed = {c["id"]: len(c["deployments"]) for c in summary["carriers"]}
    assert deployed == {"a": 2, "b": 1}  # every passenger deployed


@pytest.mark.slow
def test_carrier_without_valid_certificate_cannot_join(tls_fleets):
    import numpy as np

    run = tls_fleets["forged"]
    summary = run["summary"]
    assert run["codes"]["coordinator"] == 0, run["logs"]["coordinator"]
    assert run["codes"]["a"] == 0, run["logs"]["a"]
    assert run["codes"]["b"] != 0, "the forged carrier b claims success"
    assert summary["ended"] and summary["stages_decided"] == summary["stages"]
    ids = [c["id"] for c in summary["carriers"]]
    b = summary["carriers"][ids.index("b")]
    assert b["deployments"] == [] and not any("b" in d for d in summary["decisions"])
    assert all(x is None for x in summary["observations"][ids.index("b")]), "b's stages must all be ∅"
    assert "carrier b is live" not in run["logs"]["coordinator"]
    # The rest of the mission is what the planner does offline with b's stages ∅: on a's true
    # observations, those that reached the coordinator (on a loaded host, the slow tier's two
    # workers, one of a's came after its stage's wait once: ∅ there, for the fleet as offline).
    _, x = offline_decisions()
    x = np.array(x)
    x[ids.index("b"), :] = np.nan
    seen = np.array([[np.nan if v is None else v for v in row] for row in summary["observations"]], dtype=float)
    a = ids.index("a")
    np.testing.assert_array_equal(seen[a][~np.isnan(seen[a])], x[a][~np.isnan(seen[a])])
    assert not np.isnan(seen[a]).all(), run["logs"]["coordinator"]  # a took part
    late = np.isnan(seen[a]) & ~np.isnan(x[a])
    x[a, late] = np.nan
    expected, _ = offline_decisions(x)
    assert summary["decisions"] == expected, (late, run["logs"]["coordinator"][-3000:])


@pytest.mark.parametrize("argv, expected", [
    (["--scenario", "no/such/file.yaml"], "no/such/file.yaml: cannot read"),
    (["--scenario", "{tmp}/no-carriers.yaml"], "no-carriers.yaml: carriers: expected a non-empty list"),
    (["--scenario", "{tmp}/broken.yaml"], "broken.yaml: not valid YAML"),
    (["--carriers", "a", "--listen", "tcp/127.0.0.1:7447"], "expected tls/HOST:PORT"),
], ids=["missing-scenario", "no-carriers", "broken-yaml", "plain-tcp-endpoint"])
def test_gen_certs_bad_input_is_one_line_and_exit_2(tmp_path, capsys, monkeypatch, argv, expected):
    monkeypatch.chdir(ROOT)
    (tmp_path / "no-carriers.yaml").write_text("name: x\nstages: 4\n")
    (tmp_path / "broken.yaml").write_text("name: [x\n")
    argv = [arg.replace("{tmp}", str(tmp_path)) for arg in argv]
    assert gen_certs.main(["--out", str(tmp_path / "certs"), *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and expected in err, err
    assert not (tmp_path / "certs").exists()


def test_gen_certs_writes_configs_for_a_scenario(tmp_path, capsys):
    assert gen_certs.main(["--out", str(tmp_path), "--scenario", str(TINY)]) == 0
    for name in ("ca.pem", "coordinator.pem", "coordinator.key", "carrier-a.pem", "carrier-b.key",
                 "coordinator.json5", "carrier-a.json5", "carrier-b.json5"):
        assert (tmp_path / name).is_file(), name
    assert (tmp_path / "carrier-a.key").stat().st_mode & 0o077 == 0  # private keys: owner only
    conf = zenoh.Config.from_file(str(tmp_path / "carrier-a.json5"))
    assert json.loads(conf.get_json("transport/link/tls"))["connect_certificate"] == str(tmp_path / "carrier-a.pem")


def test_gen_certs_modes_hold_whatever_the_umask_and_fix_an_existing_key(tmp_path, capsys):
    """Private keys and configs 0600, the folder 0700, certificates 0644, under umask 000, and an
    existing key left 0644 by an earlier run (or a copy) is brought back to 0600."""
    import os
    import stat

    out = tmp_path / "certs"
    out.mkdir(mode=0o777)
    (out / "carrier-a.key").write_text("old")
    os.chmod(out / "carrier-a.key", 0o644)
    old = os.umask(0)
    try:
        assert gen_certs.main(["--out", str(out), "--scenario", str(TINY)]) == 0
    finally:
        os.umask(old)
    mode = lambda p: stat.S_IMODE(p.stat().st_mode)  # noqa: E731
    assert mode(out) == 0o700
    for path in out.iterdir():
        expected = 0o644 if path.suffix == ".pem" else 0o600
        assert mode(path) == expected, (path.name, oct(mode(path)))
    assert (out / "carrier-a.key").read_text() != "old"


def test_gen_certs_without_cryptography_names_the_extra(tmp_path):
    """Without the cryptography package gen_certs exits 2 with one line naming the extra."""
    blocker = tmp_path / "block"
    blocker.mkdir()
    (blocker / "cryptography").mkdir()
    (blocker / "cryptography" / "__init__.py").write_text("raise ImportError('blocked for the test')\n")
    proc = subprocess.run([sys.executable, str(ROOT / "tools" / "gen_certs.py"), "--out", str(tmp_path / "c"),
                           "--carriers", "a"], capture_output=True, text=True, timeout=60,
                          env={**__import__("os").environ, "PYTHONPATH": str(blocker)})
    assert proc.returncode == 2 and proc.stderr.splitlines() == [
        f"error: tools/gen_certs.py needs the cryptography package: {gen_certs.INSTALL_HINT}"], proc.stderr
    assert "[security]" in proc.stderr and not (tmp_path / "c").exists()


@pytest.mark.parametrize("limited", [True, False], ids=["generated-limit", "control-no-limit"])
def test_a_10_mib_payload_is_dropped_at_the_first_hop(certs, limited):
    """The generated configs bound Zenoh's own message size (transport.link.rx.max_message_size,
    planner.limits.TRANSPORT_MAX_MESSAGE_BYTES): a 10 MiB put on carrier c0's own key, followed by
    a small marker, reaches neither the coordinator's subscriber nor carrier c1 (the coordinator's
    link drops it; it is never relayed), while the marker does. Control: with zenoh's default
    limit (1 GiB) the same payload is relayed in full."""
    from planner.limits import TRANSPORT_MAX_MESSAGE_BYTES

    port = free_port()
    coord_conf = gen_certs.coordinator_config(certs)
    sender_conf = carrier_conf(certs, certs.carriers["c0"])
    other_conf = carrier_conf(certs, certs.carriers["c1"])
    if limited:
        assert coord_conf["transport"]["link"]["rx"]["max_message_size"] == TRANSPORT_MAX_MESSAGE_BYTES
        sender_conf["transport"]["link"]["rx"] = dict(coord_conf["transport"]["link"]["rx"])
    else:
        del coord_conf["transport"]["link"]["rx"]
    big = bytes(10 * 1024 * 1024)
    key = keys.carrier_key(MISSION, "c0", "obs")
    with open_session(coord_conf, port, "listen") as coord:
        inbox = Inbox()
        coord.declare_subscriber(f"marsupial/{MISSION}/**", inbox)
        with open_session(sender_conf, port, "connect") as car, open_session(other_conf, port, "connect") as other:
            assert wait_connected(car, WAIT_S) and wait_connected(other, WAIT_S)
            other_inbox = Inbox()
            other.declare_subscriber(f"marsupial/{MISSION}/**", other_inbox)
            # c1's subscription has reached the coordinator (a fixed sleep was too short on a
            # loaded host): a probe is relayed to c1 before the payload is sent.
            deliver(car, other_inbox, [], (key, b"probe"))
            car.put(key, big, congestion_control=zenoh.CongestionControl.BLOCK)  # never dropped by the sender
            deliver(car, inbox, [], (key, b"marker"))
            assert other_inbox.wait_for((key, b"marker"))
            time.sleep(0.5)
            got = [len(p) for k, p in inbox.items + other_inbox.items if len(p) > 1024]
            if limited:
                assert got == [], got
            else:
                assert got and set(got) == {len(big)}, got


def test_acl_a_carrier_reads_only_what_the_protocol_needs(certs):
    """Least privilege for reads: carrier c1, subscribed to everything of the mission, receives
    the coordinator's Decision, c0's Observation and its own Accepted, but not c0's Hello, Bye,
    Pose, Accepted or Refusal (the coordinator's egress rules drop them)."""
    port = free_port()
    m = MISSION
    with open_session(gen_certs.coordinator_config(certs), port, "listen") as coord:
        with open_session(carrier_conf(certs, certs.carriers["c0"]), port, "connect") as c0, \
                open_session(carrier_conf(certs, certs.carriers["c1"]), port, "connect") as c1:
            assert wait_connected(c0, WAIT_S) and wait_connected(c1, WAIT_S)
            inbox = Inbox()
            c1.declare_subscriber(f"marsupial/{m}/**", inbox)
            time.sleep(0.5)
            hidden = [(keys.carrier_key(m, "c0", topic), b"c0 " + topic.encode()) for topic in ("hello", "bye", "pose")]
            for key, payload in hidden:
                c0.put(key, payload)
            coord.put(keys.accepted_key(m, "c0"), b"c0's answer")
            coord.put(keys.refusal_key(m, "c0"), b"c0's refusal")
            deliver(c0, inbox, [], (keys.carrier_key(m, "c0", "obs"), b"c0 obs"))
            deliver(coord, inbox, [], (keys.decision_key(m), b"decision"))
            deliver(coord, inbox, [], (keys.accepted_key(m, "c1"), b"c1's answer"))
            time.sleep(0.3)
            got = {k for k, _ in inbox.items}
            assert got == {keys.carrier_key(m, "c0", "obs"), keys.decision_key(m), keys.accepted_key(m, "c1")}, got
