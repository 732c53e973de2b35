"""The rules a coordinator is checked on (:data:`COORDINATOR_RULES`, each citing the section or
rule of docs/protocol.md it comes from) and their evaluation on recorded flights: a pure
function of the scenario's truth and what the kit saw."""
from __future__ import annotations

import msgpack

from .. import keys
from .. import messages as wm
from .coordflight import ANSWER_S, HELLO_EPOCH, Heard, Seen
from .fleet import World
from .rules import Result

#: After the takeover's Decision, how long a Decision the coordinator had already sent may still
#: arrive, seconds (loopback delivers well within it).
SETTLE_S = 0.5

#: Every rule the coordinator kit checks: (id, rule or section of docs/protocol.md, what it says).
COORDINATOR_RULES = (
    ("decode", "[P-4.5]", "every message it publishes and every State reply decodes at the kit's revision"),
    ("token", "[P-2.5]", "its liveliness token is present before its first Decision and stays until its End"),
    ("state", "[P-5.3]", "State answers a carrier's query: its fingerprint, N stages, only the asking carrier, the "
                       "revision it speaks (>= 3); a query announcing no revision gets a revision-1 reply"),
    ("hello-answered", "[P-5.8]", f"every Hello of revision 3 or later is answered within {ANSWER_S:g} s: "
                                "Accepted or Refusal"),
    ("accepted", "[P-5.8]", "a good Hello is accepted: Accepted names the carrier, the world's fingerprint, the "
                          "Hello's next_stage, collecting <= N, revision >= 3"),
    ("refusal-reason", "[P-3.3]", "a bad Hello is refused with the reason of the first check it fails "
                                "(unknown-carrier, world-mismatch, missing-field), naming the fingerprint it "
                                "carried and the coordinator's"),
    ("refusal-keeps", "[P-5.9]", "a Refusal never undoes a Hello accepted before: State shows that carrier "
                               "not refused and none of its later messages rejected no-hello"),
    ("rejections", "[P-3.4]", "a bad message is counted in State under its reason (malformed, wrong-mission); "
                            "the kit's good messages never are"),
    ("decision-order", "[P-6.4]", "one Decision per stage, every stage in order, t = t_j; a repeat is identical"),
    ("feasible", "[P-6.3]", "a carrier is selected only at a stage it observed with x, with a passenger left"),
    ("forced", "[P-6.13]", "a carrier the forced rule binds at a stage (valid, d > 0, valid stages left <= d) "
                        "is selected"),
    ("late-joiner", "[P-5.11]", "a carrier joining after stage 0 is accepted (Accepted at State's next_stage, to "
                                "revision 3 and later), live, none of its messages rejected"),
    ("broadcast-revision", "[P-4.2]", "once a revision-1 carrier's Hello is accepted, what it broadcasts (Decisions "
                                      "from that carrier's join stage on, End) is revision 1's; that carrier gets no "
                                      "Accepted"),
    ("silent-carrier", "[P-10.3]", "a carrier gone silent with its token held does not stop the mission: every "
                                 "later stage is decided and End comes"),
    ("end", "[P-9.1]", "End once every stage is decided: stages N, reason complete, every repeat identical, no "
                     "Decision after it; its epoch the Decisions' [P-7.4]"),
    ("hello-epoch", "[P-7.3]", f"after a Hello reporting epoch {HELLO_EPOCH} before its first Decision, its "
                             f"Decisions keep its own epoch, 1 (a carrier's message never changes who decides)"),
    ("takeover", "[P-7.3]", "after a Decision of a higher epoch on its decision key it publishes no Decision "
                          "and no End, and its process exits"),
)


def evaluate(world: World, flights: list[Seen]) -> list[Result]:
    """Every rule of :data:`COORDINATOR_RULES`, in that order, judged on every flight."""
    results = {rule: Result(rule) for rule, _, _ in COORDINATOR_RULES}
    for seen in flights:
        _decode_and_state(world, seen, results)
        _hellos(world, seen, results)
        _counts(seen, results)
        _decisions(world, seen, results)
        _epochs(seen, results)
        _token(seen, results)
    return [results[rule] for rule, _, _ in COORDINATOR_RULES]


