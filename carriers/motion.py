"""A carrier's body in motion: physics to a stage time at fixed steps (paced or not), and
what the motion publishes: Poses, Progress (sim clock), the trail of an Observation; the region
counts behind what the body sensed.

:class:`Motion` is a collaborator of :class:`carriers.node.Carrier`: it owns the body and what
its motion has published, and is handed, at each call that publishes, what the carrier is now
(:class:`Moving`: its wire node, clock, timers, stage); while it paces, it yields its waits for
the carrier to take its inbox (:meth:`Motion.advance`). It carries out what a join path asks of
the body (:meth:`Motion.asked`).
"""
from __future__ import annotations

import threading
from concurrent import futures
from typing import NamedTuple

import numpy as np

from mission import joins
from mission.timeouts import DEFAULTS
from mission.timers import GoOn, due, pace
from wire import keys
from wire.messages import Pose, Progress
from wire.sizes import fit_to_links

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


class Moving(NamedTuple):
    """What the carrier is at one look, for what its motion publishes (read again after every
    wait of its inbox: a message may change its timers or its machine).

    Attributes:
        node: its wire node (``wire.transport.Node``).
        ros2: its ROS 2 node (ros2/publisher.py), or None.
        clock: its clock (monotonic s).
        timers: its :class:`mission.carrier.Timers`.
        stage: its machine's stage.
        passengers_left: its machine's passengers left.
    """

    node: object
    ros2: object
    clock: object
    timers: object
    stage: int
    passengers_left: int


