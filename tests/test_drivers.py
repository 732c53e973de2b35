"""The processes' waits are drivers of mission.timers: with the clock given (no socket, no wall
time) a carrier's and a coordinator's waits do what the rules say at the times they say
(docs/architecture.md, "Time as an input")."""
from __future__ import annotations

import dataclasses
import threading
from pathlib import Path
from types import SimpleNamespace

import pytest

import world
from carriers.exits import Exit
from carriers.node import Carrier, CarrierConfig
from mission import carrier as mc
from mission import carrier_life as cl
from mission import timers as tm

ROOT = Path(__file__).resolve().parents[1]
TINY = world.load_scenario(ROOT / "scenarios" / "tiny.yaml")


class FakeClock:
    def __init__(self, now: float = 1000.0):
        self.now = now

    def __call__(self) -> float:
        return self.now


class QuietNode:
    """A node nothing arrives on: waiting in its inbox only lets the given clock run. It records
    the State queries (at the clock's time) and stops the carrier after ``queries`` of them."""

    revision = 4

    def __init__(self, clock: FakeClock, stop: threading.Event, queries: int = 3):
        self.clock, self.stop, self.queries, self.asked, self.puts = clock, stop, queries, [], []

    def next(self, timeout_s: float):
        self.clock.now += max(0.0, timeout_s)
        return None

    def drain(self):
        return []

    def query(self, selector, timeout_s):
        self.asked.append(self.clock.now)
        self.clock.now += timeout_s  # no reply: the query waits its whole time
        if len(self.asked) >= self.queries:
            self.stop.set()
        return []

    def put(self, key, msg, *args):
        self.puts.append((self.clock.now, key.rsplit("/", 1)[-1]))

    def reject(self, *args):
        raise AssertionError(args)

    def wake(self):
        pass


def carrier_at_stage_0(mode: str, clock_name: str = "sim", **timeouts):
    """The tiny mission's first carrier waiting for the Decision of stage 0 (its lifecycle in
    phase ``wait``), its node quiet: the real carrier's loop (:meth:`Carrier.fly`) over the
    given clock."""
    stop = threading.Event()
    config = CarrierConfig(carrier=TINY.carrier_ids[0], mode=mode, clock=clock_name, log=lambda line: None,
                           **timeouts)
    clock = FakeClock()
    carrier = Carrier(TINY, config, None, stop=stop, clock=clock)  # its presence and motion made on that clock
    carrier.crew.motion.body = SimpleNamespace(time=0.0, position=lambda cid: (0.0, 0.0),  # a body standing still
                                          deploy=lambda cid: None)
    carrier.node = QuietNode(clock, stop)
    carrier.timers = mc.Timers(clock_name, config.silence_timeout_s, 0.0)
    carrier.machine, _ = mc.step(carrier.machine, mc.Joined(0))
    carrier.machine, _ = mc.step(carrier.machine, mc.Observed(0, 1, (0.0, 0.0)))
    carrier.life = dataclasses.replace(carrier.life, phase=cl.Phase.WAIT, stage=0,
                                       wait=tm.DecisionWait.opened(clock.now))
    return carrier, clock


def at_stage_0(life) -> bool:
    return life.phase is not cl.Phase.WAIT


def test_a_carrier_waiting_on_the_sim_clock_asks_state_every_decision_timeout():
    """[P-10.8] the coordinator present, sim clock: State asked once per decision timeout of
    the carrier's clock (the query's own 2 s count as waiting), never deciding alone; Progress
    every third of the silence timeout meanwhile [P-10.6]."""
    carrier, clock = carrier_at_stage_0("coordinated", decision_timeout_s=30.0, silence_timeout_s=9.0)
    carrier.crew.inbound.presence.coordinator_alive()
    start = clock.now
    carrier.fly(until=at_stage_0)
    asked = [t - start for t in carrier.node.asked]
    assert asked == [30.0, 60.0, 90.0]
    progress = [t - start for t, topic in carrier.node.puts if topic == "progress"]
    assert progress and all(b - a >= 3.0 for a, b in zip(progress, progress[1:]))
    assert not carrier.machine.resolved(0) and carrier.reason == "stopped"