def _decode_and_state(w: World, seen: Seen, results: dict) -> None:
    if not seen.states:
        results["state"].check(False, f"{seen.name}: no State reply (exit code {seen.exit_code})")
    for h in seen.heard:
        if not h.fake:
            results["decode"].check(h.error is None, f"{seen.name}: {h.topic}: {h.error}: {h.show()}")
    for _, selector, revision, payload in seen.states:
        try:
            state = wm.decode(payload, wm.State)
        except wm.ProtocolError as exc:
            results["decode"].check(False, f"{seen.name}: State for {selector}: {exc.reason}: {exc.detail}")
            continue
        results["decode"].check(True)
        asking = selector.split("carrier=", 1)[1].split(";", 1)[0]
        body = msgpack.unpackb(payload)
        problems = [f"fingerprint {state.fingerprint}, the world's {w.fingerprint}"] * (state.fingerprint != w.fingerprint)
        problems += [f"stages {state.stages}, the scenario's {w.n}"] * (state.stages != w.n)
        problems += [f"carriers {[c for c, _ in state.carriers]} for {asking}"] * any(c != asking for c, _ in state.carriers)
        if revision is None:
            try:
                wm.decode(payload, wm.State, revision=1)
                problems += ["a revision field in the reply to a query announcing none"] * ("revision" in body)
            except wm.ProtocolError as exc:
                problems.append(f"not a revision-1 State ({exc.reason}: {exc.detail})")
        elif not isinstance(body.get("revision"), int) or body["revision"] < 3:
            problems.append(f"revision {body.get('revision')!r} in the reply to a query announcing {revision}")
        results["state"].check(not problems, f"{seen.name}: State for {selector}: {'; '.join(problems)}")


def _answers(w: World, seen: Seen) -> list:
    """(hello, its answer or None): each carrier id's answers matched to its Hellos in order."""
    pools: dict = {}
    for h in seen.heard:
        if isinstance(h.message, (wm.Accepted, wm.Refusal)):
            pools.setdefault(h.topic, []).append(h)
    out = []
    for hello in seen.hellos:
        at, cid = hello[0], hello[1]
        pool = pools.get(keys.accepted_key(w.mission, cid), []) + pools.get(keys.refusal_key(w.mission, cid), [])
        pool.sort(key=lambda h: h.at)
        used = {id(a) for _, a in out if a is not None}
        answer = next((a for a in pool if a.at >= at and id(a) not in used), None)
        out.append((hello, answer))
    return out


def _hellos(w: World, seen: Seen, results: dict) -> None:
    for (at, cid, expect, fingerprint, next_stage), answer in _answers(w, seen):
        if expect.startswith("revision-"):  # an older carrier learns its acceptance from the Decisions
            results["broadcast-revision"].check(not isinstance(getattr(answer, "message", None), wm.Accepted),
                                                f"{seen.name}: Accepted to {cid}, a {expect} carrier: "
                                                f"{answer and answer.show()}")
            continue
        late = answer is not None and answer.at - at > ANSWER_S
        results["hello-answered"].check(answer is not None and not late,
                                        f"{seen.name}: Hello of {cid} ({expect} expected) "
                                        f"{'answered after ' + format(answer.at - at, '.1f') + ' s' if late else 'unanswered'}")
        if answer is None:
            continue
        m = answer.message
        if expect == "accepted":
            problems = [] if isinstance(m, wm.Accepted) else [f"refused: {answer.show()}"]
            if isinstance(m, wm.Accepted):
                problems += [f"carrier {m.carrier}"] * (m.carrier != cid)
                problems += [f"fingerprint {m.fingerprint}"] * (m.fingerprint != w.fingerprint)
                problems += [f"next_stage {m.next_stage}, the Hello's {next_stage}"] * (m.next_stage != next_stage)
                problems += [f"collecting {m.collecting} > N"] * (m.collecting > w.n)
                problems += [f"revision {m.revision}"] * (m.revision < 3)
            results["accepted"].check(not problems, f"{seen.name}: Hello of {cid}: {'; '.join(problems)}")
            if cid == seen.played[w.ids[-1]].cid and "late-joiner" in seen.faults:
                results["late-joiner"].check(isinstance(m, wm.Accepted) and m.next_stage == next_stage,
                                             f"{seen.name}: the late joiner's Hello (next_stage {next_stage}): "
                                             f"{answer.show()}")
            continue
        ok = (isinstance(m, wm.Refusal) and m.reason == expect and m.expected == w.fingerprint
              and (m.fingerprint == fingerprint or (expect != "world-mismatch" and m.fingerprint == "")))
        results["refusal-reason"].check(ok, f"{seen.name}: a Hello of {cid} that must be refused {expect} "
                                            f"(fingerprint {fingerprint}) got {answer.show()}")


