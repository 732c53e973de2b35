"""The wire: key layout, message round trips, and explicit rejection of every kind of bad payload."""
from __future__ import annotations

import json

import msgpack
import pytest

from wire import keys, zconfig
from wire.messages import (
    MAX_PAYLOAD_BYTES, PROTOCOL_VERSION, Bye, CarrierState, Confirm, Decision, End, Hello,
    Observation, ProtocolError, Refusal, State, _to_wire, decode, encode,
)

M = "tiny"

SAMPLES = {
    "hello": Hello(M, "a", 1234, "host-1", 3, 0, "0123456789abcdef"),
    "obs": Observation(M, "a", 2, 10.0, 4, (1.5, -2.0), 3, ((0.0, 0.0), (1.0, 1.0))),
    "obs-empty": Observation(M, "b", 0, 0.0, None, (0.0, 0.0), 1, ()),
    "decision": Decision(M, 3, 15.0, ("a", "b"), 12.5),
    "decision-none": Decision(M, 0, 0.0, (), 0.0),
    "confirm": Confirm(M, "a", 3, True, "deployed", (3.0, 4.0), 2),
    "end": End(M, 4, "complete"),
    "refusal": Refusal(M, "a", "world-mismatch", "fedcba9876543210", "0123456789abcdef"),
    "bye": Bye(M, "a", (0, 3), (("duplicate", 2), ("malformed", 1)), "end"),
    "state": State(mission=M, next_stage=2, stages=4, fingerprint="ab", ended=False,
                   carriers=(("a", CarrierState(1, (0,), True)), ("b", CarrierState(1, (), False))),
                   last_decision=Decision(M, 1, 5.0, ("a",), 1.0)),
    "state-empty": State(mission=M, next_stage=0, stages=4, fingerprint="ab", ended=False, carriers=(),
                         last_decision=None),
}


@pytest.mark.parametrize("name", sorted(SAMPLES))
def test_round_trip(name):
    message = SAMPLES[name]
    data = encode(message)
    assert isinstance(data, bytes) and len(data) < 1024
    back = decode(data)
    assert back == message and type(back) is type(message)
    raw = msgpack.unpackb(data)
    assert raw["v"] == PROTOCOL_VERSION and raw["type"] == type(message).TYPE and raw["mission"] == M


def _raw(name: str) -> dict:
    return _to_wire(SAMPLES[name])


def _pack(obj) -> bytes:
    return msgpack.packb(obj, use_bin_type=True)


def _reason(data: bytes, expected=None) -> str:
    with pytest.raises(ProtocolError) as info:
        decode(data, expected)
    return info.value.reason


@pytest.mark.parametrize("data, reason", [
    (b"", "malformed"),
    (b"\xc1\xc1\xc1", "malformed"),
    (b"\x92\x01", "malformed"),                      # truncated array
    (_pack([1, 2, 3]), "not-a-map"),
    (_pack("hello"), "not-a-map"),
    (_pack({"type": "obs"}), "missing-field"),       # no version
    (b"x" * (MAX_PAYLOAD_BYTES + 1), "oversized"),
], ids=["empty", "garbage", "truncated", "array", "string", "no-version", "oversized"])
def test_rejects_bad_bytes(data, reason):
    assert _reason(data) == reason


@pytest.mark.parametrize("version", [0, 2, 99, "1", 1.5, True, None])
def test_rejects_unknown_versions(version):
    raw = _raw("obs")
    raw["v"] = version
    assert _reason(_pack(raw)) in ("version", "missing-field")


def test_rejects_unknown_type_and_unexpected_type():
    raw = _raw("obs")
    raw["type"] = "teleport"
    assert _reason(_pack(raw)) == "unknown-type"
    assert _reason(encode(SAMPLES["decision"]), Observation) == "unknown-type"
    assert isinstance(decode(encode(SAMPLES["decision"]), (Observation, Decision)), Decision)


