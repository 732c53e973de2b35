"""One home for size limits (planner.limits): a scenario at the limits produces messages that
encode within the wire's payload limit, and scenario validation refuses anything beyond them."""
from __future__ import annotations

import copy
from pathlib import Path

import pytest
import yaml

import world
from planner import limits
from wire import messages
from wire.messages import CarrierState, Decision, Hello, Observation, State, decode, encode

ROOT = Path(__file__).resolve().parents[1]
BASE = yaml.safe_load((ROOT / "scenarios" / "tiny.yaml").read_text())
MISSION = "m" * 64  # the longest id the keys allow


def _ids() -> list[str]:
    return [f"{r:04d}" + "c" * 60 for r in range(limits.MAX_CARRIERS)]


def test_wire_uses_the_shared_limits():
    assert messages.MAX_STAGES == limits.MAX_STAGES and messages.MAX_CARRIERS == limits.MAX_CARRIERS
    assert messages.MAX_PAYLOAD_BYTES == limits.MAX_PAYLOAD_BYTES and messages.MAX_TEXT == limits.MAX_TEXT
    # The wire's passenger bound accepts every valid scenario's passenger count.
    hello = Hello(MISSION, _ids()[0], 2**31, "h" * 255, limits.MAX_PASSENGERS, limits.MAX_STAGES, "f" * 64)
    assert decode(encode(hello)) == hello


def test_messages_of_a_scenario_at_the_limits_encode():
    ids = _ids()
    last = limits.MAX_STAGES - 1
    deployments = tuple(range(last - limits.MAX_PASSENGERS + 1, last + 1))  # D stages, the widest ints
    decision = Decision(MISSION, last, 1e9 - 0.5, tuple(sorted(ids)), 1e9 - 0.25)
    # The largest State: as many carriers as one reply lists (an unscoped query on a mission of
    # at most MAX_STATE_CARRIERS carriers), each with D deployments, and the largest Decision.
    listed = sorted(ids)[:limits.MAX_STATE_CARRIERS]
    state = State(MISSION, limits.MAX_STAGES, limits.MAX_STAGES, "f" * 64, True,
                  tuple((cid, CarrierState(limits.MAX_PASSENGERS, deployments, True)) for cid in listed),
                  decision)
    trail = tuple((-limits.MAX_COORD + 0.123456789, limits.MAX_COORD - 0.987654321) for _ in range(limits.MAX_TRAIL))
    obs = Observation(MISSION, ids[-1], last, 1e9 - 0.5, 10**9, trail[0], limits.MAX_PASSENGERS, trail)
    hello = Hello(MISSION, ids[-1], 2**31, "h" * 255, limits.MAX_PASSENGERS, limits.MAX_STAGES, "f" * 64)
    # A coverage mission's Observation: the most region counts, each a 5-byte integer (revision 5).
    counts = (10**9 // limits.MAX_POINT_REGIONS,) * limits.MAX_POINT_REGIONS
    covered = Observation(MISSION, ids[-1], last, 1e9 - 0.5, sum(counts), trail[0], limits.MAX_PASSENGERS, trail,
                          counts)
    for message in (state, decision, obs, hello, covered):
        data = encode(message)  # raises "oversized" beyond MAX_PAYLOAD_BYTES
        assert len(data) <= limits.MAX_PAYLOAD_BYTES
        assert decode(data) == message


def _load(tmp_path, data):
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(world.ScenarioError) as info:
        world.load_scenario(path)
    return [line.split(": ", 1)[1] for line in info.value.problems]


def test_scenario_validation_refuses_beyond_the_limits(tmp_path):
    data = copy.deepcopy(BASE)
    data["carriers"][0]["passengers"] = limits.MAX_PASSENGERS + 1
    assert any(line.startswith(f"carriers[0].passengers: expected an integer >= 0 and <= {limits.MAX_PASSENGERS}")
               for line in _load(tmp_path, data))
    data = copy.deepcopy(BASE)
    data["stages"] = limits.MAX_STAGES + 1
    assert any(line.startswith(f"stages: expected an integer >= 1 and <= {limits.MAX_STAGES}")
               for line in _load(tmp_path, data))
    data = copy.deepcopy(BASE)
    data["carriers"] = [dict(data["carriers"][0], id=f"c{r}") for r in range(limits.MAX_CARRIERS + 1)]
    assert f"carriers: expected a list of at most {limits.MAX_CARRIERS} carriers, found {limits.MAX_CARRIERS + 1} carriers" \
        in _load(tmp_path, data)


def test_a_state_lists_at_most_max_state_carriers():
    ids = sorted(_ids())[:limits.MAX_STATE_CARRIERS + 1]
    state = State(MISSION, 0, 10, "f" * 64, False, tuple((cid, CarrierState(1, (), True)) for cid in ids), None)
    with pytest.raises(messages.ProtocolError, match="out-of-range"):
        encode(state)


def test_messages_of_a_mission_within_the_old_limits_keep_the_old_size():
    """Every message of a mission of at most 64 carriers fits the 64 KiB of protocol version 1's
    first limits, so older peers interoperate with such missions."""
    ids = _ids()[:64]
    decision = Decision(MISSION, limits.MAX_STAGES - 1, 1e9 - 0.5, tuple(sorted(ids)), 1e9 - 0.25)
    assert len(encode(decision)) <= 64 * 1024
