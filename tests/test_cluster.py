"""Experiment sweeps on a Dask distributed cluster: a real scheduler and two real worker processes
on loopback, started by the test; the results equal the local process pool's for the same seeds."""
from __future__ import annotations

import csv
import json
import subprocess
import sys
import time
from pathlib import Path

import pytest

from localports import distinct_free_ports

#: Marked slow (a Dask scheduler and two workers: about a minute): run by .ci/run after the default suite.
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[1]
#: Every column of a trial row except the wall-clock timings.
TIMING = {"decision_ms_mean", "decision_ms_max", "wall_s"}
SWEEP = ["overlap", "--trials", "2", "--iterations", "60", "--overlaps", "0,12", "--seed", "5",
         "--planners", "mcts-ssap,closed-loop,ssap,random", "--no-progress"]


def _rows(path: Path) -> list[dict]:
    with open(path) as f:
        return [{k: v for k, v in row.items() if k not in TIMING} for row in csv.DictReader(f)]


@pytest.fixture()
def cluster():
    """tcp://127.0.0.1:PORT of a scheduler with two single-threaded worker processes."""
    port = distinct_free_ports(1)[0]
    address = f"tcp://127.0.0.1:{port}"
    common = dict(cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    procs = [subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1",
                               "--port", str(port), "--dashboard-address", ":0", "--no-show"], **common)]
    try:
        for _ in range(2):
            procs.append(subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_worker", address,
                                           "--nworkers", "1", "--nthreads", "1", "--host", "127.0.0.1",
                                           "--dashboard-address", ":0", "--no-nanny"], **common))
        from distributed import Client

        with Client(address, timeout=30) as client:
            client.wait_for_workers(2, timeout=60)
        yield address
    finally:
        for proc in reversed(procs):
            proc.terminate()
        for proc in procs:
            try:
                proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                proc.kill()


def test_cluster_results_equal_the_local_pool(tmp_path, cluster):
    local = subprocess.run([sys.executable, "-m", "experiments", *SWEEP, "--jobs", "2", "--out", str(tmp_path / "local")],
                           cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert local.returncode == 0, local.stderr
    started = time.monotonic()
    remote = subprocess.run([sys.executable, "-m", "experiments", *SWEEP, "--cluster", cluster,
                             "--out", str(tmp_path / "cluster")], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert remote.returncode == 0, remote.stderr
    rows = _rows(tmp_path / "cluster" / "overlap_trials.csv")
    assert len(rows) == 2 * 2 * 5, f"expected 20 rows, found {len(rows)} ({time.monotonic() - started:.0f} s)"
    assert rows == _rows(tmp_path / "local" / "overlap_trials.csv")
    info = (tmp_path / "cluster" / "run_info.json").read_text()
    assert '"worker_threads": 2' in info


def test_unreachable_cluster_is_one_line_exit_2():
    port = distinct_free_ports(1)[0]  # nothing listens there
    proc = subprocess.run([sys.executable, "-m", "experiments", *SWEEP, "--cluster", f"tcp://127.0.0.1:{port}",
                           "--cluster-timeout", "2"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "--cluster" in lines[0] and str(port) in lines[0], proc.stderr


#: A simulator campaign: every fault kind drawn, a few seeds of a small scenario.
CAMPAIGN = ["-m", "mission.simulate", str(ROOT / "scenarios" / "tiny.yaml"), "--seeds", "0:30", "--quiet"]


def test_a_simulator_campaign_on_the_cluster_has_the_local_trace_hashes(tmp_path, cluster):
    local = subprocess.run([sys.executable, *CAMPAIGN, "--json", str(tmp_path / "local.json")], cwd=ROOT,
                           capture_output=True, text=True, timeout=600)
    assert local.returncode == 0, local.stderr
    remote = subprocess.run([sys.executable, *CAMPAIGN, "--scheduler", cluster,
                             "--json", str(tmp_path / "cluster.json")],
                            cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert remote.returncode == 0, remote.stderr
    rows = {name: json.loads((tmp_path / f"{name}.json").read_text())["per_seed"] for name in ("local", "cluster")}
    assert [r["seed"] for r in rows["cluster"]] == list(range(30))
    assert [r["trace_hash"] for r in rows["cluster"]] == [r["trace_hash"] for r in rows["local"]]
    assert rows["cluster"] == rows["local"]  # faults, deployments, rewards, violations: every field
    assert local.stdout.splitlines()[-1].split("trace ")[-1] == remote.stdout.splitlines()[-1].split("trace ")[-1]


def test_an_unreachable_scheduler_is_one_line_exit_2():
    port = distinct_free_ports(1)[0]  # nothing listens there
    proc = subprocess.run([sys.executable, *CAMPAIGN, "--scheduler", f"tcp://127.0.0.1:{port}",
                           "--scheduler-timeout", "2"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "--scheduler" in lines[0] and str(port) in lines[0], proc.stderr
