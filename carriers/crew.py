"""What a carrier process is made of beside its machines: which carrier it is and its
collaborators (:class:`Crew`), each built once from the scenario and the carrier's config and
given what it needs. They return what they read, or yield what they ask, and call nothing back
into the process (docs/architecture.md, "Thin processes"); the process
(:class:`carriers.node.Carrier`) holds them beside its two machines, its timers and its clock.
"""
from __future__ import annotations

import threading
from dataclasses import dataclass

from carriers.alone import Alone
from carriers.effects import CarrierEffects
from carriers.inbound import Inbound
from carriers.joining import Joining, StateQueries
from carriers.motion import Motion
from carriers.onboard import Onboard
from carriers.shared import PhysicsThread
from carriers.stage import StageWork
from carriers.who import Who
from mission import carrier as mc
from mission.peers import PeerBook, Presence
from wire.messages import SharedDecoder


@dataclass(frozen=True)
class Crew:
    """A carrier's identity and collaborators.

    Attributes:
        who: which carrier of which mission (:class:`carriers.who.Who`: the messages it sends).
        motion: its body in motion (:class:`carriers.motion.Motion`).
        inbound: what it receives and the books it feeds (:class:`carriers.inbound.Inbound`: who
            is there, the answer to its latest Hello, the passenger each Decision named for it,
            what it heard of every carrier's stages).
        alone: its on-board decision of a stage (:class:`carriers.alone.Alone`).
        work: its work at a stage (:class:`carriers.stage.StageWork`: sense, pass, move on,
            decide alone, say Hello again).
        joining: its joins and resynchronisations (:class:`carriers.joining.Joining`).
        effects: its hands on the world (:class:`carriers.effects.CarrierEffects`: what it sends,
            logs and releases for its machines' effects; its durable log and ROS 2 node while it runs).

    Its run's opening and closing (:mod:`carriers.opening`) are functions the process calls, not
    held here.
    """

    who: Who
    motion: Motion
    inbound: Inbound
    alone: Alone
    work: StageWork
    joining: Joining
    effects: CarrierEffects

    @classmethod
    def build(cls, scenario, config, parts, onboard: Onboard | None, broadcasts: SharedDecoder | None,
              physics: PhysicsThread | None, stop: threading.Event, clock, log) -> "Crew":
        """The crew of carrier ``config.carrier`` (:class:`carriers.node.CarrierConfig`) of
        ``scenario`` (its seed replaced by ``config.seed`` unless the world is shared); ``parts``:
        what it shares with the other carriers of its process (:class:`carriers.node.Parts`);
        ``onboard``: the process's on-board planner (None: one of its own); ``broadcasts``: the
        process's decoder of Decisions (None: one of its own); ``physics``: the process's physics
        thread (None: physics in the carrier's thread); ``stop``: its stop request; ``clock``:
        its clock (its presence and motion start on it); ``log``: a callable taking one line."""
        shared = parts.shared
        if config.seed is not None and shared is None:
            scenario = scenario.with_seed(int(config.seed))
        valid = scenario.valid() if shared is None else shared.valid  # every carrier's schedule [R, N]
        who = Who.of(scenario, config.carrier, config.mission, valid, None if shared is None else shared.fingerprint)
        motion = Motion(who.mission, who.cid, config.pose_interval_s, stop, physics, clock())
        onboard = onboard if onboard is not None else Onboard(scenario, config.planner_options)
        book = PeerBook(scenario.carrier_ids, valid)  # what it heard of every carrier's stages
        # What it receives and the books it feeds: who is there, the answer to its latest Hello, the
        # passenger each Decision named for it (docs/protocol.md, Decision).
        inbound = Inbound(who.mission, who.cid, config.mode, onboard,
                          broadcasts if broadcasts is not None else SharedDecoder(),  # the process's Decisions
                          book, Presence(clock()), mc.HelloAnswer(who.fingerprint),
                          mc.Releases(scenario.carriers[who.r].passengers), motion.position, log)
        alone = Alone(who.cid, book, onboard, scenario.seed, log)
        work = StageWork(who, motion, parts.gate, alone)
        joining = Joining(who.fingerprint, config, StateQueries(who.mission, who.cid, log), motion.counts, inbound, log)
        return cls(who, motion, inbound, alone, work, joining, CarrierEffects(who, motion, inbound, clock, log))
