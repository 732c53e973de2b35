"""One ``main(settings, stop)`` per process role: build the role's config from the settings, run
it, turn how it ended into the process's exit status. Each is the shape of a zenoh-python example
program (open, run, close); the work is in the packages below."""
from __future__ import annotations

import os
import sys
import threading
from pathlib import Path

from launcher.settings import Settings, operator_settings, zenoh_config
from mission.exits import EXIT_DEPOSED, EXIT_USAGE, STOPPED
from mission.modes import Mode


def say(settings: Settings, message: str) -> None:
    """One line on stderr, starting with the launcher's name."""
    print(f"{settings.name}: {message}", file=sys.stderr, flush=True)


def refuse(settings: Settings, message: str) -> int:
    """:func:`say` the reason a process refuses to run, and return :data:`EXIT_USAGE`."""
    say(settings, message)
    return EXIT_USAGE


def coordinator(settings: Settings, stop: threading.Event) -> int:
    """The coordinator: 0 when every stage was decided and End published, ``EXIT_DEPOSED`` when a
    newer coordinator took over, ``STOPPED`` when stopped first."""
    from coordinator.epochs import DuplicateCoordinator
    from coordinator.node import Coordinator, CoordinatorConfig
    from planner.jitcache import report_compiles
    from storage.missiondb import EpochsExhausted, StoreBusy, StoreMismatch

    f, t = settings.flags, settings.timeouts()
    coord = Coordinator(settings.scenario, CoordinatorConfig(
        out_dir=settings.out(), mission=f.mission, planner=f.planner, iterations=f.iterations, plan_ms=f.plan_ms,
        planner_options=settings.planner_options, seed=f.seed, realtime=f.realtime,
        join_timeout_s=t.join_s, clock=f.clock, stage_timeout_s=t.stage_s,
        silence_timeout_s=t.silence_s, render=not f.no_map, record=not f.no_record,
        record_profile=f.mcap_profile, ros2=settings.ros2(),
        # Wall clock: the last stage's Confirms take a round trip, which grows with the fleet's
        # load as the observations' arrival does, so the stage timeout bounds it too.
        confirm_timeout_s=max(t.confirm_s, t.stage_s), standby=f.standby, bye_timeout_s=t.bye_s,
        coordinator_id=f.coordinator_id,
        rejoin_timeout_s=t.rejoin_s, end_repeat_s=t.end_repeat_s, bye_grace_s=t.bye_grace_s,
        operator=operator_settings(settings)),
        zenoh_config(f, "coordinator"), scenario_path=f.scenario, stop=stop)
    # A kernel compiled on this machine for the first time takes seconds: say which (planner/jitcache.py).
    report_compiles(lambda line: coord.setup.log(f"coordinator: {line}"))
    unavailable: tuple = ()  # operator mode: a console that cannot be served is refused like a bad flag
    if f.operator:
        from console.server import ConsoleUnavailable

        unavailable = (ConsoleUnavailable,)
    try:
        summary = coord.run()
    except (StoreMismatch, DuplicateCoordinator, EpochsExhausted, *unavailable) as exc:
        return refuse(settings, str(exc))
    except StoreBusy as exc:  # stopped while waiting for another process's lock
        say(settings, f"{exc}; stopped while waiting for it")
        return STOPPED
    if summary.get("deposed_by") is not None:
        return EXIT_DEPOSED
    return 0 if summary.get("ended") and summary["stages_decided"] == summary["stages"] else STOPPED


