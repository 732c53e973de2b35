"""A carrier process: the carriers it simulates, one thread each and one Zenoh session for all,
after a check that none of them is live elsewhere (docs/fleet.md, "Many carriers per process",
"Split brain")."""
from __future__ import annotations

import sys
import threading

from carriers.node import Carrier
from carriers.onboard import Onboard, with_onboard_load
from carriers.shared import SWITCH_INTERVAL_S, PhysicsThread, StageGate, shared_world
from mission.timeouts import DEFAULTS
from wire import keys
from wire.fault_windows import fault_clock
from wire.messages import SharedDecoder


class DuplicateCarriers(RuntimeError):
    """Carriers of this process already have live liveliness tokens elsewhere (another process
    runs them): the process refuses to start, before any of its carriers flies."""

    def __init__(self, mission: str, ids):
        self.mission, self.ids = mission, tuple(ids)
        super().__init__(f"mission {mission} already has live carrier(s) {', '.join(self.ids)}; stop that "
                         f"process first, or use another --mission")


def live_duplicates(mission: str, ids, zconf, stop: threading.Event | None = None,
                    open_timeout_s: float = DEFAULTS.coordinator_s) -> list[str]:
    """Which of ``ids`` already have a live token on ``mission`` (one liveliness query over a
    short-lived session of its own; docs/fleet.md, "Split brain")."""
    from wire.transport import Node
    from wire.zconfig import OpenStopped

    try:
        probe = Node(zconf() if callable(zconf) else zconf, open_timeout_s=open_timeout_s, stop=stop)
    except OpenStopped:
        return []
    try:
        live = probe.live_tokens(keys.carrier_alive_pattern(mission), DEFAULTS.liveliness_check_s)
    finally:
        probe.close(DEFAULTS.close_s)
    wanted = {keys.carrier_alive(mission, cid): cid for cid in ids}
    return sorted(wanted[k] for k in live if k in wanted)


def run_carriers(scenario, configs, zconf, stop: threading.Event | None = None) -> dict:
    """Run several carriers in this process, one thread each; the world (schedules, fingerprint,
    features) is derived once and shared, and so is one Zenoh session
    (:class:`wire.transport.SharedSession`: every carrier declares its own subscriptions,
    publishers and liveliness token on it, so the protocol and the coordinator cannot tell them
    from carriers in processes of their own). Carriers with a ROS 2 node keep a session each
    (rmw_zenoh numbers a session's nodes and entities: ros2/graph.py numbers one node per session).

    Args:
        scenario: the loaded scenario (every config must name the same ``seed``).
        configs: one :class:`CarrierConfig` per carrier.
        zconf: a zenoh config, or a callable returning a fresh one (one per session).
        stop: the process's stop request, shared by all carriers.

    Returns:
        carrier id -> its exit reason (a key of :data:`EXIT_CODES`).

    Raises:
        DuplicateCarriers: some of these carriers are live elsewhere (checked before any flies).
    """
    stop = stop if stop is not None else threading.Event()
    configs = list(configs)
    if configs:
        mission = configs[0].mission or keys.mission_id_from_name(scenario.name)
        taken = live_duplicates(mission, [c.carrier for c in configs], zconf, stop,
                                configs[0].coordinator_timeout_s)
        if taken:
            raise DuplicateCarriers(mission, taken)
    shared = None
    if len(configs) > 1:
        seeds = {c.seed for c in configs}
        if len(seeds) != 1:
            raise ValueError("carriers of one process must share the seed")
        seed = seeds.pop()
        if seed is not None:
            scenario = scenario.with_seed(int(seed))
        shared = shared_world(scenario)
    onboard = Onboard(scenario, configs[0].planner_options) if configs else None
    gate = StageGate()
    broadcasts = SharedDecoder()  # a Decision reaches every carrier of the process: decoded once
    configs = with_onboard_load(configs)
    session = None
    if len(configs) > 1 and all(c.ros2 is None for c in configs):
        from wire.transport import SharedSession

        session = SharedSession(zconf() if callable(zconf) else zconf)
    if len(configs) > 1:
        sys.setswitchinterval(SWITCH_INTERVAL_S)
    # The simulated bodies' physics (a robot's body waits for its odometry: it keeps its own thread).
    physics = PhysicsThread() if any(c.ros2 is None for c in configs) else None
    carriers = [Carrier(scenario, c, zconf() if callable(zconf) else zconf, stop=stop, shared=shared, onboard=onboard,
                        gate=gate, broadcasts=broadcasts, session=session,
                        physics=physics if c.ros2 is None else None, clock=fault_clock(c.carrier)) for c in configs]
    reasons: dict = {}

    def body(carrier):
        try:
            reasons[carrier.cid] = carrier.run()
        except Exception:  # one carrier's bug must not take its neighbours down
            import traceback

            print(f"carrier {carrier.cid}: crashed\n{traceback.format_exc()}", file=sys.stderr, flush=True)
            reasons[carrier.cid] = "crashed"

    threads = [threading.Thread(target=body, args=(c,), name=f"carrier-{c.cid}", daemon=True) for c in carriers]
    for thread in threads:
        thread.start()
    woken = False
    for thread in threads:
        while thread.is_alive():
            thread.join(0.2)
            if stop.is_set() and not woken:  # a signal: wake every carrier from its wait
                woken = True
                for c in carriers:
                    c.stop()
    if physics is not None:
        physics.shutdown(wait=False)
    return {c.cid: reasons.get(c.cid, "crashed") for c in carriers}
