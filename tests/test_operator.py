"""Operator mode without sockets: constraints on a stage's decision in the planner step, the
operator's actions as mission events (rules, mission.db, the recovery fold, mission.mcap's
channel) and summary.json's ``operator`` block and ``by``."""
from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from mission import events as ev
from mission import operator_rules
from mission import state as ms
from planner.advice import advise, override_gain
from planner.constraints import Constraints
from planner.online import stage_step
from planner.problem import Problem, make_view
from planner.registry import make_planner

# Carriers 0 and 1 share an overlap at stage 0; carrier 2 is on its own. One passenger each.
VALID = np.ones((3, 6), dtype=bool)
PROBLEM = Problem.build(1, VALID, [[[0, 0], [1, 0]]])
X = np.full((3, 6), np.nan)
X[:, 0] = [9, 10, 2]
NONE = np.zeros((3, 6), dtype=bool)


def test_without_constraints_the_step_is_unchanged():
    planner = make_planner("mcts-ssap", iterations=200)
    plain = stage_step(PROBLEM, X, NONE, planner, 1, 0)
    empty = stage_step(PROBLEM, X, NONE, planner, 1, 0, constraints=Constraints())
    assert plain.deploy.tolist() == empty.deploy.tolist() == [False, True, False]


def test_a_force_makes_the_planner_decide_the_rest_again():
    # MCTS recommends carrier 1 (x = 10). Forced, carrier 0 deploys; carrier 1 would now share
    # its overlap (each earning half), so the planner holds carrier 1 back for a later stage.
    planner = make_planner("mcts-ssap", iterations=400)
    assert stage_step(PROBLEM, X, NONE, planner, 1, 0).deploy.tolist() == [False, True, False]
    forced = stage_step(PROBLEM, X, NONE, planner, 1, 0, constraints=Constraints(forced={0}))
    assert forced.deploy.tolist() == [True, False, False] and forced.dropped == {}


def test_a_veto_holds_the_carrier_and_the_rest_is_decided_again():
    planner = make_planner("mcts-ssap", iterations=400)
    vetoed = stage_step(PROBLEM, X, NONE, planner, 1, 0, constraints=Constraints(vetoed={1}))
    assert not vetoed.deploy[1] and vetoed.deploy[0]  # carrier 0's 9 no longer shares the overlap


@pytest.mark.parametrize("name", ["ssap", "random", "closed-loop", "mcts-random"])
def test_every_planner_honours_the_constraints(name):
    planner = make_planner(name, **({"iterations": 50} if name.startswith("mcts") else {}))
    step = stage_step(PROBLEM, X, NONE, planner, 3, 0, constraints=Constraints(forced={2}, vetoed={1}))
    assert step.deploy[2] and not step.deploy[1]


def test_constraints_that_cannot_apply_are_dropped_with_a_reason():
    x = X.copy()
    x[2, 0] = np.nan  # carrier 2 is ∅ at stage 0: it cannot be forced
    must = np.ones((3, 6), dtype=bool)
    must[0, 1:] = False  # carrier 0's last valid stage: it must deploy, a veto would strand it
    problem = Problem.build(1, must, [[[0, 0], [1, 0]]])
    step = stage_step(problem, x, NONE, make_planner("ssap"), 1, 0, constraints=Constraints(forced={2}, vetoed={0}))
    assert step.dropped == {2: "cannot-force", 0: "must-deploy"}
    assert step.deploy[0] and not step.deploy[2]


def test_advice_names_thresholds_conflicts_and_what_was_avoided():
    view = make_view(PROBLEM, 0, X, NONE)
    advice = advise(view, np.array([False, True, False]))
    assert advice[0]["conflicts"] == [1] and advice[2]["conflicts"] == []
    assert advice[0]["wait"] == pytest.approx(advice[2]["wait"]) and 2 < advice[0]["wait"] < 9
    assert advice[0]["avoided"] and not advice[2]["avoided"]  # 9 passes its threshold, held for the conflict
    assert advice[0]["now"] == pytest.approx(9 / 2) and advice[1]["now"] == 10


