"""--role report: a mission's results from whatever logs exist (mission.db and the carriers' logs).

Pure merge tests use the mission of tests/test_mission.py: carriers a (2 passengers, stages
0..2) and b (1 passenger, stages 1..2), 3 stages 5 s apart, fingerprint "fp". Process tests
write real files (storage/missiondb.py's MissionStore, storage/carrierlog.py's CarrierLog) and run
run_fleet.py as a real process; the slow one runs tiny.yaml on one host.
"""
from __future__ import annotations

import json
import shutil
import subprocess
import sys

import numpy as np
import pytest
from scipy import stats

from storage.carrierlog import CarrierLog, LogEntry, log_path
from mission import events as ev
from mission import state as ms
from mission.report import CarrierRecord, merge
from mission.summary import RunInfo, summary
from planner.problem import Problem, evaluate

from fleet_helpers import ROOT, TINY, db_rows

RUN_FLEET = str(ROOT / "run_fleet.py")
SPEC = ms.MissionSpec.build(("a", "b"), [[True, True, True], [False, True, True]], (2, 1), (0.0, 5.0, 10.0), "fp")
PROBLEM = Problem.build(np.array(SPEC.passengers), np.array(SPEC.valid), [[(0, 1), (1, 1)]], stats.poisson(3.0))
RUN = RunInfo("m", "m.yaml", "m", "ssap", {}, 7, 1, "h", 1.0, {})
P = (1.0, 2.0)


def hello(cid):
    return ev.Hello(cid, 100, "host", 2, 0, "fp", 1.0)


def obs(cid, j, x):
    return ev.Observation(cid, j, SPEC.stage_times[j], x, P, 2, (), 2.0)


def decide(j, deploy=()):
    return ev.Decided(j, tuple(deploy), 1.5, 3.0)


def confirm(cid, j, deployed, status="deployed"):
    return ev.Confirmed(cid, j, deployed, status if deployed or status != "deployed" else "idle", P, 1, 4.0)


READY = [ev.Opened(0.0), ev.LivelinessChanged("a", True, 1.0), ev.LivelinessChanged("b", True, 1.0),
         hello("a"), hello("b")]


def entry(j, x, status, deployed, left=1, observed=True):
    return LogEntry(j, SPEC.stage_times[j], x, observed, P, status, deployed, left)


def log(cid, *entries):
    return CarrierRecord(cid, f"carriers/{cid}.db", {"carrier": cid, "mission": "m", "fingerprint": "fp"}, entries)


def counted(merged):
    return {(SPEC.carriers[r], int(j)) for r, j in np.argwhere(merged.state.confirmed_deployments())}


# --------------------------------------------------------------------------- the pure merge

def test_own_deployments_without_a_coordinator_are_the_results():
    merged = merge(SPEC, (), [log("b", entry(1, 4, "own", True, 0), entry(2, 1, "own", False, 0)),
                              log("a", entry(0, 5, "own", True, 1), entry(1, 2, "own", False, 1),
                                  entry(2, 7, "own", True, 0))], db_source=None)
    assert counted(merged) == {("a", 0), ("a", 2), ("b", 1)}
    assert set(merged.state.accepted) == {"a", "b"} and not merged.conflicts
    assert merged.state.observations().tolist()[0] == [5.0, 2.0, 7.0]
    assert all(merged.decided_by(c, j) == "carrier" for c, j in counted(merged))
    data = summary(merged.state, PROBLEM, RUN)
    assert data["total_reward"] == pytest.approx(evaluate(PROBLEM, merged.state.confirmed_deployments(),
                                                          merged.state.observations())[0])
    assert data["carriers"][0]["own_stages"] == [0, 1, 2] and data["stages_decided"] == 0


