"""How a carrier's run opens and closes, one function per step, each given what it needs and
returning what it opened: its session (:func:`open_node`), its ROS 2 node (:func:`attach_ros2`:
a robot's body replaces the simulated one), what it says on the session before it joins
(:func:`announce`: subscribed, then its token), and its Bye and the closing of what it opened
(:func:`close`). The carrier (:meth:`carriers.node.Carrier.run`) calls them in that order,
its durable log opened (:func:`open_log`) between its ROS 2 node and its announcement."""
from __future__ import annotations

import threading

from carriers.exits import Exit
from carriers.who import Who
from mission.modes import Mode
from mission.timeouts import DEFAULTS
from storage.carrierlog import CarrierLog, LogMismatch, log_path
from wire import keys
from wire.link_filter import link_filter


def open_node(parts, config, who: Who, position, stop: threading.Event, clock):
    """Its session (``parts.session``, the process's, or one of its own on ``parts.zconf``), its
    links filtered (``position()``: where its body is), arrivals on ``clock``, the clock its
    lifecycle reads. Raises ``wire.zconfig.OpenStopped`` when stopped first. ``parts``:
    :class:`carriers.node.Parts`; ``config``: :class:`carriers.node.CarrierConfig`."""
    from wire.transport import Node

    return Node(parts.zconf, open_timeout_s=config.coordinator_timeout_s, stop=stop, shared=parts.session,
                links=link_filter(who.scenario, who.mission, who.cid, position, config.realtime), clock=clock)


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


def announce(config, node, who: Who, inbound, onboard) -> None:
    """Subscribed to its coordinator's keys, the on-board planner prepared when it may decide
    alone from the start (``onboard``: :class:`carriers.onboard.Onboard`), its peers listened to
    (decentralised: before its token appears, so a carrier that sees the token can reach it),
    then its token declared."""
    inbound.subscribe(node)
    if config.mode == Mode.DECENTRALISED or (config.mode == Mode.HYBRID
                                             and (config.onboard_load or "start") == "start"):
        onboard.prepare()
    if config.mode == Mode.DECENTRALISED:
        inbound.listen(node, wait=True)
    node.token(keys.carrier_alive(who.mission, who.cid))


def close(config, node, who: Who, machine, answer, reason: str, ros2, store: CarrierLog | None) -> None:
    """Its Bye (its deployments in ``machine``, the handshake machine, what ``node`` rejected,
    its exit ``reason``) when it said Hello (``answer``: :class:`mission.carrier.HelloAnswer`),
    then its ROS 2 node, its session and its durable log closed."""
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
