"""What a conformance flight is about and what the kit saw of it: the carrier under test with the
scenario's truth about it (:class:`Target`), every message seen (:class:`Seen`, :class:`Flight`),
and the observer that files the router's traffic into a flight (:class:`Observer`)."""
from __future__ import annotations

import json
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgpack

from .. import keys
from .. import messages as wm

#: Topics of the carrier under test that the kit records.
CARRIER_TOPICS = ("hello", "obs", "confirm", "own", "bye", "pose", "progress")
#: The unanswered flight: the kit answers the carrier's Hello of this number (the earlier are lost).
UNANSWERED = 3


@dataclass(frozen=True, eq=False)
class Target:
    """The carrier under test and what the scenario says it must do.

    Attributes:
        scenario_path: the scenario file, absolute.
        scenario: the loaded scenario, with the kit's seed.
        cid: the carrier's id; ``r`` its index among the scenario's carriers.
        seed: the root seed (the fingerprint's).
        mission: the mission id (key prefix ``marsupial/<mission>/``).
        n: stages; ``times``: t_j of every stage, seconds, [n].
        valid: whether the carrier is scheduled at stage j, [n]; ``x``: the world's
            observation of the carrier at stage j, [n].
        passengers: passengers it starts with.
        fingerprint: the coordinator's scenario fingerprint.
    """

    scenario_path: str
    scenario: Any
    cid: str
    r: int
    seed: int
    mission: str
    n: int
    times: list[float]
    valid: Any
    x: Any
    passengers: int
    fingerprint: str

    @classmethod
    def load(cls, scenario_path: str, carrier: str, seed: int | None = None) -> Target:
        """Raises ValueError (one line naming ``--carrier``) if the scenario has no such carrier."""
        import world

        path = str(Path(scenario_path).resolve())
        scenario = world.load_scenario(path)
        if seed is not None:
            scenario = scenario.with_seed(int(seed))
        if carrier not in scenario.carrier_ids:
            raise ValueError(f"--carrier: {carrier!r} is not a carrier of {scenario_path} "
                             f"({', '.join(scenario.carrier_ids)})")
        r = scenario.carrier_index(carrier)
        return cls(scenario_path=path, scenario=scenario, cid=carrier, r=r, seed=int(scenario.seed),
                   mission=keys.mission_id_from_name(scenario.name), n=scenario.stages,
                   times=[float(t) for t in scenario.stage_times()], valid=scenario.valid()[r],
                   x=world.observe_all(scenario)[r], passengers=int(scenario.carriers[r].passengers),
                   fingerprint=wm.scenario_fingerprint(scenario))


@dataclass
class Seen:
    """A message the kit saw: when (monotonic s), on which topic, its payload, decoded or not."""

    at: float
    topic: str
    payload: bytes
    message: Any = None
    error: str | None = None
    fake: bool = False  # published by the kit (a fault), not by the coordinator

    def show(self) -> str:
        try:
            return json.dumps(msgpack.unpackb(self.payload), default=str)[:240]
        except Exception:
            return repr(self.payload[:80])


@dataclass
class Flight:
    """Everything the kit saw of one mission, in order."""

    carrier: list = field(default_factory=list)  # Seen of the carrier under test
    decisions: list = field(default_factory=list)  # Seen of Decisions (the coordinator's and fakes)
    refusals: list = field(default_factory=list)
    ends: list = field(default_factory=list)
    coordinator_back: list = field(default_factory=list)  # times its token reappeared after a restart
    faults: dict = field(default_factory=dict)  # fault -> (stage, time or window)
    rejected: Counter = field(default_factory=Counter)  # coordinator's counts for the carrier
    exit_code: int | None = None
    output: str = ""
    name: str = "project"  # the flight (kit.FLIGHTS)
    revision: int | None = None  # the revision the kit's own coordinator speaks (None: the project's)
    accepted: list = field(default_factory=list)  # Seen of Accepted to the carrier
    fakes: set = field(default_factory=set)  # payloads of the kit's fakes, which the carrier must ignore
    state_queries: list = field(default_factory=list)  # when the carrier asked the kit's coordinator for State

    def decided(self, stage: int) -> bool:
        """The coordinator's (not a fake) Decision of ``stage`` has been seen."""
        return any(d.message.stage == stage and not d.fake for d in self.decisions)

    def heard_epoch(self, epoch: int) -> bool:
        """The carrier shows it heard ``epoch``: a Hello of that epoch, or an answer to a Decision of
        that epoch (a Confirm of its stage after it went out)."""
        if any(isinstance(s.message, wm.Hello) and s.message.epoch >= epoch for s in self.carrier):
            return True
        heard = [(d.at, d.message.stage) for d in self.decisions if not d.fake and d.message.epoch >= epoch]
        return any(isinstance(s.message, wm.Confirm) and s.message.stage == stage and s.at >= at
                   for at, stage in heard for s in self.carrier)


