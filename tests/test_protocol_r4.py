"""Revision 4 of the fleet protocol and the rules of docs/protocol.md the code changed for it, each
test naming the rule it checks ([P-s.n]): nil read as absent, End's epoch, the mission's clock on
Accepted, a Decision gap resynchronised from State, no stall for lack of Progress from a
carrier that has none, and what a peer of revision 3 gets and sends. State-machine rules are
tables of events; what needs the network runs on real Zenoh sessions on loopback."""
from __future__ import annotations

import contextlib
import dataclasses
import os
import queue
import socket
import threading
import time

import msgpack
import pytest

import world
from carriers.node import Carrier, CarrierConfig
from fleet_helpers import TINY, InProcessFleet, Quiet
from mission import carrier as mc
from mission import events as ev
from mission import state as ms
from wire import keys
from wire import messages as wm
from wire.transport import Node
from wire.zconfig import free_port, make_config

M = "tiny"
P0 = (0.0, 0.0)

#: One message of every type with every optional field off its default (so nil can be told
#: from a value), and CarrierState inside State.
SAMPLES = {
    "hello": wm.Hello(M, "a", 1, "h", 1, 0, "f", epoch=2, revision=4),
    "obs": wm.Observation(M, "a", 0, 0.0, 1, P0, 1, (), counts=(1, 0)),
    "decision": wm.Decision(M, 1, 5.0, ("a",), 1.0, epoch=2, passengers=(1,), coordinator="standby"),
    "confirm": wm.Confirm(M, "a", 1, True, "deployed", P0, 1, passenger=1),
    "own": wm.Own(M, "a", 0, 0.0, 2, False, P0, 1, counts=(2,)),
    "end": wm.End(M, 4, "complete", epoch=2, coordinator="standby"),
    "bye": wm.Bye(M, "a", (0,), (("deposed", 1),), "end"),
    "state": wm.State(mission=M, next_stage=2, stages=4, fingerprint="f", ended=False,
                      carriers=(("a", wm.CarrierState(1, (0,), True, "world-mismatch", (("duplicate", 1),))),),
                      last_decision=wm.Decision(M, 1, 5.0, ("a",), 1.0, epoch=2), epoch=2, revision=4,
                      coordinator="standby"),
    "refusal": wm.Refusal(M, "a", "unknown-carrier", "f", "g", detail="not in the scenario"),
    "pose": wm.Pose(M, "a", 1.0, P0, 0.5, 1),
    "accepted": wm.Accepted(M, "a", "f", 0, 0, 4, epoch=2, clock="wall", silence_timeout_s=7.5, realtime=2.0,
                            coordinator="standby"),
    "progress": wm.Progress(M, "a", 0, 0.0),
    "operator": wm.OperatorAction(M, "op1", 1, 0, "force", carrier="a", token="t"),
    "operator-answer": wm.OperatorAnswer(M, "op1", 1, 0, False, reason="stale-stage", detail="stage 0 is decided"),
}


def _optional_fields(cls) -> list[str]:
    return [f.name for f in dataclasses.fields(cls) if "absent" in f.metadata]


def _required_fields(cls) -> list[str]:
    return [f.name for f in dataclasses.fields(cls) if "absent" not in f.metadata and f.name != "v"]


OPTIONAL = [(kind, name) for kind, sample in SAMPLES.items() for name in _optional_fields(type(sample))]
REQUIRED = [(kind, name) for kind, sample in SAMPLES.items() for name in _required_fields(type(sample))]
#: Required fields that take nil as a value of their own (nullable).
NULLABLE = {("obs", "x"), ("own", "x"), ("state", "last_decision")}


def _decode_with(kind: str, name: str, value) -> object:
    raw = wm._to_wire(SAMPLES[kind])
    raw[name] = value
    if name == "x" and value is None:
        raw.pop("counts", None)  # [P-6.14] counts only with an x
    return wm.decode(msgpack.packb(raw, use_bin_type=True))


# --------------------------------------------------------------------------- [P-1.3] nil and absent

def test_every_message_type_has_a_sample():
    """[P-1.3] the tables below cover every message type there is (a new one needs a sample)."""
    assert {type(s).TYPE for s in SAMPLES.values()} == set(wm.MESSAGE_TYPES)
    for kind, sample in SAMPLES.items():
        assert wm.decode(wm.encode(sample)) == sample, kind
        for name in _optional_fields(type(sample)):  # off the default: a nil read as absent shows
            field = next(f for f in dataclasses.fields(sample) if f.name == name)
            assert getattr(sample, name) != field.metadata["absent"], (kind, name)