@pytest.mark.parametrize("name, field, value, reason", [
    ("obs", "stage", "2", "wrong-type"),
    ("obs", "stage", -1, "out-of-range"),
    ("obs", "stage", 2.0, "wrong-type"),
    ("obs", "stage", True, "wrong-type"),
    ("obs", "x", -3, "out-of-range"),
    ("obs", "x", 2.5, "wrong-type"),
    ("obs", "t", float("nan"), "out-of-range"),
    ("obs", "t", float("inf"), "out-of-range"),
    ("obs", "position", [1.0], "wrong-type"),
    ("obs", "position", [1.0, "y"], "wrong-type"),
    ("obs", "position", [1e12, 0.0], "out-of-range"),
    ("obs", "trail", [[0.0, 0.0]] * 600, "out-of-range"),
    ("obs", "carrier", "a/b", "out-of-range"),
    ("obs", "carrier", "*", "out-of-range"),
    ("obs", "carrier", 7, "wrong-type"),
    ("obs", "mission", "", "out-of-range"),
    ("obs", "passengers_left", -1, "out-of-range"),
    ("decision", "deploy", ["a", "a"], "out-of-range"),
    ("decision", "deploy", "a", "wrong-type"),
    ("decision", "planning_ms", -1.0, "out-of-range"),
    ("confirm", "deployed", 1, "wrong-type"),
    ("confirm", "status", "teleported", "out-of-range"),
    ("hello", "host", "h" * 300, "out-of-range"),
    ("bye", "rejected", {"x": -1}, "out-of-range"),
    ("bye", "rejected", [1, 2], "wrong-type"),
    ("state", "carriers", {"a": {"passengers_left": 1}}, "missing-field"),
    ("state", "last_decision", {"stage": 1}, "missing-field"),
])
def test_rejects_bad_fields(name, field, value, reason):
    raw = _raw(name)
    raw[field] = value
    assert _reason(_pack(raw)) == reason


@pytest.mark.parametrize("name", ["obs", "decision", "confirm", "hello", "state"])
def test_rejects_missing_and_unknown_fields(name):
    from dataclasses import MISSING, fields

    raw = _raw(name)
    optional = {f.name: f.default for f in fields(type(SAMPLES[name])) if f.default is not MISSING and f.name != "v"}
    for field in [k for k in raw if k not in ("v", "type")]:
        partial = {k: v for k, v in raw.items() if k != field}
        if field in optional:  # fields added later are optional: absent = the default
            assert getattr(decode(_pack(partial)), field) == optional[field], field
        else:
            assert _reason(_pack(partial)) == "missing-field", field
    assert _reason(_pack({**raw, "extra": 1})) == "unknown-field"


def test_decision_and_confirm_name_the_passenger():
    """Passenger types: a Decision names the passenger of each deploying carrier (parallel to
    ``deploy``), a Confirm the passenger released; both round-trip, and a Decision whose list is
    not parallel to ``deploy`` is refused."""
    d = Decision(M, 3, 15.0, ("a", "b"), 12.5, passengers=(2, 0))
    back = decode(encode(d))
    assert back == d and back.passenger_of("a") == 2 and back.passenger_of("b") == 0
    assert back.passenger_of("c") is None and Decision(M, 3, 15.0, ("a",), 1.0).passenger_of("a") is None
    c = Confirm(M, "a", 3, True, "deployed", (3.0, 4.0), 2, 1)
    assert decode(encode(c)) == c and decode(encode(c)).passenger == 1
    bad = {**_to_wire(d), "passengers": [1]}
    assert _reason(_pack(bad)) == "out-of-range"
    assert _reason(_pack({**_to_wire(c), "passenger": -1})) == "out-of-range"


def test_epoch_is_optional_absent_means_1_and_left_out_when_1():
    """docs/protocol.md, "Epochs" and "Compatibility": epoch 1 is not on the wire (the bytes of
    a mission without takeover are unchanged), any other epoch is, and a receiver reads an
    absent epoch as 1 and an explicit 1 as 1."""
    assert "epoch" not in msgpack.unpackb(encode(SAMPLES["decision"]))
    assert "epoch" not in msgpack.unpackb(encode(SAMPLES["state"]))
    second = Decision(M, 3, 15.0, ("a",), 12.5, epoch=2)
    assert msgpack.unpackb(encode(second))["epoch"] == 2 and decode(encode(second)) == second
    state = State(mission=M, next_stage=4, stages=4, fingerprint="ab", ended=True, carriers=(),
                  last_decision=second, epoch=2)
    raw = msgpack.unpackb(encode(state))
    assert raw["epoch"] == 2 and raw["last_decision"]["epoch"] == 2 and decode(encode(state)) == state
    assert decode(_pack({**_raw("decision"), "epoch": 1})).epoch == 1
    for value, reason in ((0, "out-of-range"), (-1, "out-of-range"), (2**31, "out-of-range"), ("2", "wrong-type"),
                          (True, "wrong-type")):
        assert _reason(_pack({**_raw("decision"), "epoch": value})) == reason, value
        assert _reason(_pack({**_raw("state"), "epoch": value})) == reason, value
    # [P-1.3] nil in an optional field that is not nullable is read as absent: epoch 1.
    assert decode(_pack({**_raw("decision"), "epoch": None})).epoch == 1
    assert decode(_pack({**_raw("state"), "epoch": None})).epoch == 1


