"""The scenario's link model in the deterministic simulator (mission/simulate/links.py,
world/fleet_links.py): perfect links leave the network as it was; acoustic links delay by
distance / sound speed and airtime on one shared channel, lose by the model, deterministically
from the seed; radio messages take the best path through the relays dropped by then."""
from __future__ import annotations

import copy
import dataclasses
import math
from pathlib import Path
from types import SimpleNamespace

import pytest
import yaml

from launcher.simulate import build_fleet, main
from mission import simulate as sim
from mission.simulate.links import LinkLayer
from planner import links as ch
from wire.sizes import link_sizes
from world.fleet_links import FleetLinks
from world.scenario import load_scenario, parse_scenario

ROOT = Path(__file__).resolve().parents[1]
MARINE = ROOT / "scenarios" / "marine_survey.yaml"


@pytest.fixture(scope="module")
def marine():
    return build_fleet(str(MARINE))


def _noisy(tmp_path, noise: float = 112.0) -> str:
    data = yaml.safe_load(MARINE.read_text())
    data["links"]["noise_level_db"] = noise  # nominal range 770 m: most of the survey out of reach
    path = tmp_path / "noisy.yaml"
    path.write_text(yaml.safe_dump(data))
    return str(path)


def test_perfect_links_leave_the_network_and_its_draws_as_they_were(marine):
    scenario = load_scenario(MARINE)
    perfect = dataclasses.replace(scenario, links=ch.LinkSpec())
    bare = dataclasses.replace(marine, links=None, decisions={})
    with_perfect = dataclasses.replace(marine, links=FleetLinks(perfect, link_sizes(perfect)), decisions={})
    for seed in (0, 1):
        a, b = sim.simulate(bare, seed), sim.simulate(with_perfect, seed)
        assert a.trace_hash == b.trace_hash and a.events == b.events and b.links == {}


def test_acoustic_links_are_deterministic_slower_and_change_the_trace(marine):
    bare = dataclasses.replace(marine, links=None, decisions={})
    a, b = sim.simulate(marine, 3, kinds=()), sim.simulate(marine, 3, kinds=())
    assert a.trace_hash == b.trace_hash and a.links == b.links and a.links["sent"] > 0
    p = sim.simulate(bare, 3, kinds=())
    assert p.trace_hash != a.trace_hash and a.completed and a.violations == []
    # every stage's messages take seconds of airtime on one channel: the mission takes far longer
    assert a.seconds > 50 * p.seconds


def test_lossy_acoustic_links_lose_messages_and_the_fleet_still_completes(tmp_path):
    fleet = build_fleet(_noisy(tmp_path))
    outs = [sim.simulate(fleet, seed, kinds=()) for seed in (0, 1)]
    for out in outs:
        assert out.completed and out.violations == []  # the fidelity check is off once a message is lost
        assert out.links["lost"] > 0.3 * out.links["sent"]


class _Driver(SimpleNamespace):
    pass


def _layer(scenario, stages: dict, t: float = 0.0) -> LinkLayer:
    links = FleetLinks(scenario, link_sizes(scenario) if scenario.links.model == "acoustic" else {"obs": 100})
    carriers = {cid: _Driver(machine=SimpleNamespace(stage=stages.get(cid, 0)), alive=True) for cid in links.ids}
    fake = SimpleNamespace(fleet=SimpleNamespace(seed=scenario.seed), carriers=carriers, t=t)
    return LinkLayer(fake, links, seed=0)


def test_acoustic_delay_is_airtime_plus_distance_over_sound_speed_on_one_channel():
    s = load_scenario(MARINE)
    s = dataclasses.replace(s, links=dataclasses.replace(s.links, params=tuple(
        (k, 0.0 if k == "fade_db" else v) for k, v in s.links.params)))  # no fading: within range, always delivered
    layer = _layer(s, {"vessel1": 0, "vessel2": 0})
    links = layer.links
    size = links.size("obs")
    air = 8 * size / s.links.bitrate_bps
    d1 = math.dist(links.position("vessel1", 0), links.model.base)
    d2 = math.dist(links.position("vessel2", 0), links.model.base)
    first = sim.msg("obs", "vessel1", stage=0)
    assert layer.delay("vessel1", "coordinator", first) == pytest.approx(air + d1 / s.links.sound_speed_mps)
    # the same transmission heard by a second receiver: same start, its own distance
    assert layer.delay("vessel1", "standby", first) == pytest.approx(air + d1 / s.links.sound_speed_mps)
    # the peers' copy of it is the same publication on the wire: the same transmission
    d3 = math.dist(links.position("vessel1", 0), links.position("vessel3", 0))
    assert layer.delay("vessel1", "vessel3", sim.msg("peer-obs", "vessel1", stage=0)) == pytest.approx(
        air + d3 / s.links.sound_speed_mps)
    # another message sent at the same time waits for the channel: one talker at a time
    assert layer.delay("vessel2", "coordinator", sim.msg("obs", "vessel2", stage=0)) == pytest.approx(
        2 * air + d2 / s.links.sound_speed_mps)
    assert layer.sent == 4 and layer.lost == 0


