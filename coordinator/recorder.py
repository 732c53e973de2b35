"""The coordinator's recorder: mission.mcap (or the ROS 2 bag) and the ROS 2 topics written as
the mission runs (recording/live.py, imported only when recording), fed every recorded event
after mission.db has it and the carriers' Poses. :class:`Recording` is a collaborator of
:class:`coordinator.node.Coordinator`, given what it needs.
"""
from __future__ import annotations

from collections import deque
from pathlib import Path

from wire.messages import Pose, ProtocolError, decode

#: Poses set aside at most: more than one stage's burst of the largest fleet
#: (``planner.limits.MAX_CARRIERS`` carriers at ``mission.timeouts.POSES_PER_STAGE`` each).
POSES_HELD = 1 << 15


class Recording:
    """The coordinator's recorder: started by :meth:`open` (or never: not recording), fed every
    recorded event (:attr:`event`) and the carriers' Poses, finalised by :meth:`close`.

    Poses wait in :attr:`poses` (a deque of (carrier, inbox item)) until the coordinator has
    nothing else to do: a carrier sends a stage's Poses in a burst just before its Observation,
    so recorded in arrival order they would stand ahead of the stage's Observations in the inbox,
    between the stage's first Observation and its Decision.

    Args:
        mission: the mission id (a Pose of another is dropped).
        has: whether a carrier id is the scenario's.
        log: where its failures are logged (a callable taking one line).
    """

    def __init__(self, mission: str, has, log):
        self.mission, self._has, self.log = mission, has, log
        self.recorder = None  # recording.live.LiveRecorder while mission.mcap is written
        self.poses: deque = deque()

    @property
    def event(self):
        """What mission.db hands each recorded event to (None: not recording)."""
        return None if self.recorder is None else self.recorder.event

    def pose(self, cid: str, item) -> None:
        """A carrier's Pose: not a mission event and never a rejection (docs/protocol.md, "Pose");
        set aside for the recorder (:meth:`record_poses`); past :data:`POSES_HELD` waiting, the
        oldest is recorded now (a coordinator that is never idle holds a bounded backlog)."""
        if self.recorder is not None and self._has(cid):
            if len(self.poses) >= POSES_HELD:
                self._record_pose(*self.poses.popleft())
            self.poses.append((cid, item))

    def record_poses(self, busy=lambda: False) -> None:
        """Record the Poses set aside, oldest first, until none is left or ``busy()``."""
        while self.poses and not busy():
            self._record_pose(*self.poses.popleft())

    def _record_pose(self, cid: str, item) -> None:
        """Only the recorder looks at a Pose, and quietly drops one it cannot use."""
        if self.recorder is None:
            return
        try:
            msg = decode(item.payload, Pose)
        except ProtocolError:
            return
        if msg.mission == self.mission and msg.carrier == cid:
            self.recorder.message(msg)

    def open(self, out: Path, scenario, problem, metadata: dict, profile: str | None, sinks, past) -> None:
        """Start mission.mcap (recording/live.py) in ``profile`` (None: no file, only ``sinks``,
        the ROS 2 topics), replaying ``past`` (the events already in mission.db: a resumed
        mission's past; a fresh mission's ``open``)."""
        try:
            from recording.live import LiveRecorder

            self.recorder = LiveRecorder(out, scenario, problem, metadata=metadata, log=self.log, profile=profile,
                                         sinks=sinks())
            for event in past():
                self.recorder.event(event)
        except Exception as exc:
            self.log(f"coordinator: mission.mcap not recorded: {type(exc).__name__}: {exc}")
            self.recorder = None

    def close(self) -> None:
        self.record_poses()
        if self.recorder is not None:
            try:
                self.recorder.close()
            except Exception as exc:
                self.log(f"coordinator: mission.mcap not finalised: {type(exc).__name__}: {exc}")
            self.recorder = None


def start(recording: Recording, config, node, out: Path, scenario, problem, metadata: dict, past) -> None:
    """Start ``recording`` as the coordinator's ``config`` asks (``record``, ``record_profile``,
    ``ros2``: its topics only with a session, ``node``); nothing when it asks for neither."""
    ros2 = config.ros2 if node is not None else None
    if not config.record and ros2 is None:
        return
    recording.open(out, scenario, problem, metadata, config.record_profile if config.record else None,
                   lambda: () if ros2 is None else (ros2.coordinator_sink(node.session, problem, recording.log),), past)