@pytest.mark.parametrize("revision, present, expected", [
    (4, True, [0.0, 10.0, 30.0, 70.0]),  # unanswered: again after 10, 20, 40 s (the retry time doubling)
    (2, True, [0.0]),                    # a coordinator of revision 1 or 2 sends no Accepted: never again
    (4, False, [0.0]),                   # the coordinator's token absent: its return is a Resync
], ids=["unanswered", "revision-2", "absent"])
def test_a_carrier_says_an_unanswered_hello_again(revision, present, expected):
    """[P-5.14] the real carrier's lifecycle says its Hello again when no answer came, the
    interval doubling, only to a coordinator that answers Hellos and whose token is present."""
    carrier, clock = carrier_at_stage_0("coordinated", decision_timeout_s=30.0, hello_timeout_s=10.0)
    carrier.node.revision = revision
    if present:
        carrier.crew.inbound.presence.coordinator_alive()
    start = clock.now
    carrier.execute(mc.SendHello(0, 1))
    carrier.fly(until=lambda life: at_stage_0(life) or clock.now - start >= 100.0)
    hellos = [t - start for t, topic in carrier.node.puts if topic == "hello"]
    assert len(hellos) == len(expected) and all(e <= h < e + 2.5 for h, e in zip(hellos, expected)), hellos


@pytest.mark.parametrize("mode, expected", [("coordinated", "going on"), ("hybrid", "deciding on board")])
def test_a_carrier_on_the_wall_clock_stops_waiting_after_the_decision_timeout(mode, expected):
    """[P-8.1] wall clock, the coordinator present: the wait ends after the decision timeout of
    the carrier's clock, without asking State."""
    carrier, clock = carrier_at_stage_0(mode, "wall", decision_timeout_s=30.0)
    lines = []
    carrier.config = dataclasses.replace(carrier.config, log=lines.append)
    carrier.crew.inbound.presence.coordinator_alive()
    start = clock.now
    carrier.crew.inbound.listening = ()  # deciding alone: nobody to listen to (its node is quiet)
    carrier.fly(until=at_stage_0)
    assert carrier.node.asked == [] and 30.0 <= clock.now - start < 32.0
    assert carrier.life.phase is (cl.Phase.WORK if mode == "coordinated" else cl.Phase.ALONE)
    assert any(expected in line for line in lines), lines


def test_a_coordinated_carrier_exits_after_the_coordinator_timeout():
    """[P-8.1] the coordinator's token gone: a coordinated carrier holds, then exits
    coordinator-lost once it has been absent for the coordinator timeout of its clock."""
    carrier, clock = carrier_at_stage_0("coordinated", coordinator_timeout_s=30.0)
    carrier.crew.inbound.presence.coordinator_alive()
    gone = clock.now
    carrier.crew.inbound.presence.coordinator_gone(gone)
    carrier.fly()
    assert carrier.reason == "coordinator-lost" and 30.0 <= clock.now - gone < 32.0


def test_a_joining_carrier_asks_state_again_until_the_coordinator_timeout():
    """[P-5.2] no reply: asked again 0.2 s after the last query's end, until the coordinator
    timeout since the first; then [P-5.5] 4 a coordinated carrier exits coordinator-lost."""
    carrier, clock = carrier_at_stage_0("coordinated", coordinator_timeout_s=10.0)
    carrier.machine = mc.initial(carrier.cid, carrier.crew.who.valid, TINY.stage_times(), 1)
    carrier.node.queries = 1000
    start = clock.now
    carrier.step(cl.Start(start))
    carrier.fly()
    asked = [round(t - start, 6) for t in carrier.node.asked]
    assert carrier.reason == "coordinator-lost" and not carrier.machine.flying
    assert asked == [0.0, 2.2, 4.4, 6.6, 8.8]


def alone_at_stage_1(clock_name: str, peer_timeout_s: float = 5.0, silence_timeout_s: float = 9.0):
    """A carrier deciding stage 1 on board (its lifecycle in phase ``alone``) with a given clock:
    the tiny mission's first carrier, its peer (scheduled there) live and silent from now on."""
    carrier, clock = carrier_at_stage_0("hybrid", clock_name, peer_timeout_s=peer_timeout_s,
                                        silence_timeout_s=silence_timeout_s)
    me, peer = TINY.carrier_ids[:2]
    carrier.machine, _ = mc.step(carrier.machine, mc.MovedOn(0))
    carrier.machine, _ = mc.step(carrier.machine, mc.Observed(1, 1, (0.0, 0.0)))
    carrier.crew.motion.pending = SimpleNamespace(stage=1)
    carrier.crew.inbound.listening = (peer,)
    carrier.crew.inbound.presence.peer(peer, True)
    carrier.crew.inbound.presence.heard_from(peer, clock())
    carrier.crew.alone.deploy = lambda j: True  # the planner's choice is not what is tested here
    carrier.life = dataclasses.replace(carrier.life, phase=cl.Phase.ALONE, stage=1, opened=clock.now, deciding=True)
    resent = lambda: [t for t, topic in carrier.node.puts if topic == "obs"]
    return carrier, clock, resent


