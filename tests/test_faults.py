"""The fleet under faults, as real OS processes over real Zenoh (run_fleet.py single-role mode):
a coordinator SIGKILLed and restarted on the same results directory, a carrier SIGKILLed and
restarted, and a carrier's network link cut for several seconds (network namespaces).

Every test runs a 10- or 12-stage mission (:func:`faults_yaml`) at ``--realtime 5`` (a stage per wall
second), polls mission.db for the moment to strike (never sleeps and hopes), and then checks
mission.db, summary.json and the carriers' own accounts (their Bye messages).
"""
from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import world
from world import build_problem
from planner.registry import planner_settings
from planner.registry import make_planner
from planner.online import run_online
from wire.zconfig import free_port

from tools import netns
from fleet_helpers import ROOT, db_rows, deployed_matrix

#: Marked slow (faults over real processes and network namespaces: about a minute): run by .ci/run after the default suite.
pytestmark = pytest.mark.slow

RUN_FLEET = str(ROOT / "run_fleet.py")

def faults_yaml(stages: int) -> str:
    """A longer tiny.yaml: 2 carriers, ``stages`` stages 5 s apart (a: every stage, b: from
    stage 1), so a fault early in the mission leaves stages to recover in. 200 MCTS iterations:
    planning takes about 1 ms."""
    length = 10.0 * stages  # metres at 2 m/s: a reaches its last waypoint at t = 5 * stages s
    return f"""\
name: faults
seed: 11
map:
  bounds: [0, 0, {length + 8:g}, 40]
  walls:
    - [[12, 23.5], [30, 23.5]]
features:
  density: 0.05
sensing_radius: 5.0
stage_interval: 5.0
stages: {stages}
carriers:
  - id: a
    passengers: 3
    start_time: 0
    speed: 2.0
    waypoints: [[4, 20], [{length - 4:g}, 20]]
  - id: b
    passengers: 2
    start_time: 5
    speed: 2.0
    waypoints: [[20, 4], [20, 22], [{length - 6:g}, 22]]
planner:
  name: mcts-ssap
  iterations: 200
"""


#: One stage per wall second.
PACE = ["--realtime", "5"]


