"""The rules a carrier is checked on (:data:`RULES`, each from a section of docs/protocol.md) and
their evaluation on a recorded flight: a pure function of the target and what was seen."""
from __future__ import annotations

from dataclasses import dataclass

from .. import messages as wm
from .flight import UNANSWERED, Flight, Seen, Target

#: Every rule the kit checks: (id, section of docs/protocol.md, what it says).
RULES = (
    ("decode", "[P-11.2]", "every message it sends decodes at the kit's revision (optional fields of any revision "
                           "up to it accepted, whatever it announced [P-4.5])"),
    ("hello-first", "[P-5.6]", "a Hello comes before its first Observation, Confirm, Own or Bye"),
    ("fingerprint", "[P-2.6]", "its Hello carries the coordinator's fingerprint (no Refusal)"),
    ("observation-stage", "[P-6.7]", "an Observation is of the stage being collected (not a later or a decided one; a repeat that crossed its Decision on the way, within 2 s, excepted)"),
    ("observation-time", "[P-3.2]", "an Observation's t is t_j of its stage (±0.001 s), stage < N"),
    ("observation-world", "[P-6.12]", "x is the world's: features in sight at t_j, nil where not scheduled"),
    ("passengers", "[P-6.9]", "passengers_left starts at the scenario's count and drops by one per deployment"),
    ("confirm", "[P-6.9]", "every Decision of a stage it joined for is answered (Confirm, or Own of that stage)"),
    ("confirm-outcome", "[P-6.9]", "the first answer follows the Decision: deployed / idle / refused / late"),
    ("passenger-named", "[P-6.9]", "a deployment releases the passenger the Decision names (Confirm passenger)"),
    ("decision-gap", "[P-6.6]", "on Decision j+2 without Decision j+1 it asks State before confirming it"),
    ("duplicate", "[P-6.8]", "a repeated Decision is answered already, with the first outcome, nothing twice"),
    ("late", "[P-6.8]", "a Decision that comes late is still answered, once"),
    ("restart", "[P-5.12]", "when the coordinator's token reappears it says Hello again"),
    ("epochs", "[P-7.2]", "a Decision of a lower epoch than it heard is not answered (deposed)"),
    ("two-coordinators", "[P-7.2]", "with two live coordinators it follows the higher epoch: no answer to the "
                                    "lower epoch's Decisions"),
    ("two-ballots", "[P-7.2]", "with two live coordinators of one epoch it follows the higher ballot (revision 6): "
                               "no answer to the lower id's Decisions"),
    ("deposed-end", "[P-7.4]", "an End of a lower epoch than it heard does not end its mission (revision 4)"),
    ("hello-again", "[P-5.14]", "a Hello without an answer is said again, then its pending Observation; no sooner "
                                "than 1 s, each wait at least the one before (the unanswered flight)"),
    ("accepted", "[P-5.8]", "after Accepted it goes on: its Observation of the accepted next_stage, no Bye "
                            "before End"),
    ("refusal", "[P-5.10]", "a Refusal naming its fingerprint while its Hello is unanswered stops it: Bye "
                            "world-mismatch, nothing after, exit; one naming another fingerprint is ignored"),
    ("older-revision", "[P-4.3]", "to a coordinator whose State announces no revision it speaks revision 1: what it "
                                  "sends decodes at the coordinator's revision (Progress aside, [P-4.6])"),
    ("progress", "[P-10.6]", "Progress (sim clock) names the stage it works towards, t within it and never going "
                             "back; simulating its way to an Observation for over 2 s, one at least every 1.5 s"),
    ("bye", "[P-9.3]", "after End: Bye with reason end and its deployments, then the process exits 0"),
    ("coordinator-rejections", "[P-3.4]", "the coordinator rejected none of its messages (State, CarrierState.rejected)"),
)


