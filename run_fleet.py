"""Run a marsupial fleet mission: one coordinator and one process per carrier, talking over Zenoh.

    python run_fleet.py scenarios/six_carriers.yaml                 # everything on this host
    python run_fleet.py S.yaml --role coordinator --listen tcp/0.0.0.0:7447 --out runs/m1
    python run_fleet.py S.yaml --role carrier --carrier a --connect tcp/HOST:7447
    python run_fleet.py S.yaml --role carrier --carrier a,b,c --connect tcp/HOST:7447
    python run_fleet.py --role router --listen tcp/0.0.0.0:7447
    python run_fleet.py S.yaml --carrier-processes 8                 # R carriers in 8 processes
    python run_fleet.py S.yaml --decentralised                       # no coordinator at all
    python run_fleet.py S.yaml --role report --out runs/m1          # results from whatever logs exist

With no --role, this script starts a zenoh router (listening on tcp/127.0.0.1:<free port>: the
fleet's network, which outlives any one process), the coordinator and the carrier processes
(fresh interpreters running this script with --role carrier; by default one per carrier up to 16
carriers, else 16 processes; each carrier keeps its own Zenoh session and liveliness token,
whatever process it runs in), shows a line per stage, and leaves summary.json, mission.db,
map.png and the carriers' logs (carriers/<id>.db) in --out (default runs/<scenario>-<timestamp>).
Carriers decide on board when the coordinator is gone (hybrid, the default). See docs/fleet.md
and docs/protocol.md.
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

from mission.exits import STOPPED  # noqa: E402  (after the path set-up: run as a script)

#: Exit code for bad user input (scenario, flags, config files), and for a process that refuses
#: to start because its role and id are taken (a live coordinator of the mission without
#: --standby, a live carrier of the same id): docs/fleet.md, "Split brain".
EXIT_USAGE = 2
#: Exit code of a coordinator deposed by a coordinator of a higher epoch (it stopped deciding and
#: published no End).
EXIT_DEPOSED = 3
#: What a ROS 2 robot's carrier observes (``--robot-sensing``; ``ros2.robot.SENSING``, written
#: out here so that parsing the flags imports nothing of ros2/; tests/test_ros2_fleet.py).
ROBOT_SENSING = ("features", "frontier")
#: How long the launcher waits for carriers after the coordinator exits (s).
CARRIER_EXIT_GRACE_S = 15.0
#: Zenoh sessions one node accepts reliably here: a peer or router of zenoh 1.10 refused every
#: session beyond about 350 on this project's machines (docs/performance.md, "Fleet scale"), so
#: the one-host launcher puts larger fleets behind routers of at most this many carriers each.
CARRIERS_PER_ROUTER = 256
#: Up to this many carriers the launcher starts one process per carrier; beyond, this many
#: processes (``--carrier-processes`` overrides it).
AUTO_CARRIER_PROCESSES = 16
#: CPU priority (``nice`` increment) of the one-host launcher's carrier processes. On one
#: machine the carriers' physics competes for the CPU with the fleet's network (routers) and the
#: coordinator; robots would bring their own CPUs, so the simulated ones yield it: the routers
#: forward a stage's Confirms and the coordinator stamps them while the carriers simulate.
CARRIER_NICE = 5


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="run_fleet.py", description="Run a marsupial fleet mission over Zenoh.",
        formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__.split("\n\n", 2)[1])
    # The order of the calls is the order of --help (the main group's flags, then the groups).
    _role_flags(p)
    _mission_flags(p)
    _zenoh_flags(p)
    _view_flags(p)
    _onboard_flags(p, _timeout_flags(p))
    _output_flags(p)
    _ros2_flags(p)
    _carrier_output_flags(p)
    return p.parse_args(argv)


def _role_flags(p: argparse.ArgumentParser) -> None:
    """What this process runs: the role, its carriers, how the one-host fleet is laid out."""
    p.add_argument("scenario", nargs="?", help="scenario YAML file (not needed with --role router)")
    p.add_argument("--role", choices=("all", "coordinator", "carrier", "viewer", "router", "report"), default="all",
                   help="all (default): the whole fleet on this host; or one process's role "
                        "(viewer: a passive live view, needs rerun-sdk; router: a zenoh router that "
                        "coordinators and carriers connect to; report: summary.json, map.png and "
                        "merged_log.jsonl from the logs in --out, run after every one-host mission)")
    p.add_argument("--carrier", metavar="ID[,ID...]",
                   help="carrier id(s) (with --role carrier); several ids run in one process, "
                        "each with its own Zenoh session")
    p.add_argument("--carrier-processes", type=int, metavar="K",
                   help=f"one-host mode: run the carriers in K OS processes (default: one per carrier up to "
                        f"{AUTO_CARRIER_PROCESSES} carriers, else {AUTO_CARRIER_PROCESSES})")
    p.add_argument("--decentralised", action="store_true",
                   help="no coordinator: every carrier decides its stages on board, with the others "
                        "it can reach (one-host mode starts no coordinator; with --role carrier: this carrier)")
    p.add_argument("--no-autonomy", action="store_true",
                   help="carriers never decide on their own: they hold while the coordinator is away and "
                        "exit after --coordinator-timeout")
    p.add_argument("--routers", type=int, metavar="N",
                   help=f"one-host mode: start N zenoh routers connected to the coordinator and spread the "
                        f"carrier processes over them (default: none up to {CARRIERS_PER_ROUTER} carriers, else "
                        f"one per {CARRIERS_PER_ROUTER} carriers)")


def _mission_flags(p: argparse.ArgumentParser) -> None:
    """The planner, the seed, the clock, the mission id and where its results go."""
    from mission.timeouts import CLOCKS

    p.add_argument("--planner", help="planner name (overrides the scenario)")
    p.add_argument("--iterations", type=int, help="MCTS iterations per stage (overrides the scenario)")
    p.add_argument("--plan-ms", type=float, help="MCTS time budget per stage, ms (overrides the scenario)")
    p.add_argument("--planner-option", action="append", default=[], metavar="KEY=VALUE",
                   help="any planner option of planner.registry (e.g. layout=binary, exploration=0.1); repeatable")
    p.add_argument("--seed", type=int, help="root seed (overrides the scenario; every process needs the same)")
    p.add_argument("--realtime", type=float, default=0.0, metavar="FACTOR",
                   help="simulated seconds per wall second; 0 = as fast as possible (default)")
    p.add_argument("--clock", choices=CLOCKS, default="sim",
                   help="sim (default): a simulated mission, whatever its --realtime pace: a live carrier or "
                        "coordinator that is slow is waited for, only a failure (its token gone, or nothing from "
                        "it for --silence-timeout) ends a wait, so the mission's decisions do not depend on the "
                        "host's load; wall: a real-time mission (robots): --stage-timeout, --decision-timeout and "
                        "--peer-timeout are deadlines and a late observation is ∅")
    p.add_argument("--mission", help="mission id, the key-expression prefix (default: the scenario name)")
    p.add_argument("--out", metavar="DIR", help="results directory (default runs/<scenario>-<timestamp>)")
    p.add_argument("--standby", action="store_true",
                   help="coordinator: if the mission already has a live coordinator, wait and take over when "
                        "its liveliness token vanishes (without it: refuse to start, exit 2)")


def _zenoh_flags(p: argparse.ArgumentParser) -> None:
    z = p.add_argument_group("zenoh (flags override keys of --zenoh-config)")
    z.add_argument("-l", "--listen", action="append", default=[], metavar="ENDPOINT",
                   help="endpoint to listen on, e.g. tcp/0.0.0.0:7447 (repeatable)")
    z.add_argument("-e", "--connect", action="append", default=[], metavar="ENDPOINT",
                   help="endpoint to connect to, e.g. tcp/192.168.1.10:7447 (repeatable)")
    z.add_argument("-c", "--zenoh-config", metavar="FILE", help="zenoh JSON5 config file")
    z.add_argument("-m", "--mode", choices=("peer", "client", "router"),
                   help="zenoh mode (default: peer for the coordinator, client for carriers)")


def _view_flags(p: argparse.ArgumentParser) -> None:
    from viewer import DEFAULT_GRPC_PORT, DEFAULT_WEB_PORT

    v = p.add_argument_group("live view (pip install -e '.[view]'; docs/fleet.md, \"Seeing a mission\")")
    v.add_argument("--view", action="store_true",
                   help="one-host mode: also start a viewer and print the address of its web view")
    v.add_argument("--web-port", type=int, default=DEFAULT_WEB_PORT, help="viewer: web viewer port on 127.0.0.1 (default %(default)s)")
    v.add_argument("--grpc-port", type=int, default=DEFAULT_GRPC_PORT,
                   help="viewer: rerun gRPC server port on 127.0.0.1 (default %(default)s)")
    v.add_argument("--save", metavar="FILE.rrd", help="viewer: also write the stream to this rerun file")
    v.add_argument("--no-web", action="store_true", help="viewer: no web viewer (with --save: only the file)")
    v.add_argument("--linger", type=float, default=-1.0, metavar="SECONDS",
                   help="viewer: keep serving this long after the mission ends; < 0 = until Ctrl-C (default)")
    v.add_argument("--ready-file", help=argparse.SUPPRESS)  # one-host mode: the viewer is subscribed


def _timeout_flags(p: argparse.ArgumentParser):
    from mission.timeouts import DEFAULTS

    t = p.add_argument_group("timeouts (seconds)")
    t.add_argument("--join-timeout", type=float, default=DEFAULTS.join_s,
                   help="coordinator: wait for carriers before stage 0 (default %(default)s)")
    t.add_argument("--stage-timeout", type=float, default=DEFAULTS.stage_s,
                   help="coordinator, --clock wall: wait per stage for observations, and after the last decision "
                        "(at least 3 s) for its Confirms (default %(default)s)")
    t.add_argument("--decision-timeout", type=float, default=DEFAULTS.decision_s,
                   help="carrier: --clock wall: wait per stage for the decision, then decide it on board; "
                        "--clock sim: ask the coordinator's State again after this long (default %(default)s)")
    t.add_argument("--silence-timeout", type=float, default=DEFAULTS.silence_s,
                   help="--clock sim: a carrier waited for that sent nothing, not even Progress, for this long "
                        "is taken as stalled (default %(default)s)")
    t.add_argument("--coordinator-timeout", type=float, default=DEFAULTS.coordinator_s,
                   help="carrier: at the start, wait this long for a coordinator (then go on without it); "
                        "with --no-autonomy, exit when it has been absent this long (default %(default)s)")
    return t


def _onboard_flags(p: argparse.ArgumentParser, t) -> None:
    """A carrier's on-board planner, its durable log, and its wait for peers deciding on board
    (``t``: the timeouts group)."""
    from carriers import ONBOARD_LOADS
    from mission.timeouts import DEFAULTS
    from storage.carrierlog import SYNC_MODES

    p.add_argument("--onboard-load", choices=ONBOARD_LOADS,
                   help="carrier: when the on-board planner is loaded: at the start, or when it may be needed "
                        "(the coordinator's token gone, no decision by --decision-timeout); default start for a "
                        "process of one carrier, need for a process of several")
    p.add_argument("--log-sync", choices=SYNC_MODES,
                   help="carrier: how its durable log commits: full survives a power loss of its host, normal "
                        "only a crash of the process (default full with --role carrier, normal for the one-host "
                        "launcher's carriers: a power loss takes the whole fleet there)")
    t.add_argument("--peer-timeout", type=float, default=DEFAULTS.peer_s,
                   help="carrier deciding on board, --clock wall: wait per stage for the other carriers' "
                        "observations (default %(default)s)")


def _output_flags(p: argparse.ArgumentParser) -> None:
    """The coordinator's map and recording."""
    from recording import PROFILES

    p.add_argument("--no-map", action="store_true", help="do not draw map.png")
    p.add_argument("--no-record", action="store_true", help="coordinator: do not write mission.mcap")
    p.add_argument("--mcap-profile", choices=PROFILES, default=PROFILES[0],
                   help="coordinator: the recording's profile: foxglove (default: mission.mcap with Foxglove's "
                        "schemas) or ros2 (the rosbag2 bag ros2bag/ that ros2 bag play replays; needs .[ros2])")


