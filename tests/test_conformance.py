"""The conformance kits (python -m wire.conformance): the project's own carrier and a carrier of
revision 1 written from its page pass every rule, through the kit's faults (a late Decision, a
duplicate, a coordinator restart, a deposed Decision); carriers broken on purpose fail on the
rule they break. The coordinator kit (python -m wire.conformance coordinator) passes the
project's coordinator and fails the project's coordinator with one rule broken
(tests/broken_coordinator.py) on that rule. The flights start real processes; those with the
project's coordinator restarted, or waiting out timeouts, are slow; the flights with the kit's own
coordinator take seconds and run by default; the rule evaluation itself is checked fast on
recorded flights."""
from __future__ import annotations

import subprocess
import sys

import msgpack
import pytest

import world
from fleet_helpers import ROOT, TINY, sensed_world_file
from wire import conformance as wc
from wire import messages as wm
from wire.conformance.rules import CROSSING_S

CLIENT = ROOT / "tests" / "revision1_carrier.py"
BROKEN_COORDINATOR = ROOT / "tests" / "broken_coordinator.py"
COORDINATOR_FLAGS = ["{scenario}", "--role", "coordinator", "--connect", "{endpoint}", "--mission", "{mission}",
                     "--seed", "{seed}", "--out", "{workdir}", "--no-map", "--no-record", "--join-timeout", "3",
                     "--silence-timeout", "2", "--stage-timeout", "2", "--realtime", "0"]
PROJECT_COORDINATOR = [sys.executable, "-m", "launcher", *COORDINATOR_FLAGS]
PROJECT_CARRIER = [sys.executable, str(ROOT / "run_fleet.py"), "{scenario}", "--role", "carrier", "--carrier",
                   "{carrier}", "--connect", "{endpoint}", "--seed", "{seed}", "--mission", "{mission}",
                   "--no-autonomy", "--out", "{workdir}"]


def _client(tmp_path, fault=None, *extra) -> list[str]:
    tiny = world.load_scenario(TINY)
    path = sensed_world_file(tiny, world.simulate_mission(tiny), tiny.carrier_index("a"), tmp_path / "a.json")
    return [sys.executable, str(CLIENT), "--endpoint", "{endpoint}", "--mission", "{mission}", "--carrier",
            "{carrier}", "--world", str(path), *(["--fault", fault] if fault else []), *extra]


#: The rules only the kit's own coordinators exercise (flights other than project).
SCRIPTED_ONLY = {"two-coordinators", "two-ballots", "deposed-end", "refusal", "older-revision", "decision-gap", "hello-again"}
#: The rules a revision-1 carrier is never exercised on (no Accepted, no passengers named, no Progress).
LATER_REVISIONS = {"accepted", "passenger-named", "progress"}


def _statuses(results) -> dict:
    return {r.rule: r.status for r in results}


# --------------------------------------------------------------------------- fast: the rules on recorded flights

def _kit(tmp_path) -> wc.Kit:
    return wc.Kit(str(TINY), "a", ["true"], workdir=str(tmp_path), log=lambda line: None)


def _seen(at, message, fake=False) -> wc.Seen:
    return wc.Seen(at, type(message).TYPE, wm.encode(message), message, fake=fake)


