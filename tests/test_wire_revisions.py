"""The wire as a contract: every published revision of docs/protocol.md is kept under
tests/fixtures/wire/r<N>/ (the page as published, and messages written from it), and today's
code must still speak each one to a peer of that revision (docs/protocol.md, "Compatibility").

* What a carrier of revision N sends, today's coordinator accepts, and re-encoded for revision N
  it is the same map (nothing lost, nothing added).
* What a carrier of revision N accepts, today's encoder produces for that revision from the same
  content, whatever later-revision fields the content has (``passengers``...), and never a field
  that revision's page does not list.
* A carrier of revision 1 — tests/revision1_carrier.py, written from the revision 1 page with
  plain zenoh and msgpack — flies six_carriers next to today's carriers; the mission's decisions
  and deployments are the offline planner's, which today's carriers reproduce on their own
  (tests/test_fleet_scale.py), and nobody rejects anything.
"""
from __future__ import annotations

import dataclasses
import json
import re
import subprocess
import sys
from pathlib import Path

import msgpack
import numpy as np
import pytest

import world
from fleet_helpers import ROOT, InProcessFleet, deployed_matrix, offline, sensed_world_file
from wire import messages as wm

FIXTURES = ROOT / "tests" / "fixtures" / "wire"
SIX = ROOT / "scenarios" / "six_carriers.yaml"
CLIENT = ROOT / "tests" / "revision1_carrier.py"


def revisions() -> list[int]:
    return sorted(int(p.name[1:]) for p in FIXTURES.glob("r*") if p.is_dir())


def fixture(revision: int) -> dict:
    return json.loads((FIXTURES / f"r{revision}" / "messages.json").read_text())


def page_fields(revision: int) -> dict[str, set[str]]:
    """Message type -> the fields its table lists, read from that revision's page (plus the
    envelope); ``carrier-state`` for State's nested CarrierState map."""
    page = (FIXTURES / f"r{revision}" / "protocol.md").read_text()
    out = {}
    for kind in wm.MESSAGE_TYPES:
        head = f'(`type: "{kind}"`'
        if head not in page:
            continue
        section = page.split(head)[1].split("\n### ")[0].split("\n## ")[0]
        out[kind] = set(re.findall(r"^\| `(\w+)` \|", section, re.M)) | {"v", "type", "mission"}
    state = page.split('(`type: "state"`')[1].split("\n## ")[0]
    if "CarrierState is a map" in state:  # revisions 1 and 2: one sentence
        sentence = state.split("CarrierState is a map")[1].split("\n\n")[0]
        out["carrier-state"] = set(re.findall(r"`(\w+)` \(", sentence))
    else:  # revision 3: a table of its own
        table = state.split("### CarrierState")[1].split("\n### ")[0]
        out["carrier-state"] = set(re.findall(r"^\| `(\w+)` \|", table, re.M))
    return out


def shape(body: dict, kind: str) -> set[str]:
    return set(body)


def test_every_published_revision_is_kept():
    """Fixtures for every revision before this code's, and this code's own page: a change that
    publishes revision N + 1 must first freeze revision N here."""
    kept = revisions()
    assert kept == list(range(1, wm.REVISION)), kept
    for r in kept:
        assert fixture(r)["revision"] == r
        assert page_fields(r)["decision"] >= {"stage", "t", "deploy", "planning_ms"}
    assert "passengers" not in page_fields(1)["decision"] and "passengers" in page_fields(2)["decision"]
    assert "accepted" not in page_fields(2) and "progress" in page_fields(3) and "accepted" in page_fields(3)
    assert page_fields(3)["carrier-state"] == {"passengers_left", "deployments", "live", "refused", "rejected"}
    assert "epoch" not in page_fields(3)["end"] and "clock" not in page_fields(3)["accepted"]
    assert "epoch" in page_fields(4)["end"] and "counts" not in page_fields(4)["obs"] | page_fields(4)["own"]
    assert "counts" in page_fields(5)["obs"] and all("coordinator" not in page_fields(5)[k]
                                                     for k in ("decision", "end", "accepted", "state"))


def test_region_counts_are_left_out_for_a_revision_4_peer_and_unknown_to_it():
    """Revision 5's Observation and Own ``counts`` (coverage missions): sent at 5, left out at 4,
    ``unknown-field`` to a revision 4 reader; their sum must be ``x``."""
    obs = wm.Observation("m", "a", 2, 40.0, 5, (1.0, 2.0), 3, (), counts=(2, 0, 3))
    assert msgpack.unpackb(wm.encode(obs))["counts"] == [2, 0, 3]
    assert "counts" not in msgpack.unpackb(wm.encode(obs, 4))
    assert wm.decode(wm.encode(obs)).counts == (2, 0, 3)
    with pytest.raises(wm.ProtocolError) as info:
        wm.decode(wm.encode(obs), revision=4)
    assert info.value.reason == "unknown-field"
    for bad in (dict(x=6), dict(x=None)):
        body = dict(msgpack.unpackb(wm.encode(obs)), **bad)
        with pytest.raises(wm.ProtocolError) as info:
            wm.decode(msgpack.packb(body))
        assert info.value.reason == "out-of-range" and "counts" in info.value.detail
    own = wm.Own("m", "a", 2, 40.0, 5, True, (1.0, 2.0), 2, counts=(5,))
    assert wm.decode(wm.encode(own)).counts == (5,) and "counts" not in msgpack.unpackb(wm.encode(own, 4))


