"""The carrier's side of the stage handshake as a pure state machine.

``step(state, event) -> (state, effects)``. The carrier process (carriers/node.py) owns the
physics, the clock and the network: it tells the machine where it is (events carry the body's
position at that moment) and carries out the effects in order (:class:`Deploy` before the
:class:`SendConfirm` that reports it). Rules (docs/protocol.md, "Stage handshake"):

* each stage's decision is handled **at most once**; a repeated Decision is answered
  ``already`` with the first outcome, nothing happens again;
* a Decision for a stage the carrier has passed (it gave up waiting, or it joined after that
  stage) is answered ``late`` if it selects the carrier, ``idle`` otherwise, never deployed;
* a Decision for a stage the carrier has not reached yet is held until it gets there (the
  carrier is then *behind*: it reaches the stage at once and publishes no Observation); a
  repeat of it is answered ``already`` after it (a rejected Decision changes nothing, not even
  the epoch);
* a selected carrier deploys if it is scheduled at the stage and has a passenger left, else it
  answers ``refused``;
* when no decision comes in time (or the coordinator is gone) the carrier decides the stage
  itself (:class:`DecidedOwn`, its on-board planner's choice): status ``own``, announced in an
  Own message; a coordinator's decision for that stage arriving later is answered ``already``;
* every outcome is written to the carrier's durable log (:class:`LogOutcome`) before the carrier
  acts on it (:class:`Deploy`), and every observation when it is made (:class:`LogObservation`);
* when the coordinator comes back, the carrier resynchronises from State (:class:`Resync`) and
  repeats its answers and its own decisions;
* a Hello with no answer for its retry time (it was lost on the link) is said again
  (:class:`HelloUnanswered`), with the pending Observation and the answers since the join;
* a Decision of a ballot (epoch, coordinator id: :mod:`mission.ballot`) below the highest the
  carrier has heard (in a Decision or a State) comes from a deposed coordinator: rejected
  (``deposed``), never answered; so is an End that states a lower one (an End that states no
  epoch, of an earlier revision, ends the mission);
* a Decision that arrives while the Decision of an earlier stage the carrier needs never did
  (they arrive in order: that one was lost) makes it ask State first (:class:`AskState`) and
  take the lost stages from it (:class:`Resync` with ``gap``).
"""
from __future__ import annotations

from dataclasses import dataclass, field

from .ballot import Ballot
from .evolve import evolve
from .timeouts import T_TOLERANCE_S

Point = tuple[float, float]


# --------------------------------------------------------------------------- events

@dataclass(frozen=True)
class Replayed:
    """At join: a deployment on record at ``stage`` was replayed in the carrier's world (the
    body advanced to t_j and released a passenger at ``position``)."""

    stage: int
    position: Point


@dataclass(frozen=True)
class Recalled:
    """At join: the carrier's own log holds how it resolved ``stage``, a stage the coordinator
    has not decided (State's next_stage is not past it): it decided it on board while the
    coordinator was away (``own``, with what it sensed, ``x``). The answer stands as it was
    (it is never acted on again); after its Hello, its account goes to the coordinator again
    (:func:`accounts`)."""

    stage: int
    status: str
    deployed: bool
    position: Point
    x: int | None = None


@dataclass(frozen=True)
class Missed:
    """At join: the record lists a deployment of this carrier at ``stage`` that its own log has no
    outcome for (:func:`missed`): the Decision never reached it; answered ``late``."""

    stage: int
    position: Point


@dataclass(frozen=True)
class Joined:
    """The first State answer: the carrier joins at ``next_stage`` (or the mission has ended)."""

    next_stage: int
    ended: bool = False
    epoch: int = 1
    coordinator: str = ""


@dataclass(frozen=True)
class DecisionHeard:
    """A Decision of ``stage`` (at ``t`` s) arrived; ``position``: where the carrier is now."""

    stage: int
    t: float
    deploy: tuple[str, ...]
    position: Point
    epoch: int = 1
    coordinator: str = ""


@dataclass(frozen=True)
class Observed:
    """The carrier sensed ``x`` (None = ∅) at ``stage`` at ``position``, published its
    Observation and waits for the decision."""

    stage: int
    x: int | None = None
    position: Point = (0.0, 0.0)


