"""The mission as ROS 2 topics (--ros2) and as a ROS 2 bag (--mcap-profile ros2), over real Zenoh
sessions on loopback: what a ROS 2 host running rmw_zenoh would see, checked with a plain zenoh
session standing in for it and with rosbags as the independent reader of every payload."""
from __future__ import annotations

import json
import subprocess
import sys
import threading
import time

import pytest
import zenoh

import world
from ros2 import msgs, rmw
from ros2.publisher import CoordinatorTopics, Ros2Settings
from wire.zconfig import free_port, make_config, open_session
from world.scene import build_scene

from fleet_helpers import ROOT, TINY, InProcessFleet, db_rows

typesys = pytest.importorskip("rosbags.typesys")
STORE = typesys.get_typestore(typesys.Stores.ROS2_JAZZY)
DOMAIN = 7


def ros_name(dds: str) -> str:
    """``pkg::msg::dds_::Type_`` -> ``pkg/msg/Type``."""
    pkg, kind, _, name = dds.split("::")
    return f"{pkg}/{kind}/{name[:-1]}"


class RosHost:
    """A plain zenoh session that watches a ROS 2 domain the way rmw_zenoh's graph cache and a
    subscriber do: every graph token, every sample with its attachment."""

    def __init__(self, endpoint: str, domain: int = DOMAIN):
        self.session = open_session(make_config("client", [], [endpoint]), 20.0)
        self.tokens: list[str] = []
        self.samples: list[tuple[str, bytes, bytes | None]] = []
        self._lock = threading.Lock()

        def on_token(sample):
            if sample.kind == zenoh.SampleKind.PUT:
                with self._lock:
                    self.tokens.append(str(sample.key_expr))

        def on_sample(sample):
            att = sample.attachment
            with self._lock:
                self.samples.append((str(sample.key_expr), sample.payload.to_bytes(),
                                     None if att is None else att.to_bytes()))

        self._subs = [self.session.liveliness().declare_subscriber(f"@ros2_lv/{domain}/**", on_token, history=True),
                      self.session.declare_subscriber(f"{domain}/**", on_sample)]

    def close(self):
        for s in self._subs:
            s.undeclare()
        self.session.close()


def _topic_of(key: str) -> tuple[str, str, str]:
    """(topic, DDS type, hash) of a data key ``<domain>/<topic...>/<type>/<hash>``."""
    parts = key.split("/")
    return "/" + "/".join(parts[1:-2]), parts[-2], parts[-1]


@pytest.fixture(scope="module")
def tiny():
    return world.load_scenario(TINY)