def _counts(seen: Seen, results: dict) -> None:
    """What State says of each kit carrier's messages, at the last poll."""
    if not seen.played:
        return
    first, last, told = list(seen.played)[0], list(seen.played)[-1], seen.told
    if "bad-hello" in seen.faults:
        mine = told.get(first)
        counts = dict(mine.rejected) if mine is not None else {}
        results["refusal-keeps"].check(mine is not None and mine.refused is None and "no-hello" not in counts,
                                       f"{seen.name}: {first} after its bad Hellos: "
                                       f"{'no State' if mine is None else f'refused {mine.refused!r}, rejected {counts}'}")
    caused = {"malformed", "wrong-mission", "missing-field", "world-mismatch"}
    for cid, mine in told.items():
        counts = dict(mine.rejected)
        if cid == first and "bad-message" in seen.faults:
            missing = [r for r in ("malformed", "wrong-mission") if counts.get(r, 0) < 1]
            results["rejections"].check(not missing, f"{seen.name}: {cid}'s counts {counts} lack {missing}")
        allowed = caused if cid == first else set()
        wrong = {r: n for r, n in counts.items() if r not in allowed}
        results["rejections"].check(not wrong, f"{seen.name}: good messages of {cid} rejected: {wrong}")
    if "late-joiner" in seen.faults:
        mine = told.get(last)
        results["late-joiner"].check(mine is not None and mine.live and not mine.rejected,
                                     f"{seen.name}: the late joiner {last} in State: {mine}")


def _decisions(w: World, seen: Seen, results: dict) -> None:
    real = seen.of(wm.Decision)
    firsts: dict = {}
    for h in real:
        d = h.message
        if d.stage in firsts:
            f = firsts[d.stage].message
            results["decision-order"].check((f.deploy, f.passengers, f.epoch) == (d.deploy, d.passengers, d.epoch),
                                            f"{seen.name}: stage {d.stage} decided twice: {firsts[d.stage].show()} "
                                            f"then {h.show()}")
            continue
        expected = len(firsts)
        results["decision-order"].check(d.stage == expected and abs(d.t - w.times[d.stage]) <= 1e-3,
                                        f"{seen.name}: Decision of stage {d.stage} (t {d.t}) where stage "
                                        f"{expected} was next: {h.show()}")
        firsts[d.stage] = h
        _feasible(w, seen, results, d)
    ends = seen.of(wm.End)
    old = next(((at, ns) for at, _, expect, _, ns in seen.hellos if expect == "revision-1"), None)
    if old is not None:
        for h in [firsts[j] for j in sorted(firsts) if j >= old[1]] + ends:
            try:
                wm.decode(h.payload, revision=1)
                results["broadcast-revision"].check(True)
            except wm.ProtocolError as exc:
                results["broadcast-revision"].check(False, f"{seen.name}: not revision 1's ({exc.reason}: {exc.detail}) "
                                                           f"with a revision-1 carrier in the mission: {h.show()}")
    if "silent" in seen.faults:
        stage, _ = seen.faults["silent"]
        missing = [j for j in range(stage, w.n) if j not in firsts]
        results["silent-carrier"].check(not missing and bool(ends),
                                        f"{seen.name}: after {w.ids[-1]} went silent at stage {stage}: "
                                        f"{'stages ' + str(missing) + ' undecided' if missing else 'no End'}")
    if seen.name == "main" and len(firsts) < w.n:
        results["end"].check(False, f"{seen.name}: stages {[j for j in range(w.n) if j not in firsts]} never decided "
                                    f"(exit code {seen.exit_code})")
    elif seen.name == "main":
        _end(w, seen, results, real, ends)


