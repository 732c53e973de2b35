"""Every Hello is answered and every rejection a carrier causes is visible to it
(docs/protocol.md, "Hello", "Refusal", "Accepted", "CarrierState"), and the smaller rules of the
stranger review: a Bye needs a Hello, a Confirm's claim is checked as an Own's, ids, versions."""
from __future__ import annotations

import json
import os
import queue
import re
import time

import msgpack
import pytest
import zenoh

import world
from fleet_helpers import ROOT, TINY, InProcessFleet
from mission import events as ev
from mission import state as ms
from wire import keys
from wire import messages as wm

PROTOCOL = (ROOT / "docs" / "protocol.md").read_text()
SPEC = ms.MissionSpec.build(("a", "b"), [[True, False], [True, True]], (1, 1), (0.0, 5.0), "f")


def _hello(cid="a", next_stage=0, fingerprint="f", revision=wm.REVISION):
    return ev.Hello(cid, 1, "h", 1, next_stage, fingerprint, 0.0, revision)


def _effects(state, event, kind):
    return [e for e in ms.step(state, event)[1] if isinstance(e, kind)]


def test_every_hello_gets_an_answer_from_the_state_machine():
    s = ms.initial(SPEC)
    assert [(e.carrier, e.revision) for e in _effects(s, _hello(), ms.Accept)] == [("a", wm.REVISION)]
    assert [e.reason for e in _effects(s, _hello(fingerprint="x"), ms.Refuse)] == ["world-mismatch"]
    assert [e.reason for e in _effects(s, _hello("zz"), ms.Refuse)] == ["unknown-carrier"]
    refused = _effects(s, _hello(next_stage=3), ms.Refuse)
    assert [e.reason for e in refused] == ["out-of-range"] and "next_stage 3 > 2" in refused[0].detail
    assert ms.step(s, _hello(next_stage=2))[0].accepted["a"].next_stage == 2  # N itself: all decided


def test_a_bye_needs_a_hello_and_a_confirm_is_checked_like_an_own():
    s = ms.initial(SPEC)
    bye = ev.Bye("a", (), (), "end", 1.0)
    assert [e.reason for e in _effects(s, bye, ms.Reject)] == ["no-hello"]
    s, _ = ms.step(s, _hello())
    assert _effects(s, bye, ms.Reject) == []
    s, _ = ms.step(s, ev.LivelinessChanged("a", True))
    s, _ = ms.step(s, ev.Decided(0, ("a",), 1.0))
    s, _ = ms.step(s, ev.Decided(1, (), 1.0))
    claim = dict(carrier="a", stage=1, deployed=True, position=(0.0, 0.0), passengers_left=0)
    assert [e.reason for e in _effects(s, ev.Confirmed(status="deployed", **claim), ms.Reject)] == ["out-of-range"]
    assert [e.reason for e in _effects(s, ev.Accounted(t=5.0, x=None, **claim), ms.Reject)] == ["out-of-range"]


def test_refusals_are_written_for_the_refused_carriers_revision():
    new = wm.refusal("m", "a", "out-of-range", "f" * 80, "e", "x" * 300, wm.REVISION)
    assert (new.reason, len(new.fingerprint), len(new.detail)) == ("out-of-range", 64, 200)
    old = wm.refusal("m", "a", "out-of-range", "f", "e", "bad epoch", 1)
    assert (old.reason, old.detail) == ("world-mismatch", "")
    assert msgpack.unpackb(wm.encode(old, 1)) == {"v": 1, "type": "refusal", "mission": "m", "carrier": "a",
                                                   "reason": "world-mismatch", "fingerprint": "f", "expected": "e"}
    with pytest.raises(ValueError):
        wm.encode(new, 2)  # a reason revision 2 does not have is never sent to it
    with pytest.raises(wm.ProtocolError) as info:
        wm.decode(wm.encode(new), revision=2)
    assert info.value.reason in ("out-of-range", "unknown-field")
    with pytest.raises(ValueError):
        wm.encode(wm.Accepted("m", "a", "f", 0, 0, 3), 2)
    assert wm.announced(msgpack.packb({"revision": 3, "fingerprint": "abc", "epoch": 0})) == (3, "abc")
    assert wm.announced(msgpack.packb({"revision": 99})) == (wm.REVISION, "")
    assert wm.announced(b"\xc1") == (1, "") and wm.announced(msgpack.packb([1])) == (1, "")


@pytest.mark.parametrize("body, reason", [
    ({"v": 1.0}, "version"), ({"v": True}, "version"), ({"v": 2}, "version"),
    ({"type": None}, "missing-field"),  # nil type is absent type ([P-1.3])
])
def test_envelope_values(body, reason):
    raw = {"v": 1, "type": "end", "mission": "m", "stages": 1, "reason": "complete", **body}
    with pytest.raises(wm.ProtocolError) as info:
        wm.decode(msgpack.packb(raw))
    assert info.value.reason == reason


