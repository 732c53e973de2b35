"""Simulated fault schedules replayed on real processes (issue 33, item 6): a schedule the
simulator draws from a seed is carried out on the real fleet (run_fleet.py single-role
processes over real Zenoh, tests/test_faults.py's helpers), each fault placed at the stage it
struck in the simulated mission and lasting as long, and the real fleet makes the simulated
mission's decisions.

The kinds replayed are those whose decisions are a function of the schedule alone, not of how
long each side took: ``coordinator-crash`` with carriers that hold (``--no-autonomy``, the
simulator's ``coordinated`` mode), and the intruders' messages, ``corrupt`` (garbled ones and
another mission's, mid-mission) and ``stale`` (a carrier's messages of an earlier run of the
mission, before its Hello), each published by a Zenoh session of the test at the stage it
struck in the simulated mission. Carrier crashes and cuts are not replayed: which stages are
decided without the carrier depends on the real processes' timing, which the simulated one does
not reproduce.
"""
from __future__ import annotations

import json
import time

import pytest

from launcher.simulate import build_fleet
from mission import simulate as sim
from test_faults import Fleet, faults_yaml
from wire import keys
from wire.messages import Bye, Confirm, Observation, encode
from wire.transport import Node
from wire.zconfig import free_port, make_config

pytestmark = pytest.mark.slow


def _crash_stage(fleet, seed: int) -> tuple[int, float, dict]:
    """The stage after whose Decision the seed's drawn coordinator crash struck in the simulated
    mission (-1: before the first), how long the coordinator stayed down (s), and the simulated
    mission's decisions (stage -> ids)."""
    s = sim.Simulation(fleet, seed, kinds=("coordinator-crash",))
    out = s.run()
    assert out.violations == [] and out.completed, out.violations
    crash = next(f for f in s.faults if f.kind == "coordinator-crash")
    k = max((j for j, t in s.decided_at.items() if t < crash.at), default=-1)
    final = next(d for d in s.coordinators.values() if d.phase == "done")
    return k, crash.until - crash.at, {j: tuple(sorted(d.deploy)) for j, d in final.state.decisions.items()}


def test_a_simulated_coordinator_crash_replayed_on_real_processes_makes_the_same_decisions(tmp_path):
    path = tmp_path / "faults.yaml"
    path.write_text(faults_yaml(10))
    fleet = build_fleet(str(path), mode="coordinated")
    # the first seeds with one drawn crash, striking mid-mission (stages are left to the restarted
    # process) and shorter than 20 s (the wall seconds the replay waits before the restart)
    picked = []
    for seed in range(300):
        if sum(f.kind == "coordinator-crash" for f in sim.Simulation(fleet, seed, kinds=("coordinator-crash",)).faults) != 1:
            continue
        k, down, decisions = _crash_stage(fleet, seed)
        if 1 <= k <= fleet.n_stages - 3 and down < 20.0:
            picked.append((seed, k, down, decisions))
        if len(picked) == 2:
            break
    assert len(picked) == 2
    for seed, k, down, decisions in picked:
        real = Fleet(path, tmp_path / f"run-{seed}", f"tcp/127.0.0.1:{free_port()}")
        try:
            real.coordinator("coordinator-1")
            for cid in fleet.ids:
                real.carrier(cid, extra=["--no-autonomy"])
            real.poll(f"stage {k} decided", lambda: real.decided() >= k)
            real.kill("coordinator-1")
            time.sleep(down)  # down as long as in the simulated mission (the carriers hold, well within their timeout)
            real.coordinator("coordinator-2")
            codes = real.wait_all()
        finally:
            real.cleanup()
        assert all(code == 0 for name, code in codes.items() if name != "coordinator-1"), (codes, real.output())
        made = {j: tuple(sorted(json.loads(deploy))) for j, deploy in real.rows("SELECT stage, deploy FROM decisions")}
        assert made == decisions, (seed, k, made, decisions)


