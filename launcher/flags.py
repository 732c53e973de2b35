"""The launcher's command line: every flag, its spelling, default and help (a contract: the docs
and the tests use them), and the way back from values to a command line (:func:`to_argv`), by
which the one-host supervisor gives its children the flags it was given.

Reading the flags loads nothing but the modules that hold their defaults."""
from __future__ import annotations

import argparse
import functools
from collections import namedtuple

from launcher import AUTO_CARRIER_PROCESSES, CARRIERS_PER_ROUTER, NAME, ROBOT_SENSING

#: The usage examples, the epilog of ``--help``.
EXAMPLES = """\
    python run_fleet.py scenarios/six_carriers.yaml                 # everything on this host
    python run_fleet.py S.yaml --role coordinator --listen tcp/0.0.0.0:7447 --out runs/m1
    python run_fleet.py S.yaml --role carrier --carrier a --connect tcp/HOST:7447
    python run_fleet.py S.yaml --role carrier --carrier a,b,c --connect tcp/HOST:7447
    python run_fleet.py --role router --listen tcp/0.0.0.0:7447
    python run_fleet.py S.yaml --carrier-processes 8                 # R carriers in 8 processes
    python run_fleet.py S.yaml --decentralised                       # no coordinator at all
    python run_fleet.py S.yaml --operator                            # a person approves, vetoes, forces
    python run_fleet.py S.yaml --role report --out runs/m1          # results from whatever logs exist"""


class _Parser(argparse.ArgumentParser):
    """argparse, with "did you mean" for a misspelt flag (``--plannr`` -> ``--planner``)."""

    def error(self, message: str):
        from validation import did_you_mean

        if message.startswith("unrecognized arguments: "):
            flags = [o for a in self._actions for o in a.option_strings if o.startswith("--")]
            hints = [did_you_mean(w.split("=")[0], flags, cutoff=0.7)
                     for w in message.split(": ", 1)[1].split() if w.startswith("--")]
            message += "".join(h for h in hints if h)
        super().error(message)


def build_parser(prog: str = NAME, name: str = NAME) -> argparse.ArgumentParser:
    """The launcher's parser, shown as ``prog`` in usage lines; ``name`` is the default of the
    hidden ``--name`` (what the messages start with)."""
    p = _Parser(
        prog=prog, description="Run a marsupial fleet mission over Zenoh.",
        formatter_class=argparse.RawDescriptionHelpFormatter, epilog=EXAMPLES)
    # The order of the calls is the order of --help (the main group's flags, then the groups).
    _role_flags(p)
    _mission_flags(p)
    _zenoh_flags(p)
    _view_flags(p)
    _onboard_flags(p, _timeout_flags(p))
    _output_flags(p)
    _operator_flags(p)
    _ros2_flags(p)
    _carrier_output_flags(p)
    p.add_argument("--name", default=name, help=argparse.SUPPRESS)  # the messages' first word, for the children
    return p


def parse_args(argv=None, prog: str = NAME, name: str = NAME) -> argparse.Namespace:
    return build_parser(prog, name).parse_args(argv)


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
                        "sharing one Zenoh session (a carrier with --ros2 keeps one of its own)")
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

    p.add_argument("--planner", help="planner name (overrides the scenario): a built-in (random, ssap, mcts-random, "
                                      "mcts-ssap, closed-loop, ...), an installed plug-in's entry-point name, or a "
                                      "plug-in as package.module:Factory (docs/planner.md, \"Writing a planner "
                                      "plug-in\")")
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
    p.add_argument("--schedule", metavar="FILE",
                   help="one-host fleet: fly this fault schedule (the faults of a seed in python -m mission.simulate "
                        "--json), each fault struck at the mission point it names (docs/fleet.md, \"Fault schedules "
                        "on real processes\")")
    p.add_argument("--standby", action="store_true",
                   help="coordinator: if the mission already has a live coordinator, wait and take over when "
                        "its liveliness token vanishes (without it: refuse to start, exit 2)")
    p.add_argument("--coordinator-id", metavar="ID",
                   help="coordinator: this coordinator's id, with its epoch its ballot (docs/protocol.md, \"Epochs\"; "
                        "ranks two coordinators that took one epoch on different disks); default <host>-<pid>; the "
                        "one-host fleet names its own coordinator and standby")


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
                   help="viewer: keep serving the web view this long after the mission ends; < 0 = until Ctrl-C "
                        "(default; the launcher says so); with --no-web the viewer exits once --save is written")
    v.add_argument("--ready-file", help=argparse.SUPPRESS)  # one-host mode: the viewer is subscribed


