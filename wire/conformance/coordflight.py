"""A flight of the kit for replacement coordinators: the kit is the zenoh router and every
carrier of the scenario (:mod:`wire.conformance.fleet`), COMMAND is the coordinator under test;
what the kit saw goes into a :class:`Seen` record per flight, which
:mod:`wire.conformance.coordrules` judges.

Two flights, each with a coordinator process of its own on a router of its own:

* ``main``: every carrier joins and flies the mission, with the faults of :data:`FAULT_TEXT`
  (bad Hellos, bad messages, a late joiner, a carrier that goes silent);
* ``takeover``: a carrier's Hello reports a higher epoch before the first Decision, then, once
  stage 1 is decided, the kit publishes a Decision of a higher epoch than the coordinator's, as a
  newer coordinator would: the coordinator under test must stop.
"""
from __future__ import annotations

import os
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgpack

from .. import keys
from .. import messages as wm
from .fleet import Played, World
# One record of a message heard, for both kits (its ``topic`` here is the key it came on).
from .flight import Seen as Heard

#: What the coordinator under test is told, by environment variable and by ``{placeholder}`` in
#: its ARGS: (variable, placeholder, meaning).
PLACEHOLDERS = (
    ("MARSUPIAL_ENDPOINT", "endpoint", "the endpoint to connect to (zenoh client mode)"),
    ("MARSUPIAL_SCENARIO", "scenario", "the scenario file (absolute path)"),
    ("MARSUPIAL_MISSION", "mission", "the mission id (key prefix marsupial/<mission>/)"),
    ("MARSUPIAL_SEED", "seed", "the root seed (the fingerprint's)"),
    ("MARSUPIAL_WORKDIR", "workdir", "a directory of its own for files it writes (a new one per flight)"),
)

#: Every fault the coordinator kit can make (the command line's help prints these).
FAULT_TEXT = {
    "bad-hello": "once the first carrier's Hello is answered: a Hello from an id not in the scenario, one "
                 "of that carrier with another fingerprint, and one of it missing a field (each must be "
                 "refused with its reason; the carrier stays accepted)",
    "bad-message": "the first carrier sends a payload that is not msgpack and an Observation of another "
                   "mission on its obs key (counted in State under malformed and wrong-mission)",
    "late-joiner": "the last carrier declares its token and says Hello only once stage 0 is decided",
    "silent": "the last carrier stops sending anything after answering stage N-3 (its token stays)",
    "old-carrier": "the last carrier speaks revision 1: State asked without a revision, Hello without one, no "
                   "Progress (it gets no Accepted; from its join on, Decisions and End are revision 1's)",
    "takeover": "a second flight: the first carrier's Hello reports epoch 5; once stage 1 is decided the "
                "kit publishes a Decision of a higher epoch than the coordinator's (a newer coordinator)",
}
FAULTS = tuple(FAULT_TEXT)
INTRUDER = "zz-conformance-intruder"
HELLO_EPOCH = 5  # the epoch the takeover flight's first Hello reports
PROGRESS_S = 0.5  # how often a waiting kit carrier says it is alive, seconds
STATE_PERIOD_S = 1.0  # how often the kit asks State for each carrier's counts, seconds
END_WATCH_S = 3.0  # after the first End, how long the kit still watches for Decisions and Ends
EXIT_S = 10.0  # after End (or the takeover), how long the coordinator has to exit, seconds
ANSWER_S = 5.0  # how long a Hello may wait for its answer, seconds


@dataclass
class Seen:
    """Everything the kit saw of one flight.

    Attributes:
        name: ``main`` or ``takeover``; ``faults``: the faults made, fault -> (stage, time).
        hellos: (time, the id in its key, the answer the kit expects: ``accepted`` or a
            refusal's reason, the fingerprint it sent, its next_stage), per Hello the kit sent.
        heard: every message of the coordinator (Decisions, Ends, Accepted, Refusals).
        states: (time, selector, the asking revision, payload) of each State reply.
        told: carrier -> its latest CarrierState (the coordinator's counts of its messages).
        tokens: (time, ``alive`` or ``gone``) of the coordinator's liveliness token.
        played: the kit's carriers, as they ended the flight.
        exit_code: the coordinator's exit code (None: still running, stopped by the kit).
        exited_at: when it exited (monotonic s); ``output``: its last output.
    """

    name: str
    faults: dict = field(default_factory=dict)
    hellos: list = field(default_factory=list)
    heard: list = field(default_factory=list)
    states: list = field(default_factory=list)
    told: dict = field(default_factory=dict)
    played: dict = field(default_factory=dict)
    tokens: list = field(default_factory=list)  # (time, "alive" or "gone") of the coordinator's token
    exit_code: int | None = None
    exited_at: float | None = None
    output: str = ""

    def of(self, cls: type, fake: bool | None = False) -> list[Heard]:
        return [h for h in self.heard if isinstance(h.message, cls) and (fake is None or h.fake == fake)]