def _ros2_flags(p: argparse.ArgumentParser) -> None:
    r = p.add_argument_group("ROS 2 over Zenoh, rmw_zenoh's format, Jazzy and later (docs/fleet.md, \"ROS 2\")")
    r.add_argument("--ros2", action="store_true",
                   help="publish the mission as ROS 2 topics in rmw_zenoh's key space (every role; nothing "
                        "changes in the mission protocol)")
    r.add_argument("--ros2-domain", type=int, metavar="N",
                   help="ROS domain id of those topics (default: ROS_DOMAIN_ID, else 0)")
    r.add_argument("--ros2-robot", action="store_true",
                   help="carrier (one id, with --role carrier): the body is a real ROS 2 robot: pose from its "
                        "NS/odom, observations from NS/features, deployments commanded on NS/deploy")
    r.add_argument("--ros2-namespace", metavar="NS", help="with --ros2-robot: the robot's ROS 2 namespace (default /)")
    r.add_argument("--robot-sensing", choices=ROBOT_SENSING,
                   help="with --ros2-robot: what a stage's observation is: features (default: the number of "
                        "poses in NS/features) or frontier (the frontier cells of the robot's NS/map within the "
                        "scenario's sensing radius, the importer's --replay value)")


def _carrier_output_flags(p: argparse.ArgumentParser) -> None:
    """What the carriers publish and print."""
    from mission.timeouts import POSE_INTERVAL_S, POSES_PER_STAGE

    p.add_argument("--pose-interval", type=float, default=None, metavar="SECONDS",
                   help=f"carrier: publish a Pose every this many simulated seconds (whole seconds; 0 = never; "
                        f"default {POSE_INTERVAL_S:g}, or with --realtime 0 the whole seconds that keep a carrier "
                        f"within {POSES_PER_STAGE} Poses a stage)")
    p.add_argument("--quiet", action="store_true", help="carriers print nothing but errors")
    p.add_argument("--verbose", action="store_true",
                   help="one-host mode: let carriers print their own events (quiet by default)")


