"""The one-host fleet (``--role all``, the default): the network (a router of the fleet's own, or
the user's), the coordinator, the viewer, the carrier processes, one line about them, the
supervision until the mission is over, then the report and the result lines.

Every child is this launcher again with a role (``python -m launcher SCENARIO --role ...``), and
its command line is written from the launcher's own settings (:func:`child_argv`): each flag the
role takes, with the value this launcher was given, so a new flag reaches the children with no
edit here. What a role does not take is listed once, in :data:`EXCLUDED`."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from launcher import AUTO_CARRIER_PROCESSES, CARRIER_EXIT_GRACE_S, CARRIERS_PER_ROUTER
from launcher.flags import defaults, flags_type, to_argv
from launcher.roles import refuse, say
from launcher.settings import Settings
from launcher.signals import carrier_child, ignore_sigint, stop_children
from mission.exits import EXIT_DEPOSED, EXIT_USAGE, STOPPED

#: Flags of the one-host launcher itself: a child gets its role, carriers, network and results
#: directory from the supervisor instead.
ONE_HOST = ("role", "carrier", "carrier_processes", "routers", "view", "verbose", "listen", "connect", "mode",
            "standby", "coordinator_id", "out", "ready_file", "schedule")
#: The ids the one-host fleet gives its coordinator and its standby (the simulator's names: a
#: schedule's ballots rank them as in the simulated mission).
PRIMARY_ID, STANDBY_ID = "coordinator", "standby"
#: The viewer's own flags.
VIEWER = ("web_port", "grpc_port", "save", "no_web", "linger")
#: Operator mode's flags: the coordinator's alone.
OPERATOR = ("operator", "operator_port", "operator_timeout", "operator_required", "operator_bind", "operator_cert",
            "operator_key")
#: Per role, the flags a child does not take from the launcher's command line (they keep their
#: defaults there); every other flag is passed on as given.
EXCLUDED = {
    "coordinator": ONE_HOST + VIEWER + ("quiet", "log_sync"),
    "carrier": ONE_HOST + VIEWER + OPERATOR,
    "viewer": ONE_HOST + OPERATOR,
    "report": ONE_HOST + VIEWER + OPERATOR + ("quiet", "log_sync"),
}
#: What a router takes: it serves any mission, so nothing of the mission.
ROUTER_TAKES = ("zenoh_config", "name")


def child_flags(flags, role: str, **given):
    """The flags of a child of ``role``: the launcher's ``flags`` for what the role takes (every
    other flag at its default), the role, and ``given`` (the supervisor's own values)."""
    fields = flags_type()._fields
    takes = ROUTER_TAKES if role == "router" else [name for name in fields if name not in EXCLUDED[role]]
    given = {name: tuple(value) if isinstance(value, list) else value for name, value in given.items()}
    return defaults()._replace(**{name: getattr(flags, name) for name in takes}, role=role)._replace(**given)


def child_argv(flags, role: str, **given) -> list[str]:
    """The command line (after the interpreter) of a child of ``role``: it parses back to
    :func:`child_flags` (tests/test_launcher.py)."""
    return ["-m", "launcher", *to_argv(child_flags(flags, role, **given))]


def child_env() -> dict:
    """The children's environment: ours, and in a clone its root first on the module path (the
    launcher then runs from a clone that was never installed, as ``python run_fleet.py`` does)."""
    from world.paths import IN_CLONE, REPO_ROOT

    env = dict(os.environ)
    if IN_CLONE:
        env["PYTHONPATH"] = os.pathsep.join([str(REPO_ROOT)] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    return env


@dataclass
class Fleet:
    """The one-host fleet's child processes and the network they share."""

    settings: Settings
    out: Path
    listen: list[str]  # the first router's endpoints (none: the user's router)
    connect: list[str]  # what the coordinator and the viewer connect to
    routers: list = field(default_factory=list)
    router_endpoints: list[str] = field(default_factory=list)  # the routers beyond the first
    coordinator: subprocess.Popen | None = None
    viewer: subprocess.Popen | None = None
    carriers: dict = field(default_factory=dict)  # "id,id,..." -> its process
    via: dict = field(default_factory=dict)  # "id,id,..." -> the endpoints its process connects to
    standby: subprocess.Popen | None = None  # a standby coordinator (a schedule's takeover or pause)
    windows: Path | None = None  # a schedule's message faults in force (wire.fault_windows)

    def start(self, role: str, preexec=ignore_sigint, **given) -> subprocess.Popen:
        """A child of ``role`` (SIGINT ignored until it is up); ``given``: its own flag values. A
        coordinator draws no map.png: the report draws it once, at the end, from the merged logs
        (the coordinator's drawing was a second of CPU and its import another, before it exits)."""
        if role != "router":
            given.setdefault("out", str(self.out))
        if role == "coordinator":
            given["no_map"] = True
        env = child_env()
        if self.windows is not None:
            from wire.fault_windows import ENV

            env[ENV] = str(self.windows)
        return subprocess.Popen([sys.executable, *child_argv(self.settings.flags, role, **given)],
                                env=env, preexec_fn=preexec,
                                stdout=subprocess.DEVNULL if role == "router" else None)

    def procs(self) -> list:
        return [p for p in (self.coordinator, self.standby, *self.carriers.values(), *self.routers, self.viewer)
                if p is not None]

    def others(self) -> list:
        """The carriers, the routers, the viewer and a standby: what is left once the coordinator is gone."""
        return [*self.carriers.values(), *self.routers] + [p for p in (self.viewer, self.standby) if p is not None]


def main(settings: Settings, stop: threading.Event) -> int:
    """The whole fleet on this host; the exit status is the coordinator's (0: the mission ended)."""
    if stop.is_set():
        return STOPPED
    f = settings.flags
    if f.connect and not f.listen:
        problem = taken(settings, list(f.connect))  # else our carriers would join the live mission
        if problem:
            return refuse(settings, problem)
    fleet = start_network(settings)
    if settings.schedule:
        fleet.windows = fleet.out / ".fault-windows.json"
        fleet.windows.write_text('{"loss": [], "cut": []}')
    started = time.monotonic()
    if not f.decentralised:
        fleet.coordinator = fleet.start("coordinator", connect=fleet.connect, coordinator_id=PRIMARY_ID)
    injector = scheduled(fleet, stop) if settings.schedule else None
    if f.view:  # subscribed before the carriers start, so the view misses nothing
        start_viewer(fleet, stop)
    start_carriers(fleet)
    announce(fleet)
    if injector is not None:
        injector.start()
    try:
        supervise(fleet, stop)
    finally:
        if injector is not None:
            injector.finish()
    if stop.is_set():
        say(settings, "interrupted; stopping the fleet")
        stop_children(fleet.procs())
        return STOPPED
    code = 0 if fleet.coordinator is None else fleet.coordinator.returncode
    if code in (EXIT_USAGE, EXIT_DEPOSED):
        return without_coordinator(fleet, code, stop)
    return finish(fleet, code, started, stop)


def start_network(settings: Settings) -> Fleet:
    """The results directory and the fleet's network: a router of the user's (``--connect``
    without ``--listen``: everyone connects to it), else a router of the fleet's own, not the
    coordinator, so that carriers keep talking to each other when the coordinator is gone."""
    from wire.zconfig import free_port

    f = settings.flags
    out = Path(settings.out())
    out.mkdir(parents=True, exist_ok=True)
    if f.connect and not f.listen:
        return Fleet(settings, out, [], list(f.connect))
    listen = list(f.listen) or [f"tcp/127.0.0.1:{free_port()}"]
    fleet = Fleet(settings, out, listen, [e.replace("0.0.0.0", "127.0.0.1") for e in listen])
    fleet.routers.append(fleet.start("router", listen=listen))
    return fleet


def scheduled(fleet: Fleet, stop: threading.Event):
    """``--schedule``: the standby a takeover or a pause needs (started once the primary has
    opened mission.db, so that it waits as a standby), and the :class:`launcher.faults.Injector`
    that strikes each fault at its mission point."""
    from launcher.faults import OWN_DISK, STANDBY, STANDBY_OUT, Injector

    settings = fleet.settings
    if any(f.kind in STANDBY for f in settings.schedule):
        deadline = time.monotonic() + 60
        while not (fleet.out / "mission.db").exists() and not stop.is_set() and time.monotonic() < deadline:
            stop.wait(0.05)
        own = {"out": str(fleet.out / STANDBY_OUT)} if any(f.kind in OWN_DISK for f in settings.schedule) else {}
        fleet.standby = fleet.start("coordinator", connect=fleet.connect, standby=True, coordinator_id=STANDBY_ID,
                                    **own)

    # a process is started again only if it is not running (the simulator's rule: a second
    # crash of a process already down restarts nothing of its own)
    def coordinator():
        if fleet.coordinator.poll() is not None:
            fleet.coordinator = fleet.start("coordinator", connect=fleet.connect, coordinator_id=PRIMARY_ID)

    def carrier(cid: str):
        if fleet.carriers[cid].poll() is not None:
            start_carrier(fleet, cid, fleet.via[cid])

    return Injector(fleet, settings.schedule, settings.points,
                    {"coordinator": coordinator, "carrier": carrier}, threading.Event())


def start_viewer(fleet: Fleet, stop: threading.Event) -> None:
    """``--view``: the viewer, waited for (at most 60 s) until it is subscribed."""
    ready = fleet.out / ".viewer-ready"
    ready.unlink(missing_ok=True)
    viewer = fleet.viewer = fleet.start("viewer", connect=fleet.connect, ready_file=str(ready))
    deadline = time.monotonic() + 60
    while not ready.exists() and viewer.poll() is None and not stop.is_set() and time.monotonic() < deadline:
        stop.wait(0.05)
    ready.unlink(missing_ok=True)
    if viewer.poll() is not None:
        say(fleet.settings, f"the viewer exited with code {viewer.returncode}; going on without it")


def start_carriers(fleet: Fleet) -> None:
    """More routers when the fleet is large (joined to the first, each serving a share of the
    carriers), then the carrier processes."""
    from wire.zconfig import free_port

    f, scenario = fleet.settings.flags, fleet.settings.scenario
    n_routers = f.routers
    if n_routers is None:
        n = scenario.n_carriers
        n_routers = 0 if n <= CARRIERS_PER_ROUTER or not fleet.listen else -(-n // CARRIERS_PER_ROUTER)
    for _ in range(n_routers):
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        fleet.routers.append(fleet.start("router", listen=[endpoint], connect=fleet.connect))
        fleet.router_endpoints.append(endpoint)
    endpoints = fleet.router_endpoints
    # a schedule strikes one carrier at a time: one process per carrier
    processes = scenario.n_carriers if fleet.settings.schedule else f.carrier_processes
    for g, group in enumerate(carrier_groups(scenario.carrier_ids, processes)):
        start_carrier(fleet, ",".join(group), [endpoints[g % len(endpoints)]] if endpoints else fleet.connect)


def start_carrier(fleet: Fleet, cids: str, via: list[str]) -> None:
    """The carrier process of ``cids`` (``id,id,...``), connecting to ``via``."""
    f = fleet.settings.flags
    fleet.via[cids] = via
    fleet.carriers[cids] = fleet.start("carrier", preexec=carrier_child, carrier=cids, connect=via,
                                       log_sync=f.log_sync or "normal", quiet=not f.verbose)


def slow_links_note(settings: Settings) -> str | None:
    """The line that tells a user a mission over acoustic links runs for minutes of wall time
    (the fleet waits on its simulated links for real: each stage's messages queue on one
    half-duplex channel, and a lost one is waited for up to ``decision_s``), and the fast way to
    see the same mission; None over other links."""
    scenario = settings.scenario
    if scenario is None or scenario.links.model != "acoustic":
        return None
    wait = settings.timeouts().decision_s
    return (f"acoustic links: the fleet waits for its messages in wall time, so this mission takes minutes "
            f"(a lost message is waited for up to {wait:.0f} s; scenarios/marine_survey.yaml takes about 8 to 9 "
            f"minutes); the same mission in seconds in the deterministic simulator: python -m mission.simulate "
            f"{scenario.source or 'SCENARIO'} --seeds 0:1 --faults none --json OUT.json (its reward and deployments)")


def announce(fleet: Fleet) -> None:
    f = fleet.settings.flags
    note = slow_links_note(fleet.settings)
    if note:
        print(f"{f.name}: {note}", flush=True)
    shown = ", ".join(f"{_short(cids)} pid {p.pid}" for cids, p in fleet.carriers.items())
    coordinator, viewer = fleet.coordinator, fleet.viewer
    print(f"{f.name}: network {', '.join(fleet.connect)}"
          + (f" (router pid {fleet.routers[0].pid})" if fleet.listen else "")
          + ("; no coordinator (decentralised)" if coordinator is None else f"; coordinator pid {coordinator.pid}")
          + f"; carriers {shown}"
          + (f"; {len(fleet.router_endpoints)} more router(s) at {', '.join(fleet.router_endpoints)}"
             if fleet.router_endpoints else ""),
          flush=True)
    if viewer is not None and viewer.poll() is None and not f.no_web:
        from viewer.node import viewer_url

        print(f"{f.name}: viewer pid {viewer.pid}; live view at {viewer_url(f.web_port, f.grpc_port)}", flush=True)


def supervise(fleet: Fleet, stop: threading.Event) -> None:
    """Until the mission is over or a stop request. The mission lasts as long as its
    coordinator; decentralised, or when the coordinator died, as long as its carriers (they go
    on without it)."""
    carriers = fleet.carriers
    refused = set()
    while not stop.is_set():
        coordinator = fleet.coordinator  # a schedule's takeover or restart replaces it
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
                say(fleet.settings, f"carrier process {_short(cids)} exited with code {EXIT_USAGE} (refused: a "
                                    f"duplicate or another world, reason above); the mission goes on without it")
        stop.wait(0.05)


def without_coordinator(fleet: Fleet, code: int, stop: threading.Event) -> int:
    """The coordinator refused to start (``EXIT_USAGE``: a live coordinator of the mission, so
    nobody decides: carriers stopped) or was deposed (``EXIT_DEPOSED``: a newer coordinator
    decides now, our carriers fly on under it)."""
    if code == EXIT_USAGE:
        stop_children(fleet.others(), grace_s=5.0)
        say(fleet.settings, f"the coordinator refused to start (exit {code}, reason above); carriers stopped")
        return code
    say(fleet.settings, f"the coordinator was deposed by a coordinator of a newer epoch (exit {code}); the "
                        f"carriers go on under that one, whose --out holds the results")
    while any(p.poll() is None for p in fleet.carriers.values()) and not stop.is_set():
        stop.wait(0.1)
    stop_children(fleet.others(), grace_s=5.0)
    return code


def finish(fleet: Fleet, code: int, started: float, stop: threading.Event) -> int:
    """After the mission: the carriers' grace, the report, the result lines, the viewer's linger."""
    settings, carriers, out = fleet.settings, fleet.carriers, fleet.out
    deadline = time.monotonic() + CARRIER_EXIT_GRACE_S
    while time.monotonic() < deadline and any(p.poll() is None for p in carriers.values()):
        time.sleep(0.05)
    stop_children(list(carriers.values()), grace_s=5.0)
    stop_children(fleet.routers + ([fleet.standby] if fleet.standby is not None else []), grace_s=5.0)
    bad = {cid: p.returncode for cid, p in carriers.items() if p.returncode not in (0,)}
    if bad:
        say(settings, f"carrier exit codes {bad}")
    report(fleet)  # summary.json from whatever logs exist, also when the coordinator died
    summary_path = out / "summary.json"
    if code != 0 or not summary_path.exists():
        say(settings, f"the coordinator exited with code {code}" if fleet.coordinator is not None
            else "no summary.json (the report failed)")
        if fleet.viewer is not None:
            stop_children([fleet.viewer], grace_s=5.0)
        return code or 1
    print_results(settings, json.loads(summary_path.read_text()), out, started)
    if fleet.viewer is not None:
        wait_for_viewer(settings, fleet.viewer, stop)
    return 0


def print_results(settings: Settings, summary: dict, out: Path, started: float) -> None:
    f = settings.flags
    from mission.summary import bound_text

    lat = summary.get("latency_ms", {})
    told = bound_text(summary)  # a percentage only against a bound that means one
    if summary.get("reward") == "coverage":  # the features in the union of the discs (maximum coverage bound)
        told = f"coverage reward over {summary['coverage']['regions']} regions; {told}"
    print(f"total reward {summary['total_reward']:.3f} (features {summary['total_features']:.1f}); "
          f"{told}; decision round trip p50 "
          f"{_ms(lat.get('p50'))} p99 {_ms(lat.get('p99'))}; wall {time.monotonic() - started:.1f} s "
          f"(the whole run; the coordinator's {summary.get('wall_time_s', 0.0):.1f} s is summary.json's wall_time_s)")
    print(f"results: {out}/summary.json, mission.db, merged_log.jsonl"
          + ("" if f.no_record else ", ros2bag/" if f.mcap_profile == "ros2" else ", mission.mcap")
          + ("" if f.no_map else ", map.png"))


def report(fleet: Fleet) -> int:
    """After the mission: ``--role report`` on the results directory (a child like the others,
    SIGINT ignored so a late Ctrl-C cannot cut it half-way; its files are replaced atomically)."""
    argv = [sys.executable, *child_argv(fleet.settings.flags, "report", out=str(fleet.out))]
    try:
        return subprocess.run(argv, env=child_env(), preexec_fn=ignore_sigint, timeout=300).returncode
    except subprocess.TimeoutExpired:
        say(fleet.settings, "the report did not finish in 300 s")
        return 1


def wait_for_viewer(settings: Settings, viewer, stop: threading.Event) -> None:
    """The mission is over; the viewer keeps serving (``--linger``) until it exits or Ctrl-C."""
    from viewer.node import viewer_url

    f = settings.flags
    if viewer.poll() is None and not f.no_web:
        print(f"{f.name}: the live view stays at {viewer_url(f.web_port, f.grpc_port)}"
              + (" until Ctrl-C" if f.linger < 0 else f" for {f.linger:g} s"), flush=True)
    while viewer.poll() is None and not stop.is_set():
        stop.wait(0.1)
    stop_children([viewer], grace_s=5.0)


def _ms(value) -> str:
    return "-" if value is None else f"{value:.1f} ms"


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


def taken(settings: Settings, connect) -> str | None:
    """Through a router another mission with this id may be live: the one line a process of ours
    would refuse with (a live coordinator, live carriers of our ids), or None. One liveliness
    query over a short-lived session, before the launcher starts anything."""
    from carriers.process import DuplicateCarriers, live_duplicates
    from coordinator.epochs import DuplicateCoordinator
    from mission.timeouts import DEFAULTS
    from wire import keys
    from wire.transport import Node
    from wire.zconfig import make_config

    f, scenario = settings.flags, settings.scenario
    mission = f.mission or keys.mission_id_from_name(scenario.name)
    conf = lambda: make_config("client", [], connect, f.zenoh_config)  # noqa: E731
    probe = Node(conf(), open_timeout_s=10.0)
    try:
        if probe.live_tokens(keys.coordinator_alive(mission), DEFAULTS.liveliness_check_s):
            return str(DuplicateCoordinator(mission))
    finally:
        probe.close(DEFAULTS.close_s)
    ids = live_duplicates(mission, scenario.carrier_ids, conf, open_timeout_s=10.0)
    return str(DuplicateCarriers(mission, ids)) if ids else None
