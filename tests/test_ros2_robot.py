"""A ROS 2 robot as one carrier (--ros2-robot): a simulated robot (tests/ros2_robot_sim.py, a plain
zenoh session in rmw_zenoh's format, independent of ros2/) drives carrier ``a`` of tiny.yaml or
``c3`` of six_carriers.yaml beside simulated carriers; the mission decides what the all-simulated
mission decides, and the robot is told to release exactly the passengers the mission deployed."""
from __future__ import annotations

import threading

import numpy as np
import pytest

import world
from ros2.publisher import Ros2Settings

from fleet_helpers import ROOT, TINY, InProcessFleet, deployed_matrix, offline

pytest.importorskip("rosbags")
from ros2_robot_sim import SimulatedRobot  # noqa: E402

DOMAIN = 3


def _fly(scenario, robot_id, out, acknowledge=True, ack_timeout_s=10.0, sensing="features", cloud_topic="",
         voxel=0.0, offset=(0.0, 0.0, 0.0)):
    fleet = InProcessFleet(scenario, out)
    fleet.start_coordinator()
    robot = SimulatedRobot(scenario, robot_id, fleet.endpoint, "/robot1", DOMAIN, acknowledge=acknowledge,
                           sensing=sensing)
    stop = threading.Event()
    thread = threading.Thread(target=robot.run, args=(stop,), daemon=True)
    thread.start()
    try:
        for cid in scenario.carrier_ids:
            if cid == robot_id:
                fleet.start_carrier(cid, ros2=Ros2Settings(domain=DOMAIN, robot=True, namespace="/robot1",
                                                           ack_timeout_s=ack_timeout_s, sensing=sensing,
                                                           cloud_topic=cloud_topic, voxel=voxel,
                                                           sensor_offset=offset))
            else:
                fleet.start_carrier(cid)
        summary = fleet.join(180.0)
    finally:
        stop.set()
        thread.join(5)
        robot.close()
    return fleet, robot, summary


def _check(scenario, robot_id, fleet, robot, summary):
    reference, x = offline(scenario)
    assert summary["ended"] and summary["stages_decided"] == scenario.stages
    assert all(fleet.results[cid] == "end" for cid in scenario.carrier_ids)
    np.testing.assert_array_equal(np.array(summary["observations"], dtype=float), x)
    np.testing.assert_array_equal(deployed_matrix(summary, scenario), reference.deployed)
    assert summary["total_reward"] == pytest.approx(reference.reward)
    from ros2.robot import RobotBody

    assert isinstance(fleet.carriers[robot_id].crew.motion.body, RobotBody)  # its body was the robot, not the physics
    r = scenario.carrier_index(robot_id)
    mine = summary["carriers"][r]
    assert sorted(p for _, p in robot.released) == sorted(d.get("passenger", i) for i, d in
                                                          enumerate(mine["deployments"]))
    assert len(robot.released) == int(reference.deployed[r].sum()) == scenario.carriers[r].passengers
    # Where it deployed is where the robot's odometry put it.
    trace = world.simulate_mission(scenario)
    for d in mine["deployments"]:
        np.testing.assert_allclose(d["position"], trace.positions[r, d["stage"]], atol=1e-9)


def test_a_ros2_robot_flies_as_a_carrier_of_tiny(tmp_path):
    tiny = world.load_scenario(TINY)
    fleet, robot, summary = _fly(tiny, "a", tmp_path)
    _check(tiny, "a", fleet, robot, summary)


def test_an_unacknowledged_deployment_is_logged_and_confirmed(tmp_path):
    tiny = world.load_scenario(TINY)
    fleet, robot, summary = _fly(tiny, "a", tmp_path, acknowledge=False, ack_timeout_s=0.3)
    _check(tiny, "a", fleet, robot, summary)
    lines = [ln for ln in fleet.log.lines if "no acknowledgement of passenger" in ln]
    assert len(lines) == len(robot.released) == 2
    assert "counted as deployed (never re-sent)" in lines[0]


@pytest.mark.slow
def test_a_ros2_robot_flies_as_a_carrier_of_six_carriers(tmp_path):
    six = world.load_scenario(ROOT / "scenarios" / "six_carriers.yaml")
    fleet, robot, summary = _fly(six, "c3", tmp_path)
    _check(six, "c3", fleet, robot, summary)


