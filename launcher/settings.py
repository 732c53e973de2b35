"""From a parsed command line to the launcher's settings: every problem with the flags (a
``validation.Flaw`` each: the flag, what it takes, what it was given; one line by its
``line()``), or a frozen :class:`Settings`. Nothing here changes the parsed
``argparse.Namespace``; what validation derives (the carrier ids, the planner options, the ROS
domain) is a field of the settings.

Checking loads only what the flags given need (rerun-sdk with the live view, ros2/ with ROS 2,
the planner registry for the coordinator's planner), so a carrier process that parses its flags
loads no planner kernels (tests/test_fleet_scale.py)."""
from __future__ import annotations

import argparse
import dataclasses
import math
import os
import re
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from launcher import ROBOT_SENSING
from launcher.flags import flags_of
from planner.registry import OPTIONS
from validation import Check, Found, Number, Flaw, Flaws


#: The timeout flags and the :class:`mission.timeouts.Timeouts` field each sets.
TIMEOUT_FLAGS = {"join_timeout": "join_s", "stage_timeout": "stage_s", "decision_timeout": "decision_s",
                 "silence_timeout": "silence_s", "coordinator_timeout": "coordinator_s", "peer_timeout": "peer_s"}


@dataclass(frozen=True)
class Settings:
    """What a launcher process runs with.

    Attributes:
        flags: every flag's value (``launcher.flags.flags_type()``): as given, but ``scenario``
            is the file loaded (a bundled scenario's name resolved) and ``ros2_domain`` the
            domain in force (``ROS_DOMAIN_ID`` when the flag is absent) whenever ROS 2 is on.
        scenario: the loaded ``world.Scenario``; None for the router.
        carriers: ``--carrier``'s ids, in order (empty unless ``--role carrier``).
        planner_options: ``--planner-option``'s (key, checked value) pairs, in order.
        schedule: ``--schedule``'s faults (``mission.simulate.Fault``), in order; points: each
            one's mission points (``mission.simulate.schedule.points``).
    """

    flags: Any
    scenario: Any = None
    carriers: tuple[str, ...] = ()
    planner_options: tuple[tuple[str, Any], ...] = ()
    schedule: tuple = ()
    points: tuple = ()

    @property
    def name(self) -> str:
        """The first word of the launcher's messages."""
        return self.flags.name

    def ros2(self):
        """The processes' ROS 2 settings (ros2/publisher.py), or None: with neither --ros2 nor
        --ros2-robot nothing of ros2/ is imported."""
        f = self.flags
        if not (f.ros2 or f.ros2_robot):
            return None
        from ros2.publisher import Ros2Settings

        return Ros2Settings(domain=f.ros2_domain, robot=f.ros2_robot, namespace=f.ros2_namespace or "/",
                            sensing=f.robot_sensing or ROBOT_SENSING[0], cloud_topic=f.robot_cloud_topic or "",
                            voxel=f.robot_voxel or 0.0,
                            sensor_offset=tuple(f.robot_sensor_offset or (0.0, 0.0, 0.0)))

    def timeouts(self):
        """The mission's waits (:class:`mission.timeouts.Timeouts`; docs/fleet.md, "Waits over
        slow links"): the defaults with the timeout flags given over them, and each wait that
        crosses the links and was not given lengthened by the link model's latency bound
        (:func:`world.fleet_links.latency_bound`), in wall seconds: divided by ``--realtime``
        when the mission is paced, as the links' delays are (wire/link_filter.py)."""
        from mission.timeouts import DEFAULTS, over_links

        given = {name: getattr(self.flags, flag) for flag, name in TIMEOUT_FLAGS.items()
                 if getattr(self.flags, flag) is not None}
        latency = 0.0
        if self.scenario is not None and self.scenario.links.model != "perfect":
            from wire.sizes import link_sizes
            from world.fleet_links import latency_bound

            latency = latency_bound(self.scenario, link_sizes(self.scenario))
            if self.flags.realtime and self.flags.realtime > 0:
                latency /= self.flags.realtime
        return over_links(dataclasses.replace(DEFAULTS, **given), latency, given)

    def out(self) -> str:
        """``--out``, else a fresh ``runs/<mission id>-<timestamp>`` under the current directory."""
        from wire import keys

        if self.flags.out:
            return self.flags.out
        return str(Path("runs") / f"{keys.mission_id_from_name(self.scenario.name)}-{time.strftime('%Y%m%d-%H%M%S')}")


