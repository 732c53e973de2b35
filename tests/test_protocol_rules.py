"""The numbered rules of docs/protocol.md, one test (or a table of cases) per rule whose behaviour
exists in the code, each citing its rule id in its docstring; and the page's rule book itself:
every rule id a test cites exists on the page, and every MUST rule is cited by some test.

These tests drive the pure parts (the codec, the key layout, the mission state machine and the
carrier state machine) with the messages and events the rules speak of, as a peer written from
the page would meet them; the flights over real Zenoh sessions are in tests/test_protocol_doc.py,
tests/test_wire_revisions.py and the conformance tests.
"""
from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import msgpack
import pytest

from mission import carrier as mc
from mission import events as ev
from mission import state as ms
from wire import keys
from wire import messages as wm

ROOT = Path(__file__).resolve().parents[1]
PAGE = (ROOT / "docs" / "protocol.md").read_text()
RULE = re.compile(r"\*\*\[(P-\d+\.\d+)\]")
CITED = re.compile(r"\[(P-\d+\.\d+)\]")

#: MUST rules that no test cites yet, each with the reason; keep it short and say so in reviews.
UNCITED_MUSTS: dict[str, str] = {
    "P-6.12": "a simulated carrier reports the project's world: judged by the conformance kit's rule "
              "observation-world on every carrier it flies (tests/test_conformance.py)",
}


def rules() -> dict[str, str]:
    """Rule id -> its text (up to the next rule or heading) on the page."""
    out = {}
    marks = list(RULE.finditer(PAGE))
    for k, m in enumerate(marks):
        end = marks[k + 1].start() if k + 1 < len(marks) else len(PAGE)
        text = PAGE[m.start():end].split("\n#")[0]
        assert m.group(1) not in out, f"rule {m.group(1)} defined twice"
        out[m.group(1)] = text
    return out


def cited_by_tests() -> dict[str, set[str]]:
    """Rule id -> the test files that cite it."""
    out: dict[str, set[str]] = {}
    for path in (ROOT / "tests").glob("test_*.py"):
        for rule in CITED.findall(path.read_text()):
            out.setdefault(rule, set()).add(path.name)
    return out


def test_every_cited_rule_is_on_the_page():
    """Every rule id a test cites is a rule of the page, and every id the page cites is one of
    its rules."""
    book = rules()
    assert set(cited_by_tests()) - set(book) == set()
    assert set(CITED.findall(PAGE)) - set(book) == set()


def test_every_must_rule_is_cited_by_a_test():
    """Every MUST rule of the page is cited by a test, except the short explicit list above
    (each still a rule of the page, a MUST one, and not cited elsewhere either)."""
    book = rules()
    musts = {rule for rule, text in book.items() if "MUST" in text.replace("MUST NOT", "MUST")}
    cited = set(cited_by_tests())
    uncited = sorted(musts - cited - set(UNCITED_MUSTS), key=lambda r: tuple(map(int, r[2:].split("."))))
    assert uncited == [], f"MUST rules no test cites: {uncited}"
    assert set(UNCITED_MUSTS) <= musts, set(UNCITED_MUSTS) - musts
    assert set(UNCITED_MUSTS) & cited == set(), "cited now: remove from UNCITED_MUSTS"


def test_rule_ids_follow_the_sections():
    """A rule's section number is the number of the section it is written in."""
    section = None
    for line in PAGE.splitlines():
        m = re.match(r"## (\d+)\. ", line)
        if m:
            section = int(m.group(1))
        for rule in RULE.findall(line):
            assert int(rule[2:].split(".")[0]) == section, (rule, section)


# --- rules: helpers

M = "m"


def body(kind: str, **fields) -> dict:
    return {"v": 1, "type": kind, "mission": M, **fields}


HELLO = dict(carrier="a", pid=1, host="h", passengers_left=1, next_stage=0, fingerprint="f")
OBS = dict(carrier="a", stage=0, t=0.0, x=None, position=[0.0, 0.0], passengers_left=1, trail=[])
CONFIRM = dict(carrier="a", stage=0, deployed=False, status="idle", position=[0.0, 0.0], passengers_left=1)


def reason(payload, expected=None, revision=wm.REVISION) -> str | None:
    try:
        wm.decode(payload if isinstance(payload, bytes) else msgpack.packb(payload), expected, revision)
    except wm.ProtocolError as exc:
        return exc.reason
    return None


def spec(n_stages=3, carriers=("a", "b")):
    return ms.MissionSpec.build(carriers, [[True] * n_stages for _ in carriers], (1,) * len(carriers),
                                tuple(5.0 * j for j in range(n_stages)), "f")


def accepted(state, cid, revision=wm.REVISION, next_stage=0):
    state, effects = ms.step(state, ev.Hello(cid, 1, "h", 1, next_stage, "f", 0.0, revision))
    assert any(isinstance(e, ms.Accept) for e in effects)
    return state


def rejections(effects) -> list[str]:
    return [e.reason for e in effects if isinstance(e, ms.Reject)]


# --- rules: 1 conventions

@pytest.mark.parametrize("payload, expected", [
    (b"\xc1", "malformed"),
    (msgpack.packb([1, 2]), "not-a-map"),
    (msgpack.packb({"type": "hello"}), "missing-field"),
    (msgpack.packb({"v": None, "type": "hello"}), "missing-field"),
    (msgpack.packb({"v": 1.0, "type": "hello"}), "version"),
    (msgpack.packb({"v": True, "type": "hello"}), "version"),
    (msgpack.packb({"v": 2, "type": "hello"}), "version"),
    (msgpack.packb({"v": 1}), "missing-field"),
    (msgpack.packb({"v": 1, "type": "nope"}), "unknown-type"),
])
def test_the_envelope(payload, expected):
    """[P-1.2] the envelope: a map with the integer v = 1 and a type; [P-3.3] its checks in order."""
    assert reason(payload) == expected


def test_nil_in_a_required_field_is_wrong_type_and_nullable_fields_take_nil():
    """[P-1.3] nil in a required field that is not nullable is wrong-type; a nullable one (an
    Observation's x) takes nil as a value of its own; nil in an optional field is its absence."""
    assert reason(body("hello", **dict(HELLO, host=None))) == "wrong-type"
    assert wm.decode(msgpack.packb(body("obs", **OBS))).x is None
    hello = wm.decode(msgpack.packb(body("hello", **HELLO, epoch=None, revision=None)))
    assert (hello.epoch, hello.revision) == (1, 1)  # nil in an optional field: its default


def test_absent_optional_fields_have_their_defaults_and_unknown_fields_are_rejected():
    """[P-1.4] an absent optional field means its default (Hello epoch 1, revision 1); a missing
    required field is missing-field; a field the receiver's revision does not list is
    unknown-field."""
    hello = wm.decode(msgpack.packb(body("hello", **HELLO)))
    assert (hello.epoch, hello.revision) == (1, 1)
    assert reason(body("hello", **{k: v for k, v in HELLO.items() if k != "pid"})) == "missing-field"
    assert reason(body("hello", **HELLO, colour="red")) == "unknown-field"
    assert reason(body("hello", **HELLO, revision=3), revision=2) == "unknown-field"


def test_unknown_enum_values():
    """[P-1.5] a Confirm status or a Refusal reason the receiver does not know is out-of-range; a
    Refusal reason newer than the peer's revision is not sent to it (world-mismatch instead); End
    and Bye reasons are free text."""
    assert reason(body("confirm", **dict(CONFIRM, status="maybe"))) == "out-of-range"
    refusal = body("refusal", carrier="a", reason="sunspots", fingerprint="f", expected="g")
    assert reason(refusal) == "out-of-range"
    assert reason(dict(refusal, reason="key-mismatch"), revision=1) == "out-of-range"
    assert wm.refusal(M, "a", "key-mismatch", "f", "g", "bad key", revision=1).reason == "world-mismatch"
    assert wm.refusal(M, "a", "key-mismatch", "f", "g", "bad key", revision=3).reason == "key-mismatch"
    assert wm.decode(msgpack.packb(body("end", stages=1, reason="the sun went down"))).reason == "the sun went down"
    bye = body("bye", carrier="a", deployments=[], rejected={}, reason="gone fishing")
    assert wm.decode(msgpack.packb(bye)).reason == "gone fishing"


@pytest.mark.parametrize("field, value, expected", [
    ("host", "é" * 255, None),            # 255 characters, 510 bytes: within "str ≤ 255"
    ("host", "é" * 256, "out-of-range"),
    ("pid", True, "wrong-type"),          # a boolean is never an integer
    ("passengers_left", -1, "out-of-range"),
    ("next_stage", 100_001, "out-of-range"),
])
def test_strings_count_characters_and_ranges_are_checked(field, value, expected):
    """[P-1.6] str ≤ n counts characters, not bytes; out of range is out-of-range, another type
    wrong-type."""
    assert reason(body("hello", **dict(HELLO, **{field: value}))) == expected


@pytest.mark.parametrize("data", [b"", b"\x00" * 10, msgpack.packb({"v": 1, "type": "obs", "stage": float("nan")}),
                                  msgpack.packb({"v": 1, "type": "state", "carriers": {"x" * 200: 1}}),
                                  b"\xdf\xff\xff\xff\xff"])
