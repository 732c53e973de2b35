"""The link model (planner/links.py, world/links.py, world/relays.py): one table row per rule —
radio and acoustic margins, delivery probability, the acoustic channel, determinism, best paths,
walls counted in a real pymunk world, the relay dropping rule, and bad `links` input."""
from __future__ import annotations

import copy
import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from planner import links as ch
from world.links import LinkModel, Walls
from world.relays import fleet_relays, relay_drops, route_to_base
from world.scenario import ScenarioError, parse_scenario

ROOT = Path(__file__).resolve().parents[1]
TINY = yaml.safe_load((ROOT / "scenarios" / "tiny.yaml").read_text())
RADIO = ch.LinkSpec.of("radio")
ACOUSTIC = ch.LinkSpec.of("acoustic")


def _scenario(**top):
    data = copy.deepcopy(TINY)
    data.update(top)
    return parse_scenario(data, "test.yaml")


# --------------------------------------------------------------------------- radio margin
# defaults: margin = 20 - 40 - 30 log10(d) - 12 walls + 90 = 70 - 30 log10(d) - 12 walls (dB)
@pytest.mark.parametrize("distance, walls, expected", [
    (1.0, 0, 70.0),        # the reference distance
    (0.2, 0, 70.0),        # nearer than 1 m is clamped to 1 m
    (10.0, 0, 40.0),
    (100.0, 0, 10.0),
    (100.0, 1, -2.0),      # a wall costs wall_loss_db
    (100.0, 3, -26.0),
    (1000.0, 0, -20.0),
], ids=lambda v: str(v))
def test_radio_margin(distance, walls, expected):
    assert ch.margin_db(RADIO, distance, walls) == pytest.approx(expected)


@pytest.mark.parametrize("params, distance, walls, expected", [
    ({"path_loss_exponent": 2.0}, 100.0, 0, 30.0),
    ({"wall_loss_db": 0.0}, 100.0, 5, 10.0),
    ({"tx_power_dbm": 0.0, "sensitivity_dbm": -70.0}, 10.0, 0, 0.0),
], ids=["exponent", "no-wall-loss", "power-and-sensitivity"])
def test_radio_parameters(params, distance, walls, expected):
    assert ch.margin_db(ch.LinkSpec.of("radio", **params), distance, walls) == pytest.approx(expected)


# --------------------------------------------------------------------------- acoustic margin
@pytest.mark.parametrize("f_khz, expected", [(10.0, 1.187), (25.0, 6.105), (1.0, 0.069)], ids=["10kHz", "25kHz", "1kHz"])
def test_thorp_absorption(f_khz, expected):
    assert ch.thorp_db_per_km(f_khz) == pytest.approx(expected, abs=2e-3)


@pytest.mark.parametrize("distance, expected", [
    (1.0, 170 - 85 - 10 - 0.0061),                     # only absorption over 1 m
    (1000.0, 170 - 85 - 10 - 45 - 6.105),              # 15 log10(1000) = 45 dB spreading
    (4000.0, 170 - 85 - 10 - 15 * math.log10(4000) - 4 * 6.105),
], ids=["1m", "1km", "4km"])
def test_acoustic_margin(distance, expected):
    assert ch.margin_db(ACOUSTIC, distance) == pytest.approx(expected, abs=0.01)


def test_acoustic_range_is_kilometres_and_radio_range_hundreds_of_metres():
    assert 2000 < ch.open_range_m(ACOUSTIC) < 6000
    assert ch.open_range_m(RADIO) == pytest.approx(10 ** (70 / 30), rel=1e-6)
    assert ch.open_range_m(ch.LinkSpec()) == math.inf