@dataclass(frozen=True)
class DecidedOwn:
    """No decision of ``stage`` came in time: the carrier's own planner says ``deploy``."""

    stage: int
    deploy: bool
    position: Point


@dataclass(frozen=True)
class Passed:
    """The carrier is at t_j of a stage decided without it (behind): answer its decision if it
    arrived, and go on."""

    stage: int
    position: Point


@dataclass(frozen=True)
class MovedOn:
    """The carrier leaves ``stage`` (its decision was handled, lost, or timed out)."""

    stage: int


@dataclass(frozen=True)
class StateSeen:
    """What a State reply says (docs/protocol.md, "State"), for :class:`Resync`."""

    next_stage: int
    deployments: tuple[int, ...]
    last_decision: tuple[int, float, tuple[str, ...]] | None  # (stage, t, deploy)
    ended: bool
    epoch: int = 1
    coordinator: str = ""


@dataclass(frozen=True)
class Resync:
    """The coordinator's token reappeared; ``state``: its State reply (None if none came).
    ``gap``: not the token, but a Decision of stage ``gap`` that came without the one(s)
    before it (:class:`AskState`): the lost stages are taken from ``state``."""

    state: StateSeen | None
    position: Point
    gap: int | None = None


@dataclass(frozen=True)
class Collecting:
    """Sim clock, a long wait for a Decision: the coordinator's State says it is still collecting
    ``stage`` (its ``next_stage``), in ``epoch``."""

    stage: int
    epoch: int = 1
    coordinator: str = ""


@dataclass(frozen=True)
class HelloUnanswered:
    """The carrier's latest Hello has had no answer for its retry time while the coordinator's
    token was present (:func:`mission.timers.hello_again`): it was lost on the way, so were the
    messages since (rejected ``no-hello``); say them again ([P-5.14])."""

    position: Point


@dataclass(frozen=True)
class EndHeard:
    """End arrived, from a coordinator of ``epoch`` (None: the End states none, as before
    revision 4) and ``coordinator`` ("": not stated, as before revision 6)."""

    epoch: int | None = None
    coordinator: str = ""


# --------------------------------------------------------------------------- effects

@dataclass(frozen=True)
class Deploy:
    """Release one passenger now (the body is at the stage's position)."""

    stage: int


@dataclass(frozen=True)
class SendConfirm:
    stage: int
    deployed: bool
    status: str
    position: Point
    passengers_left: int


@dataclass(frozen=True)
class SendOwn:
    """Publish an Own message: the carrier decided ``stage`` itself."""

    stage: int
    x: int | None
    deployed: bool
    position: Point
    passengers_left: int


@dataclass(frozen=True)
class LogObservation:
    """Write the observation of ``stage`` to the carrier's durable log."""

    stage: int
    x: int | None
    position: Point


@dataclass(frozen=True)
class LogOutcome:
    """Write how ``stage`` was resolved to the durable log; comes before the :class:`Deploy` and
    the message that report it."""

    stage: int
    status: str
    deployed: bool
    position: Point
    passengers_left: int


@dataclass(frozen=True)
class SendHello:
    """Publish Hello with ``next_stage`` (where the carrier goes on from); ``again``: the latest
    one had no answer ([P-5.14]: the retry time doubles, :class:`HelloAnswer`)."""

    next_stage: int
    passengers_left: int
    again: bool = False


@dataclass(frozen=True)
class ResendObservation:
    """Publish the pending Observation again (its stage is still open at the coordinator)."""

    stage: int


@dataclass(frozen=True)
class AskState:
    """Resynchronise from the coordinator's State now (:class:`Resync` with ``gap`` ``stage``):
    the Decision of ``stage`` came and the Decision of a stage before it, which this carrier
    waits for or will reach, never did (docs/protocol.md, [P-6.6])."""

    stage: int


@dataclass(frozen=True)
class Reject:
    reason: str
    detail: str


@dataclass(frozen=True)
class Log:
    line: str


# --------------------------------------------------------------------------- state

