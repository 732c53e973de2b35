"""What a coordinator process is made of beside its machines: its collaborators (:class:`Crew`),
each built once from the process's setup and config and given what it needs. They return what
they read or build and call nothing back into the process (docs/architecture.md, "Thin
processes"); the process (:class:`coordinator.node.Coordinator`) holds them beside its two
machines and its clock.
"""
from __future__ import annotations

import threading
from dataclasses import dataclass

from coordinator.answers import Answers
from coordinator.effects import MissionEffects
from coordinator.epochs import Epochs, default_ident
from coordinator.inbound import Inbound
from coordinator.recorder import Recording
from coordinator.results import Results, results_for
from coordinator.setup import MissionSetup


@dataclass(frozen=True)
class Crew:
    """A coordinator's collaborators.

    Attributes:
        recording: the recorder (:class:`coordinator.recorder.Recording`: mission.mcap, the ROS 2
            topics, the Poses set aside).
        epochs: split brain and its session (:class:`coordinator.epochs.Epochs`: the claim on the
            mission, its ballot, a newer one's deposition).
        answers: what it answers (:class:`coordinator.answers.Answers`: State, Accepted, Refusal,
            what State tells), given the mission state at each call.
        inbound: the inbox's reader (:class:`coordinator.inbound.Inbound`: what each item says,
            when each carrier was heard).
        results: summary.json and map.png at the end (:class:`coordinator.results.Results`).
        effects: its hands on the world (:class:`coordinator.effects.MissionEffects`: the I/O
            effects of both machines; the session and mission.db once the mission opens).

    The mission's opening (:mod:`coordinator.opening`), the planner call
    (:mod:`coordinator.planning`) and the operator's console (a stage's hold, a generator of
    waits and events) are functions and generators the process calls, not held here.
    """

    recording: Recording
    epochs: Epochs
    answers: Answers
    inbound: Inbound
    results: Results
    effects: MissionEffects

    @classmethod
    def build(cls, setup: MissionSetup, config, stop: threading.Event, clock) -> "Crew":
        """The collaborators of a coordinator of ``setup`` and ``config``
        (:class:`coordinator.node.CoordinatorConfig`): ``stop`` its stop request (set when it is
        deposed), ``clock`` its clock (what a standby's wait reads)."""
        recording = Recording(setup.mission, setup.spec.has, setup.log)
        epochs = Epochs(setup.mission, setup.log, stop, clock, config.coordinator_id or default_ident())
        answers = Answers(setup, epochs, config)
        inbound = Inbound(setup.mission, setup.spec.has, setup.fingerprint, epochs, recording)
        results = results_for(setup, config, epochs, recording, answers)
        return cls(recording, epochs, answers, inbound, results,
                   MissionEffects(setup.mission, setup.spec, answers, recording, setup.log))