def test_a_robot_of_another_ros2_format_is_refused_in_one_line(tmp_path):
    """Humble's rmw_zenoh writes no RIHS01 hash (``TypeHashNotSupported``): its odometry key can
    never match ours, so the robot's carrier stops at once with one line (exit reason
    ros2-mismatch, code 2) and the mission goes on without it."""
    from carriers.node import EXIT_CODES
    from wire.zconfig import make_config, open_session

    tiny = world.load_scenario(TINY)
    fleet = InProcessFleet(tiny, tmp_path, join_timeout_s=3.0)  # not the default 10 s for the carrier that left
    fleet.start_coordinator()
    humble = open_session(make_config("client", [], [fleet.endpoint]), 20.0)
    token = humble.liveliness().declare_token(
        f"@ros2_lv/{DOMAIN}/{humble.zid()}/0/10/MP/%/%robot1/robot/%robot1%odom/nav_msgs::msg::dds_::Odometry_/"
        "TypeHashNotSupported/::,10:,:,:,,")
    try:
        fleet.start_carrier("a", ros2=Ros2Settings(domain=DOMAIN, robot=True, namespace="/robot1"))
        fleet.start_carrier("b")
        summary = fleet.join(120.0)
    finally:
        token.undeclare()
        humble.close()
    assert fleet.results["a"] == "ros2-mismatch" and EXIT_CODES["ros2-mismatch"] == 2
    lines = [ln for ln in fleet.log.lines if "carrier a:" in ln and "RIHS01" in ln]
    assert len(lines) == 1 and "Humble" in lines[0], fleet.log.lines
    assert fleet.results["b"] == "end" and summary["ended"]


def test_a_silent_robot_is_taken_where_it_was_planned_and_logged_once():
    """No odometry, no detections: the body gives up after its timeout (one line each), takes
    the planned position and x = 0, and never blocks the carrier longer than that."""
    import zenoh

    from ros2.graph import Node
    from ros2.robot import RobotBody
    from wire.zconfig import free_port, make_config

    tiny = world.load_scenario(TINY)
    session = zenoh.open(make_config("peer", [f"tcp/127.0.0.1:{free_port()}"]))
    lines: list[str] = []
    try:
        node = Node(session, DOMAIN, "/a", "carrier", watch=False)
        body = RobotBody(tiny, "a", node, "/robot9", sync=True, log=lines.append, stop=threading.Event(),
                         timeout_s=0.2)
        body.advance_to(5.0)
        assert body.position("a") == tuple(float(v) for v in tiny.carriers[0].position_at(5.0))
        assert body.sense("a") == 0
        body.advance_to(10.0)
        assert body.trajectory("a").shape == (11, 3)
        node.close()
    finally:
        session.close()
    assert [ln.split(":")[1].split(" stamped")[0].strip() for ln in lines] == ["no odometry", "no feature detections"]


# --------------------------------------------------------------------------- --robot-sensing frontier


def _their_maps(payloads):
    """A world.grid.MapHistory of the maps the simulated robot sent (CDR payloads), decoded by
    rosbags (not ros2/) and made grids by the importer's own code."""
    from ros2_robot_sim import STORE
    from world.grid import MapHistory, grid_from_message

    return MapHistory(grid_from_message(STORE.deserialize_cdr(payload, "nav_msgs/msg/OccupancyGrid"), source="sim")
                      for payload in payloads)


