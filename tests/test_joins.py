"""A carrier's join paths (mission/joins.py), the one implementation the carrier process and the
simulator drive: what each path asks of its driver, in order, and what it leaves in the machine
and the book."""
from __future__ import annotations

from mission import carrier as mc
from mission import joins
from mission import timers as tm
from mission.peers import PeerBook
from mission.simulate.model import LogEntry

TIMES = (0.0, 10.0, 20.0, 30.0, 40.0, 50.0)


def fresh(passengers: int = 3):
    return mc.initial("a", (True,) * len(TIMES), TIMES, passengers), PeerBook(("a", "b"), [[True] * 6, [True] * 6])


class Driver:
    """A driver that records what a path asks (a body at stage ``at``; positions (stage, 0))."""

    def __init__(self, machine):
        self.machine, self.at, self.asked = machine, 0, []

    def __call__(self, asked):
        self.asked.append(asked)
        if isinstance(asked, joins.Drive):
            self.at = asked.stage
        if isinstance(asked, (joins.Drive, joins.Here)):
            return (float(self.at), 0.0)
        if isinstance(asked, joins.Apply):
            self.machine, _ = mc.step(self.machine, asked.event)
            return self.machine
        return None

    def kinds(self):
        return [type(a).__name__ if not isinstance(a, (joins.Apply, joins.Execute))
                else type(getattr(a, "event", getattr(a, "effect", None))).__name__ for a in self.asked]


def test_a_join_from_state_replays_the_record_recalls_its_own_stages_then_says_hello():
    """State: stages 0..2 decided, a deployed at 1 on record; its log: 1 deployed (Confirm), 3
    decided on board (deployed, Own): the deployment replayed at 1, stage 3 recalled and replayed,
    Joined at 4 (after its log), Hello, then its Own of 3 said again."""
    machine, book = fresh()
    entries = [LogEntry(1, 10.0, 2, True, status="deployed", deployed=True),
               LogEntry(3, 30.0, 4, True, status="own", deployed=True)]
    seen = mc.StateSeen(3, (1,), None, False)
    d = Driver(machine)
    tm.drive(joins.from_state(machine, seen, entries, book), d)
    assert d.kinds() == ["Drive", "Replayed", "Release", "Drive", "Recalled", "Release", "Joined", "SendHello",
                         "SendOwn"]
    assert [a.stage for a in d.asked if isinstance(a, (joins.Drive, joins.Release))] == [1, 1, 3, 3]
    assert d.machine.stage == 4 and d.machine.passengers_left == 1
    assert book.deployed[book.index["a"], [1, 3]].tolist() == [True, True]


def test_a_deployment_on_record_it_never_made_is_answered_late_after_its_hello():
    """State says a deployed at 1; its log has no outcome of stage 1 (the Decision never reached
    it): nothing replayed, Joined, Hello, then Missed(1) (late)."""
    machine, book = fresh()
    entries = [LogEntry(0, 0.0, 2, True, status="idle", deployed=False), LogEntry(1, 10.0, 3, True)]
    d = Driver(machine)
    tm.drive(joins.from_state(machine, mc.StateSeen(2, (1,), None, False), entries, book), d)
    assert d.kinds() == ["Joined", "SendHello", "Here", "Missed"]
    assert d.machine.passengers_left == 3


def test_a_join_into_an_ended_mission_replays_nothing():
    machine, book = fresh()
    d = Driver(machine)
    tm.drive(joins.from_state(machine, mc.StateSeen(6, (0, 2), None, True), (), book), d)
    assert d.kinds() == ["Joined", "SendHello"] and d.machine.ended


def test_joining_alone_replays_its_log_and_returns_the_stage_after_it():
    machine, book = fresh(passengers=1)
    entries = [LogEntry(0, 0.0, 1, True, status="idle"), LogEntry(1, 10.0, 5, True, status="deployed", deployed=True),
               LogEntry(2, 20.0, None, False)]  # stage 2 observed nothing yet: not resolved
    d = Driver(machine)
    assert tm.drive(joins.alone(machine, entries, book), d) == 2
    assert d.kinds() == ["Drive", "Replayed", "Release"]
    r = book.index["a"]
    assert book.deployed[r, :3].tolist() == [False, True, False] and book.x[r, :2].tolist() == [1.0, 5.0]