class Router:
    """The kit's zenoh router (``tcp/127.0.0.1:<free port>``, multicast scouting off) and the
    coordinator under test, started with its placeholders; a context manager that stops both."""

    def __init__(self, world: World, workdir: Path):
        self.world, self.workdir = world, Path(workdir)
        self.endpoint = ""
        self.node: Any = None
        self.proc: subprocess.Popen | None = None

    def __enter__(self) -> Router:
        from ..transport import Node
        from ..zconfig import free_port, make_config

        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.workdir.mkdir(parents=True, exist_ok=True)
        self.node = Node(make_config("router", [self.endpoint]))
        return self

    def __exit__(self, *exc: object) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
        self.node.close(3.0)

    def values(self) -> dict[str, str]:
        w = self.world
        return {"endpoint": self.endpoint, "scenario": w.scenario_path, "mission": w.mission, "seed": str(w.seed),
                "workdir": str(self.workdir)}

    def expand(self, command: list[str]) -> list[str]:
        out = []
        for arg in command:
            for name, value in self.values().items():
                arg = arg.replace("{" + name + "}", value)
            out.append(arg)
        return out

    def start(self, command: list[str]) -> None:
        values = self.values()
        env = {variable: values[name] for variable, name, _ in PLACEHOLDERS}
        self.proc = subprocess.Popen(command, env={**os.environ, **env}, stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT)

    def finish(self, timeout_s: float) -> tuple[int | None, str]:
        """Wait up to ``timeout_s`` for the coordinator to exit (then stop it): its exit code
        (None when the kit had to stop it) and the last 4000 characters of its output."""
        assert self.proc is not None
        code: int | None
        try:
            out, _ = self.proc.communicate(timeout=max(0.1, timeout_s))
            code = self.proc.returncode
        except subprocess.TimeoutExpired:
            self.proc.terminate()
            try:
                out, _ = self.proc.communicate(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                out, _ = self.proc.communicate()
            code = None
        return code, (out or b"").decode(errors="replace")[-4000:]


class Flight:
    """One flight of the kit's carriers around the coordinator under test.

    Args:
        world: the scenario's truth; ``router``: the kit's router with the coordinator started.
        seen: where everything goes; ``faults``: the faults to make in this flight.
        deadline: monotonic time the flight ends at the latest.
    """

    def __init__(self, world: World, router: Router, seen: Seen, faults: tuple[str, ...], deadline: float):
        self.w, self.router, self.node, self.seen = world, router, router.node, seen
        self.faults, self.deadline = faults, deadline
        self.played = {cid: Played(r, cid, world.passengers[r]) for r, cid in enumerate(world.ids)}
        seen.played = self.played
        self.first, self.last = world.ids[0], world.ids[-1]
        if "old-carrier" in faults and len(self.played) > 1:
            self.played[self.last].revision = 1
            seen.faults["old-carrier"] = (0, time.monotonic())
        self.epoch = 1  # the highest epoch the kit's carriers heard
        self.ended_at: float | None = None
        self.stop_at: float | None = None  # the takeover: the flight ends then
        self.coordinator_epoch: int | None = None
        m = world.mission
        self.node.subscribe(f"{keys.prefix(m)}/coordinator/**")
        self.node.watch_liveliness(keys.coordinator_alive(m))

    # ------------------------------------------------------------------ the kit's carriers speaking
    def put(self, p: Played, topic: str, message: Any) -> None:
        self.node.put(p.key(self.w, topic), message, p.revision)

    def state(self, cid: str, revision: int | None = wm.REVISION, timeout_s: float = 2.0) -> wm.State | None:
        """Ask State as carrier ``cid`` (announcing ``revision``; None: none), record every reply,
        return the highest epoch's that decodes."""
        selector = keys.state_selector(self.w.mission, cid, revision)
        best = None
        for payload in self.node.query(selector, timeout_s=timeout_s):
            self.seen.states.append((time.monotonic(), selector, revision, payload))
            try:
                state = wm.decode(payload, wm.State)
            except wm.ProtocolError:
                continue
            if best is None or state.epoch > best.epoch:
                best = state
        return best

    def join(self, p: Played, epoch: int = 1) -> bool:
        """Token, State, Hello, the Observation of State's next stage; False when State did not answer."""
        if p.token is None:
            p.token = self.node.session.liveliness().declare_token(keys.carrier_alive(self.w.mission, p.cid))
        state = self.state(p.cid, p.revision if p.revision >= 3 else None)
        if state is None:
            return False
        self.epoch = max(self.epoch, state.epoch)
        p.next_stage, p.joined = state.next_stage, True
        expect = "accepted" if p.revision >= 3 else f"revision-{p.revision}"
        self.seen.hellos.append((time.monotonic(), p.cid, expect, self.w.fingerprint, p.next_stage))
        self.put(p, "hello", p.hello(self.w, p.next_stage, max(self.epoch, epoch)))
        if p.next_stage < self.w.n:
            self.put(p, "obs", p.observation(self.w, p.next_stage))
        return True

    def bad_hellos(self) -> None:
        """Three Hellos that must be refused, each with its reason (``bad-hello``)."""
        w, p, now = self.w, self.played[self.first], time.monotonic()
        self.seen.hellos.append((now, INTRUDER, "unknown-carrier", w.fingerprint, 0))
        self.node.put(keys.carrier_key(w.mission, INTRUDER, "hello"), wm.Hello(
            w.mission, INTRUDER, 0, "conformance-kit", 1, 0, w.fingerprint, revision=wm.REVISION), wm.REVISION)
        other = "0" * 16
        self.seen.hellos.append((now, p.cid, "world-mismatch", other, p.next_stage))
        self.put(p, "hello", wm.Hello(w.mission, p.cid, 0, "conformance-kit", p.left, p.next_stage, other,
                                      epoch=self.epoch, revision=wm.REVISION))
        self.seen.hellos.append((now, p.cid, "missing-field", w.fingerprint, p.next_stage))
        self.node.put_raw(p.key(w, "hello"), msgpack.packb(
            {"v": 1, "type": "hello", "mission": w.mission, "carrier": p.cid, "fingerprint": w.fingerprint,
             "revision": wm.REVISION}))
        self.seen.faults["bad-hello"] = (p.next_stage, now)

    def bad_messages(self) -> None:
        """A payload that is not msgpack and an Observation of another mission (``bad-message``)."""
        w, p = self.w, self.played[self.first]
        self.node.put_raw(p.key(w, "obs"), b"\xc1 not msgpack")
        j = min(p.next_stage, w.n - 1)
        body = msgpack.unpackb(wm.encode(wm.Observation(w.mission, p.cid, j, w.times[j], None,
                                                        w.positions[p.r][j], p.left, ())))
        self.node.put_raw(p.key(w, "obs"), msgpack.packb({**body, "mission": "another-mission"}))
        self.seen.faults["bad-message"] = (j, time.monotonic())

    # ------------------------------------------------------------------ what the coordinator says
    def take(self, item: Any) -> None:
        if item.kind in ("alive", "gone"):
            self.seen.tokens.append((item.received, item.kind))
            return
        if item.kind != "sample":
            return
        heard = Heard(item.received, item.key, item.payload)
        if any(h.fake and h.payload == item.payload for h in self.seen.heard):
            return
        try:
            heard.message = wm.decode(item.payload)
        except wm.ProtocolError as exc:
            heard.error = f"{exc.reason}: {exc.detail}"
        self.seen.heard.append(heard)
        m = heard.message
        if isinstance(m, wm.Accepted) and m.carrier == self.first and self._due("bad-hello"):
            self.bad_hellos()
        elif isinstance(m, wm.Decision) and item.key == keys.decision_key(self.w.mission):
            self.decided(m)
        elif isinstance(m, wm.End) and item.key == keys.end_key(self.w.mission) and self.ended_at is None:
            self.ended_at = time.monotonic()
            for p in self.played.values():
                if p.active:
                    self.put(p, "bye", p.bye(self.w))

    def _due(self, fault: str) -> bool:
        return fault in self.faults and fault not in self.seen.faults

    def decided(self, d: wm.Decision) -> None:
        """Every kit carrier that observed the stage answers; then it observes the next one."""
        if d.epoch < self.epoch or self.stop_at is not None:
            return
        self.epoch = d.epoch
        if self.coordinator_epoch is None:
            self.coordinator_epoch = d.epoch
        w, j = self.w, d.stage
        # The late joiner first: its Hello reaches the coordinator before the others' next
        # Observations (puts of one session are ordered), so it is expected at the next stage.
        if self._due("late-joiner") and len(self.played) > 1 and not self.played[self.last].joined:
            if self.join(self.played[self.last]):
                self.seen.faults["late-joiner"] = (self.played[self.last].next_stage, time.monotonic())
        for p in self.played.values():
            if not p.active or j not in p.observed or j in p.answered:
                continue
            self.put(p, "confirm", p.confirm(w, d))
            if p.cid == self.last and self._due("silent") and j >= max(0, w.n - 3) and len(self.played) > 1:
                p.silent = True
                self.seen.faults["silent"] = (j + 1, time.monotonic())
                continue
            p.next_stage = max(p.next_stage, j + 1)
            if p.next_stage < w.n:
                if p.cid == self.first and self._due("bad-message"):
                    self.bad_messages()
                self.put(p, "obs", p.observation(w, p.next_stage))
        if self._due("takeover") and j >= 1:
            self.take_over(d)

    def take_over(self, d: wm.Decision) -> None:
        """Publish a Decision of a higher epoch than the coordinator's, as a newer coordinator."""
        w, j = self.w, min(d.stage + 1, self.w.n - 1)
        fake = wm.Decision(w.mission, j, w.times[j], (), 0.0, epoch=d.epoch + 1)
        payload = wm.encode(fake)
        now = time.monotonic()
        self.seen.heard.append(Heard(now, keys.decision_key(w.mission), payload, fake, fake=True))
        self.node.put_raw(keys.decision_key(w.mission), payload)
        self.seen.faults["takeover"] = (j, now)
        self.stop_at = now + EXIT_S

    # ------------------------------------------------------------------ the loop
    def fly(self) -> None:
        """Wait for State, join the carriers (the late joiner later), then answer the coordinator
        until End (and :data:`END_WATCH_S` more), the takeover's watch, or the deadline."""
        first = self.played[self.first]
        while time.monotonic() < self.deadline and self.state(first.cid, timeout_s=1.0) is None:
            if self.router.proc is not None and self.router.proc.poll() is not None:
                return
            time.sleep(0.2)
        self.state(first.cid, revision=None)  # a query announcing no revision: a revision-1 reply
        epoch = HELLO_EPOCH if "takeover" in self.faults else 1
        for p in self.played.values():
            if p.cid == self.last and "late-joiner" in self.faults and len(self.played) > 1:
                continue
            self.join(p, epoch if p.cid == self.first else 1)
        last_progress = last_state = 0.0
        while (now := time.monotonic()) < self.deadline:
            if self.ended_at is not None and now - self.ended_at > END_WATCH_S:
                break
            if self.stop_at is not None and (now > self.stop_at or self.router.proc.poll() is not None):
                break
            if self.ended_at is None and self.router.proc.poll() is not None and not self.node.pending():
                break  # the coordinator exited before End: nothing more will come
            if now - last_progress > PROGRESS_S and self.ended_at is None and self.stop_at is None:
                last_progress = now
                for p in self.played.values():
                    if p.active and p.next_stage < self.w.n and p.revision >= 3:
                        self.put(p, "progress", p.progress(self.w))
            if now - last_state > STATE_PERIOD_S and self.ended_at is None:
                last_state = now
                self.poll_counts()
            item = self.node.next(0.05)
            while item is not None:
                self.take(item)
                item = self.node.next(0.0)

    def poll_counts(self) -> None:
        for p in self.played.values():
            if not p.joined:
                continue
            state = self.state(p.cid, timeout_s=0.5)
            mine = state.carrier(p.cid) if state is not None else None
            if mine is not None:
                self.seen.told[p.cid] = mine