@dataclass(frozen=True)
class Answer:
    """A carrier's (first) answer to one stage's decision (``status`` ``own``: it decided the
    stage itself, having observed ``x``)."""

    deployed: bool
    status: str
    position: Point
    passengers_left: int
    x: int | None = None

    @property
    def own(self) -> bool:
        return self.status == "own"




@dataclass(frozen=True)
class Handshake:
    """One carrier's view of the mission.

    Attributes:
        cid: its id; valid: ``[N]`` scheduled at stage j; stage_times: ``[N]`` t_j seconds.
        passengers_left: passengers on board.
        stage: the stage it is at (driving to, observing or waiting for).
        joined: the first stage this process handles itself (State's next_stage at join).
        handled: stage -> the first :class:`Answer`.
        buffered: stage -> deploy ids of a decision for a stage not reached yet.
        repeats: stages in ``buffered`` whose decision came again (answered ``already`` too).
        latest_decided: the highest stage a Decision was heard for (-1: none).
        state_next: the coordinator's next_stage, as last learnt from State.
        pending: the stage of the Observation waiting for its decision, or None.
        sensed: what the carrier observed at ``pending`` (None = ∅).
        ended: End was heard (or State says the mission ended).
        epoch: the highest coordinator epoch heard (Decision, State); 0 before any.
        coordinator: the coordinator id of the highest ballot heard ("": none stated).
        outranked: the last Decision or End heard came from a deposed coordinator (a ballot
            below the highest heard) and no current Decision or State came since: the live
            coordinator does not decide (:mod:`mission.carrier_life` takes it as absent).
        flying: it joined (:class:`Joined`): from then on it handles its stages.
    """

    cid: str
    valid: tuple[bool, ...]
    stage_times: tuple[float, ...]
    passengers_left: int
    stage: int = 0
    joined: int = 0
    handled: dict = field(default_factory=dict)
    buffered: dict = field(default_factory=dict)
    latest_decided: int = -1
    state_next: int = 0
    pending: int | None = None
    sensed: int | None = None
    ended: bool = False
    epoch: int = 0
    coordinator: str = ""
    outranked: bool = False
    repeats: frozenset = frozenset()
    flying: bool = False

    @property
    def n_stages(self) -> int:
        return len(self.stage_times)

    def decided_upto(self) -> int:
        """Stages known to be decided already (0..N): the carrier is behind the coordinator at
        every stage below this."""
        return max(self.latest_decided + 1, self.state_next)

    def behind(self, j: int) -> bool:
        return j < self.decided_upto()

    def resolved(self, j: int) -> bool:
        """The wait for stage j's decision is over: answered, or the coordinator moved on."""
        return j in self.handled or self.latest_decided > j or self.state_next > j

    def hello_stage(self) -> int:
        return min(max(self.stage, self.state_next), self.n_stages)

    def deployments(self) -> tuple[int, ...]:
        return tuple(sorted(j for j, a in self.handled.items() if a.deployed))

    @property
    def ballot(self) -> Ballot:
        """The highest ballot heard (docs/protocol.md [P-7.2])."""
        return Ballot(self.epoch, self.coordinator)

    def hearing(self, epoch: int, coordinator: str = "") -> "Handshake":
        """This state once a current Decision or State of ballot ``(epoch, coordinator)`` is heard."""
        top = self.ballot.highest(Ballot(epoch, coordinator))
        if top == self.ballot and not self.outranked:
            return self
        return evolve(self, epoch=top.epoch, coordinator=top.coordinator, outranked=False)


def current(state: Handshake, epoch: int, coordinator: str = "") -> bool:
    """A Decision or State of ballot ``(epoch, coordinator)`` comes from the coordinator that
    decides now: its ballot is not below the highest the carrier has heard (a lower one is a
    deposed coordinator's: :meth:`mission.ballot.Ballot.below`)."""
    return not Ballot(epoch, coordinator).below(state.ballot)


def passenger_for(named: int | None, released, count: int) -> int:
    """The passenger (index ``0..count-1``) a deployment releases: the one the Decision named
    (``named``) if it is still on board, else the lowest index on board (a stage decided on
    board names none). ``released``: the indices released already."""
    gone = set(released)
    if named is not None and named not in gone and named < count:
        return named
    return next((i for i in range(count) if i not in gone), 0)


