"""A carrier of protocol revision 1, written from tests/fixtures/wire/r1/protocol.md alone.

Plain zenoh + msgpack + the standard library: it imports nothing of this project, so it stands
for a carrier somebody else wrote against the page as published before passenger types. It is
strict as that page says: a field the page does not list is rejected (``unknown-field``), and so
is anything else off the page; rejections are counted and reported in its Bye.

What it senses comes from outside, as a robot's sensors would: ``--world FILE`` is a JSON map
``{"scenario": path, "seed": int, "stage_times": [t_j], "x": [x_j or null], "positions":
[[x, y]], "passengers": D}`` (null x: not scheduled at j). It computes the world's fingerprint
itself from the scenario file and the seed (the page's section "Fingerprint"). It never decides
alone: without a Decision within ``--decision-timeout`` it goes on without deploying; when the
coordinator's token reappears it resynchronises (State, Hello, its pending Observation, its
answers again as ``already``), as the page says.

    python tests/revision1_carrier.py --endpoint tcp/127.0.0.1:7447 --mission six_carriers \\
        --carrier c1 --world c1.json --result c1-result.json
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import queue
import socket
import sys
import time
from collections import Counter

import msgpack
import zenoh

#: Revision 1's fields per message type: (required, optional). Section "Messages" of the page.
FIELDS = {
    "decision": ({"stage", "t", "deploy", "planning_ms"}, {"epoch"}),
    "end": ({"stages", "reason"}, set()),
    "refusal": ({"carrier", "reason", "fingerprint", "expected"}, set()),
    "state": ({"next_stage", "stages", "fingerprint", "ended", "carriers", "last_decision"}, {"epoch"}),
}
CARRIER_STATE = {"passengers_left", "deployments", "live"}
ENVELOPE = {"v", "type", "mission"}


class Rejected(Exception):
    def __init__(self, reason: str, detail: str):
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


def check_fields(body: dict, kind: str, nested: bool = False) -> None:
    """The page's strictness: every listed field present (optional ones may be absent), nothing else."""
    required, optional = FIELDS[kind]
    envelope = ENVELOPE if not nested else set()
    unknown = set(body) - required - optional - ENVELOPE
    if unknown:
        raise Rejected("unknown-field", f"{kind}: unexpected field {sorted(unknown)[0]!r}")
    missing = (required | envelope) - set(body)
    if missing:
        raise Rejected("missing-field", f"{kind}: missing field {sorted(missing)[0]!r}")


def _int(value, lo, hi, name):
    if isinstance(value, bool) or not isinstance(value, int):
        raise Rejected("wrong-type", f"{name}: expected integer")
    if not lo <= value <= hi:
        raise Rejected("out-of-range", f"{name}: {value} not in {lo}..{hi}")
    return value


def read(payload: bytes, kind: str, mission: str) -> dict:
    """One message of type ``kind`` as revision 1 reads it, or :class:`Rejected`."""
    if len(payload) > 131072:
        raise Rejected("oversized", f"{len(payload)} bytes")
    try:
        body = msgpack.unpackb(payload, raw=False)
    except Exception:
        raise Rejected("malformed", "not msgpack") from None
    if not isinstance(body, dict):
        raise Rejected("not-a-map", type(body).__name__)
    if "v" not in body:
        raise Rejected("missing-field", "v")
    if type(body["v"]) is not int or body["v"] != 1:
        raise Rejected("version", repr(body["v"]))
    if body.get("type") != kind:
        raise Rejected("unknown-type", repr(body.get("type")))
    check_fields(body, kind)
    if body["mission"] != mission:
        raise Rejected("wrong-mission", repr(body["mission"]))
    if kind == "decision":
        _decision_values(body)
    if kind == "state":
        if not isinstance(body["carriers"], dict) or len(body["carriers"]) > 64:
            raise Rejected("out-of-range", "carriers")
        for entry in body["carriers"].values():
            if not isinstance(entry, dict):
                raise Rejected("wrong-type", "carriers entry")
            if set(entry) - CARRIER_STATE:
                raise Rejected("unknown-field", f"carriers entry: {sorted(set(entry) - CARRIER_STATE)[0]!r}")
            if CARRIER_STATE - set(entry):
                raise Rejected("missing-field", f"carriers entry: {sorted(CARRIER_STATE - set(entry))[0]!r}")
        last = body["last_decision"]
        if last is not None:
            if not isinstance(last, dict) or last.get("type", "decision") != "decision":
                raise Rejected("wrong-type", "last_decision")
            check_fields({k: v for k, v in last.items() if k not in ENVELOPE}, "decision", nested=True)
            _decision_values(last)
        if "epoch" in body:
            _int(body["epoch"], 1, 2**31 - 1, "epoch")
    return body