def _intrusions(fleet, seed: int) -> tuple[list, dict]:
    """The messages the seed's ``corrupt``/``stale`` faults inject in the simulated mission, each
    as (the stage after whose Decision it arrived, -1 before the first; the message), in time
    order, and the simulated mission's decisions (stage -> ids)."""
    s = sim.Simulation(fleet, seed, kinds=("corrupt", "stale"))
    sent = sorted((t, args[2]) for t, _, fn, args in s.heap if getattr(fn, "__name__", "") == "_arrive"
                  and args[0] == "intruder")
    out = s.run()
    assert out.violations == [] and out.completed, out.violations
    final = next(d for d in s.coordinators.values() if d.phase == "done")
    stage = [(max((j for j, at in s.decided_at.items() if at < t), default=-1), m) for t, m in sent]
    return stage, {j: tuple(sorted(d.deploy)) for j, d in final.state.decisions.items()}


def _real(m, mission: str) -> tuple[str, bytes]:
    """The key and bytes of a simulated intruder's message on the real wire."""
    key = keys.carrier_key(mission, m.src, m.kind)
    if m.garbled:
        return key, b"\xc1 not msgpack"
    fields = dict(m.body)
    if m.kind == "bye":
        message = Bye(mission, m.src, tuple(fields["deployments"]), (), fields["reason"])
    elif m.kind == "confirm":
        message = Confirm(mission, m.src, fields["stage"], fields["deployed"], fields["status"], (0.0, 0.0),
                          fields["passengers_left"])
    else:
        message = Observation(m.mission if m.mission != "m" else mission, m.src, fields["stage"], fields["t"],
                              fields["x"], (0.0, 0.0), fields["passengers_left"], ())
    return key, encode(message)


def test_simulated_intruders_replayed_on_real_processes_change_no_decision(tmp_path):
    path = tmp_path / "faults.yaml"
    path.write_text(faults_yaml(10))
    fleet = build_fleet(str(path), mode="coordinated")
    # the first seed whose schedule has both kinds: stale messages before the Hellos, corrupt ones
    # mid-mission (stages left to decide after them)
    for seed in range(100):
        sent, decisions = _intrusions(fleet, seed)
        if any(m.src in fleet.ids and not m.garbled and m.mission == "m" for _, m in sent) \
                and any(0 <= k <= fleet.n_stages - 3 and (m.garbled or m.mission != "m") for k, m in sent):
            break
    else:
        pytest.fail("no seed of 100 draws both kinds")
    mission = keys.mission_id_from_name("faults")
    real = Fleet(path, tmp_path / "run", f"tcp/127.0.0.1:{free_port()}")
    intruder = None
    try:
        real.coordinator()
        intruder = Node(make_config("client", [], [real.endpoint]))
        # the coordinator subscribes before it declares its token: what comes next is heard
        real.poll("the coordinator's token", lambda: intruder.live_tokens(keys.coordinator_alive(mission), 0.5))
        for k, m in sent:
            if k < 0 and not m.garbled and m.mission == "m":
                intruder.put_raw(*_real(m, mission))  # an earlier run's messages, before any Hello
        for cid in fleet.ids:
            real.carrier(cid, extra=["--no-autonomy"])
        for k, m in sent:
            if m.garbled or m.mission != "m":
                real.poll(f"stage {k} decided", lambda k=k: real.decided() >= k)
                intruder.put_raw(*_real(m, mission))
        codes = real.wait_all()
    finally:
        if intruder is not None:
            intruder.close()
        real.cleanup()
    assert all(code == 0 for code in codes.values()), (codes, real.output())
    made = {j: tuple(sorted(json.loads(deploy))) for j, deploy in real.rows("SELECT stage, deploy FROM decisions")}
    assert made == decisions, (seed, made, decisions)
    rejected = json.loads((tmp_path / "run" / "summary.json").read_text())["rejected"]["coordinator"]
    stale = sum(1 for k, m in sent if k < 0 and not m.garbled and m.mission == "m")
    assert rejected.get("no-hello", 0) >= stale, rejected
    # every message published before the last stage's Decision reached a coordinator still
    # deciding; one after it may arrive when the coordinator has written its summary, or exited
    deciding = sum(1 for k, _ in sent if k <= fleet.n_stages - 2)
    assert sum(rejected.values()) >= deciding, (rejected, deciding)