def test_a_mission_as_ros2_topics_and_bag(tiny, tmp_path):
    settings = Ros2Settings(domain=DOMAIN)
    fleet = InProcessFleet(tiny, tmp_path, ros2=settings, record_profile="ros2")
    fleet.start_coordinator()
    host = RosHost(fleet.endpoint)  # before the carriers: it sees every carrier's sample
    try:
        for cid in tiny.carrier_ids:
            fleet.start_carrier(cid, ros2=settings)
        summary = fleet.join()
        time.sleep(0.3)
    finally:
        host.close()
    assert summary["ended"] and summary["stages_decided"] == tiny.stages

    # The graph: a node per carrier and one for the coordinator; every token parses, and every
    # publisher's type hash is rosbags'.
    tokens = [rmw.parse_token(k) for k in host.tokens]
    nodes = {(t.namespace, t.node) for t in tokens if t.kind == rmw.NODE}
    assert nodes == {("/mission", "coordinator"), ("/a", "carrier"), ("/b", "carrier")}
    pubs = {t.topic: t for t in tokens if t.kind == rmw.PUBLISHER}
    assert {"/mission/world", "/mission/carriers", "/mission/deployments", "/mission/decisions", "/mission/observations",
            "/mission/confirmations", "/mission/reward", "/mission/log", "/clock", "/a/pose", "/b/pose",
            "/tf"} <= set(pubs)
    for t in pubs.values():
        assert t.type_hash == STORE.hash_rihs01(ros_name(t.dds_type)), t.topic
        assert t.domain == DOMAIN
    assert pubs["/mission/world"].qos == rmw.QoS(durability=rmw.TRANSIENT_LOCAL, depth=1)

    # The GIDs a ROS 2 graph cache gives the publishers: XXH3-128 of each token (rmw_zenoh's
    # Entity::Entity, computed here with xxhash directly), per topic.
    import xxhash

    graph_gids: dict[str, set[bytes]] = {}
    for key, t in zip(host.tokens, tokens):
        if t.kind == rmw.PUBLISHER:
            graph_gids.setdefault(t.topic, set()).add(xxhash.xxh3_128(key.encode()).digest()[::-1])

    # The samples: keys of those publishers, each with an attachment that names its publisher's
    # graph GID and whose sequence numbers count up by one per publisher (from 1), and a payload
    # rosbags decodes.
    by_topic: dict[str, list] = {}
    seqs: dict[bytes, list[int]] = {}
    for key, payload, att in host.samples:
        topic, dds, h = _topic_of(key)
        assert key == rmw.topic_key(DOMAIN, topic, dds, h)
        assert pubs[topic].dds_type == dds and pubs[topic].type_hash == h
        assert att is not None
        meta = rmw.parse_attachment(att)
        assert meta.gid in graph_gids[topic], topic
        seqs.setdefault(meta.gid, []).append(meta.sequence_number)
        by_topic.setdefault(topic, []).append(STORE.deserialize_cdr(payload, ros_name(dds)))
    for numbers in seqs.values():  # the coordinator may publish before the host subscribes
        assert numbers[0] >= 1 and numbers == list(range(numbers[0], numbers[0] + len(numbers))), numbers
    decisions = [json.loads(m.data) for m in by_topic["/mission/decisions"]]
    db = tmp_path / "mission.db"
    stored = {stage: json.loads(deploy) for stage, deploy in db_rows(db, "SELECT stage, deploy FROM decisions")}
    assert {d["stage"]: d["deploy"] for d in decisions} == stored
    assert by_topic["/mission/reward"][-1].data == pytest.approx(summary["total_reward"])
    observed = {(o["carrier"], o["stage"]): o["x"] for o in (json.loads(m.data) for m in by_topic["/mission/observations"])}
    held = {(cid, j): x for r, cid in enumerate(tiny.carrier_ids)
            for j, x in enumerate(summary["observations"][r]) if x is not None}
    assert {k: v for k, v in observed.items() if v is not None} == held
    assert len(by_topic["/a/pose"]) > 0 and by_topic["/a/pose"][0].header.frame_id == "map"
    children = {tr.child_frame_id for m in by_topic["/tf"] for tr in m.transforms}
    assert children == {"a", "b"}
    carriers = by_topic["/mission/carriers"][-1].markers
    assert {m.text.split()[0] for m in carriers if m.ns == "carrier_labels"} == {"a", "b"}
    deployed = sum(len(c["deployments"]) for c in summary["carriers"])
    last = by_topic["/mission/deployments"][-1].markers
    assert len(by_topic["/mission/deployments"]) == deployed
    assert sum(m.ns == "passengers" for m in last) == sum(m.ns == "sensing_discs" for m in last) == deployed

    # The bag, read back with rosbags' reader.
    from rosbags.rosbag2 import Reader

    with Reader(tmp_path / "ros2bag") as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        counts = {c.topic: c.msgcount for c in reader.connections}
        reward, world_msg = None, None
        for conn, _, raw in reader.messages():
            if conn.topic == "/mission/reward":
                reward = STORE.deserialize_cdr(raw, conn.msgtype).data
            if conn.topic == "/mission/world":
                world_msg = STORE.deserialize_cdr(raw, conn.msgtype)
    assert types["/mission/world"] == "visualization_msgs/msg/MarkerArray"
    assert types["/a/pose"] == "geometry_msgs/msg/PoseStamped" and types["/tf"] == "tf2_msgs/msg/TFMessage"
    assert counts["/mission/decisions"] == tiny.stages
    assert counts["/mission/observations"] == db_rows(db, "SELECT COUNT(*) FROM observations")[0][0]
    assert counts["/mission/confirmations"] == db_rows(db, "SELECT COUNT(*) FROM confirmations")[0][0]
    assert counts["/mission/world"] == 1
    assert reward == pytest.approx(summary["total_reward"])
    assert {"bounds", "walls", "paths", "decision_points", "overlaps", "features"} <= {m.ns for m in world_msg.markers}

    # The same bag rebuilt from mission.db holds the same mission messages.
    from recording.rebuild import rebuild

    rebuilt = rebuild(tmp_path, str(TINY), str(tmp_path / "rebuilt"), profile="ros2")
    with Reader(rebuilt) as reader:
        again = {c.topic: c.msgcount for c in reader.connections}
    for topic in ("/mission/decisions", "/mission/observations", "/mission/confirmations", "/mission/world"):
        assert again[topic] == counts[topic], topic