def test_a_ros2_robot_observes_the_frontier_of_its_growing_map(tmp_path):
    """--robot-sensing frontier: every stage's observation of the robot's carrier is
    world.grid.MapHistory's value (the importer's --replay rule) of the robot's odometry
    position in the maps it sent (none yet at stage 0: x = 0; the map stamped at the stage time;
    the latest before it), and the growing map changes it."""
    tiny = world.load_scenario(TINY)
    fleet, robot, summary = _fly(tiny, "a", tmp_path, sensing="frontier")
    assert summary["ended"] and summary["stages_decided"] == tiny.stages
    assert all(fleet.results[cid] == "end" for cid in tiny.carrier_ids)
    r = tiny.carrier_index("a")
    trace = world.simulate_mission(tiny)
    maps = _their_maps(p for _, p in robot.maps)
    assert [g.stamp for g in maps.grids] == [2.0, 5.0, 8.0, 11.0, 14.0]
    expected = [maps.value(float(t), trace.positions[r, j], tiny.sensing_radius)
                for j, t in enumerate(tiny.stage_times())]
    observed = np.array(summary["observations"], dtype=float)
    assert observed[r].tolist() == expected
    assert expected[0] == 0 and len({v for v in expected if v}) >= 2, expected
    # The other carrier senses its simulated features, as ever.
    b = tiny.carrier_index("b")
    np.testing.assert_array_equal(observed[b], world.observe_all(tiny)[b])
    mine = summary["carriers"][r]
    assert len(robot.released) == len(mine["deployments"]) == tiny.carriers[r].passengers
    assert not [ln for ln in fleet.log.lines if "map ignored" in ln or "undecodable" in ln]


def _peer_and_robot(tiny, sensing="frontier", binary=True):
    """A zenoh peer on loopback (the carrier's session) and a simulated ``sensing`` robot
    (namespace /robot7) connected to it as a client."""
    import zenoh

    from wire.zconfig import free_port, make_config

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    session = zenoh.open(make_config("peer", [endpoint]))
    robot = SimulatedRobot(tiny, "a", endpoint, "/robot7", DOMAIN, sensing=sensing, binary=binary)
    return session, robot


def _body(tiny, session, lines, sync=False, timeout_s=10.0, sensing="frontier", scans=None):
    """The carrier's node on ``session`` and its ``sensing`` body of robot /robot7 (paced unless
    ``sync``)."""
    from ros2.graph import Node
    from ros2.robot import RobotBody

    node = Node(session, DOMAIN, "/a", "carrier", log=lines.append, watch=False)
    return node, RobotBody(tiny, "a", node, "/robot7", sync=sync, log=lines.append, stop=threading.Event(),
                           timeout_s=timeout_s, sensing=sensing, scans=scans)


def _arrived(history, t, timeout_s=10.0):
    """Until ``history`` (a body's odometry) holds a message stamped ``t`` or later."""
    import time

    deadline = time.monotonic() + timeout_s
    history.pull()
    while not history.reached(t) and time.monotonic() < deadline:
        time.sleep(0.01)
        history.pull()
    assert history.reached(t), f"no message stamped {t} s within {timeout_s} s"


def _odometry_until(robot, stop, t, x, y):
    """The robot's odometry at (x, y) stamped ``t``, 20 times a second until ``stop``."""
    def run():
        while not stop.wait(0.05):
            robot.publish_odometry(t, x, y)
    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread


def test_a_map_sent_before_the_carrier_subscribed_arrives():
    """NS/map is transient local: the map a robot (map_server, SLAM) sent before the carrier's
    body existed still reaches it (its AdvancedSubscriber asks the publisher's cache)."""
    tiny = world.load_scenario(TINY)
    session, robot = _peer_and_robot(tiny)
    lines: list[str] = []
    stop = threading.Event()
    try:
        robot.publish_map(14.0)  # nobody subscribes yet
        node, body = _body(tiny, session, lines)
        thread = _odometry_until(robot, stop, 15.0, 34.0, 20.0)
        body.advance_to(15.0)
        assert body.position("a") == (34.0, 20.0)
        x = body.sense("a", 3)
        stop.set()
        thread.join(2)
        node.close()
    finally:
        stop.set()
        robot.close()
        session.close()
    assert x == _their_maps(p for _, p in robot.maps).value(15.0, (34.0, 20.0), tiny.sensing_radius) > 0
    assert lines == []