def _corridor(count: int, fade: float = 4.0):
    tiny = yaml.safe_load((ROOT / "scenarios" / "tiny.yaml").read_text())
    data = copy.deepcopy(tiny)
    data.update(map={"bounds": [-10, -10, 400, 100], "walls": []}, features={"density": 0.0}, stages=3,
                stage_interval=75.0,
                carriers=[{"id": "a", "passengers": 1, "start_time": 0, "speed": 2.0, "waypoints": [[0, 0], [300, 0]]}],
                links={"model": "radio", "base": [0, 0], "fade_db": fade, "relays": {"count": count}})
    return parse_scenario(data, "corridor.yaml")


def test_radio_messages_take_the_relays_dropped_by_then():
    s = _corridor(3)
    links = FleetLinks(s, {"obs": 100})
    assert [r.position for r in links.relays] == [(100.0, 0.0), (200.0, 0.0)]  # the third not needed by 300 m
    # stage 2 (t = 150 s): the carrier is at 300 m, both relays dropped: three hops of 100 m
    hops = links.between("a", "coordinator", {"a": 2})
    assert [round(d) for d, _ in hops] == [100, 100, 100] and ch.margin_db(s.links, 100.0) >= 0
    # stage 1 (t = 75 s, 150 m out): only the first relay is down
    assert [round(d) for d, _ in links.between("a", "coordinator", {"a": 1})] == [50, 100]
    bare = FleetLinks(_corridor(0), {"obs": 100})
    assert [round(d) for d, _ in bare.between("a", "coordinator", {"a": 2})] == [300]
    m = sim.msg("obs", "a", stage=2)
    steady = _corridor(3, fade=0.0)  # no fading: a hop at margin >= 0 always arrives, below never
    assert _layer(steady, {"a": 2}).delay("a", "coordinator", m) is not None
    assert _layer(_corridor(0, fade=0.0), {"a": 2}).delay("a", "coordinator", m) is None  # 300 m: margin -4.3 dB
    fates = [_layer(s, {"a": 2}).delay("a", "coordinator", m) for _ in range(3)]
    assert len(set(fates)) == 1 and fates[0] == pytest.approx(3 * s.links.latency_s)  # same seed, same fate


def test_the_command_compares_with_perfect_links(tmp_path, capsys):
    out = tmp_path / "p.json"
    assert main([str(MARINE), "--seeds", "0:2", "--faults", "none", "--quiet", "--perfect-links", "--json",
                 str(out)]) == 0
    rows = yaml.safe_load(out.read_text())["per_seed"]
    assert all("links" not in row for row in rows)