class Motion:
    """The carrier's physics and what its motion publishes.

    Attributes:
        body: its body: a ``world.Simulation`` of this carrier (set when the carrier runs), or a
            ROS 2 robot's body that replaces it (ros2/publisher.py); None before.
        track: what its motion has published so far (:class:`Track`).
        pending: the Observation it published at the stage whose decision it waits for (None:
            none waits).
    """

    def __init__(self, mission: str, cid: str, pose_interval_s: float, stop: threading.Event, physics, now: float):
        self.mission, self.cid, self.pose_interval_s, self.stop = mission, cid, pose_interval_s, stop
        self.physics = physics  # the process's PhysicsThread, or None: physics in the carrier's thread
        self.body = None
        self.track = Track(now)
        self.pending = None

    def position(self) -> tuple[float, float]:
        return tuple(map(float, self.body.position(self.cid)))

    def counts(self, j: int, x) -> tuple[int, ...] | None:
        """The region counts behind ``x`` at stage j under the coverage reward (world/regions.py),
        None otherwise (and when a body other than the simulated one, a ROS 2 robot's, sensed ``x``)."""
        sense_counts = getattr(self.body, "sense_counts", None)
        counts = sense_counts(self.cid, j) if x is not None and sense_counts is not None else None
        return counts if counts is not None and sum(counts) == x else None

    def _physics_until(self, t: float, each_chunk=None) -> None:
        """Physics to mission time ``t`` (s) at fixed steps, unpaced, a chunk at a time so that a
        stop request is seen soon (``each_chunk()`` after each)."""
        while True:  # at least once: a body may have to look at the time (a robot's odometry)
            self.body.advance_to(min(t, self.body.time + PROGRESS_CHUNK_S))
            if each_chunk is not None:
                each_chunk()
            if self.body.time >= t - 1e-9 or self.stop.is_set():
                return

    def advance(self, t: float, paced: bool, now: Moving):
        """Physics to mission time ``t`` (s) at fixed steps, paced when realtime > 0 (and
        ``paced``); on the sim clock a Progress message at least every ``progress_s`` of wall
        time on the way. Unpaced, in the process's physics thread when it has one
        (:class:`carriers.shared.PhysicsThread`) while this thread sends the Progress. ``now``:
        what the carrier is (:class:`Moving`). A generator: while it paces, it yields how long
        the carrier is to take its inbox (s) and is sent what the carrier is then; it returns
        what the carrier is at its end."""
        if now.timers.realtime <= 0 or not paced:  # no inbox wait on the way: the carrier stays as it is
            self.run_to(t, now)
            return now
        wall0, t0 = now.clock(), self.body.time
        while self.body.time < t - 1e-9 and not self.stop.is_set():
            target = min(t, self.body.time + PACE_CHUNK_S)
            self.body.advance_to(target)
            self.publish_poses(now)
            self.progress(now)
            while not self.stop.is_set():  # the chunk's wall time (mission.timers.pace)
                at = now.clock()
                rule = pace(wall0, self.body.time - t0, now.timers.realtime, at)
                if isinstance(rule, GoOn):
                    break
                now = yield min(0.05, rule.until - at)
        return now

    def drive(self, j: int, who, paced: bool, now: Moving):
        """Its body to stage j's time (:meth:`advance`, a generator as it is; ``who``: the carrier,
        :class:`carriers.who.Who`), then a Pose for every pose tick it passed
        (:meth:`publish_poses`, told what the carrier is at the end of the drive)."""
        now = yield from self.advance(who.scenario.stage_time(j), paced, now)
        self.publish_poses(now)

    def run_to(self, t: float, now: Moving) -> None:
        """Physics to mission time ``t`` (s) at fixed steps, unpaced, in the process's physics
        thread when it has one (:class:`carriers.shared.PhysicsThread`) while this thread sends
        the Progress (sim clock) that falls due on the way. ``now``: what the carrier is."""
        if self.physics is None:
            self._physics_until(t, lambda: self.progress(now))
            return
        job = self.physics.submit(self._physics_until, t)
        while not futures.wait((job,), DEFAULTS.progress_s).done:
            self.progress(now)
        self.progress(now)
        job.result()

    def asked(self, step, who, now: Moving):
        """What a join path asks of the body (:mod:`mission.joins`), carried out: ``Drive`` it
        (unpaced) to a stage's time, ``Here``, a passenger released (``Release``); what the path
        is answered (where the body is; None for a release). ``who``: the carrier
        (:class:`carriers.who.Who`); ``now``: what the carrier is (:class:`Moving`)."""
        if isinstance(step, joins.Release):
            self.body.deploy(self.cid)
            return None
        if isinstance(step, joins.Drive):
            self.run_to(who.scenario.stage_time(step.stage), now)
        return self.position()

    def progress(self, moving: Moving, every_s: float = DEFAULTS.progress_s, now: float | None = None) -> None:
        """Sim clock: tell the coordinator and the peers that this carrier is working (a
        Progress message) when it is due (:func:`mission.timers.due`: ``every_s`` since the last;
        ``now``: the caller's look at the clock, else the clock now) [P-10.6]."""
        now = moving.clock() if now is None else now
        if moving.timers.clock != "sim" or not due(self.track.progress_at, now, every_s):
            return
        self.send_progress(moving, now)

    def send_progress(self, moving: Moving, now: float | None = None) -> None:
        """A Progress message now (its lifecycle's :class:`mission.carrier_life.SendProgress`, or
        :meth:`progress` when due)."""
        self.track.progress_at = moving.clock() if now is None else now
        if moving.node.revision < Progress.SINCE:
            return  # a coordinator of an earlier revision has no Progress (it would reject it)
        moving.node.put(keys.carrier_key(self.mission, self.cid, "progress"),
                        Progress(self.mission, self.cid, moving.stage, float(self.body.time)))

    def observe(self, j: int, who, passengers_left: int):
        """Sense at stage j (x None where it is not scheduled: ``who.valid``) and keep the
        Observation it publishes (:attr:`pending`; acoustic: the trail fitted to the frame,
        wire/sizes.py); x."""
        x = self.body.sense(self.cid, j) if who.valid[j] else None
        self.pending = fit_to_links(who.observation(j, x, self.position(), passengers_left, self.trail(),
                                                    self.counts(j, x)), who.scenario.links)
        return x

    def trail(self) -> tuple:
        samples = self.body.trajectory(self.cid)
        new = samples[self.track.trail_from:, 1:3]
        self.track.trail_from = len(samples)
        if len(new) > MAX_TRAIL:
            new = new[np.linspace(0, len(new) - 1, MAX_TRAIL).astype(int)]
        return tuple((float(a), float(b)) for a, b in new)

    def publish_poses(self, moving: Moving) -> None:
        """A Pose for every pose tick the physics passed since the last call: the trajectory
        samples (one per second of simulated time) whose time is a multiple of the interval."""
        every = self.pose_interval_s
        if every <= 0 or moving.node is None:
            return
        samples = self.body.trajectory(self.cid)
        step = max(1, int(round(every)))
        track = self.track
        for k in range(track.pose_from, len(samples)):
            if k > 0:
                dx, dy = samples[k, 1] - samples[k - 1, 1], samples[k, 2] - samples[k - 1, 2]
                if dx * dx + dy * dy > 1e-12:
                    track.heading = float(np.arctan2(dy, dx))
            if k % step == 0:
                moving.node.put(keys.carrier_key(self.mission, self.cid, "pose"), Pose(
                    self.mission, self.cid, float(samples[k, 0]), (float(samples[k, 1]), float(samples[k, 2])),
                    track.heading, moving.passengers_left))
                if moving.ros2 is not None:
                    moving.ros2.pose(float(samples[k, 0]), float(samples[k, 1]), float(samples[k, 2]), track.heading)
        track.pose_from = len(samples)