def test_a_confirm_only_the_carrier_log_holds_is_added_without_a_latency():
    events = READY + [obs("a", 0, 5), decide(0, ["a"]), ev.Published(0, 3.5)]  # the coordinator died here
    merged = merge(SPEC, events, [log("a", entry(0, 5, "deployed", True, 1))])
    assert counted(merged) == {("a", 0)} and merged.added == {("a", 0)}
    assert merged.state.confirms[("a", 0)].latency_ms is None  # the carrier's clock is not the coordinator's
    assert merged.decided_by("a", 0) == "coordinator" and merged.counted_from("a", 0) == "carriers/a.db"
    assert not merged.adds_nothing


def test_what_mission_db_holds_already_is_absorbed():
    events = READY + [obs("a", 0, 5), decide(0, ["a"]), ev.Published(0, 3.5), confirm("a", 0, True),
                      obs("a", 1, 2), obs("b", 1, 4), decide(1, ["b"]), confirm("a", 1, False, "idle"),
                      confirm("b", 1, True)]
    merged = merge(SPEC, events, [log("a", entry(0, 5, "deployed", True, 1), entry(1, 2, "idle", False, 1)),
                                  log("b", entry(1, 4, "deployed", True, 0))])
    assert merged.adds_nothing and not merged.conflicts
    assert summary(merged.state, PROBLEM, RUN) == summary(ms.fold(SPEC, events), PROBLEM, RUN)
    assert merged.counted_from("a", 0) == "mission.db"
    assert [r["sources"] for r in merged.rows() if r["carrier"] == "a" and r["stage"] == 0] == \
        [["mission.db", "carriers/a.db"]]


def test_a_stage_decided_by_both_that_agree_counts_once():
    # The coordinator decided stage 1 without a's observation; a, cut off, decided it itself.
    events = READY + [obs("a", 0, 5), decide(0), obs("b", 1, 4), decide(1, ["b"]), confirm("b", 1, True)]
    merged = merge(SPEC, events, [log("a", entry(1, 6, "own", True, 1))])
    assert counted(merged) == {("a", 1), ("b", 1)} and not merged.conflicts
    assert merged.decided_by("a", 1) == "carrier" and merged.state.observation(0, 1) == 6.0
    # Its Confirm of the same stage on record too: they agree, still one deployment.
    events2 = events + [confirm("a", 1, True, "already")]
    merged2 = merge(SPEC, events2, [log("a", entry(1, 6, "own", True, 1))])
    assert counted(merged2) == {("a", 1), ("b", 1)} and not merged2.conflicts


@pytest.mark.parametrize("status", ["own", "late"])
def test_a_log_that_contradicts_mission_db_is_a_conflict_and_the_first_record_stands(status):
    events = READY + [obs("a", 0, 5), decide(0, ["a"]), confirm("a", 0, True)]
    merged = merge(SPEC, events, [log("a", entry(0, 5, status, False, 2))])
    assert counted(merged) == {("a", 0)}
    assert [c.reason for c in merged.conflicts] == ["duplicate"]
    assert merged.conflicts[0].line().startswith("carriers/a.db: stage 0: ")
    [row] = [r for r in merged.rows() if r["carrier"] == "a" and r["stage"] == 0]
    assert row["conflict"] and row["status"] == "deployed" and row["deployed"] and row["decided_by"] == "coordinator"


def test_no_passenger_is_released_twice():
    # a carries 2: mission.db has both; its log repeats one and claims a third.
    events = READY + [obs("a", 0, 5), decide(0, ["a"]), confirm("a", 0, True), obs("a", 1, 3), obs("b", 1, 1),
                      decide(1, ["a"]), confirm("a", 1, True)]
    merged = merge(SPEC, events, [log("a", entry(0, 5, "deployed", True, 1), entry(2, 9, "own", True, 0)),
                                  log("b", entry(1, 1, "own", True, 0), entry(2, 8, "own", True, 0))])
    assert counted(merged) == {("a", 0), ("a", 1), ("b", 1)}
    assert sorted((c.carrier, c.stage, c.reason) for c in merged.conflicts) == [("a", 2, "passengers"),
                                                                                 ("b", 2, "passengers")]
    per_carrier = merged.state.confirmed_deployments().sum(axis=1)
    assert (per_carrier <= np.array(SPEC.passengers)).all()
    rows = [(r["carrier"], r["stage"]) for r in merged.rows() if r["deployed"]]
    assert len(rows) == len(set(rows)) == 3