def test_a_malformed_map_is_logged_in_one_line_and_ignored():
    """A map whose cells are not width x height, and a payload that is no OccupancyGrid at all:
    one line each, the process goes on, and the next good map counts."""
    from ros2_robot_sim import STORE, map_message

    tiny = world.load_scenario(TINY)
    session, robot = _peer_and_robot(tiny)
    lines: list[str] = []
    stop = threading.Event()
    try:
        node, body = _body(tiny, session, lines)
        robot.wait_for_subscriber(stop, "map", timeout_s=10.0)
        short = map_message(8.0, cells=np.zeros(10, dtype=np.int8))
        robot.publish_map(8.0, bytes(STORE.serialize_cdr(short, "nav_msgs/msg/OccupancyGrid")))
        robot.publish_map(8.0, b"\x00\x01\x00\x00\xff\xff")
        robot.publish_map(8.0, bytes(STORE.serialize_cdr(short, "nav_msgs/msg/OccupancyGrid")))  # the same fault
        good = robot.publish_map(11.0)
        thread = _odometry_until(robot, stop, 11.0, 26.0, 20.0)
        body.advance_to(11.0)
        x = body.sense("a")
        stop.set()
        thread.join(2)
        node.close()
    finally:
        stop.set()
        robot.close()
        session.close()
    assert x == _their_maps([good]).value(11.0, (26.0, 20.0), tiny.sensing_radius) > 0
    assert len(body.maps.grids) == 1 and body.maps.grids[0].stamp == 11.0
    ignored = [ln for ln in lines if "map ignored" in ln]
    assert len(ignored) == 1 and "expected width x height = 88 x 78 = 6864 cells" in ignored[0], lines
    undecodable = [ln for ln in lines if "undecodable nav_msgs/msg/OccupancyGrid" in ln]
    assert len(undecodable) == 1 and len(lines) == 2, lines


def test_the_maps_a_frontier_body_keeps_are_the_ones_its_stages_need():
    """needed_maps: the latest map at or before each coming stage time and the newest (paced:
    the newest only) — what bounds the body's memory without changing any stage's map."""
    from ros2.robot import needed_maps
    from world.grid import latest_at

    stamps = [2.0, 5.0, 8.0, 11.0, 14.0, 17.0]
    stages = [0.0, 5.0, 10.0, 15.0]
    assert needed_maps([], stages, 0.0, True) == []
    assert needed_maps(stamps, stages, 0.0, True) == [1, 2, 4, 5]
    assert needed_maps(stamps, stages, 10.0, True) == [2, 4, 5]
    assert needed_maps(stamps, stages, 10.5, True) == [4, 5]
    assert needed_maps(stamps, stages, 0.0, False) == [5]
    rng = np.random.default_rng(3)
    for _ in range(200):
        stamps = sorted(rng.uniform(0, 30, rng.integers(1, 12)).round(1).tolist())
        now = float(rng.choice(stages))
        kept = needed_maps(stamps, stages, now, True)
        for t in (s for s in stages if s >= now):  # every coming stage finds the same map among the kept
            k = latest_at(stamps, t)
            kk = latest_at([stamps[i] for i in kept], t)
            assert (k < 0 and kk < 0) or stamps[k] == stamps[kept[kk]]


# --------------------------------------------------------------------------- --robot-sensing frontier3d


def _their_octomaps(files, tmp_path) -> list:
    """(stamp, world.voxels.VoxelGrid) of the maps the simulated robot sent: the trees as OctoMap
    itself wrote them to files, read by the import's file reader (``python -m world import
    MAP.bt``), not by the message path."""
    from world.voxels import read_octomap

    out = []
    for k, (t, raw) in enumerate(files):
        path = tmp_path / f"sent{k}.{'bt' if raw.startswith(b'# Octomap OcTree binary') else 'ot'}"
        path.write_bytes(raw)
        out.append((t, read_octomap(path)))
    return out


def _value3d(maps, t, point, radius, keep=(1.0, 0.1)):
    """The import's value of ``point`` (x, y, z) in the latest map stamped at or before ``t``."""
    from world.voxels import FrontierCounter3D

    before = [g for s, g in maps if s <= t + 1e-9]
    return 0 if not before else int(FrontierCounter3D(before[-1], 6).count([point], radius, *keep)[0])