class HelloAnswer:
    """The coordinator's answer to the carrier's latest Hello (docs/protocol.md, "Refusal",
    "Accepted"): only the answer to the latest Hello counts; one naming another fingerprint, or
    coming after that Hello was answered, is about someone else's.

    Attributes:
        fingerprint: the carrier's world fingerprint.
        unanswered: None before any Hello; True while the latest one is not answered yet.
        refused: the Refusal of the latest Hello (any object the process hands in), else None.
        at: when the latest Hello went out (the caller's clock, s).
        tries: the Hellos said again since the latest of a join or a Resync ([P-5.14]).
    """

    def __init__(self, fingerprint: str):
        self.fingerprint = fingerprint
        self.unanswered: bool | None = None
        self.refused = None
        self.at = 0.0
        self.tries = 0

    @property
    def said_hello(self) -> bool:
        return self.unanswered is not None

    def sent(self, at: float = 0.0, again: bool = False) -> None:
        """A Hello went out at ``at``; ``again``: the previous one had no answer."""
        self.unanswered = True
        self.at = float(at)
        self.tries = self.tries + 1 if again else 0

    def answered(self, fingerprint: str, refusal=None) -> bool:
        """An answer naming ``fingerprint`` arrived (``refusal``: the Refusal, None for Accepted);
        True when it is the answer to the latest Hello (and taken)."""
        if fingerprint != self.fingerprint or not self.unanswered:
            return False
        self.unanswered = False
        self.refused = refusal
        return True


class Releases:
    """Which passenger each stage releases (docs/protocol.md, Decision): the one a current
    Decision named for this carrier (the first naming per stage counts), else the lowest index
    on board. Fed by the carrier process; no clock, no I/O.

    Args:
        count: the carrier's passengers.
    """

    def __init__(self, count: int):
        self.count = int(count)
        self.named: dict[int, int] = {}     # stage -> the passenger a Decision named
        self.released: dict[int, int] = {}  # stage -> the passenger released there

    def name(self, state: Handshake, stage: int, epoch: int, passenger: int | None, coordinator: str = "") -> None:
        """A Decision of ballot ``(epoch, coordinator)`` named ``passenger`` (None: none) for this
        carrier at ``stage``; a deposed coordinator's naming is ignored."""
        if passenger is not None and current(state, epoch, coordinator):
            self.named.setdefault(stage, passenger)

    def release(self, stage: int) -> int:
        """The carrier deploys at ``stage``: the passenger released (recorded)."""
        self.released[stage] = passenger_for(self.named.get(stage), self.released.values(), self.count)
        return self.released[stage]

    def at(self, stage: int) -> int | None:
        """The passenger released at ``stage``, None when none was."""
        return self.released.get(stage)


@dataclass(frozen=True)
class Timers:
    """What a carrier times its waits by (docs/protocol.md, [P-10.2]).

    Attributes:
        clock: ``sim`` or ``wall`` (:data:`mission.timeouts.CLOCKS`).
        silence_timeout_s: sim clock: a peer silent this long is stalled; a carrier waiting for
            a Decision sends Progress a third of it apart, seconds.
        realtime: the pace, simulated seconds per wall second (0: unpaced).
    """

    clock: str
    silence_timeout_s: float
    realtime: float


def follow(own: Timers, told: Timers | None, repace: bool = True) -> tuple[Timers, tuple[str, ...]]:
    """The timers a carrier started with ``own`` uses once the coordinator told it the
    mission's (``told``: its Accepted of revision 4 or later; None: it said nothing), and one
    log line per setting that differs. The clock and the silence timeout are the coordinator's:
    its waits judge the carrier by them (a carrier sending Progress by a longer silence timeout
    would be taken as stalled; one on the wall clock would decide alone while the coordinator
    waits). The pace is taken only when ``repace`` (a simulated body; a robot moves at its own
    pace, and chose how it reads its clock when it started)."""
    if told is None or told == own:
        return own, ()
    lines = []
    for name, unit in (("clock", ""), ("silence_timeout_s", " s"), ("realtime", "")):
        mine, theirs = getattr(own, name), getattr(told, name)
        if mine != theirs:
            kept = name == "realtime" and not repace
            what = "keeping this carrier's (its body keeps its own pace)" if kept else "following the coordinator"
            lines.append(f"the coordinator's {name} is {theirs}{unit}, this carrier's {mine}{unit}: {what}")
    return Timers(told.clock, told.silence_timeout_s, told.realtime if repace else own.realtime), tuple(lines)