def test_deciding_alone_on_the_wall_clock_waits_the_peer_timeout():
    """[P-8.4] wall clock: the peer's observation is waited for the peer timeout at most, then
    the carrier decides; it repeats nothing (a wall-clock wait is a deadline)."""
    carrier, clock, resent = alone_at_stage_1("wall", peer_timeout_s=5.0)
    start = clock.now
    carrier.fly(until=lambda life: life.phase is not cl.Phase.ALONE)
    assert carrier.machine.handled[1].status == "own" and carrier.machine.handled[1].deployed
    assert 5.0 <= clock.now - start < 5.1 and resent() == []


def test_deciding_alone_on_the_sim_clock_waits_out_a_silent_peer_and_repeats_its_observation():
    """[P-8.4] sim clock: a peer silent since the wait opened is waited for the silence timeout
    (not the peer timeout); meanwhile the carrier's observation goes out again every third of it;
    a stage settled meanwhile (a Decision came) is not decided on board."""
    carrier, clock, resent = alone_at_stage_1("sim", peer_timeout_s=1.0, silence_timeout_s=9.0)
    start = clock.now
    carrier.fly(until=lambda life: life.phase is not cl.Phase.ALONE)
    assert carrier.machine.handled[1].status == "own"
    assert 9.0 <= clock.now - start < 9.1
    assert [round(t - start) for t in resent()] == [0, 3, 6]
    carrier, clock, resent = alone_at_stage_1("sim", peer_timeout_s=1.0, silence_timeout_s=9.0)
    carrier.apply(mc.DecisionHeard(1, float(TINY.stage_time(1)), (), (0.0, 0.0)))
    carrier.fly(until=lambda life: life.phase is not cl.Phase.ALONE)
    assert carrier.machine.handled[1].status == "idle"


class StraightBody:
    """A body driving along x at 1 m/s; one trajectory sample per simulated second."""

    def __init__(self):
        self.time = 0.0

    def advance_to(self, t: float) -> None:
        self.time = max(self.time, t)

    def trajectory(self, cid):
        import numpy as np

        ts = np.arange(0.0, np.floor(self.time + 1e-9) + 1.0)
        return np.column_stack([ts, ts, np.zeros_like(ts)])


def test_a_paced_body_waits_its_inbox_and_reads_the_carrier_again_after_each_wait():
    """The body in motion (:class:`carriers.motion.Motion`) with a given clock: 4 s of simulated
    time at twice the wall time take 2 s of its clock, spent in the carrier's inbox wait; one Pose
    per simulated second, each with the passengers the carrier has at that look (a deployment
    heard during a wait shows in the next Poses); Progress once per second of its clock."""
    from carriers.motion import Motion, Moving

    clock, stop = FakeClock(), threading.Event()
    motion = Motion("tiny", "a", 1.0, stop, None, clock())
    motion.body = StraightBody()
    node = QuietNode(clock, stop)
    sent = []
    node.put = lambda key, msg, *args: sent.append((clock.now, key.rsplit("/", 1)[-1], msg))
    carrier = {"passengers_left": 2}

    def wait(s):
        clock.now += s
        if clock.now - start >= 1.0:
            carrier["passengers_left"] = 1  # a Decision handled while it waited

    def moving():
        return Moving(node, None, clock, mc.Timers("sim", 9.0, 2.0), 0, carrier["passengers_left"])

    start = clock.now
    # the carrier's driver: it waits, then tells the motion what it is
    tm.drive(motion.advance(4.0, True, moving()), lambda wait_s: (wait(wait_s), moving())[1])
    assert 2.0 <= clock.now - start < 2.1
    poses = [(msg.t, msg.passengers_left) for _, topic, msg in sent if topic == "pose"]
    assert [t for t, _ in poses] == [0.0, 1.0, 2.0, 3.0, 4.0]
    assert poses[0][1] == 2 and poses[-1][1] == 1
    progress = [t - start for t, topic, _ in sent if topic == "progress"]
    assert progress and all(b - a >= 1.0 for a, b in zip(progress, progress[1:]))