def test_a_bad_message_raises_only_a_protocol_error(data):
    """[P-1.7] whatever the bytes, decoding gives a message or a ProtocolError with a reason,
    never another exception."""
    assert reason(data) in wm.REASONS


# --- rules: 2 keys, ids, fingerprint

def _id_vectors():
    table = PAGE.split("**[P-2.2]")[1].split("### Key expressions")[0]
    rows = re.findall(r"^\| (.+?) \| (.+?) \|$", table, re.M)[2:]
    out = []
    for name, mission in rows:
        if name.startswith("`"):
            out.append((name.strip("`"), mission.strip("`")))
        else:  # "63 × `a` followed by `-b`"
            count, char, tail = re.match(r"(\d+) × `(.)` followed by `(.*)`", name).groups()
            c2, ch2, tail2 = re.match(r"(\d+) × `(.)` followed by `(.*)`", mission).groups()
            out.append((int(count) * char + tail, int(c2) * ch2 + tail2))
    return out


def test_the_page_gives_mission_id_vectors():
    """[P-2.2] the page's table of vectors is there, with `Six carriers!` among them."""
    vectors = dict(_id_vectors())
    assert vectors["Six carriers!"] == "Six-carriers" and len(vectors) >= 8


@pytest.mark.parametrize("name, mission", _id_vectors())
def test_the_default_mission_id(name, mission):
    """[P-2.2] the default mission id of each vector on the page is the code's, and a valid id
    [P-2.1]."""
    assert keys.mission_id_from_name(name) == mission
    assert keys.check_id(mission, "mission") == mission


@pytest.mark.parametrize("value, ok", [("a", True), ("_x.y-z", True), ("a" * 64, True), ("a" * 65, False),
                                       ("-a", False), (".a", False), ("a\n", False), ("a/b", False), ("a*", False),
                                       ("", False)])
def test_ids(value, ok):
    """[P-2.1] ids match the pattern as a whole string (a trailing newline does not)."""
    assert bool(keys.ID_PATTERN.match(value)) == ok


def test_the_coordinator_subscribes_and_parses_the_layout():
    """[P-2.3] the keys a coordinator subscribes to cover every carrier topic; [P-2.4] a key
    outside the layout is not a carrier key (bad-key), a message type not carried on its key is
    unknown-type."""
    for topic in keys.CARRIER_TOPICS:
        assert keys.parse_carrier_key(M, keys.carrier_key(M, "a", topic)) == ("a", topic)
    assert keys.parse_carrier_key(M, f"marsupial/{M}/carrier/a/obs/extra") is None
    assert keys.parse_carrier_key(M, f"marsupial/{M}/carrier/a b/obs") is None
    assert keys.parse_carrier_key("other", keys.carrier_key(M, "a", "obs")) is None
    assert reason(body("obs", **OBS), wm.Hello) == "unknown-type"


def test_the_fingerprint_algorithm():
    """[P-2.6] 16 lowercase hex digits of SHA-256 over the header line and the file's bytes."""
    import hashlib

    data = b"name: x\r\n# no newline conversion"
    assert wm.fingerprint_bytes(data, 7) == hashlib.sha256(b"marsupial-fleet/1 seed=7\n" + data).hexdigest()[:16]
    assert re.fullmatch(r"[0-9a-f]{16}", wm.fingerprint_bytes(data, 0))


# --- rules: 3 messages and their checks

def test_oversized_is_rejected_unread():
    """[P-3.1] a payload over 131,072 bytes is oversized, before it is parsed."""
    assert wm.MAX_PAYLOAD_BYTES == 131_072
    assert reason(b"\xc1" * (wm.MAX_PAYLOAD_BYTES + 1)) == "oversized"


def test_stage_and_time_ranges():
    """[P-3.2] the codec's ranges, then the receiver's: stage < N and t = t_j within 0.001 s."""
    assert reason(body("obs", **dict(OBS, stage=100_000))) == "out-of-range"
    assert reason(body("obs", **dict(OBS, t=2e9))) == "out-of-range"
    s = accepted(ms.initial(spec()), "a")
    obs = ev.Observation("a", 3, 15.0, None, (0.0, 0.0), 1)
    assert rejections(ms.step(s, obs)[1]) == ["out-of-range"]
    assert rejections(ms.step(s, ev.Observation("a", 1, 5.002, 1, (0.0, 0.0), 1))[1]) == ["out-of-range"]
    assert rejections(ms.step(s, ev.Observation("a", 0, 0.0009, 1, (0.0, 0.0), 1))[1]) == []
    c = mc.initial("a", (True,) * 3, (0.0, 5.0, 10.0), 1)
    assert [e.reason for e in mc.step(c, mc.DecisionHeard(3, 15.0, (), (0.0, 0.0)))[1]] == ["out-of-range"]
    assert [e.reason for e in mc.step(c, mc.DecisionHeard(1, 5.01, (), (0.0, 0.0)))[1]] == ["out-of-range"]


@pytest.mark.parametrize("payload, expected", [
    # the codec's order: size, msgpack, map, v, type, unknown fields, then fields in table order
    (dict(body("obs", **OBS), v=2, colour=1), "version"),
    ({"v": 1, "colour": 1}, "missing-field"),
    (dict(body("obs", **OBS), colour=1, stage=-1), "unknown-field"),
    (dict(body("obs", **{k: v for k, v in OBS.items() if k != "trail"}), stage=-1), "out-of-range"),
    (dict(body("obs", **{k: v for k, v in OBS.items() if k != "stage"}), t="x"), "missing-field"),
    (dict(body("obs", **OBS), mission="bad/id", stage="x"), "out-of-range"),
    (body("confirm", **dict(CONFIRM, deployed=True, status="idle")), "out-of-range"),
    (body("confirm", **dict(CONFIRM, passenger=0)), "out-of-range"),
])
def test_the_codec_checks_in_order(payload, expected):
    """[P-3.3] the codec's checks in the page's order: the first that fails names the reason."""
    assert reason(payload) == expected


def test_the_mission_checks_in_order():
    """[P-3.3] the mission's checks: carrier, stage < N and t, an accepted Hello, then the
    message's own rules; a refused carrier's messages are world-mismatch."""
    s = ms.initial(spec())
    assert rejections(ms.step(s, ev.Observation("z", 0, 0.0, 1, (0.0, 0.0), 1))[1]) == ["unknown-carrier"]
    assert rejections(ms.step(s, ev.Observation("a", 5, 0.0, 1, (0.0, 0.0), 1))[1]) == ["out-of-range"]
    assert rejections(ms.step(s, ev.Observation("a", 0, 9.0, 1, (0.0, 0.0), 1))[1]) == ["out-of-range"]
    assert rejections(ms.step(s, ev.Observation("a", 0, 0.0, 1, (0.0, 0.0), 1))[1]) == ["no-hello"]
    refused, _ = ms.step(s, ev.Hello("a", 1, "h", 1, 0, "other", 0.0))
    assert rejections(ms.step(refused, ev.Observation("a", 0, 0.0, 1, (0.0, 0.0), 1))[1]) == ["world-mismatch"]
    s = accepted(s, "a")
    assert rejections(ms.step(s, ev.Observation("a", 1, 5.0, 1, (0.0, 0.0), 1))[1]) == ["future-stage"]
    assert rejections(ms.step(s, ev.Confirmed("a", 0, False, "idle", (0.0, 0.0), 1))[1]) == ["stale-stage"]


def test_rejections_are_counted_for_state():
    """[P-3.4] the counts per reason a coordinator keeps per carrier go to CarrierState rejected,
    and a carrier's own counts to its Bye."""
    entry = wm.CarrierState(1, (), True, None, (("no-hello", 2),))
    state = wm.State(M, 0, 1, "f", False, (("a", entry),), None, revision=3)
    assert msgpack.unpackb(wm.encode(state))["carriers"]["a"]["rejected"] == {"no-hello": 2}
    bye = wm.Bye(M, "a", (), (("deposed", 1),), "end")
    assert msgpack.unpackb(wm.encode(bye))["rejected"] == {"deposed": 1}


def test_a_refused_hello_is_counted_under_its_reason():
    """[P-3.4] every refused Hello is a rejection too, counted for its carrier under the reason of
    the check it failed (a Hello accepted before still stands [P-5.9]); CarrierState rejected
    shows the count."""
    from types import SimpleNamespace

    from coordinator.answers import Answers

    s = ms.initial(spec())
    for hello in (ev.Hello("a", 1, "h", 1, 0, "other", 0.0), ev.Hello("a", 1, "h", 1, 9, "f", 0.0)):
        effects = ms.step(s, hello)[1]
        refused = [e.reason for e in effects if isinstance(e, ms.Refuse)]
        assert refused and rejections(effects) == refused
    s = accepted(s, "a")
    effects = ms.step(s, ev.Hello("a", 1, "h", 1, 0, "other", 0.0))[1]
    assert rejections(effects) == ["world-mismatch"] and any(isinstance(e, ms.Refuse) for e in effects)
    setup = SimpleNamespace(mission=M, spec=s.spec, ids=("a", "b"), n_stages=3, fingerprint="f")
    answers = Answers(setup, SimpleNamespace(epoch=1, ident=""), None)
    answers.serve(s)
    answers.rejected("a", "world-mismatch")
    reply = msgpack.unpackb(answers.state_reply({"carrier": "a", "revision": "3"}))
    assert reply["carriers"]["a"]["rejected"] == {"world-mismatch": 1}