def _decision_values(body: dict) -> None:
    _int(body["stage"], 0, 99999, "stage")
    if not isinstance(body["deploy"], list) or not all(isinstance(c, str) for c in body["deploy"]):
        raise Rejected("wrong-type", "deploy")
    if len(set(body["deploy"])) != len(body["deploy"]):
        raise Rejected("out-of-range", "deploy repeats a carrier")
    if "epoch" in body:
        _int(body["epoch"], 1, 2**31 - 1, "epoch")


def fingerprint(scenario_path: str, seed: int) -> str:
    """The page's section "Fingerprint": SHA-256 over the header line and the file, 16 hex digits."""
    with open(scenario_path, "rb") as f:
        data = f.read()
    return hashlib.sha256(f"marsupial-fleet/1 seed={int(seed)}\n".encode() + data).hexdigest()[:16]


FAULTS = ("fingerprint", "future-obs", "no-confirm", "unknown-field", "stale-epoch", "ignore-refusal")


def fly(endpoint: str, mission: str, cid: str, world: dict, decision_timeout_s: float = 30.0,
        fault: str | None = None) -> dict:
    """Fly one mission as a revision 1 carrier; returns what happened (deployments, rejections,
    the decisions it accepted, why it stopped). ``fault``: break one rule on purpose (for the
    conformance kit's tests): one of :data:`FAULTS`."""
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    deadline = time.monotonic() + 60
    while True:  # "Connecting": retry until the coordinator listens
        try:
            session = zenoh.open(conf)
            break
        except zenoh.ZError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.2)
    prefix = f"marsupial/{mission}"
    mine = f"{prefix}/carrier/{cid}"
    inbox: "queue.Queue[tuple[str, bytes]]" = queue.Queue()
    entities = [session.declare_subscriber(f"{prefix}/coordinator/{topic}",
                                           lambda s, t=topic: inbox.put((t, s.payload.to_bytes())))
                for topic in ("decision", "end")]
    entities.append(session.declare_subscriber(f"{prefix}/coordinator/refusal/{cid}",
                                               lambda s: inbox.put(("refusal", s.payload.to_bytes()))))
    entities.append(session.liveliness().declare_subscriber(
        f"{prefix}/coordinator/alive", history=True,
        handler=lambda s: inbox.put(("alive" if s.kind == zenoh.SampleKind.PUT else "gone", b""))))
    entities.append(session.liveliness().declare_token(f"{mine}/alive"))
    publishers: dict = {}
    rejected: Counter = Counter()
    outcome = {"deployments": [], "decisions": {}, "rejected": rejected, "reason": None}
    mine_fp = fingerprint(world["scenario"], world["seed"] + (1 if fault == "fingerprint" else 0))
    me = {"left": int(world["passengers"]), "epoch": 1, "stage": 0, "pending": None, "seen": False,
          "gone": False, "said_hello": False}
    handled: dict = {}  # stage -> (deployed, status, passengers_left after, position)
    replay: list = []  # decisions learnt from State at a resynchronisation, handled as received

    def put(topic: str, body: dict) -> None:
        if topic not in publishers:
            publishers[topic] = session.declare_publisher(
                f"{mine}/{topic}", reliability=zenoh.Reliability.RELIABLE,
                congestion_control=zenoh.CongestionControl.BLOCK)
            entities.append(publishers[topic])
        publishers[topic].put(msgpack.packb({"v": 1, "type": topic, "mission": mission, **body}))

    def query_state(timeout_s: float):
        """State of the highest epoch ("State"), retrying until ``timeout_s``."""
        best = None
        end = time.monotonic() + timeout_s
        while best is None and time.monotonic() < end:
            for reply in session.get(f"{prefix}/coordinator/state?carrier={cid}", timeout=2.0):
                if reply.ok is None:
                    continue
                try:
                    candidate = read(reply.ok.payload.to_bytes(), "state", mission)
                except Rejected as exc:
                    rejected[exc.reason] += 1
                    continue
                if best is None or candidate.get("epoch", 1) > best.get("epoch", 1):
                    best = candidate
            if best is None:
                time.sleep(0.2)
        return best

    def hello(next_stage: int) -> None:
        me["said_hello"] = True
        put("hello", {"carrier": cid, "pid": os.getpid(), "host": socket.gethostname()[:255],
                      "passengers_left": me["left"], "next_stage": next_stage, "fingerprint": mine_fp,
                      **({"epoch": me["epoch"]} if me["epoch"] > 1 else {})})

    def confirm(stage: int, deployed: bool, status: str, position, after: int) -> None:
        put("confirm", {"carrier": cid, "stage": stage, "deployed": deployed, "status": status,
                        "position": position, "passengers_left": after})

    def resync() -> None:
        """The coordinator's token reappeared ("Joining late, restarting, resynchronising")."""
        state = query_state(10.0)
        if state is None or state.get("epoch", 1) < me["epoch"]:
            return
        me["epoch"] = max(me["epoch"], state.get("epoch", 1))
        hello(max(me["stage"], state["next_stage"]))
        last = state["last_decision"]
        if last is not None and last["stage"] not in handled:
            replay.append(last)
        pending = me["pending"]
        if pending is not None and pending["stage"] >= state["next_stage"] and pending["stage"] not in handled:
            put("obs", pending)
        for j, (deployed, _, after, position) in sorted(handled.items()):
            confirm(j, deployed, "already", position, after)

    def receive(timeout_s: float):
        """The next valid (kind, message) from the coordinator, or None at the timeout."""
        end = time.monotonic() + timeout_s
        while True:
            if replay:
                return "decision", replay.pop(0)
            left = end - time.monotonic()
            if left <= 0:
                return None
            try:
                kind, payload = inbox.get(timeout=left)
            except queue.Empty:
                return None
            if kind == "gone":
                me["gone"] = True
                continue
            if kind == "alive":
                if me["seen"] and me["gone"]:
                    me["gone"] = False
                    resync()
                me["seen"] = True
                continue
            try:
                return kind, read(payload, kind, mission)
            except Rejected as exc:
                rejected[exc.reason] += 1

    def observation(j: int) -> dict:
        return {"carrier": cid, "stage": j, "t": float(world["stage_times"][j]), "x": world["x"][j],
                "position": [float(v) for v in world["positions"][j]], "passengers_left": me["left"], "trail": []}

    try:
        state = query_state(30.0)  # "Join": query State, retrying
        if state is None:
            outcome["reason"] = "coordinator-lost"
            return outcome
        if state["fingerprint"] != mine_fp and fault != "fingerprint":
            outcome["reason"] = "world-mismatch"
            return outcome
        if state["ended"]:
            outcome["reason"] = "end"
            return outcome
        me["epoch"] = state.get("epoch", 1)
        me["stage"] = state["next_stage"]
        hello(state["next_stage"])
        ended = False
        stages = state["stages"]
        early: dict = {}  # stage -> decision that arrived before the carrier got there
        for j in range(state["next_stage"], stages):
            if ended:
                break
            me["stage"] = j
            position = [float(v) for v in world["positions"][j]]
            if j not in early:
                body = observation(j)
                if fault == "unknown-field" and j == 1:
                    body["colour"] = "red"
                me["pending"] = body
                put("obs", body)
                if fault == "future-obs" and j == 1 and j + 1 < stages:
                    put("obs", observation(j + 1))
            decision = early.pop(j, None)
            wait_until = time.monotonic() + decision_timeout_s
            while decision is None and not ended:
                got = receive(max(0.0, wait_until - time.monotonic()))
                if got is None:
                    break  # no Decision in time: go on without deploying (never decides alone)
                kind, message = got
                if kind == "end":
                    ended = True
                elif kind == "refusal":
                    if message["fingerprint"] == mine_fp and fault != "ignore-refusal":
                        outcome["reason"] = "world-mismatch"
                        return outcome
                elif message.get("epoch", 1) < me["epoch"] and fault != "stale-epoch":
                    rejected["deposed"] += 1
                elif message["stage"] == j and j not in handled:
                    me["epoch"] = max(me["epoch"], message.get("epoch", 1))
                    decision = message
                elif message["stage"] > j:
                    me["epoch"] = max(me["epoch"], message.get("epoch", 1))
                    early[message["stage"]] = message
                    break  # j's decision was lost: go on at once
                elif message["stage"] in handled:  # a repeat: "already" with the first outcome
                    me["epoch"] = max(me["epoch"], message.get("epoch", 1))
                    deployed, _, after, where = handled[message["stage"]]
                    confirm(message["stage"], deployed, "already", where, after)
            me["pending"] = None
            if decision is None:
                continue
            outcome["decisions"][j] = list(decision["deploy"])
            selected = cid in decision["deploy"]
            if selected and world["x"][j] is not None and me["left"] > 0:
                me["left"] -= 1
                outcome["deployments"].append(j)
                status = "deployed"
            else:
                status = "refused" if selected else "idle"
            handled[j] = (status == "deployed", status, me["left"], position)
            if not (fault == "no-confirm" and j == 1):
                confirm(j, status == "deployed", status, position, me["left"])
        end_wait = time.monotonic() + 10
        while not ended and time.monotonic() < end_wait:
            got = receive(end_wait - time.monotonic())
            if got is not None and got[0] == "end":
                ended = True
        outcome["reason"] = "end" if ended else "finished"
        return outcome
    finally:
        try:
            if me["said_hello"]:  # a Bye needs a Hello
                put("bye", {"carrier": cid, "deployments": outcome["deployments"], "rejected": dict(rejected),
                            "reason": outcome["reason"] or "stopped"})
                time.sleep(0.3)  # let the Bye leave before the session closes
        finally:
            for entity in entities:
                try:
                    entity.undeclare()
                except Exception:
                    pass
            session.close()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--endpoint", required=True)
    parser.add_argument("--mission", required=True)
    parser.add_argument("--carrier", required=True)
    parser.add_argument("--world", required=True, help="JSON file: what the carrier senses (see above)")
    parser.add_argument("--result", help="write what happened here (JSON)")
    parser.add_argument("--decision-timeout", type=float, default=30.0)
    parser.add_argument("--fault", choices=FAULTS, help="break one rule on purpose (conformance kit tests)")
    args = parser.parse_args(argv)
    with open(args.world) as f:
        world = json.load(f)
    outcome = fly(args.endpoint, args.mission, args.carrier, world, args.decision_timeout, args.fault)
    if args.result:
        with open(args.result, "w") as f:
            json.dump({**outcome, "rejected": dict(outcome["rejected"])}, f)
    return 0 if outcome["reason"] in ("end", "finished") else 1


if __name__ == "__main__":
    sys.exit(main())