def test_a_stage_decided_by_a_coordinator_whose_db_is_gone_is_the_carriers_account():
    merged = merge(SPEC, (), [log("a", entry(0, 5, "deployed", True, 1), entry(1, 3, "idle", False, 1),
                                  entry(2, None, None, False, observed=True))], db_source=None)
    assert counted(merged) == {("a", 0)} and merged.decided_by("a", 0) == "coordinator"
    assert merged.decided_by("a", 2) is None  # sensed (∅), never decided: shown, changes nothing
    assert ("a", 2) not in merged.state.accounts
    from mission.report import annotate

    data = annotate(summary(merged.state, PROBLEM, RUN), merged)
    assert data["carriers"][0]["deployments"][0]["by"] == "coordinator"
    assert data["carriers"][0]["deployments"][0]["source"] == "carriers/a.db"
    assert data["carriers"][0]["log"] == "carriers/a.db" and data["carriers"][1]["log"] is None


# --------------------------------------------------------------------------- files and the command line

def _report(scenario, out, *extra):
    return subprocess.run([sys.executable, RUN_FLEET, str(scenario), "--role", "report", "--out", str(out), *extra],
                          capture_output=True, text=True, timeout=120, cwd=ROOT)


def _one_line_error(proc, *words):
    assert proc.returncode == 2, (proc.stdout, proc.stderr)
    assert "Traceback" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    for word in words:
        assert word in lines[0], lines[0]


def _tiny_identity(seed=None):
    import world
    from wire.messages import scenario_fingerprint

    scenario = world.load_scenario(TINY)
    scenario = scenario if seed is None else scenario.with_seed(seed)
    return {"mission": "tiny", "scenario": "tiny", "fingerprint": scenario_fingerprint(scenario),
            "seed": scenario.seed}


def _write_log(out, cid, meta, rows):
    """A carrier log as storage/carrierlog.py writes it: (stage, t, x, position, status, deployed, left)."""
    clog = CarrierLog(log_path(out, cid), dict(meta, carrier=cid))
    for stage, t, x, position, status, deployed, left in rows:
        clog.observed(stage, t, x, position)
        if status is not None:
            clog.outcome(stage, t, status, deployed, position, left, 1.0)
    clog.close()


def test_report_from_carrier_logs_alone_and_a_foreign_log_is_skipped(tmp_path):
    out = tmp_path / "run"
    meta = {k: v for k, v in _tiny_identity().items() if k != "scenario"}
    _write_log(out, "a", meta, [(0, 0.0, 6, (4.0, 20.0), "own", True, 1), (1, 5.0, 2, (14.0, 20.0), "own", False, 1)])
    _write_log(out, "b", dict(meta, seed=99), [(1, 5.0, 3, (20.0, 4.0), "own", True, 0)])
    proc = _report(TINY, out, "--no-map")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("report: total reward ") and len(proc.stdout.strip().splitlines()) == 1
    assert "carriers/b.db: skipped, another mission's log (seed is 99" in proc.stderr
    data = json.loads((out / "summary.json").read_text())
    assert data["planner"] == "dec-closed-loop" and data["stages_decided"] == 0
    assert [d["stage"] for d in data["carriers"][0]["deployments"]] == [0]
    assert data["carriers"][0]["deployments"][0]["by"] == "carrier" and data["carriers"][1]["deployments"] == []
    assert data["report"]["inputs"] == ["carriers/a.db"] and len(data["report"]["skipped"]) == 1
    rows = [json.loads(line) for line in (out / "merged_log.jsonl").read_text().splitlines()]
    assert [(r["stage"], r["carrier"], r["decided_by"]) for r in rows][:2] == [(0, "a", "carrier"), (1, "a", "carrier")]
    assert not (out / "summary.coordinator.json").exists()