def check(args: argparse.Namespace, scenario=None) -> tuple[Settings | None, list[Flaw]]:
    """The settings of a parsed command line and its loaded scenario (None: the router), or None
    and every problem found (at least one). ``args`` is left as it was."""
    flags = flags_of(args)
    if scenario is not None and scenario.source:
        flags = flags._replace(scenario=scenario.source)
    problems: list[Flaw] = []
    problems += _values(flags)
    options, option_problems = _planner_options(flags, scenario)
    problems += option_problems
    problems += _roles(flags)
    carriers, carrier_problems = _carriers(flags, scenario)
    problems += carrier_problems
    domain, ros2_problems = _ros2(flags, carriers)
    problems += ros2_problems
    if domain is not None:
        flags = flags._replace(ros2_domain=domain)
    if scenario is not None:
        problems += _mission(flags, scenario)
    if scenario is not None and not problems:  # the planner is built from the other flags
        problems += _planner(flags, scenario, options)
    schedule, points, schedule_problems = _schedule(flags, scenario)
    problems += schedule_problems
    if problems:
        return None, problems
    return Settings(flags, scenario, carriers, options, schedule, points), []


def _schedule(f, scenario) -> tuple[tuple, tuple, list[Flaw]]:
    """``--schedule``: its faults and their mission points, or the one problem of its file (which
    fault, which field)."""
    if not f.schedule:
        return (), (), []
    if f.role != "all" or f.decentralised:
        return (), (), [Flaw("--schedule", "the one-host fleet with a coordinator (--role all)",
                                Found(f"--role {f.role}" + (" --decentralised" if f.decentralised else "")))]
    import json

    from mission.simulate import schedule

    try:
        faults = schedule.load(f.schedule, scenario.carrier_ids if scenario is not None else None)
        points = schedule.points(json.loads(Path(f.schedule).read_text()))
    except schedule.ScheduleError as exc:
        return (), (), [_said("--schedule", str(exc))]
    from launcher.faults import FLOWN

    for k, fault in enumerate(faults):
        if fault.kind not in FLOWN:
            return (), (), [_said("--schedule", f"{f.schedule}: fault {k}: field 'kind': expected a kind the real "
                                                f"fleet flies ({', '.join(FLOWN)}), found {fault.kind!r}")]
    return faults, tuple(points), []


#: The numeric flags' checks, in the order their problems are listed (the planner's budgets are
#: checked by the registry's options).
_NUMBERS: tuple[tuple[str, Check], ...] = (
    ("realtime", Number(minimum=0, noun="a factor")),
    ("iterations", OPTIONS["iterations"].spec),
    ("plan_ms", OPTIONS["plan_ms"].spec),
    ("pose_interval", Number(minimum=0, noun="seconds")),
    ("seed", Number(integer=True, minimum=0)),
    *((name, Number(minimum=0, exclusive=True, noun="seconds")) for name in (
        "join_timeout", "stage_timeout", "decision_timeout", "coordinator_timeout", "peer_timeout", "silence_timeout")),
    ("routers", Number(integer=True, minimum=0)),
    ("operator_timeout", Number(minimum=0, noun="seconds")),
    ("operator_port", Number(integer=True, minimum=0, maximum=65535)),
    ("carrier_processes", Number(integer=True, minimum=1)),
)


def _values(f) -> list[Flaw]:
    """Each number in its range."""
    problems = Flaws()
    for key, spec in _NUMBERS:
        value = getattr(f, key)
        if value is not None:
            problems.check(spec, value, f"--{key.replace('_', '-')}")
    return problems.items


def _planner_options(f, scenario) -> tuple[tuple, list[Flaw]]:
    """``--planner-option``'s pairs, checked against the planner in force (a plug-in's own options
    included): ``--planner``, else the scenario's."""
    from planner.registry import DEFAULT_PLANNER, is_planner, parse_option

    name = f.planner or (scenario.planner.name if scenario is not None else DEFAULT_PLANNER)
    name = name if is_planner(name) else None  # an unknown planner is --planner's problem alone
    options, out = [], []
    for text in f.planner_option:
        try:
            options.append(parse_option(text, name))
        except ValueError as exc:
            out.append(Flaw("--planner-option", "KEY=VALUE of planner.registry", text, str(exc)))
    return tuple(options), out