def _feasible(w: World, seen: Seen, results: dict, d: wm.Decision) -> None:
    for cid, p in seen.played.items():
        j, selected = d.stage, cid in d.deploy
        observed = p.observed.get(j) is not None
        left = p.left_before.get(j, 0)
        if selected:
            results["feasible"].check(observed and left > 0,
                                      f"{seen.name}: {cid} selected at stage {j} "
                                      f"{'with no passenger left' if observed else 'without an observation there'}")
        if j in p.observed and w.must_deploy(p.r, j, left, observed):
            results["forced"].check(selected, f"{seen.name}: {cid} must deploy at stage {j} ({left} passenger(s), "
                                              f"valid stages left {int(w.valid[p.r][j:].sum())}) and is not selected")


def _end(w: World, seen: Seen, results: dict, real: list[Heard], ends: list[Heard]) -> None:
    last_decision = max(h.at for h in real)
    if not ends:
        results["end"].check(False, f"{seen.name}: every stage decided, no End")
        return
    first = ends[0].message
    epoch = real[-1].message.epoch
    problems = [f"stages {first.stages}"] * (first.stages != w.n) + [f"reason {first.reason!r}"] * (first.reason != "complete")
    problems += ["repeats differ"] * any(e.payload != ends[0].payload for e in ends)
    problems += ["a Decision after End"] * any(h.at > ends[0].at for h in real)
    problems += ["End before the last Decision"] * (ends[0].at < last_decision)
    # End's epoch is revision 4's [P-7.4]: absent in the revision-1 End a revision-1 carrier reads [P-4.2]
    body = msgpack.unpackb(ends[0].payload)
    older = any(expect == "revision-1" for _, _, expect, _, _ in seen.hellos)
    if "epoch" in body or not older:
        problems += [f"epoch {body.get('epoch')}, the Decisions' {epoch}"] * (body.get("epoch", 1) != epoch)
    results["end"].check(not problems, f"{seen.name}: {'; '.join(problems)}: {ends[0].show()}")


def _token(seen: Seen, results: dict) -> None:
    """[P-2.5] the coordinator's token, from its first Decision to its End (or the flight's end)."""
    real = seen.of(wm.Decision)
    if not real:
        return
    start = real[0].at
    stop = min([h.at for h in seen.of(wm.End)] + [seen.faults.get("takeover", (0, float("inf")))[1], float("inf")])
    alive_at = next((at for at, kind in seen.tokens if kind == "alive"), None)
    gone = [at for at, kind in seen.tokens if kind == "gone" and start < at < stop]
    early = alive_at is not None and alive_at <= start
    results["token"].check(early and not gone, f"{seen.name}: " + ("its token vanished while it decided" if early
                                                                   else "no token before its first Decision"))


def _epochs(seen: Seen, results: dict) -> None:
    if "takeover" not in seen.faults and seen.name != "takeover":
        return
    real = seen.of(wm.Decision)
    if real:
        results["hello-epoch"].check(real[0].message.epoch == 1,
                                     f"{seen.name}: first Decision of epoch {real[0].message.epoch} after a Hello "
                                     f"of epoch {HELLO_EPOCH}")
    if "takeover" in seen.faults:
        _, at = seen.faults["takeover"]
        after = [h for h in real if h.at > at + SETTLE_S] + [h for h in seen.of(wm.End) if h.at > at]
        results["takeover"].check(not after and seen.exit_code is not None,
                                  f"{seen.name}: after a newer epoch's Decision: "
                                  f"{after[0].show() if after else 'its process did not exit'}")