def test_encode_refuses_what_decode_would_reject():
    with pytest.raises(ProtocolError):
        encode(Observation(M, "a", -1, 0.0, 1, (0.0, 0.0), 1, ()))
    with pytest.raises(ProtocolError):
        encode(Observation(M, "a", 0, 0.0, 1, (0.0, 0.0), 1, ((0.0, 0.0),) * 5000))


def test_decode_never_raises_anything_else():
    import numpy as np

    rng = np.random.default_rng(0)
    good = [encode(m) for m in SAMPLES.values()]
    for _ in range(3000):
        base = bytearray(good[int(rng.integers(len(good)))])
        for _ in range(int(rng.integers(1, 4))):
            base[int(rng.integers(len(base)))] = int(rng.integers(256))
        try:
            decode(bytes(base))
        except ProtocolError:
            pass


def test_key_layout_puts_each_publisher_under_its_own_subtree():
    carrier_keys = [keys.carrier_key(M, "a", t) for t in keys.CARRIER_TOPICS] + [keys.carrier_alive(M, "a")]
    assert all(k.startswith("marsupial/tiny/carrier/a/") for k in carrier_keys)
    coordinator_keys = [keys.decision_key(M), keys.end_key(M), keys.state_key(M), keys.coordinator_alive(M)]
    assert all(k.startswith("marsupial/tiny/coordinator/") for k in coordinator_keys)
    assert keys.parse_carrier_key(M, "marsupial/tiny/carrier/a/obs") == ("a", "obs")
    assert keys.parse_carrier_key(M, "marsupial/other/carrier/a/obs") is None
    assert keys.parse_carrier_key(M, "marsupial/tiny/carrier/a/b/obs") is None
    with pytest.raises(ValueError):
        keys.carrier_key(M, "a/**", "obs")
    assert keys.mission_id_from_name("six carriers: demo!") == "six-carriers-demo"


def test_zenoh_config_flags_override_the_file(tmp_path):
    path = tmp_path / "z.json5"
    path.write_text('{ mode: "peer", listen: { endpoints: ["tcp/127.0.0.1:1111"] }, // comment\n }')
    conf = zconfig.make_config(None, [], [], str(path))
    assert json.loads(conf.get_json("listen/endpoints")) == ["tcp/127.0.0.1:1111"]
    assert json.loads(conf.get_json("scouting/multicast/enabled")) is False
    conf = zconfig.make_config("client", [], ["tcp/10.0.0.1:7447"], str(path))
    assert json.loads(conf.get_json("mode")) == "client"
    assert json.loads(conf.get_json("connect/endpoints")) == ["tcp/10.0.0.1:7447"]
    conf = zconfig.make_config(None, ["tcp/127.0.0.1:2222"], [], str(path))
    assert json.loads(conf.get_json("listen/endpoints")) == ["tcp/127.0.0.1:2222"]


def test_zenoh_shared_memory_is_off_unless_the_file_says(tmp_path):
    """zenoh 1.x's shared-memory pool (16 MB per session, kept resident) is off for fleet
    processes; a config file that mentions shared_memory decides for itself."""
    assert json.loads(zconfig.make_config("peer").get_json("transport/shared_memory/enabled")) is False
    path = tmp_path / "shm.json5"
    path.write_text("{ transport: { shared_memory: { enabled: true } } }")
    assert json.loads(zconfig.make_config(None, [], [], str(path)).get_json("transport/shared_memory/enabled")) is True


@pytest.mark.parametrize("kwargs, fragment", [
    ({"listen": ["127.0.0.1:7447"]}, "--listen"),
    ({"connect": ["tcp 1"]}, "--connect"),
    ({"config_file": "/nonexistent/z.json5"}, "file not found"),
    ({"mode": "satellite"}, "--mode"),
])
def test_zenoh_config_errors_are_one_line(kwargs, fragment, tmp_path):
    with pytest.raises(zconfig.ConfigError) as info:
        zconfig.make_config(**kwargs)
    assert fragment in str(info.value) and "\n" not in str(info.value)


def test_zenoh_config_bad_file(tmp_path):
    path = tmp_path / "bad.json5"
    path.write_text("{ mode: ")
    with pytest.raises(zconfig.ConfigError) as info:
        zconfig.make_config(config_file=str(path))
    assert str(path) in str(info.value)


def test_a_config_file_mode_beats_the_role_default(tmp_path):
    with_mode = tmp_path / "router.json5"
    with_mode.write_text('{ mode: "router" }')
    nested = tmp_path / "nested.json5"
    nested.write_text('{ routing: { peer: { mode: "peer_to_peer" } } }')
    assert zconfig.file_sets_mode(str(with_mode))
    assert not zconfig.file_sets_mode(str(nested)) and not zconfig.file_sets_mode(None)