def test_the_rules_on_a_recorded_flight(tmp_path):
    """A hand-made flight of tiny's carrier a: clean, then with a future Observation, a missing
    Confirm and an unknown field; each fault fails its own rule and only it."""
    kit = _kit(tmp_path)
    t = kit.target
    m, fp, x = t.mission, t.fingerprint, t.x

    def obs(j, at):
        value = None if not t.valid[j] else int(x[j])
        return _seen(at, wm.Observation(m, "a", j, t.times[j], value, (0.0, 0.0), 2, ()))

    def clean():
        f = wc.Flight()
        f.carrier.append(_seen(0.0, wm.Hello(m, "a", 1, "h", 2, 0, fp)))
        for j in range(t.n):
            f.carrier.append(obs(j, 1.0 + j))
            f.decisions.append(_seen(1.5 + j, wm.Decision(m, j, t.times[j], (), 1.0)))
            f.carrier.append(_seen(1.6 + j, wm.Confirm(m, "a", j, False, "idle", (0.0, 0.0), 2)))
        f.ends.append(wc.Seen(9.0, "end", b""))
        f.carrier.append(_seen(9.1, wm.Bye(m, "a", (), (), "end")))
        f.exit_code = 0
        return f

    kit.flight = clean()
    results = _statuses(kit.evaluate())
    assert {r for r, s in results.items() if s == "FAIL"} == set()
    assert results["confirm"] == results["observation-world"] == results["bye"] == "pass"

    kit.flight = clean()
    kit.flight.carrier.insert(2, obs(2, 1.05))  # stage 2 while stage 0 is collected
    assert {r for r, s in _statuses(kit.evaluate()).items() if s == "FAIL"} == {"observation-stage"}

    j0 = next(j for j in range(t.n) if t.valid[j])  # a stage it observes
    kit.flight = clean()  # its repeat crossed Decision j0 on the way: sent before it could hear it
    kit.flight.carrier.append(obs(j0, 1.5 + j0 + 0.05))
    assert {r for r, s in _statuses(kit.evaluate()).items() if s == "FAIL"} == set()
    kit.flight = clean()  # the same repeat long after the Decision: a decided stage observed
    kit.flight.carrier.append(obs(j0, 1.5 + j0 + CROSSING_S + 0.3))
    assert {r for r, s in _statuses(kit.evaluate()).items() if s == "FAIL"} == {"observation-stage"}

    kit.flight = clean()
    del kit.flight.carrier[4]  # the Confirm of stage 1
    assert {r for r, s in _statuses(kit.evaluate()).items() if s == "FAIL"} == {"confirm"}

    kit.flight = clean()
    body = msgpack.unpackb(kit.flight.carrier[1].payload)
    kit.flight.carrier[1] = wc.Seen(1.0, "obs", msgpack.packb({**body, "colour": "red"}), None, "unknown-field: x")
    failed = {r for r, s in _statuses(kit.evaluate()).items() if s == "FAIL"}
    assert "decode" in failed and failed <= {"decode", "observation-stage"}


def test_the_ballot_rule_on_a_recorded_flight(tmp_path):
    """[P-7.2] two live coordinators of epoch 2 (flight two-ballots): a Confirm of stage 1 between
    the lower id's contradicting Decision and the higher id's fails ``two-ballots``; one sent to a
    carrier of revision 5 (no ids on the wire: it ranks by epoch alone) is not judged."""
    kit = _kit(tmp_path)
    t = kit.target
    m, fp = t.mission, t.fingerprint

    def flight(confirm_between: bool, revision: int = wm.REVISION):
        f = wc.Flight()
        f.name = "two-ballots"
        f.carrier.append(_seen(0.0, wm.Hello(m, "a", 1, "h", 2, 0, fp, epoch=2, revision=revision)))
        fake = wm.Decision(m, 1, t.times[1], ("a",), 0.0, epoch=2, coordinator="kit-a")
        f.decisions.append(wc.Seen(1.2, "decision", wm.encode(fake, revision), fake, fake=True))
        if confirm_between:
            f.carrier.append(_seen(1.3, wm.Confirm(m, "a", 1, True, "deployed", (0.0, 0.0), 1)))
        f.decisions.append(_seen(1.5, wm.Decision(m, 1, t.times[1], (), 1.0, epoch=2, coordinator="kit-b")))
        return f

    kit.flight = flight(True)
    assert _statuses(kit.evaluate())["two-ballots"] == "FAIL"
    kit.flight = flight(False)
    assert _statuses(kit.evaluate())["two-ballots"] == "pass"
    kit.flight = flight(True, revision=5)
    assert _statuses(kit.evaluate())["two-ballots"] == "-"


FIXTURES = sorted((ROOT / "tests" / "fixtures" / "wire").glob("r*/messages.json"))


