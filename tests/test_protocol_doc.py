"""docs/protocol.md is enough to write a carrier: a carrier written here with plain zenoh and
msgpack (no wire/, no carriers/ code) takes part in a real mission next to a real carrier, and
the mission ends exactly as the offline planner's run."""
from __future__ import annotations

import hashlib
import json
import os
import queue
import re
import socket
import threading
import time
from dataclasses import fields

import msgpack
import numpy as np
import zenoh

import world
from fleet_helpers import ROOT, TINY, InProcessFleet, deployed_matrix, offline

PROTOCOL = (ROOT / "docs" / "protocol.md").read_text()


def foreign_carrier(endpoint: str, mission: str, cid: str, x_row, positions, passengers: int, result: dict,
                    scenario_path=TINY, seed: int = 7):
    """A carrier from the protocol document alone. ``x_row[j]`` is what it senses at stage j
    (NaN = not scheduled); ``positions[j]`` where it is. Its fingerprint it computes itself, as
    the page's section "Fingerprint" says, from the scenario file and the seed."""
    mine_fp = hashlib.sha256(f"marsupial-fleet/1 seed={seed}\n".encode() + scenario_path.read_bytes()).hexdigest()[:16]
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    prefix = f"marsupial/{mission}"
    mine = f"{prefix}/carrier/{cid}"
    inbox: "queue.Queue[tuple[str, bytes]]" = queue.Queue()
    deadline = time.monotonic() + 60
    while True:  # the coordinator may not listen yet: retry, as a client should
        try:
            session = zenoh.open(conf)
            break
        except zenoh.ZError:
            assert time.monotonic() < deadline, "no coordinator"
            time.sleep(0.2)
    token = session.liveliness().declare_token(f"{mine}/alive")
    subs = [session.declare_subscriber(f"{prefix}/coordinator/{topic}",
                                       lambda s, t=topic: inbox.put((t, s.payload.to_bytes())))
            for topic in ("decision", "end")]

    publishers = {}

    def put(topic, body):  # reliable puts: one declared publisher per key (docs/protocol.md, Conventions)
        if topic not in publishers:
            publishers[topic] = session.declare_publisher(
                f"{mine}/{topic}", reliability=zenoh.Reliability.RELIABLE,
                congestion_control=zenoh.CongestionControl.BLOCK)
        publishers[topic].put(msgpack.packb({"v": 1, "type": topic, "mission": mission, **body}))

    try:
        state = None
        deadline = time.monotonic() + 30
        while state is None and time.monotonic() < deadline:
            for reply in session.get(f"{prefix}/coordinator/state", timeout=2.0):
                if reply.ok is not None:
                    state = msgpack.unpackb(reply.ok.payload.to_bytes())
            time.sleep(0.05)
        assert state is not None and state["type"] == "state" and state["fingerprint"] == mine_fp
        left, deployments = passengers, []
        put("hello", {"carrier": cid, "pid": os.getpid(), "host": socket.gethostname(), "passengers_left": left,
                      "next_stage": state["next_stage"], "fingerprint": mine_fp})
        ended = False
        for j in range(state["next_stage"], state["stages"]):
            x = None if np.isnan(x_row[j]) else int(x_row[j])
            position = [float(v) for v in np.nan_to_num(positions[j])]
            put("obs", {"carrier": cid, "stage": j, "t": 5.0 * j, "x": x, "position": position,
                        "passengers_left": left, "trail": []})
            decision = None
            while decision is None and not ended:
                topic, payload = inbox.get(timeout=30)
                message = msgpack.unpackb(payload)
                if topic == "end":
                    ended = True
                elif message["stage"] == j:
                    decision = message
            if ended:
                break
            deploy = cid in decision["deploy"] and left > 0
            if deploy:
                left -= 1
                deployments.append(j)
            put("confirm", {"carrier": cid, "stage": j, "deployed": deploy, "status": "deployed" if deploy else "idle",
                            "position": position, "passengers_left": left})
        while not ended:
            ended = inbox.get(timeout=30)[0] == "end"
        put("bye", {"carrier": cid, "deployments": deployments, "rejected": {}, "reason": "end"})
        result["deployments"] = deployments
        time.sleep(0.2)
    finally:
        for entity in [*subs, *publishers.values(), token]:
            entity.undeclare()
        session.close()