# --------------------------------------------------------------------------- delivery probability
@pytest.mark.parametrize("spec, margin, expected", [
    (RADIO, 0.0, 0.5),
    (RADIO, 4.0, 0.841345),                            # Phi(1): one fade standard deviation
    (RADIO, -8.0, 0.022750),                           # Phi(-2)
    (ch.LinkSpec.of("radio", fade_db=0.0), 0.0, 1.0),  # no fading: a step at margin 0
    (ch.LinkSpec.of("radio", fade_db=0.0), -0.01, 0.0),
    (ch.LinkSpec(), -100.0, 1.0),                      # perfect
], ids=["zero", "+1sd", "-2sd", "step-at-0", "step-below", "perfect"])
def test_probability(spec, margin, expected):
    assert ch.probability(spec, margin) == pytest.approx(expected, abs=1e-6)


# --------------------------------------------------------------------------- transmissions
def test_perfect_delivers_at_once_and_draws_nothing():
    rng = np.random.default_rng(1)
    d = ch.transmit(ch.LinkSpec(), [(1e6, 10)], 10_000, 3.5, rng)
    assert (d.delivered, d.time, d.probability) == (True, 3.5, 1.0)
    assert rng.random() == np.random.default_rng(1).random()


@pytest.mark.parametrize("hops", [1, 3], ids=["direct", "two-relays"])
def test_radio_draws_one_uniform_per_hop_delivered_or_not(hops):
    rng, twin = np.random.default_rng(5), np.random.default_rng(5)
    d = ch.transmit(RADIO, [(120.0, 0)] * hops, 50, 10.0, rng)
    u = twin.random(hops)
    p = ch.probability(RADIO, ch.margin_db(RADIO, 120.0))
    assert d.delivered == bool((u < p).all())
    assert d.probability == pytest.approx(p ** hops)
    assert d.time == pytest.approx(10.0 + hops * RADIO.latency_s)
    assert rng.random() == twin.random()


def test_same_seed_same_fates_and_rate_matches_probability():
    fates = [[ch.transmit(RADIO, [(200.0, 0)], 50, 0.0, rng).delivered for _ in range(4000)]
             for rng in (np.random.default_rng(9), np.random.default_rng(9))]
    assert fates[0] == fates[1]
    p = ch.probability(RADIO, ch.margin_db(RADIO, 200.0))
    assert 0.1 < p < 0.9
    assert np.mean(fates[0]) == pytest.approx(p, abs=0.03)


@pytest.mark.parametrize("send, free_at, size, distance, start, arrival", [
    (10.0, -math.inf, 125, 1500.0, 10.0, 12.0),   # 1 s on the channel at 1000 bit/s, 1 s of travel
    (10.0, 10.5, 125, 1500.0, 10.5, 12.5),        # waits for the channel
    (10.0, 9.0, 250, 0.0, 10.0, 12.0),            # a channel already free
], ids=["idle", "busy", "free"])
def test_acoustic_delay_and_airtime(send, free_at, size, distance, start, arrival):
    d = ch.transmit(ACOUSTIC, [(distance, 0)], size, send, np.random.default_rng(0), ch.Channel(free_at))
    assert d.start == pytest.approx(start)
    assert d.time == pytest.approx(arrival)
    assert d.channel == ch.Channel(start + 8 * size / 1000)


def test_acoustic_channel_has_one_talker_at_a_time():
    rng, channel, starts = np.random.default_rng(0), ch.Channel(), []
    for _ in range(3):  # three carriers send at the same moment
        d = ch.transmit(ACOUSTIC, [(300.0, 0)], 100, 0.0, rng, channel)
        channel = d.channel
        starts.append(d.start)
    assert starts == pytest.approx([0.0, 0.8, 1.6])


@pytest.mark.parametrize("size, hops, error", [
    (257, 1, "frame_bytes"),
    (10, 2, "one hop"),
], ids=["too-big-for-frame", "acoustic-relay"])
def test_acoustic_refusals(size, hops, error):
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match=error):
        ch.transmit(ACOUSTIC, [(100.0, 0)] * hops, size, 0.0, rng)
    assert rng.random() == np.random.default_rng(0).random()  # a refused message draws nothing