@pytest.mark.parametrize("kind, name", OPTIONAL, ids=[f"{k}.{n}" for k, n in OPTIONAL])
def test_nil_in_an_optional_field_is_read_as_absent(kind, name):
    """[P-1.3] a receiver treats nil in an optional field exactly as the field being absent: the
    message decodes as if the key were not there (its default), every other field unchanged."""
    field = next(f for f in dataclasses.fields(SAMPLES[kind]) if f.name == name)
    with_nil = _decode_with(kind, name, None)
    raw = wm._to_wire(SAMPLES[kind])
    del raw[name]
    without = wm.decode(msgpack.packb(raw, use_bin_type=True))
    assert with_nil == without == dataclasses.replace(SAMPLES[kind], **{name: field.metadata["absent"]})


@pytest.mark.parametrize("name", _optional_fields(wm.CarrierState))
def test_nil_in_an_optional_field_of_carrier_state_is_read_as_absent(name):
    """[P-1.3] the same inside State's CarrierState maps."""
    raw = wm._to_wire(SAMPLES["state"])
    raw["carriers"]["a"][name] = None
    entry = wm.decode(msgpack.packb(raw)).carrier("a")
    field = next(f for f in dataclasses.fields(wm.CarrierState) if f.name == name)
    assert getattr(entry, name) == field.metadata["absent"]


@pytest.mark.parametrize("kind, name", REQUIRED, ids=[f"{k}.{n}" for k, n in REQUIRED])
def test_nil_in_a_required_field_keeps_its_reason(kind, name):
    """[P-1.3] nil in a required field that is not nullable is ``wrong-type``; a nullable one
    takes nil as its value."""
    if (kind, name) in NULLABLE:
        assert getattr(_decode_with(kind, name, None), name) is None
        return
    with pytest.raises(wm.ProtocolError) as info:
        _decode_with(kind, name, None)
    assert info.value.reason == "wrong-type", info.value


@pytest.mark.parametrize("name", ["v", "type"])
def test_nil_v_and_type_are_missing_fields(name):
    """[P-1.3] nil ``v`` and nil ``type`` are rejected with the reason of absent ones."""
    raw = wm._to_wire(SAMPLES["obs"])
    absent = {k: v for k, v in raw.items() if k != name}
    for body in ({**raw, name: None}, absent):
        with pytest.raises(wm.ProtocolError) as info:
            wm.decode(msgpack.packb(body))
        assert info.value.reason == "missing-field"


@pytest.mark.parametrize("kind", sorted(SAMPLES))
def test_a_sender_omits_an_optional_field_at_its_default(kind):
    """[P-1.3] a sender omits an optional field rather than send nil."""
    cls = type(SAMPLES[kind])
    defaults = {name: next(f for f in dataclasses.fields(cls) if f.name == name).metadata["absent"]
                for name in _optional_fields(cls)}
    sent = msgpack.unpackb(wm.encode(dataclasses.replace(SAMPLES[kind], **defaults)))
    assert not set(defaults) & set(sent), kind
    assert None not in [v for k, v in sent.items() if k not in NULLABLE_KEYS.get(kind, ())]


NULLABLE_KEYS = {"obs": ("x",), "own": ("x",), "state": ("last_decision",)}


# --------------------------------------------------------------------------- revision 4 on the wire

def test_revision_4_fields_exist_from_revision_4_only():
    """[P-4.5] [P-7.4] [P-10.2] revision 4 adds End ``epoch`` and Accepted ``clock``,
    ``silence_timeout_s``, ``realtime``: a reader of revision 3 finds them ``unknown-field``, an
    encoder for revision 3 leaves them out, and the revision-3 Accepted is still sent (its
    enumerated ``clock`` is not a revision-3 value, but revision 3 has no such field)."""
    assert wm.REVISION >= 4
    for kind, names in (("end", {"epoch"}), ("accepted", {"clock", "silence_timeout_s", "realtime"})):
        sample = SAMPLES[kind]
        assert names <= set(msgpack.unpackb(wm.encode(sample)))
        assert not names & set(msgpack.unpackb(wm.encode(sample, 3)))
        with pytest.raises(wm.ProtocolError) as info:
            wm.decode(wm.encode(sample), revision=3)
        assert info.value.reason == "unknown-field"
        assert wm.defined_in(sample, 3)
    assert not wm.defined_in(SAMPLES["accepted"], 2)


def test_revision_5_counts_exist_from_revision_5_only():
    """[P-6.14] revision 5 adds Observation and Own ``counts``: an encoder for revision 4 leaves
    them out, and a reader of revision 4 finds them ``unknown-field``."""
    assert wm.REVISION >= 5
    for kind in ("obs", "own"):
        sample = SAMPLES[kind]
        assert "counts" in msgpack.unpackb(wm.encode(sample))
        assert "counts" not in msgpack.unpackb(wm.encode(sample, 4))
        with pytest.raises(wm.ProtocolError) as info:
            wm.decode(wm.encode(sample), revision=4)
        assert info.value.reason == "unknown-field"