def test_a_config_file_that_listens_makes_a_coordinator_the_rendezvous(tmp_path):
    """docs/security.md's quick start: a coordinator given only a config file with listen
    endpoints listens there as a peer (it used to run as a client with nobody to connect to)."""
    from launcher.flags import flags_of, parse_args
    from launcher.settings import zenoh_config

    listens = tmp_path / "coordinator.json5"
    listens.write_text('{ listen: { endpoints: ["tcp/127.0.0.1:7447"] } }')
    silent = tmp_path / "carrier.json5"
    silent.write_text('{ listen: { endpoints: [] }, connect: { endpoints: ["tcp/127.0.0.1:7447"] } }')
    assert zconfig.file_listens(str(listens))
    assert not zconfig.file_listens(str(silent)) and not zconfig.file_listens(None)
    for path, mode in ((listens, "peer"), (silent, "client")):
        args = parse_args(["scenarios/tiny.yaml", "--role", "coordinator", "--zenoh-config", str(path)])
        assert zconfig_mode(zenoh_config(flags_of(args), "coordinator")) == mode


def zconfig_mode(conf) -> str:
    import json
    return json.loads(conf.get_json("mode"))


def test_shared_decoder_gives_what_decode_gives_once_per_payload():
    """A broadcast decoded once per process: every receiver gets decode()'s message (the same
    object), a bad payload the same rejection each time, and the cache stays bounded."""
    import threading

    from wire.messages import Decision, End, ProtocolError, SharedDecoder, decode, encode

    ids = tuple(f"c{k:04d}" for k in range(0, 300, 3))
    data = encode(Decision("m1", 2, 20.0, ids, 5.0, 1, tuple(k % 3 for k in range(len(ids)))))
    shared = SharedDecoder(capacity=2)
    got = []
    threads = [threading.Thread(target=lambda: got.append(shared.decode(bytes(data), Decision))) for _ in range(16)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(got) == 16 and all(m is got[0] for m in got) and got[0] == decode(data, Decision)
    for bad, expected in ((data[:-3], Decision), (data, End)):
        with pytest.raises(ProtocolError) as own:
            decode(bad, expected)
        for _ in range(2):
            with pytest.raises(ProtocolError) as seen:
                shared.decode(bad, expected)
            assert (seen.value.reason, seen.value.detail) == (own.value.reason, own.value.detail)
    assert len(shared._seen) == 2


def test_nodes_on_a_shared_session_keep_their_own_entities_and_tokens():
    """The carriers of one process share one session (wire.transport.SharedSession): each keeps
    its own subscriptions and liveliness token; one that closes takes only its token away; the
    session closes with the last node. Real zenoh: a router and a watcher on loopback."""
    import time

    from tests.localports import distinct_free_ports
    from wire.transport import Node, SharedSession

    endpoint = f"tcp/127.0.0.1:{distinct_free_ports(1)[0]}"
    router = zconfig.open_session(zconfig.make_config("router", [endpoint]), 10.0)
    watcher = Node(zconfig.make_config("client", [], [endpoint]), open_timeout_s=10)
    shared = SharedSession(zconfig.make_config("client", [], [endpoint]))
    try:
        a, b = (Node(None, open_timeout_s=10, shared=shared) for _ in range(2))
        assert a.session is b.session
        for node, cid in ((a, "a"), (b, "b")):
            node.subscribe("t/decision")
            node.token(f"t/carrier/{cid}/alive")

        def live(expected):
            deadline = time.monotonic() + 10
            while time.monotonic() < deadline:
                found = watcher.live_tokens("t/carrier/*/alive", 1.0)
                if found == expected:
                    return found
                time.sleep(0.1)
            return found

        assert live(["t/carrier/a/alive", "t/carrier/b/alive"]) == ["t/carrier/a/alive", "t/carrier/b/alive"]
        watcher.put_raw("t/decision", b"one")
        for node in (a, b):  # one put reaches every node's own inbox once
            item = node.next(10)
            assert item is not None and item.payload == b"one" and node.next(0.3) is None
        assert a.close(5)
        assert live(["t/carrier/b/alive"]) == ["t/carrier/b/alive"]
        watcher.put_raw("t/decision", b"two")
        assert b.next(10).payload == b"two" and a.next(0.3) is None
        assert not b.session.is_closed()
        assert b.close(5)
        assert b.session.is_closed() and live([]) == []
    finally:
        watcher.close(3)
        router.close()