def coordinator_waiting(clock_name: str, tmp_path, **timeouts):
    """The tiny mission's coordinator with both carriers live and accepted (revision 4), its
    inbox empty: waiting only lets its clock run."""
    from coordinator.node import Coordinator, CoordinatorConfig
    from mission import events as ev
    from mission import state as ms
    from wire.messages import REVISION

    lines = []
    clock = FakeClock()
    coordinator = Coordinator(TINY, CoordinatorConfig(out_dir=str(tmp_path), clock=clock_name, log=lines.append,
                                                      **timeouts), None, clock=clock)
    coordinator.pump = lambda timeout_s: setattr(clock, "now", clock.now + max(0.0, timeout_s))
    state = coordinator.state
    for cid in TINY.carrier_ids:
        state, _ = ms.step(state, ev.LivelinessChanged(cid, True))
        state, _ = ms.step(state, ev.Hello(cid, 1, "h", 1, 0, coordinator.setup.fingerprint, 0.0, REVISION))
    coordinator.state = state
    return coordinator, clock, lines


def stage_0_opened(coordinator, clock):
    """Its lifecycle collecting stage 0 (opened now) until it decides: its decision recorded (the
    time) and taken as deposed, so the loop ends there."""
    from mission import coordinator_life as kl

    decided = []
    coordinator.decide = lambda j: decided.append(clock.now)
    coordinator.life = dataclasses.replace(coordinator.life, phase=kl.Phase.STAGE, stage=0, opened=clock.now)
    return decided


def test_the_coordinator_waits_for_a_carrier_heard_from_until_its_silence(tmp_path):
    """[P-10.3] sim clock: a carrier heard from 10 s after the stage opened is waited for past
    the stage timeout, until the silence timeout after that; then it is stalled (logged)."""
    coordinator, clock, lines = coordinator_waiting("sim", tmp_path, silence_timeout_s=30.0, stage_timeout_s=5.0)
    opened = clock.now
    coordinator.crew.inbound.heard = {cid: opened + 10.0 for cid in TINY.carrier_ids}
    waiting = coordinator.state.waiting(0)
    assert waiting
    decided = stage_0_opened(coordinator, clock)
    coordinator.fly()
    assert len(decided) == 1 and 40.0 <= decided[0] - opened < 40.1
    assert any("stalled" in line and all(cid in line for cid in waiting) for line in lines), lines


def test_the_coordinator_on_the_wall_clock_waits_the_stage_timeout(tmp_path):
    """[P-10.3] wall clock: the stage timeout is a deadline, whoever is heard from."""
    coordinator, clock, lines = coordinator_waiting("wall", tmp_path, silence_timeout_s=30.0, stage_timeout_s=5.0)
    opened = clock.now
    coordinator.crew.inbound.heard = {cid: opened + 4.9 for cid in TINY.carrier_ids}
    decided = stage_0_opened(coordinator, clock)
    coordinator.fly()
    assert len(decided) == 1 and 5.0 <= decided[0] - opened < 5.1 and not any("stalled" in line for line in lines)


def test_no_wait_of_the_processes_reads_the_clock_itself():
    """carriers/ and coordinator/ call no ``time.monotonic()``: a process's clock is its
    ``clock`` attribute, read by its drivers, and every timing decision is a mission.timers rule."""
    import ast

    calls = []
    for folder in ("carriers", "coordinator"):
        for path in sorted((ROOT / folder).glob("*.py")):
            for node in ast.walk(ast.parse(path.read_text())):
                if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
                        and node.func.attr in ("monotonic", "perf_counter")):
                    calls.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert calls == []


def test_no_driver_compares_times_itself():
    """The drivers of the lifecycles (carriers/, coordinator/, mission/simulate/) compare no
    difference of two times: every wait is a rule of mission.timers, called by a machine
    (mission/carrier_life.py) or a driver (docs/architecture.md, "The carrier's lifecycle")."""
    import ast

    found = []
    for folder in ("carriers", "coordinator", "mission/simulate"):
        for path in sorted((ROOT / folder).glob("*.py")):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.Compare) and any(
                        isinstance(side, ast.BinOp) and isinstance(side.op, ast.Sub)
                        and any(isinstance(n, ast.Name) and n.id == "now" for n in ast.walk(side))
                        for side in (node.left, *node.comparators)):
                    found.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert found == []