def test_accepted_clock_defaults_and_ranges():
    """[P-10.2] absent = the sim clock, a 30 s silence timeout, unpaced (protocol constants, not
    the command line's defaults); ``clock`` is ``sim`` or ``wall``, the silence timeout > 0, the
    pace >= 0."""
    assert wm.ACCEPTED_ABSENT == ("sim", 30.0, 0.0)
    bare = wm.Accepted(M, "a", "f", 0, 0, 4)
    assert (bare.clock, bare.silence_timeout_s, bare.realtime) == wm.ACCEPTED_ABSENT
    assert not {"clock", "silence_timeout_s", "realtime"} & set(msgpack.unpackb(wm.encode(bare)))
    assert wm.decode(wm.encode(SAMPLES["accepted"])).clock == "wall"
    for name, value, reason in (("clock", "lockstep", "out-of-range"), ("clock", 1, "wrong-type"),
                                ("silence_timeout_s", 0, "out-of-range"), ("silence_timeout_s", -1.0, "out-of-range"),
                                ("silence_timeout_s", "30", "wrong-type"), ("realtime", -0.5, "out-of-range"),
                                ("realtime", float("nan"), "out-of-range")):
        with pytest.raises(wm.ProtocolError) as info:
            _decode_with("accepted", name, value)
        assert info.value.reason == reason, (name, value)
    assert _decode_with("accepted", "realtime", 0).realtime == 0.0


def test_end_epoch_is_stated_or_not():
    """[P-7.4] End ``epoch``: a stated epoch (1 included, a revision-4 coordinator always states
    it) or none (None: an End of an earlier revision); nil is none ([P-1.3])."""
    for epoch in (1, 2):
        end = wm.End(M, 4, "complete", epoch)
        assert msgpack.unpackb(wm.encode(end))["epoch"] == epoch and wm.decode(wm.encode(end)) == end
    old = wm.decode(msgpack.packb({"v": 1, "type": "end", "mission": M, "stages": 4, "reason": "complete"}))
    assert old.epoch is None and _decode_with("end", "epoch", None).epoch is None
    for value, reason in ((0, "out-of-range"), (2**31, "out-of-range"), ("2", "wrong-type")):
        with pytest.raises(wm.ProtocolError) as info:
            _decode_with("end", "epoch", value)
        assert info.value.reason == reason


# --------------------------------------------------------------------------- [P-7.4] End and epochs

@pytest.mark.parametrize("heard, end_epoch, ends", [
    (0, None, True), (0, 1, True), (1, 1, True), (2, 1, False), (2, 2, True), (2, 3, True),
    (3, None, True),  # an End stating no epoch (revisions 1-3: a restarted one has epoch >= 2) is acted on
], ids=["none-heard", "first", "equal", "deposed", "current", "newer", "unstated"])
def test_a_carrier_ignores_a_deposed_coordinators_end(heard, end_epoch, ends):
    """[P-7.4] a carrier ignores an End whose epoch is lower than the highest it has heard
    (rejected ``deposed``: counted and reported in its Bye); any other End ends its mission."""
    state = mc.initial("a", (True,) * 4, (0.0, 5.0, 10.0, 15.0), 2)
    state, _ = mc.step(state, mc.Joined(0, epoch=max(1, heard)))
    state = dataclasses.replace(state, epoch=heard)
    new, effects = mc.step(state, mc.EndHeard(end_epoch))
    assert new.ended is ends
    assert [e.reason for e in effects if isinstance(e, mc.Reject)] == ([] if ends else ["deposed"])
    if not ends:
        assert new == dataclasses.replace(state, outranked=True)  # the live coordinator is outranked


# --------------------------------------------------------------------------- [P-10.2] the mission's clock

OWN = mc.Timers("wall", 30.0, 0.0)


@pytest.mark.parametrize("told, repace, expected, lines", [
    (None, True, OWN, 0),                                          # revision < 4: it said nothing
    (OWN, True, OWN, 0),
    (mc.Timers("sim", 30.0, 0.0), True, mc.Timers("sim", 30.0, 0.0), 1),
    (mc.Timers("sim", 9.0, 2.0), True, mc.Timers("sim", 9.0, 2.0), 3),
    (mc.Timers("sim", 9.0, 2.0), False, mc.Timers("sim", 9.0, 0.0), 3),  # a robot keeps its pace
], ids=["unsaid", "same", "clock", "all", "robot"])
def test_a_carrier_follows_the_missions_clock(told, repace, expected, lines):
    """[P-10.2] a carrier uses the coordinator's clock and silence timeout for its own timers
    when Accepted carries them, and its pace unless its body is a robot; one line per setting
    that differed."""
    timers, said = mc.follow(OWN, told, repace)
    assert timers == expected and len(said) == lines
    assert all("coordinator's" in line for line in said)


