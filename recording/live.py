"""The coordinator's recorder: mission.mcap written while the mission runs.

The coordinator hands it every mission event it records (after mission.db has it: the file
never shows what the log does not) and every carrier Pose it receives; the recorder turns them
into MCAP messages through :mod:`recording.stream`. A recording error is logged once and turns
the recorder off: it never stops a mission. Resuming a mission (a restarted coordinator)
rewrites mission.mcap from the stored events first, then goes on live.
"""
from __future__ import annotations

from pathlib import Path

from recording.stream import Clock, feed_event, feed_message

#: File name of the recording in a results directory.
MCAP_NAME = "mission.mcap"


class LiveRecorder:
    """mission.mcap of one coordinator run.

    Args:
        out_dir: the results directory.
        scenario: the scenario (with the run's seed).
        problem: the planner problem (for the reward so far).
        metadata: strings for the MCAP metadata record.
        log: callable taking one line (for the one error message).
    """

    def __init__(self, out_dir, scenario, problem=None, metadata=None, log=print):
        from recording.mcap import McapRecorder
        from world.scene import build_scene

        self.path = Path(out_dir) / MCAP_NAME
        self._log = log
        scene = build_scene(scenario)
        self.clock = Clock(scene.stage_times)
        self.sink = McapRecorder(self.path, scene, problem, metadata)

    def _guard(self, fn, *args) -> None:
        if self.sink is None:
            return
        try:
            fn(*args)
        except Exception as exc:  # a recording problem must never stop a mission
            self._log(f"coordinator: {self.path.name} recording stopped: {type(exc).__name__}: {exc}")
            sink, self.sink = self.sink, None
            try:
                sink.close()
            except Exception:
                pass

    def event(self, event) -> None:
        """A mission event the coordinator recorded (mission.events)."""
        self._guard(feed_event, self.sink, event, self.clock)

    def message(self, msg) -> None:
        """A decoded wire message outside the mission log (a carrier's Pose)."""
        self._guard(feed_message, self.sink, msg, self.clock)

    def close(self) -> None:
        """Finish the file: summary section, footer (idempotent)."""
        if self.sink is not None:
            sink, self.sink = self.sink, None
            sink.close()