@pytest.fixture(scope="module")
def scenario_file(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("faults") / "faults.yaml"
    path.write_text(faults_yaml(10))
    return path


@pytest.fixture(scope="module")
def scenario(scenario_file):
    return world.load_scenario(scenario_file)


class Fleet:
    """The processes of one test; each writes its output to a log file under ``logs``."""

    def __init__(self, scenario_file: Path, out: Path, endpoint: str):
        self.scenario_file = scenario_file
        self.out = out
        self.endpoint = endpoint
        self.db = out / "mission.db"
        self.procs: dict[str, subprocess.Popen] = {}
        self.killed: set[str] = set()
        self.logs = out.parent / "logs"
        self.logs.mkdir(parents=True, exist_ok=True)

    def start(self, name: str, role_args: list[str], host=None, extra=()) -> subprocess.Popen:
        argv = [sys.executable, RUN_FLEET, str(self.scenario_file), *role_args, *PACE, *extra]
        log = open(self.logs / f"{name}.log", "a")
        spawn = host.popen if host is not None else subprocess.Popen
        proc = spawn(argv, stdout=log, stderr=subprocess.STDOUT, text=True, cwd=str(ROOT))
        log.close()
        self.procs[name] = proc
        return proc

    def coordinator(self, name="coordinator", host=None, extra=()):
        return self.start(name, ["--role", "coordinator", "--listen", self.endpoint, "--out", str(self.out),
                                 "--no-map"], host, extra)

    def carrier(self, cid, name=None, host=None, extra=()):
        return self.start(name or cid, ["--role", "carrier", "--carrier", cid, "--connect", self.endpoint,
                                        "--out", str(self.out), "--quiet"], host, extra)

    def output(self) -> str:
        return "\n".join(f"--- {p.name}\n{p.read_text()[-3000:]}" for p in sorted(self.logs.glob("*.log")))

    def rows(self, sql: str):
        if not self.db.exists():
            return []
        try:
            return db_rows(self.db, sql)
        except Exception:  # the file exists but the schema is not written yet
            return []

    def poll(self, what: str, condition, timeout_s: float = 90.0):
        """Poll ``condition()`` every 10 ms until it returns a true value (returned)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            value = condition()
            if value:
                return value
            dead = [n for n, p in self.procs.items() if p.poll() is not None and p.returncode != 0
                    and n not in self.killed]
            if dead:
                break
            time.sleep(0.01)
        raise AssertionError(f"timed out waiting for {what}\n{self.output()}")

    def decided(self) -> int:
        """Highest decided stage in mission.db (-1 when none)."""
        rows = self.rows("SELECT MAX(stage) FROM decisions")
        return rows[0][0] if rows and rows[0][0] is not None else -1

    def kill(self, name: str) -> float:
        """SIGKILL one process; returns the wall time (s since the epoch) just before the signal."""
        self.killed.add(name)
        t = time.time()
        self.procs[name].send_signal(signal.SIGKILL)
        self.procs[name].wait(10)
        return t

    def wait_all(self, timeout_s: float = 90.0) -> dict[str, int]:
        deadline = time.monotonic() + timeout_s
        codes = {}
        for name, proc in self.procs.items():
            try:
                codes[name] = proc.wait(max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                codes[name] = None
        return codes

    def cleanup(self) -> None:
        for proc in self.procs.values():
            if proc.poll() is None:
                proc.kill()
                proc.wait(10)


def _summary(fleet: Fleet) -> dict:
    return json.loads((fleet.out / "summary.json").read_text())


def _byes(fleet: Fleet, cid: str) -> list[list[int]]:
    """The deployments each process of carrier ``cid`` reported in its Bye (its own account)."""
    return [json.loads(p)["deployments"] for (p,) in
            fleet.rows(f"SELECT payload FROM events WHERE kind='bye' AND carrier='{cid}' ORDER BY seq")]


def _recorded_observations(summary: dict) -> np.ndarray:
    return np.array([[np.nan if v is None else v for v in row] for row in summary["observations"]], dtype=float)


def _check_at_most_once(fleet: Fleet, scenario, summary: dict) -> None:
    """No carrier deployed twice at a stage or more passengers than it carries, by the
    coordinator's record and by each carrier process's own account."""
    for carrier, spec in zip(summary["carriers"], scenario.carriers):
        stages = [d["stage"] for d in carrier["deployments"]]
        assert len(stages) == len(set(stages)) <= spec.passengers, carrier
        for own in _byes(fleet, spec.id):
            assert len(own) == len(set(own)) <= spec.passengers, (spec.id, own)
            assert set(stages) <= set(own), (spec.id, stages, own)
    confirmed = fleet.rows("SELECT carrier, stage FROM confirmations WHERE deployed=1")
    assert len(confirmed) == len(set(confirmed))
    for stage, count in fleet.rows("SELECT stage, COUNT(*) FROM events WHERE kind='decision' GROUP BY stage"):
        assert count == 1, f"stage {stage} decided {count} times"


def _replanned(scenario, x: np.ndarray) -> np.ndarray:
    """The planner core's decisions over observations ``x`` with the scenario's seed."""
    name, options = planner_settings(scenario)
    return run_online(build_problem(scenario), x, make_planner(name, **options), scenario.seed).deployed


def test_coordinator_sigkill_and_restart_recovers_from_mission_db(scenario_file, scenario, tmp_path):
    """SIGKILL the coordinator after stage 2 is decided; a new coordinator process on the same
    --out replays mission.db and finishes: every stage decided exactly once, the decisions those of
    an uninterrupted run on the same observations, no carrier deploying twice."""
    fleet = Fleet(scenario_file, tmp_path / "run", f"tcp/127.0.0.1:{free_port()}")
    try:
        fleet.coordinator("coordinator-1")
        for cid in scenario.carrier_ids:
            fleet.carrier(cid, extra=["--no-autonomy"])  # they hold: the recovery is mission.db's alone
        fleet.poll("stage 2 decided", lambda: fleet.decided() >= 2)
        killed_at = fleet.kill("coordinator-1")
        before = dict(fleet.rows("SELECT stage, deploy FROM decisions"))
        k = max(before)
        assert 2 <= k < scenario.stages - 1  # killed mid-mission: stages are left to the new process
        fleet.coordinator("coordinator-2")
        codes = fleet.wait_all()
    finally:
        fleet.cleanup()
    assert codes["coordinator-2"] == 0, fleet.output()
    assert codes["a"] == 0 and codes["b"] == 0, (codes, fleet.output())
    summary = _summary(fleet)
    assert summary["resumed"] and summary["ended"] and summary["end_reason"] == "complete"
    assert summary["stages_decided"] == scenario.stages
    # Each stage decided exactly once, the first k+1 by the killed process and never again.
    decided = dict(fleet.rows("SELECT stage, deploy FROM decisions"))
    assert sorted(decided) == list(range(scenario.stages))
    assert {j: decided[j] for j in before} == before
    reopened = fleet.rows("SELECT seq FROM events WHERE kind='open' ORDER BY seq")[1][0]
    by_restarted = [s for (s,) in fleet.rows(f"SELECT stage FROM decisions WHERE seq > {reopened}")]
    assert sorted(by_restarted) == list(range(k + 1, scenario.stages))
    reopened_at = fleet.rows(f"SELECT wall_time FROM events WHERE seq = {reopened}")[0][0]
    back = fleet.rows(f"SELECT MAX(wall_time) FROM events WHERE kind='alive' AND seq > {reopened}")[0][0]
    resumed = fleet.rows(f"SELECT wall_time FROM events WHERE kind='decision' AND stage = {k + 1}")[0][0]
    print(f"coordinator SIGKILL after stage {k}: restarted process opened mission.db "
          f"{reopened_at - killed_at:.1f} s after the kill; carriers live again {back - reopened_at:.1f} s "
          f"and stage {k + 1} decided {resumed - reopened_at:.1f} s after it opened mission.db")
    # No observation was lost (the carriers held and re-sent theirs), and the decisions are an
    # uninterrupted run's: the planner core over the same observations with the same seed.
    x = _recorded_observations(summary)
    np.testing.assert_array_equal(x, world.observe_all(scenario))
    np.testing.assert_array_equal(deployed_matrix(summary, scenario), _replanned(scenario, x))
    _check_at_most_once(fleet, scenario, summary)
    # Each carrier process's own account equals the decisions (nothing lost, nothing repeated).
    for r, cid in enumerate(scenario.carrier_ids):
        expected = [j for j in range(scenario.stages) if cid in summary["decisions"][j]]
        assert _byes(fleet, cid) == [expected]


def test_carrier_sigkill_is_detected_by_liveliness_and_a_restarted_carrier_rejoins(
        scenario_file, scenario, tmp_path):
    """SIGKILL carrier a after stage 1: the coordinator records its liveliness loss within 2 s
    (the stage timeout is 10 s, so this is the token, not a timeout); a's stages are ∅ while it is
    gone (two stages are decided without it); a new process for a learns from the mission state where it is and how many passengers it
    has left, observes again and never deploys twice."""
    fleet = Fleet(scenario_file, tmp_path / "run", f"tcp/127.0.0.1:{free_port()}")
    ra = scenario.carrier_index("a")
    passengers = scenario.carriers[ra].passengers
    try:
        fleet.coordinator(extra=["--stage-timeout", "10"])
        for cid in scenario.carrier_ids:
            fleet.carrier(cid, name=f"{cid}-1")
        fleet.poll("stage 1 decided", lambda: fleet.decided() >= 1)
        killed_at = fleet.kill("a-1")
        dead = fleet.poll("a's liveliness loss in mission.db", lambda: fleet.rows(
            "SELECT wall_time, stage, seq FROM events WHERE kind='dead' AND carrier='a'"))
        dead_time, dead_stage, dead_seq = dead[0]
        # Two stages go by without a (the coordinator no longer waits for it), then a restarts.
        fleet.poll("two stages decided without a", lambda: fleet.decided() >= dead_stage + 1)
        fleet.carrier("a", name="a-2")
        codes = fleet.wait_all()
    finally:
        fleet.cleanup()
    detection_s = dead_time - killed_at
    print(f"liveliness loss recorded {detection_s * 1e3:.0f} ms after SIGKILL")
    assert detection_s < 2.0, detection_s
    assert codes["coordinator"] == 0 and codes["a-2"] == 0 and codes["b-1"] == 0, (codes, fleet.output())
    summary = _summary(fleet)
    assert summary["ended"] and summary["end_reason"] == "complete"
    assert summary["stages_decided"] == scenario.stages
    # The new process's Hello: where it joins and what it carries, learnt from the mission state.
    hellos = fleet.rows("SELECT seq, stage, payload FROM events WHERE kind='hello' AND carrier='a' ORDER BY seq")
    assert len(hellos) == 2
    rejoin_seq, rejoin_stage, payload = hellos[1]
    hello = json.loads(payload)
    assert dead_stage <= rejoin_stage < scenario.stages
    deployed_before = [j for j in range(rejoin_stage) if "a" in summary["decisions"][j]]
    refuted = {s for (s,) in fleet.rows("SELECT stage FROM confirmations WHERE carrier='a' AND deployed=0")}
    assert deployed_before and hello["passengers_left"] == passengers - len(set(deployed_before) - refuted)
    # While a was gone its scheduled stages are ∅ (recorded missing).
    gone = [j for (j,) in fleet.rows(
        f"SELECT stage FROM decisions WHERE seq > {dead_seq} AND seq < {rejoin_seq}")]
    assert len(gone) >= 2, gone
    missing = {s for (s,) in fleet.rows("SELECT stage FROM observations WHERE carrier='a' AND missing=1")}
    assert set(gone) <= missing
    # After rejoining it observes from its place in the schedule (the world's own values) ...
    after = [(s, x) for s, x in fleet.rows(
        f"SELECT stage, x FROM observations WHERE carrier='a' AND missing=0 AND seq > {rejoin_seq}")]
    assert after and all(s >= rejoin_stage for s, _ in after)
    truth = world.observe_all(scenario)
    assert all(x == truth[ra, s] for s, x in after)
    # ... answers the decisions from then on, and never deploys twice or beyond its passengers.
    answered = {s for (s,) in fleet.rows(f"SELECT stage FROM confirmations WHERE carrier='a' AND seq > {rejoin_seq}")}
    assert set(range(rejoin_stage, scenario.stages)) <= answered
    _check_at_most_once(fleet, scenario, summary)
    own = _byes(fleet, "a")[-1]
    assert set(deployed_before) - refuted <= set(own)


_NO_NETNS = netns.unavailable()


@pytest.mark.skipif(_NO_NETNS is not None, reason=f"network namespaces unavailable: {_NO_NETNS}")
def test_network_partition_of_a_carrier(tmp_path):
    """Coordinator, carrier a and carrier b on three hosts (network namespaces), carriers that
    never decide on their own (--no-autonomy); a's link goes down for 6 s after stage 2, then up. Zenoh's lease is 3 s here and clients retry every second
    at most (a --zenoh-config file), so the cut outlasts the lease: a's token vanishes, a's
    session reconnects after the cut and resynchronises. The mission completes; the stages decided while a was cut off are ∅ for a;
    nothing is deployed twice; a joins the first undecided stage at once (no lagging behind)."""
    cut_s = 6.0
    # 12 stages: a is away for the cut plus its reconnection (about 7 s) while the coordinator
    # goes on at a stage per second; stages must be left for a to come back to.
    scenario_file = tmp_path / "faults12.yaml"
    scenario_file.write_text(faults_yaml(12))
    scenario = world.load_scenario(scenario_file)
    zconf = tmp_path / "lease.json5"
    zconf.write_text("{ transport: { link: { tx: { lease: 3000, keep_alive: 4 } } },\n"
                     "  connect: { retry: { period_init_ms: 250, period_max_ms: 1000, period_increase_factor: 2 } } }\n")
    lease = ["--zenoh-config", str(zconf)]
    with netns.hosts(3) as (coordinator_host, host_a, host_b):
        fleet = Fleet(scenario_file, tmp_path / "run", f"tcp/{coordinator_host.ip}:7447")
        try:
            fleet.coordinator(host=coordinator_host, extra=["--stage-timeout", "1.5", *lease])
            fleet.carrier("a", host=host_a, extra=[*lease, "--no-autonomy"])
            fleet.carrier("b", host=host_b, extra=[*lease, "--no-autonomy"])
            fleet.poll("stage 2 decided", lambda: fleet.decided() >= 2)
            cut_at = time.time()
            host_a.link(False)
            time.sleep(cut_s)
            host_a.link(True)
            restored_at = time.time()
            codes = fleet.wait_all()
        finally:
            fleet.cleanup()
    assert codes == {"coordinator": 0, "a": 0, "b": 0}, (codes, fleet.output())
    summary = _summary(fleet)
    assert summary["ended"] and summary["end_reason"] == "complete"
    assert summary["stages_decided"] == scenario.stages
    # The cut outlasted the lease: a's token vanished during the cut and came back after it.
    tokens = fleet.rows("SELECT kind, wall_time FROM events WHERE carrier='a' AND kind IN ('alive', 'dead') "
                        "ORDER BY seq")
    assert [k for k, _ in tokens][:3] == ["alive", "dead", "alive"], tokens
    assert cut_at < tokens[1][1] < restored_at < tokens[2][1]
    print(f"partition: a's token lost {tokens[1][1] - cut_at:.1f} s into the {cut_s:.0f} s cut, "
          f"back {tokens[2][1] - restored_at:.1f} s after the link")
    published = {s: t for s, t in fleet.rows(
        "SELECT stage, wall_time FROM events WHERE kind='decision'")}
    # Stage j's observation is sent after decision j-1 arrives: when decision j-1 went out after
    # the cut and decision j before the link came back, a could not have reported j.
    cut_off = [j for j in range(1, scenario.stages) if published[j - 1] > cut_at and published[j] < restored_at]
    assert cut_off, f"no stage decided entirely within the {cut_s} s cut"
    missing = {s for (s,) in fleet.rows("SELECT stage FROM observations WHERE carrier='a' AND missing=1")}
    assert set(cut_off) <= missing
    x = _recorded_observations(summary)
    ra = scenario.carrier_index("a")
    assert np.isnan(x[ra, cut_off]).all()
    # a resumes at once: of the first two stages decided after its new Hello, it observed one
    # (a carrier replaying the missed stages at its own pace would miss both).
    rejoined = fleet.rows("SELECT seq, stage FROM events WHERE kind='hello' AND carrier='a' ORDER BY seq")[-1]
    assert rejoined[1] > max(cut_off)  # its Hello says it goes on after the stages it missed
    next_two = [s for (s,) in fleet.rows(
        f"SELECT stage FROM decisions WHERE seq > {rejoined[0]} ORDER BY stage LIMIT 2")]
    assert next_two and any(s not in missing for s in next_two), (rejoined, next_two, sorted(missing))
    later = [s for s in range(max(cut_off) + 1, scenario.stages) if s not in missing]
    print(f"partition: stages ∅ for a {sorted(missing)}, observed again from stage {min(later, default=None)}")
    answered = {s for (s,) in fleet.rows("SELECT stage FROM confirmations WHERE carrier='a'")}
    assert later and max(answered) == scenario.stages - 1
    truth = world.observe_all(scenario)
    np.testing.assert_array_equal(x[ra, later], truth[ra, later])
    _check_at_most_once(fleet, scenario, summary)
    # The other carrier was not affected: all its observations are the world's.
    rb = scenario.carrier_index("b")
    np.testing.assert_array_equal(x[rb], truth[rb])
