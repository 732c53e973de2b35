"""Planner plug-ins: the registry's entry points and ``package.module:Factory`` names, their
declared options and errors, and the conformance kit (planner/conformance.py) proving each named
failure on a deliberately broken plug-in (tests/planner_plugins.py)."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cli_helpers import in_process
from planner import conformance, registry
from planner.cli import conformance as kit_cli
from planner.cli import solve
from planner.registry import Option, PluginError, PluginNotFound, check_settings, make_planner, parse_option

ROOT = Path(__file__).resolve().parents[1]
HERE = Path(__file__).resolve().parent
THRESHOLD = "planner_plugins:Threshold"


@pytest.fixture(autouse=True)
def _forget_plugins():
    """Each test loads its plug-ins afresh (the registry keeps what it loaded)."""
    yield
    registry._PLUGINS.clear()


def _env() -> dict:
    return dict(os.environ, PYTHONPATH=os.pathsep.join([str(HERE), str(ROOT), os.environ.get("PYTHONPATH", "")]))


def test_importing_the_registry_loads_no_plugin_machinery():
    code = "import sys, planner.registry; print(sorted(m for m in sys.modules if m.startswith('importlib.metadata')))"
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_a_dotted_path_builds_the_plugin_with_its_declared_defaults():
    planner = make_planner(THRESHOLD)
    assert planner.cut == 3.0 and planner.name == "threshold"
    assert make_planner(THRESHOLD, cut=5, iterations=7).cut == 5.0  # a built-in it does not use: ignored
    assert make_planner("planner_plugins:make_threshold", cut=1.5).cut == 1.5  # a factory function
    found = registry.entry(THRESHOLD)
    assert found.plugin and found.options == () and [o.name for o in found.own] == ["cut"]
    assert THRESHOLD not in registry.planner_names()  # the built-ins' list is unchanged
    budgeted = registry.entry("planner_plugins:Budgeted")
    assert budgeted.options == ("iterations", "plan_ms")
    planner = make_planner("planner_plugins:Budgeted", iterations=9, exploration=3.0)
    assert (planner.iterations, planner.plan_ms, planner.cut) == (9, None, 3.0)


def test_bad_options_are_refused_naming_the_plugin():
    with pytest.raises(ValueError) as err:
        make_planner(THRESHOLD, cut=-1)
    assert str(err.value) == "planner 'planner_plugins:Threshold': cut must be a number >= 0, got -1"
    with pytest.raises(ValueError, match=r"planner 'planner_plugins:Threshold': unknown planner option\(s\) \['q'\]"):
        make_planner(THRESHOLD, q=1)
    problems = check_settings(THRESHOLD, {"cut": "high", "iterations": 0, "q": 1})
    assert [(p.field, p.expected) for p in problems] == [
        ("cut", "a number >= 0 (an option of planner 'planner_plugins:Threshold')"),
        ("iterations", "an integer >= 1 and <= 1e+09 (an option of planner 'planner_plugins:Threshold')"),
        ("q", "a planner option (iterations, plan_ms, exploration, samples, layout, learn_prior, cut) "
              "(an option of planner 'planner_plugins:Threshold')")]
    assert check_settings(THRESHOLD, {"cut": 2.5}) == []
    assert parse_option("cut=4", THRESHOLD) == ("cut", 4.0)
    with pytest.raises(ValueError, match=r"cut: expected a number >= 0 \(an option of planner 'planner_plugins:Threshold'\), found '-2'"):
        parse_option("cut=-2", THRESHOLD)
    with pytest.raises(ValueError, match="with KEY one of iterations"):
        parse_option("cut=4")  # without the planner, only the built-ins are known


@pytest.mark.parametrize("items, words", [
    (("cut",), "options[0]: expected a built-in option name"),
    ((3,), "options[0]: expected a built-in option name (iterations, plan_ms, exploration, samples, layout, "
           "learn_prior) or an Option of planner.registry, found 3"),
    ((Option("iterations", int, 1, "x"),), "options[0]: expected a new option name"),
    ((Option("q", float, 0.5, "x"), Option("q", float, 0.5, "x")), "options[1]: expected a new option name"),
    ((Option("q", float, 2.0, "x", maximum=1),), "options[0] (q): default 2.0 is not a number <= 1"),
    ((Option("q", list, None, "x"),), "options[0] (q): expected a kind among int, float, str, bool"),
    ((Option("mode", str, None, "x"),), "options[0] (mode): expected choices for a str option"),
    ((Option("not valid", int, None, "x"),), "options[0]: expected an option name that is a Python identifier"),
    ("iterations", "options: expected a sequence"),
], ids=["unknown-builtin", "not-an-option", "builtin-name", "repeated", "bad-default", "bad-kind",
        "str-without-choices", "bad-name", "a-string"])
def test_declarations_are_checked_naming_the_plugin(items, words):
    with pytest.raises(PluginError) as err:
        registry.declared_options("pkg.mod:Factory", items)
    assert str(err.value).startswith("planner 'pkg.mod:Factory': ") and words in str(err.value), str(err.value)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("name, words", [
    ("no_such_module_zz:Planner", "cannot import no_such_module_zz: ModuleNotFoundError"),
    ("planner_plugins:Nope", "module planner_plugins has no attribute 'Nope'"),
    ("planner_plugins:", "expected package.module:Factory"),
    ("planner_plugins:__doc__", "expected a callable factory, found str"),
])
def test_names_that_do_not_load_are_one_line_errors(name, words):
    with pytest.raises(PluginError) as err:
        registry.entry(name)
    assert words in str(err.value) and "\n" not in str(err.value)
    problems = check_settings(name, {})
    assert [p.field for p in problems] == ["name"] and words in problems[0].expected


def test_an_unknown_plain_name_lists_the_known_ones():
    with pytest.raises(ValueError, match="unknown planner 'greedyy'; expected one of: closed-loop, "):
        registry.entry("greedyy")
    [problem] = check_settings("mcts-sap", {})
    assert problem.expected.endswith("(did you mean 'mcts-ssap'?)")


def test_an_entry_point_is_found_lazily_by_its_name(tmp_path, monkeypatch):
    """A distribution's metadata on the import path declares ``thresh-ep`` in the group: the name
    resolves to the plug-in, its options checked, and it joins the known names."""
    info = tmp_path / "thresh_plugin-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: thresh-plugin\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(f"[{registry.ENTRY_POINT_GROUP}]\nthresh-ep = {THRESHOLD}\n"
                                           f"broken-ep = planner_plugins:BadDeclaration\n"
                                           f"missing-ep = no_such_module_zz:X\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    assert "thresh-ep" in registry.known_names() and "thresh-ep" not in registry.planner_names()
    assert make_planner("thresh-ep", cut=4).cut == 4.0
    with pytest.raises(ValueError, match="planner 'thresh-ep': cut must be a number >= 0"):
        make_planner("thresh-ep", cut=-4)
    with pytest.raises(PluginError, match="planner 'broken-ep': options\\[0\\]"):
        make_planner("broken-ep")
    with pytest.raises(PluginNotFound, match="planner 'missing-ep': cannot load entry point no_such_module_zz:X"):
        make_planner("missing-ep")


# ----------------------------------------------------------------------------- the conformance kit

#: (plug-in, check that fails, named reason); every other check passes or does not apply.
BROKEN = [
    ("DeploysTwice", "feasible", "deploys-twice"),
    ("BeyondPassengers", "feasible", "beyond-passengers"),
    ("IgnoresForced", "feasible", "infeasible"),
    ("Raises", "feasible", "raises"),
    ("GlobalRandom", "deterministic", "nondeterministic"),
    ("Stateful", "deterministic", "nondeterministic"),
    ("OverBudget", "budget", "over-budget"),
    ("OverIterations", "budget", "over-budget"),
    ("AcceptsBadOptions", "options", "bad-option-accepted"),
    ("BadDeclaration", "declaration", "bad-declaration"),
    ("OnBoardBeyond", "onboard", "beyond-passengers"),
]


@pytest.mark.parametrize("plugin, check, reason", BROKEN, ids=[row[0] for row in BROKEN])
def test_the_kit_names_each_failure(plugin, check, reason):
    report = conformance.check_planner(f"planner_plugins:{plugin}", count=1)
    assert not report.passed
    assert [(c.name, c.reason) for c in report.failures] == [(check, reason)]
    assert all("\n" not in c.detail for c in report.checks)
    assert reason in conformance.REASONS


@pytest.mark.parametrize("plugin", ["Threshold", "Budgeted", "OnBoard", "make_threshold"])
def test_honest_plugins_pass(plugin):
    report = conformance.check_planner(f"planner_plugins:{plugin}", {"cut": 2.0}, count=1)
    assert report.passed, report.failures
    outcomes = {c.name: c.outcome for c in report.checks}
    assert list(outcomes) == ["declaration", "builds", "feasible", "deterministic", "budget", "options", "onboard"]
    assert outcomes["onboard"] == ("pass" if plugin == "OnBoard" else "not-applicable")
    assert outcomes["budget"] == ("pass" if plugin == "Budgeted" else "not-applicable")


def test_the_kit_checks_a_builtin_planner_too():
    report = conformance.check_planner("ssap", count=1)
    assert report.passed and {c.name: c.outcome for c in report.checks}["onboard"] == "pass"


def test_the_kits_instances_are_seeded_and_of_every_family():
    first, again = conformance.instances(3, 2), conformance.instances(3, 2)
    assert [(f, i) for f, i, _ in first] == [(f, i) for f in conformance.FAMILIES for i in range(2)]
    for (_, _, a), (_, _, b) in zip(first, again):
        assert np.array_equal(a.observations, b.observations, equal_nan=True)
    assert any(np.isnan(inst.observations[inst.problem.valid]).any() for f, _, inst in first if f == "surprises")
    assert all(inst.problem.weights is not None for f, _, inst in first if f == "values")


def test_classify_names_each_rule():
    from planner.problem import Problem, make_view

    problem = Problem.build([1, 2], np.array([[True, True, True], [True, False, True]]), [])
    x = np.array([[1.0, 2.0, 3.0], [1.0, np.nan, 2.0]])
    deployed = np.zeros((2, 3), bool)
    deployed[0, 0] = True
    view = make_view(problem, 1, x, deployed)
    cases = [([0, 2], "deploys-twice"), ([True, False][::-1], "infeasible"), ([1, 0], "beyond-passengers"),
             ([0.5, 0], "infeasible"), ([False, False, False], "infeasible"), (["yes", "no"], "infeasible")]
    for decision, reason in cases:
        with pytest.raises(conformance.Violation) as err:
            conformance.classify(np.array(decision), view)
        assert err.value.reason == reason, decision
    assert conformance.classify(np.array([0, 0]), view).tolist() == [False, False]


# ----------------------------------------------------------------------------- its command line

def _kit(*args):
    done = in_process(kit_cli.main, args)
    return done.returncode, done.stdout, done.stderr


def test_the_command_exits_0_1_and_2(tmp_path):
    code, out, err = _kit(THRESHOLD, "--option", "cut=2", "--instances", "1", "--json", str(tmp_path / "r.json"))
    assert code == 0 and err == "" and out.splitlines()[-1] == f"planner '{THRESHOLD}': conformant (7 checks)"
    report = json.loads((tmp_path / "r.json").read_text())
    assert report["passed"] is True and report["options"] == {"cut": 2.0}
    assert [c["name"] for c in report["checks"]][:3] == ["declaration", "builds", "feasible"]
    code, out, err = _kit("planner_plugins:BeyondPassengers", "--instances", "1")
    assert code == 2 and "FAIL  feasible     [beyond-passengers] paper #0, stage " in out
    assert err.splitlines() == [err.strip()] and err.startswith(
        "python -m planner.conformance: planner 'planner_plugins:BeyondPassengers' broke rule beyond-passengers "
        "(check feasible): paper #0, stage "), err
    assert out.splitlines()[-1].endswith("1 check(s) failed: feasible (beyond-passengers)")
    for args, words in [(("no_such_module_zz:P",), "PLANNER: planner 'no_such_module_zz:P': cannot import"),
                        (("greedyy",), "PLANNER: expected an entry-point name, package.module:Factory or one of"),
                        ((THRESHOLD, "--option", "cut=-1"), "--option: cut: expected a number >= 0"),
                        ((THRESHOLD, "--option", "q=1"), "--option: expected KEY=VALUE with KEY one of"),
                        ((THRESHOLD, "--instances", "0"), "--instances: expected an integer >= 1, found '0'"),
                        ((THRESHOLD, "--instances", "1", "--json", str(tmp_path / "no" / "r.json")), "--json: cannot write")]:
        code, out, err = _kit(*args)  # argparse's own usage errors included
        assert code == 2 and len(err.splitlines()) == 1 and words in err, (args, err)
        assert err.startswith("python -m planner.conformance: error: ")


def test_python_m_planner_conformance_forwards_to_the_command():
    proc = subprocess.run([sys.executable, "-m", "planner.conformance", "planner_plugins:DeploysTwice",
                           "--instances", "1"], cwd=ROOT, env=_env(), capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "[deploys-twice]" in proc.stdout
    assert proc.stderr.splitlines() == [proc.stderr.strip()] and "'planner_plugins:DeploysTwice' broke rule deploys-twice" in proc.stderr


def test_solve_runs_a_plugin_by_its_dotted_path(tmp_path, capsys):
    path = tmp_path / "instance.json"
    path.write_text(json.dumps({"carriers": 2, "passengers": 1, "stages": 4,
                                "observations": [[1, 5, 2, 0], [4, 1, 1, 6]]}))
    base = [str(path), "--planner", THRESHOLD, "--no-clairvoyant", "--no-online-optimum", "--no-upper-bound"]
    assert solve.main([*base, "--planner-option", "cut=4"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["planner"] == THRESHOLD and out["deployments"] == [[1], [0]]
    assert solve.main([*base, "--planner-option", "cut=-4"]) == 2
    err = capsys.readouterr().err
    assert err.splitlines() == [f"python -m planner.cli.solve: error: --planner-option: cut: expected a number >= 0 "
                                f"(an option of planner '{THRESHOLD}'), found '-4'"]
    assert solve.main([str(path), "--planner", "no_such_module_zz:P"]) == 2
    assert "--planner: planner 'no_such_module_zz:P': cannot import" in capsys.readouterr().err


def test_a_scenario_names_a_plugin_and_its_own_options(tmp_path):
    import yaml

    import world
    from planner.registry import planner_settings

    base = yaml.safe_load((ROOT / "scenarios" / "tiny.yaml").read_text())

    def load(planner):
        path = tmp_path / "s.yaml"
        path.write_text(yaml.safe_dump({**base, "planner": planner}))
        return world.load_scenario(path)

    scenario = load({"name": THRESHOLD, "cut": 5, "iterations": 50})
    assert scenario.planner.plugin_options == (("cut", 5.0),)
    name, options = planner_settings(scenario)
    assert name == THRESHOLD and make_planner(name, **options).cut == 5.0
    for planner, line in [
        ({"name": THRESHOLD, "cut": -5}, "planner.cut: expected a number >= 0 (an option of planner "
                                         "'planner_plugins:Threshold'), found -5"),
        ({"name": "mcts-ssap", "cut": 5}, "planner.cut: expected a known key"),
        ({"name": "no_such_module_zz:P"}, "planner.name: expected a loadable planner plug-in (planner "
                                          "'no_such_module_zz:P': cannot import no_such_module_zz"),
    ]:
        with pytest.raises(world.ScenarioError) as err:
            load(planner)
        assert len(err.value.problems) == 1 and line in err.value.problems[0], err.value.problems


@pytest.mark.parametrize("plugin, rule", [
    ("planner_plugins:Raises", "raises at stage 2: RuntimeError: no plan for stage 2"),
    ("planner_plugins:DeploysTwice", "deploys-twice at stage"),
    ("planner_plugins:BeyondPassengers", "beyond-passengers at stage"),
    ("planner_plugins:IgnoresForced", "infeasible at stage"),
    ("planner_plugins:OverBudget", "over-budget at stage 0: the decision took"),
])
def test_solve_exits_2_with_one_line_naming_the_plugin_and_the_rule(tmp_path, plugin, rule):
    """A plug-in that raises, returns an infeasible action or runs past its plan_ms: solve exits 2
    with one line naming it and the rule it broke (planner/guard.py), never a traceback."""
    from planner.instance import instance_dict, random_instance

    inst = random_instance(np.random.default_rng(3), carriers=3, passengers=2, stages=6, overlaps=4)
    path = tmp_path / "inst.json"
    path.write_text(json.dumps(instance_dict(inst)))
    budget = ["--planner-option", "plan_ms=20"] if "OverBudget" in plugin else []
    proc = subprocess.run([sys.executable, "-m", "planner.cli.solve", str(path), "--planner", plugin, *budget,
                           "--no-clairvoyant", "--no-online-optimum", "--no-upper-bound"],
                          cwd=ROOT, env=_env(), capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and proc.stdout == "", proc.stderr
    assert proc.stderr.splitlines() == [f"python -m planner.cli.solve: planner {plugin!r} broke rule "
                                        + proc.stderr.split(" broke rule ")[1].rstrip()], proc.stderr
    assert f"planner {plugin!r} broke rule {rule}" in proc.stderr, proc.stderr


@pytest.mark.slow
@pytest.mark.parametrize("plugin, rule, stages", [
    ("planner_plugins:Raises", "raises", [2]),
    ("planner_plugins:BeyondPassengers", "beyond-passengers", None),
])
def test_a_fleet_survives_a_failing_plugin_and_decides_those_stages_with_ssap(tmp_path, plugin, rule, stages):
    """Real processes (run_fleet.py on the tiny scenario): the coordinator flies a plug-in that
    raises at stage 2, or deploys beyond its passengers; it exits 0, every stage decided, each
    failed stage decided by SSAP (the stage's Decision is SSAP's offline choice), and why is in
    mission.db and summary.json ``planner_faults``."""
    from fleet_helpers import db_rows

    out = tmp_path / "run"
    proc = subprocess.run([sys.executable, str(ROOT / "run_fleet.py"), str(ROOT / "scenarios" / "tiny.yaml"),
                           "--planner", plugin, "--out", str(out), "--no-map", "--no-record"],
                          cwd=ROOT, env=_env(), capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["ended"] and summary["stages_decided"] == summary["stages"] == 4
    faults = summary["planner_faults"]
    assert faults and {f["rule"] for f in faults} == {rule} and all(f["fallback"] == "ssap" for f in faults)
    if stages is not None:
        assert [f["stage"] for f in faults] == stages
    assert all(f["planner"] == plugin for f in faults)
    rows = db_rows(out / "mission.db", "SELECT stage FROM events WHERE kind='planner-fault' ORDER BY seq")
    assert [s for (s,) in rows] == [f["stage"] for f in faults]
    assert f"planner {plugin!r} broke rule {rule}" in proc.stdout + proc.stderr
    for cid in ("a", "b"):  # every carrier keeps within its passengers: SSAP decided those stages
        entry = next(c for c in summary["carriers"] if c["id"] == cid)
        assert len(entry["deployments"]) <= 2


def test_the_simulator_flies_a_failing_plugin_as_the_fleet_does():
    """The deterministic simulator's coordinator takes the fleet's guarded step
    (mission.decide.stage_decision): a plug-in raising at stage 2 has that stage decided by
    SSAP, the mission completes without a violation, and its stage-2 decision is SSAP's on the
    same mission state."""
    import dataclasses

    from launcher.simulate import build_fleet
    from mission import simulate as sim
    from mission.decide import stage_decision

    fleet = build_fleet(str(ROOT / "scenarios" / "tiny.yaml"), "coordinated")
    fleet = dataclasses.replace(fleet, planner=make_planner("planner_plugins:Raises"))
    s = sim.Simulation(fleet, 0)
    out = s.run()
    assert out.completed and out.violations == [], out.violations
    assert len(fleet.decisions) >= 4  # every stage decided, stage 2 by the fallback
    heard = []
    step = stage_decision(fleet.problem, s.coordinators["coordinator"].state, 2, fleet.planner, fleet.seed,
                          on_fault=heard.append)
    state = s.coordinators["coordinator"].state
    ssap = stage_decision(fleet.problem, state, 2, make_planner("ssap"), fleet.seed)
    assert [f.rule for f in heard] == ["raises"] and np.array_equal(step.deploy, ssap.deploy)