def fail(message: str) -> int:
    print(f"run_fleet.py: {message}", file=sys.stderr)
    return EXIT_USAGE


def load(args):
    """The scenario, or None after printing the world's one-line errors."""
    import world

    try:
        return world.load_scenario(args.scenario)
    except world.ScenarioError as exc:
        for line in exc.problems:
            print(line, file=sys.stderr)
        return None
    except OSError as exc:
        print(f"{args.scenario}: cannot read the scenario: {exc.strerror or exc}", file=sys.stderr)
        return None


def check_flags(args, scenario) -> str | None:
    """One line about the first bad flag, or None."""
    from wire import keys

    if args.realtime < 0:
        return f"--realtime: expected a factor >= 0, found {args.realtime}"
    from planner.registry import OPTIONS, parse_option

    for flag, key in (("--iterations", "iterations"), ("--plan-ms", "plan_ms")):
        value = getattr(args, key)
        try:
            value is None or OPTIONS[key].check(value)
        except ValueError as exc:
            return f"{flag}: expected {exc}, found {value}"
    try:
        args.planner_options = tuple(parse_option(text) for text in args.planner_option)
    except ValueError as exc:
        return f"--planner-option: {exc}"
    if args.pose_interval is not None and args.pose_interval < 0:
        return f"--pose-interval: expected seconds >= 0, found {args.pose_interval}"
    if args.seed is not None and args.seed < 0:
        return f"--seed: expected an integer >= 0, found {args.seed}"
    if args.decentralised and args.no_autonomy:
        return "--decentralised and --no-autonomy exclude each other"
    if args.decentralised and args.role == "coordinator":
        return "--decentralised runs no coordinator"
    for name in ("join_timeout", "stage_timeout", "decision_timeout", "coordinator_timeout", "peer_timeout",
                 "silence_timeout"):
        if getattr(args, name) <= 0:
            return f"--{name.replace('_', '-')}: expected seconds > 0, found {getattr(args, name)}"
    for k, cid in enumerate(scenario.carrier_ids):
        if not keys.ID_PATTERN.match(cid):
            return (f"{args.scenario}: carriers[{k}].id: expected an id usable in key expressions "
                    f"({keys.ID_PATTERN.pattern}), found {cid!r}")
    if args.mission is None and not keys.ID_PATTERN.match(keys.mission_id_from_name(scenario.name)):
        return f"{args.scenario}: name: cannot derive a mission id from {scenario.name!r}; pass --mission"
    if args.mission is not None:
        try:
            keys.check_id(args.mission, "--mission")
        except ValueError as exc:
            return str(exc)
    if (args.role == "viewer" or args.view) and args.no_web and not args.save:
        return "--no-web needs --save FILE.rrd (else the viewer shows nothing)"
    if args.role == "viewer" or args.view:
        try:
            import rerun  # noqa: F401
        except ImportError:
            return "the live view needs rerun-sdk: pip install -e '.[view]'"
    if args.routers is not None and args.routers < 0:
        return f"--routers: expected an integer >= 0, found {args.routers}"
    if args.carrier_processes is not None and args.carrier_processes < 1:
        return f"--carrier-processes: expected an integer >= 1, found {args.carrier_processes}"
    if args.standby and args.role != "coordinator":
        return "--standby: only with --role coordinator"
    if args.role == "carrier":
        if not args.carrier:
            return "--role carrier needs --carrier ID (or ID,ID,...)"
        args.carriers = [c.strip() for c in args.carrier.split(",")]
        known = set(scenario.carrier_ids)
        for cid in args.carriers:
            if cid not in known:
                listed = ", ".join(scenario.carrier_ids[:20]) + (", ..." if len(known) > 20 else "")
                return f"--carrier: expected one of {listed} (carriers of {args.scenario}), found {cid!r}"
        if len(set(args.carriers)) != len(args.carriers):
            return f"--carrier: a carrier id is repeated in {args.carrier!r}"
    problem = _check_ros2(args)
    if problem:
        return problem
    if args.role == "report" and not args.out:
        return "--role report needs --out DIR (the results directory to read)"
    if args.role not in ("carrier", "viewer", "router", "report") and not args.decentralised:
        from planner.registry import make_planner, planner_settings

        name, options = planner_settings(scenario, args.planner, args.iterations, args.plan_ms, args.planner_options)
        try:
            make_planner(name, **options)
        except ValueError as exc:
            return f"--planner: {exc}"
    return None