@pytest.mark.parametrize("cloud_topic", ["", "points"], ids=["octomap", "scans"])
def test_a_ros2_robot_observes_the_frontier_voxels_of_its_3d_map(tmp_path, cloud_topic):
    """--robot-sensing frontier3d: the robot (OctoMap's own OcTree of its LiDAR scans, sent on
    NS/octomap_binary as octomap_server does, and each scan on NS/points) drives carrier a of
    tiny; every stage's observation is the import's value (its .bt reader, FrontierCounter3D,
    the paper's height band) of the robot's odometry position, z included, in the latest map
    stamped at or before the stage time (none at stage 0: x = 0) — read from the OctoMap, or
    (--robot-cloud-topic points) made by the carrier from the scans, voxel for voxel OctoMap's."""
    from ros2_robot_sim import LIDAR_UP, ROBOT_Z, VOXEL

    tiny = world.load_scenario(TINY)
    fleet, robot, summary = _fly(tiny, "a", tmp_path, sensing="frontier3d", cloud_topic=cloud_topic,
                                 voxel=VOXEL if cloud_topic else 0.0, offset=(0.0, 0.0, LIDAR_UP))
    assert summary["ended"] and summary["stages_decided"] == tiny.stages
    assert all(fleet.results[cid] == "end" for cid in tiny.carrier_ids)
    r = tiny.carrier_index("a")
    trace = world.simulate_mission(tiny)
    maps = _their_octomaps(robot.files, tmp_path)
    assert [t for t, _ in maps] == [2.0, 5.0, 8.0, 11.0, 14.0]
    points = [(*trace.positions[r, j], ROBOT_Z) for j in range(tiny.stages)]
    expected = [_value3d(maps, float(t), points[j], tiny.sensing_radius) for j, t in enumerate(tiny.stage_times())]
    observed = np.array(summary["observations"], dtype=float)
    assert observed[r].tolist() == expected
    assert expected[0] == 0 and len({v for v in expected if v}) >= 2, expected
    # The height band matters here (the shaft below, the ceiling's edge above), and z is the
    # odometry's: on the floor (z = 0) the band keeps other voxels.
    counted_all = [_value3d(maps, float(t), points[j], tiny.sensing_radius, (0.0, 0.0))
                   for j, t in enumerate(tiny.stage_times())]
    on_floor = [_value3d(maps, float(t), (*points[j][:2], 0.0), tiny.sensing_radius)
                for j, t in enumerate(tiny.stage_times())]
    assert counted_all != expected and on_floor != expected, (counted_all, on_floor, expected)
    b = tiny.carrier_index("b")
    np.testing.assert_array_equal(observed[b], world.observe_all(tiny)[b])
    assert len(robot.released) == len(summary["carriers"][r]["deployments"]) == tiny.carriers[r].passengers
    assert not [ln for ln in fleet.log.lines if "ignored" in ln or "undecodable" in ln]


def test_a_full_octomap_and_a_malformed_one(tmp_path):
    """A full tree (octomap_msgs' fullMapToMsg: ``binary`` false, OctoMap's .ot stream) counts
    as the file does; a truncated tree and a tree of another type are logged once each and
    ignored, and the process goes on."""
    import time

    from ros2_robot_sim import OCTOMAP_TYPE, ROBOT_Z, STORE, OctoMapRobot

    tiny = world.load_scenario(TINY)
    session, robot = _peer_and_robot(tiny, "frontier3d", binary=False)
    lines: list[str] = []
    stop = threading.Event()
    try:
        node, body = _body(tiny, session, lines, sensing="frontier3d")
        robot.wait_for_subscriber(stop, "octomap_binary", timeout_s=10.0)
        other = OctoMapRobot(binary=True)
        other.scan(20.0, 20.0)
        cut = other.message(7.0, str(tmp_path))
        cut.data = cut.data[:-5]
        wrong = other.message(7.0, str(tmp_path))
        wrong.id = "CountingOcTree"
        for msg in (cut, wrong, cut):
            robot.publish_map(7.0, bytes(STORE.serialize_cdr(msg, OCTOMAP_TYPE)))
        robot.publish_map(8.0, at=(22.0, 20.0))
        thread = _odometry_until(robot, stop, 8.0, 22.0, 20.0)
        body.advance_to(8.0)
        deadline = time.monotonic() + 10
        while body.maps.newest < 8.0 and time.monotonic() < deadline:  # paced: the newest map counts
            time.sleep(0.01)
            body.maps.pull()
        x = body.sense("a")
        stop.set()
        thread.join(2)
        node.close()
    finally:
        stop.set()
        robot.close()
        session.close()
    maps = _their_octomaps(robot.files, tmp_path)
    assert robot.files[0][1].startswith(b"# Octomap OcTree file")  # the full format
    assert x == _value3d(maps, 8.0, (22.0, 20.0, ROBOT_Z), tiny.sensing_radius) > 0
    assert len(body.maps.grids) == 1 and body.maps.stamps == [8.0]
    ignored = [ln for ln in lines if "map ignored" in ln]
    assert len(ignored) == 2, lines
    assert "a whole tree, found the data truncated" in ignored[0], ignored
    assert "/robot7/octomap_binary (stamp 7.000 s)" in ignored[0], ignored
    assert "of id OcTree" in ignored[1] and "CountingOcTree" in ignored[1], ignored