# --------------------------------------------------------------------------- [P-6.6] a Decision gap

TIMES = (0.0, 5.0, 10.0, 15.0)


def _carrier(*events, passengers=3):
    state = mc.initial("a", (True,) * 4, TIMES, passengers)
    effects = ()
    for e in events:
        state, effects = mc.step(state, e)
    return state, effects


def _heard(j, deploy=("a",)):
    return mc.DecisionHeard(j, TIMES[j], tuple(deploy), P0)


def _confirms(effects):
    return [(e.stage, e.status, e.deployed) for e in effects if isinstance(e, mc.SendConfirm)]


@pytest.mark.parametrize("before, event, asks", [
    ([mc.Joined(0), mc.Observed(0)], _heard(1), True),                          # waits at 0, gets 1
    ([mc.Joined(0), mc.Observed(0)], _heard(3), True),                          # k = 3
    ([mc.Joined(0), mc.Observed(0), _heard(0), mc.MovedOn(0)], _heard(2), True),  # driving to 1, gets 2
    ([mc.Joined(0), mc.Observed(0)], _heard(0), False),                         # the one it waits for
    ([mc.Joined(0), mc.Observed(0), _heard(0), mc.MovedOn(0)], _heard(1), False),  # the next one
    ([mc.Joined(2)], _heard(1), False),                                          # before it joined
    ([], _heard(2), False),                                                      # while it joins
    ([mc.Joined(0), mc.Observed(0), mc.DecidedOwn(0, False, P0), mc.MovedOn(0)], _heard(1), False),  # its own
    ([mc.Joined(0), mc.Observed(0), _heard(2)], _heard(2), False),               # a repeat: asked once
], ids=["k2", "k3", "driving", "awaited", "next", "before-join", "joining", "decided-itself", "repeat"])
def test_a_decision_gap_asks_state_before_confirming(before, event, asks):
    """[P-6.6] a Decision of j+k (k >= 2) without the Decision of j+1 the carrier waits for (or
    will reach) makes it resynchronise from State (:class:`AskState`) and confirm nothing yet."""
    state, _ = _carrier(*before)
    _, effects = mc.step(state, event)
    assert (mc.AskState(event.stage) in effects) is asks
    if asks:
        assert _confirms(effects) == []


def test_a_gap_takes_the_lost_stages_from_state():
    """[P-6.6] waiting at stage 0, the carrier gets Decision 2 (0 and 1 lost); State says it was
    selected at 0 (CarrierState ``deployments``) and not at 1: it deploys at 0 at once (its body is
    at t_0), passes 1 idle and deploys at 2 as the Decision it got says, so it released exactly
    the passengers the coordinator counts."""
    state, effects = _carrier(mc.Joined(0), mc.Observed(0), _heard(2))
    assert mc.AskState(2) in effects
    seen = mc.StateSeen(next_stage=3, deployments=(0, 2), last_decision=(2, 10.0, ("a",)), ended=False)
    state, effects = mc.step(state, mc.Resync(seen, P0, gap=2))
    assert _confirms(effects) == [(0, "deployed", True)] and mc.Deploy(0) in effects
    assert any(isinstance(e, mc.SendHello) for e in effects)
    assert state.resolved(0) and state.passengers_left == 2
    state, _ = mc.step(state, mc.MovedOn(0))
    assert state.behind(1)
    state, effects = mc.step(state, mc.Passed(1, P0))
    assert _confirms(effects) == [(1, "idle", False)]
    state, effects = mc.step(state, mc.Passed(2, P0))
    assert _confirms(effects) == [(2, "deployed", True)]
    assert state.deployments() == seen.deployments and state.passengers_left == 1


def test_a_gap_without_state_confirms_nothing_it_does_not_know():
    """[P-6.6] no State answered (or only a deposed coordinator's): the lost stage is not made
    up; the carrier says Hello again and goes on as the Decision it got says."""
    state, _ = _carrier(mc.Joined(0, epoch=2), mc.Observed(0), _heard(1))
    for seen in (None, mc.StateSeen(2, (0,), None, False, epoch=1)):
        new, effects = mc.step(state, mc.Resync(seen, P0, gap=1))
        assert _confirms(effects) == [] and any(isinstance(e, mc.SendHello) for e in effects)
        assert 0 not in new.handled


# --------------------------------------------------------------------------- [P-10.4] no Progress, no stall

