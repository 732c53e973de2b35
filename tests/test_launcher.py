"""The launcher as a package: its flags written back into a command line (every flag), the
children's command lines parsed back to the settings they came from, validation that leaves the
parsed flags alone and says every problem in one line, bundled scenarios, run_fleet.py as a shim
that still runs a mission, and the marsupial-fleet command's subcommands."""
from __future__ import annotations

import argparse
import ast
import copy
import json
import subprocess
import sys
from dataclasses import FrozenInstanceError
from pathlib import Path

import pytest

import scenarios
import world
from launcher import cli, supervisor
from launcher.flags import build_parser, defaults, flags_of, flags_type, parse_args, to_argv
from launcher.settings import check, load_scenario, resolve_scenario
from mission.exits import EXIT_DEPOSED, EXIT_USAGE

ROOT = Path(__file__).resolve().parents[1]
TINY = ROOT / "scenarios" / "tiny.yaml"


@pytest.fixture(scope="module")
def tiny():
    return world.load_scenario(TINY)


def _actions():
    return [a for a in build_parser()._actions if not isinstance(a, argparse._HelpAction)]


def _other_value(action: argparse.Action):
    """A value of ``action`` that is not its default (one that reads as a flag where it can, to
    try the ``--flag=value`` spelling)."""
    if isinstance(action, argparse._StoreTrueAction):
        return True
    if isinstance(action, argparse._AppendAction):
        return ("tcp/127.0.0.1:7447", "-x=1")
    if action.choices:
        return next(c for c in action.choices if c != action.default)
    if isinstance(action.nargs, int):
        return tuple(-2.5 + k for k in range(action.nargs))
    if action.type is int:
        return 7 if action.default != 7 else 8
    if action.type is float:
        return -2.5 if action.default != -2.5 else 2.5
    return "-odd value" if action.option_strings else "some/scenario.yaml"


def test_every_flag_is_written_back_as_given():
    """to_argv inverts the parser for every flag, one at a time and all at once."""
    assert len(_actions()) > 40  # the parser is the whole command line
    everything = {}
    for action in _actions():
        value = _other_value(action)
        everything[action.dest] = value
        flags = defaults()._replace(**{action.dest: value})
        assert flags_of(parse_args(to_argv(flags))) == flags, action.dest
    flags = defaults()._replace(**everything)
    assert flags_of(parse_args(to_argv(flags))) == flags
    assert to_argv(defaults()) == []  # a default is never written out


def test_excluded_flags_are_flags():
    """The supervisor's lists name real flags (a renamed flag cannot slip out of them)."""
    fields = set(flags_type()._fields)
    named = set(supervisor.ROUTER_TAKES).union(*supervisor.EXCLUDED.values())
    assert named <= fields, named - fields


@pytest.mark.parametrize("role", ["coordinator", "carrier", "viewer", "report", "router"])
def test_a_childs_command_line_parses_back_to_its_settings(tiny, role):
    """Each child of the one-host launcher parses its command line back to exactly the settings
    it was given: every flag the role takes with the launcher's value, the others at their
    defaults; and the child's own check accepts them."""
    argv = [str(TINY), "--seed", "4", "--realtime", "1.5", "--clock", "wall", "--planner", "ssap",
            "--planner-option", "iterations=30", "--mission", "m-1", "--no-record", "--no-map",
            "--join-timeout", "7", "--stage-timeout", "9.25", "--pose-interval", "2", "--linger", "-1",
            "--zenoh-config", str(ROOT / "config" / "coordinator.json5"), "--onboard-load", "need",
            "--mcap-profile", "foxglove", "--web-port", "9191", "--save", "v.rrd", "--carrier-processes", "2",
            "--verbose", "--log-sync", "full", "--silence-timeout", "33"]
    settings, problems = check(parse_args(argv), tiny)
    assert problems == []
    given = {"coordinator": {"connect": ["tcp/127.0.0.1:1"]}, "carrier": {"carrier": "a,b", "quiet": True},
             "viewer": {"ready_file": "/tmp/r"}, "report": {"out": "runs/x"}, "router": {"listen": ["tcp/127.0.0.1:2"]}}
    child = supervisor.child_argv(settings.flags, role, **given[role])
    assert child[:2] == ["-m", "launcher"] and child[child.index("--role") + 1] == role
    expected = supervisor.child_flags(settings.flags, role, **given[role])
    assert flags_of(parse_args(child[2:])) == expected
    for name in flags_type()._fields:
        taken = name in supervisor.ROUTER_TAKES if role == "router" else name not in supervisor.EXCLUDED[role]
        if taken and name not in given[role] and name != "role":
            assert getattr(expected, name) == getattr(settings.flags, name), name
    if role != "router":
        again, problems = check(parse_args(child[2:]), tiny)
        assert problems == [] and again.planner_options == settings.planner_options


