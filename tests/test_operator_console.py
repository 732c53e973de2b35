"""The operator console as a person uses it: a real fleet mission (run_fleet.py, real processes,
Zenoh on loopback) with ``--operator``, its page in real headless Chromium, approve, veto and
force clicked with the mouse on given stages, the page closed before the last stage; the fleet's
decisions, summary.json, mission.db and mission.mcap follow. Screenshots go to tests/artifacts/."""
from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
import threading
import time
import urllib.request

import numpy as np
import pytest

import world
from fleet_helpers import ROOT, TINY, db_rows, offline
from wire.zconfig import free_port

view_screenshot = pytest.importorskip("tools.view_screenshot")
pytest.importorskip("websocket")

ARTIFACTS = ROOT / "tests" / "artifacts"
RUN_FLEET = str(ROOT / "run_fleet.py")


class Launcher:
    """run_fleet.py in the background, its output collected line by line."""

    def __init__(self, args, cwd):
        self.proc = subprocess.Popen([sys.executable, RUN_FLEET, *args], stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, text=True, cwd=cwd)
        self.lines: list[str] = []
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self):
        for line in self.proc.stdout:
            self.lines.append(line)

    def wait_for(self, text: str, timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        while not any(text in line for line in self.lines):
            assert self.proc.poll() is None, "".join(self.lines)[-3000:]
            assert time.monotonic() < deadline, f"no {text!r} in: " + "".join(self.lines)[-3000:]
            time.sleep(0.2)

    def finish(self, timeout_s: float) -> int:
        try:
            return self.proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
            raise AssertionError("the mission did not end: " + "".join(self.lines)[-3000:])


def holding(j: int) -> str:
    """The page holds stage j for the operator, its Approve button enabled."""
    return (f"(() => typeof STATE !== 'undefined' && STATE && STATE.hold && STATE.hold.stage === {j} && "
            f"STATE.hold.status === 'holding' && !document.getElementById('approve').disabled)()")


def post(port: int, body: dict) -> dict:
    req = urllib.request.Request(f"http://127.0.0.1:{port}/action", json.dumps(body).encode(),
                                 {"Content-Type": "application/json"})
    with urllib.request.urlopen(req, timeout=40) as r:
        return json.load(r)


@pytest.mark.slow
@pytest.mark.skipif(view_screenshot.chromium_path() is None, reason="chromium is not installed (apt-get install chromium)")
def test_an_operator_approves_vetoes_and_forces_in_a_browser(tmp_path):
    port, out = free_port(), tmp_path / "run"
    fleet = Launcher([str(TINY), "--operator", "--operator-timeout", "25", "--operator-port", str(port),
                      "--out", str(out), "--no-map"], cwd=tmp_path)
    shots = {}
    try:
        fleet.wait_for("operator console at", 120)
        with view_screenshot.Browser((1500, 900)) as page:
            page.open(f"http://127.0.0.1:{port}/")
            # Stage 0: the planner recommends a (x = 8); the operator vetoes it, then approves.
            page.wait_for(holding(0), 90)
            assert page.eval("STATE.hold.deploy") == [True, False]
            shots["recommendation"] = page.screenshot()
            page.click("#veto-a")
            page.wait_for("STATE.hold.vetoed.includes('a') && STATE.hold.deploy[0] === false", 20)
            time.sleep(0.5)
            shots["vetoed"] = page.screenshot()
            page.click("#approve")
            # Stage 1: the planner recommends b; the operator forces a as well, then approves.
            page.wait_for(holding(1), 90)
            assert page.eval("STATE.hold.deploy") == [False, True]
            page.click("#force-a")
            page.wait_for("STATE.hold.forced.includes('a')", 20)
            time.sleep(0.5)
            shots["forced"] = page.screenshot()
            page.click("#approve")
            # A second console's veto for stage 0, decided long ago: refused, with the reason.
            page.wait_for(holding(2), 90)
            late = post(port, {"stage": 0, "action": "veto", "carrier": "a"})
            assert late["accepted"] is False and late["reason"] == "stale-stage" and "already decided" in late["detail"]
            page.click("#approve")
            # Stage 3: the page is closed before anyone answers: the recommendation stands.
            page.wait_for(holding(3), 90)
            shots["last"] = page.screenshot()
            page.close_page()
        assert fleet.finish(240) == 0, "".join(fleet.lines)[-3000:]
    finally:
        if fleet.proc.poll() is None:
            fleet.proc.send_signal(signal.SIGINT)
            fleet.proc.wait(30)
        ARTIFACTS.mkdir(exist_ok=True)
        for name, png in shots.items():
            (ARTIFACTS / f"operator_{name}.png").write_bytes(png)

    summary = json.loads((out / "summary.json").read_text())
    assert summary["decisions"][0] == [] and "a" in summary["decisions"][1] and "b" in summary["decisions"][1]
    by = {(c["id"], d["stage"]): d["by"] for c in summary["carriers"] for d in c["deployments"]}
    assert by[("a", 1)] == "operator" and by[("b", 1)] == "coordinator"
    assert not any(stage == 0 for (_, stage) in by)  # the veto held: nobody deployed at stage 0
    op = summary["operator"]
    assert (op["approvals"], op["vetoes"], op["forces"], op["timeouts"]) == (3, 1, 1, 1)
    assert [o["stage"] for o in op["overrides"]] == [0, 1]
    assert all(isinstance(o["estimated_gain"], float) for o in op["overrides"])
    assert op["overrides"][0]["recommended"] == ["a"] and op["overrides"][0]["decided"] == []
    # On the record: mission.db's operator rows and the recording's /operator channel.
    rows = db_rows(out / "mission.db", "SELECT stage, carrier, payload FROM events WHERE kind = 'operator' ORDER BY seq")
    assert [(s, c, json.loads(p)["action"]) for s, c, p in rows] == [
        (0, "a", "veto"), (0, None, "approve"), (1, "a", "force"), (1, None, "approve"), (2, None, "approve")]
    from mcap.reader import make_reader

    with open(out / "mission.mcap", "rb") as f:
        records = [json.loads(m.data) for _, ch, m in make_reader(f).iter_messages(topics=["/operator"])]
    assert [r["kind"] for r in records].count("action") == 5 and [r["kind"] for r in records].count("decision") == 4

    # The screenshots show the map: each carrier's colour is drawn in the map's area.
    from world.scene import carrier_colour, rgb

    colours = [rgb(carrier_colour(r)) for r in range(2)]
    counts = view_screenshot.colour_pixels(shots["forced"], colours, box=(0, 90, 800, 900))
    assert min(counts) >= 100, f"carrier colour pixels on the map: {counts} (see {ARTIFACTS})"


@pytest.mark.slow
def test_an_autonomous_console_only_watches(tmp_path):
    """``--operator-timeout 0``: the page is served, nobody waits for it, and the fleet decides
    exactly what the planner decides offline."""
    port, out = free_port(), tmp_path / "run"
    fleet = Launcher([str(TINY), "--operator", "--operator-timeout", "0", "--operator-port", str(port),
                      "--out", str(out), "--no-map", "--no-record"], cwd=tmp_path)
    fleet.wait_for("operator console at", 120)
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/map.json", timeout=10) as r:
        assert [c["id"] for c in json.load(r)["carriers"]] == ["a", "b"]
    assert fleet.finish(240) == 0, "".join(fleet.lines)[-3000:]
    summary = json.loads((out / "summary.json").read_text())
    expected, _ = offline(world.load_scenario(TINY))
    decided = np.zeros_like(expected.deployed)
    for j, deploy in enumerate(summary["decisions"]):
        for cid in deploy:
            decided[["a", "b"].index(cid), j] = True
    assert decided.tolist() == expected.deployed.tolist()
    op = summary["operator"]
    assert op["watched"] == 4 and op["approvals"] == op["timeouts"] == op["vetoes"] == op["forces"] == 0