def test_last_decision_is_in_the_replys_revision():
    """[P-5.3] State's last_decision is the Decision as published, with the coordinator's ballot,
    encoded in the reply's revision only: with a revision-1 carrier in the mission the broadcast
    leaves passengers out, a reply to a query of revision 3 or later names them."""
    from types import SimpleNamespace

    from coordinator.answers import Answers

    s = accepted(accepted(ms.initial(spec()), "a", revision=1), "b")
    s, _ = ms.step(s, ev.Decided(0, ("b",), 1.0, 0.0, (0,)))
    setup = SimpleNamespace(mission=M, spec=s.spec, ids=("a", "b"), n_stages=3, fingerprint="f")
    answers = Answers(setup, SimpleNamespace(epoch=2, ident="c1"), None)
    answers.serve(s)
    broadcast = msgpack.unpackb(wm.encode(answers.decision(s, 0), s.common_revision(wm.REVISION)))
    assert "passengers" not in broadcast and "coordinator" not in broadcast and broadcast["epoch"] == 2
    last = msgpack.unpackb(answers.state_reply({"carrier": "b", "revision": str(wm.REVISION)}))["last_decision"]
    assert last["passengers"] == [0] and last["coordinator"] == "c1" and last["epoch"] == 2
    assert {k: v for k, v in last.items() if k not in ("passengers", "coordinator")} == broadcast
    old = msgpack.unpackb(answers.state_reply({"carrier": "a"}))["last_decision"]
    assert old == broadcast


def test_epoch_1_is_carried_by_its_absence_but_in_end():
    """[P-7.1] every Decision, State and Accepted carries the epoch as [P-1.4] says: epoch 1 is
    left out; End states it, 1 included [P-7.4]."""
    assert "epoch" not in msgpack.unpackb(wm.encode(wm.Decision(M, 0, 0.0, (), 1.0, 1)))
    assert "epoch" not in msgpack.unpackb(wm.encode(wm.State(M, 0, 1, "f", False, (), None, epoch=1)))
    assert "epoch" not in msgpack.unpackb(wm.encode(wm.Accepted(M, "a", "f", 0, 0, wm.REVISION, 1)))
    assert msgpack.unpackb(wm.encode(wm.End(M, 1, "complete", 1)))["epoch"] == 1


def test_the_observation_box():
    """[P-3.3] an Observation's own rules: an identical repeat absorbed (before and after its
    stage is decided), a different one duplicate, then stale-stage once decided."""
    s = accepted(accepted(ms.initial(spec()), "a"), "b")
    s, _ = ms.step(s, ev.Observation("a", 0, 0.0, 2, (1.0, 1.0), 1))
    assert rejections(ms.step(s, ev.Observation("a", 0, 0.0, 2, (1.0, 1.0), 1))[1]) == []
    assert rejections(ms.step(s, ev.Observation("a", 0, 0.0, 3, (1.0, 1.0), 1))[1]) == ["duplicate"]
    s, _ = ms.step(s, ev.Decided(0, (), 1.0))
    assert rejections(ms.step(s, ev.Observation("a", 0, 0.0, 2, (1.0, 1.0), 1))[1]) == []
    assert rejections(ms.step(s, ev.Observation("a", 0, 0.0, 3, (1.0, 1.0), 1))[1]) == ["stale-stage"]


def test_a_repeat_is_compared_on_the_fields_the_page_names():
    """[P-1.7] a repeat is absorbed uncounted: an Observation compared on x and position only
    (not t, trail, passengers_left), an Own on x, deployed, position and passengers_left (not t);
    a difference in a compared field is duplicate."""
    s = accepted(ms.initial(spec()), "a")
    s, _ = ms.step(s, ev.Observation("a", 0, 0.0, 2, (1.0, 1.0), 1, ((0.0, 0.0),)))
    assert rejections(ms.step(s, ev.Observation("a", 0, 0.0009, 2, (1.0, 1.0), 0, ()))[1]) == []
    assert rejections(ms.step(s, ev.Observation("a", 0, 0.0, 2, (1.0, 2.0), 1))[1]) == ["duplicate"]
    s, _ = ms.step(s, ev.Accounted("a", 1, 5.0, 1, False, (2.0, 2.0), 1))
    assert rejections(ms.step(s, ev.Accounted("a", 1, 5.0009, 1, False, (2.0, 2.0), 1))[1]) == []
    assert rejections(ms.step(s, ev.Accounted("a", 1, 5.0, 1, False, (2.0, 2.0), 0))[1]) == ["duplicate"]
    assert rejections(ms.step(s, ev.Accounted("a", 1, 5.0, 2, False, (2.0, 2.0), 1))[1]) == ["duplicate"]


def test_poses_are_never_counted_and_do_not_make_a_carrier_heard():
    """[P-3.5] a Pose is not a mission event: the coordinator's inbox hands it to the recorder
    only, and it is not one of the topics that make a carrier heard [P-10.5]."""
    from coordinator.inbound import TOPIC_TYPES

    assert "pose" in keys.CARRIER_TOPICS and "pose" not in TOPIC_TYPES
    assert set(TOPIC_TYPES) == {"hello", "obs", "confirm", "own", "bye", "progress"}


# --- rules: 4 revisions

def test_the_broadcast_revision_is_the_lowest_ever_accepted():
    """[P-4.2] each carrier is answered in min(own, its Hello's); broadcasts in the minimum over
    every Hello accepted in the mission, a carrier gone since included, the coordinator's own
    before any."""
    s = ms.initial(spec())
    assert s.common_revision(wm.REVISION) == wm.REVISION
    s = accepted(s, "a", revision=1)
    s = accepted(s, "b", revision=wm.REVISION)
    s, _ = ms.step(s, ev.LivelinessChanged("a", True))
    s, _ = ms.step(s, ev.LivelinessChanged("a", False))  # a is gone: it may resume
    assert s.common_revision(wm.REVISION) == 1
    assert s.revision_of("b", wm.REVISION) == wm.REVISION and s.revision_of("b", 2) == 2
    assert s.revision_of("never-said-hello", wm.REVISION) == 1
    folded = ms.fold(s.spec, [ev.Hello("a", 1, "h", 1, 0, "f", 0.0, 1)])  # recovered from the store
    assert folded.common_revision(wm.REVISION) == 1


def test_the_state_query_parameter_shapes_only_its_reply():
    """[P-4.2] the State query's revision parameter gives the reply's revision (a value that is
    not 1 to 5 decimal digits ≥ 1 is 1) [P-5.3]; [P-4.3] a carrier's selector announces its
    revision."""
    assert keys.asked_revision({"revision": "2"}, wm.REVISION, 1) == 2
    assert keys.asked_revision({"revision": "123456"}, wm.REVISION, 1) == 1
    assert keys.asked_revision({"carrier": "a"}, wm.REVISION, 1) == 1
    assert keys.asked_revision({"colour": "red", "revision": "3", "carrier": "a"}, wm.REVISION, 1) == 3  # unknown: ignored
    assert keys.state_selector(M, "a", 4) == f"marsupial/{M}/coordinator/state?carrier=a;revision=4"


def test_a_revision_adds_only_optional_fields():
    """[P-4.1] every field a revision after 1 added is optional (has a default when absent)."""
    from dataclasses import fields

    for cls in (*wm.MESSAGE_TYPES.values(), wm.CarrierState):
        for f in fields(cls):
            if f.metadata.get("since", 1) > getattr(cls, "SINCE", 1):
                assert "absent" in f.metadata, (cls.__name__, f.name)


def test_new_fields_and_types_are_not_sent_to_an_earlier_peer():
    """[P-4.4] a message type a later revision added is not sent to an earlier peer; [P-1.4] nor
    a field."""
    accepted_msg = wm.Accepted(M, "a", "f", 0, 0, wm.REVISION)
    assert wm.defined_in(accepted_msg, 3) and not wm.defined_in(accepted_msg, 2)
    with pytest.raises(ValueError):
        wm.encode(wm.Progress(M, "a", 0, 0.0), 2)
    hello = wm.Hello(M, "a", 1, "h", 1, 0, "f", revision=3)
    assert "revision" not in msgpack.unpackb(wm.encode(hello, 2))


def test_a_receiver_decodes_at_its_own_revision():
    """[P-4.5] a revision 2 carrier announces nothing and sends Confirm passenger: decoded at the
    receiver's own revision it is accepted; [P-4.6] a receiver of revision 1 rejects it
    unknown-field, and an earlier receiver rejects a later type unknown-type."""
    confirm = body("confirm", **dict(CONFIRM, deployed=True, status="deployed", passenger=1))
    assert wm.decode(msgpack.packb(confirm)).passenger == 1
    assert reason(confirm, revision=1) == "unknown-field"
    assert reason(body("progress", carrier="a", stage=0, t=0.0), revision=2) == "unknown-type"


# --- rules: 5 joining

