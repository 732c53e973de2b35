"""The mission stream: what a recorder or a viewer consumes, from the wire or from mission.db.

A *sink* (recording.mcap.McapRecorder, viewer.rerun_view.RerunView) implements the methods of
:class:`Sink`, every one stamped with simulated mission time ``t`` in seconds. Two feeders turn
what is at hand into those calls, so the live recorder, the viewer and the rebuild from
mission.db show the same thing:

* :func:`feed_message` — a decoded wire message (wire.messages: Hello, Observation, Decision,
  Confirm, Pose, End, Bye), as a viewer receives it;
* :func:`feed_event` — a mission event (mission.events), as the coordinator records it and
  storage/missiondb.py loads it back.

Messages without a time of their own (Hello, Confirm, Bye, End, liveliness) are stamped with the
time of their stage or, failing that, the latest simulated time seen (:class:`Clock`).

:class:`Tally` (mission/records.py, with the records the JSON channels carry) keeps the running
score: observations, confirmed deployments and the reward so far under the penalty rule
(planner.problem.evaluate), as summary.json counts it.
"""
from __future__ import annotations

import numpy as np

from mission import events as ev
from mission.records import (  # noqa: F401 (re-exported)
    Tally, confirm_record, decision_record, observation_record, operator_action_record, operator_decision_record,
)


class Sink:
    """What a consumer of the mission stream implements (every method optional: the defaults
    do nothing). Positions ``(x, y)`` in metres, ``t`` in seconds of mission time."""

    def observation(self, t, stage, carrier, x, position, passengers_left): ...

    def decision(self, t, stage, deploy, planning_ms): ...

    def confirm(self, t, stage, carrier, deployed, status, position, passengers_left): ...

    def pose(self, t, carrier, position, heading, passengers_left): ...

    def log(self, t, level, text): ...

    def end(self, t, stages, reason): ...

    def operator(self, t, record: dict): ...


class Clock:
    """The latest simulated time seen in a stream (s), and stage times."""

    def __init__(self, stage_times):
        self.stage_times = np.asarray(stage_times, dtype=float)
        self.now = float(self.stage_times[0]) if len(self.stage_times) else 0.0

    def at(self, t: float) -> float:
        self.now = max(self.now, float(t))
        return float(t)

    def stage(self, j: int) -> float:
        j = int(j)
        t = float(self.stage_times[j]) if 0 <= j < len(self.stage_times) else self.now
        return self.at(t)


def feed_message(sink: Sink, msg, clock: Clock) -> None:
    """Hand one decoded wire message to ``sink``."""
    kind = getattr(type(msg), "TYPE", None)
    if kind == "obs":
        sink.observation(clock.at(msg.t), msg.stage, msg.carrier, msg.x, msg.position, msg.passengers_left)
    elif kind == "decision":
        sink.decision(clock.at(msg.t), msg.stage, tuple(msg.deploy), msg.planning_ms)
    elif kind == "confirm":
        sink.confirm(clock.stage(msg.stage), msg.stage, msg.carrier, msg.deployed, msg.status, msg.position,
                     msg.passengers_left)
    elif kind == "pose":
        sink.pose(clock.at(msg.t), msg.carrier, msg.position, msg.heading, msg.passengers_left)
    elif kind == "hello":
        sink.log(clock.now, "info", f"carrier {msg.carrier} joins at stage {msg.next_stage} "
                                    f"({msg.passengers_left} passengers, host {msg.host}, pid {msg.pid})")
    elif kind == "bye":
        sink.log(clock.now, "info", f"carrier {msg.carrier} leaves ({msg.reason}); deployed at stages "
                                    f"{list(msg.deployments)}")
    elif kind == "end":
        sink.end(clock.now, msg.stages, msg.reason)


def feed_event(sink: Sink, event, clock: Clock) -> None:
    """Hand one mission event (mission.events, live or loaded from mission.db) to ``sink``."""
    if isinstance(event, ev.Observation):
        sink.observation(clock.at(event.t), event.stage, event.carrier, event.x, event.position,
                         event.passengers_left)
    elif isinstance(event, ev.Decided):
        sink.decision(clock.stage(event.stage), event.stage, tuple(event.deploy), event.planning_ms)
        if event.hold:  # operator mode: how the stage's hold ended and what the operator changed
            sink.operator(clock.stage(event.stage), operator_decision_record(event))
    elif isinstance(event, ev.OperatorAction):
        sink.operator(clock.stage(event.stage), operator_action_record(event))
    elif isinstance(event, ev.Confirmed):
        sink.confirm(clock.stage(event.stage), event.stage, event.carrier, event.deployed, event.status,
                     event.position, event.passengers_left)
    elif isinstance(event, ev.Hello):
        sink.log(clock.now, "info", f"carrier {event.carrier} joins at stage {event.next_stage} "
                                    f"({event.passengers_left} passengers, host {event.host}, pid {event.pid})")
    elif isinstance(event, ev.LivelinessChanged):
        sink.log(clock.now, "info" if event.alive else "warning",
                 f"carrier {event.carrier} {'is live' if event.alive else 'lost its liveliness token'}")
    elif isinstance(event, ev.Bye):
        sink.log(clock.now, "info", f"carrier {event.carrier} leaves ({event.reason}); deployed at stages "
                                    f"{list(event.deployments)}")
    elif isinstance(event, ev.Opened):
        sink.log(clock.now, "info", "coordinator opened the mission")
    elif isinstance(event, ev.Ended):
        sink.end(clock.now, None, event.reason)