def test_carriers_without_progress_are_the_revisions_before_3():
    """[P-10.4] the carriers a coordinator never takes as stalled for silence: those whose
    accepted Hello announced a revision < 3 (none announced: 1)."""
    spec = ms.MissionSpec.build(("a", "b", "c"), [[True]] * 3, (1, 1, 1), (0.0,), "f")
    s = ms.initial(spec)
    for cid, revision in (("a", 1), ("b", 2), ("c", 3)):
        s, _ = ms.step(s, ev.Hello(cid, 1, "h", 1, 0, "f", 0.0, revision))
    assert s.without_progress(("a", "b", "c")) == {"a", "b"}
    assert s.without_progress(("c", "zz")) == frozenset()
    assert ms.PROGRESS_REVISION == wm.Progress.SINCE


def _raw_carrier(endpoint: str, revision: int | None, delay_s: float, x: int, result: dict) -> None:
    """A carrier that sends no Progress: State, Hello (announcing ``revision``; None: none, as
    revisions 1 and 2), then its Observation of stage 0 ``delay_s`` after the Hello."""
    node = Node(make_config("client", [], [endpoint]), open_timeout_s=30.0)
    try:
        node.token(keys.carrier_alive(M, "a"))
        selector = keys.state_selector(M, "a", revision) if revision else f"{keys.state_key(M)}?carrier=a"
        deadline = time.monotonic() + 30
        replies = []
        while not replies and time.monotonic() < deadline:
            replies = node.query(selector)
        state = wm.decode(replies[0], wm.State)
        speak = 1 if revision is None else min(revision, state.revision)
        node.put(keys.carrier_key(M, "a", "hello"), wm.Hello(M, "a", os.getpid(), socket.gethostname(), 2, 0,
                                                              state.fingerprint, revision=revision or 1), speak)
        time.sleep(delay_s)
        node.put(keys.carrier_key(M, "a", "obs"), wm.Observation(M, "a", 0, 0.0, x, (4.0, 20.0), 2, ()), speak)
        result["sent"] = True
        time.sleep(1.0)
    finally:
        node.close(3.0)


@pytest.mark.parametrize("revision, counted", [(None, True), (3, False)], ids=["revision-1", "revision-3"])
def test_a_carrier_without_progress_gets_the_stage_timeout(tmp_path, revision, counted):
    """[P-10.4] sim clock, silence timeout 1 s, stage timeout 10 s: a carrier of revision 1 (no
    Progress) whose Observation of stage 0 comes 3 s late is waited for and its value counts; a
    carrier of revision 3 that sends no Progress for as long is stalled and ∅ at stage 0."""
    alone = tmp_path / "tiny.yaml"  # tiny with carrier a only: the mission starts once a has joined
    text = TINY.read_text()
    alone.write_text(text[:text.index("  - id: b")] + text[text.index("planner:"):])
    scenario = world.load_scenario(alone)
    assert scenario.carrier_ids == ("a",) or list(scenario.carrier_ids) == ["a"]
    fleet = InProcessFleet(scenario, tmp_path / "run", join_timeout_s=60.0, silence_timeout_s=1.0,
                           stage_timeout_s=10.0)
    fleet.start_coordinator()
    result: dict = {}
    thread = threading.Thread(target=_raw_carrier, args=(fleet.endpoint, revision, 3.0, 7, result), daemon=True)
    thread.start()
    coordinator = fleet.coordinator
    deadline = time.monotonic() + 60
    while 0 not in coordinator.state.decisions and time.monotonic() < deadline:
        time.sleep(0.05)
    reported = coordinator.state.reported.get(("a", 0))
    coordinator.stop()
    thread.join(30)
    fleet.join(60)
    assert result.get("sent") and 0 in coordinator.state.decisions
    assert reported == (7 if counted else None)
    if counted:
        assert not any("stalled" in line for line in fleet.log.lines), fleet.log.lines
    else:
        assert any("stage 0: nothing from a" in line and "stalled" in line for line in fleet.log.lines)


# --------------------------------------------------------------------------- real sessions: End and Accepted