def _check_ros2(args) -> str | None:
    """The ROS 2 flags: one line about the first bad one, or None; fills in ``args.ros2_domain``."""
    ros2 = args.ros2 or args.ros2_robot
    if (not ros2 and args.ros2_domain is None and args.ros2_namespace is None and args.robot_sensing is None
            and args.mcap_profile == "foxglove"):
        return None
    from ros2.publisher import check_domain, check_namespace, default_domain

    if args.ros2_domain is None:
        text = os.environ.get("ROS_DOMAIN_ID", "").strip()
        if text and not text.isdigit():
            return f"ROS_DOMAIN_ID: expected an integer 0..232, found {text!r}"
        args.ros2_domain = default_domain()
    problem = check_domain(args.ros2_domain)
    if problem:
        return problem
    if args.ros2_robot and (args.role != "carrier" or len(getattr(args, "carriers", [])) != 1):
        return "--ros2-robot: only with --role carrier and one --carrier ID (the robot's carrier)"
    if args.ros2_namespace is not None:
        if not args.ros2_robot:
            return "--ros2-namespace: only with --ros2-robot (the robot's namespace)"
        problem = check_namespace(args.ros2_namespace)
        if problem:
            return problem
    if args.robot_sensing is not None and not args.ros2_robot:
        return "--robot-sensing: only with --ros2-robot (what the robot's carrier observes)"
    if args.mcap_profile == "ros2" and args.role in ("all", "coordinator"):
        try:
            import rosbags  # noqa: F401
        except ImportError:
            return "--mcap-profile ros2 needs rosbags: pip install -e '.[ros2]'"
    return None


def _ros2_settings(args):
    """The processes' ROS 2 settings (ros2/publisher.py), or None: with neither --ros2 nor
    --ros2-robot nothing of ros2/ is imported."""
    if not (args.ros2 or args.ros2_robot):
        return None
    from ros2.publisher import Ros2Settings

    return Ros2Settings(domain=args.ros2_domain, robot=args.ros2_robot, namespace=args.ros2_namespace or "/",
                        sensing=args.robot_sensing or ROBOT_SENSING[0])


def zenoh_config(args, role: str):
    from wire.zconfig import DEFAULT_PORT, file_listens, file_sets_mode, make_config

    listen, connect = list(args.listen), list(args.connect)
    if not args.zenoh_config:
        if role in ("coordinator", "router") and not listen and not connect:
            listen = [f"tcp/127.0.0.1:{DEFAULT_PORT}"]
        if role in ("carrier", "viewer") and not connect:
            connect = [f"tcp/127.0.0.1:{DEFAULT_PORT}"]
    mode = args.mode
    if mode is None and not file_sets_mode(args.zenoh_config):
        if role == "router":
            mode = "router"
        elif role == "coordinator" and (listen or file_listens(args.zenoh_config)):
            mode = "peer"  # it is the carriers' rendezvous
        else:
            mode = "client"  # a carrier, or a coordinator that only connects (to a router)
    return make_config(mode, listen, connect, args.zenoh_config)


def install_stop_handlers() -> threading.Event:
    """SIGINT (Ctrl-C) and SIGTERM only set the returned stop request; the process's loop
    honours it between steps (a store write or a message is never cut in half) and shuts down
    cleanly (End/Bye, summary.json). Later signals change nothing. Installed explicitly because
    a process started in the background inherits SIGINT ignored."""
    stop = threading.Event()

    def handler(signum, frame):
        stop.set()

    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)
    return stop