# --------------------------------------------------------------------------- best path
@pytest.mark.parametrize("prob, path, p", [
    ([[1, .9], [.9, 1]], (0, 1), .9),
    ([[1, .1, .9], [.1, 1, .9], [.9, .9, 1]], (0, 2, 1), .81),       # the relay beats the weak direct link
    ([[1, .85, .9], [.85, 1, .9], [.9, .9, 1]], (0, 1), .85),        # the direct link beats .81
    ([[1, 0, 0], [0, 1, .5], [0, .5, 1]], (), 0.0),                  # no path
    ([[1, 0, .5, 0], [0, 1, 0, .5], [.5, 0, 1, .5], [0, .5, .5, 1]], (0, 2, 3, 1), .125),
], ids=["direct", "via-relay", "direct-better", "cut-off", "chain"])
def test_best_path(prob, path, p):
    got, q = ch.best_path(np.asarray(prob, dtype=float), 0, 1)
    assert got == path
    assert q == pytest.approx(p)


# --------------------------------------------------------------------------- walls (pymunk)
WALLED = {"bounds": [0, 0, 100, 100],
          "walls": [[[50, 0], [50, 40], [50, 80]],      # a polyline with a joint at (50, 40)
                    [[70, 10], [70, 30]]],
          "obstacles": [[[20, 60], [30, 60], [30, 70], [20, 70]]]}


@pytest.mark.parametrize("a, b, walls", [
    ((10, 20), (40, 20), 0),      # clear
    ((10, 20), (60, 20), 1),      # the polyline
    ((10, 40), (60, 40), 1),      # through the polyline's joint: one wall, not two
    ((10, 20), (90, 20), 2),      # both walls
    ((10, 65), (40, 65), 2),      # into and out of the obstacle
    ((10, 90), (90, 90), 0),      # above everything
    ((60, 20), (10, 20), 1),      # either direction
    ((30, 30), (30, 30), 0),      # one point
], ids=["clear", "one", "joint", "two", "obstacle", "above", "reverse", "point"])
def test_walls_crossed_in_a_real_pymunk_world(a, b, walls):
    s = _scenario(map=WALLED)
    assert Walls(s.map.segments).crossed(a, b) == walls


def test_wall_attenuation_through_the_scenario_model():
    s = _scenario(map=WALLED, links={"model": "radio", "wall_loss_db": 15})
    m = LinkModel(s)
    clear, walled = m.margin((10, 20), (40, 20)), m.margin((10, 20), (90, 20))
    expect = ch.margin_db(s.links, 80.0) - 2 * 15
    assert walled == pytest.approx(expect)
    assert clear == pytest.approx(ch.margin_db(s.links, 30.0))
    assert m.probability((10, 20), (90, 20)) < m.probability((10, 20), (40, 20))
    acoustic = LinkModel(_scenario(map=WALLED, links="acoustic"))
    assert acoustic.hop((10, 20), (90, 20)) == (80.0, 0)  # the sea has no walls


# --------------------------------------------------------------------------- relays
STRAIGHT = [[0, 0], [350, 0]]
CORNER = [[0, 0], [40, 0], [40, 60]]  # round the end of a wall at x = 30 from y = 5 up


def _corridor(relays, walls=(), path=STRAIGHT, fade=0.0):
    return _scenario(
        map={"bounds": [-10, -10, 400, 100], "walls": [list(w) for w in walls]},
        features={"density": 0.0}, stages=2, stage_interval=1.0,
        carriers=[{"id": "a", "passengers": 1, "start_time": 0, "speed": 2.0, "waypoints": path}],
        links={"model": "radio", "base": [0, 0], "fade_db": fade, "relays": relays})


