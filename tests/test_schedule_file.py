"""Fault schedule files (mission/simulate/schedule.py): what ``python -m mission.simulate
--schedule`` and ``run_fleet.py --schedule`` read, the mission points the simulator reports, a
bad file as one line naming the file, the fault and the field; and the message faults' receive
filter of a real fleet (wire/fault_windows.py)."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from mission import simulate as sim
from mission.simulate import schedule
from wire import keys
from wire.fault_windows import ENV, FaultWindows, JumpedClock, fault_clock

from fleet_helpers import ROOT

GOOD = {"kind": "crash", "at": 0.5, "until": 1.0, "who": "a", "size": 0.0, "decided": 2, "decided_until": 3}


def test_a_reported_schedule_reads_back_as_its_faults():
    faults = schedule.parse([GOOD, {"kind": "loss", "at": 0, "until": 4, "size": 0.25}], "f.json", ("a", "b"))
    assert faults == (sim.Fault("crash", 0.5, 1.0, "a", 0.0), sim.Fault("loss", 0.0, 4.0, "", 0.25))
    assert schedule.points([GOOD]) == [{"decided": 2, "decided_until": 3, "joined": None, "started": None}]
    assert schedule.points([{**GOOD, "joined": ["a"]}])[0]["joined"] == ["a"]


@pytest.mark.parametrize("data, says", [
    ({"kind": "crash"}, "f.json: expected a JSON list of faults, found dict"),
    ([GOOD, 3], "f.json: fault 1: expected an object"),
    ([{**GOOD, "kind": "meteor"}], "f.json: fault 0: field 'kind': expected one of"),
    ([{k: v for k, v in GOOD.items() if k != "at"}], "f.json: fault 0: field 'at': missing"),
    ([GOOD, {**GOOD, "until": "soon"}], "f.json: fault 1: field 'until': expected a finite number"),
    ([{**GOOD, "until": 0.1}], "f.json: fault 0: field 'until': expected a time >= at"),
    ([{**GOOD, "who": "z"}], "f.json: fault 0: field 'who': expected a carrier id"),
    ([{**GOOD, "decided": -1}], "f.json: fault 0: field 'decided': expected an integer >= 0"),
    ([{**GOOD, "when": 3}], "f.json: fault 0: field 'when': unknown"),
    ([{**GOOD, "joined": ["a", "z"]}], "f.json: fault 0: field 'joined': expected a list of the scenario's carrier ids"),
    ([{**GOOD, "joined": 2}], "f.json: fault 0: field 'joined': expected a list"),
])
def test_a_bad_schedule_names_the_fault_and_the_field(data, says):
    with pytest.raises(schedule.ScheduleError) as err:
        schedule.parse(data, "f.json", ("a", "b"))
    assert str(err.value).startswith(says) and "\n" not in str(err.value)


def test_the_mission_points_count_the_stages_decided_before():
    faults = (sim.Fault("crash", 0.5, 2.5, "a"), sim.Fault("freeze", 0.0, 0.1, "b"))
    rows = schedule.with_points(faults, {0: 0.2, 1: 0.6, 2: 2.0, 3: 3.0}, {"b": 0.05, "a": 0.3}, {"a": 0.01, "b": 0.02})
    assert [(r["decided"], r["decided_until"], r["joined"], r["started"]) for r in rows] == [(1, 3, ["a", "b"], ["a", "b"]), (0, 0, [], [])]
    assert rows[0]["kind"] == "crash" and schedule.parse(rows, "r", ("a", "b")) == faults


def _run_fleet(*args):
    return subprocess.run([sys.executable, str(ROOT / "run_fleet.py"), str(ROOT / "scenarios" / "tiny.yaml"), *args],
                          cwd=ROOT, capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize("content, says", [
    ("not json", "not JSON"),
    (json.dumps([{**GOOD, "who": "a"}, {"kind": "crash", "until": 2}]), "fault 1: field 'at': missing"),
    (json.dumps([{**GOOD, "kind": "corrupt"}]), "fault 0: field 'kind': expected a kind the real fleet flies"),
])
def test_run_fleet_refuses_a_bad_schedule_in_one_line(tmp_path, content, says):
    path = tmp_path / "F.json"
    path.write_text(content)
    proc = _run_fleet("--schedule", str(path), "--out", str(tmp_path / "out"))
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "--schedule" in lines[0] and str(path) in lines[0] and says in lines[0], proc.stderr
    assert "Traceback" not in proc.stderr and not (tmp_path / "out").exists()


def test_a_schedule_needs_the_one_host_fleet(tmp_path):
    path = tmp_path / "F.json"
    path.write_text(json.dumps([GOOD]))
    proc = _run_fleet("--schedule", str(path), "--role", "coordinator")
    assert proc.returncode == 2 and "--schedule" in proc.stderr and "--role coordinator" in proc.stderr, proc.stderr


def test_the_receive_filter_drops_what_the_windows_in_force_lose(tmp_path):
    path = tmp_path / "windows.json"
    ids = ("a", "b")
    obs = keys.carrier_key("m", "a", "obs")
    f = FaultWindows(str(path), "m", "b", ids, 7)
    assert f.delay(obs, b"") == 0.0  # no file yet: nothing dropped
    path.write_text(json.dumps({"loss": [], "cut": ["a"]}))
    assert f.delay(obs, b"") is None  # a cut off: nobody hears it
    assert f.delay(keys.carrier_key("m", "b", "obs"), b"") == 0.0  # its own echo passes
    path.write_text(json.dumps({"loss": [0.5], "cut": []}))
    os.utime(path, ns=(1, 1))  # a new stamp even within the file system's time resolution
    kept = sum(f.delay(obs, b"") is not None for _ in range(2000))
    assert 850 < kept < 1150  # about half, drawn from the receiver's own seeded Generator
    first, second = (FaultWindows(str(path), "m", "b", ids, 7) for _ in range(2))
    assert [first.delay(obs, b"") for _ in range(64)] == [second.delay(obs, b"") for _ in range(64)]  # seeded


def test_a_clock_jump_moves_one_hosts_clock_forward_for_good(tmp_path, monkeypatch):
    """clock-jump on a real fleet: the clock a carrier's lifecycle reads is the base clock plus
    its host's jumps in the windows' file (the simulator's Clock.jumped), read at most every
    ``every_s``; another host's clock does not move, and without the launcher's file the base
    clock is the process's clock itself."""
    import time

    path = tmp_path / "windows.json"
    now = [100.0]
    a = JumpedClock(str(path), "a", base=lambda: now[0], every_s=0.5)
    b = JumpedClock(str(path), "b", base=lambda: now[0], every_s=0.5)
    assert a() == 100.0  # no file yet
    path.write_text(json.dumps({"loss": [], "cut": [], "jumps": {"a": 42.5}}))
    assert a() == 100.0  # read again only after every_s
    now[0] = 100.5
    assert a() == 143.0 and b() == 100.5
    path.write_text(json.dumps({"jumps": {"a": 50.0}}))
    os.utime(path, ns=(1, 1))
    now[0] = 101.0
    assert a() == 151.0  # the total so far
    monkeypatch.delenv(ENV, raising=False)
    assert fault_clock("a") is time.monotonic
    monkeypatch.setenv(ENV, str(path))
    clock = fault_clock("a")
    assert isinstance(clock, JumpedClock) and clock() >= time.monotonic() + 50.0 - 1.0


def test_marsupial_fleet_run_takes_the_same_schedule_flag(tmp_path):
    path = tmp_path / "F.json"
    path.write_text(json.dumps([GOOD, {**GOOD, "who": "nobody"}]))
    proc = subprocess.run([sys.executable, "-c", "import sys; from launcher.cli import main; sys.exit(main())", "run",
                           str(ROOT / "scenarios" / "tiny.yaml"), "--schedule", str(path)],
                          cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and f"{path}: fault 1: field 'who'" in lines[0], proc.stderr