def _roles(f) -> list[Flaw]:
    """Flags that go together, and what the live view needs."""
    out = []
    if f.decentralised and f.no_autonomy:
        out.append(Flaw("--decentralised", "no --no-autonomy beside it (they exclude each other)", Found("both")))
    if f.decentralised and f.role == "coordinator":
        out.append(Flaw("--decentralised", "a role other than coordinator (it runs no coordinator)",
                           Found("--role coordinator")))
    viewer = f.role == "viewer" or f.view
    if viewer and f.no_web and not f.save:
        out.append(Flaw("--no-web", "--save FILE.rrd beside it (else the viewer shows nothing)", Found("no --save")))
    if viewer:
        try:
            import rerun  # noqa: F401
        except ImportError:
            out.append(Flaw("--view" if f.view else "--role viewer",
                               "rerun-sdk for the live view (pip install -e '.[view]')", Found("no rerun module")))
    if f.standby and f.role != "coordinator":
        out.append(Flaw("--standby", "--role coordinator", Found(f"--role {f.role}")))
    if f.coordinator_id is not None:
        from wire.keys import ID_PATTERN

        if f.role != "coordinator":
            out.append(Flaw("--coordinator-id", "--role coordinator (the one-host fleet names its own)",
                               Found(f"--role {f.role}")))
        elif not ID_PATTERN.match(f.coordinator_id):
            out.append(Flaw("--coordinator-id", "an id: 1 to 64 of letters, digits, '_', '.', '-', not "
                               "starting with '.' or '-'", Found(repr(f.coordinator_id))))
    out += _operator(f)
    if f.role == "report" and not f.out:
        out.append(Flaw("--out", "DIR with --role report (the results directory to read)", Found("nothing")))
    if f.out and Path(f.out).exists() and not Path(f.out).is_dir():
        out.append(Flaw("--out", "a results directory (existing or new)", Found(f"the file {f.out!r}")))
    elif f.out and any(p.exists() and not p.is_dir() for p in Path(f.out).parents):
        parent = next(p for p in Path(f.out).parents if p.exists() and not p.is_dir())
        out.append(Flaw("--out", "a results directory (existing or new)", Found(f"{f.out!r} under the file {str(parent)!r}")))
    return out


def _operator(f) -> list[Flaw]:
    """Operator mode's flags: with a coordinator, TLS by pairs, another address only over TLS."""
    out = []
    if f.operator and (f.decentralised or f.role not in ("all", "coordinator")):
        out.append(Flaw("--operator", "a coordinator (--role all or coordinator, not --decentralised)",
                           Found("--decentralised" if f.decentralised else f"--role {f.role}")))
    if f.operator_required and f.operator_timeout is not None:
        out.append(Flaw("--operator-timeout", "not beside --operator-required (one says how long a stage waits)",
                           Found("both")))
    if bool(f.operator_cert) != bool(f.operator_key):
        out.append(Flaw("--operator-cert" if f.operator_key else "--operator-key",
                           "--operator-cert and --operator-key together", Found("only one of them")))
    if f.operator and f.operator_bind not in ("127.0.0.1", "localhost", "::1") and not f.operator_cert:
        out.append(Flaw("--operator-bind", "--operator-cert and --operator-key beside an address other than "
                                              "127.0.0.1 (the console is served over TLS there)",
                           Found(f.operator_bind)))
    if f.operator and f.operator_port and f.role in ("all", "coordinator") and not _port_free(f.operator_bind,
                                                                                             f.operator_port):
        out.append(Flaw("--operator-port", f"a free port on {f.operator_bind}", Found(f.operator_port),
                           "in use (another console or server listens there)"))
    for flag in ("operator_cert", "operator_key"):
        path = getattr(f, flag)
        if path and not Path(path).is_file():
            out.append(Flaw(f"--{flag.replace('_', '-')}", "a PEM file", Found(path), "no such file"))
    return out


def _port_free(host: str, port: int) -> bool:
    import socket

    try:
        with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as probe:
            probe.bind((host, int(port)))
        return True
    except OSError:
        return False


def operator_settings(settings: "Settings"):
    """The coordinator's operator mode (:class:`console.hold.OperatorSettings`), or None without
    ``--operator``."""
    f = settings.flags
    if not f.operator:
        return None
    from console import TIMEOUT_S
    from console.hold import OperatorSettings

    timeout_s = TIMEOUT_S if f.operator_timeout is None else f.operator_timeout
    return OperatorSettings(f.operator_port, timeout_s, f.operator_required, settings.timeouts().stage_s,
                            f.operator_bind, (f.operator_cert, f.operator_key) if f.operator_cert else None)