def initial(cid: str, valid, stage_times, passengers: int) -> Handshake:
    return Handshake(cid, tuple(bool(v) for v in valid), tuple(float(t) for t in stage_times), int(passengers))


def replay_plan(state: Handshake, next_stage: int, deployments, logged=None) -> list[int]:
    """The deployments a joining carrier replays in its world, ascending: those before
    ``next_stage``, at most as many as it has passengers. ``deployments``: those on the
    coordinator's record (State); ``logged``: stage -> deployed of the outcomes in the carrier's
    own durable log, None when it has none (a new host). With its log, the log decides: a
    deployment on record it has no outcome for never happened (its Decision never reached the
    carrier: :func:`missed`), one its log holds did, on record or not (its Confirm or Own was lost)."""
    if logged is None:
        stages = set(deployments)
    else:
        stages = {j for j in deployments if logged.get(j)} | {j for j, deployed in logged.items() if deployed}
    return sorted(j for j in stages if j < next_stage)[: state.passengers_left]


def waited_state(seen: StateSeen, j: int, position: Point) -> "Collecting | Resync":
    """What a State says to a carrier that waited long for the Decision of stage j (sim clock,
    [P-10.8]): still collecting j, the coordinator may not have its Observation
    (:class:`Collecting`: it is said again); past j, the Decision was lost on the way; behind j,
    the coordinator lost its Hello or its accounts of the stages since: both resynchronise
    (:class:`Resync`, found by mission.simulate)."""
    if seen.next_stage == j:
        return Collecting(j, seen.epoch, seen.coordinator)
    return Resync(seen, position)


def join_stage(next_stage: int, logged) -> int:
    """Where a joining carrier goes on from: State's ``next_stage``, or after the last stage its
    own log (``logged``: stage -> deployed, None: none) resolved, if later — the stages it
    decided on board while the coordinator was away are done (:class:`Recalled`), never again."""
    return max(next_stage, max(logged, default=-1) + 1) if logged else next_stage


def missed(next_stage: int, deployments, logged) -> list[int]:
    """The deployments on record (State) before ``next_stage`` whose Decision never reached the
    carrier (its durable log, ``logged``, has no outcome there): it answers them ``late``
    (:class:`Missed`), so the record counts the passenger as still on board. None without a log."""
    if logged is None:
        return []
    return sorted(j for j in deployments if j < next_stage and j not in logged)


# --------------------------------------------------------------------------- step

def step(state: Handshake, event) -> tuple[Handshake, tuple]:
    handler = _HANDLERS.get(type(event))
    if handler is None:
        raise TypeError(f"not a carrier event: {event!r}")
    return handler(state, event)


def _answer(state: Handshake, j: int, deploy, position: Point, allow: bool):
    """Execute (or decline) one decision and confirm it: at most once per stage."""
    selected = state.cid in deploy
    effects = []
    left = state.passengers_left
    if not selected:
        status, deployed = "idle", False
    elif not allow:
        status, deployed = "late", False
    elif left <= 0 or not state.valid[j]:
        status, deployed = "refused", False
    else:
        status, deployed = "deployed", True
        left -= 1
    answer = Answer(deployed, status, (float(position[0]), float(position[1])), left)
    effects.append(LogOutcome(j, status, deployed, answer.position, left))
    if deployed:
        effects.append(Deploy(j))
        effects.append(Log(f"deployed a passenger at stage {j} at ({position[0]:.1f}, {position[1]:.1f}) m"))
    effects.append(SendConfirm(j, deployed, status, answer.position, left))
    if j in state.repeats:  # the repeat of a decision held until the stage (see _on_decision)
        effects.append(SendConfirm(j, deployed, "already", answer.position, left))
    new = evolve(state, passengers_left=left, handled={**state.handled, j: answer},
                 buffered={k: v for k, v in state.buffered.items() if k != j},
                 repeats=state.repeats - {j})
    return new, effects


