"""``marsupial-fleet``: the installed command (``[project.scripts]``), one subcommand per command
line of the project. Each subcommand hands the rest of its arguments to that command line's own
``main``, imported only when it runs, so ``marsupial-fleet X ARGS`` is ``python -m MODULE ARGS``:

    marsupial-fleet run six_carriers               # python run_fleet.py (a file or a bundled scenario)
    marsupial-fleet solve INSTANCE.json            # python -m coordinator.solve
    marsupial-fleet world check S.yaml             # python -m world (check, render, import)
    marsupial-fleet experiments all                # python -m experiments
    marsupial-fleet record rebuild RUN_DIR         # python -m recording
    marsupial-fleet conformance carrier S.yaml --carrier a -- COMMAND   # python -m wire.conformance
    marsupial-fleet conformance coordinator S.yaml -- COMMAND          # python -m wire.conformance coordinator
    marsupial-fleet conformance planner package.module:Factory         # python -m planner.conformance
"""
from __future__ import annotations

import argparse
import inspect
import sys

from mission.exits import EXIT_USAGE
from validation import did_you_mean

#: The command's name (its messages start with it).
PROG = "marsupial-fleet"
#: Subcommand -> (what it runs, its one-line help).
COMMANDS = {
    "run": ("run_fleet.py", "run a mission: a scenario file or a bundled scenario's name, then run_fleet.py's flags"),
    "solve": ("python -m coordinator.solve", "plan one JSON instance offline and print the result"),
    "world": ("python -m world", "scenario tools: check, render, import"),
    "experiments": ("python -m experiments", "the paper's experiments, and check of published results"),
    "record": ("python -m recording", "mission recordings: rebuild mission.mcap from mission.db"),
    "conformance": ("python -m wire.conformance | python -m planner.conformance",
                    "conformance kits: 'carrier' or 'coordinator' (a peer on the wire), 'planner' (a planner plug-in)"),
}
#: ``conformance``'s kits.
KITS = ("carrier", "coordinator", "planner")


def build_parser() -> argparse.ArgumentParser:
    """The top level's help: the subcommands (each subcommand parses its own arguments)."""
    p = argparse.ArgumentParser(prog=PROG, description="Plan and fly marsupial robot fleets.",
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog="Each subcommand takes --help. See README.md, \"Installed as a command\".")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    for name, (runs, text) in COMMANDS.items():
        sub.add_parser(name, help=f"{text} ({runs})", add_help=False)
    return p


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        build_parser().print_help()
        return 0 if argv else EXIT_USAGE
    command, rest = argv[0], argv[1:]
    if command not in COMMANDS:
        print(f"{PROG}: expected a command ({', '.join(COMMANDS)}), found {command!r}", file=sys.stderr)
        return EXIT_USAGE
    return {"run": _run, "solve": _solve, "world": _world, "experiments": _experiments, "record": _record,
            "conformance": _conformance}[command](rest)


def _run(argv: list[str]) -> int:
    from launcher.main import main as launch

    return launch(argv, prog=f"{PROG} run", name=PROG)


def _solve(argv: list[str]) -> int:
    from coordinator.solve import main as solve

    return _call(solve, argv, f"{PROG} solve")


def _world(argv: list[str]) -> int:
    from launcher.scenario_check import world_command

    return world_command(argv)


def _experiments(argv: list[str]) -> int:
    from experiments.__main__ import main as experiments

    return experiments(argv)


def _record(argv: list[str]) -> int:
    from recording.__main__ import main as record

    return record(argv)


def _conformance(argv: list[str]) -> int:
    """The kit named first; anything else is the carrier kit's arguments (the default kit, as for
    ``python -m wire.conformance``), unless it reads as a misspelt kit name."""
    if argv and argv[0] in ("-h", "--help"):
        print(f"usage: {PROG} conformance [{{{','.join(KITS)}}}] ARGS (each kit takes --help; the carrier kit "
              "is the default)")
        return 0
    misspelt = bool(argv) and argv[0] not in KITS and not argv[0].startswith("-")
    hint = did_you_mean(argv[0], KITS, cutoff=0.75) if misspelt else ""
    if not argv or hint:
        found = repr(argv[0]) if argv else "nothing"
        print(f"{PROG} conformance: expected a kit ({', '.join(KITS)}){hint}, found {found}", file=sys.stderr)
        return EXIT_USAGE
    if argv[0] not in KITS or argv[0] == "carrier":
        from wire.conformance import main as carrier_kit

        return carrier_kit(argv[1:] if argv[0] == "carrier" else argv)
    if argv[0] == "coordinator":
        from wire.conformance.cli import coordinator_main

        return coordinator_main(argv[1:], prog=f"{PROG} conformance coordinator")
    kit = _planner_kit()
    if kit is None:
        print(f"{PROG} conformance planner: the planner conformance kit (planner.cli.conformance) is not installed "
              f"in this version", file=sys.stderr)
        return EXIT_USAGE
    return _call(kit, argv[1:], f"{PROG} conformance planner")


def _planner_kit():
    """The planner conformance kit's ``main``, or None when this version has none."""
    try:
        from planner.cli.conformance import main as kit
    except ImportError as exc:
        if exc.name not in ("planner.cli", "planner.cli.conformance"):
            raise  # the kit is there and something it needs is not: let that be seen
        return None
    return kit


def _call(main, argv: list[str], prog: str) -> int:
    """``main(argv)``, and ``prog=prog`` too when it names itself by a ``prog`` parameter."""
    if "prog" in inspect.signature(main).parameters:
        return main(argv, prog=prog)
    return main(argv)
