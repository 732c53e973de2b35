"""Wire codec figures: encode and decode time per message of wire.messages (the code of record),
and of a msgspec prototype of the same messages (typed Structs with the page's constraints,
unknown fields forbidden), with a check of which documented rejection reasons the prototype
gives for the corpus of bad payloads of tests/test_wire.py.

    python -m tools.wire_bench [--n 20000]

Prints one line per message and codec (µs per encode / decode, median of 5 runs) and the
rejection-reason agreement. msgspec is optional (``pip install msgspec``); without it only the
code of record is measured.
"""


import argparse
import statistics
import time

import msgpack

from wire import messages as wm

M = "six_carriers"

SAMPLES = {
    "hello": wm.Hello(M, "c1", 4242, "robot-1", 3, 0, "3f1c2a9be07d4c55", revision=3),
    "obs": wm.Observation(M, "c1", 2, 40.0, 3, (10.0, 50.0), 3, tuple((10.0, 30.0 + k) for k in range(20))),
    "decision": wm.Decision(M, 2, 40.0, ("c1", "c3", "c5"), 12.5, passengers=(0, 1, 0)),
    "confirm": wm.Confirm(M, "c1", 2, True, "deployed", (10.0, 50.0), 2, 0),
    "state": wm.State(M, 3, 12, "3f1c2a9be07d4c55", False,
                      tuple((f"c{k}", wm.CarrierState(2, (2,), True)) for k in range(1, 7)),
                      wm.Decision(M, 2, 40.0, ("c1",), 12.5), revision=3),
}


def _time(fn, n: int) -> float:
    """µs per call, median of 5 runs of ``n`` calls."""
    runs = []
    for _ in range(5):
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        runs.append((time.perf_counter() - t0) / n * 1e6)
    return statistics.median(runs)


# --------------------------------------------------------------------------- the msgspec prototype

