"""mission.mcap: a real fleet's recording reads back with the `mcap` package and agrees with
summary.json; a SIGTERMed coordinator leaves a complete file; the rebuild from mission.db
gives the same channels and counts; carriers never import the recording libraries."""
from __future__ import annotations

import json
import math
import re
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from mcap.reader import make_reader

import world
from fleet_helpers import ROOT, TINY

RUN_FLEET = str(ROOT / "run_fleet.py")
SIX = ROOT / "scenarios" / "six_carriers.yaml"

#: topic -> schema name every mission.mcap carries.
CHANNELS = {
    "/world": "foxglove.SceneUpdate", "/carriers": "foxglove.SceneUpdate", "/tf": "foxglove.FrameTransform",
    "/deployments": "foxglove.SceneUpdate", "/log": "foxglove.Log", "/observations": "marsupial.Observation",
    "/decisions": "marsupial.Decision", "/confirmations": "marsupial.Confirm", "/reward": "marsupial.Reward",
}


def read_mcap(path):
    """(topic -> schema name, topic -> message count, topic -> [(log_time ns, bytes)])."""
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None, "no summary section: not finalised"
        schemas = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
        counts = {c.topic: summary.statistics.channel_message_counts.get(c.id, 0) for c in summary.channels.values()}
        messages: dict = {}
        for _schema, channel, message in reader.iter_messages(log_time_order=False):
            messages.setdefault(channel.topic, []).append((message.log_time, message.data))
    for topic, items in messages.items():
        assert len(items) == counts[topic], topic
    return schemas, counts, messages


def _json(messages, topic):
    return [json.loads(data) for _t, data in messages.get(topic, [])]