def _timeout_flags(p: argparse.ArgumentParser):
    from mission.timeouts import DEFAULTS

    t = p.add_argument_group("timeouts (seconds)", "Not given, a timeout is its default, lengthened on acoustic "
                             "links by the link model's latency (docs/fleet.md, \"Waits over slow links\"); given, it "
                             "stands as given.")
    t.add_argument("--join-timeout", type=float, default=None,
                   help=f"coordinator: wait for carriers before stage 0 (default {DEFAULTS.join_s:g})")
    t.add_argument("--stage-timeout", type=float, default=None,
                   help="coordinator, --clock wall: wait per stage for observations, and after the last decision "
                        f"(at least 3 s) for its Confirms (default {DEFAULTS.stage_s:g})")
    t.add_argument("--decision-timeout", type=float, default=None,
                   help="carrier: --clock wall: wait per stage for the decision, then decide it on board; "
                        "--clock sim: ask the coordinator's State again after this long "
                        f"(default {DEFAULTS.decision_s:g})")
    t.add_argument("--silence-timeout", type=float, default=None,
                   help="--clock sim: a carrier waited for that sent nothing, not even Progress, for this long "
                        f"is taken as stalled (default {DEFAULTS.silence_s:g})")
    t.add_argument("--coordinator-timeout", type=float, default=None,
                   help="carrier: at the start, wait this long for a coordinator (then go on without it); "
                        "with --no-autonomy, exit when it has been absent this long "
                        f"(default {DEFAULTS.coordinator_s:g})")
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
    t.add_argument("--peer-timeout", type=float, default=None,
                   help="carrier deciding on board, --clock wall: wait per stage for the other carriers' "
                        f"observations (default {DEFAULTS.peer_s:g})")


def _output_flags(p: argparse.ArgumentParser) -> None:
    """The coordinator's map and recording."""
    from recording import PROFILES

    p.add_argument("--no-map", action="store_true", help="do not draw map.png")
    p.add_argument("--no-record", action="store_true", help="coordinator: do not write mission.mcap")
    p.add_argument("--mcap-profile", choices=PROFILES, default=PROFILES[0],
                   help="coordinator: the recording's profile: foxglove (default: mission.mcap with Foxglove's "
                        "schemas) or ros2 (the rosbag2 bag ros2bag/ that ros2 bag play replays; needs .[ros2])")