class ScriptedCoordinator:
    """A coordinator played by the test on a real Zenoh session (peer mode, listening): its
    token, a State answer of ``epoch`` and ``revision`` (None: a coordinator of revision 1 or 2,
    which announces none), and what the test publishes; it records the carriers' messages."""

    def __init__(self, scenario, epoch: int, revision: int | None):
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.fingerprint = wm.scenario_fingerprint(scenario)
        self.epoch, self.revision, self.stages = epoch, revision, scenario.stages
        # What State says (the test changes it as the mission it plays goes on).
        self.next_stage, self.deployments, self.last_decision = 0, (), None
        self.node = Node(make_config("peer", [self.endpoint]))
        self.node.subscribe(f"{keys.prefix(M)}/carrier/**")
        self.node.serve(keys.state_key(M), self.state)
        self.node.token(keys.coordinator_alive(M))
        self.heard: "queue.Queue[wm.Hello | wm.Bye | wm.Observation]" = queue.Queue()
        self._stop = threading.Event()
        self._pump = threading.Thread(target=self._receive, daemon=True)
        self._pump.start()

    def state(self, parameters) -> bytes:
        asked = keys.asked_revision(parameters, self.revision or 1, 1)
        left = 2 - len(self.deployments)
        carriers = (("a", wm.CarrierState(left, tuple(self.deployments), True)),)
        return wm.encode(wm.State(mission=M, next_stage=self.next_stage, stages=self.stages,
                                  fingerprint=self.fingerprint, ended=False, carriers=carriers,
                                  last_decision=self.last_decision, epoch=self.epoch,
                                  revision=self.revision or 1), asked)

    def _receive(self) -> None:
        while not self._stop.is_set():
            item = self.node.next(0.1)
            if item is None or item.kind != "sample" or item.key.endswith(("/pose", "/progress")):
                continue
            try:
                self.heard.put(wm.decode(item.payload))
            except wm.ProtocolError:
                pass

    def expect(self, cls, timeout_s: float = 30.0):
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            try:
                msg = self.heard.get(timeout=0.1)
            except queue.Empty:
                continue
            if isinstance(msg, cls):
                return msg
        return None

    def put(self, key: str, message, revision: int) -> None:
        self.node.put(key, message, revision)

    def close(self) -> None:
        self._stop.set()
        self._pump.join(5)
        self.node.close(3.0)


@contextlib.contextmanager
def _flying(scenario, coordinator: ScriptedCoordinator, **options):
    """A real carrier ``a`` (coordinated) flying against ``coordinator``: yields (carrier, its
    thread, {"reason": how its run ended}); stops both and closes the coordinator afterwards."""
    carrier = Carrier(scenario, CarrierConfig("a", log=Quiet(), mode="coordinated", **options),
                      make_config("client", [], [coordinator.endpoint]))
    out: dict = {}
    thread = threading.Thread(target=lambda: out.setdefault("reason", carrier.run()), daemon=True)
    try:
        thread.start()
        yield carrier, thread, out
    finally:
        carrier.stop()
        thread.join(30)
        coordinator.close()


def test_a_deposed_coordinators_end_does_not_end_the_mission():
    """[P-7.4] [P-10.2] a real carrier joins a coordinator of epoch 3 (revision 4): Accepted
    gives it the mission's clock, which its timers follow; an End of epoch 2 (a deposed
    coordinator's) is rejected ``deposed`` and the carrier flies on; the End of epoch 3 ends
    it: Bye ``end`` with the rejection counted."""
    tiny = world.load_scenario(TINY)
    coordinator = ScriptedCoordinator(tiny, epoch=3, revision=4)
    with _flying(tiny, coordinator, clock="wall", silence_timeout_s=30.0) as (carrier, thread, out):
        hello = coordinator.expect(wm.Hello)
        assert hello is not None and hello.epoch == 3 and hello.revision == wm.REVISION
        coordinator.put(keys.accepted_key(M, "a"), wm.Accepted(
            M, "a", coordinator.fingerprint, 0, 0, 4, epoch=3, clock="sim", silence_timeout_s=9.0, realtime=0.0), 4)
        assert coordinator.expect(wm.Observation) is not None
        deadline = time.monotonic() + 10
        while carrier.timers != mc.Timers("sim", 9.0, 0.0) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert carrier.timers == mc.Timers("sim", 9.0, 0.0)
        # Somebody else's Refusal (another fingerprint) and a deposed coordinator's End: ignored.
        coordinator.put(keys.refusal_key(M, "a"), wm.Refusal(M, "a", "world-mismatch", "0" * 16,
                                                             coordinator.fingerprint), 4)
        coordinator.put(keys.end_key(M), wm.End(M, 0, "complete", epoch=2), 4)
        assert coordinator.expect(wm.Bye, timeout_s=2.0) is None and thread.is_alive()
        coordinator.put(keys.end_key(M), wm.End(M, 0, "complete", epoch=3), 4)
        bye = coordinator.expect(wm.Bye)
        thread.join(30)
    assert bye is not None and bye.reason == "end" and dict(bye.rejected) == {"deposed": 1}
    assert out["reason"] == "end"