def prototype():
    """msgspec Structs of five messages with the page's constraints (ranges, lengths, the id
    pattern, unknown fields forbidden), a Decoder per type and a reason mapping from msgspec's
    error text to the page's reasons."""
    from typing import Annotated, Literal, Optional, Union

    import msgspec
    from msgspec import Meta

    Id = Annotated[str, Meta(pattern=r"^[A-Za-z0-9_][A-Za-z0-9_.-]{0,63}\Z", max_length=64)]
    Stage = Annotated[int, Meta(ge=0, le=99999)]
    Count = Annotated[int, Meta(ge=0, le=100000)]
    Passengers = Annotated[int, Meta(ge=0, le=100)]
    Seconds = Annotated[float, Meta(ge=-1e9, le=1e9)]
    Coord = Annotated[float, Meta(ge=-1e7, le=1e7)]
    Point = tuple[Coord, Coord]
    opts = dict(forbid_unknown_fields=True, tag_field="type", omit_defaults=True)

    class Hello(msgspec.Struct, tag="hello", **opts):
        v: object
        mission: Id
        carrier: Id
        pid: Annotated[int, Meta(ge=0, le=2**31)]
        host: Annotated[str, Meta(max_length=255)]
        passengers_left: Passengers
        next_stage: Count
        fingerprint: Annotated[str, Meta(max_length=64)]
        epoch: Annotated[int, Meta(ge=1, le=2**31 - 1)] = 1
        revision: Annotated[int, Meta(ge=1, le=65535)] = 1

    class Observation(msgspec.Struct, tag="obs", **opts):
        v: object
        mission: Id
        carrier: Id
        stage: Stage
        t: Seconds
        x: Optional[Annotated[int, Meta(ge=0, le=10**9)]]
        position: Point
        passengers_left: Passengers
        trail: Annotated[list[Point], Meta(max_length=512)]

    class Decision(msgspec.Struct, tag="decision", **opts):
        v: object
        mission: Id
        stage: Stage
        t: Seconds
        deploy: Annotated[list[Id], Meta(max_length=1024)]
        planning_ms: Annotated[float, Meta(ge=0.0, le=1e9)]
        epoch: Annotated[int, Meta(ge=1, le=2**31 - 1)] = 1
        passengers: Annotated[list[Annotated[int, Meta(ge=0, le=99)]], Meta(max_length=1024)] = []

        def __post_init__(self):
            if len(set(self.deploy)) != len(self.deploy):
                raise ValueError("deploy: repeated carrier id")
            if self.passengers and len(self.passengers) != len(self.deploy):
                raise ValueError("passengers: one per deploying carrier")

    class Confirm(msgspec.Struct, tag="confirm", **opts):
        v: object
        mission: Id
        carrier: Id
        stage: Stage
        deployed: bool
        status: Literal["deployed", "idle", "late", "refused", "already"]
        position: Point
        passengers_left: Passengers
        passenger: Optional[Annotated[int, Meta(ge=0, le=99)]] = None

    class CarrierState(msgspec.Struct, **opts):
        passengers_left: Passengers
        deployments: Annotated[list[Stage], Meta(max_length=100000)]
        live: bool
        refused: Optional[Annotated[str, Meta(max_length=40)]] = None
        rejected: Annotated[dict[Annotated[str, Meta(max_length=40)], Annotated[int, Meta(ge=0, le=2**53)]],
                            Meta(max_length=64)] = {}

    class State(msgspec.Struct, tag="state", **opts):
        v: object
        mission: Id
        next_stage: Count
        stages: Count
        fingerprint: Annotated[str, Meta(max_length=64)]
        ended: bool
        carriers: Annotated[dict[Id, CarrierState], Meta(max_length=64)]
        last_decision: Optional[Decision]
        epoch: Annotated[int, Meta(ge=1, le=2**31 - 1)] = 1
        revision: Annotated[int, Meta(ge=1, le=65535)] = 1

    types = {"hello": Hello, "obs": Observation, "decision": Decision, "confirm": Confirm, "state": State}
    any_decoder = msgspec.msgpack.Decoder(Union[tuple(types.values())])
    encoder = msgspec.msgpack.Encoder()

    def reason(exc: Exception) -> str:
        text = str(exc)
        if isinstance(exc, msgspec.ValidationError):
            if "unknown field" in text:
                return "unknown-field"
            if "missing required field" in text:
                return "missing-field" if "`type`" not in text else "missing-field"
            if "Invalid value" in text and "$.type" in text:
                return "unknown-type"
            if text.startswith("Expected `object`") and "- at" not in text:
                return "not-a-map"
            if "Expected `array` of length" in text and "<=" not in text:
                return "wrong-type"  # a point that is not [x, y]
            if ">=" in text or "<=" in text or "length" in text or "regex" in text or "Invalid" in text:
                return "out-of-range"
            if "Expected" in text:
                return "wrong-type"
            return "out-of-range"  # a __post_init__ ValueError
        return "malformed"

    def decode(data: bytes):
        if len(data) > wm.MAX_PAYLOAD_BYTES:
            raise wm.ProtocolError("oversized", "")
        try:
            raw = msgspec.msgpack.decode(data)  # untyped first: a truncated payload is malformed
        except msgspec.DecodeError as exc:
            raise wm.ProtocolError("malformed", str(exc)) from None
        if not isinstance(raw, dict):
            raise wm.ProtocolError("not-a-map", type(raw).__name__)
        if "v" not in raw or "type" not in raw:
            raise wm.ProtocolError("missing-field", "v or type")
        if type(raw["v"]) is not int or raw["v"] != 1:
            raise wm.ProtocolError("version", repr(raw["v"])[:20])
        try:
            message = any_decoder.decode(data)
        except (msgspec.ValidationError, msgspec.DecodeError) as exc:
            raise wm.ProtocolError(reason(exc), str(exc)) from None
        return message

    def convert(message):
        """The prototype's Struct for a wire.messages dataclass (via its wire map)."""
        return any_decoder.decode(wm.encode(message))

    return types, encoder.encode, decode, convert