@pytest.mark.parametrize("revision", revisions())
def test_fixtures_follow_their_page(revision):
    """The fixtures themselves: written from their page, field by field."""
    fields = page_fields(revision)
    doc = fixture(revision)
    for side in ("carrier_sends", "carrier_accepts"):
        for kind, samples in doc[side].items():
            for body in samples:
                assert body["type"] == kind and set(body) <= fields[kind], (revision, kind, set(body) - fields[kind])
                if kind == "state":
                    for entry in body["carriers"].values():
                        assert {"passengers_left", "deployments", "live"} <= set(entry) <= fields["carrier-state"]
                    if body["last_decision"] is not None:
                        assert set(body["last_decision"]) <= fields["decision"]


@pytest.mark.parametrize("revision", revisions())
def test_what_an_older_carrier_sends_is_accepted_as_it_is(revision):
    for kind, samples in fixture(revision)["carrier_sends"].items():
        for body in samples:
            data = msgpack.packb(body)
            message = wm.decode(data)  # today's receiver
            assert type(message).TYPE == kind
            assert msgpack.unpackb(wm.encode(message, revision)) == body  # nothing lost, nothing added


@pytest.mark.parametrize("revision", revisions())
def test_what_an_older_carrier_accepts_is_what_it_gets(revision):
    """From the same content, with every later field filled in, today's encoder for that
    revision gives exactly the fixture: the later fields are left out, never sent."""
    later = {"decision": {"passengers": None}, "state": {"revision": wm.REVISION}}
    fields = page_fields(revision)
    for kind, samples in fixture(revision)["carrier_accepts"].items():
        for body in samples:
            message = wm.decode(msgpack.packb(body), revision=revision)
            if kind == "decision" and not message.passengers and message.deploy:
                message = dataclasses.replace(message, passengers=tuple(range(len(message.deploy))))
            if kind == "end" and revision < 4:  # revision 4's End epoch: never sent to an earlier carrier
                message = dataclasses.replace(message, epoch=3)
            if kind == "accepted" and revision < 4:  # revision 4's mission clock: never sent to an earlier carrier
                message = dataclasses.replace(message, clock="wall", silence_timeout_s=7.5, realtime=2.0)
            if kind in ("decision", "end", "accepted", "state") and revision < 6:  # revision 6's ballots
                message = dataclasses.replace(message, coordinator="standby")
            if kind == "state":
                message = dataclasses.replace(message, revision=wm.REVISION)
                if message.last_decision is not None and message.last_decision.deploy:
                    message = dataclasses.replace(message, last_decision=dataclasses.replace(
                        message.last_decision, passengers=(1,) * len(message.last_decision.deploy)))
            sent = msgpack.unpackb(wm.encode(message, revision))
            assert set(sent) <= fields[kind], (kind, set(sent) - fields[kind])
            if revision >= 2 and kind in later:
                continue  # a revision 2 peer gets the passengers this content names
            assert sent == body, kind


def test_a_later_field_is_unknown_to_an_earlier_reader():
    """decode(..., revision=N) reads as a receiver of revision N: what revision 2 added is
    ``unknown-field`` at revision 1, and so is revision 3's Hello ``revision`` at revision 2."""
    d = wm.Decision("m", 0, 0.0, ("a",), 1.0, passengers=(0,))
    with pytest.raises(wm.ProtocolError) as info:
        wm.decode(wm.encode(d), revision=1)
    assert info.value.reason == "unknown-field"
    assert wm.decode(wm.encode(d, 1), revision=1).passengers == ()
    hello = wm.Hello("m", "a", 1, "h", 1, 0, "f", revision=wm.REVISION)
    assert "revision" in msgpack.unpackb(wm.encode(hello)) and "revision" not in msgpack.unpackb(wm.encode(hello, 2))
    with pytest.raises(wm.ProtocolError) as info:
        wm.decode(wm.encode(hello), revision=2)
    assert info.value.reason == "unknown-field"


def test_the_revision1_client_is_as_strict_as_its_page():
    """The client of the flight below rejects what revision 2 added: it would have rejected
    every deploying Decision of six_carriers before the coordinator spoke its revision."""
    sys.path.insert(0, str(CLIENT.parent))
    import revision1_carrier as client

    d = wm.Decision("six_carriers", 2, 40.0, ("c1",), 1.0, passengers=(0,))
    with pytest.raises(client.Rejected) as info:
        client.read(wm.encode(d, 2), "decision", "six_carriers")
    assert info.value.reason == "unknown-field"
    assert client.read(wm.encode(d, 1), "decision", "six_carriers")["deploy"] == ["c1"]
    for body in fixture(1)["carrier_accepts"]["state"]:
        client.read(msgpack.packb(body), "state", "six_carriers")