def test_each_answer_only_on_its_own_key_and_for_its_own_carrier():
    """[P-2.4] [P-3.3] a real carrier: an Accepted on the refusal key is rejected ``unknown-type``,
    an answer naming another carrier on its key ``key-mismatch`` (the envelope's mission is
    checked first, then the carrier against the key); its own Accepted is then taken, and its
    Bye counts both rejections."""
    tiny = world.load_scenario(TINY)
    coordinator = ScriptedCoordinator(tiny, epoch=1, revision=4)
    with _flying(tiny, coordinator) as (carrier, thread, out):
        assert coordinator.expect(wm.Hello) is not None
        mine = wm.Accepted(M, "a", coordinator.fingerprint, 0, 0, 4, epoch=1)
        coordinator.put(keys.refusal_key(M, "a"), mine, 4)
        coordinator.put(keys.accepted_key(M, "a"), dataclasses.replace(mine, carrier="b"), 4)
        time.sleep(0.5)
        assert carrier.crew.inbound.answer.unanswered is True
        coordinator.put(keys.accepted_key(M, "a"), mine, 4)
        assert coordinator.expect(wm.Observation) is not None
        coordinator.put(keys.end_key(M), wm.End(M, 0, "complete", epoch=1), 4)
        bye = coordinator.expect(wm.Bye)
        thread.join(30)
    assert bye is not None and dict(bye.rejected) == {"unknown-type": 1, "key-mismatch": 1}


def test_a_confirms_status_is_checked_in_table_order():
    """[P-3.3] Confirm ``status`` (an enumeration, before ``position`` in its table) is checked in
    its turn: a bad status with a bad position is ``out-of-range``, not ``wrong-type``."""
    good = msgpack.unpackb(wm.encode(wm.Confirm(M, "a", 1, False, "idle", (0.0, 0.0), 1)))
    for bad in ({**good, "status": "gone", "position": "here"}, {**good, "status": "gone"}):
        with pytest.raises(wm.ProtocolError) as err:
            wm.decode(msgpack.packb(bad))
        assert err.value.reason == "out-of-range" and "status" in err.value.detail
    with pytest.raises(wm.ProtocolError) as err:
        wm.decode(msgpack.packb({**good, "position": "here"}))
    assert err.value.reason == "wrong-type"


def test_joining_an_ended_mission_says_hello_at_states_next_stage():
    """[P-5.5] State ``ended`` at the first join: the carrier's Hello (before its Bye ``end``)
    says State's ``next_stage``."""
    state = mc.initial("a", [True] * 4, [0.0, 10.0, 20.0, 30.0], 2)
    state, effects = mc.step(state, mc.Joined(4, ended=True, epoch=2))
    assert state.ended and effects == () and state.hello_stage() == 4


def test_a_revision_4_carrier_with_a_revision_3_coordinator():
    """[P-4.5] [P-7.4] [P-10.2] a coordinator of revision 3 restarted (epoch 2): its Accepted
    says nothing of the clock (the carrier keeps its own timers) and its End states no epoch,
    which the carrier of revision 4 acts on: Bye ``end``, nothing rejected; everything the
    carrier sent reads at revision 3."""
    tiny = world.load_scenario(TINY)
    coordinator = ScriptedCoordinator(tiny, epoch=2, revision=3)
    with _flying(tiny, coordinator, clock="wall", silence_timeout_s=12.0) as (carrier, thread, out):
        hello = coordinator.expect(wm.Hello)
        assert hello is not None and hello.revision == wm.REVISION and hello.epoch == 2
        coordinator.put(keys.accepted_key(M, "a"), wm.Accepted(M, "a", coordinator.fingerprint, 0, 0, 3, epoch=2), 3)
        assert coordinator.expect(wm.Observation) is not None
        time.sleep(0.5)
        assert carrier.timers == mc.Timers("wall", 12.0, 0.0)
        assert carrier.crew.inbound.answer.unanswered is False  # the Accepted was taken
        coordinator.put(keys.end_key(M), wm.End(M, 0, "complete", epoch=2), 3)  # encoded for revision 3: no epoch
        bye = coordinator.expect(wm.Bye)
        thread.join(30)
    assert bye is not None and bye.reason == "end" and dict(bye.rejected) == {}
    assert out["reason"] == "end"
    assert carrier.node.revision == 3


def _raw_peer(endpoint: str) -> Node:
    return Node(make_config("client", [], [endpoint]), open_timeout_s=30.0)