@pytest.mark.parametrize("relays, walls, path, at, xy", [
    ({"count": 2}, (), STRAIGHT, [100, 200], [(100, 0), (200, 0)]),   # margin 10 dB at 100 m in the open
    ({"count": 5}, (), STRAIGHT, [100, 200, 300], [(100, 0), (200, 0), (300, 0)]),  # the path ends first
    ({"count": 3, "drop_margin_db": 20}, (), STRAIGHT, [46, 92, 138],  # 70 - 30 log10(d) >= 20: d <= 46.4
     [(46, 0), (92, 0), (138, 0)]),
    ({"count": 3, "step_m": 25}, (), STRAIGHT, [100, 200, 300], [(100, 0), (200, 0), (300, 0)]),
    # behind the wall from (40, 7) on (-12 dB): dropped at the last good check, (40, 6)
    ({"count": 2}, ([[30, 5], [30, 90]],), CORNER, [46], [(40, 6)]),
    ({"carriers": {"a": 1}}, (), STRAIGHT, [100], [(100, 0)]),
    ({}, (), STRAIGHT, [], []),
], ids=["open", "runs-out-of-path", "threshold", "coarse-steps", "wall", "per-carrier", "none"])
def test_relay_dropping_rule(relays, walls, path, at, xy):
    s = _corridor(relays, walls, path)
    drops = fleet_relays(LinkModel(s))
    assert [r.distance for r in drops] == pytest.approx(at)
    assert [r.position[0] for r in drops] == pytest.approx([p[0] for p in xy])
    assert [r.position[1] for r in drops] == pytest.approx([p[1] for p in xy])
    assert [r.time for r in drops] == pytest.approx([x / 2.0 for x in at])  # start 0, 2 m/s
    assert [r.index for r in drops] == list(range(len(at)))


def test_relays_carry_messages_to_the_base():
    s = _corridor({"count": 3}, fade=4.0)
    m = LinkModel(s)
    drops = fleet_relays(m)
    far = (330.0, 0.0)
    assert m.probability(m.base, far) < 0.1  # margin -5.6 dB direct
    path, p = route_to_base(m, drops, far, t=1e9)
    # nodes: carrier, base, relays at 100, 200, 300 m: carrier -> 300 -> 200 -> 100 -> base
    assert path == (0, 4, 3, 2, 1)
    assert p == pytest.approx(math.prod(m.probability(a, b) for a, b in
                                        [(far, (300, 0)), ((300, 0), (200, 0)), ((200, 0), (100, 0)), ((100, 0), (0, 0))]))
    assert p > 0.95
    late, q = route_to_base(m, drops, far, t=60.0)  # only the relay at 100 m dropped by t = 60 s
    assert late == (0, 2, 1) and q < 0.5
    d = m.transmit(far, m.base, 60, 0.0, np.random.default_rng(0), via=[r.position for r in drops[::-1]])
    assert d.probability == pytest.approx(p) and d.time == pytest.approx(4 * s.links.latency_s)


def test_relay_drops_are_deterministic():
    s = _corridor({"count": 3})
    m = LinkModel(s)
    c = s.carriers[0]
    assert relay_drops(m, c, 3, 10.0, 1.0) == relay_drops(LinkModel(s), c, 3, 10.0, 1.0)


# --------------------------------------------------------------------------- the scenario field
def test_links_default_is_perfect_and_a_name_is_enough():
    assert _scenario().links == ch.LinkSpec()
    assert _scenario(links="acoustic").links == ACOUSTIC
    assert _scenario(links={"model": "radio", "wall_loss_db": 3}).links.wall_loss_db == 3.0