def test_a_message_without_type_is_missing_a_field():
    with pytest.raises(wm.ProtocolError) as info:
        wm.decode(msgpack.packb({"v": 1, "mission": "m", "stages": 1, "reason": "complete"}))
    assert info.value.reason == "missing-field"


@pytest.mark.parametrize("value", ["a\n", "a\nb", "", "-a", "a" * 65, "a b"])
def test_ids_are_whole_strings(value):
    assert not keys.ID_PATTERN.match(value)
    with pytest.raises(ValueError):
        keys.check_id(value)


def test_carrier_state_fields_are_documented():
    from dataclasses import fields

    table = PROTOCOL.split("### CarrierState")[1].split("\n## ")[0].split("\n### ")[0]
    assert set(re.findall(r"^\| `(\w+)` \|", table, re.M)) == {f.name for f in fields(wm.CarrierState)}


def test_every_refusal_reason_is_documented():
    table = PROTOCOL.split("Every reason a Hello is refused for")[1].split("\n\n", 2)[1]
    documented = set(re.findall(r"`([a-z-]+)`", "\n".join(line.split("|")[1] for line in table.splitlines()[2:])))
    assert documented == set(wm.REFUSAL_REASONS)


# --------------------------------------------------------------------------- over the wire

class Client:
    """A bare zenoh session speaking as carrier ids of one mission (plain msgpack)."""

    def __init__(self, endpoint: str, mission: str):
        conf = zenoh.Config()
        conf.insert_json5("mode", '"client"')
        conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
        conf.insert_json5("scouting/multicast/enabled", "false")
        deadline = time.monotonic() + 60
        while True:
            try:
                self.session = zenoh.open(conf)
                break
            except zenoh.ZError:
                assert time.monotonic() < deadline, "no coordinator"
                time.sleep(0.2)
        self.m = mission
        self.answers: "queue.Queue[tuple[str, dict]]" = queue.Queue()
        self.entities = [self.session.declare_subscriber(
            f"marsupial/{mission}/coordinator/{kind}/*",
            lambda s, k=kind: self.answers.put((k, msgpack.unpackb(s.payload.to_bytes()))))
            for kind in ("refusal", "accepted")]
        self.pubs: dict = {}

    def put(self, cid: str, topic: str, body) -> None:
        key = f"marsupial/{self.m}/carrier/{cid}/{topic}"
        if key not in self.pubs:
            self.pubs[key] = self.session.declare_publisher(key, reliability=zenoh.Reliability.RELIABLE,
                                                            congestion_control=zenoh.CongestionControl.BLOCK)
            self.entities.append(self.pubs[key])
        self.pubs[key].put(body if isinstance(body, bytes) else msgpack.packb(body))

    def answer(self, timeout_s: float = 10.0) -> tuple[str, dict]:
        return self.answers.get(timeout=timeout_s)

    def state(self, cid: str, revision: int | None) -> dict:
        selector = f"marsupial/{self.m}/coordinator/state?carrier={cid}" + (f";revision={revision}" if revision else "")
        for _ in range(50):
            for reply in self.session.get(selector, timeout=2.0):
                if reply.ok is not None:
                    return msgpack.unpackb(reply.ok.payload.to_bytes())
            time.sleep(0.1)
        raise AssertionError("no State")

    def close(self):
        for entity in self.entities:
            entity.undeclare()
        self.session.close()