def _ignore_sigint() -> None:
    """In a child before it runs Python: SIGINT ignored until the child's own
    :func:`install_stop_handlers` (Python keeps an inherited ignored SIGINT instead of raising
    KeyboardInterrupt), so a Ctrl-C during its start-up cannot interrupt it half-way; the
    launcher forwards the stop again once the children are up (:func:`_stop_children`)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _carrier_child() -> None:
    """In a carrier process of a one-host fleet: :func:`_ignore_sigint`, and a lower CPU priority
    (:data:`CARRIER_NICE`) than the coordinator and the routers."""
    _ignore_sigint()
    os.nice(CARRIER_NICE)


def run_coordinator(args, scenario, stop: threading.Event) -> int:
    from coordinator.epochs import DuplicateCoordinator
    from coordinator.node import Coordinator, CoordinatorConfig
    from storage.missiondb import StoreBusy, StoreMismatch
    from mission.timeouts import DEFAULTS

    out = args.out or default_out(scenario)
    coord = Coordinator(scenario, CoordinatorConfig(
        out_dir=out, mission=args.mission, planner=args.planner, iterations=args.iterations,
        plan_ms=args.plan_ms, planner_options=getattr(args, "planner_options", ()), seed=args.seed, realtime=args.realtime, join_timeout_s=args.join_timeout,
        clock=args.clock, stage_timeout_s=args.stage_timeout, silence_timeout_s=args.silence_timeout,
        render=not args.no_map, record=not getattr(args, "no_record", False),
        record_profile=args.mcap_profile, ros2=_ros2_settings(args),
        # Wall clock: the last stage's Confirms take a round trip, which grows with the fleet's
        # load like the observations' arrival the stage timeout bounds (R = 1,024 on 2 cores: up
        # to 26 s). The sim clock waits for them as for observations.
        confirm_timeout_s=max(DEFAULTS.confirm_s, args.stage_timeout),
        standby=getattr(args, "standby", False)),
        zenoh_config(args, "coordinator"),
        scenario_path=args.scenario, stop=stop)
    try:
        summary = coord.run()
    except (StoreMismatch, DuplicateCoordinator) as exc:
        return fail(str(exc))
    except StoreBusy as exc:  # stopped while waiting for another process's lock
        print(f"run_fleet.py: {exc}; stopped while waiting for it", file=sys.stderr, flush=True)
        return STOPPED
    if summary.get("deposed_by") is not None:
        return EXIT_DEPOSED
    return 0 if summary.get("ended") and summary["stages_decided"] == summary["stages"] else STOPPED


def run_carrier(args, scenario, stop: threading.Event) -> int:
    """One or several carriers (``--carrier a,b,c``) in this process: one thread and one Zenoh
    session per carrier, the scenario loaded once. Exit code: the first non-zero carrier code."""
    from carriers.node import EXIT_CODES, CarrierConfig
    from carriers.process import DuplicateCarriers, run_carriers
    from mission.timeouts import pose_interval
    from planner.registry import planner_settings
    from wire.zconfig import ConfigError

    log = (lambda line: None) if args.quiet else (lambda line: print(line, flush=True))
    mode = "decentralised" if args.decentralised else "coordinated" if args.no_autonomy else "hybrid"
    _, options = planner_settings(scenario, None, args.iterations, args.plan_ms, args.planner_options)
    out = args.out or default_out(scenario)  # its log: pass the same --out again to resume from it
    configs = [CarrierConfig(
        carrier=cid, mission=args.mission, seed=args.seed, realtime=args.realtime, clock=args.clock,
        silence_timeout_s=args.silence_timeout, decision_timeout_s=args.decision_timeout, coordinator_timeout_s=args.coordinator_timeout,
        log=log, pose_interval_s=pose_interval(scenario.stage_interval, args.realtime)
        if args.pose_interval is None else args.pose_interval, mode=mode, out_dir=out, peer_timeout_s=args.peer_timeout,
        join_timeout_s=args.join_timeout, planner_options=tuple(sorted(options.items())),
        log_sync=args.log_sync or "full", onboard_load=args.onboard_load, ros2=_ros2_settings(args))
        for cid in getattr(args, "carriers", [args.carrier])]
    try:
        reasons = run_carriers(scenario, configs, lambda: zenoh_config(args, "carrier"), stop=stop)
    except DuplicateCarriers as exc:
        return fail(str(exc))
    except ConfigError as exc:  # nobody to connect to
        print(f"run_fleet.py: {exc}", file=sys.stderr, flush=True)
        return EXIT_CODES["coordinator-lost"]
    codes = []
    for cid, reason in reasons.items():
        if reason not in ("end", "finished"):
            print(f"carrier {cid}: exiting ({reason})", file=sys.stderr, flush=True)
        codes.append(EXIT_CODES.get(reason, 1))
    return next((c for c in codes if c != 0), 0)


def run_router(args, stop: threading.Event) -> int:
    """A zenoh router (mode ``router``) for fleets across hosts: coordinators and carriers of any
    number of missions connect to it as clients; missions stay apart by their key prefix
    ``marsupial/<mission>/``. Runs until SIGINT/SIGTERM."""
    from wire.zconfig import close_session, open_session

    conf = zenoh_config(args, "router")
    session = open_session(conf, 10.0, stop=stop)
    where = ", ".join(args.listen) or "the config's endpoints"
    print(f"run_fleet.py: zenoh router pid {os.getpid()} listening on {where}", flush=True)
    try:
        while not stop.wait(0.2):
            pass
    finally:
        close_session(session, (), 3.0)
    return 0


def run_report(args, scenario) -> int:
    """summary.json, merged_log.jsonl and map.png from the logs in ``--out`` (coordinator/report.py):
    one line with the totals and the files; a one-line error and exit 2 when it cannot be made."""
    from coordinator.report import ReportError, run_report as report

    try:
        result = report(scenario, args.out, mission=args.mission, seed=args.seed, scenario_path=args.scenario,
                        render=not args.no_map, log=lambda line: print(f"run_fleet.py: {line}", file=sys.stderr,
                                                                       flush=True))
    except ReportError as exc:
        return fail(str(exc))
    print(result.line(Path(args.out)), flush=True)
    return 0


def run_viewer(args, scenario, stop: threading.Event) -> int:
    from viewer.node import Viewer, ViewerConfig

    viewer = Viewer(scenario, ViewerConfig(
        mission=args.mission, seed=args.seed, web=not args.no_web, web_port=args.web_port, grpc_port=args.grpc_port,
        save=args.save, linger_s=args.linger, open_timeout_s=args.coordinator_timeout,
        ready_file=args.ready_file), zenoh_config(args, "viewer"),
        stop=stop)
    try:
        return viewer.run()
    except RuntimeError as exc:  # the rerun server could not start (a port in use, no binary)
        print(f"viewer: {exc}", file=sys.stderr, flush=True)
        return 1


def default_out(scenario) -> str:
    from wire import keys

    return str(Path("runs") / f"{keys.mission_id_from_name(scenario.name)}-{time.strftime('%Y%m%d-%H%M%S')}")


def _forward(args) -> list[str]:
    """Flags every child gets from the launcher's own command line."""
    out = []
    for flag, value in (("--planner", args.planner), ("--iterations", args.iterations),
                        ("--plan-ms", args.plan_ms), ("--seed", args.seed), ("--mission", args.mission),
                        ("--zenoh-config", args.zenoh_config), ("--onboard-load", args.onboard_load),
                        ("--pose-interval", args.pose_interval)):
        if value is not None:
            out += [flag, str(value)]
    for text in args.planner_option:
        out += ["--planner-option", text]
    out += ["--realtime", str(args.realtime), "--clock", args.clock, "--silence-timeout", str(args.silence_timeout),
            "--join-timeout", str(args.join_timeout),
            "--stage-timeout", str(args.stage_timeout), "--decision-timeout", str(args.decision_timeout),
            "--coordinator-timeout", str(args.coordinator_timeout), "--peer-timeout", str(args.peer_timeout)]
    for flag in ("no_record", "decentralised", "no_autonomy", "ros2"):
        if getattr(args, flag):
            out.append("--" + flag.replace("_", "-"))
    if args.ros2:
        out += ["--ros2-domain", str(args.ros2_domain)]
    if args.mcap_profile != "foxglove":
        out += ["--mcap-profile", args.mcap_profile]
    return out