class Observer:
    """Files what the kit's router hears of the mission into a :class:`Flight`: the carrier under
    test's messages, the Decisions, its Refusals, End and the coordinator's token; and asks the
    coordinator (State) how many of that carrier's messages it rejected, per coordinator process.

    Args:
        target: the carrier under test.
        flight: where everything goes.
        node: the kit's router (wire.transport.Node); the observer subscribes to the mission's keys
            and watches the coordinator's token on it.
    """

    def __init__(self, target: Target, flight: Flight, node: Any):
        self.target, self.flight, self.node = target, flight, node
        self.gone = False  # the coordinator's token has vanished and not reappeared
        self.rejected_now: Counter = Counter()  # the current coordinator process's counts
        node.subscribe(f"{keys.prefix(target.mission)}/**")
        node.watch_liveliness(keys.coordinator_alive(target.mission))

    def take(self, item: Any) -> Seen | None:
        """One item of the router's inbox: the coordinator's token changes are noted, a message is
        recorded (:meth:`record`)."""
        if item.kind in ("alive", "gone"):
            if item.kind == "gone":
                self.gone = True
            elif self.gone:
                self.gone = False
                self.flight.coordinator_back.append(item.received)
            return None
        return self.record(item)

    def record(self, item: Any) -> Seen | None:
        """The Seen of a message the kit keeps (None for one it does not, or its own fake)."""
        t, f = self.target, self.flight
        parsed = keys.parse_carrier_key(t.mission, item.key)
        if parsed is not None:
            cid, topic = parsed
            if cid != t.cid or topic not in CARRIER_TOPICS:
                return None
            seen = Seen(item.received, topic, item.payload)
            try:
                seen.message = wm.decode(item.payload)
            except wm.ProtocolError as exc:
                seen.error = f"{exc.reason}: {exc.detail}"
            f.carrier.append(seen)
            return seen
        if item.payload in f.fakes:
            return None  # the kit's own fake, on record where it was made
        if item.key == keys.accepted_key(t.mission, t.cid):
            seen = Seen(item.received, "accepted", item.payload)
            try:
                seen.message = wm.decode(item.payload, wm.Accepted)
            except wm.ProtocolError:
                return None
            f.accepted.append(seen)
            return seen
        if item.key == keys.decision_key(t.mission):
            if any(d.fake and d.payload == item.payload for d in f.decisions):
                return None  # our own fault, already on record
            seen = Seen(item.received, "decision", item.payload)
            try:
                seen.message = wm.decode(item.payload, wm.Decision)
            except wm.ProtocolError:
                return None
            duplicate = "duplicate" in f.faults and any(d.payload == item.payload for d in f.decisions)
            seen.fake = duplicate and f.faults["duplicate"][1] <= item.received
            f.decisions.append(seen)
            return seen
        if item.key == keys.refusal_key(t.mission, t.cid):
            seen = Seen(item.received, "refusal", item.payload)
            f.refusals.append(seen)
            return seen
        if item.key == keys.end_key(t.mission):
            seen = Seen(item.received, "end", item.payload)
            f.ends.append(seen)
            return seen
        return None

    def settle(self, seconds: float) -> None:
        """Record what arrives for ``seconds`` while the coordinator is stopped: a Decision it
        published just before the stop arrives here, not after the kit's fake one."""
        until = time.monotonic() + seconds
        while (left := until - time.monotonic()) > 0:
            item = self.node.next(left)
            if item is not None and item.kind not in ("alive", "gone"):
                self.record(item)

    def poll_rejections(self) -> None:
        """Ask the coordinator for its rejection counts of the carrier (no answer: keep the last)."""
        selector = keys.state_selector(self.target.mission, self.target.cid, wm.REVISION)
        for payload in self.node.query(selector, timeout_s=0.5):
            try:
                state = wm.decode(payload, wm.State)
            except wm.ProtocolError:
                continue
            mine = state.carrier(self.target.cid)
            if mine is not None:
                self.rejected_now = Counter(dict(mine.rejected))
                return

    def bank_rejections(self) -> None:
        """The current coordinator process's counts go to the flight: it is being replaced (a new
        process counts from zero) or the flight is over."""
        self.flight.rejected += self.rejected_now
        self.rejected_now = Counter()
