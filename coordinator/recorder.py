"""The coordinator's recorder hooks: mission.mcap (or the ROS 2 bag) and the ROS 2 topics
written as the mission runs (recording/live.py, imported only when recording), fed every
recorded event after mission.db has it and the carriers' Poses.

:class:`RecorderHooks` is a part of :class:`coordinator.node.Coordinator`.
"""
from __future__ import annotations

from pathlib import Path

from wire.messages import Pose, ProtocolError, decode


class RecorderHooks:
    """Start, feed and finalise the coordinator's recorder (``self.recorder``)."""

    def _pose(self, cid: str, item) -> None:
        """A carrier's Pose: not a mission event and never a rejection (docs/protocol.md, "Pose");
        only the recorder looks at it, and quietly drops one it cannot use."""
        if self.recorder is None or cid not in self.spec.carriers:
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
        if self.recorder is not None:
            try:
                self.recorder.close()
            except Exception as exc:
                self.log(f"coordinator: mission.mcap not finalised: {type(exc).__name__}: {exc}")
            self.recorder = None
