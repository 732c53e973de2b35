"""Simulated fault schedules replayed on real processes: a schedule the simulator draws from a
seed is carried out on the real fleet over real Zenoh, each fault placed at the stage it struck
in the simulated mission, and the real fleet makes the simulated mission's decisions.

``coordinator-crash`` with carriers that hold (``--no-autonomy``, the simulator's
``coordinated`` mode) is flown by ``run_fleet.py --schedule`` (launcher/faults.py; every other
kind it flies: tests/test_schedule_flight.py). The intruders' messages, ``corrupt`` (garbled
ones and another mission's, mid-mission) and ``stale`` (a carrier's messages of an earlier run
of the mission, before its Hello), which the launcher does not fly, are each published by a
Zenoh session of the test at the stage it struck in the simulated mission (run_fleet.py
single-role processes, tests/test_faults.py's helpers).
"""
from __future__ import annotations

import json

import pytest

from launcher.simulate import build_fleet, mission_json
from mission import simulate as sim
from test_faults import Fleet, faults_yaml
from tools import schedule_flight as flight
from wire import keys
from wire.messages import Bye, Confirm, Observation, encode
from wire.transport import Node
from wire.zconfig import free_port, make_config

pytestmark = pytest.mark.slow


def test_a_simulated_coordinator_crash_flown_on_real_processes_makes_the_same_decisions(tmp_path):
    """The seeds' schedules flown by ``run_fleet.py --schedule`` (the launcher's injector, the one
    implementation: tools/schedule_flight.py), the carriers holding while the coordinator is down."""
    path = tmp_path / "faults.yaml"
    path.write_text(faults_yaml(10))
    fleet = build_fleet(str(path), mode="coordinated")
    # the first seeds with one drawn crash, striking mid-mission (stages are left to the restarted
    # process) and shorter than 20 s (the wall seconds the flight keeps it down)
    picked = []
    for seed in range(300):
        s = sim.Simulation(fleet, seed, kinds=("coordinator-crash",))
        out = s.run()
        crash = [f for f in s.faults if f.kind == "coordinator-crash"]
        if len(crash) != 1 or out.violations or not out.completed:
            continue
        row = mission_json(fleet, seed, ("coordinator-crash",))
        if 1 <= row["faults"][0]["decided"] <= fleet.n_stages - 3 and crash[0].until - crash[0].at < 20.0:
            final = next(d for d in s.coordinators.values() if d.phase == "done")
            picked.append((row, [list(final.state.decisions[j].deploy) for j in range(fleet.n_stages)]))
        if len(picked) == 2:
            break
    assert len(picked) == 2
    for row, decisions in picked:
        real = flight.fly(path, row["faults"], "coordinated", tmp_path / f"run-{row['seed']}")
        assert real["code"] == 0, real["output"]
        assert [sorted(d) for d in real["decisions"]] == [sorted(d) for d in decisions], (row, real)
        assert real["deployments"] == row["deployments"], (row, real)
        struck = next(e for e in real["log"] if e["what"] == "struck")
        assert struck["decided"] >= row["faults"][0]["decided"]


def _intrusions(fleet, seed: int) -> tuple[list, dict]:
    """The messages the seed's ``corrupt``/``stale`` faults inject in the simulated mission, each
    as (the stage after whose Decision it arrived, -1 before the first; the message), in time
    order, and the simulated mission's decisions (stage -> ids)."""
    s = sim.Simulation(fleet, seed, kinds=("corrupt", "stale"))
    sent = sorted((t, args[2]) for t, _, fn, args in s.heap if getattr(fn, "__name__", "") == "arrive"
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