def test_check_leaves_the_parsed_flags_alone(tiny, monkeypatch):
    """Validation derives the carrier ids, the planner options and the ROS domain into the
    settings, which are frozen; the namespace it read is unchanged."""
    monkeypatch.setenv("ROS_DOMAIN_ID", "5")
    args = parse_args([str(TINY), "--role", "carrier", "--carrier", "b, a", "--ros2",
                       "--planner-option", "layout=binary"])
    before = copy.deepcopy(vars(args))
    settings, problems = check(args, tiny)
    assert problems == [] and vars(args) == before
    assert settings.carriers == ("b", "a") and settings.planner_options == (("layout", "binary"),)
    assert settings.flags.ros2_domain == 5 and args.ros2_domain is None
    with pytest.raises(FrozenInstanceError):
        settings.carriers = ()
    with pytest.raises(AttributeError):
        settings.flags.seed = 3


def test_every_problem_is_one_line_naming_the_flag(tiny):
    args = parse_args([str(TINY), "--realtime", "-1", "--seed", "-2", "--routers", "-1", "--standby",
                       "--planner-option", "layout=tree"])
    settings, problems = check(args, tiny)
    assert settings is None
    assert [p.line() for p in problems] == [
        "--realtime: expected a factor >= 0, found -1.0",
        "--seed: expected an integer >= 0, found -2",
        "--routers: expected an integer >= 0, found -1",
        "--planner-option: layout: expected one of auto, joint, binary, found 'tree'",
        "--standby: expected --role coordinator, found --role all"]
    assert [p.field for p in problems] == ["--realtime", "--seed", "--routers", "--planner-option", "--standby"]


def test_planner_options_are_those_of_the_planner_in_force(tiny):
    """A plug-in's own option is taken for that plug-in (by --planner), refused naming the plug-in
    when out of range, and refused for a built-in planner that has no such option."""
    plugin = ["--planner", "planner_plugins:Threshold"]
    settings, problems = check(parse_args([str(TINY), *plugin, "--planner-option", "cut=4.5"]), tiny)
    assert problems == [] and settings.planner_options == (("cut", 4.5),)
    _, problems = check(parse_args([str(TINY), *plugin, "--planner-option", "cut=-1"]), tiny)
    assert [p.line() for p in problems] == [
        "--planner-option: cut: expected a number >= 0 (an option of planner 'planner_plugins:Threshold'), found '-1'"]
    _, problems = check(parse_args([str(TINY), "--planner", "ssap", "--planner-option", "cut=4.5"]), tiny)
    assert len(problems) == 1 and problems[0].field == "--planner-option" and "cut=4.5" in problems[0].line()
    _, problems = check(parse_args([str(TINY), "--planner", "nope", "--planner-option", "layout=joint"]), tiny)
    assert [p.field for p in problems] == ["--planner"]