def test_a_resync_says_hello_whatever_the_epoch_of_state():
    """[P-5.4] on Resync a carrier sends Hello even when State's epoch is lower than the one it
    knows (a coordinator restarted on a fresh store); the lower epoch's State is not applied
    [P-7.2], and the Hello carries the carrier's position to go on from [P-5.13]."""
    c = mc.initial("a", (True,) * 4, (0.0, 5.0, 10.0, 15.0), 1)
    c, _ = mc.step(c, mc.Joined(0, epoch=3))
    c, _ = mc.step(c, mc.Observed(0, 1, (0.0, 0.0)))
    low = mc.StateSeen(2, (), (1, 5.0, ("a",)), False, epoch=1)
    after, effects = mc.step(c, mc.Resync(low, (0.0, 0.0)))
    hellos = [e for e in effects if isinstance(e, mc.SendHello)]
    assert len(hellos) == 1 and hellos[0].next_stage == 0
    assert after.state_next == 0 and after.epoch == 3  # nothing learnt from the lower epoch
    assert not any(isinstance(e, mc.SendConfirm) for e in effects)
    none, effects = mc.step(c, mc.Resync(None, (0.0, 0.0)))
    assert any(isinstance(e, mc.SendHello) for e in effects)


def test_a_carrier_joins_after_subscribing():
    """[P-5.1] the project's carrier subscribes to its coordinator keys and declares its token
    before it joins (the order of run's statements: subscribe, token, join)."""
    source = (ROOT / "carriers" / "node.py").read_text().split("def run(")[1]
    assert source.index("opening.begin(") < source.index("self.step(cl.Start(")
    begin = (ROOT / "carriers" / "opening.py").read_text().split("def begin(")[1].split("\ndef ")[0]
    assert "announce(config, node, crew)" in begin
    announce = (ROOT / "carriers" / "opening.py").read_text().split("def announce(")[1].split("\ndef ")[0]
    assert announce.index("inbound.subscribe(node)") < announce.index("node.token(")
    subscribe = (ROOT / "carriers" / "inbound.py").read_text().split("def subscribe(")[1].split("def listen(")[0]
    assert all(f"subscribe(keys.{key}" in subscribe for key in ("decision_key", "end_key", "refusal_key",
                                                                 "accepted_key"))


def test_state_is_asked_of_every_coordinator():
    """[P-5.2] a State query asks every matching queryable and keeps every reply (target ALL,
    consolidation NONE), and the carrier keeps the reply of the highest ballot (epoch, coordinator)."""
    transport = (ROOT / "wire" / "transport.py").read_text()
    assert "QueryTarget.ALL" in transport and "ConsolidationMode.NONE" in transport
    joining = (ROOT / "carriers" / "joining.py").read_text()
    assert "_ballot(best).below(_ballot(state))" in joining


def test_a_join_into_an_ended_mission():
    """[P-5.5] a first State that says ended ends the carrier's mission (it says Hello, then Bye
    end: the carrier process's join path, checked in tests/test_wire_answers.py); no stage is
    handled."""
    c = mc.initial("a", (True,) * 2, (0.0, 5.0), 1)
    c, effects = mc.step(c, mc.Joined(2, ended=True))
    assert c.ended and effects == ()
    joining = (ROOT / "mission" / "joins.py").read_text().split("def from_state(")[1].split("def alone(")[0]
    assert joining.index("mc.Joined(start, seen.ended") < joining.index("mc.SendHello(")


def test_hello_is_required():
    """[P-5.6] Observations, Confirms, Owns and Byes of a carrier without an accepted Hello are
    no-hello, and it is not waited for."""
    s = ms.initial(spec())
    s, _ = ms.step(s, ev.LivelinessChanged("a", True))
    assert "a" not in s.expected(0)
    for e in (ev.Observation("a", 0, 0.0, 1, (0.0, 0.0), 1), ev.Accounted("a", 0, 0.0, 1, False, (0.0, 0.0), 1),
              ev.Bye("a", (), (), "end")):
        assert rejections(ms.step(s, e)[1]) == ["no-hello"]
    s = accepted(s, "a")
    assert "a" in s.expected(0)


def test_decisions_before_the_join():
    """[P-5.7] a Decision received before the join is held: of a stage at or after the join stage
    it is handled there; of an earlier one it is never answered. After the join, an earlier
    stage's Decision is answered already if replayed, else late."""
    c = mc.initial("a", (True,) * 4, (0.0, 5.0, 10.0, 15.0), 2)
    c, effects = mc.step(c, mc.DecisionHeard(0, 0.0, ("a",), (0.0, 0.0)))
    assert effects == ()
    c, effects = mc.step(c, mc.DecisionHeard(2, 10.0, ("a",), (0.0, 0.0)))
    assert not any(isinstance(e, (mc.SendConfirm, mc.Deploy)) for e in effects)
    c, _ = mc.step(c, mc.Replayed(1, (0.0, 0.0)))
    c, _ = mc.step(c, mc.Joined(2))
    assert c.behind(2)
    c, effects = mc.step(c, mc.Passed(2, (1.0, 1.0)))
    assert [(e.stage, e.status) for e in effects if isinstance(e, mc.SendConfirm)] == [(2, "deployed")]
    assert 0 not in c.handled
    c, effects = mc.step(c, mc.DecisionHeard(1, 5.0, ("a",), (0.0, 0.0)))
    assert [(e.stage, e.status) for e in effects if isinstance(e, mc.SendConfirm)] == [(1, "already")]
    c, effects = mc.step(c, mc.DecisionHeard(0, 0.0, ("a",), (0.0, 0.0)))
    assert [(e.stage, e.status) for e in effects if isinstance(e, mc.SendConfirm)] == [(0, "late")]


def test_every_hello_is_answered():
    """[P-5.8] accepted: Accept; refused: Refuse with the reason, in the Hello's revision (an
    earlier one gets world-mismatch without detail); a Hello that could not be read is refused
    with the fingerprint and revision as far as they can be read."""
    s = ms.initial(spec())
    for hello, expected in ((ev.Hello("a", 1, "h", 1, 0, "f"), ms.Accept),
                            (ev.Hello("a", 1, "h", 1, 0, "g"), ms.Refuse),
                            (ev.Hello("a", 1, "h", 1, 9, "f"), ms.Refuse),
                            (ev.Hello("z", 1, "h", 1, 0, "f"), ms.Refuse)):
        assert [type(e) for e in ms.step(s, hello)[1] if isinstance(e, (ms.Accept, ms.Refuse))] == [expected]
    old = wm.refusal(M, "a", "out-of-range", "f", "g", "next_stage 9 > 3", 1)
    assert old.reason == "world-mismatch" and "detail" not in msgpack.unpackb(wm.encode(old, 1))
    assert wm.announced(msgpack.packb({"v": 1, "type": "hello", "fingerprint": "abc", "revision": 3})) == (3, "abc")
    assert wm.announced(b"\xc1") == (1, "")


def test_a_hello_of_another_type_is_refused_world_mismatch():
    """[P-5.8] a payload of another type on a hello key is unknown-type, a reason no revision
    lists for a Refusal: it is refused world-mismatch, without detail, even to revision 4."""
    payload = msgpack.packb(body("obs", **dict(OBS, fingerprint="f", revision=wm.REVISION)))
    assert reason(payload, wm.Hello) == "unknown-type"
    revision, fp = wm.announced(payload)
    answer = wm.refusal(M, "a", "unknown-type", fp, "f", "not a hello", revision)
    assert (revision, answer.reason, answer.fingerprint, answer.detail) == (wm.REVISION, "world-mismatch", "f", "")


def test_a_refusal_undoes_nothing():
    """[P-5.9] a Hello refused after an accepted one of the same carrier leaves it accepted."""
    s = accepted(ms.initial(spec()), "a")
    s2, effects = ms.step(s, ev.Hello("a", 2, "other", 1, 0, "g"))
    assert "a" in s2.accepted and s2.accepted["a"].host == "h"
    assert [e.reason for e in effects if isinstance(e, ms.Refuse)] == ["world-mismatch"]


def test_a_refused_carrier_stops_only_on_the_answer_to_its_latest_hello():
    """[P-5.10] a Refusal naming the fingerprint of the latest unanswered Hello is taken; one
    naming another fingerprint ("" for an unreadable Hello), or after the Hello was answered, is
    ignored."""
    answer = mc.HelloAnswer("f")
    answer.sent()
    assert not answer.answered("", "refusal") and not answer.answered("g", "refusal")
    assert answer.answered("f", None) and answer.refused is None  # accepted
    assert not answer.answered("f", "refusal")  # after the answer: somebody else's
    answer.sent()
    assert answer.answered("f", "refusal") and answer.refused == "refusal"


def test_refused_carriers_count_as_joined():
    """[P-5.11] the join wait ends when every carrier is live with an accepted Hello or refused."""
    s = ms.initial(spec())
    s, _ = ms.step(s, ev.LivelinessChanged("a", True))
    s = accepted(s, "a")
    assert not s.all_joined()
    s, _ = ms.step(s, ev.Hello("b", 1, "h", 1, 0, "g"))
    assert s.all_joined()