def test_a_revision1_carrier_flies_six_carriers_next_to_todays(tmp_path):
    """Three carriers of revision 1 (separate processes, the standalone client) and three of
    today's: the mission's decisions and deployments are the offline planner's, the revision 1
    carriers deploy where it says and reject nothing, the coordinator rejects nothing."""
    six = world.load_scenario(SIX)
    trace = world.simulate_mission(six)
    reference, x = offline(six)
    fleet = InProcessFleet(six, tmp_path / "run", join_timeout_s=30.0, stage_timeout_s=15.0)
    fleet.start_coordinator()
    old = ("c1", "c3", "c5")
    procs = {}
    for cid in old:
        r = six.carrier_index(cid)
        procs[cid] = subprocess.Popen(
            [sys.executable, str(CLIENT), "--endpoint", fleet.endpoint, "--mission", fleet.coordinator.setup.mission,
             "--carrier", cid, "--world", str(sensed_world_file(six, trace, r, tmp_path / f"{cid}.json")),
             "--result", str(tmp_path / f"{cid}-result.json"), "--decision-timeout", "20"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    for cid in six.carrier_ids:
        if cid not in old:
            fleet.start_carrier(cid)
    try:
        summary = fleet.join(120)
        for cid, proc in procs.items():
            _, err = proc.communicate(timeout=30)
            assert proc.returncode == 0, (cid, err[-2000:])
    finally:
        for proc in procs.values():
            if proc.poll() is None:
                proc.kill()
    np.testing.assert_array_equal(np.array(summary["observations"], dtype=float), x)
    np.testing.assert_array_equal(deployed_matrix(summary, six), reference.deployed)
    assert summary["rejected"]["coordinator"] == {}
    assert all(not counts for counts in summary["rejected"]["carriers"].values()), summary["rejected"]
    for cid in old:
        result = json.loads((tmp_path / f"{cid}-result.json").read_text())
        r = six.carrier_index(cid)
        assert result["reason"] == "end" and result["rejected"] == {}
        assert result["deployments"] == [int(j) for j in np.flatnonzero(reference.deployed[r])]
        decided = {int(j): sorted(d) for j, d in result["decisions"].items()}
        expected = {j: sorted(six.carrier_ids[b] for b in np.flatnonzero(reference.deployed[:, j]))
                    for j in range(six.stages)}
        assert decided == expected  # every stage's Decision, as the planner decided it


def test_the_coordinator_speaks_the_lowest_revision_it_accepted():
    """mission.state: what is broadcast is in the lowest revision among accepted Hellos (this
    code's own before any); each carrier is answered in its own."""
    from mission import events as ev
    from mission import state as ms

    spec = ms.MissionSpec.build(("a", "b"), [[True], [True]], (1, 1), (0.0,), "f")
    s = ms.initial(spec)
    assert s.common_revision(wm.REVISION) == wm.REVISION and s.revision_of("a", wm.REVISION) == 1
    s, _ = ms.step(s, ev.Hello("a", 1, "h", 1, 0, "f", 0.0, wm.REVISION))
    assert s.common_revision(wm.REVISION) == wm.REVISION and s.revision_of("a", wm.REVISION) == wm.REVISION
    s, _ = ms.step(s, ev.Hello("b", 2, "h", 1, 0, "f", 0.0))  # announced none: revision 1
    assert s.common_revision(wm.REVISION) == 1 and s.revision_of("b", wm.REVISION) == 1
    assert s.revision_of("a", 2) == 2  # never above the coordinator's own


@pytest.mark.parametrize("parameters, revision", [
    ({}, 1), ({"carrier": "c1"}, 1), ({"revision": "3"}, 3), ({"revision": "2"}, 2), ({"revision": "99"}, 3),
    ({"revision": "0"}, 1), ({"revision": "x"}, 1), ({"revision": "²"}, 1), ({"revision": "3\n"}, 1),
])
def test_the_state_query_announces_the_askers_revision(parameters, revision):
    from wire import keys

    assert keys.asked_revision(parameters, 3, 1) == revision
    assert keys.state_selector("m", "c1", 3) == "marsupial/m/coordinator/state?carrier=c1;revision=3"


@pytest.mark.parametrize("revision", revisions())
def test_a_trail_fitted_to_an_acoustic_frame_is_an_observation_of_every_revision(revision):
    """On acoustic links a carrier thins its trail to fit the frame (wire.sizes.fit_trail): no new
    field, no new encoding, so a coordinator of any published revision reads it as any other."""
    from wire.sizes import fit_trail

    full = wm.Observation("m", "c1", 3, 360.0, 4, (300.0, 100.0), 2, tuple((float(k), 0.5 * k) for k in range(300)))
    fitted = fit_trail(full, 180)
    body = msgpack.unpackb(wm.encode(fitted, revision))
    assert len(wm.encode(fitted, revision)) <= 180 and 0 < len(fitted.trail) < len(full.trail)
    assert set(body) <= page_fields(revision)["obs"] and set(body) == shape(msgpack.unpackb(wm.encode(full, revision)), "obs")
    assert wm.decode(wm.encode(fitted, revision)) == fitted
