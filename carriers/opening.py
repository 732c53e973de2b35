"""How a carrier's run opens and closes, one function per step, each given what it needs and
returning what it opened: its simulated body (:func:`simulated_body`), its session
(:func:`open_node`), its ROS 2 node (:func:`attach_ros2`: a robot's body replaces the simulated
one), what it says on the session before it joins (:func:`announce`: subscribed, then its
token), and its Bye and the closing of what it opened (:func:`close`). The carrier
(:meth:`carriers.node.Carrier.run`) calls them in that order, its durable log opened
(:func:`open_log`) between its ROS 2 node and its announcement (:func:`begin`: the three)."""
from __future__ import annotations

import threading

import world
from carriers.crew import Crew
from carriers.exits import Exit
from carriers.who import Who
from mission.modes import Mode
from mission.timeouts import DEFAULTS
from storage.carrierlog import CarrierLog, LogMismatch, log_path
from wire import keys
from wire.link_filter import link_filter


def simulated_body(who: Who, parts) -> world.Simulation:
    """Its body: a ``world.Simulation`` of carrier ``who`` alone, with the features its process's
    carriers share (``parts.shared``, None: the scenario's own)."""
    return world.Simulation(who.scenario, carriers=[who.cid],
                            features=None if parts.shared is None else parts.shared.features)


def open_node(parts, config, who: Who, position, stop: threading.Event, clock):
    """Its session (``parts.session``, the process's, or one of its own on ``parts.zconf``), its
    links filtered (``position()``: where its body is), arrivals on ``clock``, the clock its
    lifecycle reads; None when stopped first. ``parts``: :class:`carriers.node.Parts`;
    ``config``: :class:`carriers.node.CarrierConfig`."""
    from wire.transport import Node
    from wire.zconfig import OpenStopped

    try:
        return Node(parts.zconf, open_timeout_s=config.coordinator_timeout_s, stop=stop, shared=parts.session,
                    links=link_filter(who.scenario, who.mission, who.cid, position, config.realtime), clock=clock)
    except OpenStopped:
        return None


def attach_ros2(config, node, who: Who, motion, stop: threading.Event, log):
    """Its ROS 2 node (None without ``config.ros2``: nothing of ros2/ is imported); a robot's
    body replaces the simulated one in ``motion``."""
    if config.ros2 is None:
        return None
    ros2 = config.ros2.attach(node.session, who.scenario, who.cid, config.realtime, stop, log)
    if ros2.robot is not None:
        motion.body = ros2.robot
    return ros2


def open_log(config, who: Who, log) -> CarrierLog | None:
    """The durable log of carrier ``who`` (``<out_dir>/carriers/<id>.db``; None: no ``out_dir``);
    one of another mission there ends the run (``log-mismatch``)."""
    if config.out_dir is None:
        return None
    meta = {"mission": who.mission, "carrier": who.cid, "scenario": who.scenario.name,
            "fingerprint": who.fingerprint, "seed": int(who.scenario.seed)}
    try:
        return CarrierLog(log_path(config.out_dir, who.cid), meta, sync=config.log_sync)
    except LogMismatch as exc:
        log(str(exc))
        raise Exit("log-mismatch")


def begin(config, node, crew: Crew, stop: threading.Event, log) -> None:
    """What it opens on its session before it joins: its ROS 2 node (:func:`attach_ros2`) and its
    durable log (:func:`open_log`), each held by its hands (``crew.effects``) as soon as it is
    open, so that :func:`close` closes what opened whatever fails next; then its announcement
    (:func:`announce`)."""
    crew.effects.ros2 = attach_ros2(config, node, crew.who, crew.motion, stop, log)
    crew.effects.store = open_log(config, crew.who, log)
    announce(config, node, crew)


def announce(config, node, crew: Crew) -> None:
    """Subscribed to its coordinator's keys (``crew.inbound``), the on-board planner prepared when
    it may decide alone from the start (``crew.alone.onboard``: :class:`carriers.onboard.Onboard`),
    its peers listened to (decentralised: before its token appears, so a carrier that sees the
    token can reach it), then its token declared."""
    who, inbound, onboard = crew.who, crew.inbound, crew.alone.onboard
    inbound.subscribe(node)
    if config.mode == Mode.DECENTRALISED or (config.mode == Mode.HYBRID
                                             and (config.onboard_load or "start") == "start"):
        onboard.prepare()
    if config.mode == Mode.DECENTRALISED:
        inbound.listen(node, wait=True)
    node.token(keys.carrier_alive(who.mission, who.cid))


def close(config, node, crew: Crew, machine, reason: str) -> None:
    """Its Bye (its deployments in ``machine``, the handshake machine, what ``node`` rejected,
    its exit ``reason``) when it said Hello (``crew.inbound.answer``:
    :class:`mission.carrier.HelloAnswer`), then its ROS 2 node, its session and its durable log
    closed (``crew.effects``: they are held there while it runs)."""
    who, answer, ros2, store = crew.who, crew.inbound.answer, crew.effects.ros2, crew.effects.store
    try:
        if answer.said_hello or config.mode == Mode.DECENTRALISED:  # a Bye needs a Hello
            node.put(*who.bye(machine.deployments(), tuple(sorted(node.rejected.items())), reason))
    except Exception:
        pass
    if ros2 is not None:
        ros2.close()
    node.close(DEFAULTS.close_s)
    if store is not None:
        store.close()
