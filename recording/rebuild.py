"""Rebuild mission.mcap from a results directory (for missions recorded without it, or to redo it).

Sources: the mission events of mission.db (storage/missiondb.py ``load_events``: observations,
decisions, confirmations, liveliness, Hellos, Byes, the end — exactly what the live recorder
was fed), and the carriers' poses from the scenario's deterministic trajectories
(``world.simulate_mission``: a carrier's path depends only on the scenario and its id), one per
``pose_interval`` seconds up to the last decided stage, with the passengers left per the
confirmed deployments. So a rebuilt file has the same channels and the same mission messages
as a live recording; its poses are the planned physics, not what the carriers reported (a
carrier that crashed or joined late is drawn along its whole path).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from mission import events as ev
from mission.timeouts import pose_interval
from recording import PROFILES
from recording.live import open_sink, recording_path
from recording.stream import Clock, feed_event, feed_message
from world.paths import REPO_ROOT, SCENARIOS


def _scenario_path(run_dir: Path, summary: dict, given: str | None) -> Path:
    if given:
        return Path(given)
    candidates = []
    if summary.get("scenario_file"):
        f = Path(summary["scenario_file"])
        candidates += [f, run_dir / f, REPO_ROOT / f]
    if summary.get("scenario"):
        candidates.append(SCENARIOS / f"{summary['scenario']}.yaml")
    for c in candidates:
        if c.is_file():
            return c
    raise FileNotFoundError(f"{run_dir}: cannot find the scenario file (tried {', '.join(map(str, candidates)) or 'nothing'}); "
                            "pass --scenario FILE")


def _event_time(event, stage_times) -> float | None:
    if isinstance(event, ev.Observation):
        return float(event.t)
    if isinstance(event, (ev.Decided, ev.Confirmed)):
        return float(stage_times[event.stage])
    return None


def rebuild(run_dir, scenario_path: str | None = None, out: str | None = None, pose_interval_s: float | None = None,
            profile: str = "foxglove") -> Path:
    """Write ``out`` (``RUN_DIR/mission.mcap`` by default; with ``profile="ros2"`` the bag
    ``RUN_DIR/ros2bag``) from ``RUN_DIR/mission.db``. ``pose_interval_s``: None = what an unpaced
    mission's carriers use by default (:func:`mission.timeouts.pose_interval`).

    Returns:
        The path written.
    """
    import world
    from world import build_problem
    from storage.missiondb import load_events, load_meta
    from wire.messages import Pose
    from world.scene import build_scene

    if profile not in PROFILES:
        raise ValueError(f"--profile: expected one of {', '.join(PROFILES)}, found {profile!r}")
    run_dir = Path(run_dir)
    db = run_dir / "mission.db"
    if not db.is_file():
        raise FileNotFoundError(f"{db}: no mission log")
    summary_file = run_dir / "summary.json"
    summary = json.loads(summary_file.read_text()) if summary_file.is_file() else {}
    meta = load_meta(db)
    summary.setdefault("scenario", meta.get("scenario"))
    scenario = world.load_scenario(_scenario_path(run_dir, summary, scenario_path))
    seed = meta.get("seed", summary.get("seed"))
    if seed is not None:
        scenario = scenario.with_seed(int(seed))
    mission = meta.get("mission", summary.get("mission", scenario.name))
    events = load_events(db)
    scene = build_scene(scenario)
    times = scene.stage_times
    decided = [e.stage for e in events if isinstance(e, ev.Decided)]
    last_t = float(times[max(decided)]) if decided else float(times[0])
    # Confirmed deployments: (carrier, stage time) -> passengers left afterwards.
    deployed_at = {}
    for e in events:
        if isinstance(e, ev.Confirmed) and e.deployed:
            deployed_at.setdefault(e.carrier, set()).add(float(times[e.stage]))
    poses = []
    if pose_interval_s is None:
        pose_interval_s = pose_interval(scenario.stage_interval, 0.0)
    if pose_interval_s > 0:
        step = max(1, int(round(pose_interval_s)))
        trace = world.simulate_mission(scenario)
        for r, c in enumerate(scenario.carriers):
            samples = trace.trajectories[r]
            heading = 0.0
            for k in range(len(samples)):
                t, x, y = (float(v) for v in samples[k])
                if k > 0:
                    dx, dy = x - samples[k - 1, 1], y - samples[k - 1, 2]
                    if dx * dx + dy * dy > 1e-12:
                        heading = float(np.arctan2(dy, dx))
                if t > last_t + 1e-9:
                    break
                if k % step == 0:
                    left = c.passengers - sum(1 for td in deployed_at.get(c.id, ()) if td < t - 1e-9)
                    poses.append(Pose(mission, c.id, t, (x, y), heading, max(0, left)))
        poses.sort(key=lambda p: (p.t, p.carrier))
    target = Path(out) if out else recording_path(run_dir, profile)
    problem = build_problem(scenario)
    sink = open_sink(target, profile, scene, problem, metadata={
        "mission": mission, "scenario": scenario.name, "seed": scenario.seed,
        "planner": meta.get("planner", summary.get("planner", "")), "fingerprint": meta.get("fingerprint", ""),
        "rebuilt_from": "mission.db"})
    clock = Clock(times)
    k = 0
    try:
        for e in events:
            t = _event_time(e, times)
            while t is not None and k < len(poses) and poses[k].t <= t + 1e-9:
                feed_message(sink, poses[k], clock)
                k += 1
            feed_event(sink, e, clock)
        for p in poses[k:]:
            feed_message(sink, p, clock)
    finally:
        sink.close()
    return target