def carrier_groups(ids, processes: int | None = None) -> list[list[str]]:
    """The carriers of each carrier process: ``processes`` contiguous blocks of ``ids`` (sizes
    differ by at most one); None = one per carrier up to AUTO_CARRIER_PROCESSES carriers, else
    AUTO_CARRIER_PROCESSES blocks."""
    ids = list(ids)
    k = processes if processes is not None else (len(ids) if len(ids) <= AUTO_CARRIER_PROCESSES
                                                 else AUTO_CARRIER_PROCESSES)
    k = max(1, min(k, len(ids)))
    base, extra = divmod(len(ids), k)
    out, start = [], 0
    for g in range(k):
        size = base + (1 if g < extra else 0)
        out.append(ids[start:start + size])
        start += size
    return out


def _short(cids: str) -> str:
    ids = cids.split(",")
    return cids if len(ids) <= 3 else f"{ids[0]}..{ids[-1]} ({len(ids)})"


def _stop_children(procs, grace_s: float = 10.0) -> None:
    """Stop our own children: give them a moment (a terminal's Ctrl-C reached them already), then
    SIGINT once, then SIGKILL after ``grace_s`` seconds."""
    for sig, wait_s in ((None, 1.0), (signal.SIGINT, grace_s), (signal.SIGKILL, 2.0)):
        alive = [p for p in procs if p.poll() is None]
        if not alive:
            return
        if sig is not None:
            for p in alive:
                try:
                    p.send_signal(sig)
                except ProcessLookupError:
                    pass
        deadline = time.monotonic() + wait_s
        while time.monotonic() < deadline and any(p.poll() is None for p in alive):
            time.sleep(0.05)


def taken(args, scenario, connect) -> str | None:
    """Through a router another mission with this id may be live: the one line a process of ours
    would refuse with (a live coordinator, live carriers of our ids), or None. One liveliness
    query over a short-lived session, before the launcher starts anything."""
    from carriers.process import DuplicateCarriers, live_duplicates
    from coordinator.epochs import DuplicateCoordinator
    from mission.timeouts import DEFAULTS
    from wire import keys
    from wire.transport import Node
    from wire.zconfig import make_config

    mission = args.mission or keys.mission_id_from_name(scenario.name)
    conf = lambda: make_config("client", [], connect, args.zenoh_config)  # noqa: E731
    probe = Node(conf(), open_timeout_s=10.0)
    try:
        if probe.live_tokens(keys.coordinator_alive(mission), DEFAULTS.liveliness_check_s):
            return str(DuplicateCoordinator(mission))
    finally:
        probe.close(DEFAULTS.close_s)
    ids = live_duplicates(mission, scenario.carrier_ids, conf, open_timeout_s=10.0)
    return str(DuplicateCarriers(mission, ids)) if ids else None


@dataclass
class _Fleet:
    """The one-host fleet's child processes and the network they share."""

    out: Path
    script: list[str]
    common: list[str]  # the flags every child gets
    listen: list[str]
    connect: list[str]
    routers: list = field(default_factory=list)
    router_endpoints: list[str] = field(default_factory=list)  # the routers beyond the first
    coordinator: subprocess.Popen | None = None
    viewer: subprocess.Popen | None = None
    carriers: dict = field(default_factory=dict)  # "id,id,..." -> its process

    def procs(self) -> list:
        return [p for p in (self.coordinator, *self.carriers.values(), *self.routers, self.viewer) if p is not None]

    def connect_flags(self, endpoints=None) -> list[str]:
        return sum((["--connect", e] for e in (self.connect if endpoints is None else endpoints)), [])

    def others(self) -> list:
        """The carriers, the routers and the viewer: what is left once the coordinator is gone."""
        return [*self.carriers.values(), *self.routers] + ([self.viewer] if self.viewer is not None else [])


def run_all(args, scenario, stop: threading.Event) -> int:
    if stop.is_set():
        return STOPPED
    if args.connect and not args.listen:
        problem = taken(args, scenario, list(args.connect))  # else our carriers would join the live mission
        if problem:
            return fail(problem)
    fleet = _start_network(args, scenario)
    started = time.monotonic()
    if not args.decentralised:
        fleet.coordinator = subprocess.Popen(
            fleet.script + ["--role", "coordinator"] + fleet.common + fleet.connect_flags()
            + (["--no-map"] if args.no_map else []),
            preexec_fn=_ignore_sigint)
    if args.view:  # subscribed before the carriers start, so the view misses nothing
        _start_viewer(args, fleet, stop)
    _start_carriers(args, scenario, fleet)
    _announce(args, fleet)
    _supervise(fleet, stop)
    if stop.is_set():
        print("run_fleet.py: interrupted; stopping the fleet", file=sys.stderr, flush=True)
        _stop_children(fleet.procs())
        return STOPPED
    code = 0 if fleet.coordinator is None else fleet.coordinator.returncode
    if code in (EXIT_USAGE, EXIT_DEPOSED):
        return _without_coordinator(fleet, code, stop)
    return _finish(args, fleet, code, started, stop)