@dataclass
class Result:
    """One rule's outcome: how often the carrier was exercised on it and the first failure."""

    rule: str
    exercised: int = 0
    failure: str | None = None

    def check(self, ok: bool, message: str = "") -> None:
        self.exercised += 1
        if not ok and self.failure is None:
            self.failure = message[:300]

    @property
    def status(self) -> str:
        return "-" if self.exercised == 0 else ("pass" if self.failure is None else "FAIL")


def evaluate(target: Target, flight: Flight) -> list[Result]:
    """Every rule of :data:`RULES`, in that order, judged on ``flight``."""
    f = flight
    results = {rule: Result(rule) for rule, _, _ in RULES}
    msgs = [s for s in f.carrier if s.message is not None]
    for s in f.carrier:  # decoded at the kit's own revision, whatever the carrier announced [P-11.2]
        results["decode"].check(s.error is None, f"{s.error}: {s.show()}")
    hello_at = next((s.at for s in msgs if isinstance(s.message, wm.Hello)), None)
    for s in msgs:
        if isinstance(s.message, (wm.Observation, wm.Confirm, wm.Own, wm.Bye)):
            results["hello-first"].check(hello_at is not None and s.at >= hello_at,
                                         f"before any Hello: {s.show()}")
            break
    for s in msgs:
        if isinstance(s.message, wm.Hello):
            results["fingerprint"].check(s.message.fingerprint == target.fingerprint,
                                         f"fingerprint {s.message.fingerprint}, the world's {target.fingerprint}: {s.show()}")
    for s in f.refusals:
        results["fingerprint"].check(False, f"refused: {s.show()}")
    real = [d for d in f.decisions if not d.fake]
    _observations(target, f, results, msgs, real)
    _answers(target, f, results, msgs, real)
    _named(target, results, msgs, real)
    _scripted(target, f, results, msgs, real)
    _progress(target, f, results, msgs, real)
    return [results[rule] for rule, _, _ in RULES]


def _observations(target: Target, flight: Flight, results: dict, msgs: list[Seen], real: list[Seen]) -> None:
    t = target
    answers = first_answers(msgs)
    for s in msgs:
        m = s.message
        if not isinstance(m, wm.Observation):
            continue
        decided = [d.message.stage for d in real if d.at <= s.at]
        collecting = max(decided, default=-1) + 1
        # stages it decided itself before this Observation: it may go on past them
        own_before = {x.message.stage for x in msgs if isinstance(x.message, wm.Own) and x.at <= s.at}
        results["observation-stage"].check(
            m.stage == collecting or (m.stage < collecting and m.x is None and not t.valid[min(m.stage, t.n - 1)])
            or (m.stage < collecting and _resent(flight, s)) or _crossed(msgs, real, s)
            or (m.stage > collecting and set(range(collecting, m.stage)) <= own_before),
            f"stage {m.stage} while stage {collecting} was collected: {s.show()}")
        in_range = m.stage < t.n and abs(m.t - t.times[m.stage]) <= 1e-3
        results["observation-time"].check(in_range, f"t {m.t} for stage {m.stage}: {s.show()}")
        if m.stage < t.n:
            world_x = None if not t.valid[m.stage] else int(t.x[m.stage])
            results["observation-world"].check(m.x == world_x, f"x {m.x}, the world's {world_x}: {s.show()}")
            deployed_before = sum(1 for j, a in answers.items() if j < m.stage and a.deployed)
            results["passengers"].check(m.passengers_left == t.passengers - deployed_before,
                                        f"passengers_left {m.passengers_left}, expected "
                                        f"{t.passengers - deployed_before}: {s.show()}")


CROSSING_S = 2.0  # how long an Observation sent before its Decision arrived may be on its way


