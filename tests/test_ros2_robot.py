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


def _fly(scenario, robot_id, out, acknowledge=True, ack_timeout_s=10.0):
    fleet = InProcessFleet(scenario, out)
    fleet.start_coordinator()
    robot = SimulatedRobot(scenario, robot_id, fleet.endpoint, "/robot1", DOMAIN, acknowledge=acknowledge)
    stop = threading.Event()
    thread = threading.Thread(target=robot.run, args=(stop,), daemon=True)
    thread.start()
    try:
        for cid in scenario.carrier_ids:
            if cid == robot_id:
                fleet.start_carrier(cid, ros2=Ros2Settings(domain=DOMAIN, robot=True, namespace="/robot1",
                                                           ack_timeout_s=ack_timeout_s))
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

    assert isinstance(fleet.carriers[robot_id].sim, RobotBody)  # its body was the robot, not the physics
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
