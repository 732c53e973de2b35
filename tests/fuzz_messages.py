"""Hostile and broken messages for the fleet's subscribed keys (used by tests/test_fuzz.py).

Every message built here must be rejected by its receiver whatever the mission's progress, so a
fuzzed mission must end exactly like a clean one. What is *not* generated, because it is
indistinguishable from a legitimate message and only authentication stops it (docs/security.md):
a well-formed observation, hello, confirm or bye of a scenario carrier for a stage it has not
reported yet, a well-formed decision or end of this mission, or a liveliness token of a scenario
carrier. Mutations are applied only to messages of another mission, or on keys of carriers that
do not exist, so that no mutation can turn into such a message (the mission name `MUTATION_BASE_MISSION`
is 9 characters long and starts with 'z': at most `MAX_FLIPS` byte changes cannot spell the real id).
"""

from __future__ import annotations

from dataclasses import dataclass

import msgpack
import numpy as np

from wire import keys, messages
from wire.messages import MAX_PAYLOAD_BYTES, Bye, Confirm, Decision, End, Hello, Observation

MUTATION_BASE_MISSION = "zzzzzzzzz"
MAX_FLIPS = 3
UNKNOWN_CARRIERS = ("zz9", "ghost", "c-404")
COORDINATOR_TOPICS = ("hello", "obs", "confirm", "bye")


@dataclass(frozen=True)
class Fuzz:
    """One message to send: which process must reject it, where, what, and why it is bad."""

    target: str  # "coordinator" or "carriers"
    key: str
    payload: bytes
    category: str


def _wire(message) -> dict:
    """The msgpack map of a message without validation (so it can be corrupted)."""
    return messages._to_wire(message)


def _pack(obj) -> bytes:
    return msgpack.packb(obj, use_bin_type=True)


def _templates(mission: str, cid: str, stage: int, n_stages: int) -> dict[str, object]:
    """Well-formed messages of each coordinator-bound topic from carrier `cid`."""
    return {
        "hello": Hello(mission, cid, 4242, "fuzzhost", 1, 0, "0" * 16),
        "obs": Observation(mission, cid, stage, 5.0 * stage, 3, (1.0, 2.0), 1, ((0.0, 0.0), (1.0, 2.0))),
        "confirm": Confirm(mission, cid, stage, True, "deployed", (1.0, 2.0), 0),
        "bye": Bye(mission, cid, (0,), (("malformed", 1),), "end"),
    }


def _wrong_types() -> dict[str, object]:
    return {"mission": 7, "carrier": ["a"], "stage": "3", "t": "noon", "x": [1], "position": "here",
            "passengers_left": 1.5, "trail": {"a": 1}, "pid": -1.0, "host": 5, "next_stage": None,
            "fingerprint": 0, "deployed": "yes", "status": 1, "deployments": "all", "rejected": [1],
            "reason": {}, "deploy": "a", "planning_ms": "fast", "stages": "4"}


def _corrupt(rng: np.random.Generator, data: bytes) -> bytes:
    data = bytearray(data)
    for _ in range(int(rng.integers(1, MAX_FLIPS + 1))):
        i = int(rng.integers(len(data)))
        data[i] = int(rng.integers(256)) if rng.random() < 0.5 else data[i] ^ (1 << int(rng.integers(8)))
    return bytes(data)


def _junk(rng: np.random.Generator, kind: int, target: str, key: str, other_mission: bytes) -> Fuzz:
    """Kinds both receivers get: 0 random bytes, 1 msgpack that is not a map, 2 a truncated or
    byte-flipped encoding of `other_mission` (a valid message of another mission), 3 random bytes
    over the payload limit."""
    if kind == 3:
        size = int(rng.integers(MAX_PAYLOAD_BYTES + 1, 2 * MAX_PAYLOAD_BYTES))
        return Fuzz(target, key, rng.bytes(size), "oversized")
    if kind == 0:
        return Fuzz(target, key, rng.bytes(int(rng.integers(0, 300))), "random-bytes")
    if kind == 1:
        obj = [[1, 2], 7, "obs", None, 3.5, b"\x00"][int(rng.integers(6))]
        return Fuzz(target, key, _pack(obj), "not-a-map")
    if rng.random() < 0.5:
        return Fuzz(target, key, other_mission[: int(rng.integers(len(other_mission)))], "truncated")
    return Fuzz(target, key, _corrupt(rng, other_mission), "mutated")