def test_a_resync_repeats_answers_and_confirms_lost_deployments():
    """[P-5.12] the coordinator's token reappearing makes a carrier resynchronise (Resync is the
    carrier's event for it); [P-5.13] with a current State: a Confirm late for a listed
    deployment never received, State's last decision handled, the pending Observation re-sent if
    its stage is open, and every handled stage repeated already."""
    c = mc.initial("a", (True,) * 5, (0.0, 5.0, 10.0, 15.0, 20.0), 3)
    c, _ = mc.step(c, mc.Joined(0))
    c, _ = mc.step(c, mc.Observed(0, 1, (0.0, 0.0)))
    c, _ = mc.step(c, mc.DecisionHeard(0, 0.0, (), (0.0, 0.0)))
    c, _ = mc.step(c, mc.MovedOn(0))
    c, _ = mc.step(c, mc.Observed(1, 1, (0.0, 0.0)))
    seen = mc.StateSeen(3, (1, 2), (2, 10.0, ("a",)), False)
    c, effects = mc.step(c, mc.Resync(seen, (2.0, 2.0)))
    kinds = [(type(e).__name__, getattr(e, "stage", None), getattr(e, "status", None)) for e in effects
             if not isinstance(e, (mc.Log, mc.LogOutcome, mc.Deploy))]
    assert kinds[0] == ("SendHello", None, None)
    assert ("SendConfirm", 1, "late") in kinds and ("SendConfirm", 0, "already") in kinds
    assert 2 in c.buffered  # State's last decision, for a stage not reached yet: held
    assert not any(k[0] == "ResendObservation" for k in kinds)  # stage 1 is decided



def test_a_hello_without_an_answer_is_said_again():
    """[P-5.14] a carrier whose latest Hello had no answer says it again with what went out since
    (its pending Observation, a Confirm already for each stage handled since the join), as a
    Resync without a State; nothing before it flies or once its mission ended. The retry time
    doubles (mission.timers.hello_again; tests/test_timers.py) from the latest Hello of a join or
    a Resync."""
    c = mc.initial("a", (True,) * 3, (0.0, 5.0, 10.0), 2)
    assert mc.step(c, mc.HelloUnanswered((0.0, 0.0))) == (c, ())  # not flying: no Hello to repeat
    c, _ = mc.step(c, mc.Joined(0))
    c, _ = mc.step(c, mc.Observed(0, 1, (0.0, 0.0)))
    c, _ = mc.step(c, mc.DecisionHeard(0, 0.0, ("a",), (0.0, 0.0)))
    c, _ = mc.step(c, mc.MovedOn(0))
    c, _ = mc.step(c, mc.Observed(1, 1, (0.0, 0.0)))
    after, effects = mc.step(c, mc.HelloUnanswered((1.0, 1.0)))
    sent = [e for e in effects if not isinstance(e, mc.Log)]
    assert after == c
    assert sent == [mc.SendHello(1, 1, again=True), mc.ResendObservation(1), mc.SendConfirm(0, True, "already",
                                                                                              (0.0, 0.0), 1)]
    ended, _ = mc.step(c, mc.EndHeard(None))
    assert mc.step(ended, mc.HelloUnanswered((1.0, 1.0)))[1] == ()
    answer = mc.HelloAnswer("f")
    answer.sent(3.0)
    answer.sent(13.0, again=True)
    answer.sent(33.0, again=True)
    assert (answer.at, answer.tries, answer.unanswered) == (33.0, 2, True)
    answer.sent(40.0)  # a Resync's Hello: from the retry time again
    assert (answer.at, answer.tries) == (40.0, 0)


def test_a_hello_said_again_is_answered_and_changes_nothing():
    """[P-5.14] [P-5.8] the coordinator answers a Hello said again as any Hello (an Accepted each)
    and keeps what it holds of the carrier: its Observations, its join."""
    s = ms.initial(spec())
    s, _ = ms.step(s, ev.LivelinessChanged("a", True))
    s = accepted(s, "a")
    s, _ = ms.step(s, ev.Observation("a", 0, 0.0, 2, (0.0, 0.0), 1))
    again, effects = ms.step(s, ev.Hello("a", 1, "h", 1, 0, "f", 0.0, wm.REVISION))
    assert [type(e) for e in effects if isinstance(e, (ms.Accept, ms.Refuse))] == [ms.Accept]
    assert again.reported == s.reported and again.accepted == s.accepted and again.waiting(0) == s.waiting(0)


# --- rules: 6 stages

def test_every_carrier_observes_every_stage():
    """[P-6.7] a carrier not scheduled at j still publishes its Observation, with x nil, and is
    not behind a stage that is not known decided."""
    c = mc.initial("a", (False, True), (0.0, 5.0), 1)
    c, _ = mc.step(c, mc.Joined(0))
    assert not c.behind(0)
    c, effects = mc.step(c, mc.Observed(0, 4, (0.0, 0.0)))
    assert c.sensed is None and effects[0].x is None


def test_each_stage_at_most_once():
    """[P-6.8] a repeated Decision is answered already with the first outcome; a Decision of a
    passed stage late (selected) or idle, never a deployment."""
    c = mc.initial("a", (True,) * 3, (0.0, 5.0, 10.0), 2)
    c, _ = mc.step(c, mc.Joined(0))
    c, _ = mc.step(c, mc.Observed(0, 1, (0.0, 0.0)))
    c, first = mc.step(c, mc.DecisionHeard(0, 0.0, ("a",), (1.0, 1.0)))
    c, again = mc.step(c, mc.DecisionHeard(0, 0.0, ("a",), (9.0, 9.0)))
    assert [e.status for e in first if isinstance(e, mc.SendConfirm)] == ["deployed"]
    assert [(e.status, e.deployed, e.position) for e in again] == [("already", True, (1.0, 1.0))]
    assert not any(isinstance(e, mc.Deploy) for e in again)
    c, _ = mc.step(c, mc.MovedOn(0))
    c, _ = mc.step(c, mc.Observed(1, 1, (0.0, 0.0)))
    c, _ = mc.step(c, mc.MovedOn(1))  # gave up waiting for stage 1
    c, late = mc.step(c, mc.DecisionHeard(1, 5.0, ("a",), (0.0, 0.0)))
    assert [(e.status, e.deployed) for e in late if isinstance(e, mc.SendConfirm)] == [("late", False)]
    assert not any(isinstance(e, mc.Deploy) for e in late)


@pytest.mark.parametrize("selected, valid, left, status", [
    (True, True, 1, "deployed"), (True, True, 0, "refused"), (True, False, 1, "refused"), (False, True, 1, "idle"),
])
def test_handling_a_decision(selected, valid, left, status):
    """[P-6.9] selected, scheduled, with a passenger: deploy (logged before the release, the
    release before the Confirm); without a passenger or not scheduled: refused; else idle."""
    c = mc.initial("a", (valid,), (0.0,), left)
    c, _ = mc.step(c, mc.Joined(0))
    c, _ = mc.step(c, mc.Observed(0, 1, (0.0, 0.0)))
    c, effects = mc.step(c, mc.DecisionHeard(0, 0.0, ("a",) if selected else (), (0.0, 0.0)))
    kinds = [type(e) for e in effects if not isinstance(e, mc.Log)]
    assert [e.status for e in effects if isinstance(e, mc.SendConfirm)] == [status]
    assert kinds == ([mc.LogOutcome, mc.Deploy, mc.SendConfirm] if status == "deployed" else
                     [mc.LogOutcome, mc.SendConfirm])


def test_the_named_passenger_is_released():
    """[P-6.9] the passenger a Decision names, if on board, else the lowest index on board."""
    c = mc.initial("a", (True,), (0.0,), 3)
    releases = mc.Releases(3)
    releases.name(c, 0, 1, 2)
    assert releases.release(0) == 2
    releases.name(c, 1, 1, 2)
    assert releases.release(1) == 0  # 2 is gone: the lowest on board


def test_an_early_observation_is_sent_again():
    """[P-6.10] a carrier that went on to stage k and published its Observation of k re-sends it
    after answering the Decision of j < k."""
    c = mc.initial("a", (True,) * 3, (0.0, 5.0, 10.0), 1)
    c, _ = mc.step(c, mc.Joined(0))
    c, _ = mc.step(c, mc.Observed(0, 1, (0.0, 0.0)))
    c, _ = mc.step(c, mc.DecidedOwn(0, False, (0.0, 0.0)))
    c, _ = mc.step(c, mc.MovedOn(0))
    c, _ = mc.step(c, mc.Observed(1, 1, (0.0, 0.0)))
    c, effects = mc.step(c, mc.DecisionHeard(0, 0.0, (), (0.0, 0.0)))
    assert [type(e) for e in effects] == [mc.SendConfirm, mc.ResendObservation]
    assert effects[0].status == "already" and effects[1].stage == 1


def test_what_counts_as_done():
    """[P-6.11] per carrier and stage: its Own, else its Confirm, else the Decision, within the
    carrier's passengers and its Bye."""
    s = accepted(accepted(ms.initial(spec(2)), "a"), "b")
    s, _ = ms.step(s, ev.Decided(0, ("a", "b"), 1.0))
    s, _ = ms.step(s, ev.Confirmed("a", 0, False, "refused", (0.0, 0.0), 1))
    deployed = s.deployed()
    assert not deployed[0, 0] and deployed[1, 0]  # a's Confirm wins, b's Decision stands
    s, _ = ms.step(s, ev.Accounted("b", 1, 5.0, 1, True, (0.0, 0.0), 0))
    # b has one passenger and accounts for it at stage 1: the unanswered Decision of stage 0 has
    # no passenger left to count (exception 2); a's refusal leaves a with none
    assert s.deployed()[1].tolist() == [False, True]
    assert s.deployments_of("b") == [1] and s.deployments_of("a") == []
    s, _ = ms.step(s, ev.Decided(1, ("a",), 1.0))
    s, _ = ms.step(s, ev.Bye("a", (), (), "end", 9.0))
    assert s.deployments_of("a") == []  # exception 1: its Bye lists no deployment