@pytest.mark.parametrize("path", FIXTURES, ids=lambda p: p.parent.name)
def test_each_revisions_fixtures_pass_the_kits_at_their_own_revision(tmp_path, path):
    """[P-11.2] what a carrier of revision r sends (its fixtures) passes the carrier kit's decode,
    and [P-4.3] the kit's coordinator speaking r finds nothing newer than r in it; [P-4.5] what a
    coordinator sends such a carrier passes the coordinator kit's decode."""
    import json

    fixture = json.loads(path.read_text())
    r = int(fixture["revision"])
    kit = _kit(tmp_path)
    kit.flight = wc.Flight(name="older" if r < 3 else "scripted", revision=r)
    for i, body in enumerate(b for kind in fixture["carrier_sends"].values() for b in kind):
        payload = msgpack.packb(body)
        try:
            kit.flight.carrier.append(wc.Seen(float(i), body["type"], payload, wm.decode(payload)))
        except wm.ProtocolError as exc:
            kit.flight.carrier.append(wc.Seen(float(i), body["type"], payload, None, f"{exc.reason}: {exc.detail}"))
    results = _statuses(kit.evaluate())
    assert results["decode"] == "pass", wc.table(kit.evaluate())
    assert results["older-revision"] == ("pass" if r < 3 else "-"), wc.table(kit.evaluate())
    if r == 2:  # Confirm passenger is revision 2's: a revision-1 coordinator must not be sent it
        kit.flight.revision = 1
        assert _statuses(kit.evaluate())["older-revision"] == "FAIL"
    seen = wc.coordflight.Seen("main")
    for i, body in enumerate(b for kind in fixture["carrier_accepts"].values() for b in kind):
        payload = msgpack.packb(body)
        heard = wc.coordflight.Heard(float(i), "fixture", payload)
        try:
            heard.message = wm.decode(payload)
        except wm.ProtocolError as exc:
            heard.error = f"{exc.reason}: {exc.detail}"
        seen.heard.append(heard)
    world_ = wc.fleet.World.load(str(TINY))
    decode = next(x for x in wc.coordrules.evaluate(world_, [seen]) if x.rule == "decode")
    assert decode.exercised == len(seen.heard) and decode.failure is None, decode.failure


def test_the_command_line_refuses_bad_usage(tmp_path):
    for args, text in [([str(TINY), "--carrier", "a"], "usage"),
                       ([str(TINY), "--carrier", "zz", "--", "true"], "not a carrier"),
                       ([str(TINY), "--carrier", "a", "--faults", "meteor", "--", "true"], "unknown fault"),
                       ([str(tmp_path / "none.yaml"), "--carrier", "a", "--", "true"], "no such file")]:
        proc = subprocess.run([sys.executable, "-m", "wire.conformance", *args], capture_output=True, text=True,
                              cwd=ROOT, timeout=60)
        assert proc.returncode == 2 and text in proc.stderr, (args, proc.stderr)
        assert "Traceback" not in proc.stderr


def test_the_help_documents_every_flag_and_what_the_carrier_is_told(capsys):
    assert wc.main(["--help"]) == 0
    text = capsys.readouterr().out
    for flag in ("--carrier", "--seed", "--faults", "--flight", "--revision", "--late", "--timeout", "--workdir"):
        assert flag in text, flag
    assert "COMMAND one more second" in text and "DIR/carrier" in text  # --timeout, --workdir
    for variable, placeholder, _ in wc.harness.PLACEHOLDERS:
        assert variable in text and "{" + placeholder + "}" in text
    assert all(fault in text for fault in wc.FAULTS) and all(rule in text for rule, _, _ in wc.RULES)
    assert all(flight in text for flight in wc.FLIGHTS) and all(section in text for _, section, _ in wc.RULES)
    assert "exit status: 0" in text


def test_main_returns_the_usage_status_in_process(capsys):
    """What a dispatcher calling ``main(argv)`` gets: a status, one error line, no exception."""
    assert wc.main([str(TINY), "--carrier", "a"], prog="marsupial-fleet conformance carrier") == 2
    err = capsys.readouterr().err
    assert err.startswith("usage: marsupial-fleet conformance carrier SCENARIO")
    assert err.splitlines()[-1] == "marsupial-fleet conformance carrier: error: no COMMAND after -- (the carrier under test)"


# --------------------------------------------------------------------------- slow: real flights