def _optional_fields() -> set[str]:
    """Names of message fields that are optional on the wire (they have a default)."""
    from dataclasses import MISSING
    from dataclasses import fields as dc_fields

    from wire.messages import MESSAGE_TYPES

    return {f.name for cls in MESSAGE_TYPES.values() for f in dc_fields(cls)
            if f.default is not MISSING and f.name != "v"}


def _message_variants(rng, base: dict, mission: str) -> list[tuple[str, bytes]]:
    """Broken versions of one well-formed message map of this mission (each rejected by decode,
    or by the mission check)."""
    out = []
    fields = [k for k in base if k not in ("v", "type")]
    wrong = _wrong_types()
    # wrong type in one field
    name = fields[int(rng.integers(len(fields)))]
    out.append(("wrong-type", _pack({**base, name: wrong.get(name, [[]])})))
    # missing field (a required one: optional fields decode without it)
    required = [k for k in fields if k not in _optional_fields()]
    name = required[int(rng.integers(len(required)))]
    out.append(("missing-field", _pack({k: v for k, v in base.items() if k != name})))
    # unknown field
    out.append(("unknown-field", _pack({**base, "launch_codes": 1234})))
    # bad version
    version = [2, 0, "1", None, True, 1.0001][int(rng.integers(6))]
    out.append(("version", _pack({**base, "v": version})))
    # unknown type
    out.append(("unknown-type", _pack({**base, "type": ["launch", "state", "", "OBS"][int(rng.integers(4))]})))
    # wrong mission, well-formed otherwise
    out.append(("wrong-mission", _pack({**base, "mission": "not-" + mission})))
    return out


def coordinator_fuzz(
    rng: np.random.Generator, mission: str, carriers: list[str], n_stages: int, count: int
) -> list[Fuzz]:
    """`count` messages for the coordinator's subscriptions ``marsupial/<m>/carrier/*/{hello,obs,confirm,bye}``."""
    out: list[Fuzz] = []
    while len(out) < count:
        cid = carriers[int(rng.integers(len(carriers)))]
        topic = COORDINATOR_TOPICS[int(rng.integers(len(COORDINATOR_TOPICS)))]
        key = keys.carrier_key(mission, cid, topic)
        kind = int(rng.integers(10))
        if kind <= 2:
            other = _templates(MUTATION_BASE_MISSION, cid, int(rng.integers(n_stages)), n_stages)[topic]
            out.append(_junk(rng, kind, "coordinator", key, messages.encode(other)))
        elif kind in (3, 4):
            base = _wire(_templates(mission, cid, int(rng.integers(n_stages)), n_stages)[topic])
            for category, payload in _message_variants(rng, base, mission):
                out.append(Fuzz("coordinator", key, payload, category))
        elif kind == 5:
            # A well-formed message from a carrier the scenario does not have (anything goes there).
            ghost = UNKNOWN_CARRIERS[int(rng.integers(len(UNKNOWN_CARRIERS)))]
            msg = _templates(mission, ghost, int(rng.integers(n_stages)), n_stages)[topic]
            data = messages.encode(msg)
            if rng.random() < 0.3:
                data = _corrupt(rng, data)
            out.append(Fuzz("coordinator", keys.carrier_key(mission, ghost, topic), data, "unknown-carrier"))
        elif kind == 6:
            # Another carrier's message on this carrier's key.
            other = [c for c in carriers if c != cid] or ["zz9"]
            msg = _templates(mission, other[int(rng.integers(len(other)))], 0, n_stages)[topic]
            out.append(Fuzz("coordinator", key, messages.encode(msg), "key-mismatch"))
        elif kind == 7:
            # Stages that do not exist (observation, confirmation).
            stage = int(rng.integers(n_stages, messages.MAX_STAGES))
            topic = ("obs", "confirm")[int(rng.integers(2))]
            msg = _templates(mission, cid, stage, n_stages)[topic]
            out.append(Fuzz("coordinator", keys.carrier_key(mission, cid, topic), messages.encode(msg), "out-of-range"))
        elif kind == 8:
            # A message type that is valid but not accepted on this topic.
            wrong = {"hello": "obs", "obs": "confirm", "confirm": "bye", "bye": "hello"}[topic]
            msg = _templates(mission, cid, 0, n_stages)[wrong]
            out.append(Fuzz("coordinator", key, messages.encode(msg), "wrong-topic"))
        else:
            if rng.random() < 0.02:
                out.append(_junk(rng, 3, "coordinator", key, b""))
            else:
                # Structurally deep or huge-looking values.
                base = _wire(_templates(mission, cid, 0, n_stages)["obs"])
                bomb = [[[[[]]]]] * 50 if rng.random() < 0.5 else "x" * 5000
                out.append(Fuzz("coordinator", key, _pack({**base, "trail": bomb}), "hostile-value"))
    return out[:count]