def test_a_carrier_written_from_the_protocol_document(tmp_path):
    tiny = world.load_scenario(TINY)
    trace = world.simulate_mission(tiny)
    fleet = InProcessFleet(tiny, tmp_path)
    fleet.start_coordinator()
    fleet.start_carrier("b")
    ra = tiny.carrier_index("a")
    result: dict = {}
    thread = threading.Thread(target=foreign_carrier, daemon=True, args=(
        fleet.endpoint, fleet.coordinator.setup.mission, "a", trace.x[ra], trace.positions[ra],
        tiny.carriers[ra].passengers, result))
    thread.start()
    summary = fleet.join()
    thread.join(30)
    reference, x = offline(tiny)
    assert summary["rejected"]["coordinator"] == {}
    np.testing.assert_array_equal(np.array(summary["observations"], dtype=float), x)
    np.testing.assert_array_equal(deployed_matrix(summary, tiny), reference.deployed)
    assert result["deployments"] == [int(j) for j in np.flatnonzero(reference.deployed[ra])]


def test_the_fingerprint_worked_example():
    """The algorithm as the page states it, run on the page's own example, gives the page's
    value, and the code agrees (for the file's seed and for another one)."""
    from wire.messages import scenario_fingerprint

    m = re.search(r"\$ \{ printf '(.*?)\\n'; cat (\S+); \} \| sha256sum \| cut -c1-16\n\s+([0-9a-f]{16})", PROTOCOL)
    assert m, "worked example not found"
    header, path, value = m.groups()
    data = header.encode() + b"\n" + (ROOT / path).read_bytes()
    assert hashlib.sha256(data).hexdigest()[:16] == value
    tiny = world.load_scenario(ROOT / path)
    assert header == f"marsupial-fleet/1 seed={tiny.seed}"
    assert scenario_fingerprint(tiny) == value
    other = hashlib.sha256(f"marsupial-fleet/1 seed={tiny.seed + 1}\n".encode() + (ROOT / path).read_bytes())
    assert scenario_fingerprint(tiny.with_seed(tiny.seed + 1)) == other.hexdigest()[:16] != value


def _documented_fields(type_name: str) -> set[str]:
    section = PROTOCOL.split(f'(`type: "{type_name}"`')[1].split("\n### ")[0].split("\n## ")[0]
    return set(re.findall(r"^\| `(\w+)` \|", section, re.M))


def test_every_message_field_is_documented():
    from wire.messages import MESSAGE_TYPES

    for type_name, cls in MESSAGE_TYPES.items():
        in_code = {f.name for f in fields(cls)} - {"mission", "v"}
        assert _documented_fields(type_name) == in_code, type_name


def _field_rows(section: str) -> dict[str, list[str]]:
    """field -> its cells (field, type, since, presence, default, meaning) in a field table."""
    rows = {}
    for line in section.splitlines():
        m = re.match(r"^\| `(\w+)` \|", line)
        if m:
            rows[m.group(1)] = [cell.strip() for cell in line.strip().strip("|").split("|")]
    return rows


def test_field_tables_say_since_and_presence_as_the_code_does():
    """Each field table's columns (field, type, since, presence, default, meaning): `since` is the
    revision the code marks (a message type's own revision for its required fields), `optional`
    exactly the fields the codec takes as absent with a default, a required field `nullable`
    exactly when it takes nil as a value, and every optional field names its default."""
    from wire.messages import MESSAGE_TYPES, CarrierState, ProtocolError

    sections = {name: PROTOCOL.split(f'(`type: "{name}"`')[1].split("\n### ")[0].split("\n## ")[0]
                for name in MESSAGE_TYPES}
    sections["carrier-state"] = PROTOCOL.split("### CarrierState")[1].split("\n### ")[0].split("\n## ")[0]
    classes = {**MESSAGE_TYPES, "carrier-state": CarrierState}
    for name, cls in classes.items():
        rows = _field_rows(sections[name])
        assert [c for c in rows.values() if len(c) != 6] == [], name
        in_code = [f.name for f in fields(cls) if f.name not in ("mission", "v")]
        assert [r for r in rows if r in in_code] == in_code, name  # the codec checks fields in this order
        for f in fields(cls):
            if f.name in ("mission", "v"):
                continue
            cells = rows[f.name]
            since = max(f.metadata.get("since", 1), getattr(cls, "SINCE", 1))
            assert cells[2] == str(since), (name, f.name, cells[2], since)
            optional = "absent" in f.metadata
            assert cells[3].startswith("optional") == optional, (name, f.name, cells[3])
            assert cells[3].startswith("required") == (not optional), (name, f.name, cells[3])
            assert (cells[4] != "—") == optional, (name, f.name, cells[4])
            check = f.metadata["check"]
            try:
                check(None, f.name)
                takes_nil = True
            except ProtocolError:
                takes_nil = False
            except Exception:  # a nested map's validator: nil is not a map
                takes_nil = False
            if not optional:  # an optional field's nil is its absence ([P-1.3]), nullable or not
                assert ("nullable" in cells[3]) == takes_nil, (name, f.name, cells[3])


