"""The link model on a real fleet (wire/link_filter.py): a short marine mission over real Zenoh
sessions on acoustic links completes, every process's receive filter draws the fates of what it
receives, and the Observations on the wire fit the frame. Slow: a mission over a 1,200 bit/s
channel takes tens of seconds."""
from __future__ import annotations

import json
import threading
from pathlib import Path

import pytest
import yaml

from fleet_helpers import InProcessFleet, db_rows
from wire import link_filter as lf
from wire import messages as wm
from world.scenario import parse_scenario

ROOT = Path(__file__).resolve().parents[1]
MARINE = ROOT / "scenarios" / "marine_survey.yaml"

pytestmark = pytest.mark.slow


def test_a_marine_mission_flies_over_acoustic_links(tmp_path, monkeypatch):
    data = yaml.safe_load(MARINE.read_text())
    data["stages"] = 4
    scenario = parse_scenario(data, str(MARINE))
    fates: list = []
    lock = threading.Lock()
    real = lf.LinkFilter.delay

    def counted(self, key, payload):
        out = real(self, key, payload)
        with lock:
            fates.append((self.receiver, key.rsplit("/", 1)[-1], out))
        return out

    monkeypatch.setattr(lf.LinkFilter, "delay", counted)
    fleet = InProcessFleet(scenario, tmp_path, stage_timeout_s=30.0)
    fleet.start_coordinator()
    for cid in scenario.carrier_ids:
        fleet.start_carrier(cid)
    fleet.join(timeout_s=240.0)
    receivers = {r for r, _, _ in fates}
    assert receivers == {"coordinator", *scenario.carrier_ids}
    # acoustic messages take seconds: airtime at 1,200 bit/s plus sound over hundreds of metres
    delays = [d for r, k, d in fates if d is not None and k == "obs"]
    assert delays and min(delays) > 0.5
    decided = db_rows(tmp_path / "mission.db", "SELECT stage FROM decisions")
    assert sorted(r[0] for r in decided) == list(range(4))
    frame = scenario.links.frame_bytes
    rows = db_rows(tmp_path / "mission.db", "SELECT carrier, stage, payload FROM events WHERE kind = 'observation'")
    assert rows
    for cid, stage, payload in rows:  # each Observation as it crossed the links fits the frame
        p = json.loads(payload)
        obs = wm.Observation("marine_survey", cid, stage, p["t"], p.get("x"), tuple(p["position"]), p["passengers_left"],
                             tuple(map(tuple, p["trail"])))
        assert len(wm.encode(obs)) <= frame