def _already(state: Handshake, j: int) -> SendConfirm:
    first = state.handled[j]
    return SendConfirm(j, first.deployed, "already", first.position, first.passengers_left)


def _on_replayed(state: Handshake, e: Replayed):
    if state.passengers_left <= 0:
        raise ValueError("no passenger left to replay a deployment")
    left = state.passengers_left - 1
    answer = Answer(True, "deployed", (float(e.position[0]), float(e.position[1])), left)
    return evolve(state, passengers_left=left, handled={**state.handled, e.stage: answer}), ()


def _early_observation(state: Handshake, j: int) -> tuple:
    """A Decision of j came while this carrier is at a later stage (it gave up waiting for j, or
    decided j and more on its own while cut off): the coordinator was behind it, so its
    Observation of the stage it is at arrived too early and was rejected as future-stage; it is
    sent again, or the coordinator would wait for it as long as the carrier sends Progress."""
    if state.pending is not None and state.pending > j and state.pending >= state.decided_upto():
        return (ResendObservation(state.pending),)
    return ()


def _on_recalled(state: Handshake, e: Recalled):
    if e.stage in state.handled:
        return state, ()
    left = state.passengers_left - int(e.deployed)
    if left < 0:
        raise ValueError("no passenger left for a deployment in the log")
    position = (float(e.position[0]), float(e.position[1]))
    answer = Answer(bool(e.deployed), e.status, position, left, e.x)
    return evolve(state, passengers_left=left, handled={**state.handled, e.stage: answer}), ()


def accounts(state: Handshake, stages) -> tuple:
    """The Own messages that say again how this carrier decided ``stages`` itself (those of them
    it decided on board): after its Hello, a joining carrier's recalled stages ([P-8.5])."""
    return tuple(SendOwn(j, a.x, a.deployed, a.position, a.passengers_left)
                 for j in stages if (a := state.handled.get(j)) is not None and a.own)


def _on_missed(state: Handshake, e: Missed):
    if e.stage in state.handled:
        return state, ()
    return _answer(state, e.stage, (state.cid,), e.position, allow=False)


def _on_collecting(state: Handshake, e: Collecting):
    """State says the coordinator collects the stage this carrier waits at: it may never have
    had this carrier's Observation (rejected as future-stage, or lost in a reconnection); an
    identical repeat is absorbed by the coordinator."""
    if current(state, e.epoch, e.coordinator) and state.pending == e.stage and e.stage not in state.handled:
        return state, (ResendObservation(e.stage),)
    return state, ()


def _on_joined(state: Handshake, e: Joined):
    if e.ended:  # its Hello still says State's next stage [P-5.5]
        return evolve(state, ended=True, state_next=max(state.state_next, e.next_stage)), ()
    effects = (Log(f"joined at stage {e.next_stage} ({len(state.handled)} deployment(s) on record)"),) \
        if e.next_stage > 0 else ()
    return evolve(state.hearing(e.epoch, e.coordinator), stage=e.next_stage, joined=e.next_stage,
                  state_next=max(state.state_next, e.next_stage), flying=True), effects


