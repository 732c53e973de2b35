"""The launcher: the fleet's command line (``python run_fleet.py``, ``python -m launcher``,
``marsupial-fleet run``), the validation that turns it into settings, one ``main`` per process
role, and the one-host supervisor. Its constants are defined here, where reading them loads
nothing else (the flags' help texts use them)."""

#: The name the launcher's messages start with (``run_fleet.py: ...``), whichever entry point
#: started it; ``marsupial-fleet run`` passes its own.
NAME = "run_fleet.py"
#: What a ROS 2 robot's carrier observes (``--robot-sensing``; ``ros2.robot.SENSING``, written
#: out here so that parsing the flags imports nothing of ros2/; tests/test_ros2_fleet.py).
ROBOT_SENSING = ("features", "frontier", "frontier3d")
#: How long the launcher waits for carriers after the coordinator exits (s).
CARRIER_EXIT_GRACE_S = 15.0
#: Zenoh sessions one node accepts reliably: beyond a few hundred a peer or router refused
#: sessions (docs/performance.md, "Fleet scale"), so the one-host launcher puts larger fleets
#: behind routers of at most this many carriers each.
CARRIERS_PER_ROUTER = 256
#: Up to this many carriers the launcher starts one process per carrier; beyond, this many
#: processes (``--carrier-processes`` overrides it).
AUTO_CARRIER_PROCESSES = 16
#: CPU priority (``nice`` increment) of the one-host launcher's carrier processes. On one
#: machine the carriers' physics competes for the CPU with the fleet's network (routers) and the
#: coordinator; robots would bring their own CPUs, so the simulated ones yield it: the routers
#: forward a stage's Confirms and the coordinator stamps them while the carriers simulate.
CARRIER_NICE = 5
#: Roles whose process ends with ``os._exit`` once its ``main`` returned (launcher.main): the
#: fleet's processes, and the one-host supervisor (``all``), whose children are stopped by then,
#: so that nothing left in the interpreter's finalisation can keep a stopped fleet's launcher, and
#: the terminal or pipe it holds, alive.
HARD_EXIT_ROLES = ("coordinator", "carrier", "router", "all")
