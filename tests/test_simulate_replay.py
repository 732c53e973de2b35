"""Simulated fault schedules replayed on real processes (issue 33, item 6): a schedule the
simulator draws from a seed is carried out on the real fleet (run_fleet.py single-role
processes over real Zenoh, tests/test_faults.py's helpers), each fault placed at the stage it
struck in the simulated mission and lasting as long, and the real fleet makes the simulated
mission's decisions.

The kind replayed is ``coordinator-crash`` with carriers that hold (``--no-autonomy``, the
simulator's ``coordinated`` mode): its decisions are a function of the schedule alone, not of
how long each side took. Carrier crashes and cuts are not replayed: which stages are decided
without the carrier depends on the real processes' timing, which the simulated one does not
reproduce.
"""
from __future__ import annotations

import json
import time

import pytest

from launcher.simulate import build_fleet
from mission import simulate as sim
from test_faults import Fleet, faults_yaml
from wire.zconfig import free_port

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