def test_every_rejection_reason_is_documented():
    from wire.messages import REASONS

    table = PROTOCOL.split("### Rejections: the reason codes")[1].split("\n#")[0]
    documented = set(re.findall(r"^\| `([a-z-]+)` \|", table, re.M))
    used = set(REASONS)
    for path in [*(ROOT / "mission").glob("*.py"), *(ROOT / "wire").glob("*.py"),
                 ROOT / "coordinator" / "node.py", ROOT / "carriers" / "node.py"]:
        used |= set(re.findall(r"(?:Reject|ProtocolError)\(\s*\"([a-z-]+)\"", path.read_text()))
    assert used - documented == set()


def test_hello_is_required_and_a_refused_hello_is_answered(tmp_path):
    """From the page alone: a Hello with another fingerprint is answered by a Refusal on
    coordinator/refusal/<id>; a later bad Hello does not undo an accepted one; an Observation
    without a Hello is rejected (no-hello)."""
    tiny = world.load_scenario(TINY)
    fleet = InProcessFleet(tiny, tmp_path, planner="ssap", join_timeout_s=30.0)
    fleet.start_coordinator()
    m = fleet.coordinator.setup.mission
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([fleet.endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    deadline = time.monotonic() + 60
    while True:
        try:
            session = zenoh.open(conf)
            break
        except zenoh.ZError:
            assert time.monotonic() < deadline, "no coordinator"
            time.sleep(0.2)
    refusals: "queue.Queue[dict]" = queue.Queue()
    sub = session.declare_subscriber(f"marsupial/{m}/coordinator/refusal/a",
                                     lambda s: refusals.put(msgpack.unpackb(s.payload.to_bytes())))
    token = session.liveliness().declare_token(f"marsupial/{m}/carrier/a/alive")
    pubs = {topic: session.declare_publisher(f"marsupial/{m}/carrier/{cid}/{topic}",
                                             reliability=zenoh.Reliability.RELIABLE,
                                             congestion_control=zenoh.CongestionControl.BLOCK)
            for cid, topic in (("a", "hello"), ("b", "obs"))}

    def hello(fingerprint):
        pubs["hello"].put(msgpack.packb({"v": 1, "type": "hello", "mission": m, "carrier": "a", "pid": os.getpid(),
                                         "host": "foreign", "passengers_left": 2, "next_stage": 0,
                                         "fingerprint": fingerprint}))

    try:
        state = None
        while state is None:
            assert time.monotonic() < deadline, "no State"
            for reply in session.get(f"marsupial/{m}/coordinator/state", timeout=2.0):
                if reply.ok is not None:
                    state = msgpack.unpackb(reply.ok.payload.to_bytes())
        hello("0000000000000000")
        refusal = refusals.get(timeout=10)
        assert refusal == {"v": 1, "type": "refusal", "mission": m, "carrier": "a", "reason": "world-mismatch",
                           "fingerprint": "0000000000000000", "expected": state["fingerprint"]}
        hello(state["fingerprint"])
        while "a" not in fleet.coordinator.state.accepted:
            assert time.monotonic() < deadline
            time.sleep(0.05)
        hello("1111111111111111")
        assert refusals.get(timeout=10)["fingerprint"] == "1111111111111111"
        pubs["obs"].put(msgpack.packb({"v": 1, "type": "obs", "mission": m, "carrier": "b", "stage": 0, "t": 0.0,
                                       "x": None, "position": [0.0, 0.0], "passengers_left": 1, "trail": []}))
        while fleet.coordinator.node.rejected.get("no-hello", 0) < 1:
            assert time.monotonic() < deadline, dict(fleet.coordinator.node.rejected)
            time.sleep(0.05)
        assert fleet.coordinator.state.accepted["a"].host == "foreign"  # the later bad Hello undid nothing
        assert fleet.coordinator.state.refused == {}
    finally:
        fleet.coordinator.stop()
        for entity in [sub, token, *pubs.values()]:
            entity.undeclare()
        session.close()
    summary = fleet.join()
    assert summary["end_reason"] == "stopped"
    assert summary["rejected"]["coordinator"]["world-mismatch"] == 2


def test_every_carrier_key_is_in_the_key_table():
    from wire import keys

    table = PROTOCOL.split("## Key expressions")[1].split("\n## ")[0]
    for topic in keys.CARRIER_TOPICS:
        assert f"| `marsupial/<m>/carrier/<id>/{topic}` |" in table, topic


def test_a_pose_written_from_the_page_decodes():
    """Pose from the page alone (plain msgpack): the project's decoder takes it as it is, and a
    heading outside -pi..pi is out-of-range."""
    from wire.messages import Pose, ProtocolError, decode

    body = {"v": 1, "type": "pose", "mission": "tiny", "carrier": "a", "t": 3.0, "position": [10.0, 20.0],
            "heading": 1.5707963, "passengers_left": 2}
    pose = decode(msgpack.packb(body))
    assert isinstance(pose, Pose) and pose.position == (10.0, 20.0) and pose.passengers_left == 2
    try:
        decode(msgpack.packb(dict(body, heading=4.0)))
        raise AssertionError("accepted a heading of 4 rad")
    except ProtocolError as exc:
        assert exc.reason == "out-of-range"


def test_every_citation_of_a_section_resolves():
    """Code and docs cite sections of this page by name (`docs/protocol.md, "Stage handshake"`):
    each name is in one of the page's headings (ignoring case), so a reader finds it."""
    headings = [line.lower() for line in PROTOCOL.splitlines() if line.startswith("#")]
    citing = [p for p in ROOT.rglob("*") if p.suffix in (".py", ".md") and p.is_file()
              and not {".venv", "fixtures", "journal", ".git"} & set(p.relative_to(ROOT).parts)]
    unresolved = []
    for path in citing:
        for m in re.finditer(r'docs/protocol\.md,\s+((?:"[^"]+"(?:,\s*|\s+and\s+)?)+)', path.read_text(errors="replace")):
            for name in re.findall(r'"([^"]+)"', m.group(1)):
                if not any(name.lower() in h for h in headings):
                    unresolved.append((str(path.relative_to(ROOT)), name))
    assert unresolved == []


def test_every_role_rule_has_a_row_and_every_row_real_tests():
    """docs/security.md's "Checks by role" table and docs/protocol.md's section 13 agree: each
    [P-13.n] rule is one row, each row cites one, and every test a row names exists under tests/
    (the first of each row opens a real Zenoh session: it is a fleet, security or operator test)."""
    security = (ROOT / "docs" / "security.md").read_text()
    section = PROTOCOL[PROTOCOL.index("## 13. Authority by role"):PROTOCOL.index("## Example")]
    rules = re.findall(r"\*\*\[(P-13\.\d+)\]", section)
    assert rules == [f"P-13.{n}" for n in range(1, len(rules) + 1)] and len(rules) >= 7
    table = security[security.index("| kind | who may send (key) |"):]
    rows = [line for line in table.split("\n\n")[0].splitlines()[2:]]
    cited = [re.findall(r"\[(P-13\.\d+)\]", row.split("|")[5]) for row in rows]
    assert cited == [[r] for r in rules], cited
    for row in rows:
        tests = re.findall(r"`(test_\w+\.py)::(test_\w+)`", row.split("|")[6])
        assert tests, row
        for file, name in tests:
            text = (ROOT / "tests" / file).read_text()
            assert re.search(rf"^def {name}\(", text, re.M), (file, name)
        assert tests[0][0] in {"test_authority.py", "test_security.py", "test_operator_key.py", "test_split_brain.py"}