def test_a_late_ros2_viewer_gets_the_latched_world(tiny):
    """/mission/world is transient local: an rmw_zenoh subscriber (an AdvancedSubscriber querying
    late publishers' caches, as rmw_subscription_data.cpp declares it) that comes later gets it."""
    from zenoh import ext

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    a = zenoh.open(make_config("peer", [endpoint]))
    b = zenoh.open(make_config("client", [], [endpoint]))
    try:
        sink = CoordinatorTopics(a, build_scene(tiny), DOMAIN)
        time.sleep(0.3)
        key = rmw.topic_key(DOMAIN, "/mission/world", msgs.dds_name("visualization_msgs/msg/MarkerArray"),
                            msgs.type_hash("visualization_msgs/msg/MarkerArray"))
        got = []
        sub = ext.declare_advanced_subscriber(b, key, lambda s: got.append(s.payload.to_bytes()),
                                              history=ext.HistoryConfig(detect_late_publishers=True, max_samples=1))
        deadline = time.monotonic() + 5
        while not got and time.monotonic() < deadline:
            time.sleep(0.05)
        sub.undeclare()
        sink.close()
    finally:
        b.close()
        a.close()
    assert got, "no latched /mission/world"
    markers = STORE.deserialize_cdr(got[0], "visualization_msgs/msg/MarkerArray").markers
    assert any(m.ns == "paths" for m in markers)


def test_carrier_namespaces_are_ros_names():
    from ros2.topics import carrier_namespace

    assert [carrier_namespace(c) for c in ("c1", "robot-1.a", "0007")] == ["/c1", "/robot_1_a", "/c_0007"]


def test_off_imports_nothing_of_ros2():
    """Without --ros2 the processes import nothing of ros2/ (nor rosbags)."""
    code = (
        "import sys\nfrom launcher.flags import parse_args\nfrom launcher.settings import check\n"
        "import carriers.node, coordinator.node, recording.live, recording.rebuild\n"
        "args = parse_args(['scenarios/tiny.yaml', '--role', 'carrier', '--carrier', 'a'])\n"
        "import world\n"
        "settings, problems = check(args, world.load_scenario('scenarios/tiny.yaml'))\n"
        "assert problems == [] and settings.ros2() is None\n"
        "print([m for m in sys.modules if m == 'ros2' or m.startswith(('ros2.', 'rosbags'))])\n")
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip().splitlines()[-1] == "[]"


