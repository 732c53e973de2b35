"""The two per-event and per-second costs found behind a fleet stage's wall time at scale
(docs/performance.md, "Where a stage's wall time goes"), each against its replacement in the
same run:

* **sessions**: the CPU per wall second of K carriers' entities (the subscriptions and tokens a
  carrier declares) idling on K zenoh client sessions, one per carrier, against one shared
  session (``wire.transport.SharedSession``), a router on loopback;
* **commits**: mission.db writes (``storage.missiondb.MissionStore``, ``synchronous=FULL``) one
  transaction per event, against the same events in one batch (``MissionStore.batch``).

    python -m tools.overhead_bench [--carriers 64] [--seconds 20] [--events 500]

Prints one line per case and the ratio. Real zenoh sessions and a real SQLite file (in a
temporary directory: the fsync costs of the disk it is on).
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from wire import keys, zconfig
from wire.transport import Node, SharedSession


def idle_sessions(carriers: int, seconds: float, shared: bool) -> float:
    """Process CPU (ms) per wall second of ``carriers`` carriers' entities, idle."""
    endpoint = f"tcp/127.0.0.1:{zconfig.free_port()}"
    router = zconfig.open_session(zconfig.make_config("router", [endpoint]), 10.0)
    session = SharedSession(zconfig.make_config("client", [], [endpoint])) if shared else None
    nodes = []
    try:
        for k in range(carriers):
            node = Node(zconfig.make_config("client", [], [endpoint]), 10.0, shared=session)
            cid = f"c{k:04d}"
            for key in (keys.decision_key("m"), keys.end_key("m"), keys.refusal_key("m", cid),
                        keys.accepted_key("m", cid)):
                node.subscribe(key)
            node.watch_liveliness(keys.coordinator_alive("m"))
            node.token(keys.carrier_alive("m", cid))
            nodes.append(node)
        time.sleep(2.0)  # joined and settled
        cpu, wall = time.process_time(), time.monotonic()
        time.sleep(seconds)
        return (time.process_time() - cpu) * 1e3 / (time.monotonic() - wall)
    finally:
        for node in nodes:
            node.close(3.0)
        router.close()


def commits(events: int, batched: bool) -> float:
    """Milliseconds per recorded observation."""
    from storage.missiondb import MissionStore

    with tempfile.TemporaryDirectory() as tmp:
        store = MissionStore(Path(tmp) / "mission.db", {"mission": "bench"})
        started = time.perf_counter()
        if batched:
            with store.batch():
                for k in range(events):
                    store.observation(f"c{k}", 0, k, (0.0, 0.0), t=0.0)
        else:
            for k in range(events):
                store.observation(f"c{k}", 0, k, (0.0, 0.0), t=0.0)
        elapsed = time.perf_counter() - started
        store.close()
    return elapsed * 1e3 / events


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m tools.overhead_bench", description=__doc__.split("\n\n")[0])
    p.add_argument("--carriers", type=int, default=64, help="carriers in the process (default 64)")
    p.add_argument("--seconds", type=float, default=20.0, help="idle time measured (default 20 s)")
    p.add_argument("--events", type=int, default=500, help="mission.db writes (default 500)")
    args = p.parse_args(argv)
    own = idle_sessions(args.carriers, args.seconds, shared=False)
    one = idle_sessions(args.carriers, args.seconds, shared=True)
    print(f"idle, {args.carriers} carriers: a session each {own:.2f} ms CPU/s ({own / args.carriers:.3f} per carrier); "
          f"one shared session {one:.2f} ms CPU/s; ratio {own / max(one, 1e-9):.0f}x")
    each = commits(args.events, batched=False)
    batch = commits(args.events, batched=True)
    print(f"mission.db, {args.events} observations: a commit each {each:.3f} ms/write; one batch {batch:.3f} ms/write; "
          f"ratio {each / max(batch, 1e-9):.0f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