def test_a_revision_3_carrier_never_receives_revision_4_fields(tmp_path):
    """[P-4.2] [P-7.4] [P-10.2] today's coordinator (sim clock, silence 7 s, paced 2x), a carrier's
    Hello claiming epoch 5 kept as a claim and not adopted [P-7.3] (it stays at 1): carrier ``b`` of revision 4 gets an
    Accepted with the clock; carrier ``a`` of revision 3 an Accepted without it, and the End
    (broadcast in the lowest revision accepted, 3) without epoch; every byte reads at revision 3."""
    tiny = world.load_scenario(TINY)
    fleet = InProcessFleet(tiny, tmp_path / "run", join_timeout_s=60.0, silence_timeout_s=7.0, realtime=2.0)
    fleet.start_coordinator()
    peers = {}
    got: dict[str, "queue.Queue[bytes]"] = {}
    try:
        for cid, revision, epoch in (("b", 4, 5), ("a", 3, 1)):
            node = peers[cid] = _raw_peer(fleet.endpoint)
            node.subscribe(keys.accepted_key(M, cid))
            node.subscribe(keys.end_key(M))
            node.token(keys.carrier_alive(M, cid))
            replies = []
            deadline = time.monotonic() + 30
            while not replies and time.monotonic() < deadline:
                replies = node.query(keys.state_selector(M, cid, revision))
            state = wm.decode(replies[0], wm.State)
            assert state.revision == wm.REVISION
            node.put(keys.carrier_key(M, cid, "hello"), wm.Hello(
                M, cid, os.getpid(), "h", 1, 0, state.fingerprint, epoch=epoch, revision=revision), revision)
            got[cid] = queue.Queue()
            item = node.next(10.0)
            assert item is not None and item.key == keys.accepted_key(M, cid), item
            got[cid].put(item.payload)
        deadline = time.monotonic() + 10
        while "b" not in fleet.coordinator.crew.epochs.claims and time.monotonic() < deadline:
            time.sleep(0.05)
        assert fleet.coordinator.crew.epochs.claims["b"] == 5 and fleet.coordinator.crew.epochs.epoch == 1
        fleet.coordinator.stop()
        for cid, node in peers.items():
            item = node.next(10.0)
            while item is not None and item.key != keys.end_key(M):
                item = node.next(10.0)
            assert item is not None, cid
            got[cid].put(item.payload)
        fleet.join(60)
    finally:
        for node in peers.values():
            node.close(3.0)
    accepted_b, end_b = (msgpack.unpackb(got["b"].get()) for _ in range(2))
    accepted_a, end_a = (msgpack.unpackb(got["a"].get()) for _ in range(2))
    told = wm.decode(msgpack.packb(accepted_b), wm.Accepted)
    assert (told.clock, told.silence_timeout_s, told.realtime, told.epoch) == ("sim", 7.0, 2.0, 1)
    assert {"silence_timeout_s", "realtime"} <= set(accepted_b) and told.revision == wm.REVISION
    assert not {"clock", "silence_timeout_s", "realtime"} & set(accepted_a)
    assert end_a == end_b and "epoch" not in end_a  # one broadcast, in the lowest revision
    for body in (accepted_a, end_a):
        wm.decode(msgpack.packb(body), revision=3)


def test_a_carrier_that_lost_a_decision_takes_it_from_state():
    """[P-6.6] a real carrier waits at stage 0; the coordinator (played here) decided 0 selecting
    it, but that Decision is lost: the carrier gets Decision 1 (nobody deploys). Before confirming
    1 it asks State, which lists its deployment at 0: it deploys at 0 (Confirm ``deployed``, its
    lowest passenger), says Hello from stage 2, answers 1 ``idle`` and goes on at stage 2; its
    Bye reports the deployment at 0, as the coordinator counts it."""
    tiny = world.load_scenario(TINY)
    coordinator = ScriptedCoordinator(tiny, epoch=1, revision=4)
    confirms, hellos = [], []
    with _flying(tiny, coordinator, clock="sim") as (carrier, thread, out):
        assert coordinator.expect(wm.Hello) is not None
        observation = coordinator.expect(wm.Observation)
        assert observation is not None and observation.stage == 0
        decision = wm.Decision(M, 1, 5.0, (), 1.0)
        coordinator.next_stage, coordinator.deployments, coordinator.last_decision = 2, (0,), decision
        coordinator.put(keys.decision_key(M), decision, 4)  # Decision 0 never went out: lost
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            msg = coordinator.expect((wm.Confirm, wm.Hello, wm.Observation), timeout_s=1.0)
            if isinstance(msg, wm.Confirm):
                confirms.append((msg.stage, msg.status, msg.deployed, msg.passenger))
            elif isinstance(msg, wm.Hello):
                hellos.append(msg.next_stage)
            elif isinstance(msg, wm.Observation) and msg.stage == 2:
                break
        else:
            raise AssertionError(f"no Observation of stage 2; confirms {confirms}")
        coordinator.put(keys.end_key(M), wm.End(M, 2, "stopped", epoch=1), 4)
        bye = coordinator.expect(wm.Bye)
        thread.join(30)
    assert confirms[0] == (0, "deployed", True, 0), confirms
    assert (1, "idle", False, None) in confirms and hellos == [2], (confirms, hellos)
    assert bye is not None and bye.deployments == (0,) and dict(bye.rejected) == {}