@pytest.mark.slow
def test_the_project_carrier_passes(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "wire.conformance", str(TINY), "--carrier", "a", "--workdir",
                           str(tmp_path / "kit"), "--", *PROJECT_CARRIER], capture_output=True, text=True,
                          cwd=tmp_path, timeout=400)
    assert proc.returncode == 0, proc.stdout + proc.stderr[-3000:]
    rows = {line.split()[0]: line.split()[2] for line in proc.stdout.splitlines()[2:] if line.split()[0] in
            {r for r, _, _ in wc.RULES}}
    assert set(rows) == {r for r, _, _ in wc.RULES}, proc.stdout
    assert {r for r, status in rows.items() if status != "pass"} == SCRIPTED_ONLY, proc.stdout


@pytest.mark.slow
def test_a_revision1_carrier_from_its_page_passes(tmp_path):
    kit = wc.Kit(str(TINY), "a", _client(tmp_path), workdir=str(tmp_path / "kit"), log=lambda line: None)
    results = kit.run()
    assert wc.passed(results), wc.table(results) + kit.flight.output
    assert {r.rule for r in results if not r.exercised} == SCRIPTED_ONLY | LATER_REVISIONS, wc.table(results)


@pytest.mark.slow
@pytest.mark.parametrize("fault, rule", [
    ("fingerprint", "fingerprint"), ("future-obs", "observation-stage"), ("no-confirm", "confirm"),
    ("unknown-field", "decode"), ("stale-epoch", "epochs"),
])
def test_a_broken_carrier_fails_the_rule_it_breaks(tmp_path, fault, rule):
    kit = wc.Kit(str(TINY), "a", _client(tmp_path, fault), workdir=str(tmp_path / "kit"), log=lambda line: None)
    results = kit.run()
    assert not wc.passed(results)
    assert _statuses(results)[rule] == "FAIL", wc.table(results) + kit.flight.output


# --------------------------------------------------------------------------- the carrier kit's scripted flights

def _flight(tmp_path, command, flight, revision=None) -> tuple[list, wc.Kit]:
    kit = wc.Kit(str(TINY), "a", command, workdir=str(tmp_path / "kit"), log=lambda line: None, flight=flight,
                 revision=revision, timeout_s=90)
    return kit.run(), kit


def _exercised_and_passed(results, kit, rules) -> None:
    statuses = _statuses(results)
    assert wc.passed(results), wc.table(results) + kit.flight.output
    assert all(statuses[rule] == "pass" for rule in rules), wc.table(results)


def test_the_project_carrier_passes_the_kits_own_coordinator(tmp_path):
    """[P-5.8] Accepted and it goes on; [P-6.9] the named passenger is the one released (the kit
    names the last on board, not the default); End and Bye. Quick: the kit is the coordinator."""
    results, kit = _flight(tmp_path, PROJECT_CARRIER, "scripted")
    _exercised_and_passed(results, kit, ("accepted", "passenger-named", "confirm-outcome", "bye"))


@pytest.mark.slow
def test_a_revision1_carrier_passes_a_revision1_coordinator(tmp_path):
    """[P-4.3] each revision's carrier at its own revision: the revision-1 carrier written from its
    page against the kit's coordinator speaking revision 1."""
    results, kit = _flight(tmp_path, _client(tmp_path), "older", 1)
    _exercised_and_passed(results, kit, ("older-revision", "confirm", "bye"))


@pytest.mark.slow
@pytest.mark.parametrize("revision", [1, 2])
def test_the_project_carrier_falls_back_to_an_older_coordinator(tmp_path, revision):
    """[P-4.3] a coordinator whose State announces no revision is spoken revision 1 to: no Hello
    revision, no Confirm passenger, whatever its Decisions carry."""
    results, kit = _flight(tmp_path, PROJECT_CARRIER, "older", revision)
    _exercised_and_passed(results, kit, ("older-revision", "confirm", "bye"))


@pytest.mark.slow
def test_the_project_carrier_stops_when_refused_and_ignores_anothers_refusal(tmp_path):
    """[P-5.10] a Refusal naming another fingerprint is ignored; one naming its own stops it."""
    results, kit = _flight(tmp_path, PROJECT_CARRIER, "refusal")
    _exercised_and_passed(results, kit, ("refusal",))