def _start_network(args, scenario) -> _Fleet:
    """The results directory and the fleet's network: a router of the user's (``--connect``
    without ``--listen``: everyone connects to it), else a router of the fleet's own, not the
    coordinator, so that carriers keep talking to each other when the coordinator is gone."""
    from wire.zconfig import free_port

    out = Path(args.out or default_out(scenario))
    out.mkdir(parents=True, exist_ok=True)
    script = [sys.executable, str(Path(__file__).resolve()), args.scenario]
    common = _forward(args) + ["--out", str(out)]
    if args.connect and not args.listen:
        return _Fleet(out, script, common, [], list(args.connect))
    listen = args.listen or [f"tcp/127.0.0.1:{free_port()}"]
    fleet = _Fleet(out, script, common, listen, [e.replace("0.0.0.0", "127.0.0.1") for e in listen])
    fleet.routers.append(_start_router(args, listen, []))
    return fleet


def _start_viewer(args, fleet: _Fleet, stop: threading.Event) -> None:
    """``--view``: the viewer, waited for (at most 60 s) until it is subscribed."""
    ready = fleet.out / ".viewer-ready"
    ready.unlink(missing_ok=True)
    viewer = fleet.viewer = subprocess.Popen(
        fleet.script + ["--role", "viewer", "--web-port", str(args.web_port), "--grpc-port", str(args.grpc_port),
                        "--linger", str(args.linger), "--ready-file", str(ready)] + fleet.common
        + fleet.connect_flags()
        + (["--save", args.save] if args.save else []) + (["--no-web"] if args.no_web else []),
        preexec_fn=_ignore_sigint)
    deadline = time.monotonic() + 60
    while not ready.exists() and viewer.poll() is None and not stop.is_set() and time.monotonic() < deadline:
        stop.wait(0.05)
    ready.unlink(missing_ok=True)
    if viewer.poll() is not None:
        print(f"run_fleet.py: the viewer exited with code {viewer.returncode}; going on without it",
              file=sys.stderr, flush=True)


def _start_carriers(args, scenario, fleet: _Fleet) -> None:
    """More routers when the fleet is large (joined to the first, each serving a share of the
    carriers), then the carrier processes."""
    from wire.zconfig import free_port

    n_routers = args.routers
    if n_routers is None:
        n = scenario.n_carriers
        n_routers = 0 if n <= CARRIERS_PER_ROUTER or not fleet.listen else -(-n // CARRIERS_PER_ROUTER)
    for _ in range(n_routers):
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        fleet.routers.append(_start_router(args, [endpoint], fleet.connect))
        fleet.router_endpoints.append(endpoint)
    endpoints = fleet.router_endpoints
    for g, group in enumerate(carrier_groups(scenario.carrier_ids, args.carrier_processes)):
        via = [endpoints[g % len(endpoints)]] if endpoints else fleet.connect
        fleet.carriers[",".join(group)] = subprocess.Popen(
            fleet.script + ["--role", "carrier", "--carrier", ",".join(group)] + fleet.common
            + fleet.connect_flags(via) + ["--log-sync", args.log_sync or "normal"]
            + ([] if args.verbose else ["--quiet"]), preexec_fn=_carrier_child)


def _announce(args, fleet: _Fleet) -> None:
    shown = ", ".join(f"{_short(cids)} pid {p.pid}" for cids, p in fleet.carriers.items())
    coordinator, viewer = fleet.coordinator, fleet.viewer
    print(f"run_fleet.py: network {', '.join(fleet.connect)}"
          + (f" (router pid {fleet.routers[0].pid})" if fleet.listen else "")
          + ("; no coordinator (decentralised)" if coordinator is None else f"; coordinator pid {coordinator.pid}")
          + f"; carriers {shown}"
          + (f"; {len(fleet.router_endpoints)} more router(s) at {', '.join(fleet.router_endpoints)}"
             if fleet.router_endpoints else ""),
          flush=True)
    if viewer is not None and viewer.poll() is None and not args.no_web:
        from viewer.node import viewer_url

        print(f"run_fleet.py: viewer pid {viewer.pid}; live view at {viewer_url(args.web_port, args.grpc_port)}",
              flush=True)


def _supervise(fleet: _Fleet, stop: threading.Event) -> None:
    """Until the mission is over or a stop request. The mission lasts as long as its
    coordinator; decentralised, or when the coordinator died, as long as its carriers (they go
    on without it)."""
    coordinator, carriers = fleet.coordinator, fleet.carriers
    refused = set()
    while not stop.is_set():
        if coordinator is not None and coordinator.poll() is not None and coordinator.returncode == 0:
            break
        if (coordinator is None or coordinator.poll() is not None) and all(p.poll() is not None
                                                                          for p in carriers.values()):
            break
        if coordinator is not None and coordinator.poll() in (EXIT_USAGE, EXIT_DEPOSED):
            break
        for cids, p in carriers.items():
            if p.poll() == EXIT_USAGE and cids not in refused:  # its one line is above
                refused.add(cids)
                print(f"run_fleet.py: carrier process {_short(cids)} exited with code {EXIT_USAGE} (refused: a "
                      f"duplicate or another world, reason above); the mission goes on without it",
                      file=sys.stderr, flush=True)
        stop.wait(0.05)


def _without_coordinator(fleet: _Fleet, code: int, stop: threading.Event) -> int:
    """The coordinator refused to start (``EXIT_USAGE``: a live coordinator of the mission, so
    nobody decides: carriers stopped) or was deposed (``EXIT_DEPOSED``: a newer coordinator
    decides now, our carriers fly on under it)."""
    if code == EXIT_USAGE:
        _stop_children(fleet.others(), grace_s=5.0)
        print(f"run_fleet.py: the coordinator refused to start (exit {code}, reason above); carriers stopped",
              file=sys.stderr, flush=True)
        return code
    print(f"run_fleet.py: the coordinator was deposed by a coordinator of a newer epoch (exit {code}); the "
          f"carriers go on under that one, whose --out holds the results", file=sys.stderr, flush=True)
    while any(p.poll() is None for p in fleet.carriers.values()) and not stop.is_set():
        stop.wait(0.1)
    _stop_children(fleet.others(), grace_s=5.0)
    return code


def _finish(args, fleet: _Fleet, code: int, started: float, stop: threading.Event) -> int:
    """After the mission: the carriers' grace, the report, the result lines, the viewer's linger."""
    carriers, out = fleet.carriers, fleet.out
    deadline = time.monotonic() + CARRIER_EXIT_GRACE_S
    while time.monotonic() < deadline and any(p.poll() is None for p in carriers.values()):
        time.sleep(0.05)
    _stop_children(list(carriers.values()), grace_s=5.0)
    _stop_children(fleet.routers, grace_s=5.0)
    bad = {cid: p.returncode for cid, p in carriers.items() if p.returncode not in (0,)}
    if bad:
        print(f"run_fleet.py: carrier exit codes {bad}", file=sys.stderr, flush=True)
    _report(fleet.script, out, args)  # summary.json from whatever logs exist, also when the coordinator died
    summary_path = out / "summary.json"
    if code != 0 or not summary_path.exists():
        print(f"run_fleet.py: the coordinator exited with code {code}" if fleet.coordinator is not None
              else "run_fleet.py: no summary.json (the report failed)", file=sys.stderr)
        if fleet.viewer is not None:
            _stop_children([fleet.viewer], grace_s=5.0)
        return code or 1
    _print_results(args, json.loads(summary_path.read_text()), out, started)
    if fleet.viewer is not None:
        _wait_for_viewer(args, fleet.viewer, stop)
    return 0


def _print_results(args, summary: dict, out: Path, started: float) -> None:
    bound = summary.get("clairvoyant") or {}  # None: the coordinator was stopped before the bound
    lat = summary.get("latency_ms", {})
    print(f"total reward {summary['total_reward']:.3f} (features {summary['total_features']:.1f}); "
          f"clairvoyant {'optimum' if bound.get('exact') else 'bound'} {bound.get('reward', float('nan')):.3f} "
          f"({(bound.get('fraction') or 0) * 100:.0f}%); decision round trip p50 "
          f"{_ms(lat.get('p50'))} p99 {_ms(lat.get('p99'))}; wall {time.monotonic() - started:.1f} s")
    print(f"results: {out}/summary.json, mission.db, merged_log.jsonl"
          + ("" if args.no_record else ", ros2bag/" if args.mcap_profile == "ros2" else ", mission.mcap")
          + ("" if args.no_map else ", map.png"))


def _start_router(args, listen, connect) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, str(Path(__file__).resolve()), "--role", "router"]
        + sum((["--listen", e] for e in listen), []) + sum((["--connect", e] for e in connect), [])
        + (["--zenoh-config", args.zenoh_config] if args.zenoh_config else []),
        stdout=subprocess.DEVNULL, preexec_fn=_ignore_sigint)