def reason_agreement(decode_proto) -> tuple[int, list[str]]:
    """Bad payloads (tests/test_wire.py's corpus, the five prototyped types): how many get the
    same reason from both codecs, and the ones that do not."""
    from wire.messages import _to_wire

    def raw(name):
        return _to_wire(SAMPLES[name])

    cases = [(b"", None), (b"\xc1\xc1\xc1", None), (b"\x92\x01", None), (msgpack.packb([1, 2, 3]), None),
             (msgpack.packb({"type": "obs"}), None), (b"x" * (wm.MAX_PAYLOAD_BYTES + 1), None)]
    for version in (0, 2, "1", 1.0, True, None):
        cases.append((msgpack.packb({**raw("obs"), "v": version}), None))
    fields = [("obs", "stage", "2"), ("obs", "stage", -1), ("obs", "stage", 2.0), ("obs", "stage", True),
              ("obs", "x", -3), ("obs", "x", 2.5), ("obs", "t", float("nan")), ("obs", "t", float("inf")),
              ("obs", "position", [1.0]), ("obs", "position", [1.0, "y"]), ("obs", "position", [1e12, 0.0]),
              ("obs", "trail", [[0.0, 0.0]] * 600), ("obs", "carrier", "a/b"), ("obs", "carrier", "a\n"),
              ("obs", "carrier", 7), ("obs", "mission", ""), ("obs", "passengers_left", -1),
              ("obs", "colour", "red"), ("obs", "type", "teleport"), ("decision", "deploy", ["a", "a"]),
              ("decision", "deploy", "a"), ("decision", "planning_ms", -1.0), ("decision", "passengers", [0, 1]),
              ("confirm", "deployed", 1), ("confirm", "status", "teleported"), ("hello", "host", "h" * 300),
              ("hello", "epoch", 0), ("state", "carriers", {"a": {"passengers_left": 1}}),
              ("state", "last_decision", {"stage": 1})]
    for name, key, value in fields:
        cases.append((msgpack.packb({**raw(name), key: value}), None))
    missing = raw("obs")
    del missing["x"]
    cases.append((msgpack.packb(missing), None))
    same, differ = 0, []
    for data, _ in cases:
        try:
            wm.decode(data)
            ours = "accepted"
        except wm.ProtocolError as exc:
            ours = exc.reason
        try:
            decode_proto(data)
            theirs = "accepted"
        except wm.ProtocolError as exc:
            theirs = exc.reason
        if ours == theirs:
            same += 1
        else:
            differ.append(f"{data[:60]!r}: wire.messages {ours}, msgspec {theirs}")
    return same, differ


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tools.wire_bench", description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=20000, help="calls per timing run (default 20000)")
    args = parser.parse_args(argv)
    try:
        types, encode_proto, decode_proto, convert = prototype()
    except ImportError:
        types = None
    print(f"{'message':<10} {'bytes':>6} {'encode µs':>10} {'decode µs':>10}   {'msgspec enc':>11} {'msgspec dec':>11}")
    for name, message in SAMPLES.items():
        data = wm.encode(message)
        enc = _time(lambda: wm.encode(message), args.n)
        dec = _time(lambda: wm.decode(data), args.n)
        line = f"{name:<10} {len(data):>6} {enc:>10.2f} {dec:>10.2f}"
        if types is not None:
            struct = convert(message)
            assert decode_proto(encode_proto(struct)) == struct
            line += f"   {_time(lambda: encode_proto(struct), args.n):>11.2f} {_time(lambda: decode_proto(data), args.n):>11.2f}"
        print(line, flush=True)
    if types is not None:
        same, differ = reason_agreement(decode_proto)
        print(f"rejection reasons: {same} of {same + len(differ)} bad payloads get the same reason from msgspec")
        for line in differ:
            print(f"  differs: {line}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