def _crossed(msgs: list[Seen], real: list[Seen], seen: Seen) -> bool:
    """An Observation repeated while it waited (the same stage and x as one that came before its
    Decision) that crossed that Decision on the way: it reached the kit at most ``CROSSING_S``
    after the Decision went out, so the carrier sent it before it could have heard it."""
    m = seen.message
    decided = [d.at for d in real if d.message.stage == m.stage and d.at <= seen.at]
    if not decided:
        return False
    first = min(decided)
    return seen.at - first <= CROSSING_S and any(
        isinstance(o.message, wm.Observation) and o.message.stage == m.stage and o.message.x == m.x and o.at <= first
        for o in msgs)


def _resent(flight: Flight, seen: Seen) -> bool:
    """An Observation of a stage decided in the meantime, re-sent at a resynchronisation."""
    return bool(flight.coordinator_back) and any(abs(seen.at - back) < 10.0 for back in flight.coordinator_back)


def first_answers(msgs: list[Seen]) -> dict:
    """stage -> the carrier's first Confirm or Own of it."""
    out: dict = {}
    for s in msgs:
        m = s.message
        if isinstance(m, (wm.Confirm, wm.Own)) and m.stage not in out:
            out[m.stage] = m
    return out


def _answers(target: Target, flight: Flight, results: dict, msgs: list[Seen], real: list[Seen]) -> None:
    t, f = target, flight
    answers = first_answers(msgs)
    left = t.passengers
    for j in range(t.n):
        decision = next((d for d in real if d.message.stage == j), None)
        if decision is None:
            continue
        first = answers.get(j)
        results["confirm"].check(first is not None, f"no Confirm or Own of stage {j}; its Decision: {decision.show()}")
        if first is None or isinstance(first, wm.Own):
            if isinstance(first, wm.Own):
                left -= int(first.deployed)
            continue
        d = decision.message
        selected = t.cid in d.deploy
        expected = {"deployed": selected and t.valid[j] and left > 0, "idle": not selected,
                    "refused": selected and (not t.valid[j] or left == 0), "late": selected}
        results["confirm-outcome"].check(expected.get(first.status, False),
                                         f"status {first.status!r} for a Decision "
                                         f"{'selecting' if selected else 'not selecting'} it at stage {j} "
                                         f"({left} passenger(s) left): {decision.show()}")
        left -= int(first.deployed)
        results["passengers"].check(first.passengers_left == left,
                                    f"passengers_left {first.passengers_left} after stage {j}, expected {left}")
    confirms = [s for s in msgs if isinstance(s.message, wm.Confirm)]
    if "duplicate" in f.faults:
        stage, at = f.faults["duplicate"]
        again = [s.message for s in confirms if s.message.stage == stage and s.at > at]
        first = answers.get(stage)
        ok = bool(again) and all(c.status == "already" and first is not None and c.deployed == first.deployed
                                 for c in again)
        results["duplicate"].check(ok, f"answers to the repeated Decision of stage {stage}: "
                                       f"{[(c.status, c.deployed) for c in again] or 'none'}")
    if "late" in f.faults:
        stage, _ = f.faults["late"]
        n_first = sum(1 for s in confirms if s.message.stage == stage and s.message.status != "already")
        results["late"].check(n_first == 1, f"{n_first} first answer(s) to the late Decision of stage {stage}")
    if "restart" in f.faults:
        back = f.coordinator_back[0] if f.coordinator_back else None
        hello = back is not None and any(isinstance(s.message, wm.Hello) and s.at > back for s in msgs)
        results["restart"].check(hello, "no Hello after the coordinator's token reappeared"
                                 if back is not None else "the coordinator did not come back")
    if "deposed" in f.faults:
        stage, (start, _) = f.faults["deposed"]
        real_d = next((d for d in real if d.message.stage == stage), None)
        real_at = real_d.at if real_d is not None else float("inf")
        wrong = [s for s in confirms if s.message.stage == stage and start <= s.at < real_at]
        # On a loaded host the real Decision can arrive just after the fake one: an answer that
        # deploys where the real Decision does not select the carrier answered the fake.
        first = answers.get(stage)
        wrong += [s for s in confirms if s.message is first and s not in wrong and first.deployed
                  and real_d is not None and t.cid not in real_d.message.deploy]
        results["epochs"].check(not wrong, f"answered a Decision of epoch 1 after hearing epoch 2: "
                                           f"{wrong[0].show() if wrong else ''}")
    if f.ends:
        byes = [s for s in msgs if isinstance(s.message, wm.Bye)]
        deployments = tuple(sorted(j for j, a in answers.items() if a.deployed))
        bye = byes[-1].message if byes else None
        results["bye"].check(bye is not None and bye.reason == "end" and tuple(bye.deployments) == deployments
                             and f.exit_code == 0,
                             f"Bye {byes[-1].show() if byes else 'missing'} (deployments {list(deployments)}), "
                             f"exit code {f.exit_code}")
    # Stage rejections are judged above (observation-stage): a carrier that decided a stage
    # itself legitimately sends a later stage's Observation the coordinator rejects.
    other = {k: v for k, v in f.rejected.items() if k not in ("future-stage", "stale-stage")}
    results["coordinator-rejections"].check(not other, f"the coordinator rejected: {dict(f.rejected)}")