def test_a_frame_too_small_is_refused_before_the_simulation(tmp_path, capsys):
    data = yaml.safe_load(MARINE.read_text())
    data["links"]["frame_bytes"] = 150
    path = tmp_path / "small.yaml"
    path.write_text(yaml.safe_dump(data))
    assert main([str(path), "--seeds", "0:1", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "links.frame_bytes: expected at least" in err and "hello message" in err


# --------------------------------------------------------------------------- the picture and the recording
def test_the_scene_and_the_recording_carry_the_base_and_the_relays():
    from foxglove.messages import SceneUpdate

    from recording.mcap import world_entities
    from world.scene import build_scene

    s = _corridor(3)
    scene = build_scene(s)
    assert scene.links == "radio" and scene.base == (0.0, 0.0)
    assert [r.position for r in scene.relays] == [(100.0, 0.0), (200.0, 0.0)]
    data = SceneUpdate(entities=world_entities(scene, 0.0)).encode()
    assert b"links/base" in data and b"links/relay/a/0" in data and b"links/relay/a/1" in data
    assert b"dropped_at_s" in data and b"100.000" in data  # the second relay's planned drop time
    assert build_scene(load_scenario(ROOT / "scenarios" / "tiny.yaml")).base is None  # perfect: none


# --------------------------------------------------------------------------- the real fleet's receive filter
def _key(mission: str, cid: str, topic: str) -> str:
    from wire import keys

    return keys.carrier_key(mission, cid, topic)


def test_the_receive_filter_is_absent_on_perfect_links():
    from wire.link_filter import link_filter

    assert link_filter(load_scenario(ROOT / "scenarios" / "tiny.yaml"), "m", "coordinator") is None


def test_the_receive_filter_delays_by_the_model_and_learns_positions():
    from wire import messages as wm
    from wire.link_filter import link_filter

    s = load_scenario(MARINE)
    s = dataclasses.replace(s, links=dataclasses.replace(s.links, params=tuple(
        (k, 0.0 if k == "fade_db" else v) for k, v in s.links.params)))
    f = link_filter(s, "marine_survey", "coordinator", realtime=0.0)
    obs = wm.encode(wm.Observation("marine_survey", "vessel2", 3, 360.0, 1, (1200.0, 600.0), 3, ()))
    delay = f.delay(_key("marine_survey", "vessel2", "obs"), obs)
    # 600 m from the base (1200, 0): airtime of its bytes, then 0.4 s of sound (the channel was free)
    assert delay == pytest.approx(8 * len(obs) / s.links.bitrate_bps + 600.0 / 1500.0, abs=0.05)
    assert f.positions["vessel2"] == (1200.0, 600.0)
    far = wm.encode(wm.Observation("marine_survey", "vessel1", 3, 360.0, 1, (1200.0, 1600.0 + 2000.0), 3, ()))
    assert f.delay(_key("marine_survey", "vessel1", "obs"), far) is None  # 3.6 km: beyond range, no fading
    assert f.sent == 2 and f.lost == 1
    pose = wm.encode(wm.Pose("marine_survey", "vessel3", 1.0, (5.0, 5.0), 0.0, 3))
    assert f.delay(_key("marine_survey", "vessel3", "pose"), pose) == 0.0 and f.positions["vessel3"] == (5.0, 5.0)


def test_a_node_holds_a_delayed_sample_and_drops_a_lost_one():
    from wire.transport import Held, Inbound, Node

    node = Node.__new__(Node)  # the inbox logic only: no zenoh session
    import queue

    node.inbox, node._held, node._held_quiet, node._quiet = queue.Queue(), Held(), Held(), []
    fates = {"a": 0.0, "b": None, "c": 0.3}
    node.links = SimpleNamespace(delay=lambda key, payload: fates[key])
    for key in ("c", "b", "a"):
        node.inbox.put(Inbound("sample", key, b"x"))
    node.inbox.put(Inbound("alive", "token"))
    got = [node.next(1.0) for _ in range(3)]
    assert [i.key for i in got] == ["a", "token", "c"] and node.next(0.05) is None


def test_the_live_view_draws_the_base_and_the_relays():
    from viewer.rerun_view import RerunView
    from world.scene import build_scene

    logged = {}
    rec = SimpleNamespace(log=lambda path, value, static=False: logged.setdefault(path, value))
    RerunView(rec, build_scene(_corridor(3)))
    assert "world/links/base" in logged and "world/links/relays" in logged
    logged.clear()
    RerunView(rec, build_scene(load_scenario(ROOT / "scenarios" / "tiny.yaml")))
    assert not any(path.startswith("world/links") for path in logged)


def test_the_receive_filter_routes_radio_through_the_relays_dropped_by_the_stage_it_heard():
    from wire import messages as wm
    from wire.link_filter import link_filter

    s = _corridor(3, fade=0.0)
    f = link_filter(s, "m", "coordinator")
    far = wm.encode(wm.Observation("m", "a", 0, 0.0, 1, (300.0, 0.0), 1, ()))
    assert f.delay(_key("m", "a", "obs"), far) is None  # stage 0 heard: no relay down, 300 m in the open
    later = wm.encode(wm.Observation("m", "a", 1, 75.0, 1, (300.0, 0.0), 1, ()))
    # stage 1 heard: the relay at 100 m (dropped at 50 s) is down: 200 m and 100 m, two hops
    assert f.delay(_key("m", "a", "obs"), later) == pytest.approx(2 * s.links.latency_s)