def test_override_gain_estimates_cost_and_gain():
    view = make_view(PROBLEM, 0, X, NONE)
    rec = np.array([False, True, False])
    both = override_gain(view, rec, np.array([True, True, False]), np.random.default_rng(0))
    assert both < 0  # deploying both in the overlap halves both rewards: the planner says it costs
    assert override_gain(view, rec, rec, np.random.default_rng(0)) == 0.0


# --------------------------------------------------------------------------- mission events
SPEC = ms.MissionSpec.build(("a", "b"), [[True, True, True], [False, True, True]], (2, 1), (0.0, 5.0, 10.0), "fp")
READY = [ev.Opened(0.0), ev.LivelinessChanged("a", True, 1.0), ev.LivelinessChanged("b", True, 1.0),
         ev.Hello("a", 1, "h", 2, 0, "fp", 1.0), ev.Hello("b", 1, "h", 1, 0, "fp", 1.0)]


def act(j, action, carrier=None, who="console"):
    return ev.OperatorAction(j, action, carrier, who, 2.0)


def run(events):
    state, effects = ms.initial(SPEC), ()
    for e in events:
        state, effects = ms.step(state, e)
    return state, effects


ACTION_CASES = [
    # id, events before, the action, rejection reason (None = accepted)
    ("force", [], act(0, "force", "a"), None),
    ("veto", [], act(1, "veto", "a"), "future-stage"),
    ("approve", [], act(0, "approve"), None),
    ("stale", [ev.Decided(0, (), 1.0, 2.0)], act(0, "veto", "a"), "stale-stage"),
    ("unknown", [], act(0, "force", "z"), "unknown-carrier"),
    ("not-scheduled", [], act(0, "force", "b"), "not-scheduled"),
    ("bad-action", [], act(0, "launch", "a"), "out-of-range"),
    ("void", [ev.Observation("a", 0, 0.0, None, (0.0, 0.0), 2)], act(0, "force", "a"), "cannot-force"),
    ("must-deploy", [ev.Decided(0, (), 1.0, 2.0)], act(1, "veto", "b"), None),
    ("must-deploy-last", [ev.Decided(0, (), 1.0, 2.0), ev.Decided(1, (), 1.0, 2.0)], act(2, "veto", "b"),
     "must-deploy"),
    ("ended", [ev.Ended("complete", 3.0)], act(0, "approve"), "stale-stage"),
]


@pytest.mark.parametrize("before, action, reason", [c[1:] for c in ACTION_CASES], ids=[c[0] for c in ACTION_CASES])
def test_operator_action_rules(before, action, reason):
    state, effects = run(READY + before + [action])
    got = [e.reason for e in effects if isinstance(e, ms.Reject)]
    assert got == ([] if reason is None else [reason])
    assert (action in state.operator_actions.get(action.stage, ())) == (reason is None)


def test_the_latest_action_per_carrier_stands():
    state, _ = run(READY + [act(0, "force", "a"), act(0, "veto", "a"), act(0, "approve")])
    assert operator_rules.constraints(state.operator_actions[0]) == ((), ("a",), True)


def _operator_mission():
    return READY + [
        ev.Observation("a", 0, 0.0, 5, (1.0, 2.0), 2), act(0, "force", "a"), act(0, "approve"),
        ev.Decided(0, ("a",), 2.0, 2.5, (), (), ("a",), (), "approved", -0.25), ev.Published(0, 2.6),
        ev.Confirmed("a", 0, True, "deployed", (1.0, 2.0), 1, 2.7),
        ev.Observation("a", 1, 5.0, 7, (1.0, 3.0), 1), ev.Observation("b", 1, 5.0, 8, (2.0, 3.0), 1),
        act(1, "veto", "a", "ops-1"),
        ev.Decided(1, ("b",), 2.0, 3.5, (), ("a", "b"), (), ("a",), "timeout", 0.5), ev.Published(1, 3.6),
        ev.Confirmed("b", 1, True, "deployed", (2.0, 3.0), 0, 3.7),
        ev.Observation("a", 2, 10.0, 1, (1.0, 4.0), 1),
        ev.Decided(2, ("a",), 2.0, 4.5, (), None, (), (), "approved", 0.0), ev.Published(2, 4.6),
        ev.Confirmed("a", 2, True, "deployed", (1.0, 4.0), 0, 4.7), ev.Ended("complete", 5.0),
    ]