def test_cli_errors_are_one_line_and_exit_2(tmp_path):
    _one_line_error(_report(TINY, tmp_path / "nowhere"), "no such results directory")
    (tmp_path / "empty").mkdir()
    _one_line_error(_report(TINY, tmp_path / "empty"), "nothing to report")
    proc = subprocess.run([sys.executable, RUN_FLEET, str(TINY), "--role", "report"], capture_output=True, text=True,
                          timeout=60, cwd=ROOT)
    _one_line_error(proc, "--out")
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "mission.db").write_bytes(b"not a database at all" * 100)
    _one_line_error(_report(TINY, bad), "mission.db", "cannot read")
    badlog = tmp_path / "badlog"
    (badlog / "carriers").mkdir(parents=True)
    (badlog / "carriers" / "a.db").write_bytes(b"\0garbage" * 100)
    _one_line_error(_report(TINY, badlog), "a.db", "cannot read")


def test_a_mission_db_of_another_mission_is_refused(tmp_path):
    from storage.missiondb import MissionStore

    out = tmp_path / "run"
    MissionStore(out / "mission.db", dict(_tiny_identity(seed=3), planner="ssap")).close()
    _one_line_error(_report(TINY, out), "mission.db", "another mission", "seed is 3", "--seed")
    assert not (out / "summary.json").exists()
    assert _report(TINY, out, "--seed", "3", "--no-map").returncode == 0  # the right seed: its (empty) results


# --------------------------------------------------------------------------- a real mission

def _logs_from_mission_db(db, out):
    """The carrier logs a fleet writes, rebuilt from what mission.db saw the carriers do
    (carriers/node.py writes them in the main line of work; until then, CarrierLog directly)."""
    meta = {k: v for k, v in _tiny_identity().items() if k != "scenario"}
    seen = {(c, s): (x, (px, py)) for c, s, x, px, py in db_rows(
        db, "SELECT carrier, stage, x, pos_x, pos_y FROM observations WHERE missing=0")}
    times = {0: 0.0, 1: 5.0, 2: 10.0, 3: 15.0}
    rows = {}
    for c, s, deployed, status, px, py in db_rows(
            db, "SELECT carrier, stage, deployed, status, pos_x, pos_y FROM confirmations ORDER BY stage"):
        x = seen.get((c, s), (None, None))[0]
        rows.setdefault(c, []).append((s, times[s], x, (px, py), status, bool(deployed), 0))
    for c, rs in rows.items():
        _write_log(out, c, meta, rs)


def _truncate_mission_db(src, dst, stages):
    """A mission.db as a coordinator killed after deciding ``stages`` stages leaves it."""
    import world
    from world import build_problem
    from storage.missiondb import MissionStore, load_events, load_meta

    scenario = world.load_scenario(TINY)
    problem = build_problem(scenario)
    spec = ms.MissionSpec.build(scenario.carrier_ids, problem.valid, problem.passengers, scenario.stage_times(),
                                _tiny_identity()["fingerprint"])
    meta = {k: v for k, v in load_meta(src).items() if k != "schema"}
    store = MissionStore(dst, meta)
    state = ms.fold(spec, store.mission_events())
    for event in load_events(src)[1:]:
        if isinstance(event, ev.Decided) and event.stage >= stages:
            break
        state, effects = ms.step(state, event)
        for effect in effects:
            if isinstance(effect, ms.Record):
                store.record(effect, state)
    store.close()


