"""The validation toolkit (validation/): one problem shape and one error line for every input."""
import json

import msgpack

import pytest

import validation as v
from planner.instance import InstanceError, parse_instance
from planner.priors import prior_problems
from wire.messages import Hello, ProtocolError, decode, encode
from world.scenario import ScenarioError, parse_scenario


@pytest.mark.parametrize("check, good, normalised, bad, expected", [
    (v.Number(integer=True, minimum=1), 3.0, 3, 0, "an integer >= 1"),
    (v.Number(minimum=0, exclusive=True), 2, 2.0, 0, "a number > 0"),
    (v.Number(integer=True, minimum=0, maximum=5), 5, 5, 6, "an integer >= 0 and <= 5"),
    (v.Number(maximum=1), -3, -3.0, float("nan"), "a number <= 1"),
    (v.Choice(("auto", "joint")), "joint", "joint", "tree", "one of auto, joint"),
    (v.Flag(), False, False, 0, "true or false"),
    (v.Text(max_len=3), "abc", "abc", "abcd", "a non-empty string of at most 3 characters"),
], ids=["int-min", "exclusive", "range", "max-only", "choice", "flag", "text"])
def test_a_check_normalises_what_it_accepts_and_names_what_it_expects(check, good, normalised, bad, expected):
    assert check.check(good) == normalised and type(check.check(good)) is type(normalised)
    assert check.expected() == expected
    with pytest.raises(v.Invalid) as err:
        check.check(bad)
    assert err.value.expected == expected


def test_booleans_are_not_numbers_and_command_line_text_parses():
    with pytest.raises(v.Invalid):
        v.Number(integer=True).check(True)
    assert v.Flag().parse("Yes") is True and v.Flag().parse("0") is False
    assert v.Number(integer=True, minimum=1).parse(" 7 ") == 7
    with pytest.raises(v.Invalid):
        v.Number(integer=True).parse("seven")


def test_the_collector_keeps_paths_hints_and_missing_fields():
    problems = v.Flaws()
    problems.unknown_keys({"speeed": 1, "zzz": 2, "speed": 1}, "carriers[0]", ("speed", "waypoints"))
    problems.missing({"speed": 1}, "carriers[0]", ("speed", "waypoints"))
    assert problems.check(v.Number(minimum=0, exclusive=True), -1, "carriers[0].speed") is None
    assert len(problems) == 4
    assert problems.lines("s.yaml") == [
        "s.yaml: carriers[0].speeed: expected a known key (did you mean 'speed'?), found unknown key 'speeed'",
        "s.yaml: carriers[0].zzz: expected a known key (one of: speed, waypoints), found unknown key 'zzz'",
        "s.yaml: carriers[0].waypoints: expected a value, found nothing (missing)",
        "s.yaml: carriers[0].speed: expected a number > 0, found -1",
    ]


def test_found_values_show_in_the_style_of_their_input():
    assert v.show("x") == "'x'" and v.show("x", "json") == '"x"'
    assert v.show(None) == "nothing (null)" and v.show(None, "json") == "null"
    assert v.show({"a": 1}) == "a mapping" and v.show(list(range(100))) == "a list of 100 items"
    assert v.show(v.Found("3 carriers"), "json") == "3 carriers"
    assert v.Flaw("mean", "a number > 0", -1).within("prior").line("i.json") == "i.json: prior.mean: expected a number > 0, found -1"
    assert v.Flaw("", "a mapping", 3).line("f") == "f: (top level): expected a mapping, found 3"


def test_scenario_instance_prior_and_wire_errors_are_toolkit_problems():
    """The four readers report through the toolkit: the same problem renders the same line."""
    with pytest.raises(ScenarioError) as err:
        parse_scenario({"name": "x", "seed": -1}, "s.yaml")
    assert "s.yaml: seed: expected an integer >= 0, found -1" in err.value.problems

    with pytest.raises(InstanceError) as err:
        parse_instance({"carriers": 2, "passengers": 1, "stages": 3, "observation": []}, "i.json")
    assert err.value.problem == v.Flaw("observation", err.value.expected, v.Found("an unknown field"))
    assert "(did you mean 'observations'?)" in str(err.value)

    assert prior_problems({"kind": "poisson", "mean": -2}) == [v.Flaw("mean", "a number > 0", -2)]
    with pytest.raises(InstanceError) as err:
        parse_instance({"carriers": 1, "passengers": 1, "stages": 2, "prior": {"kind": "poisson", "mean": -2}}, "i.json")
    assert str(err.value) == "i.json: prior.mean: expected a number > 0, found -2"

    good = msgpack.unpackb(encode(Hello(mission="m", carrier="a", pid=1, host="h", passengers_left=1,
                                        next_stage=0, fingerprint="f", epoch=2)))
    with pytest.raises(ProtocolError) as err:
        decode(msgpack.packb({**good, "epoch": "one"}))
    assert err.value.reason == "wrong-type" and err.value.problem is not None
    assert err.value.detail == err.value.problem.line() == "hello.epoch: expected integer, found str"


def test_instance_errors_keep_their_json_rendering():
    with pytest.raises(InstanceError) as err:
        parse_instance(json.loads('{"carriers": "two", "passengers": 1, "stages": 3}'), "i.json")
    assert str(err.value) == 'i.json: carriers: expected an integer >= 1, found "two"'