@pytest.mark.slow
def test_a_revision1_carrier_stops_when_refused(tmp_path):
    """[P-5.10] the revision-1 carrier, refused as world-mismatch (the only reason it knows)."""
    results, kit = _flight(tmp_path, _client(tmp_path), "refusal")
    _exercised_and_passed(results, kit, ("refusal",))


@pytest.mark.slow
def test_a_carrier_that_ignores_its_refusal_fails_refusal(tmp_path):
    """[P-5.10] the revision-1 carrier broken to fly on after its Refusal."""
    results, kit = _flight(tmp_path, _client(tmp_path, "ignore-refusal", "--decision-timeout", "1"), "refusal")
    assert _statuses(results)["refusal"] == "FAIL", wc.table(results)


@pytest.mark.slow
def test_the_project_carrier_sends_progress_on_a_paced_mission(tmp_path):
    """[P-10.6] stages of 2.5 s of wall time: Progress at least every 1.5 s on the way, of the
    stage it works towards. The carrier is given the pace (--realtime) as well as the Accepted."""
    results, kit = _flight(tmp_path, [*PROJECT_CARRIER, "--realtime", "2"], "progress")
    _exercised_and_passed(results, kit, ("progress", "confirm", "bye"))
    assert _statuses(results)["progress"] == "pass" and next(r for r in results if r.rule == "progress").exercised > 3


@pytest.mark.slow
def test_the_project_carrier_follows_the_higher_of_two_live_coordinators(tmp_path):
    """[P-7.2] both coordinators live, the deposed one's contradicting Decision first at every
    stage: only the higher epoch's are answered; [P-7.4] the deposed one's End does not end it."""
    results, kit = _flight(tmp_path, PROJECT_CARRIER, "two-coordinators")
    _exercised_and_passed(results, kit, ("two-coordinators", "deposed-end", "confirm-outcome", "bye"))


@pytest.mark.slow
def test_the_project_carrier_follows_the_higher_ballot_of_two_live_coordinators(tmp_path):
    """[P-7.2] both coordinators of epoch 2 and live, ids kit-a (deposed, its contradicting
    Decision first at every stage) and kit-b: only the higher ballot's are answered; [P-7.4] the
    lower ballot's End does not end it."""
    results, kit = _flight(tmp_path, PROJECT_CARRIER, "two-ballots")
    _exercised_and_passed(results, kit, ("two-ballots", "deposed-end", "confirm-outcome", "bye"))


@pytest.mark.slow
def test_a_revision1_carrier_follows_the_higher_of_two_live_coordinators(tmp_path):
    """[P-7.2] the revision-1 carrier (its End carries no epoch: no deposed End is sent to it)."""
    results, kit = _flight(tmp_path, _client(tmp_path), "two-coordinators")
    _exercised_and_passed(results, kit, ("two-coordinators", "confirm-outcome", "bye"))
    assert _statuses(results)["deposed-end"] == "-"


@pytest.mark.slow
def test_a_carrier_answering_the_deposed_coordinator_fails_two_coordinators(tmp_path):
    """[P-7.2] the revision-1 carrier broken to ignore epochs."""
    results, kit = _flight(tmp_path, _client(tmp_path, "stale-epoch"), "two-coordinators")
    assert _statuses(results)["two-coordinators"] == "FAIL", wc.table(results)


def test_the_project_carrier_resynchronises_on_a_decision_gap(tmp_path):
    """[P-6.6] Decision 1 lost, Decision 2 published while it waits at 1: it asks State before
    confirming 2, and goes on at 3."""
    results, kit = _flight(tmp_path, PROJECT_CARRIER, "gap")
    _exercised_and_passed(results, kit, ("decision-gap", "confirm-outcome", "observation-stage", "bye"))


@pytest.mark.slow
def test_the_project_carrier_says_an_unanswered_hello_again(tmp_path):
    """[P-5.14] the kit loses the carrier's first two Hellos: it says Hello again (after 10 s, then
    20 s) with its pending Observation, and flies the mission once the third is answered."""
    results, kit = _flight(tmp_path, PROJECT_CARRIER, "unanswered")
    _exercised_and_passed(results, kit, ("hello-again", "accepted", "confirm-outcome", "bye"))