@pytest.mark.slow
def test_report_of_a_real_one_host_run_equals_the_coordinators_summary(tmp_path):
    out = tmp_path / "run"
    proc = subprocess.run([sys.executable, RUN_FLEET, str(TINY), "--out", str(out), "--no-record"],
                          capture_output=True, text=True, timeout=180, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "report: total reward" in proc.stdout and "Traceback" not in proc.stderr
    coordinator = json.loads((out / "summary.coordinator.json").read_text())
    report = json.loads((out / "summary.json").read_text())
    assert "report" not in coordinator and report["report"]["adds_to_mission_db"] == []

    def deployments(s):
        return [[(d["stage"], d["x"], d["position"], d["reward"]) for d in c["deployments"]] for c in s["carriers"]]

    def agree(s, ref=coordinator, decisions=True):
        assert deployments(s) == deployments(ref)
        assert s["total_reward"] == pytest.approx(ref["total_reward"])
        if decisions:
            assert s["decisions"] == ref["decisions"]

    agree(report)

    def without_annotations(s):
        s = {k: v for k, v in s.items() if k != "report"}
        s["carriers"] = [dict({k: v for k, v in c.items() if k != "log"},
                              deployments=[{k: v for k, v in d.items() if k != "source"} for d in c["deployments"]])
                         for c in s["carriers"]]
        return s

    assert without_annotations(report) == coordinator  # every field the coordinator wrote
    assert (out / "map.png").stat().st_size > 10_000 and (out / "merged_log.jsonl").exists()

    # The carriers' logs of the same mission add nothing: every entry is absorbed.
    _logs_from_mission_db(out / "mission.db", out)
    proc = _report(TINY, out, "--no-map")
    assert proc.returncode == 0, proc.stderr
    again = json.loads((out / "summary.json").read_text())
    assert again["report"]["adds_to_mission_db"] == [] and again["report"]["conflicts"] == []
    agree(again)
    assert json.loads((out / "summary.coordinator.json").read_text()) == coordinator  # kept once, untouched

    # The coordinator killed after stage 2: its mission.db and the logs give the same results.
    cut = tmp_path / "cut"
    shutil.copytree(out / "carriers", cut / "carriers")
    _truncate_mission_db(out / "mission.db", cut / "mission.db", stages=2)
    proc = _report(TINY, cut, "--no-map")
    assert proc.returncode == 0, proc.stderr
    merged = json.loads((cut / "summary.json").read_text())
    assert merged["stages_decided"] == 2 and merged["report"]["adds_to_mission_db"]
    agree(merged, decisions=False)

    # No mission.db at all (a coordinator on another host, lost): the logs alone.
    (cut / "mission.db").unlink()
    proc = _report(TINY, cut, "--no-map")
    assert proc.returncode == 0, proc.stderr
    alone = json.loads((cut / "summary.json").read_text())
    assert alone["stages_decided"] == 0
    agree(alone, decisions=False)
    assert {d["by"] for c in alone["carriers"] for d in c["deployments"]} == {"coordinator"}


@pytest.mark.slow
def test_one_host_mode_reports_a_mission_whose_coordinator_was_killed(tmp_path):
    import os
    import re
    import signal

    out = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, RUN_FLEET, str(TINY), "--out", str(out), "--realtime", "2", "--no-map",
                             "--no-record", "--coordinator-timeout", "3"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        lines, pid = [], None
        while not any("stage   1 of " in line for line in lines):
            line = proc.stdout.readline()
            assert line, "".join(lines)
            lines.append(line)
            m = re.search(r"coordinator pid (\d+)", line)
            pid = int(m.group(1)) if m else pid
        os.kill(pid, signal.SIGKILL)  # no summary.json of its own
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode != 0 and "Traceback" not in stderr
    assert "report: total reward" in stdout, stderr[-2000:]
    data = json.loads((out / "summary.json").read_text())
    assert "report" in data and not data["ended"] and 2 <= data["stages_decided"] < 4
    assert not (out / "summary.coordinator.json").exists()
    for carrier, passengers in zip(data["carriers"], (2, 1)):
        stages = [d["stage"] for d in carrier["deployments"]]
        assert len(stages) == len(set(stages)) <= passengers
    assert (out / "merged_log.jsonl").read_text().count("\n") >= 2