def carrier(settings: Settings, stop: threading.Event) -> int:
    """One or several carriers (``--carrier a,b,c``) in this process: one thread per carrier,
    sharing the scenario and one Zenoh session. Exit status: the first non-zero carrier's."""
    from carriers.node import EXIT_CODES, CarrierConfig
    from carriers.process import DuplicateCarriers, run_carriers
    from mission.timeouts import pose_interval
    from planner.jitcache import report_compiles
    from planner.registry import planner_settings
    from wire.zconfig import ConfigError

    f, scenario, t = settings.flags, settings.scenario, settings.timeouts()
    log = (lambda line: None) if f.quiet else (lambda line: print(line, flush=True))
    report_compiles(None if f.quiet else (lambda line: log(f"carriers {','.join(settings.carriers)}: {line}")))
    mode = Mode.DECENTRALISED if f.decentralised else Mode.COORDINATED if f.no_autonomy else Mode.HYBRID
    _, options = planner_settings(scenario, None, f.iterations, f.plan_ms, settings.planner_options)
    poses = pose_interval(scenario.stage_interval, f.realtime) if f.pose_interval is None else f.pose_interval
    out = settings.out()  # its log: pass the same --out again to resume from it
    configs = [CarrierConfig(
        carrier=cid, mission=f.mission, seed=f.seed, realtime=f.realtime, clock=f.clock,
        silence_timeout_s=t.silence_s, decision_timeout_s=t.decision_s, end_timeout_s=t.end_s,
        coordinator_timeout_s=t.coordinator_s, log=log, pose_interval_s=poses, mode=mode, out_dir=out,
        peer_timeout_s=t.peer_s, join_timeout_s=t.join_s, hello_timeout_s=t.hello_s,
        planner_options=tuple(sorted(options.items())),
        log_sync=f.log_sync or "full", onboard_load=f.onboard_load, ros2=settings.ros2())
        for cid in settings.carriers]
    try:
        reasons = run_carriers(scenario, configs, lambda: zenoh_config(f, "carrier"), stop=stop)
    except DuplicateCarriers as exc:
        return refuse(settings, str(exc))
    except ConfigError as exc:  # nobody to connect to
        say(settings, str(exc))
        return EXIT_CODES["coordinator-lost"]
    codes = []
    for cid, reason in reasons.items():
        if reason not in ("end", "finished"):
            print(f"carrier {cid}: exiting ({reason})", file=sys.stderr, flush=True)
        codes.append(EXIT_CODES.get(reason, 1))
    return next((c for c in codes if c != 0), 0)


def router(settings: Settings, stop: threading.Event) -> int:
    """A zenoh router (mode ``router``) for fleets across hosts: coordinators and carriers of any
    number of missions connect to it as clients; missions stay apart by their key prefix
    ``marsupial/<mission>/``. Runs until SIGINT/SIGTERM."""
    from wire.zconfig import close_session, open_session

    session = open_session(zenoh_config(settings.flags, "router"), 10.0, stop=stop)
    where = ", ".join(settings.flags.listen) or "the config's endpoints"
    print(f"{settings.name}: zenoh router pid {os.getpid()} listening on {where}", flush=True)
    try:
        while not stop.wait(0.2):
            pass
    finally:
        close_session(session, (), 3.0)
    return 0


def report(settings: Settings, stop: threading.Event | None = None) -> int:
    """summary.json, merged_log.jsonl and map.png from the logs in ``--out`` (coordinator/report.py):
    one line with the totals and the files; a one-line error and ``EXIT_USAGE`` when it cannot
    be made. It runs to the end whatever ``stop`` says (its files are replaced atomically)."""
    from coordinator.report import ReportError, run_report

    f = settings.flags
    try:
        result = run_report(settings.scenario, f.out, mission=f.mission, seed=f.seed, scenario_path=f.scenario,
                            render=not f.no_map, log=lambda line: say(settings, line))
    except ReportError as exc:
        return refuse(settings, str(exc))
    print(result.line(Path(f.out)), flush=True)
    return 0


def viewer_linger(f) -> float:
    """How long the viewer serves after the mission ends (s; < 0: until Ctrl-C): ``--linger``,
    except that a viewer without its web view (``--no-web``, the file of ``--save`` only) has
    nothing left to serve and exits once the file is written."""
    return 0.0 if f.no_web else f.linger


def viewer(settings: Settings, stop: threading.Event) -> int:
    """A passive live view in rerun (viewer/node.py) until the mission ends and ``--linger``."""
    from viewer.node import Viewer, ViewerConfig

    f = settings.flags
    view = Viewer(settings.scenario, ViewerConfig(
        mission=f.mission, seed=f.seed, web=not f.no_web, web_port=f.web_port, grpc_port=f.grpc_port,
        save=f.save, linger_s=viewer_linger(f), open_timeout_s=settings.timeouts().coordinator_s,
        ready_file=f.ready_file), zenoh_config(f, "viewer"), stop=stop)
    try:
        return view.run()
    except RuntimeError as exc:  # the rerun server could not start (a port in use, no binary)
        print(f"viewer: {exc}", file=sys.stderr, flush=True)
        return 1