@pytest.mark.parametrize("links, field, words", [
    ({"model": "radar"}, "links.model", "one of perfect, radio, acoustic (did you mean 'radio'?)"),
    ({"model": "radio", "wall_loss_db": -1}, "links.wall_loss_db", "from 0 to 60 (dB"),
    ({"model": "radio", "path_loss_exponent": "3"}, "links.path_loss_exponent", "a number from 1 to 6"),
    ({"model": "acoustic", "sound_speed_mps": 340}, "links.sound_speed_mps", "from 1300 to 1700"),
    ({"model": "acoustic", "frame_bytes": 12.5}, "links.frame_bytes", "an integer from 1 to 65535"),
    ({"model": "acoustic", "bitrate_bps": 0}, "links.bitrate_bps", "from 1 to 1e+06 (bit/s"),
    ({"model": "acoustic", "wall_loss_db": 10}, "links.wall_loss_db", "unknown key 'wall_loss_db'"),
    ({"model": "acoustic", "relays": {"count": 2}}, "links.relays", "only with links.model radio"),
    ({"model": "perfect", "relays": {"count": 2}}, "links.relays", "found links.model perfect"),
    ({"relays": {"count": 2}}, "links.relays", "only with links.model radio"),
    ({"model": "radio", "relays": {"carriers": {"z": 1}}}, "links.relays.carriers.z", "unknown carrier 'z'"),
    ({"model": "radio", "relays": {"count": -1}}, "links.relays.count", "an integer from 0 to 1000"),
    ({"model": "radio", "relays": {"count": 1, "drop_margin_db": 99}}, "links.relays.drop_margin_db", "from 0 to 60"),
    ({"model": "radio", "base": [1]}, "links.base", "a point [x, y]"),
    ({"model": "acoustic", "base": [50, 20]}, "links.base", "a point inside map.bounds [0.0, 0.0, 40.0, 40.0]"),
    (7, "links", "a model name (perfect, radio, acoustic)"),
], ids=["model", "wall-loss", "exponent-type", "sound-speed", "frame-integer", "bitrate", "unknown-key",
        "relays-acoustic", "relays-perfect", "relays-default", "relay-carrier", "relay-count", "relay-margin",
        "base", "base-outside", "not-a-mapping"])
def test_bad_links_name_the_field(links, field, words):
    with pytest.raises(ScenarioError) as err:
        _scenario(links=links)
    lines = [line for line in err.value.problems if f"test.yaml: {field}:" in line]
    assert lines and words in lines[0], err.value.problems


def test_the_map_shows_the_base_and_the_relays(tmp_path):
    import matplotlib.pyplot as plt

    from world.render import _draw_links, render_map

    s = _corridor({"count": 3})
    fig, ax = plt.subplots()
    assert [h.get_label() for h in _draw_links(ax, s)] == ["base (radio links)", "relay (3)"]
    assert sorted(tuple(line.get_xydata()[0]) for line in ax.lines) == [(0, 0), (100, 0), (200, 0), (300, 0)]
    plt.close(fig)
    assert _draw_links(ax, _scenario()) == []  # perfect links: nothing drawn
    assert render_map(s, tmp_path / "relays.png", stage_labels=False).stat().st_size > 10_000


def test_stage_connectivity_predicts_who_hears_whom():
    from world.relays import stage_connectivity

    s = _corridor({"count": 3}, fade=4.0)
    m = LinkModel(s)
    bare = stage_connectivity(m)
    with_relays = stage_connectivity(m, fleet_relays(m))
    assert bare.shape == with_relays.shape == (2, 2, 2)  # 2 stages; the base and carrier a
    # stage 1 is at t = 1 s: the carrier is 2 m out, next to the base
    assert bare[1, 0, 1] == pytest.approx(m.probability((0, 0), (2, 0))) and bare[1, 0, 1] == bare[1, 1, 0]
    far = dataclasses.replace(s, stage_interval=165.0)  # stage 1 at 330 m, after every drop
    mf = LinkModel(far)
    assert stage_connectivity(mf)[1, 0, 1] < 0.1
    assert stage_connectivity(mf, fleet_relays(mf))[1, 0, 1] > 0.95
    assert np.isnan(stage_connectivity(LinkModel(dataclasses.replace(s, first_stage_time=200.0)))[0, 0, 1])


@pytest.mark.parametrize("param", [*ch.RADIO_PARAMS, *ch.ACOUSTIC_PARAMS, *ch.RELAY_PARAMS], ids=lambda p: p.name)
def test_the_docs_table_is_the_parameter_table(param):
    """docs/scenario.md's parameter tables say what planner/links.py holds (default, range, unit)."""
    text = (ROOT / "docs" / "scenario.md").read_text()
    row = (f"| `{param.name}` | {param.default:g} | {param.lo:g} to {param.hi:g}{' (integer)' if param.integer else ''} "
           f"| {param.unit or '—'} |")
    assert row in text
