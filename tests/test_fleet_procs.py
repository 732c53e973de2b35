"""The fleet as real OS processes: run_fleet.py on one host, a carrier killed mid-mission, and
carriers on separate hosts (network namespaces)."""
from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

import world
from wire.zconfig import free_port

from tools import netns
from fleet_helpers import ROOT, TINY, alive, db_rows, deployed_matrix, offline

RUN_FLEET = str(ROOT / "run_fleet.py")


@pytest.fixture(scope="module")
def tiny():
    return world.load_scenario(TINY)


def _check_no_double_deployment(summary, db, scenario):
    for carrier, spec in zip(summary["carriers"], scenario.carriers):
        stages = [d["stage"] for d in carrier["deployments"]]
        assert len(stages) == len(set(stages)) <= spec.passengers
    confirmed = db_rows(db, "SELECT carrier, stage FROM confirmations WHERE deployed=1")
    assert len(confirmed) == len(set(confirmed))
    decided = [s for (s,) in db_rows(db, "SELECT stage FROM decisions")]
    assert len(decided) == len(set(decided))


@pytest.mark.slow
def test_run_fleet_on_one_host(tiny, tmp_path):
    out = tmp_path / "run"
    proc = subprocess.run([sys.executable, RUN_FLEET, str(TINY), "--out", str(out)],
                          capture_output=True, text=True, timeout=180, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr
    assert all(f"stage {j:>3} of 0..{tiny.stages - 1} " in proc.stdout for j in range(tiny.stages))
    # tools.startup_bench times the first of these lines and compares their deploy columns
    from tools.startup_bench import STAGE_LINE
    assert sum(bool(STAGE_LINE.match(line)) for line in proc.stdout.splitlines()) == tiny.stages
    assert (out / "mission.db").exists() and (out / "map.png").stat().st_size > 10_000
    summary = json.loads((out / "summary.json").read_text())
    for field in ("scenario", "planner", "seed", "stages", "carriers", "total_reward", "total_features",
                  "clairvoyant", "wall_time_s", "latency_ms", "rejected"):
        assert field in summary, field
    pids = {c["pid"] for c in summary["carriers"]} | {summary["coordinator"]["pid"]}
    assert len(pids) == tiny.n_carriers + 1  # one OS process each
    for carrier in summary["carriers"]:
        assert carrier["host"] and carrier["passengers"] >= len(carrier["deployments"])
        for dep in carrier["deployments"]:
            assert set(dep) >= {"stage", "x", "position", "reward"}
    assert summary["latency_ms"]["p50"] is not None and summary["latency_ms"]["p99"] >= summary["latency_ms"]["p50"]
    # one stage-number convention: the console's stage j is summary.json's stage j
    lines = {int(line.split()[1]): line for line in proc.stdout.splitlines() if line.startswith("stage ")}
    for j, deploy in enumerate(summary["decisions"]):
        assert f"| deploy {' '.join(deploy) or '-'} |" in lines[j], (j, lines[j])
    reference, _ = offline(tiny)
    np.testing.assert_array_equal(deployed_matrix(summary, tiny), reference.deployed)
    assert summary["total_reward"] == pytest.approx(reference.reward)
    assert summary["clairvoyant"]["reward"] >= summary["total_reward"] - 1e-9


def test_bad_scenario_gets_one_line_errors_and_exit_2(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text(TINY.read_text().replace("stages: 4", "stages: -4").replace("speed: 2.0", "speed: fast", 1))
    proc = subprocess.run([sys.executable, RUN_FLEET, str(bad), "--out", str(tmp_path / "o")],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) >= 2 and all(str(bad) in line for line in lines), proc.stderr
    assert "Traceback" not in proc.stderr and not (tmp_path / "o").exists()
    proc = subprocess.run([sys.executable, RUN_FLEET, str(TINY), "--role", "carrier", "--carrier", "nobody"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "--carrier" in proc.stderr and "Traceback" not in proc.stderr


def _role(role, extra, **kwargs):
    return subprocess.Popen([sys.executable, RUN_FLEET, str(TINY), "--role", role, *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, **kwargs)


def _read_until(proc, marker, timeout_s):
    """Lines of ``proc``'s stdout up to and including the first containing ``marker``."""
    lines = []
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            break
        lines.append(line)
        if marker in line:
            return lines
    raise AssertionError(f"{marker!r} not seen; output so far:\n{''.join(lines)}")


@pytest.mark.slow
def test_killed_carrier_becomes_empty_and_the_mission_completes(tiny, tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    timing = ["--realtime", "5"]  # a stage per wall second
    coordinator = _role("coordinator", ["--listen", endpoint, "--out", str(tmp_path), "--no-map", *timing])
    carriers = {cid: _role("carrier", ["--carrier", cid, "--connect", endpoint, *timing])
                for cid in tiny.carrier_ids}
    try:
        _read_until(coordinator, f"stage   1 of 0..{tiny.stages - 1}", 120)  # stage 1 is decided
        carriers["a"].send_signal(signal.SIGKILL)
        rest, _ = coordinator.communicate(timeout=120)
    finally:
        for proc in [coordinator, *carriers.values()]:
            if proc.poll() is None:
                proc.kill()
            proc.wait(10)
    assert coordinator.returncode == 0, rest
    assert "carrier a is gone" in rest
    summary = json.loads((tmp_path / "summary.json").read_text())
    db = tmp_path / "mission.db"
    ra = tiny.carrier_index("a")
    # The token vanished after stage 1 was decided (the coordinator's next stage then was >= 2).
    dead_at = db_rows(db, "SELECT stage FROM events WHERE kind='dead' AND carrier='a'")[0][0]
    assert dead_at == 2  # killed within the second between decision 1 and observation 2
    after = list(range(dead_at + 1, tiny.stages))
    assert after  # a is scheduled to the last stage: at least one stage is lost
    obs = np.array(summary["observations"], dtype=float)
    assert np.isnan(obs[ra, dead_at + 1:]).all()               # a's stages after its death are ∅
    assert set(summary["carriers"][ra]["missing_stages"]) >= set(after)
    assert not summary["carriers"][ra]["live_at_end"] and summary["ended"]
    assert summary["stages_decided"] == tiny.stages
    assert all(dep["stage"] <= dead_at for dep in summary["carriers"][ra]["deployments"])
    _check_no_double_deployment(summary, db, tiny)
    assert carriers["b"].returncode == 0 and carriers["a"].returncode == -signal.SIGKILL


@pytest.mark.slow
def test_separate_hosts_with_network_namespaces(tiny, tmp_path):
    reason = netns.unavailable()
    if reason:
        pytest.skip(f"network namespaces unavailable: {reason}")
    with netns.hosts(1 + tiny.n_carriers) as (coordinator_host, *carrier_hosts):
        endpoint = f"tcp/{coordinator_host.ip}:7447"
        argv = [sys.executable, RUN_FLEET, str(TINY)]
        coordinator = coordinator_host.popen(
            argv + ["--role", "coordinator", "--listen", endpoint, "--out", str(tmp_path), "--no-map"],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        carriers = [host.popen(argv + ["--role", "carrier", "--carrier", cid, "--connect", endpoint],
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
                    for cid, host in zip(tiny.carrier_ids, carrier_hosts)]
        try:
            output, _ = coordinator.communicate(timeout=150)
            outputs = [p.communicate(timeout=60)[0] for p in carriers]
        finally:
            for proc in [coordinator, *carriers]:
                if proc.poll() is None:
                    proc.kill()
                    proc.wait(10)
    assert coordinator.returncode == 0, output
    assert all(p.returncode == 0 for p in carriers), outputs
    summary = json.loads((tmp_path / "summary.json").read_text())
    reference, x = offline(tiny)
    np.testing.assert_array_equal(np.array(summary["observations"], dtype=float), x)
    np.testing.assert_array_equal(deployed_matrix(summary, tiny), reference.deployed)
    _check_no_double_deployment(summary, tmp_path / "mission.db", tiny)


@pytest.mark.slow
def test_ctrl_c_stops_every_process_cleanly(tiny, tmp_path):
    out = tmp_path / "run"
    # Its own process group, as a terminal would make it: Ctrl-C reaches the whole group.
    proc = subprocess.Popen([sys.executable, RUN_FLEET, str(TINY), "--out", str(out), "--realtime", "1", "--no-map"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        lines = _read_until(proc, f"stage   0 of 0..{tiny.stages - 1}", 120)
        pids = [int(p) for p in re.findall(r"pid (\d+)", "".join(lines))]
        assert len(pids) == 2 + tiny.n_carriers  # the router, the coordinator, the carriers
        os.killpg(proc.pid, signal.SIGINT)
        rest, _ = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(10)
    assert proc.returncode == 130, rest
    assert "Traceback" not in rest
    deadline = time.monotonic() + 5
    while any(alive(pid) for pid in pids) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not any(alive(pid) for pid in pids)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["end_reason"] == "stopped" and summary["stages_decided"] < tiny.stages