def _on_decision(state: Handshake, e: DecisionHeard):
    heard = Ballot(e.epoch, e.coordinator)
    if heard.below(state.ballot):
        return evolve(state, outranked=True), (Reject("deposed", f"decision for stage {e.stage} of ballot {heard}; "
                            f"ballot {state.ballot} decides now"),)
    j = e.stage
    if j >= state.n_stages:  # rejected: it raises nothing, not even the epoch
        return state, (Reject("out-of-range", f"decision for stage {j} >= {state.n_stages}"),)
    if abs(e.t - state.stage_times[j]) > T_TOLERANCE_S:
        return state, (Reject("out-of-range", f"t: stage {j} is at {state.stage_times[j]} s, found {e.t}"),)
    newer = state.ballot.below(heard)
    state = state.hearing(e.epoch, e.coordinator)
    if j in state.handled:
        return state, (_already(state, j), *_early_observation(state, j))
    if j < state.stage or j < state.joined:
        # Passed (gave up waiting, or decided before this process joined): too late to deploy.
        new, effects = _answer(state, j, e.deploy, e.position, allow=False)
        return new, (*effects, *_early_observation(state, j))
    if j in state.buffered:
        # A repeat (a re-publication) of a stage not reached yet: answered ``already`` once the
        # first is handled; a newer ballot's decision replaces the one held.
        buffered = {**state.buffered, j: tuple(e.deploy)} if newer else state.buffered
        return evolve(state, buffered=buffered, repeats=state.repeats | {j}), ()
    latest = max(state.latest_decided, j)
    if j == state.stage and state.pending == j:
        new, effects = _answer(state, j, e.deploy, e.position, allow=True)
        return evolve(new, latest_decided=latest), tuple(effects)
    lost = lost_stages(state, j)
    new = evolve(state, buffered={**state.buffered, j: tuple(e.deploy)}, latest_decided=latest)
    # Decisions arrive in order: a later one with an earlier missing means that one was lost;
    # its outcome comes from State before anything is confirmed ([P-6.6]).
    return new, (AskState(j),) if lost else ()


def lost_stages(state: Handshake, j: int) -> tuple[int, ...]:
    """The stages before ``j`` whose Decision this carrier still needs and has not received (it
    waits at them or will reach them, they are not known to be decided from State, it did not
    decide them itself): lost on the way when the Decision of ``j`` arrives. None before it
    joined (a Decision then is held: where it joins is not known yet)."""
    if not state.flying:
        return ()
    start = max(state.stage, state.joined, state.state_next)
    return tuple(t for t in range(start, j) if t not in state.handled and t not in state.buffered)


def _on_observed(state: Handshake, e: Observed):
    x = e.x if state.valid[e.stage] else None
    return (evolve(state, stage=e.stage, pending=e.stage, sensed=x),
            (LogObservation(e.stage, x, (float(e.position[0]), float(e.position[1]))),))


def _on_decided_own(state: Handshake, e: DecidedOwn):
    """The carrier's own decision of the stage it waits at: at most once per stage, like a
    coordinator's; a deployment it cannot make (no passenger, not scheduled) is not made."""
    j = e.stage
    if j in state.handled or state.pending != j or state.resolved(j):
        return state, ()
    left = state.passengers_left
    deployed = bool(e.deploy) and left > 0 and state.valid[j]
    left -= int(deployed)
    position = (float(e.position[0]), float(e.position[1]))
    answer = Answer(deployed, "own", position, left, state.sensed)
    effects = [LogOutcome(j, "own", deployed, position, left)]
    if deployed:
        effects += [Deploy(j), Log(f"deployed a passenger at stage {j} on its own at ({position[0]:.1f}, "
                                   f"{position[1]:.1f}) m")]
    effects.append(SendOwn(j, state.sensed, deployed, position, left))
    return evolve(state, passengers_left=left, handled={**state.handled, j: answer}), tuple(effects)


def _on_passed(state: Handshake, e: Passed):
    j = e.stage
    new, effects = evolve(state, stage=j), []
    if j in state.buffered and j not in state.handled:
        new, effects = _answer(new, j, state.buffered[j], e.position, allow=True)
    return evolve(new, stage=j + 1, pending=None), tuple(effects)


def _on_moved_on(state: Handshake, e: MovedOn):
    return evolve(state, stage=e.stage + 1, pending=None), ()


