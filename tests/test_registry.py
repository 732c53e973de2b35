"""planner.registry: the one home of planner names, options, defaults and their validation, read by
scenario files, the solve command and run_fleet.py."""
from __future__ import annotations

import copy
import math
from pathlib import Path

import pytest
import yaml

import world
from planner.cli import solve
from planner import registry
from planner.registry import OPTIONS, check_settings, make_planner, parse_option

ROOT = Path(__file__).resolve().parents[1]
BASE = yaml.safe_load((ROOT / "scenarios" / "tiny.yaml").read_text())


def test_defaults_live_in_the_registry():
    assert OPTIONS["iterations"].default == registry.DEFAULT_ITERATIONS == 10_000
    assert OPTIONS["exploration"].default == registry.DEFAULT_EXPLORATION == 0.05 * math.sqrt(2.0)
    assert OPTIONS["layout"].choices == ("auto", "joint", "binary")
    spec = world.PlannerSpec()
    assert spec.name == registry.DEFAULT_PLANNER
    assert {k: getattr(spec, k) for k in OPTIONS} == registry.defaults()


def test_layout_reaches_the_mcts_planner_and_others_ignore_it():
    assert make_planner("mcts-ssap", layout="binary").layout == "binary"
    assert make_planner("mcts-random").layout == "auto"
    assert make_planner("closed-loop", layout="joint", exploration=1.0).name == "closed-loop"
    with pytest.raises(ValueError, match="layout must be one of auto, joint, binary"):
        make_planner("mcts-ssap", layout="tree")


def test_check_settings_reports_field_paths():
    problems = check_settings("mcts-sap", {"layout": "tree", "iterations": 0, "samples": None})
    assert [(p.field, p.expected) for p in problems] == [
        ("name", "one of random, ssap, mcts-random, mcts-ssap, closed-loop, closed-loop-gated, online-optimal, dec-mcts, dec-closed-loop (did you mean 'mcts-ssap'?)"),
        ("layout", "one of auto, joint, binary"),
        ("iterations", "an integer >= 1 and <= 1e+09"),
    ]
    assert check_settings("ssap", {"plan_ms": 5.0}) == []


def test_parse_option():
    assert parse_option("layout=binary") == ("layout", "binary")
    assert parse_option("plan-ms=2.5") == ("plan_ms", 2.5)
    with pytest.raises(ValueError, match="^layout: expected one of auto, joint, binary, found 'tree'$"):
        parse_option("layout=tree")
    with pytest.raises(ValueError, match="expected KEY=VALUE"):
        parse_option("depth=3")


def _scenario_lines(tmp_path, planner_block):
    data = copy.deepcopy(BASE)
    data["planner"] = planner_block
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(data))
    try:
        return world.load_scenario(path), []
    except world.ScenarioError as err:
        return None, [line.split(": ", 1)[1] for line in err.problems]


def test_scenario_planner_block_takes_the_registry_options(tmp_path):
    scenario, lines = _scenario_lines(tmp_path, {"name": "mcts-ssap", "layout": "binary", "iterations": 50})
    assert lines == [] and scenario.planner.layout == "binary" and scenario.planner.iterations == 50
    assert scenario.planner.options()["layout"] == "binary"
    _, lines = _scenario_lines(tmp_path, {"name": "mcts-ssap", "layout": "tree"})
    assert lines == ["planner.layout: expected one of auto, joint, binary, found 'tree'"]
    _, lines = _scenario_lines(tmp_path, {"name": "mcts-ssap", "laytou": "binary"})
    assert lines == ["planner.laytou: expected a known key (did you mean 'layout'?), found unknown key 'laytou'"]


def test_solve_command_has_one_flag_per_registry_option(tmp_path, capsys):
    flags = {a.dest for a in solve.build_parser()._actions}
    assert set(OPTIONS) <= flags
    with pytest.raises(SystemExit) as stop:
        solve.main([str(tmp_path / "x.json"), "--planner", "mcts-ssap", "--layout", "tree"])
    assert stop.value.code == 2
    assert "--layout: expected one of auto, joint, binary, found 'tree'" in capsys.readouterr().err


def test_run_fleet_takes_planner_options_from_the_registry():
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "run_fleet.py", "scenarios/tiny.yaml", "--planner-option", "layout=tree"],
                          cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [
        "run_fleet.py: --planner-option: layout: expected one of auto, joint, binary, found 'tree'"]


def test_planner_settings_apply_planner_options(tmp_path):
    from planner.registry import planner_settings

    scenario = world.load_scenario(ROOT / "scenarios" / "tiny.yaml")
    name, options = planner_settings(scenario, "mcts-ssap", 50, None, (("layout", "binary"),))
    assert name == "mcts-ssap" and options["layout"] == "binary" and options["iterations"] == 50
    assert make_planner(name, **options).layout == "binary"