def _operator_flags(p: argparse.ArgumentParser) -> None:
    """Operator mode: the console and how long a stage waits for the operator."""
    import console

    o = p.add_argument_group("operator console (docs/fleet.md, \"The operator console\")")
    o.add_argument("--operator", action="store_true",
                   help="coordinator: serve the operator's console; each stage's recommendation waits for the "
                        "operator to approve it, veto a carrier's deployment or force one")
    o.add_argument("--operator-port", type=int, default=console.PORT, metavar="PORT",
                   help="the console's port on 127.0.0.1 (default %(default)s; 0: any free port, printed)")
    # Not an argparse group of exclusive flags: the launcher's check says which one to drop.
    o.add_argument("--operator-timeout", type=float, default=None, metavar="SECONDS",
                   help=f"the recommendation stands after this long without an answer (default {console.TIMEOUT_S:g}; "
                        "0: autonomous, the console watches)")
    o.add_argument("--operator-required", action="store_true",
                   help="instead of --operator-timeout: wait for the operator up to the stage's own wait "
                        "(--stage-timeout), then the recommendation stands")
    o.add_argument("--operator-bind", default="127.0.0.1", metavar="ADDR",
                   help="serve the console on this address (default %(default)s); another address needs "
                        "--operator-cert and --operator-key, and the operator credential (operator.token)")
    o.add_argument("--operator-cert", metavar="FILE", help="PEM certificate: serve the console over HTTPS")
    o.add_argument("--operator-key", metavar="FILE", help="PEM private key of --operator-cert")


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
                        "poses in NS/features), frontier (the frontier cells of the robot's NS/map within the "
                        "scenario's sensing radius, the importer's --replay value) or frontier3d (the frontier "
                        "voxels of its OctoMap on NS/octomap_binary within that radius and the paper's height "
                        "band, the 3D import's value)")
    r.add_argument("--robot-cloud-topic", metavar="TOPIC",
                   help="with --robot-sensing frontier3d: make the 3D map from the robot's "
                        "sensor_msgs/msg/PointCloud2 scans on NS/TOPIC (OctoMap's ray casting, the 3D import's) "
                        "instead of reading its NS/octomap_binary")
    r.add_argument("--robot-voxel", type=float, metavar="M",
                   help="with --robot-cloud-topic: that map's voxel size in m (default: the resolution of the "
                        "scenario's map.voxels OctoMap, else 0.2, the 3D import's)")
    r.add_argument("--robot-sensor-offset", type=float, nargs=3, metavar=("X", "Y", "Z"),
                   help="with --robot-cloud-topic: the LiDAR's position in the robot's base frame in m, where each "
                        "scan's rays start (default 0 0 0; the 3D import's --sensor-offset)")


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


@functools.lru_cache(maxsize=None)
def _canonical() -> tuple[tuple[argparse.Action, ...], type]:
    """The parser's actions (help left out) and the :data:`Flags` type of their values."""
    actions = tuple(a for a in build_parser()._actions if not isinstance(a, argparse._HelpAction))
    return actions, namedtuple("Flags", [a.dest for a in actions])


def flags_type() -> type:
    """``Flags``: a NamedTuple with one field per flag (its ``dest``), in the parser's order."""
    return _canonical()[1]


def defaults():
    """The :func:`flags_type` value of a command line that gives no flag at all."""
    actions, kind = _canonical()
    return kind(*(_frozen(a.default) for a in actions))


def flags_of(args: argparse.Namespace):
    """The parsed flags as a :func:`flags_type` value (a repeatable flag's values as a tuple)."""
    return flags_type()(**{name: _frozen(getattr(args, name)) for name in flags_type()._fields})


def _frozen(value):
    return tuple(value) if isinstance(value, list) else value


def to_argv(flags) -> list[str]:
    """A command line that parses back to ``flags`` (:func:`flags_of` of it equals ``flags``):
    the positional scenario first, then each flag whose value differs from its default, in the
    parser's order (a repeatable flag once per value)."""
    positional, options = [], []
    for action in _canonical()[0]:
        value = _frozen(getattr(flags, action.dest))
        if value == _frozen(action.default):
            continue
        if not action.option_strings:
            positional.append(str(value))
            continue
        flag = action.option_strings[-1]  # the long spelling
        if isinstance(action, argparse._StoreTrueAction):
            options.append(flag)
        elif isinstance(action, argparse._AppendAction):
            options += [token for item in value for token in _pair(flag, item)]
        elif type(action) is argparse._StoreAction and isinstance(action.nargs, int):
            options += [flag, *(str(v) for v in value)]  # numbers: a negative one reads as a value
        elif type(action) is argparse._StoreAction:
            options += _pair(flag, value)
        else:  # a new kind of flag must say how it is written out
            raise TypeError(f"to_argv: cannot write out {flag} ({type(action).__name__})")
    return positional + options


def _pair(flag: str, value) -> list[str]:
    """``[flag, value]``, or ``[flag=value]`` when the value would read as a flag."""
    text = str(value)
    return [f"{flag}={text}"] if text.startswith("-") else [flag, text]