def _report(script, out: Path, args) -> int:
    """One-host mode, after the mission: ``--role report`` on ``out`` (a child like the others,
    SIGINT ignored so a late Ctrl-C cannot cut it half-way; its files are replaced atomically)."""
    flags = [f for flag, value in (("--seed", args.seed), ("--mission", args.mission)) if value is not None
             for f in (flag, str(value))]
    try:
        return subprocess.run(script + ["--role", "report", "--out", str(out)] + flags
                              + (["--no-map"] if args.no_map else []), preexec_fn=_ignore_sigint, timeout=300).returncode
    except subprocess.TimeoutExpired:
        print("run_fleet.py: the report did not finish in 300 s", file=sys.stderr, flush=True)
        return 1


def _wait_for_viewer(args, viewer, stop: threading.Event) -> None:
    """The mission is over; the viewer keeps serving (``--linger``) until it exits or Ctrl-C."""
    from viewer.node import viewer_url

    if viewer.poll() is None and not args.no_web:
        print(f"run_fleet.py: the live view stays at {viewer_url(args.web_port, args.grpc_port)}"
              + (" until Ctrl-C" if args.linger < 0 else f" for {args.linger:g} s"), flush=True)
    while viewer.poll() is None and not stop.is_set():
        stop.wait(0.1)
    _stop_children([viewer], grace_s=5.0)


def _ms(value) -> str:
    return "-" if value is None else f"{value:.1f} ms"


#: Roles whose process ends with ``os._exit`` once ``main`` returned (see the end of this file).
HARD_EXIT_ROLES = ("coordinator", "carrier", "router")


def main(argv=None) -> int:
    stop = install_stop_handlers()  # first: a signal from here on is a stop request, never an exception
    args = parse_args(argv)
    main.role = args.role
    from wire.zconfig import ConfigError

    if args.role == "router":
        try:
            return run_router(args, stop)
        except ConfigError as exc:
            return fail(str(exc))
    if args.scenario is None:
        return fail("the scenario file is required (except with --role router)")
    scenario = load(args)
    if scenario is None:
        return EXIT_USAGE
    problem = check_flags(args, scenario)
    if problem:
        return fail(problem)

    try:
        if args.role == "coordinator":
            return run_coordinator(args, scenario, stop)
        if args.role == "carrier":
            return run_carrier(args, scenario, stop)
        if args.role == "viewer":
            return run_viewer(args, scenario, stop)
        if args.role == "report":
            return run_report(args, scenario)
        return run_all(args, scenario, stop)
    except ConfigError as exc:
        return fail(str(exc))


if __name__ == "__main__":
    try:
        code = main()
    except Exception:
        if getattr(main, "role", None) not in HARD_EXIT_ROLES:
            raise
        # A bug: say where, and exit. Returning into the interpreter's shutdown would wait for
        # zenoh's callback threads, which are not daemons, for ever.
        import traceback

        traceback.print_exc()
        code = 1
    if getattr(main, "role", None) in HARD_EXIT_ROLES:
        # Everything is closed and written by now (sessions, mission.db, logs, mission.mcap). Skip
        # the interpreter's finalisation: a foreign thread re-entering Python during it (zenoh's
        # callback threads, the on-board planner's loader) aborted a process now and then
        # ("FATAL: exception not rethrown", exit -6; 2 runs of about 80 in one CI run).
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code if isinstance(code, int) else 1)
    sys.exit(code)