@pytest.mark.slow
def test_a_carrier_going_on_at_once_after_a_gap_fails_decision_gap(tmp_path):
    """[P-6.6] the revision-1 carrier, written before the rule, confirms Decision 2 without asking State."""
    results, kit = _flight(tmp_path, _client(tmp_path), "gap")
    assert _statuses(results)["decision-gap"] == "FAIL", wc.table(results)


def test_the_carrier_kit_refuses_a_bad_flight_or_revision(tmp_path):
    for args, text in [(["--flight", "moon"], "invalid choice"), (["--flight", "older", "--revision", "3"], "--revision"),
                       (["--revision", "0", "--flight", "scripted"], "--revision")]:
        proc = subprocess.run([sys.executable, "-m", "wire.conformance", str(TINY), "--carrier", "a", *args, "--",
                               "true"], capture_output=True, text=True, cwd=ROOT, timeout=60)
        assert proc.returncode == 2 and text in proc.stderr, (args, proc.stderr)


# --------------------------------------------------------------------------- the coordinator kit

def _coordinator_rows(stdout: str) -> dict:
    names = {r for r, _, _ in wc.COORDINATOR_RULES}
    return {line.split()[0]: line.split()[2] for line in stdout.splitlines() if line.split() and line.split()[0] in names}


def test_the_coordinator_kit_help_documents_every_flag_fault_and_rule(capsys):
    assert wc.main(["coordinator", "--help"]) == 0
    text = capsys.readouterr().out
    assert text.startswith("usage: python -m wire.conformance coordinator [SCENARIO] [options] -- COMMAND")
    for flag in ("--seed", "--faults", "--timeout", "--workdir"):
        assert flag in text, flag
    assert "SIGKILL 10 s later" in text and "DIR/takeover" in text  # --timeout, --workdir explained
    for variable, placeholder, _ in wc.coordflight.PLACEHOLDERS:
        assert variable in text and "{" + placeholder + "}" in text
    assert all(fault in text for fault in wc.coordflight.FAULTS)
    assert all(rule in text and section in text for rule, section, _ in wc.COORDINATOR_RULES)
    assert "exit status: 0" in text


def test_the_carrier_kit_is_still_the_default_and_a_subcommand(capsys):
    """The documented spelling without a subcommand and ``carrier`` reach the same kit."""
    assert wc.main(["--help"]) == 0
    default = capsys.readouterr().out
    assert wc.main(["carrier", "--help"]) == 0
    named = capsys.readouterr().out
    assert "--carrier ID" in default and "'coordinator' checks a coordinator" in default
    assert named.replace("python -m wire.conformance carrier", "python -m wire.conformance") == default


def test_the_coordinator_kit_refuses_bad_usage(tmp_path):
    for args, text in [(["coordinator"], "no COMMAND"), (["coordinator", "nowhere", "--", "true"], "no such file"),
                       (["coordinator", "--faults", "meteor", "--", "true"], "unknown fault")]:
        proc = subprocess.run([sys.executable, "-m", "wire.conformance", *args], capture_output=True, text=True,
                              cwd=ROOT, timeout=60)
        assert proc.returncode == 2 and text in proc.stderr, (args, proc.stderr)
        assert "Traceback" not in proc.stderr


def _coordinator_kit(tmp_path, command, faults) -> tuple[list, wc.CoordinatorKit]:
    kit = wc.CoordinatorKit(str(TINY), command, faults=faults, timeout_s=90, workdir=str(tmp_path / "kit"),
                            log=lambda line: None)
    return kit.run(), kit


def test_the_project_coordinator_passes_a_plain_flight(tmp_path):
    """[P-5.8] every Hello answered, [P-6.4] Decisions in order, [P-6.3] feasible, [P-9.1] End
    once, [P-5.3] State served: the project's coordinator, no faults (quick: one flight of tiny)."""
    results, kit = _coordinator_kit(tmp_path, PROJECT_COORDINATOR, ())
    statuses = _statuses(results)
    assert wc.passed(results), wc.table(results, wc.COORDINATOR_RULES) + kit.flights[0].output
    assert {r for r, s in statuses.items() if s == "pass"} >= {"decode", "state", "hello-answered", "accepted",
                                                               "decision-order", "end", "rejections"}