def test_operator_events_are_stored_replayed_and_summarised(tmp_path):
    from mission.summary import RunInfo, summary
    from storage.missiondb import MissionStore, load_events

    store = MissionStore(tmp_path / "mission.db", {"mission": "m"})
    live_state = ms.fold(SPEC, store.mission_events())
    for e in _operator_mission()[1:]:  # the store's own open stands for READY's
        live_state, effects = ms.step(live_state, e)
        for effect in effects:
            if isinstance(effect, ms.Record):
                store.record(effect, live_state)
    store.close()
    replayed = ms.fold(SPEC, load_events(tmp_path / "mission.db"))
    assert replayed == live_state
    assert replayed.decisions[1].vetoed == ("a",) and replayed.decisions[1].recommended == ("a", "b")
    assert [a.operator for a in replayed.operator_actions[1]] == ["ops-1"]

    problem = Problem.build(np.array(SPEC.passengers), np.array(SPEC.valid), [], stats.poisson(3.0))
    out = summary(replayed, problem, RunInfo("m", "m.yaml", "m", "ssap", {}, 7), bound=False)
    by = {(c["id"], d["stage"]): d["by"] for c in out["carriers"] for d in c["deployments"]}
    assert by == {("a", 0): "operator", ("b", 1): "coordinator", ("a", 2): "coordinator"}
    block = out["operator"]
    assert (block["approvals"], block["vetoes"], block["forces"], block["timeouts"]) == (2, 1, 1, 1)
    assert [o["stage"] for o in block["overrides"]] == [0, 1]
    assert block["estimated_gain_total"] == pytest.approx(0.25)
    assert len(block["actions"]) == 3


def test_a_mission_without_operator_has_no_operator_block():
    from mission.summary import RunInfo, summary

    state, _ = run(READY + [ev.Decided(0, (), 1.0, 2.0)])
    problem = Problem.build(np.array(SPEC.passengers), np.array(SPEC.valid), [], stats.poisson(3.0))
    assert "operator" not in summary(state, problem, RunInfo("m", "m.yaml", "m", "ssap", {}, 7), bound=False)


def test_the_operator_channel_in_mission_mcap():
    from recording.stream import Clock, Sink, feed_event

    class Keep(Sink):
        def __init__(self):
            self.got = []

        def operator(self, t, record):
            self.got.append((t, record))

    sink, clock = Keep(), Clock(SPEC.stage_times)
    for e in _operator_mission():
        feed_event(sink, e, clock)
    kinds = [(r["kind"], r["stage"]) for _, r in sink.got]
    assert kinds == [("action", 0), ("action", 0), ("decision", 0), ("action", 1), ("decision", 1), ("decision", 2)]
    assert sink.got[4][1]["vetoed"] == ["a"] and sink.got[4][1]["hold"] == "timeout"


# --------------------------------------------------------------------------- the experiment's operators
@pytest.mark.parametrize("seed", [0, 1])
def test_the_autonomous_operator_is_the_online_loop(seed):
    """The experiment's loop with an operator who never overrules decides exactly as run_online
    (two instance families drawn from the seed: no overlaps, many)."""
    from experiments.operator import run_with_operator
    from planner.instance import random_instance
    from planner.online import run_online

    for overlaps in (0, 12):
        inst = random_instance(np.random.default_rng(seed), 4, 2, 8, overlaps, 3.0)
        planner = make_planner("mcts-ssap", iterations=100)
        alone = run_online(inst.problem, inst.observations, planner, seed)
        out = run_with_operator(inst.problem, inst.observations, planner, seed, "autonomous")
        assert out["reward"] == pytest.approx(alone.reward) and out["overrides"] == 0