def _carriers(f, scenario) -> tuple[tuple[str, ...], list[Flaw]]:
    """``--role carrier``'s ids: given, known to the scenario, each once."""
    if f.role != "carrier":
        return (), []
    if not f.carrier:
        return (), [Flaw("--carrier", "ID (or ID,ID,...) with --role carrier", Found("nothing"))]
    ids = tuple(c.strip() for c in f.carrier.split(","))
    known = list(scenario.carrier_ids) if scenario is not None else []
    for cid in ids:
        if cid not in known:
            listed = ", ".join(known[:20]) + (", ..." if len(known) > 20 else "")
            return (), [Flaw("--carrier", f"one of {listed} (carriers of {f.scenario})", cid)]
    if len(set(ids)) != len(ids):
        return (), [Flaw("--carrier", "each carrier id once", f.carrier,
                            f"a carrier id is repeated in {f.carrier!r}")]
    return ids, []


def _ros2(f, carriers: tuple[str, ...]) -> tuple[int | None, list[Flaw]]:
    """The ROS 2 flags: (the domain in force, or None when ROS 2 is off) and their problems."""
    ros2 = f.ros2 or f.ros2_robot
    if (not ros2 and f.ros2_domain is None and f.ros2_namespace is None and f.robot_sensing is None
            and f.robot_cloud_topic is None and f.robot_voxel is None and f.robot_sensor_offset is None
            and f.mcap_profile == "foxglove"):
        return None, []
    from ros2.publisher import check_domain, check_namespace, default_domain

    out = []
    domain = f.ros2_domain
    if domain is None:
        text = os.environ.get("ROS_DOMAIN_ID", "").strip()
        if text and not text.isdigit():
            return None, [Flaw("ROS_DOMAIN_ID", "an integer 0..232", text)]
        domain = default_domain()
    line = check_domain(domain)
    if line:
        out.append(_said("--ros2-domain", line))
    if f.ros2_robot and (f.role != "carrier" or len(carriers) != 1):
        out.append(Flaw("--ros2-robot", "", None, "only with --role carrier and one --carrier ID (the robot's carrier)"))
    if f.ros2_namespace is not None:
        if not f.ros2_robot:
            out.append(Flaw("--ros2-namespace", "", None, "only with --ros2-robot (the robot's namespace)"))
        else:
            line = check_namespace(f.ros2_namespace)
            if line:
                out.append(_said("--ros2-namespace", line))
    if f.robot_sensing is not None and not f.ros2_robot:
        out.append(Flaw("--robot-sensing", "", None, "only with --ros2-robot (what the robot's carrier observes)"))
    if f.robot_cloud_topic is not None:
        if f.robot_sensing != "frontier3d":
            out.append(Flaw("--robot-cloud-topic", "", None,
                               "only with --ros2-robot --robot-sensing frontier3d (the scans its 3D map is made of)"))
        elif not re.fullmatch(r"[A-Za-z][A-Za-z0-9_]*(/[A-Za-z][A-Za-z0-9_]*)*", f.robot_cloud_topic):
            out.append(Flaw("--robot-cloud-topic", "a topic in the robot's namespace such as points or "
                               "lidar/points (tokens of letters, digits and _ starting with a letter)",
                               f.robot_cloud_topic))
    if f.robot_voxel is not None:
        if f.robot_cloud_topic is None:
            out.append(Flaw("--robot-voxel", "", None, "only with --robot-cloud-topic (the voxel size of the map "
                               "the carrier makes of the robot's scans)"))
        elif not (math.isfinite(f.robot_voxel) and f.robot_voxel > 0):
            out.append(Flaw("--robot-voxel", "a voxel size > 0 (m)", f.robot_voxel))
    if f.robot_sensor_offset is not None:
        if f.robot_cloud_topic is None:
            out.append(Flaw("--robot-sensor-offset", "", None, "only with --robot-cloud-topic (where the scans' "
                               "rays start on the robot)"))
        elif not all(math.isfinite(v) for v in f.robot_sensor_offset):
            out.append(Flaw("--robot-sensor-offset", "three finite numbers X Y Z (m)", list(f.robot_sensor_offset)))
    if f.mcap_profile == "ros2" and f.role in ("all", "coordinator"):
        try:
            import rosbags  # noqa: F401
        except ImportError:
            out.append(Flaw("--mcap-profile", "rosbags for ros2 (pip install -e '.[ros2]')", Found("no rosbags module")))
    return (domain if ros2 else None), out