@pytest.mark.slow
def test_the_project_coordinator_answers_hellos_while_it_compiles(tmp_path, monkeypatch):
    """[P-5.8] on a machine's first run (no compiled kernels: an empty NUMBA_CACHE_DIR) the
    coordinator compiles its planner in a thread while it takes its inbox: the kit's Hellos are
    answered at once, not after the compile."""
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "cold-cache"))
    results, kit = _coordinator_kit(tmp_path, PROJECT_COORDINATOR, ())
    assert wc.passed(results), wc.table(results, wc.COORDINATOR_RULES) + kit.flights[0].output
    assert _statuses(results)["hello-answered"] == "pass"


@pytest.mark.slow
def test_a_coordinator_deploying_every_carrier_fails_feasible(tmp_path):
    """[P-6.3] a Decision selecting carriers that did not observe the stage fails ``feasible``."""
    results, kit = _coordinator_kit(tmp_path, [sys.executable, str(BROKEN_COORDINATOR), "select-all",
                                               *COORDINATOR_FLAGS], ())
    assert not wc.passed(results)
    assert _statuses(results)["feasible"] == "FAIL", wc.table(results, wc.COORDINATOR_RULES)


def test_a_coordinator_that_never_answers_fails_state(tmp_path):
    """[P-5.3] a coordinator that exits at once: no State reply, no stage decided, a FAIL verdict."""
    proc = subprocess.run([sys.executable, "-m", "wire.conformance", "coordinator", "--faults", "none", "--timeout",
                           "20", "--workdir", str(tmp_path / "kit"), "--", sys.executable, "-c", "pass"],
                          capture_output=True, text=True, cwd=ROOT, timeout=120)
    rows = _coordinator_rows(proc.stdout)
    assert proc.returncode == 1 and rows["state"] == "FAIL" and rows["end"] == "FAIL", proc.stdout + proc.stderr
    assert "conformance: FAIL (coordinator: main exit code 0" in proc.stdout


@pytest.mark.slow
def test_the_project_coordinator_passes_every_fault(tmp_path):
    """The documented command on the project's coordinator: every rule exercised and passed, the
    takeover flight included ([P-7.3] a newer epoch's Decision stops it; [P-4.2] a revision-1
    carrier's join makes the broadcasts revision 1's; [P-3.3] bad Hellos refused with their reason)."""
    proc = subprocess.run([sys.executable, "-m", "wire.conformance", "coordinator", str(TINY), "--workdir",
                           str(tmp_path / "kit"), "--", *PROJECT_COORDINATOR], capture_output=True, text=True,
                          cwd=ROOT, timeout=400)
    assert proc.returncode == 0, proc.stdout + proc.stderr[-3000:]
    rows = _coordinator_rows(proc.stdout)
    assert set(rows) == {r for r, _, _ in wc.COORDINATOR_RULES} and set(rows.values()) == {"pass"}, proc.stdout
    assert "conformance: PASS (coordinator: main exit code 0, takeover exit code 3" in proc.stdout


@pytest.mark.slow
@pytest.mark.parametrize("brk, faults, rule", [
    ("no-accepted", (), "hello-answered"), ("ignore-takeover", ("takeover",), "takeover"), ("no-token", (), "token"),
])
def test_a_broken_coordinator_fails_the_rule_it_breaks(tmp_path, brk, faults, rule):
    """[P-5.8] unanswered Hellos fail hello-answered; [P-7.3] ignoring a newer epoch fails takeover;
    [P-2.5] no liveliness token fails token."""
    results, kit = _coordinator_kit(tmp_path, [sys.executable, str(BROKEN_COORDINATOR), brk, *COORDINATOR_FLAGS],
                                    faults)
    assert not wc.passed(results)
    assert _statuses(results)[rule] == "FAIL", wc.table(results, wc.COORDINATOR_RULES)