def test_bad_flags_get_one_line_each_and_exit_2(tmp_path):
    proc = subprocess.run([sys.executable, str(ROOT / "run_fleet.py"), "tiny", "--seed", "-1", "--iterations", "0"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert proc.returncode == EXIT_USAGE and proc.stdout == ""
    assert proc.stderr.splitlines() == ["run_fleet.py: --iterations: expected an integer >= 1 and <= 1e+09, found 0",
                                        "run_fleet.py: --seed: expected an integer >= 0, found -1"]


def test_exit_statuses_keep_their_values():
    assert (EXIT_USAGE, EXIT_DEPOSED) == (2, 3)


def test_bundled_scenarios_are_the_scenario_files_and_load():
    names = scenarios.bundled_names()
    assert names == tuple(sorted(p.stem for p in (ROOT / "scenarios").glob("*.yaml")))
    assert "six_carriers" in names
    for name in names:
        path = scenarios.bundled_path(name)
        assert path == scenarios.bundled_path(name + ".yaml") and path.is_file()
        world.load_scenario(path)  # every file it names is there too
    assert scenarios.bundled_path("nope") is None


def test_a_scenario_is_a_file_or_a_bundled_name(tmp_path):
    assert resolve_scenario("six_carriers") == (str(scenarios.bundled_path("six_carriers")), None)
    assert resolve_scenario(str(TINY)) == (str(TINY), None)
    path, line = resolve_scenario("sixcarriers")
    assert path is None and line == ("sixcarriers: expected a scenario file or the name of a bundled scenario "
                                     f"({', '.join(scenarios.bundled_names())}), found neither")
    scenario, lines = load_scenario(str(tmp_path / "missing.yaml"))  # a path: the loader's own line
    assert scenario is None and lines == [f"{tmp_path / 'missing.yaml'}: expected an existing scenario file, found no such file"]
    proc = subprocess.run([sys.executable, str(ROOT / "run_fleet.py"), "sixcarriers"], cwd=tmp_path,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == EXIT_USAGE and proc.stderr.splitlines() == [line]


def test_run_fleet_py_is_a_shim():
    """run_fleet.py imports launcher.main and nothing else of the project; its --help is the
    launcher's."""
    tree = ast.parse((ROOT / "run_fleet.py").read_text())
    imported = {node.module for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)}
    imported |= {alias.name for node in ast.walk(tree) if isinstance(node, ast.Import) for alias in node.names}
    assert imported == {"sys", "pathlib", "launcher.main"}
    shown = subprocess.run([sys.executable, str(ROOT / "run_fleet.py"), "--help"], capture_output=True, text=True,
                           timeout=60, cwd="/")
    assert shown.returncode == 0 and shown.stdout == build_parser().format_help()


@pytest.mark.slow
def test_run_fleet_py_runs_a_mission_from_another_directory(tmp_path):
    """python /clone/run_fleet.py from elsewhere: the children (python -m launcher) find the
    clone's packages, the default --out is under the current directory, and the report leaves
    summary.json with every carrier of the scenario."""
    proc = subprocess.run([sys.executable, str(ROOT / "run_fleet.py"), "tiny", "--no-map", "--no-record",
                           "--planner", "ssap"], cwd=tmp_path, capture_output=True, text=True, timeout=240)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stdout.splitlines()[0].startswith("run_fleet.py: network tcp/127.0.0.1:")
    [summary] = list((tmp_path / "runs").glob("tiny-*/summary.json"))
    assert [c["id"] for c in json.loads(summary.read_text())["carriers"]] == ["a", "b"]


# ------------------------------------------------------------------------- marsupial-fleet


def test_the_command_lists_its_subcommands(capsys):
    assert cli.main(["--help"]) == 0
    shown = capsys.readouterr().out
    for name in ("run", "solve", "world", "experiments", "record", "conformance"):
        assert f"\n    {name}" in shown
    assert cli.main([]) == EXIT_USAGE  # nothing to do: the help, on stdout, and status 2
    assert cli.main(["fly"]) == EXIT_USAGE
    assert capsys.readouterr().err.splitlines() == [
        "marsupial-fleet: expected a command (run, solve, world, experiments, record, conformance), found 'fly'"]


def test_run_help_is_the_launchers(capsys):
    with pytest.raises(SystemExit) as done:
        cli.main(["run", "--help"])
    assert done.value.code == 0
    assert capsys.readouterr().out == build_parser("marsupial-fleet run").format_help()


def test_run_names_itself_and_passes_its_name_to_the_children(tmp_path):
    proc = subprocess.run([sys.executable, "-c", "import sys; from launcher.cli import main; sys.exit(main())",
                           "run", "tiny", "--seed", "-1"], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert proc.returncode == EXIT_USAGE
    assert proc.stderr.splitlines() == ["marsupial-fleet: --seed: expected an integer >= 0, found -1"]
    settings, _ = check(parse_args(["tiny"], name="marsupial-fleet"), world.load_scenario(TINY))
    child = supervisor.child_argv(settings.flags, "carrier", carrier="a")
    assert child[child.index("--name") + 1] == "marsupial-fleet"


def test_solve_world_and_record_hand_over_their_arguments(tmp_path, capsys):
    from planner.instance import instance_dict, random_instance
    import numpy as np

    path = tmp_path / "i.json"
    path.write_text(json.dumps(instance_dict(random_instance(np.random.default_rng(0), carriers=2, passengers=1,
                                                             stages=4, overlaps=1))))
    assert cli.main(["solve", str(path), "--planner", "ssap", "--no-clairvoyant"]) == 0
    assert "reward" in capsys.readouterr().out
    assert cli.main(["world", "check", str(scenarios.bundled_path("tiny")), "--seeds", "5"]) == 0
    assert "tiny" in capsys.readouterr().out
    assert cli.main(["record", "rebuild", str(tmp_path / "nowhere")]) == EXIT_USAGE
    assert len(capsys.readouterr().err.splitlines()) == 1


def test_conformance_needs_a_kit(capsys):
    assert cli.main(["conformance"]) == EXIT_USAGE
    assert cli.main(["conformance", "plane"]) == EXIT_USAGE
    assert capsys.readouterr().err.splitlines() == [
        "marsupial-fleet conformance: expected a kit (carrier, coordinator, planner), found nothing",
        "marsupial-fleet conformance: expected a kit (carrier, coordinator, planner) (did you mean 'planner'?), "
        "found 'plane'"]
    assert cli.main(["conformance", "carrier", "S.yaml"]) == EXIT_USAGE  # the kit's own usage line
    assert "python -m wire.conformance" in capsys.readouterr().err
    # The carrier kit is the default: its arguments may come first, as for python -m wire.conformance.
    assert cli.main(["conformance", "S.yaml"]) == EXIT_USAGE
    assert "python -m wire.conformance" in capsys.readouterr().err
    assert cli.main(["conformance", "coordinator"]) == EXIT_USAGE
    assert capsys.readouterr().err.splitlines()[-1] == (
        "marsupial-fleet conformance coordinator: error: no COMMAND after -- (the coordinator under test)")


def test_conformance_planner_runs_the_planner_kit(capsys):
    assert cli.main(["conformance", "planner", "ssap", "--instances", "1"]) == 0
    assert capsys.readouterr().out.splitlines()[-1].startswith("planner 'ssap': conformant")
    assert cli.main(["conformance", "planner", "nope:X"]) == EXIT_USAGE
    assert capsys.readouterr().err.splitlines() == [
        "marsupial-fleet conformance planner: error: PLANNER: planner 'nope:X': cannot import nope: "
        "ModuleNotFoundError: No module named 'nope'"]


def test_python_m_launcher_is_the_launcher():
    shown = subprocess.run([sys.executable, "-m", "launcher", "--help"], capture_output=True, text=True,
                           timeout=60, cwd=ROOT)
    assert shown.returncode == 0 and shown.stdout == build_parser("python -m launcher").format_help()


def test_out_naming_a_file_is_one_line(tmp_path):
    """--out must be a directory: naming a file (or a path under one) is one line and exit 2,
    before any process starts (it was a FileExistsError traceback)."""
    (tmp_path / "notes.txt").write_text("mine\n")
    for out in ("notes.txt", "notes.txt/run"):
        proc = subprocess.run([sys.executable, str(ROOT / "run_fleet.py"), "tiny", "--out", out],
                              cwd=tmp_path, capture_output=True, text=True, timeout=120)
        assert proc.returncode == EXIT_USAGE and "Traceback" not in proc.stderr, proc.stderr
        assert proc.stderr.splitlines() == [
            f"run_fleet.py: --out: expected a results directory (existing or new), found "
            + ("the file 'notes.txt'" if out == "notes.txt" else "'notes.txt/run' under the file 'notes.txt'")]
    assert (tmp_path / "notes.txt").read_text() == "mine\n"


def test_a_viewer_without_its_web_view_does_not_linger():
    from launcher.roles import viewer_linger

    assert viewer_linger(flags_of(parse_args([str(TINY), "--view", "--no-web", "--save", "x.rrd"]))) == 0.0
    assert viewer_linger(flags_of(parse_args([str(TINY), "--view"]))) < 0  # the web view: until Ctrl-C, said
    assert viewer_linger(flags_of(parse_args([str(TINY), "--view", "--linger", "5"]))) == 5.0


@pytest.mark.slow
def test_the_headless_viewer_exits_with_the_mission(tmp_path):
    """``--view --no-web --save FILE.rrd`` writes the file and the launcher exits (it waited for
    Ctrl-C, silently)."""
    pytest.importorskip("rerun")
    proc = subprocess.run([sys.executable, str(ROOT / "run_fleet.py"), "tiny", "--view", "--no-web", "--save",
                           "six.rrd", "--out", "run"], cwd=tmp_path, capture_output=True, text=True, timeout=240)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert (tmp_path / "six.rrd").stat().st_size > 10_000 and "results:" in proc.stdout


def test_a_near_miss_gets_a_did_you_mean(tiny, tmp_path):
    _, problems = check(parse_args([str(TINY), "--planner-option", "layut=binary"]), tiny)
    assert [p.field for p in problems] == ["--planner-option"] and "(did you mean 'layout'?)" in problems[0].line()
    _, problems = check(parse_args([str(TINY), "--planner", "mcts-sap"]), tiny)
    assert "(did you mean 'mcts-ssap'?)" in problems[0].line()
    proc = subprocess.run([sys.executable, str(ROOT / "run_fleet.py"), "tiny", "--plannr", "ssap"], cwd=tmp_path,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == EXIT_USAGE and "(did you mean '--planner'?)" in proc.stderr
    assert "plug-in" in build_parser().format_help()  # --planner's help names the plug-ins


def test_a_plugin_that_fails_to_import_exits_2_with_one_line(tmp_path):
    (tmp_path / "broken_plugin.py").write_text("import no_such_module_here\n")
    proc = subprocess.run([sys.executable, str(ROOT / "run_fleet.py"), "tiny", "--planner", "broken_plugin:F"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=120,
                          env={**__import__("os").environ, "PYTHONPATH": f"{tmp_path}:{ROOT}"})
    assert proc.returncode == EXIT_USAGE and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert "cannot import broken_plugin" in proc.stderr


def test_a_mission_over_acoustic_links_says_it_takes_minutes_and_the_fast_way(tiny):
    from launcher.supervisor import slow_links_note

    marine = world.load_scenario(ROOT / "scenarios" / "marine_survey.yaml")
    settings, problems = check(parse_args([str(ROOT / "scenarios" / "marine_survey.yaml")]), marine)
    assert not problems
    note = slow_links_note(settings)
    assert note and "minutes" in note and "python -m mission.simulate" in note and "marine_survey.yaml" in note
    plain, _ = check(parse_args([str(TINY)]), tiny)
    assert slow_links_note(plain) is None