def test_every_hello_is_answered_over_the_wire(tmp_path):
    """A coordinator and a bare client: a valid Hello of revision 3 gets Accepted, a bad one a
    Refusal with the reason, a Hello of no revision a world-mismatch Refusal; the carrier's
    later rejections and its refusal are in its State."""
    tiny = world.load_scenario(TINY)
    fleet = InProcessFleet(tiny, tmp_path, planner="ssap", join_timeout_s=30.0)
    fleet.start_coordinator()
    m = fleet.coordinator.setup.mission
    client = Client(fleet.endpoint, m)
    try:
        fp = client.state("a", None)["fingerprint"]
        assert "revision" not in client.state("a", None) and client.state("a", 3)["revision"] == wm.REVISION
        hello = {"v": 1, "type": "hello", "mission": m, "carrier": "a", "pid": os.getpid(), "host": "h",
                 "passengers_left": 2, "next_stage": 0, "fingerprint": fp, "revision": 3}
        cases = [
            ("a", dict(hello, epoch=0), "out-of-range"),
            ("a", dict(hello, next_stage=99), "out-of-range"),
            ("a", dict(hello, mission="other"), "wrong-mission"),
            ("a", dict(hello, carrier="b"), "key-mismatch"),
            ("zz", dict(hello, carrier="zz"), "unknown-carrier"),
            ("a", dict(hello, colour="red"), "unknown-field"),
            ("a", {k: v for k, v in hello.items() if k != "pid"}, "missing-field"),
        ]
        for cid, body, reason in cases:
            client.put(cid, "hello", body)
            kind, answer = client.answer()
            assert (kind, answer["reason"], answer["carrier"]) == ("refusal", reason, cid), (body, answer)
            assert answer["detail"] and answer["expected"] == fp
        state = client.state("a", 3)["carriers"]["a"]
        assert state["refused"] == "unknown-field" or state["refused"] == "missing-field"
        assert state["rejected"]["out-of-range"] == 2 and "refused" not in client.state("a", None)["carriers"]["a"]
        old = {k: v for k, v in hello.items() if k != "revision"}
        client.put("b", "hello", dict(old, next_stage=99, carrier="b"))  # announces no revision
        kind, answer = client.answer()
        assert kind == "refusal" and answer["reason"] == "world-mismatch" and "detail" not in answer
        client.put("a", "hello", hello)
        kind, answer = client.answer()
        assert kind == "accepted" and answer == {"v": 1, "type": "accepted", "mission": m, "carrier": "a",
                                                 "fingerprint": fp, "next_stage": 0, "collecting": 0,
                                                 "revision": wm.REVISION}
        client.put("a", "obs", {"v": 1, "type": "obs", "mission": m, "carrier": "a", "stage": 3, "t": 15.0, "x": 1,
                                "position": [0.0, 0.0], "passengers_left": 2, "trail": []})
        deadline = time.monotonic() + 10
        while client.state("a", 3)["carriers"]["a"].get("rejected", {}).get("future-stage") != 1:
            assert time.monotonic() < deadline, client.state("a", 3)
            time.sleep(0.1)
        assert client.state("a", 3)["carriers"]["a"].get("refused") is None
        client.put("a", "hello", old)  # a Hello of no revision is accepted and not answered
        with pytest.raises(queue.Empty):
            client.answer(1.0)
    finally:
        fleet.coordinator.stop()
        client.close()
    fleet.join()


def test_a_state_query_hears_every_coordinator():
    """Two queryables on the State key (a split brain): the query gets both replies (target ALL,
    consolidation NONE: docs/protocol.md, "State")."""
    from wire.transport import Node
    from wire.zconfig import free_port, make_config

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    nodes = [Node(make_config("router", [endpoint]))]
    try:
        for epoch in (1, 2):
            node = Node(make_config("client", [], [endpoint]))
            nodes.append(node)
            node.serve(keys.state_key("m"), lambda params, e=epoch: msgpack.packb({"epoch": e}))
        asker = Node(make_config("client", [], [endpoint]))
        nodes.append(asker)
        deadline = time.monotonic() + 20
        replies = []
        while len(replies) < 2 and time.monotonic() < deadline:
            replies = asker.query(keys.state_selector("m", "a", wm.REVISION), timeout_s=2.0)
        assert sorted(msgpack.unpackb(r)["epoch"] for r in replies) == [1, 2]
    finally:
        for node in reversed(nodes):
            node.close(3.0)


@pytest.mark.parametrize("name", ["tiny", "six_carriers", "urban_alpha"])
def test_the_schedule_as_the_page_states_it(name):
    """docs/protocol.md, "Where observations come from": t_j, N and who is scheduled, computed from
    the scenario file as the page says, are the project's; tools.sensed gives the world's x."""
    import math

    import numpy as np
    import yaml

    from tools.sensed import sensed

    path = ROOT / "scenarios" / f"{name}.yaml"
    raw = yaml.safe_load(path.read_text())
    times = [raw.get("first_stage_time", 0.0) + j * raw["stage_interval"] for j in range(raw["stages"])]
    scheduled = []
    for c in raw["carriers"]:
        length = sum(math.dist(a, b) for a, b in zip(c["waypoints"], c["waypoints"][1:]))
        stop = c.get("stop_time", c["start_time"] + length / c["speed"])
        scheduled.append([c["start_time"] <= t <= stop for t in times])
    scenario = world.load_scenario(path)
    assert np.allclose(times, scenario.stage_times())
    assert (np.array(scheduled) == scenario.valid()).all()
    if name == "tiny":
        doc = sensed(scenario, "a")
        assert doc["x"] == [None if np.isnan(v) else int(v) for v in world.observe_all(scenario)[0]]
        assert doc["scheduled"] == scheduled[0] and doc["fingerprint"] == wm.scenario_fingerprint(scenario)