def test_a_manual_trigger_operator_replaces_the_planner():
    """manual-trigger deploys exactly where the count reaches the prior's 75th percentile or the
    carrier must: the planner's own choice does not show through the constraints."""
    from experiments.operator import operator_constraints

    view = make_view(PROBLEM, 0, X, NONE)
    c = operator_constraints("manual-trigger", view, np.array([False, True, False]), np.random.default_rng(0))
    high = PROBLEM.prior.ppf(0.75)
    assert c.forced == {r for r in range(3) if X[r, 0] >= high} and c.vetoed == set(range(3)) - c.forced
    step = stage_step(PROBLEM, X, NONE, make_planner("mcts-ssap", iterations=50), 1, 0, constraints=c)
    assert set(np.flatnonzero(step.deploy)) == c.forced


@pytest.mark.slow
@pytest.mark.parametrize("family", ["rooms", "caves"])
def test_the_experiment_measures_a_run_imported_from_a_bag(tmp_path, family):
    """`python -m experiments operator --scenario NAME=S.yaml` measures a run as a team brings it (a
    ROS 2 bag of a generated floor plan, two families, imported by `python -m world import`) beside
    the paper's worlds: a row per operator, the autonomous one keeping 100 %, the table naming the
    scenario so the run can be repeated."""
    import csv
    import subprocess
    import sys

    from experiments.operator import main
    from tools.synthetic_run import generate, write_bag

    topics = write_bag(generate(240, 160, 0.1, carriers=2, snapshots=4, seed=3, family=family), tmp_path / "bag")
    odom = [a for cid, topic in topics.items() for a in ("--odom", f"{cid}={topic}")]
    scenario = tmp_path / "run.yaml"
    subprocess.run([sys.executable, "-m", "world", "import", str(tmp_path / "bag"), *odom, "--passengers", "c0=2",
                    "--passengers", "c1=2", "--stages", "6", "--radius", "4", "--replay", "--out", str(scenario)],
                   check=True, capture_output=True, cwd=tmp_path)
    out = tmp_path / "op"
    assert main(["--quick", "--scenario", f"{family}={scenario}", "--only-scenarios", "--out", str(out)]) == 0
    rows = [r for r in csv.DictReader(open(out / "operator_summary.csv")) if r["world"] == family]
    assert [r["operator"] for r in rows] == ["autonomous", "manual-trigger", "random-veto", "force-high"]
    assert float(rows[0]["kept"]) == 1.0 and float(rows[0]["reward"]) > 0 and all(r["trials"] == "2" for r in rows)
    assert f"--scenario {family}={scenario} --only-scenarios" in (out / "operator.md").read_text()
    assert {r["world"] for r in csv.DictReader(open(out / "operator_summary.csv"))} == {family}


@pytest.mark.parametrize("given, named", [("missing.yaml", "missing.yaml"), ("urban=scenarios/tiny.yaml", "urban"),
                                          ("overlap=scenarios/tiny.yaml", "overlap"), (None, "--only-scenarios")])
def test_the_experiment_refuses_a_scenario_in_one_line(given, named, capsys):
    from experiments.operator import main

    with pytest.raises(SystemExit) as e:
        main(["--quick", "--scenario", given] if given else ["--quick", "--only-scenarios"])
    err = capsys.readouterr().err.strip().splitlines()
    assert e.value.code == 2 and len(err) == 1 and named in err[0] and "expected" in err[0], err