def test_the_forced_rule():
    """[P-6.13] at a valid stage where a carrier has as many passengers as valid stages left, a
    decision that does not select it is refused; so is one selecting a carrier that cannot deploy
    [P-6.3]."""
    import numpy as np

    from planner import problem as pp

    problem = pp.warm_up_problem()
    x = np.ones(problem.valid.shape)
    deployed = np.zeros(problem.valid.shape, dtype=bool)
    forced = [j for j in range(problem.n_stages) if pp.make_view(problem, j, x, deployed).must_deploy.any()]
    assert forced
    view = pp.make_view(problem, forced[0], x, deployed)
    with pytest.raises(AssertionError, match="must deploy"):
        pp.enforce(view, np.zeros(problem.n_carriers, dtype=bool))
    assert pp.enforce(view, view.must_deploy).tolist() == view.must_deploy.tolist()
    missed = x.copy()
    missed[:, forced[0]] = np.nan  # a stage missed (∅) is not valid and forces nothing
    assert not pp.make_view(problem, forced[0], missed, deployed).must_deploy.any()
    with pytest.raises(AssertionError, match="cannot deploy"):
        pp.enforce(pp.make_view(problem, forced[0], missed, deployed), view.must_deploy)


def test_scheduled_is_the_time_window():
    """[P-1.8] a carrier is scheduled at j iff start_time ≤ t_j ≤ stop_time; both sides identify
    the world by its fingerprint, which the seed changes."""
    import numpy as np

    import world

    tiny = world.load_scenario(ROOT / "scenarios" / "tiny.yaml")
    t = tiny.stage_times()
    expected = np.array([[c.start_time <= tj <= c.stop_time for tj in t] for c in tiny.carriers])
    assert (tiny.valid() == expected).all()
    assert wm.scenario_fingerprint(tiny) != wm.scenario_fingerprint(tiny.with_seed(tiny.seed + 1))
    # the defaults a peer applies itself: t_j from first_stage_time (0) and stage_interval, and a
    # stop_time the entry does not give is start_time + the waypoints' length / speed
    assert t.tolist() == [0.0 + j * tiny.stage_interval for j in range(tiny.stages)]
    b = tiny.carriers[1]  # tiny.yaml gives b no stop_time: legs of 18 m and 14 m at 2 m/s from t = 5
    assert "stop_time" not in (ROOT / "scenarios" / "tiny.yaml").read_text()
    assert (b.start_time, b.speed, b.stop_time) == (5.0, 2.0, 5.0 + (18.0 + 14.0) / 2.0)
    assert [c.passengers for c in tiny.carriers] == [2, 1]  # a count: D passengers alike


def test_when_a_carrier_decides_alone():
    """[P-8.1] a hybrid carrier decides alone when the coordinator's token is absent or (wall
    clock) the decision timeout passed; on the sim clock, with the token present, it asks State
    instead and goes on waiting; a coordinated carrier exits coordinator-lost after the
    coordinator timeout."""
    from mission import timers as tm

    rule = tm.decision_wait  # its table: tests/test_timers.py
    assert rule("sim", "hybrid", True, 30.0, 0.0, 30.0, 30.0) == tm.AskState()
    assert rule("wall", "hybrid", True, 30.0, 0.0, 30.0, 30.0) == tm.DecideAlone()
    assert rule("sim", "hybrid", False, 0.0, 0.0, 30.0, 30.0) == tm.DecideAlone()
    assert rule("sim", "coordinated", False, 0.0, 30.0, 30.0, 30.0) == tm.GiveUp("coordinator-lost")
    # the carrier's lifecycle machine (mission/carrier_life.py) calls that rule and carries out
    # each of its effects; the real carrier and the simulator drive the machine
    wait = (ROOT / "mission" / "carrier_life.py").read_text().split("def _wait(")[1].split("def _alone(")[0]
    assert "tm.decision_wait(view.timers.clock, life.mode, view.present, wait.waited_s," in wait
    assert wait.index("isinstance(rule, tm.AskState)") < wait.index("AskState(j)")
    assert "_finish(life, rule.reason" in wait
    c = mc.initial("a", (True,), (0.0,), 1)
    c, _ = mc.step(c, mc.Joined(0))
    c, _ = mc.step(c, mc.Observed(0, 1, (0.0, 0.0)))
    c, effects = mc.step(c, mc.DecidedOwn(0, True, (0.0, 0.0)))
    assert [type(e) for e in effects if not isinstance(e, mc.Log)] == [mc.LogOutcome, mc.Deploy, mc.SendOwn]
    assert mc.step(c, mc.DecisionHeard(0, 0.0, (), (0.0, 0.0)))[1][0].status == "already"  # [P-8.2]


def test_a_stage_is_held_while_no_carrier_is_live():
    """[P-6.5] the coordinator's stage loop holds a stage j > 0 while no carrier is live (at most
    the join timeout)."""
    from mission import timers as tm

    assert tm.hold(False, 0.0, 19.0, 20.0) == tm.Wait(20.0) and tm.hold(True, 0.0, 1.0, 20.0) == tm.GoOn()
    loop = (ROOT / "mission" / "coordinator_life.py").read_text().split("def _stage(")[1]
    assert "if j > 0 and not st.live:" in loop
    assert "tm.hold(False, life.held_at, now, w.join_s)" in loop  # the lifecycle's table: tests/test_coordinator_life.py
    # live is the token alone: a carrier without an accepted Hello ends the hold
    s, _ = ms.step(ms.initial(spec()), ev.LivelinessChanged("a", True))
    assert s.live == {"a"} and "a" not in s.accepted


def test_decisions_name_sorted_carriers_and_passengers():
    """[P-6.4] a Decision's deploy is sorted by id with the passengers in the same order;
    [P-6.1] it is committed (Record) before it is published."""
    s = accepted(accepted(ms.initial(spec(1)), "a"), "b")
    s, effects = ms.step(s, ev.Decided(0, ("b", "a"), 1.0, 0.0, (5, 7)))
    record = s.decisions[0]
    assert record.deploy == ("a", "b") and record.passengers == (7, 5)
    assert any(isinstance(e, ms.Publish) for e in effects)
    rec = [e for e in effects if isinstance(e, ms.Record)]
    assert effects.index(rec[0]) < effects.index(next(e for e in effects if isinstance(e, ms.Publish)))


def test_a_stage_counts_as_decided_once_committed():
    """[P-6.1] stage j is decided when its Decision is committed, before it is published: the
    Observation of j + 1 that a carrier sends on the Decision is stored, not future-stage, and
    State (served before the put) says next_stage j + 1; the pace is skipped when every live
    carrier is past j."""
    s = accepted(accepted(ms.initial(spec(3)), "a"), "b")
    s, effects = ms.step(s, ev.Decided(0, (), 1.0))
    assert [type(e) for e in effects] == [ms.Record, ms.Publish] and s.next_stage == 1
    after, effects = ms.step(s, ev.Observation("a", 1, 5.0, 1, (0.0, 0.0), 1))  # no Published yet
    assert rejections(effects) == [] and ("a", 1) in after.reported
    carry = (ROOT / "coordinator" / "effects.py").read_text().split("def carry_out(")[1].split("def reject(")[0]
    assert "self.answers.serve(state)\n            return self.publish_decision(state, effect.stage)" in carry
    # the pace's exception: every live carrier past j (an Own of j, or a Hello with a later next_stage)
    for cid in ("a", "b"):
        s, _ = ms.step(s, ev.LivelinessChanged(cid, True))
    assert not s.behind(1)
    s = accepted(s, "b", next_stage=2)
    s, _ = ms.step(s, ev.Accounted("a", 1, 5.0, 1, False, (0.0, 0.0), 1))
    assert s.behind(1)
    loop = (ROOT / "mission" / "coordinator_life.py").read_text().split("def _stage(")[1]
    assert "if life.published is not None and not st.behind(j):" in loop


def test_which_passenger_a_decision_names():
    """[P-6.4] without passenger lists, the lowest-index passenger on board as the coordinator
    counts them; nobody deploying, passengers is left out (never []), and [] reads as absent."""
    import numpy as np

    from planner import passengers as pg
    from planner import problem as pp

    import world

    problem = world.build_problem(world.load_scenario(ROOT / "scenarios" / "tiny.yaml"))
    assert problem.weights is None  # tiny.yaml lists no passengers: a carries 2 alike
    x = np.ones(problem.valid.shape)
    deployed = np.zeros(problem.valid.shape, dtype=bool)
    r = 0
    j = int(np.flatnonzero(problem.valid[r])[1])
    deployed[r, int(np.flatnonzero(problem.valid[r])[0])] = True  # one passenger released before j
    deploy = np.zeros(problem.n_carriers, dtype=bool)
    deploy[r] = True
    assert pg.choose(pp.make_view(problem, j, x, deployed), deploy)[r] == 1
    raw = msgpack.unpackb(wm.encode(wm.Decision(M, 0, 0.0, (), 1.0)))
    assert "passengers" not in raw
    assert wm.decode(msgpack.packb({**raw, "passengers": []})).passengers == ()


