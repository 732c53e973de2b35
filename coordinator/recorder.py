"""The coordinator's recorder hooks: mission.mcap (or the ROS 2 bag) and the ROS 2 topics
written as the mission runs (recording/live.py, imported only when recording), fed every
recorded event after mission.db has it and the carriers' Poses.

:class:`RecorderHooks` is a part of :class:`coordinator.node.Coordinator`.
"""
from __future__ import annotations

from pathlib import Path

from wire.messages import Pose, ProtocolError, decode

#: Poses set aside at most: more than one stage's burst of the largest fleet
#: (``planner.limits.MAX_CARRIERS`` carriers at ``mission.timeouts.POSES_PER_STAGE`` each).
POSES_HELD = 1 << 15


class RecorderHooks:
    """Start, feed and finalise the coordinator's recorder (``self.recorder``).

    Poses wait in ``self.poses`` (a deque of (carrier, inbox item)) until the coordinator has
    nothing else to do: a carrier sends a stage's Poses in a burst just before its Observation,
    so recorded in arrival order they would stand ahead of the stage's Observations in the inbox,
    between the stage's first Observation and its Decision."""

    def _pose(self, cid: str, item) -> None:
        """A carrier's Pose: not a mission event and never a rejection (docs/protocol.md, "Pose");
        set aside for the recorder (:meth:`_record_poses`); past :data:`POSES_HELD` waiting, the
        oldest is recorded now (a coordinator that is never idle holds a bounded backlog)."""
        if self.recorder is not None and self.spec.has(cid):
            if len(self.poses) >= POSES_HELD:
                self._record_pose(*self.poses.popleft())
            self.poses.append((cid, item))

    def _record_poses(self, busy=lambda: False) -> None:
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

    def _open_recorder(self, out: Path) -> None:
        """Start mission.mcap (recording/live.py), replaying the events already in mission.db
        (a resumed mission's past; a fresh mission's ``open``)."""
        ros2 = self.config.ros2 if self.node is not None else None
        if not self.config.record and ros2 is None:
            return
        try:
            from recording.live import LiveRecorder

            self.recorder = LiveRecorder(out, self.scenario, self.problem, metadata={
                "mission": self.mission, "scenario": self.scenario.name, "seed": self.seed,
                "planner": self.planner_name, "fingerprint": self.fingerprint}, log=self.log,
                profile=self.config.record_profile if self.config.record else None,
                sinks=() if ros2 is None else (ros2.coordinator_sink(self.node.session, self.problem, self.log),))
            for event in self.store.mission_events():
                self.recorder.event(event)
        except Exception as exc:
            self.log(f"coordinator: mission.mcap not recorded: {type(exc).__name__}: {exc}")
            self.recorder = None

    def _close_recorder(self) -> None:
        self._record_poses()
        if self.recorder is not None:
            try:
                self.recorder.close()
            except Exception as exc:
                self.log(f"coordinator: mission.mcap not finalised: {type(exc).__name__}: {exc}")
            self.recorder = None