# --------------------------------------------------------------------------- the page's server
def test_the_console_off_loopback_needs_tls_and_the_credential(tmp_path):
    """Served over HTTPS (a certificate from tools/gen_certs.py), every request needs HTTP basic
    authentication with the mission's operator credential; an action's answer says why it was
    refused; a port in use is refused in one line."""
    import base64
    import json
    import ssl
    import urllib.error
    import urllib.request

    import world
    from console.desk import Desk, new_token
    from console.hold import OperatorSettings
    from console.server import ConsoleServer, ConsoleUnavailable
    from console.view import ConsoleView
    from fleet_helpers import TINY
    from tools import gen_certs
    from world.scene import build_scene

    scenario = world.load_scenario(TINY)
    state = ms.initial(ms.MissionSpec.build(scenario.carrier_ids, world.build_problem(scenario).valid,
                                            [c.passengers for c in scenario.carriers], scenario.stage_times(), "fp"))
    ca = gen_certs.make_ca(tmp_path)
    cert = gen_certs.issue(ca, tmp_path, "console", "console", ("127.0.0.1",))
    settings = OperatorSettings(0, 5.0, tls=(str(cert.cert), str(cert.key)))
    token = new_token(tmp_path)
    assert (tmp_path / "operator.token").stat().st_mode & 0o077 == 0  # the owner's only
    view = ConsoleView(build_scene(scenario), world.build_problem(scenario), "tiny", "mcts-ssap", settings)
    server = ConsoleServer(Desk(lambda: state, token, view), view, settings)
    context = ssl.create_default_context(cafile=str(ca.cert))
    try:
        url = f"https://127.0.0.1:{server.port}"

        def ask(path, password=None, body=None):
            headers = {"Content-Type": "application/json"}
            if password is not None:
                headers["Authorization"] = "Basic " + base64.b64encode(f"operator:{password}".encode()).decode()
            req = urllib.request.Request(url + path, None if body is None else json.dumps(body).encode(), headers)
            try:
                with urllib.request.urlopen(req, context=context, timeout=10) as r:
                    return r.status, r.read()
            except urllib.error.HTTPError as exc:
                return exc.code, exc.read()

        assert ask("/")[0] == 401 and ask("/", "wrong")[0] == 401
        status, page = ask("/", token)
        assert status == 200 and b"Approve" in page
        assert json.loads(ask("/map.json", token)[1])["name"] == "tiny"
        assert ask("/action", "wrong", {"stage": 0, "action": "approve"})[0] == 401
        answer = json.loads(ask("/action", token, {"stage": 3, "action": "veto", "carrier": "a"})[1])
        assert answer["accepted"] is False and answer["reason"] == "future-stage"
        with pytest.raises(ConsoleUnavailable, match="cannot serve the console"):
            ConsoleServer(Desk(lambda: state, token, view), view, OperatorSettings(server.port, 5.0, bind="127.0.0.1"))
    finally:
        server.close()
    with pytest.raises(ValueError, match="TLS"):
        ConsoleServer(Desk(lambda: state, token, view), view, OperatorSettings(0, 5.0, bind="0.0.0.0"))


# --------------------------------------------------------------------------- the deterministic simulator
def test_a_scheduled_simulated_operator_in_the_deterministic_simulator():
    """A simulated operator's schedule flies in the deterministic simulator like the console's
    actions on the real fleet: its actions are mission events on the coordinator's disk (so a
    crashed coordinator replays them), the decisions follow the constraints, the invariants hold,
    and the same seed gives the same trace."""
    import dataclasses

    from launcher.simulate import build_fleet
    from mission import simulate as sim
    from fleet_helpers import TINY

    fleet = build_fleet(TINY)
    plain = fleet.offline()
    first = next(j for j in sorted(plain) if plain[j])
    cid = plain[first][0]
    overruled = dataclasses.replace(fleet, decisions={}, operator=((first, "veto", cid), (first, "approve", None)))
    offline = overruled.offline()
    assert cid not in offline[first]
    for seed in range(2):
        s = sim.Simulation(overruled, seed, kinds=())
        out = s.run()
        assert out.violations == [] and out.completed
        final = s.coordinators["coordinator"].state
        assert {j: d.deploy for j, d in final.decisions.items()} == offline
        assert final.decisions[first].vetoed == (cid,) and final.decisions[first].hold == "approved"
        assert [(a.action, a.carrier) for a in final.operator_actions[first]] == [("veto", cid), ("approve", None)]
    a, b = sim.simulate(overruled, 5), sim.simulate(overruled, 5)
    assert a.trace_hash == b.trace_hash and a.violations == []
    # faults too: the campaign's invariants hold with the operator's schedule
    assert all(sim.simulate(overruled, seed).violations == [] for seed in range(6, 12))
