"""docs/protocol.md is enough to write a carrier: a carrier written here with plain zenoh and
msgpack (no wire/, no carriers/ code) takes part in a real mission next to a real carrier, and
the mission ends exactly as the offline planner's run."""
from __future__ import annotations

import json
import os
import queue
import socket
import threading
import time

import msgpack
import numpy as np
import zenoh

import world
from fleet_helpers import TINY, InProcessFleet, deployed_matrix, offline


def foreign_carrier(endpoint: str, mission: str, cid: str, x_row, positions, passengers: int, result: dict):
    """A carrier from the protocol document alone. ``x_row[j]`` is what it senses at stage j
    (NaN = not scheduled); ``positions[j]`` where it is."""
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

    def put(topic, body):
        session.put(f"{mine}/{topic}", msgpack.packb({"v": 1, "type": topic, "mission": mission, **body}))

    try:
        state = None
        deadline = time.monotonic() + 30
        while state is None and time.monotonic() < deadline:
            for reply in session.get(f"{prefix}/coordinator/state", timeout=2.0):
                if reply.ok is not None:
                    state = msgpack.unpackb(reply.ok.payload.to_bytes())
            time.sleep(0.05)
        assert state is not None and state["type"] == "state"
        left, deployments = passengers, []
        put("hello", {"carrier": cid, "pid": os.getpid(), "host": socket.gethostname(), "passengers_left": left,
                      "next_stage": state["next_stage"], "fingerprint": state["fingerprint"]})
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
        for entity in [*subs, token]:
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
        fleet.endpoint, fleet.coordinator.mission, "a", trace.x[ra], trace.positions[ra],
        tiny.carriers[ra].passengers, result))
    thread.start()
    summary = fleet.join()
    thread.join(30)
    reference, x = offline(tiny)
    assert summary["rejected"]["coordinator"] == {}
    np.testing.assert_array_equal(np.array(summary["observations"], dtype=float), x)
    np.testing.assert_array_equal(deployed_matrix(summary, tiny), reference.deployed)
    assert result["deployments"] == [int(j) for j in np.flatnonzero(reference.deployed[ra])]