def _said(flag: str, line: str) -> Flaw:
    """A problem that another module put in words (``FLAG: ...``)."""
    return Flaw(flag, "", None, line.removeprefix(f"{flag}: "))


def _mission(f, scenario) -> list[Flaw]:
    """Ids usable in key expressions: the scenario's carriers and the mission's."""
    from wire import keys

    out = []
    for k, cid in enumerate(scenario.carrier_ids):
        if not keys.ID_PATTERN.match(cid):
            out.append(Flaw(f"{f.scenario}: carriers[{k}].id",
                               f"an id usable in key expressions ({keys.ID_PATTERN.pattern})", cid))
    if f.mission is None and not keys.ID_PATTERN.match(keys.mission_id_from_name(scenario.name)):
        out.append(Flaw(f"{f.scenario}: name", "", None, f"cannot derive a mission id from {scenario.name!r}; pass --mission"))
    if f.mission is not None:
        try:
            keys.check_id(f.mission, "--mission")
        except ValueError as exc:
            out.append(Flaw("--mission", f"an id matching {keys.ID_PATTERN.pattern}", f.mission,
                               str(exc).removeprefix("--mission ")))
    return out


def _planner(f, scenario, options: tuple) -> list[Flaw]:
    """The coordinator's planner, built once to check it (the one-host launcher's too)."""
    if f.role in ("carrier", "viewer", "router", "report") or f.decentralised:
        return []
    from planner.registry import make_planner, planner_settings

    name, kwargs = planner_settings(scenario, f.planner, f.iterations, f.plan_ms, options)
    try:
        make_planner(name, **kwargs)
    except ValueError as exc:
        return [Flaw("--planner", "a planner of planner.registry with valid options", name, str(exc))]
    return []


def resolve_scenario(text: str) -> tuple[str | None, str | None]:
    """(the scenario file ``text`` names, None), or (None, one line) when ``text`` is neither a
    file nor a bundled scenario's name. A path that names no file is returned as it is, for the
    scenario loader's own line about it."""
    import scenarios

    if Path(text).is_file():
        return text, None
    bundled = scenarios.bundled_path(text)
    if bundled is not None:
        return str(bundled), None
    if "/" in text or os.sep in text:
        return text, None
    return None, (f"{text}: expected a scenario file or the name of a bundled scenario "
                  f"({', '.join(scenarios.bundled_names())}), found neither")


def load_scenario(text: str):
    """(the scenario that ``text`` names, []), or (None, the lines that say why not): the world's
    one line per problem of the file."""
    import world
    from wire.sizes import frame_problems

    path, line = resolve_scenario(text)
    if path is None:
        return None, [line]
    try:
        scenario = world.load_scenario(path)
        frames = frame_problems(scenario)  # a message the acoustic frame cannot hold: refused, never lost in flight
        return (None, [p.line(path) for p in frames]) if frames else (scenario, [])
    except world.ScenarioError as exc:
        return None, list(exc.problems)
    except OSError as exc:
        return None, [f"{path}: cannot read the scenario: {exc.strerror or exc}"]


def zenoh_config(f, role: str):
    """The Zenoh config of a process of ``role`` from the flags ``f``: the endpoints given, else a
    coordinator or router listens on the default port and a carrier or viewer connects to it;
    the mode given, else the one the role plays."""
    from wire.zconfig import DEFAULT_PORT, file_listens, file_sets_mode, make_config

    listen, connect = list(f.listen), list(f.connect)
    if not f.zenoh_config:
        if role in ("coordinator", "router") and not listen and not connect:
            listen = [f"tcp/127.0.0.1:{DEFAULT_PORT}"]
        if role in ("carrier", "viewer") and not connect:
            connect = [f"tcp/127.0.0.1:{DEFAULT_PORT}"]
    mode = f.mode
    if mode is None and not file_sets_mode(f.zenoh_config):
        if role == "router":
            mode = "router"
        elif role == "coordinator" and (listen or file_listens(f.zenoh_config)):
            mode = "peer"  # it is the carriers' rendezvous
        else:
            mode = "client"  # a carrier, or a coordinator that only connects (to a router)
    return make_config(mode, listen, connect, f.zenoh_config)