def carrier_fuzz(
    rng: np.random.Generator, mission: str, carriers: list[str], n_stages: int, count: int
) -> list[Fuzz]:
    """`count` messages for the carriers' subscriptions ``coordinator/decision`` and ``coordinator/end``."""
    out: list[Fuzz] = []
    decision_key, end_key = keys.decision_key(mission), keys.end_key(mission)
    while len(out) < count:
        key = decision_key if rng.random() < 0.8 else end_key
        kind = int(rng.integers(8))
        good = (Decision(mission, int(rng.integers(n_stages)), 5.0, (carriers[0],), 1.0) if key == decision_key
                else End(mission, n_stages, "complete"))
        if kind <= 2:
            other = (Decision(MUTATION_BASE_MISSION, int(rng.integers(n_stages)), 5.0, tuple(carriers), 1.0)
                     if key == decision_key else End(MUTATION_BASE_MISSION, n_stages, "complete"))
            out.append(_junk(rng, kind, "carriers", key, messages.encode(other)))
        elif kind in (3, 4):
            for category, payload in _message_variants(rng, _wire(good), mission):
                out.append(Fuzz("carriers", key, payload, category))
        elif kind == 5:
            # Decisions for stages the mission does not have, naming known and unknown carriers.
            stage = int(rng.integers(n_stages, messages.MAX_STAGES))
            names = [*carriers, *UNKNOWN_CARRIERS]
            deploy = tuple(sorted(rng.choice(names, size=int(rng.integers(1, 5)), replace=False).tolist()))
            msg = Decision(mission, stage, 5.0 * stage, deploy, 1.0)
            out.append(Fuzz("carriers", decision_key, messages.encode(msg), "out-of-range"))
        elif kind == 6:
            # Another message type on the decision or end key.
            cid = carriers[int(rng.integers(len(carriers)))]
            msg = Observation(mission, cid, 0, 0.0, 1, (0.0, 0.0), 1, ()) if rng.random() < 0.5 else \
                Confirm(mission, cid, 0, True, "deployed", (0.0, 0.0), 0)
            out.append(Fuzz("carriers", key, messages.encode(msg), "wrong-topic"))
        else:
            if rng.random() < 0.02:
                out.append(_junk(rng, 3, "carriers", key, b""))
            else:
                bad_id = ["not an id!", "", "a/b", "*", "$x"][int(rng.integers(5))]
                decision = _wire(Decision(mission, int(rng.integers(n_stages)), 5.0, (carriers[0],), 1.0))
                out.append(Fuzz("carriers", decision_key, _pack({**decision, "deploy": [bad_id]}), "bad-id"))
    return out[:count]