@pytest.mark.parametrize("flags, line", [
    (["--ros2", "--ros2-domain", "300"], "--ros2-domain: expected an integer 0..232"),
    (["--ros2-robot"], "--ros2-robot: only with --role carrier and one --carrier ID"),
    (["--role", "carrier", "--carrier", "a,b", "--ros2-robot"], "--ros2-robot: only with --role carrier and one"),
    (["--role", "carrier", "--carrier", "a", "--ros2-robot", "--ros2-namespace", "robot 1"],
     "--ros2-namespace: expected a ROS 2 namespace"),
    (["--role", "carrier", "--carrier", "a", "--ros2", "--ros2-namespace", "/r1"],
     "--ros2-namespace: only with --ros2-robot"),
    (["--role", "carrier", "--carrier", "a", "--robot-sensing", "frontier"], "--robot-sensing: only with --ros2-robot"),
    (["--role", "carrier", "--carrier", "a", "--ros2", "--robot-sensing", "features"],
     "--robot-sensing: only with --ros2-robot"),
    (["--role", "carrier", "--carrier", "a", "--ros2-robot", "--robot-sensing", "frontier", "--robot-cloud-topic", "p"],
     "--robot-cloud-topic: only with --ros2-robot --robot-sensing frontier3d"),
    (["--role", "carrier", "--carrier", "a", "--ros2-robot", "--robot-sensing", "frontier3d",
      "--robot-cloud-topic", "lidar points"], "--robot-cloud-topic: expected a topic in the robot's namespace"),
    (["--role", "carrier", "--carrier", "a", "--ros2-robot", "--robot-sensing", "frontier3d", "--robot-voxel", "0.2"],
     "--robot-voxel: only with --robot-cloud-topic"),
    (["--role", "carrier", "--carrier", "a", "--ros2-robot", "--robot-sensing", "frontier3d",
      "--robot-cloud-topic", "points", "--robot-voxel", "0"], "--robot-voxel: expected a voxel size > 0 (m), found 0"),
    (["--role", "carrier", "--carrier", "a", "--ros2-robot", "--robot-sensing", "frontier3d",
      "--robot-sensor-offset", "0", "0", "1"], "--robot-sensor-offset: only with --robot-cloud-topic"),
    (["--role", "carrier", "--carrier", "a", "--ros2-robot", "--robot-sensing", "frontier3d",
      "--robot-cloud-topic", "points", "--robot-sensor-offset", "0", "nan", "1"],
     "--robot-sensor-offset: expected three finite numbers X Y Z (m)"),
], ids=["domain", "robot-role", "robot-two-ids", "namespace", "namespace-without-robot", "sensing-without-robot",
        "sensing-with-ros2-only", "cloud-without-frontier3d", "cloud-topic-name", "voxel-without-cloud", "voxel-zero",
        "offset-without-cloud", "offset-nan"])
def test_bad_ros2_flags_get_one_line(tiny, flags, line):
    from launcher.flags import parse_args
    from launcher.settings import check

    settings, problems = check(parse_args(["scenarios/tiny.yaml", *flags]), tiny)
    assert settings is None and len(problems) == 1
    assert line in problems[0].line() and "\n" not in problems[0].line()


def test_robot_sensing_reaches_the_robot_settings(tiny):
    """--robot-sensing is carried in Ros2Settings.sensing (features by default); its choices
    are ros2.robot.SENSING, written out in launcher/__init__.py so that parsing imports nothing of ros2/."""
    import launcher
    from launcher.flags import parse_args
    from launcher.settings import check
    from ros2.robot import SENSING

    assert launcher.ROBOT_SENSING == SENSING
    robot = ["scenarios/tiny.yaml", "--role", "carrier", "--carrier", "a", "--ros2-robot"]
    for flags, sensing in (([], "features"), (["--robot-sensing", "frontier"], "frontier"),
                           (["--robot-sensing", "frontier3d"], "frontier3d")):
        settings, problems = check(parse_args(robot + flags), tiny)
        assert problems == [] and settings.ros2().sensing == sensing
        assert settings.ros2().cloud_topic == "" and settings.ros2().voxel == 0.0
    settings, problems = check(parse_args(robot + ["--robot-sensing", "frontier3d", "--robot-cloud-topic", "lidar/points",
                                                   "--robot-voxel", "0.4", "--robot-sensor-offset", "0.1", "0", "0.8"]),
                               tiny)
    assert problems == []
    r = settings.ros2()
    assert (r.cloud_topic, r.voxel, r.sensor_offset) == ("lidar/points", 0.4, (0.1, 0.0, 0.8))


def test_ros2_domain_defaults_to_ros_domain_id(tiny, monkeypatch):
    """The domain in force is a field of the settings (the parsed flags stay as given), and it is
    what the one-host launcher's children are given."""
    from launcher.flags import parse_args
    from launcher.settings import check
    from launcher.supervisor import child_argv

    monkeypatch.setenv("ROS_DOMAIN_ID", "12")
    args = parse_args(["scenarios/tiny.yaml", "--ros2"])
    settings, problems = check(args, tiny)
    assert problems == [] and settings.ros2().domain == 12 and args.ros2_domain is None
    argv = child_argv(settings.flags, "carrier", carrier="a")
    assert argv[argv.index("--ros2-domain") + 1] == "12"
    monkeypatch.setenv("ROS_DOMAIN_ID", "x")
    args = parse_args(["scenarios/tiny.yaml", "--ros2"])
    settings, problems = check(args, tiny)
    assert settings is None and [p.line() for p in problems] == ["ROS_DOMAIN_ID: expected an integer 0..232, found 'x'"]
