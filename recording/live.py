"""The coordinator's recorder: mission.mcap written while the mission runs.

The coordinator hands it every mission event it records (after mission.db has it: the file
never shows what the log does not) and every carrier Pose it receives; the recorder turns them
into MCAP messages through :mod:`recording.stream`. A recording error is logged once and turns
the recorder off: it never stops a mission. Resuming a mission (a restarted coordinator)
rewrites mission.mcap from the stored events first, then goes on live.

Two MCAP profiles (docs/fleet.md, "mission.mcap"): ``foxglove`` (the default: ``mission.mcap``,
Foxglove's well-known schemas, recording/mcap.py) and ``ros2`` (a rosbag2 bag ``ros2bag/``: CDR
and ``ros2msg`` schemas on the ROS 2 topics of ros2/topics.py, for ``ros2 bag play``; needs the
``[ros2]`` extra). Further sinks fed the same stream (the live ``--ros2`` publisher) are given as
factories taking the scene.
"""
from __future__ import annotations

from pathlib import Path

from recording import PROFILES
from recording.stream import Clock, feed_event, feed_message

#: File name of the recording in a results directory.
MCAP_NAME = "mission.mcap"


def recording_path(out_dir, profile: str = "foxglove") -> Path:
    """Where a profile's recording goes in a results directory."""
    if profile == "ros2":
        from ros2.bag import BAG_NAME

        return Path(out_dir) / BAG_NAME
    return Path(out_dir) / MCAP_NAME


def open_sink(path, profile: str, scene, problem=None, metadata=None):
    """The recording sink of ``profile`` writing ``path``."""
    if profile not in PROFILES:
        raise ValueError(f"profile: expected one of {', '.join(PROFILES)}, found {profile!r}")
    if profile == "ros2":
        from ros2.bag import BagRecorder

        return BagRecorder(path, scene, problem, metadata)
    from recording.mcap import McapRecorder

    return McapRecorder(path, scene, problem, metadata)


class LiveRecorder:
    """mission.mcap of one coordinator run.

    Args:
        out_dir: the results directory.
        scenario: the scenario (with the run's seed).
        problem: the planner problem (for the reward so far).
        metadata: strings for the MCAP metadata record.
        log: callable taking one line (for the one error message).
        profile: one of :data:`PROFILES`; None: no file (only ``sinks``).
        sinks: more sinks fed the same stream, as factories ``scene -> sink`` (each with a
            ``close()``), each guarded on its own.
    """

    def __init__(self, out_dir, scenario, problem=None, metadata=None, log=print, profile: str | None = "foxglove",
                 sinks=()):
        from world.scene import build_scene

        self._log = log
        scene = build_scene(scenario)
        self.clock = Clock(scene.stage_times)
        self.sinks: dict[str, object] = {}  # name -> sink, while it works
        self.path = None
        if profile is not None:
            self.path = recording_path(out_dir, profile)
            self.sinks[self.path.name] = open_sink(self.path, profile, scene, problem, metadata)
        for k, factory in enumerate(sinks):
            sink = factory(scene)
            self.sinks[getattr(sink, "name", f"sink {k}")] = sink

    @property
    def sink(self):
        """The recording file's sink (None when there is none or it stopped)."""
        return None if self.path is None else self.sinks.get(self.path.name)

    def _guard(self, fn, *args) -> None:
        for name, sink in list(self.sinks.items()):
            try:
                fn(sink, *args)
            except Exception as exc:  # a recording problem must never stop a mission
                self._log(f"coordinator: {name} recording stopped: {type(exc).__name__}: {exc}")
                self.sinks.pop(name, None)
                try:
                    sink.close()
                except Exception:
                    pass

    def event(self, event) -> None:
        """A mission event the coordinator recorded (mission.events)."""
        self._guard(feed_event, event, self.clock)

    def message(self, msg) -> None:
        """A decoded wire message outside the mission log (a carrier's Pose)."""
        self._guard(feed_message, msg, self.clock)

    def close(self) -> None:
        """Finish every sink: the file's summary section and footer (idempotent)."""
        sinks, self.sinks = self.sinks, {}
        failed = None
        for sink in sinks.values():
            try:
                sink.close()
            except Exception as exc:
                failed = failed or exc
        if failed is not None:
            raise failed
