"""A carrier's body in motion: physics to a stage time at fixed steps (paced or not), and
what the motion publishes: Poses, Progress (sim clock), the trail of an Observation; the region
counts behind what the body sensed.

:class:`Motion` is a part of :class:`carriers.node.Carrier` (it uses the carrier's ``sim``,
``node``, ``config`` and its inbox pump while it paces).
"""
from __future__ import annotations

from concurrent import futures

import numpy as np

from mission.timeouts import DEFAULTS
from mission.timers import GoOn, due, pace
from wire import keys
from wire.messages import Pose, Progress

#: Trail points per Observation at most (the protocol's limit).
MAX_TRAIL = 512
#: Sim-time chunk (s) between pacing sleeps when ``realtime > 0``.
PACE_CHUNK_S = 0.5
#: Sim-time chunk (s) of unpaced physics between two looks at the wall clock (is a Progress
#: message due?): 100 physics steps, about a millisecond of CPU.
PROGRESS_CHUNK_S = 5.0


class Track:
    """What a carrier's motion has published so far.

    Attributes:
        trail_from: the first trajectory sample not sent in an Observation's trail yet.
        pose_from: the first trajectory sample not considered for a Pose yet.
        heading: the heading of the last Pose (rad).
        progress_at: when the carrier last sent Progress (the carrier's clock, s).
    """

    def __init__(self, now: float):
        self.trail_from = 0
        self.pose_from = 0
        self.heading = 0.0
        self.progress_at = now


class Motion:
    """The carrier's physics and what its motion publishes."""

    def _position(self) -> tuple[float, float]:
        return tuple(map(float, self.sim.position(self.cid)))

    def _counts(self, j: int, x) -> tuple[int, ...] | None:
        """The region counts behind ``x`` at stage j under the coverage reward (world/regions.py),
        None otherwise (and when a body other than the simulated one, a ROS 2 robot's, sensed ``x``)."""
        sense_counts = getattr(self.sim, "sense_counts", None)
        counts = sense_counts(self.cid, j) if x is not None and sense_counts is not None else None
        return counts if counts is not None and sum(counts) == x else None

    def _physics_until(self, t: float, each_chunk=None) -> None:
        """Physics to mission time ``t`` (s) at fixed steps, unpaced, a chunk at a time so that a
        stop request is seen soon (``each_chunk()`` after each)."""
        while True:  # at least once: a body may have to look at the time (a robot's odometry)
            self.sim.advance_to(min(t, self.sim.time + PROGRESS_CHUNK_S))
            if each_chunk is not None:
                each_chunk()
            if self.sim.time >= t - 1e-9 or self._stop.is_set():
                return

    def _advance(self, t: float, paced: bool = True) -> None:
        """Physics to mission time ``t`` (s) at fixed steps, paced when realtime > 0 (and
        ``paced``); on the sim clock a Progress message at least every ``progress_s`` of wall
        time on the way. Unpaced, in the process's physics thread when it has one
        (:class:`carriers.shared.PhysicsThread`) while this thread sends the Progress."""
        if self.timers.realtime <= 0 or not paced:
            if self.physics is None:
                self._physics_until(t, self._progress)
                return
            job = self.physics.submit(self._physics_until, t)
            while not futures.wait((job,), DEFAULTS.progress_s).done:
                self._progress()
            self._progress()
            job.result()
            return
        wall0, t0 = self.clock(), self.sim.time
        while self.sim.time < t - 1e-9 and not self._stop.is_set():
            target = min(t, self.sim.time + PACE_CHUNK_S)
            self.sim.advance_to(target)
            self._publish_poses()
            self._progress()
            while not self._stop.is_set():  # the chunk's wall time (mission.timers.pace)
                now = self.clock()
                rule = pace(wall0, self.sim.time - t0, self.timers.realtime, now)
                if isinstance(rule, GoOn):
                    break
                self._pump(min(0.05, rule.until - now))
                self._check_refused()

    def _progress(self, every_s: float = DEFAULTS.progress_s, now: float | None = None) -> None:
        """Sim clock: tell the coordinator and the peers that this carrier is working (a
        Progress message) when it is due (:func:`mission.timers.due`: ``every_s`` since the last;
        ``now``: the caller's look at the clock, else the clock now) [P-10.6]."""
        now = self.clock() if now is None else now
        if self.timers.clock != "sim" or not due(self.track.progress_at, now, every_s):
            return
        self.track.progress_at = now
        if self.node.revision < Progress.SINCE:
            return  # a coordinator of an earlier revision has no Progress (it would reject it)
        self.node.put(keys.carrier_key(self.mission, self.cid, "progress"),
                      Progress(self.mission, self.cid, self.machine.stage, float(self.sim.time)))

    def _trail(self) -> tuple:
        samples = self.sim.trajectory(self.cid)
        new = samples[self.track.trail_from:, 1:3]
        self.track.trail_from = len(samples)
        if len(new) > MAX_TRAIL:
            new = new[np.linspace(0, len(new) - 1, MAX_TRAIL).astype(int)]
        return tuple((float(a), float(b)) for a, b in new)

    def _publish_poses(self) -> None:
        """A Pose for every pose tick the physics passed since the last call: the trajectory
        samples (one per second of simulated time) whose time is a multiple of the interval."""
        every = self.config.pose_interval_s
        if every <= 0 or self.node is None:
            return
        samples = self.sim.trajectory(self.cid)
        step = max(1, int(round(every)))
        track = self.track
        for k in range(track.pose_from, len(samples)):
            if k > 0:
                dx, dy = samples[k, 1] - samples[k - 1, 1], samples[k, 2] - samples[k - 1, 2]
                if dx * dx + dy * dy > 1e-12:
                    track.heading = float(np.arctan2(dy, dx))
            if k % step == 0:
                self.node.put(keys.carrier_key(self.mission, self.cid, "pose"), Pose(
                    self.mission, self.cid, float(samples[k, 0]), (float(samples[k, 1]), float(samples[k, 2])),
                    track.heading, self.machine.passengers_left))
                if self.ros2 is not None:
                    self.ros2.pose(float(samples[k, 0]), float(samples[k, 1]), float(samples[k, 2]), track.heading)
        track.pose_from = len(samples)