def test_scans_made_a_map_and_a_bad_scan(tmp_path):
    """--robot-cloud-topic, paced: a cloud without a float z field is logged once and ignored; a
    scan stamped before any odometry has no pose (logged once, ignored); a scan waits until the
    odometry covers its stamp; the others make the map whose value is the import's in OctoMap's
    own tree of the same scans."""
    import time

    from ros2.robot import ScanSource
    from ros2_robot_sim import LIDAR_UP, ROBOT_Z, T, VOXEL
    from world.voxels import read_octomap

    tiny = world.load_scenario(TINY)
    session, robot = _peer_and_robot(tiny, "frontier3d")
    lines: list[str] = []
    stop = threading.Event()
    try:
        node, body = _body(tiny, session, lines, sensing="frontier3d",
                           scans=ScanSource("points", VOXEL, (0.0, 0.0, LIDAR_UP)))
        robot.wait_for_subscriber(stop, "points", timeout_s=10.0)
        flat = T["sensor_msgs/msg/PointCloud2"](
            header=robot._header(3.0, "map"), height=1, width=1,
            fields=[T["sensor_msgs/msg/PointField"](name=c, offset=4 * i, datatype=7, count=1)
                    for i, c in enumerate("xy")],
            is_bigendian=False, point_step=8, row_step=8, data=np.zeros(8, dtype=np.uint8), is_dense=True)
        for _ in range(2):
            robot._put("points", flat, "sensor_msgs/msg/PointCloud2")
        robot.publish_scan(1.0, 18.0, 20.0)  # before any odometry: no pose
        robot.publish_odometry(2.0, 21.0, 20.0)
        robot.publish_scan(2.0, 21.0, 20.0)
        robot.publish_scan(4.0, 23.0, 20.0)  # newer than the odometry so far: waits
        deadline = time.monotonic() + 10
        while body.maps.newest < 4.0 and time.monotonic() < deadline:
            time.sleep(0.01)
            body.maps.pull()
        _arrived(body.odom, 2.0)  # paced: a stage counts what has arrived
        body.advance_to(2.0)
        x2 = body.sense("a")
        robot.publish_odometry(4.0, 23.0, 20.0)
        thread = _odometry_until(robot, stop, 4.0, 23.0, 20.0)
        _arrived(body.odom, 4.0)
        body.advance_to(4.0)
        x4 = body.sense("a")
        stop.set()
        thread.join(2)
        node.close()
    finally:
        stop.set()
        robot.close()
        session.close()
    import octomap

    def expected(scans, point):  # OctoMap's own tree of these scans, read as the import reads a file
        tree = octomap.OcTree(VOXEL)
        for _, pts, origin in scans:
            tree.insertPointCloud(pts, origin, maxrange=-1.0)
        tree.updateInnerOccupancy()
        path = tmp_path / f"m{len(scans)}.bt"
        tree.writeBinary(str(path).encode())
        return _value3d([(0.0, read_octomap(path))], 0.0, point, tiny.sensing_radius)

    assert x2 == expected(robot.scans[1:2], (21.0, 20.0, ROBOT_Z)) > 0
    assert x4 == expected(robot.scans[1:3], (23.0, 20.0, ROBOT_Z)) > 0
    ignored = [ln for ln in lines if "scan ignored" in ln]
    assert len(ignored) == 2, lines
    assert "a PointCloud2 with float x, y and z fields" in ignored[0] and "/robot7/points (stamp 3.000 s)" in ignored[0]
    assert "has no pose" in ignored[1], ignored
