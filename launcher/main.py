"""The launcher's entry point: parse, load the scenario, check, run the role.

    python run_fleet.py scenarios/six_carriers.yaml      # the script, from a clone
    python -m launcher scenarios/six_carriers.yaml       # the package
    marsupial-fleet run six_carriers                     # the installed command (launcher.cli)

:func:`run` returns the exit status; :func:`main` is a process's whole life: for the roles of
:data:`launcher.HARD_EXIT_ROLES` it ends the process itself once the role returned."""
from __future__ import annotations

import os
import sys

from launcher import HARD_EXIT_ROLES, NAME
from mission.exits import EXIT_USAGE


def run(argv=None, prog: str = NAME, name: str = NAME, role: list | None = None) -> int:
    """Run the launcher's command line ``argv`` (default ``sys.argv[1:]``); ``prog`` is shown in
    usage lines, ``name`` starts the messages. ``role``, when given, receives the role as soon as
    it is parsed (so that :func:`main` knows how to end the process even after an exception)."""
    from launcher import roles, supervisor
    from launcher.flags import parse_args
    from launcher.settings import check, load_scenario
    from launcher.signals import install_stop_handlers
    from wire.zconfig import ConfigError

    stop = install_stop_handlers()  # first: a signal from here on is a stop request, never an exception
    args = parse_args(argv, prog, name)
    if role is not None:
        role.append(args.role)
    scenario = None
    if args.role != "router":
        if args.scenario is None:
            return _fail(args.name, ["the scenario file is required (except with --role router)"])
        scenario, lines = load_scenario(args.scenario)
        if scenario is None:
            return _fail(None, lines)
    settings, problems = check(args, scenario)
    if settings is None:
        return _fail(args.name, [p.line() for p in problems])
    mains = {"coordinator": roles.coordinator, "carrier": roles.carrier, "router": roles.router,
             "viewer": roles.viewer, "report": roles.report, "all": supervisor.main}
    try:
        return mains[args.role](settings, stop)
    except ConfigError as exc:
        return roles.refuse(settings, str(exc))


def _fail(name: str | None, lines: list[str]) -> int:
    """Each line on stderr (after ``name:`` when given); :data:`EXIT_USAGE`."""
    for line in lines:
        print(f"{name}: {line}" if name else line, file=sys.stderr)
    return EXIT_USAGE


def main(argv=None, prog: str = NAME, name: str = NAME) -> int:
    """:func:`run` as a process: for a coordinator, carrier or router, an exception is printed
    and the process ends with ``os._exit`` (returning into the interpreter's shutdown would wait
    for zenoh's callback threads, which are not daemons, for ever)."""
    role: list = []
    try:
        code = run(argv, prog, name, role)
    except Exception:
        if not set(role) & set(HARD_EXIT_ROLES):
            raise
        import traceback

        traceback.print_exc()
        code = 1
    if set(role) & set(HARD_EXIT_ROLES):
        # Everything is closed and written by now (sessions, mission.db, logs, mission.mcap). Skip
        # the interpreter's finalisation: a foreign thread re-entering Python during it (zenoh's
        # callback threads, the on-board planner's loader) aborted a process now and then
        # ("FATAL: exception not rethrown", exit -6).
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code if isinstance(code, int) else 1)
    return code