def _named(target: Target, results: dict, msgs: list[Seen], real: list[Seen]) -> None:
    """[P-6.9] the passenger a Decision names is the one released."""
    answers = first_answers(msgs)
    for d in real:
        named = d.message.passenger_of(target.cid)
        first = answers.get(d.message.stage)
        if named is None or not isinstance(first, wm.Confirm) or first.status != "deployed":
            continue
        results["passenger-named"].check(first.passenger == named,
                                         f"released passenger {first.passenger} where the Decision of stage "
                                         f"{d.message.stage} names {named}: {d.show()}")


def _scripted(target: Target, flight: Flight, results: dict, msgs: list[Seen], real: list[Seen]) -> None:
    """The rules of the flights where the kit is the coordinator."""
    f = flight
    confirms = [s for s in msgs if isinstance(s.message, wm.Confirm)]
    byes = [s for s in msgs if isinstance(s.message, wm.Bye)]
    for fake in (d for d in f.decisions if d.fake and f.name in ("two-coordinators", "two-ballots")):
        j, said = fake.message.stage, wm.decode(fake.payload, wm.Decision)  # as sent: at the carrier's revision
        if f.name == "two-ballots" and not said.coordinator:
            continue  # a carrier of revision 5 or earlier is sent no ids: it ranks by epoch alone
        truth = next((d.at for d in real if d.message.stage == j), float("inf"))
        wrong = [s for s in confirms if s.message.stage == j and fake.at <= s.at < truth]
        results[f.name].check(not wrong, f"answered the Decision of stage {j} of epoch {said.epoch}"
                                         + (f" (id {said.coordinator})" if said.coordinator else "")
                                         + f": {wrong[0].show() if wrong else ''}")
    if "gap" in f.faults:
        stage, at = f.faults["gap"]
        answered = next((s.at for s in confirms if s.message.stage == stage), float("inf"))
        asked = [q for q in f.state_queries if at < q < answered]
        results["decision-gap"].check(bool(asked), f"no State query between the Decision of stage {stage} (that "
                                                   f"of {stage - 1} lost) and its Confirm")
    if "deposed-end" in f.faults:
        _, at = f.faults["deposed-end"]
        last = [s for s in confirms if s.message.stage == target.n - 1 and s.at > at]
        ok = bool(last) and all(s.message.reason == "end" for s in byes) and bool(f.ends) and \
            all(s.at > f.ends[0].at for s in byes)
        results["deposed-end"].check(ok, f"after an End of epoch 1: {'no Confirm of the last stage' if not last else ''}"
                                         f" Byes {[b.show() for b in byes]}")
    for a in f.accepted:
        later = [s for s in msgs if isinstance(s.message, wm.Observation) and s.message.stage >= a.message.next_stage]
        early_bye = [s for s in byes if s.message.reason != "end"]
        results["accepted"].check(bool(later) and not early_bye,
                                  f"after {a.show()}: {early_bye[0].show() if early_bye else 'no Observation'}")
    if "unanswered" in f.faults:
        _hello_again(results, msgs)
    if "refusal" in f.faults:
        _, foreign = f.faults.get("refusal-foreign", (None, 0.0))
        _, at = f.faults["refusal"]
        early = [s for s in byes if foreign <= s.at < at]
        after = [s for s in msgs if isinstance(s.message, (wm.Observation, wm.Confirm, wm.Own)) and s.at > at + 0.5]
        ok = not early and not after and bool(byes) and byes[-1].message.reason == "world-mismatch" \
            and f.exit_code is not None
        results["refusal"].check(ok, f"{'stopped on a Refusal naming another fingerprint: ' + early[0].show() if early else ''}"
                                     f"{'sent after its Refusal: ' + after[0].show() if after else ''} "
                                     f"Bye {byes[-1].show() if byes else 'none'}, exit code {f.exit_code}")
    if f.revision is not None and f.revision < 3:
        for s in msgs:
            if isinstance(s.message, (wm.Progress, wm.Pose)):
                continue
            try:
                wm.decode(s.payload, revision=f.revision)
                results["older-revision"].check(True)
            except wm.ProtocolError as exc:
                results["older-revision"].check(False, f"{exc.reason} at revision {f.revision}: {exc.detail}: {s.show()}")