def _on_resync(state: Handshake, e: Resync):
    """The coordinator came back (restarted, or a partition healed): announce ourselves again,
    learn how far the mission got, take its last decision (its re-publication may have raced
    our reconnection), re-send the pending Observation if its stage is still open, and repeat
    our answers (``already``) so a coordinator that lost Confirms in flight has every outcome."""
    s = e.state
    if s is not None and not current(state, s.epoch, s.coordinator):
        s = None  # a deposed coordinator's view: nothing to learn from it
    new = state
    if s is not None:
        new = evolve(new.hearing(s.epoch, s.coordinator), state_next=max(new.state_next, s.next_stage))
    effects: list = [Log("coordinator is back; re-sending hello and the pending observation") if e.gap is None
                     else Log(f"the Decision of stage {e.gap} came without the one(s) before it; "
                              + ("taking them from State" if s is not None else "no State answered"))]
    if s is not None and e.gap is not None:
        new, more = _take_lost(new, s, e.position)
        effects += more
    effects.append(SendHello(new.hello_stage(), new.passengers_left))
    if s is not None:
        last = s.last_decision
        for j in s.deployments:
            if (j < s.next_stage and j <= new.stage and j not in new.handled
                    and j not in new.buffered and (last is None or j != last[0])):
                # Decided for us while we were cut off and never received: we did not deploy
                # there. Saying so lets the coordinator count the passenger as still on board.
                new, more = _answer(new, j, (new.cid,), e.position, allow=False)
                effects += more
        if last is not None and last[0] not in new.handled and last[0] not in new.buffered:
            new, more = _on_decision(new, DecisionHeard(last[0], last[1], tuple(last[2]), e.position, s.epoch,
                                                        s.coordinator))
            effects += more
        if s.ended:
            new = evolve(new, ended=True)
    effects += _said_again(new)
    return new, tuple(_dedupe(effects))


def _said_again(state: Handshake) -> list:
    """After a Hello of a Resync or said again: the pending Observation if its stage is still
    open, and the answer to every stage handled since the join (Confirm ``already``, or its Own):
    what a coordinator that missed them (or rejected them before the Hello) needs."""
    effects: list = []
    if state.pending is not None and state.pending >= state.state_next and state.pending not in state.handled:
        effects.append(ResendObservation(state.pending))
    for j in sorted(state.handled):
        if j >= state.joined:
            a = state.handled[j]
            effects.append(SendOwn(j, a.x, a.deployed, a.position, a.passengers_left) if a.own else _already(state, j))
    return effects


def _on_hello_unanswered(state: Handshake, e: HelloUnanswered):
    """[P-5.14]: Hello again, then what went out since the lost one (a Resync without a State)."""
    if state.ended or not state.flying:
        return state, ()
    return state, (Log("no answer to its Hello; saying it again"),
                   SendHello(state.hello_stage(), state.passengers_left, again=True), *_said_again(state))


def _take_lost(state: Handshake, s: StateSeen, position: Point):
    """[P-6.6]: every stage from the one this carrier is at up to State's ``next_stage`` whose
    Decision it has not received is held as the coordinator sees it (selecting this carrier
    when State lists a deployment of it there, else not), so it deploys where the coordinator
    counts a deployment; the stage it waits at (its body at t_j) is answered now, the others
    as it passes them."""
    held = dict(state.buffered)
    for t in range(max(state.stage, state.joined), min(s.next_stage, state.n_stages)):
        if t not in state.handled and t not in held:
            held[t] = (state.cid,) if t in s.deployments else ()
    new = evolve(state, buffered=held)
    j = new.pending
    if j is not None and j == new.stage and j in held and j not in new.handled:
        return _answer(new, j, held[j], position, allow=True)
    return new, []


def _dedupe(effects):
    """A Confirm sent in this step is not repeated as ``already`` in the same step."""
    sent = set()
    for effect in effects:
        if isinstance(effect, SendConfirm):
            if effect.stage in sent:
                continue
            sent.add(effect.stage)
        yield effect


def _on_end(state: Handshake, e: EndHeard):
    if e.epoch is not None and not current(state, e.epoch, e.coordinator):  # a deposed coordinator cannot end it [P-7.4]
        return evolve(state, outranked=True), (Reject("deposed", f"End of ballot {Ballot(e.epoch, e.coordinator)}; "
                            f"ballot {state.ballot} decides now"),)
    return evolve(state, ended=True), ()


_HANDLERS = {
    Replayed: _on_replayed, Joined: _on_joined, DecisionHeard: _on_decision, Observed: _on_observed,
    Passed: _on_passed, MovedOn: _on_moved_on, Resync: _on_resync, EndHeard: _on_end, DecidedOwn: _on_decided_own,
    Collecting: _on_collecting, Missed: _on_missed, Recalled: _on_recalled, HelloUnanswered: _on_hello_unanswered,
}