@pytest.fixture(scope="module")
def six_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("six") / "run"
    proc = subprocess.run([sys.executable, RUN_FLEET, str(SIX), "--out", str(out), "--iterations", "1000", "--no-map"],
                          capture_output=True, text=True, timeout=240, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return out, json.loads((out / "summary.json").read_text())


@pytest.mark.slow
def test_six_carriers_mcap_agrees_with_the_summary(six_run):
    out, summary = six_run
    scenario = world.load_scenario(SIX)
    schemas, counts, messages = read_mcap(out / "mission.mcap")
    assert schemas == CHANNELS
    # Stages, decisions, deployments and observations: as summary.json counts them.
    decisions = _json(messages, "/decisions")
    assert counts["/decisions"] == summary["stages_decided"] == summary["stages"] == scenario.stages
    assert [d["deploy"] for d in sorted(decisions, key=lambda d: d["stage"])] == summary["decisions"]
    deployments = sum(len(c["deployments"]) for c in summary["carriers"])
    assert counts["/deployments"] == deployments > 0
    confirmed = {(c["id"], d["stage"]) for c in summary["carriers"] for d in c["deployments"]}
    assert {(m["carrier"], m["stage"]) for m in _json(messages, "/confirmations") if m["deployed"]} == confirmed
    observed = [m for m in _json(messages, "/observations") if m["x"] is not None]
    assert len(observed) == sum(v is not None for row in summary["observations"] for v in row)
    for m in observed:
        assert summary["observations"][scenario.carrier_index(m["carrier"])][m["stage"]] == m["x"]
    assert _json(messages, "/reward")[-1]["reward"] == pytest.approx(summary["total_reward"])
    # The world once; a pose per carrier per simulated second from t = 0 to the last stage.
    assert counts["/world"] == 1
    last = float(scenario.stage_times()[-1])
    assert counts["/tf"] == counts["/carriers"] == scenario.n_carriers * (int(last) + 1)
    # Stamped in simulated time: every log time lies in [0, last stage time].
    for topic, items in messages.items():
        assert all(0 <= t <= last * 1e9 + 1 for t, _ in items), topic
    times = [t for t, _ in messages["/decisions"]]
    assert sorted(times) == [round(float(t) * 1e9) for t in scenario.stage_times()]
    assert any(b"mission complete" in data for _t, data in messages["/log"])


@pytest.mark.slow
def test_rebuild_from_mission_db_matches_the_live_recording(six_run, tmp_path):
    out, _summary = six_run
    rebuilt = tmp_path / "rebuilt.mcap"
    proc = subprocess.run([sys.executable, "-m", "recording", "rebuild", str(out), "-o", str(rebuilt)],
                          capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    live_schemas, live_counts, live = read_mcap(out / "mission.mcap")
    schemas, counts, msgs = read_mcap(rebuilt)
    assert schemas == live_schemas and counts == live_counts
    for topic in ("/decisions", "/observations", "/confirmations", "/reward"):
        assert sorted(map(json.dumps, _json(msgs, topic))) == sorted(map(json.dumps, _json(live, topic))), topic
    # Poses: the scenario's deterministic trajectories are the carriers' own.
    assert sorted(t for t, _ in msgs["/tf"]) == sorted(t for t, _ in live["/tf"])


def _wait_for(predicate, timeout_s, what):
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, what
        time.sleep(0.1)


def read_prefix(path) -> dict:
    """topic -> message count of an MCAP file read as a stream up to where it ends (an
    unfinished file: no summary section, maybe a cut record)."""
    from mcap.records import Channel, Message
    from mcap.stream_reader import StreamReader

    topics, counts = {}, {}
    with open(path, "rb") as f:
        try:
            for record in StreamReader(f, skip_magic=False).records:
                if isinstance(record, Channel):
                    topics[record.id] = record.topic
                elif isinstance(record, Message):
                    topic = topics[record.channel_id]
                    counts[topic] = counts.get(topic, 0) + 1
        except Exception:
            pass  # the end of what the killed writer got out
    return counts


def _run_until_stage_2(out, extra=()):
    """run_fleet.py on tiny.yaml, paced; returns (the launcher, the coordinator's pid) once
    stage 2 of 4 is decided."""
    proc = subprocess.Popen([sys.executable, RUN_FLEET, str(TINY), "--out", str(out), "--realtime", "2", "--no-map",
                             *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    lines = []
    pid = None
    while pid is None:
        line = proc.stdout.readline()
        assert line, proc.stderr.read()[-2000:]
        lines.append(line)
        m = re.search(r"coordinator pid (\d+)", line)
        pid = int(m.group(1)) if m else None
    while not any("stage   1 of " in line for line in lines):
        line = proc.stdout.readline()
        assert line, "".join(lines)
        lines.append(line)
    return proc, pid


@pytest.mark.slow
def test_a_sigkilled_coordinator_leaves_a_readable_prefix(tmp_path):
    import os

    out = tmp_path / "run"
    proc, pid = _run_until_stage_2(out)
    try:
        time.sleep(0.5)
        os.kill(pid, signal.SIGKILL)  # no shutdown path at all: only what was flushed
        time.sleep(0.5)
        proc.send_signal(signal.SIGINT)  # the launcher stops the carriers
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    counts = read_prefix(out / "mission.mcap")
    assert counts.get("/world") == 1 and counts.get("/decisions", 0) >= 2  # flushed after every decision
    assert counts.get("/tf", 0) > 0


@pytest.mark.slow
def test_a_sigtermed_coordinator_leaves_a_readable_mcap(tmp_path):
    import os

    out = tmp_path / "run"
    proc, pid = _run_until_stage_2(out)
    try:
        os.kill(pid, signal.SIGTERM)  # mid-mission: stage 2 of 4 is decided, stage 3 is not yet
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["end_reason"] == "stopped" and 2 <= summary["stages_decided"] < 4
    _schemas, counts, messages = read_mcap(out / "mission.mcap")
    assert counts["/decisions"] == summary["stages_decided"]
    assert counts["/world"] == 1 and counts["/tf"] > 0
    assert b"mission stopped" in messages["/log"][-1][1] or any(b"mission stopped" in d for _t, d in messages["/log"])


def test_an_in_process_mission_records_every_pose_and_no_rejection(tmp_path):
    from fleet_helpers import InProcessFleet

    tiny = world.load_scenario(TINY)
    fleet = InProcessFleet(tiny, tmp_path)
    fleet.start_coordinator()
    for cid in tiny.carrier_ids:
        fleet.start_carrier(cid)
    summary = fleet.join()
    assert summary["rejected"]["coordinator"] == {}  # poses are not rejections
    _schemas, counts, messages = read_mcap(tmp_path / "mission.mcap")
    last = float(tiny.stage_times()[-1])
    assert counts["/tf"] == tiny.n_carriers * (int(last) + 1)
    assert counts["/decisions"] == tiny.stages


def test_carriers_do_not_import_the_recording_or_viewer_libraries():
    code = ("import sys, carriers.node; bad = [m for m in ('foxglove', 'mcap', 'rerun', 'recording') "
            "if m in sys.modules]; print(bad)")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "[]"


def test_pose_round_trip_and_size():
    from wire.messages import Pose, decode, encode

    pose = Pose("six_carriers", "c1", 120.0, (10.0, 55.5), math.pi / 2, 3)
    data = encode(pose)
    assert decode(data) == pose and len(data) < 128
    with pytest.raises(Exception):
        encode(Pose("m", "c1", 1.0, (0.0, 0.0), 4.0, 1))  # heading outside [-pi, pi]
    assert np.isfinite(pose.heading)


def test_the_scene_is_the_map_of_the_mission():
    from matplotlib.path import Path as MplPath

    from world.render import CARRIER_COLOURS
    from world.scene import build_scene

    scenario = world.load_scenario(SIX)
    scene = build_scene(scenario)
    geometry = world.stage_geometry(scenario)
    assert [c.id for c in scene.carriers] == list(scenario.carrier_ids)
    assert [c.colour for c in scene.carriers] == [CARRIER_COLOURS[r % len(CARRIER_COLOURS)] for r in range(6)]
    assert len(scene.overlaps) == len(geometry.overlaps) > 0
    for group, members in zip(scene.overlaps, geometry.overlaps):
        assert group.members == tuple((scenario.carrier_ids[r], j) for r, j in members)
        outline = MplPath(group.outline)
        assert all(outline.contains_point(p, radius=-1e-6) or outline.contains_point(p, radius=1e-6)
                   for p in group.points)  # every member lies inside its group's outline
    np.testing.assert_array_equal(scene.features, world.sample_features(scenario))
    assert scene.walls.shape == scenario.map.segments.shape


@pytest.mark.parametrize("stage_interval, realtime, expected", [
    (5.0, 0.0, 1.0), (20.0, 0.0, 1.0), (21.0, 0.0, 2.0), (100.0, 0.0, 5.0), (480.0, 0.0, 24.0),
    (480.0, 1.0, 1.0), (480.0, 0.5, 1.0),
])
def test_an_unpaced_carrier_sends_at_most_twenty_poses_a_stage_by_default(stage_interval, realtime, expected):
    from mission.timeouts import POSES_PER_STAGE, pose_interval

    got = pose_interval(stage_interval, realtime)
    assert got == expected and got == int(got)
    if realtime == 0:
        assert stage_interval / got <= POSES_PER_STAGE


@pytest.mark.slow
def test_the_default_pose_interval_reaches_the_carrier_processes(tmp_path):
    # run_fleet.py without --pose-interval: its carrier processes resolve the default from the
    # scenario (60-s stages, unpaced: a Pose every 3 s), and the recording has what they sent.
    text = TINY.read_text().replace("stage_interval: 5.0", "stage_interval: 60.0").replace("stages: 4", "stages: 2")
    text = text.replace("speed: 2.0", "speed: 0.25")
    scenario = tmp_path / "long.yaml"
    scenario.write_text(text)
    out = tmp_path / "run"
    proc = subprocess.run([sys.executable, RUN_FLEET, str(scenario), "--out", str(out), "--no-map"],
                          capture_output=True, text=True, timeout=240, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-2000:]
    _schemas, counts, messages = read_mcap(out / "mission.mcap")
    times = sorted({t for t, _data in messages["/tf"]})
    assert times and all(abs(t / 1e9 / 3.0 - round(t / 1e9 / 3.0)) < 1e-9 for t in times), times[:5]
    assert counts["/tf"] <= 2 * (60 // 3 + 1)