def test_collect_waits_for_the_expected_carriers():
    """[P-6.2] expected at j: live, Hello accepted, scheduled at j, not past j (no Own of j, no
    Hello with a later next_stage); a vanished token removes the carrier at once; [P-8.6] a
    coordinator neither waits for nor plans a carrier at a stage it has passed."""
    s = ms.initial(spec(3))
    for cid in ("a", "b"):
        s, _ = ms.step(s, ev.LivelinessChanged(cid, True))
    s = accepted(s, "a")
    s = accepted(s, "b", next_stage=2)
    assert s.expected(0) == {"a"}
    s, _ = ms.step(s, ev.Accounted("a", 0, 0.0, 1, False, (0.0, 0.0), 1))
    assert s.expected(0) == frozenset() and s.expected(1) == {"a"}
    s, _ = ms.step(s, ev.LivelinessChanged("a", False))
    assert s.expected(1) == frozenset()


# --- rules: 7 epochs

def test_a_lower_epoch_decision_is_deposed():
    """[P-7.2] a Decision of a lower epoch than the highest heard is rejected deposed, not
    deployed, not confirmed, and changes nothing; an equal or higher one raises the epoch."""
    c = mc.initial("a", (True,) * 2, (0.0, 5.0), 1)
    c, _ = mc.step(c, mc.Joined(0, epoch=2))
    c, _ = mc.step(c, mc.Observed(0, 1, (0.0, 0.0)))
    after, effects = mc.step(c, mc.DecisionHeard(0, 0.0, ("a",), (0.0, 0.0), epoch=1))
    assert [type(e) for e in effects] == [mc.Reject] and effects[0].reason == "deposed"
    assert after == dataclasses.replace(c, outranked=True)  # nothing changes but: the live coordinator is outranked
    after, effects = mc.step(c, mc.DecisionHeard(0, 0.0, ("a",), (0.0, 0.0), epoch=3))
    assert after.epoch == 3 and any(isinstance(e, mc.Deploy) for e in effects)


def test_takeover_and_deposition_come_from_coordinators_only():
    """[P-7.3] a Hello of a higher epoch is a claim, kept for the record and never adopted: it
    neither raises the coordinator's epoch nor deposes it; a Decision of a higher epoch on its
    decision key does; Decisions of its own or a lower epoch there, and what does not decode,
    are ignored. A resumed coordinator re-publishes its last Decision [P-7.5]."""
    import threading

    from coordinator.epochs import Epochs
    from wire.messages import Decision, encode

    lines: list[str] = []
    stop = threading.Event()
    epochs = Epochs("m", lines.append, stop, lambda: 0.0, "c")
    epochs.first_stage = 3
    for claimed in (2, 2**31 - 1, 5):
        epochs.carrier_claimed("c1", claimed)
    assert epochs.epoch == 1 and epochs.deposed_by is None and not stop.is_set()
    assert epochs.claims == {"c1": 2**31 - 1} and len(lines) == 1 and "not adopted" in lines[0]
    for payload in (b"\x00garbage", encode(Decision("m", 0, 0.0, (), 0.0, epoch=1)),
                    encode(Decision("other", 0, 0.0, (), 0.0, epoch=9))):
        epochs.decision_heard(payload)
    assert epochs.deposed_by is None and not stop.is_set()
    epochs.decision_heard(encode(Decision("m", 4, 0.0, (), 0.0, epoch=2)))
    assert epochs.deposed_by == 2 and stop.is_set()
    node = (ROOT / "coordinator" / "node.py").read_text()
    fly = node.split("    def fly(")[1].split("    def ")[0]
    assert "if self.crew.epochs.deposed_by is not None:  # deposed: the newer coordinator ends the mission" in fly
    assert "self.step(cl.Deposed())" in fly
    assert ("if self.state.next_stage > 0:  # idempotent re-publication\n"
            "            self.apply(self.crew.effects.publish_decision(self.state, self.state.next_stage - 1))") in node


# --- rules: 9 leaving

def test_bye_only_after_hello():
    """[P-9.4] a carrier sends Bye if and only if it said Hello (or flies decentralised); every
    exit reason of the page's table is one the carrier can exit with, and a Bye needs an accepted
    Hello at the coordinator."""
    from carriers.exits import EXIT_CODES

    node = (ROOT / "carriers" / "node.py").read_text().split("def run(")[1]
    assert "opening.close(self.config, self.node, crew, self.machine, reason" in node
    closing = (ROOT / "carriers" / "opening.py").read_text().split("def close(")[1]
    assert 'if answer.said_hello or config.mode == Mode.DECENTRALISED:  # a Bye needs a Hello' in closing
    table = PAGE.split("**[P-9.4]")[1].split("\n\n", 2)[1]
    documented = set(re.findall(r"^\| `([a-z0-9-]+)` \|", table, re.M))
    assert documented == set(EXIT_CODES) - {"log-mismatch"}  # a log mismatch stops before the Hello
    s = ms.initial(spec())
    assert rejections(ms.step(s, ev.Bye("a", (), (), "end"))[1]) == ["no-hello"]


def test_a_carrier_that_hears_end_stops():
    """[P-9.3] End ends the carrier's mission: no further stage is handled."""
    c = mc.initial("a", (True,) * 2, (0.0, 5.0), 1)
    c, _ = mc.step(c, mc.Joined(0))
    c, _ = mc.step(c, mc.EndHeard())
    assert c.ended


# --- rules: 10 time

def test_who_the_wait_for_the_last_confirms_covers():
    """[P-10.3] after the last stage the coordinator waits for every live carrier without a
    Confirm of N - 1 (a Hello accepted or not, an Own of N - 1 not counting), but one whose
    accepted Hello named next_stage N; a vanished token ends the wait for it."""
    s = ms.initial(spec(2, ("a", "b", "c")))
    for cid in ("a", "b", "c"):
        s, _ = ms.step(s, ev.LivelinessChanged(cid, True))
    s = accepted(accepted(s, "a"), "b", next_stage=2)
    s, _ = ms.step(s, ev.Decided(0, (), 1.0))
    s, _ = ms.step(s, ev.Decided(1, (), 1.0))
    assert s.unconfirmed(1) == {"a", "c"}
    s, _ = ms.step(s, ev.Accounted("a", 1, 5.0, 1, False, (0.0, 0.0), 1))
    assert s.unconfirmed(1) == {"a", "c"}
    s, _ = ms.step(s, ev.Confirmed("a", 1, False, "already", (0.0, 0.0), 1))
    s, _ = ms.step(s, ev.LivelinessChanged("c", False))
    assert s.unconfirmed(1) == frozenset()
    life = (ROOT / "mission" / "coordinator_life.py").read_text().split("def _confirm(")[1]
    assert "st.confirms_awaited(last)" in life


def test_silence_is_measured_from_the_stage_opening_and_the_last_message():
    """[P-10.3] on the sim clock a carrier is taken as stalled only when the silence timeout has
    passed since the stage opened and since it was last heard."""
    from mission.peers import last_heard

    assert last_heard({"a": 5.0}, {"a"}, 10.0) == 10.0
    assert last_heard({"a": 15.0}, {"a"}, 10.0) == 15.0
    from mission import timers as tm
    from mission.timers import silent

    assert not silent({"a": 15.0}, {"a"}, 10.0, 44.0, 30.0) and silent({"a": 15.0}, {"a"}, 10.0, 45.0, 30.0)
    assert not silent({}, {"a"}, 10.0, 39.0, 30.0) and silent({}, {"a"}, 10.0, 40.0, 30.0)
    # the rule's one home, and the coordinator's lifecycle reading it
    timers = (ROOT / "mission" / "timers.py").read_text()
    assert "now - opened >= silence_s and now - last_heard(heard, among, opened) >= silence_s" in timers
    assert tm.stage_wait("sim", {"a"}, (), {"a": 15.0}, 10.0, 44.0, 5.0, 30.0) == tm.Wait(45.0)
    life = (ROOT / "mission" / "coordinator_life.py").read_text().split("def _stage(")[1].split("def _stage_notes(")[0]
    assert "tm.stage_wait(life.clock, *st.waited_for(j), view.heard, life.opened, now," in life


def test_the_clocks():
    """[P-10.1] two clocks, sim and wall; the defaults of the page's timer table are the code's."""
    from mission.timeouts import CLOCKS, DEFAULTS

    assert CLOCKS == ("sim", "wall")
    table = PAGE.split("### Timers")[1].split("### Simulated time")[0]
    for timer, value in (("join timeout", DEFAULTS.join_s), ("stage timeout", DEFAULTS.stage_s),
                         ("confirm timeout", DEFAULTS.confirm_s), ("silence timeout", DEFAULTS.silence_s),
                         ("coordinator timeout", DEFAULTS.coordinator_s), ("decision timeout", DEFAULTS.decision_s),
                         ("peer timeout", DEFAULTS.peer_s), ("end timeout", DEFAULTS.end_s)):
        row = next(line for line in table.splitlines() if f"| {timer}" in line)
        assert row.split("|")[4].strip().startswith(f"{value:g} s"), (timer, row)


