"""Large-fleet features as real OS processes on loopback: several carriers per process
(--carrier-processes, --role carrier --carrier a,b), a zenoh router shared by two missions, the
scoped State reply, and the lean carrier process."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

import world
from wire import keys
from wire.messages import State, decode
from wire.zconfig import free_port

from fleet_helpers import ROOT, TINY, db_rows, deployed_matrix, offline

RUN_FLEET = str(ROOT / "run_fleet.py")
SIX = ROOT / "scenarios" / "six_carriers.yaml"


@pytest.fixture(scope="module")
def tiny():
    return world.load_scenario(TINY)


def _same_as_offline(summary, scenario):
    reference, x = offline(scenario)
    np.testing.assert_array_equal(np.array(summary["observations"], dtype=float), x)
    np.testing.assert_array_equal(deployed_matrix(summary, scenario), reference.deployed)
    assert summary["total_reward"] == pytest.approx(reference.reward)
    assert summary["rejected"]["coordinator"] == {}
    assert summary["latency_ms"]["count"] == scenario.n_carriers * scenario.stages


@pytest.mark.slow
def test_carrier_processes_give_the_decisions_of_one_process_per_carrier(tmp_path):
    six = world.load_scenario(SIX)
    out = tmp_path / "run"
    proc = subprocess.run([sys.executable, RUN_FLEET, str(SIX), "--out", str(out), "--no-map",
                           "--carrier-processes", "2"], capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    summary = json.loads((out / "summary.json").read_text())
    _same_as_offline(summary, six)
    # Six carriers, two processes of three, each carrier with its own session and Hello.
    pids = [c["pid"] for c in summary["carriers"]]
    assert len(set(pids)) == 2 and sorted(pids.count(p) for p in set(pids)) == [3, 3]
    assert len(db_rows(out / "mission.db", "SELECT DISTINCT carrier FROM events WHERE kind='hello'")) == 6


@pytest.mark.slow
def test_one_host_fleet_through_launcher_started_routers(tiny, tmp_path):
    """--routers: carriers connect to zenoh routers that connect to the coordinator (what the
    launcher does beyond 256 carriers); the mission is the offline planner's."""
    out = tmp_path / "run"
    proc = subprocess.run([sys.executable, RUN_FLEET, str(TINY), "--out", str(out), "--no-map", "--routers", "1"],
                          capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "1 more router(s) at tcp/127.0.0.1:" in proc.stdout
    _same_as_offline(json.loads((out / "summary.json").read_text()), tiny)


def _role(role, extra, scenario=TINY):
    return subprocess.Popen([sys.executable, RUN_FLEET, str(scenario), "--role", role, *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


@pytest.mark.slow
def test_one_carrier_host_simulates_several_carriers(tiny, tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    coordinator = _role("coordinator", ["--listen", endpoint, "--out", str(tmp_path), "--no-map"])
    host = _role("carrier", ["--carrier", ",".join(tiny.carrier_ids), "--connect", endpoint])
    try:
        output, _ = coordinator.communicate(timeout=90)
        host_output, _ = host.communicate(timeout=30)
    finally:
        for proc in (coordinator, host):
            if proc.poll() is None:
                proc.kill()
                proc.wait(10)
    assert coordinator.returncode == 0, output
    assert host.returncode == 0, host_output
    summary = json.loads((tmp_path / "summary.json").read_text())
    _same_as_offline(summary, tiny)
    assert len({c["pid"] for c in summary["carriers"]}) == 1
    assert all(not reasons for reasons in summary["rejected"]["carriers"].values())


@pytest.mark.slow
def test_two_missions_share_one_router_without_seeing_each_other(tiny, tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = subprocess.Popen([sys.executable, RUN_FLEET, "--role", "router", "--listen", endpoint],
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    fleets = {}
    try:
        assert "zenoh router" in router.stdout.readline()
        # The same scenario (same carrier ids) twice: only the mission id keeps them apart.
        for m in ("alpha", "beta"):
            fleets[m] = subprocess.Popen(
                [sys.executable, RUN_FLEET, str(TINY), "--mission", m, "--connect", endpoint,
                 "--out", str(tmp_path / m), "--no-map", "--carrier-processes", "1"],
                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        outputs = {m: p.communicate(timeout=120)[0] for m, p in fleets.items()}
    finally:
        for proc in [router, *fleets.values()]:
            if proc.poll() is None:
                proc.terminate()
                try:
                    proc.wait(10)
                except subprocess.TimeoutExpired:
                    proc.kill()
    for m, proc in fleets.items():
        assert proc.returncode == 0, outputs[m]
        summary = json.loads((tmp_path / m / "summary.json").read_text())
        assert summary["mission"] == m and summary["ended"]
        _same_as_offline(summary, tiny)
        # Nothing of the other mission reached this coordinator: no rejection, no foreign event.
        db = tmp_path / m / "mission.db"
        assert db_rows(db, "SELECT COUNT(*) FROM events WHERE kind='rejected'")[0][0] == 0
        hellos = db_rows(db, "SELECT carrier, payload FROM events WHERE kind='hello'")
        assert {cid for cid, _ in hellos} == set(tiny.carrier_ids)
        assert len(hellos) == tiny.n_carriers  # one Hello each: none of the twin mission's carriers
    assert router.returncode == 0


def test_state_reply_is_scoped_to_the_asking_carrier(tiny, tmp_path):
    from coordinator.node import Coordinator, CoordinatorConfig

    coord = Coordinator(tiny, CoordinatorConfig(out_dir=str(tmp_path), render=False), None)
    full = decode(coord.crew.answers.state_reply({}), State)
    assert [cid for cid, _ in full.carriers] == sorted(tiny.carrier_ids)
    mine = decode(coord.crew.answers.state_reply({"carrier": "b"}), State)
    assert [cid for cid, _ in mine.carriers] == ["b"] and mine.carrier("b") == full.carrier("b")
    assert decode(coord.crew.answers.state_reply({"carrier": "nobody"}), State).carriers == ()
    assert keys.state_selector("tiny", "b") == "marsupial/tiny/coordinator/state?carrier=b"


def test_an_unscoped_state_of_a_large_mission_lists_no_carrier(tmp_path):
    from coordinator.node import Coordinator, CoordinatorConfig
    from planner.limits import MAX_CARRIERS, MAX_STATE_CARRIERS
    from tools.scale import write_scenario

    big = world.load_scenario(write_scenario(MAX_STATE_CARRIERS + 1, tmp_path / "big.yaml", planner="ssap"))
    coord = Coordinator(big, CoordinatorConfig(out_dir=str(tmp_path), render=False), None)
    assert decode(coord.crew.answers.state_reply({}), State).carriers == ()
    last = big.carrier_ids[-1]
    assert [cid for cid, _ in decode(coord.crew.answers.state_reply({"carrier": last}), State).carriers] == [last]
    assert MAX_CARRIERS >= 1024


def test_a_carrier_process_loads_no_planner_kernels():
    """Building a carrier and stepping its world loads no numba, scipy or matplotlib: the on-board
    planner is loaded only by a running carrier that may decide alone (in the background), never
    by one run with --no-autonomy."""
    code = (
        "import sys, runpy\n"
        "sys.argv = ['run_fleet.py', %r, '--role', 'carrier', '--carrier', 'a']\n"
        "import world\nfrom launcher.flags import parse_args\nfrom launcher.settings import check\n"
        "from carriers.node import Carrier, CarrierConfig\nfrom carriers.shared import shared_world\n"
        "s = world.load_scenario(%r)\n"
        "args = parse_args(sys.argv[1:])\n"
        "assert check(args, s)[1] == []\n"
        "c = Carrier(s, CarrierConfig('a'), None, shared=shared_world(s))\n"
        "sim = world.Simulation(s, ['a'], features=c.parts.shared.features); sim.advance_to(10.0); sim.sense('a')\n"
        "import wire.transport\n"
        "heavy = sorted({m.split('.')[0] for m in sys.modules} & {'numba', 'scipy', 'matplotlib', 'llvmlite'})\n"
        "print(','.join(heavy) or 'none')\n" % (str(TINY), str(TINY)))
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, cwd=str(ROOT))
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "none"


def test_stage_gate_holds_until_every_waiting_carrier_of_the_process_answered():
    import threading
    import time

    from carriers.shared import StageGate

    gate = StageGate()
    assert gate.hold(0, 5.0)  # nobody waits: at once
    gate.waiting(3)
    gate.waiting(3)
    gate.waiting(4)
    released = threading.Event()
    holder = threading.Thread(target=lambda: gate.hold(3, 30.0) and released.set())
    holder.start()
    gate.answered(3)
    time.sleep(0.2)
    assert not released.is_set()  # one carrier still waits for stage 3
    gate.answered(3)
    holder.join(10.0)
    assert released.is_set()
    t0 = time.monotonic()
    assert not gate.hold(4, 0.3)  # a carrier that never answers holds the others at most the timeout
    assert 0.25 <= time.monotonic() - t0 < 5.0
    gate.answered(4)
    assert gate.hold(4, 0.0)


def test_the_physics_thread_runs_calls_in_order_at_a_lower_priority_and_hands_back_errors():
    import os
    import sys
    import threading
    from concurrent import futures

    from carriers.shared import PHYSICS_NICE, PhysicsThread

    physics = PhysicsThread()
    seen = []

    def call(k):
        seen.append((k, threading.current_thread().name))
        return k * k

    jobs = [physics.submit(call, k) for k in range(5)]
    assert not futures.wait(jobs, 10.0).not_done
    assert [job.result() for job in jobs] == [0, 1, 4, 9, 16]
    assert seen == [(k, "physics") for k in range(5)]  # one thread, in the order submitted
    failing = physics.submit(lambda: 1 / 0)
    assert futures.wait((failing,), 10.0).done
    with pytest.raises(ZeroDivisionError):
        failing.result()
    assert futures.wait((physics.submit(call, 7),), 10.0).done  # the thread survives a call that raised
    worker = physics.submit(threading.current_thread).result(10.0)
    if sys.platform.startswith("linux"):
        base = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
        assert os.getpriority(os.PRIO_PROCESS, worker.native_id) == min(19, base + PHYSICS_NICE)
    physics.shutdown(wait=True)
    assert not worker.is_alive()


def test_the_on_board_planner_loads_at_the_start_alone_and_when_needed_with_several(tiny):
    from carriers.node import Carrier, CarrierConfig
    from carriers.onboard import with_onboard_load

    assert [c.onboard_load for c in with_onboard_load([CarrierConfig("a")])] == ["start"]
    assert [c.onboard_load for c in with_onboard_load([CarrierConfig("a"), CarrierConfig("b")])] == ["need", "need"]
    assert [c.onboard_load for c in with_onboard_load([CarrierConfig("a", onboard_load="start"),
                                                       CarrierConfig("b")])] == ["start", "need"]
    with pytest.raises(ValueError, match="onboard_load must be one of"):
        Carrier(tiny, CarrierConfig("a", onboard_load="later"), None)


def test_merged_rows_replace_their_family_size_and_load(tmp_path):
    # tools.scale --merge: a new row replaces the documented one of the same family, R, busy
    # count and carrier flags; the others stay with their own 'measured' dates.
    import json

    from tools.scale import merge_rows

    path = tmp_path / "fidelity_scale.json"
    old = [{"family": "grid", "R": 256, "busy": 0, "carriers": "hybrid", "measured": "2026-12-01", "wall_s": 85.0},
           {"family": "grid", "R": 256, "busy": 4, "carriers": "hybrid", "measured": "2026-12-01", "wall_s": 510.0},
           {"family": "long-streets", "R": 6, "busy": 0, "carriers": "hybrid", "measured": "2026-12-01", "wall_s": 99.0}]
    path.write_text(json.dumps(old))
    new = [{"family": "grid", "R": 256, "busy": 0, "carriers": "hybrid", "measured": "2026-12-02", "wall_s": 42.0},
           {"family": "grid", "R": 1024, "busy": 0, "carriers": "hybrid", "measured": "2026-12-02", "wall_s": 190.0}]
    rows = merge_rows(path, new)
    assert json.loads(path.read_text()) == rows
    got = {(r["family"], r["R"], r["busy"]): (r["measured"], r["wall_s"]) for r in rows}
    assert got == {("grid", 256, 0): ("2026-12-02", 42.0), ("grid", 256, 4): ("2026-12-01", 510.0),
                   ("grid", 1024, 0): ("2026-12-02", 190.0), ("long-streets", 6, 0): ("2026-12-01", 99.0)}
    assert path.with_suffix(".csv").read_text().count("\n") == 5


@pytest.mark.parametrize("family", ["grid", "long-streets"])
@pytest.mark.parametrize("n, stages", [(6, 3), (256, 3), (1024, 3), (1024, 12)])
def test_generated_scenarios_are_valid_at_every_size_and_length(family, n, stages):
    # A family's scenario must load whatever R and stage count it is asked for (long streets with
    # few stages and many carriers once drew streets outside its map).
    from tools.scale import FAMILIES
    from world.scenario import parse_scenario

    scenario = parse_scenario(FAMILIES[family](n, seed=4, stages=stages))
    assert scenario.n_carriers == n and scenario.stages == stages