def _hello_again(results: dict, msgs: list[Seen]) -> None:
    """[P-5.14] the unanswered flight: its Hellos until the kit answered one (the kit answers the
    third), each wait from the last no shorter than 1 s nor than the wait before it (0.5 s
    slack: a carrier looks at its timers when it wakes), and an Observation after the answered one."""
    hellos = [s.at for s in msgs if isinstance(s.message, wm.Hello)][:UNANSWERED]
    waits = [b - a for a, b in zip(hellos, hellos[1:])]
    ok = len(hellos) == UNANSWERED and waits[0] >= 1.0 and all(b >= a - 0.5 for a, b in zip(waits, waits[1:]))
    ok = ok and any(isinstance(s.message, wm.Observation) and s.at > hellos[-1] for s in msgs)
    results["hello-again"].check(ok, f"{len(hellos)} Hello(s) without an answer, waits "
                                     f"{[round(w, 1) for w in waits]} s; the kit answers Hello {UNANSWERED}")


def _progress(target: Target, flight: Flight, results: dict, msgs: list[Seen], real: list[Seen]) -> None:
    """[P-10.6] what Progress says, and (the kit's own coordinator) how often it comes."""
    t = target
    previous = None
    for s in msgs:
        p = s.message
        if not isinstance(p, wm.Progress):
            continue
        ok = p.stage <= t.n and (p.stage == t.n or p.t <= t.times[p.stage] + 1e-3)
        ok = ok and (previous is None or (p.stage >= previous.stage and p.t >= previous.t - 1e-6))
        results["progress"].check(ok, f"Progress stage {p.stage} t {p.t} after "
                                      f"{(previous.stage, previous.t) if previous else 'none'}: {s.show()}")
        previous = p
    hello = next((s.message for s in msgs if isinstance(s.message, wm.Hello)), None)
    if flight.revision is None or flight.revision < 3 or hello is None or hello.revision < 3:
        return
    for s in msgs:
        o = s.message
        if not isinstance(o, wm.Observation) or o.stage == 0:
            continue
        start = next((d.at for d in real if d.message.stage == o.stage - 1), None)
        if start is None or s.at - start <= 2.0:
            continue
        heard = sorted([start, s.at] + [m.at for m in msgs if start < m.at < s.at and not isinstance(m.message, wm.Pose)])
        gap = max(b - a for a, b in zip(heard, heard[1:]))
        results["progress"].check(gap <= 1.5, f"silent {gap:.1f} s on its way to the Observation of stage {o.stage}")