def test_what_keeps_a_carrier_heard():
    """[P-10.5] the coordinator notes a carrier heard for every message on its hello, obs,
    confirm, own, bye or progress key that passes the key, codec and envelope checks, before the
    mission's checks; a carrier deciding alone does the same for its peers' messages."""
    inbound = (ROOT / "coordinator" / "inbound.py").read_text().split("def read(")[1]
    assert inbound.index("key-mismatch") < inbound.index("Heard(carrier=cid, at=item.received") < inbound.index(
        "Heard(to_event(msg, item.wall), cid, item.received")
    take = (ROOT / "coordinator" / "inbound.py").read_text().split("def take(")[1].split("    def ")[0]
    assert take.index("self.note(heard, state.next_stage)") < take.index("return heard.event")
    note = (ROOT / "coordinator" / "inbound.py").read_text().split("def note(")[1].split("    def ")[0]
    assert "self.heard[heard.carrier] = heard.at" in note
    peers = (ROOT / "carriers" / "inbound.py").read_text().split("def _peer(")[1]
    assert peers.index("key-mismatch") < peers.index("self.presence.heard_from(cid")


def test_a_carrier_waiting_on_the_sim_clock_asks_state():
    """[P-10.8] on the sim clock a carrier waiting for a Decision asks State every decision
    timeout: a decided stage resynchronises, the stage still collected re-sends its Observation."""
    c = mc.initial("a", (True,) * 2, (0.0, 5.0), 1)
    c, _ = mc.step(c, mc.Joined(0))
    c, _ = mc.step(c, mc.Observed(0, 1, (0.0, 0.0)))
    _, effects = mc.step(c, mc.Collecting(0))
    assert effects == (mc.ResendObservation(0),)
    seen = mc.StateSeen(3, (), None, False)  # decided past the stage it waits at: resync
    assert mc.waited_state(seen, 2, (0.0, 0.0)) == mc.Resync(seen, (0.0, 0.0))
    assert mc.waited_state(seen, 3, (0.0, 0.0)) == mc.Collecting(3, 1, "")
    assert mc.waited_state(seen, 5, (0.0, 0.0)) == mc.Resync(seen, (0.0, 0.0))  # the coordinator behind it
    joining = (ROOT / "carriers" / "joining.py").read_text().split("def recover_decision(")[1]
    assert "mc.waited_state(" in joining.split("def resync(")[0]


def test_presence_follows_the_token():
    """[P-10.7] the carrier takes the coordinator as absent from the moment its token vanishes."""
    from mission.peers import Presence

    p = Presence(0.0)
    p.coordinator_alive()
    assert p.coordinator_present
    p.coordinator_gone(1.0)
    assert not p.coordinator_present


# --- rules: 11 conformance

def test_the_kit_rules_are_on_the_page():
    """[P-11.1] every rule the carrier kit checks is in the page's carrier kit table, with the rule
    of the page it names."""
    from wire.conformance.rules import RULES

    table = PAGE.split("**The carrier kit.**")[1].split("**The coordinator kit.**")[0]
    book = rules()
    for rule, section, _ in RULES:
        assert f"| `{rule}` | {section} |" in table, rule
        assert set(CITED.findall(section)) <= set(book) and CITED.findall(section), (rule, section)


def test_the_coordinator_kit_rules_are_on_the_page():
    """[P-11.1] every rule the coordinator kit checks is in the page's coordinator kit table, with
    rule ids of the page."""
    from wire.conformance.coordrules import COORDINATOR_RULES

    table = PAGE.split("**The coordinator kit.**")[1].split("\n## ")[0]
    assert "| rule | rule of this page | the coordinator ... |" in table
    book = rules()
    for rule, _, _ in COORDINATOR_RULES:
        row = next((line for line in table.splitlines() if line.startswith(f"| `{rule}` |")), None)
        assert row is not None, rule
        ids = CITED.findall(row.split("|")[2])
        assert ids and set(ids) <= set(book), (rule, ids)


def test_choosing_an_epoch(tmp_path):
    """[P-7.1] 1 for a fresh mission; one more than the highest used before at every resumption;
    at least the floor a standby learnt from the primary's State."""
    from storage.missiondb import MissionStore

    meta = {"mission": "tiny", "seed": 7, "planner": "ssap"}
    path = tmp_path / "mission.db"
    first = MissionStore(path, meta)
    assert first.epoch == 1
    first.close()
    second = MissionStore(path, meta)
    assert second.epoch == 2
    second.event("epoch", epoch=6)  # what revisions 1 to 5 wrote when a carrier's Hello said 5
    second.close()
    assert MissionStore(path, meta).epoch == 7
    assert MissionStore(tmp_path / "standby.db", meta, min_epoch=4).epoch == 4


def test_an_epoch_above_the_wires_range_is_never_taken(tmp_path):
    """[P-7.1], [P-1.6] a coordinator whose next epoch would be above 2^31 - 1 (what a State of
    the highest epoch would make a standby take) refuses to open the mission, writing nothing,
    instead of taking an epoch no message can carry."""
    from storage.missiondb import EpochsExhausted, MissionStore, highest_epoch

    meta = {"mission": "tiny", "seed": 7, "planner": "ssap"}
    path = tmp_path / "mission.db"
    MissionStore(path, meta, min_epoch=2**31 - 1).close()
    assert highest_epoch(path) == 2**31 - 1
    with pytest.raises(EpochsExhausted, match="above the highest the protocol carries"):
        MissionStore(path, meta)
    with pytest.raises(EpochsExhausted):
        MissionStore(tmp_path / "standby.db", meta, min_epoch=2**31)
    assert highest_epoch(path) == 2**31 - 1 and highest_epoch(tmp_path / "standby.db") == 0


def test_a_decision_of_the_coordinator_that_comes_back_counts_every_own():
    """[P-8.6] an Own is the truth about that carrier at that stage whichever stage the
    coordinator is at: counted as deployed, the carrier not waited for there, its passenger
    recorded as unknown."""
    s = accepted(accepted(ms.initial(spec(3)), "a"), "b")
    for cid in ("a", "b"):
        s, _ = ms.step(s, ev.LivelinessChanged(cid, True))
    s, effects = ms.step(s, ev.Accounted("a", 1, 5.0, 2, True, (0.0, 0.0), 0))  # ahead of the coordinator
    assert rejections(effects) == []
    assert s.deployed()[0, 1] and "a" not in s.expected(1)
    assert s.releases()[0, 1] == -1  # which passenger: unknown


def test_puts_are_reliable_and_scouting_is_off():
    """[P-1.1] every put of a message goes through a declared publisher, reliable with congestion
    control BLOCK; the fleet's Zenoh configuration turns multicast scouting off."""
    import json

    from wire import zconfig

    put = (ROOT / "wire" / "transport.py").read_text().split("    def put(")[1].split("    def put_raw(")[0]
    assert "declare_publisher(" in put and "Reliability.RELIABLE" in put and "CongestionControl.BLOCK" in put
    assert "session.put(" not in put
    conf = zconfig.make_config("client", connect=["tcp/127.0.0.1:7447"])
    assert json.loads(conf.get_json("scouting/multicast/enabled")) is False


@pytest.mark.parametrize("left, valid", [(0, True), (1, False)])
def test_a_carrier_deciding_alone_never_deploys_what_it_cannot(left, valid):
    """[P-8.4] deciding alone: never a deployment without a passenger or at a stage it is not
    scheduled at; the outcome is logged before the Own that announces it."""
    c = mc.initial("a", (valid,), (0.0,), left)
    c, _ = mc.step(c, mc.Joined(0))
    c, _ = mc.step(c, mc.Observed(0, 1, (0.0, 0.0)))
    c, effects = mc.step(c, mc.DecidedOwn(0, True, (0.0, 0.0)))
    assert [type(e) for e in effects] == [mc.LogOutcome, mc.SendOwn]
    assert effects[1].deployed is False and c.passengers_left == left


def test_end_is_broadcast_with_its_epoch_in_the_lowest_revision():
    """[P-9.1] End goes out in the broadcast revision [P-4.2] with the coordinator's epoch
    (revision 4 states it, 1 included [P-7.4]; revision 3 has no such field), repeated."""
    end = wm.End(M, 3, "complete", 1)
    assert msgpack.unpackb(wm.encode(end, 4))["epoch"] == 1
    assert "epoch" not in msgpack.unpackb(wm.encode(end, 3))
    life = (ROOT / "mission" / "coordinator_life.py").read_text().split("def _end(")[1]
    assert "tm.end_due(life.last_end, life.ended_at, now, w.end_repeat_s, w.bye_s)" in life
    step = " ".join((ROOT / "coordinator" / "node.py").read_text().split("    def step(")[1].split("    def ")[0].split())
    assert "self.crew.effects.end_recorded(self.state, effect.reason, self.crew.epochs)" in step
    effects = " ".join((ROOT / "coordinator" / "effects.py").read_text().split())
    assert "state.end_reason or reason, epochs.epoch, epochs.ident)" in effects
    assert "self.node.put(keys.end_key(self.mission), self.end_message, state.common_revision(REVISION))" in effects


@pytest.mark.parametrize("revision", sorted(int(p.name[1:]) for p in (ROOT / "tests" / "fixtures" / "wire").glob("r*")))
def test_each_revisions_fixtures_are_accepted(revision):
    """[P-11.3] what a carrier of each published revision sends, today's receiver accepts as it
    is, and re-encoded for that revision it is the same map."""
    import json

    doc = json.loads((ROOT / "tests" / "fixtures" / "wire" / f"r{revision}" / "messages.json").read_text())
    for kind, samples in doc["carrier_sends"].items():
        for sample in samples:
            message = wm.decode(msgpack.packb(sample))
            assert type(message).TYPE == kind
            assert msgpack.unpackb(wm.encode(message, revision)) == sample
