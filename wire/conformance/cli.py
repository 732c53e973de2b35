"""The kits' command line (also reached through the ``marsupial-fleet`` command, which passes its
own ``prog``):

    python -m wire.conformance [carrier] SCENARIO --carrier ID [options] -- COMMAND [ARGS...]
    python -m wire.conformance coordinator [SCENARIO] [options] -- COMMAND [ARGS...]

The carrier kit is the default (no subcommand: its documented spelling of before)."""
from __future__ import annotations

import argparse
import sys
import textwrap
from pathlib import Path

from .. import messages as wm
from . import coordflight
from .coordkit import CoordinatorKit
from .coordrules import COORDINATOR_RULES
from .faults import FAULT_TEXT, FAULTS
from .harness import PLACEHOLDERS
from .kit import FLIGHT_TEXT, FLIGHTS, Kit
from .report import passed, table, verdict
from .rules import RULES

PROG = "python -m wire.conformance"
#: The kits a first argument names; anything else is the carrier kit's SCENARIO.
KITS = ("carrier", "coordinator")
WIDTH = 100  # columns of the help's own paragraphs and tables


def _entry(name: str, text: str, column: int) -> str:
    """``name`` then ``text`` wrapped at :data:`WIDTH`, continuation lines under the text."""
    return textwrap.fill(text, WIDTH, initial_indent=f"  {name:<{column - 3}} ", subsequent_indent=" " * column)


def _epilog() -> str:
    told = "\n".join(f"  {variable:<20} {'{' + name + '}':<12} {meaning}" for variable, name, meaning in PLACEHOLDERS)
    faults = "\n".join(_entry(name, text, 14) for name, text in FAULT_TEXT.items())
    flights = "\n".join(_entry(name, text, 20) for name, text in FLIGHT_TEXT.items())
    rules = "\n".join(_entry(rule, f"{text} ({section})", 28) for rule, section, text in RULES)
    return f"""\
COMMAND, the carrier under test, connects to the kit's router in zenoh client mode. It is told
where and who it is by environment variables, and by placeholders the kit replaces in ARGS:
{told}

flights (--flight; project by default):
{flights}

faults (--faults; all by default; the project flight's only):
{faults}

rules (one report line each: times exercised, pass, FAIL with the first message that broke it,
or - when not exercised; docs/protocol.md, section 11):
{rules}

exit status: 0 when every exercised rule passes, 1 otherwise, 2 for a usage error.

example (the project's own carrier):
  %(prog)s scenarios/tiny.yaml --carrier a -- \\
      python run_fleet.py {{scenario}} --role carrier --carrier {{carrier}} --connect {{endpoint}} \\
      --seed {{seed}} --mission {{mission}} --no-autonomy --out {{workdir}}
"""


def build_parser(prog: str = PROG) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=prog, usage="%(prog)s SCENARIO --carrier ID [options] -- COMMAND [ARGS...]",
        formatter_class=argparse.RawDescriptionHelpFormatter, epilog=_epilog(),
        description=textwrap.fill(
            "Fly a third-party carrier (COMMAND, everything after '--') on a zenoh router of the kit's own "
            "(tcp/127.0.0.1, a free port, multicast scouting off), with the project's coordinator and the "
            "scenario's other carriers (making deliberate faults) or with coordinators the kit plays itself "
            "(--flight), and check the carrier against docs/protocol.md, rule by rule. "
            "This is the default kit ('carrier' may be written first); 'coordinator' checks a coordinator instead "
            "(python -m wire.conformance coordinator --help).",
            WIDTH))
    parser.add_argument("scenario", metavar="SCENARIO", help="scenario YAML file")
    parser.add_argument("--carrier", required=True, metavar="ID", help="the id the carrier under test flies as")
    parser.add_argument("--seed", type=int, help="root seed (overrides the scenario's)")
    parser.add_argument("--faults", default=",".join(FAULTS), metavar="LIST",
                        help=f"comma-separated faults to make in the project flight (default all: "
                             f"{','.join(FAULTS)}; 'none' for none)")
    parser.add_argument("--flight", default="project", choices=FLIGHTS, metavar="FLIGHT",
                        help=f"who the coordinator is: {', '.join(FLIGHTS)} (default project; listed below)")
    parser.add_argument("--revision", type=int, metavar="R",
                        help="the revision the kit's own coordinator speaks in the flights other than project "
                             f"(1..{wm.REVISION}; default {wm.REVISION}, and 1 for older, which takes 1 or 2)")
    parser.add_argument("--late", type=float, default=3.0, metavar="SECONDS",
                        help="seconds the late Decision is late (the project flight's fault late; default 3)")
    parser.add_argument("--timeout", type=float, default=180.0, metavar="SECONDS",
                        help="longest mission, seconds (default 180): counted from the carrier under test's "
                             "start; then the kit stops watching, gives COMMAND one more second to exit "
                             "(else kills it) and judges what it saw")
    parser.add_argument("--workdir", metavar="DIR",
                        help="where the coordinator's results (DIR/run) and the logs (DIR/coordinator.log, "
                             "DIR/carriers.log; the project flight) go, and COMMAND's own files "
                             "({workdir} = DIR/carrier); "
                             "default: a new temporary directory, named in the report's last line")
    return parser


def _kit(parser: argparse.ArgumentParser, args: argparse.Namespace, command: list[str]) -> Kit:
    """The kit the arguments ask for; a usage error exits through ``parser.error``."""
    if not command:
        parser.error("no COMMAND after -- (the carrier under test)")
    faults = () if args.faults == "none" else tuple(x for x in args.faults.split(",") if x)
    bad = [x for x in faults if x not in FAULTS]
    if bad:
        parser.error(f"--faults: unknown fault {bad[0]!r} (one of {', '.join(FAULTS)})")
    if not Path(args.scenario).is_file():
        parser.error(f"scenario: no such file: {args.scenario}")
    try:
        return Kit(args.scenario, args.carrier, command, args.seed, faults, args.late, args.timeout, args.workdir,
                   flight=args.flight, revision=args.revision)
    except ValueError as exc:
        parser.error(str(exc))


def main(argv: list[str] | None = None, prog: str = PROG) -> int:
    """Run the kit ``argv`` names (default ``sys.argv[1:]``; a first ``coordinator`` or ``carrier``
    names it, else the carrier kit); returns the exit status: 0 pass, 1 fail, 2 usage error (one
    line on stderr after the usage), 0 after ``--help``."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == "coordinator":
        return coordinator_main(argv[1:], f"{prog} coordinator" if prog == PROG else prog)
    if argv and argv[0] == "carrier":
        return carrier_main(argv[1:], f"{prog} carrier" if prog == PROG else prog)
    return carrier_main(argv, prog)


def _split(argv: list[str]) -> tuple[list[str], list[str]]:
    """(the kit's own arguments, COMMAND and its ARGS): split at the first ``--``."""
    split = argv.index("--") if "--" in argv else len(argv)
    return argv[:split], argv[split + 1:]


def carrier_main(argv: list[str], prog: str = PROG) -> int:
    """The carrier kit on ``argv``; the exit status as :func:`main`."""
    own, command = _split(argv)
    parser = build_parser(prog)
    try:
        kit = _kit(parser, parser.parse_args(own), command)
    except SystemExit as exc:  # argparse's way out of --help and of a usage error
        return int(exc.code or 0)
    results = kit.run()
    print(table(results), flush=True)
    print(verdict(results, kit.target.cid, kit.flight.exit_code, kit.workdir), flush=True)
    return 0 if passed(results) else 1


# --------------------------------------------------------------------------- the coordinator kit

def _coordinator_epilog() -> str:
    told = "\n".join(f"  {variable:<20} {'{' + name + '}':<12} {meaning}"
                     for variable, name, meaning in coordflight.PLACEHOLDERS)
    faults = "\n".join(_entry(name, text, 15) for name, text in coordflight.FAULT_TEXT.items())
    rules = "\n".join(_entry(rule, f"{text} ({section})", 20) for rule, section, text in COORDINATOR_RULES)
    return f"""\
COMMAND, the coordinator under test, connects to the kit's router in zenoh client mode; it is
started once per flight (main, and takeover when that fault is asked for), each time with a new
router and a new {{workdir}}. It is told where it is by environment variables, and by
placeholders the kit replaces in ARGS:
{told}

The kit plays every carrier of SCENARIO: a liveliness token each, State asked with
?carrier=<id>;revision=<the kit's>, Hello, the Observation of State's next stage, a Confirm for
every Decision (deployed / idle / refused, truthfully), the next Observation at once, Progress
every {coordflight.PROGRESS_S:g} s while waiting, Bye 'end' after End. It never decides a stage itself.

faults (--faults; all by default):
{faults}

rules (one report line each: times exercised, pass, FAIL with the first thing that broke it, or -
when not exercised):
{rules}

exit status: 0 when every exercised rule passes, 1 otherwise, 2 for a usage error.

example (the project's own coordinator):
  %(prog)s scenarios/tiny.yaml -- \\
      python -m launcher {{scenario}} --role coordinator --connect {{endpoint}} --mission {{mission}} \\
      --seed {{seed}} --out {{workdir}} --no-map --no-record --join-timeout 3 --silence-timeout 2 \\
      --stage-timeout 2 --realtime 0

The coordinator runs on the sim clock with timeouts short enough for the flight: the silent
carrier is waited for its silence timeout (a revision-1 one, the stage timeout), the late joiner's
token for the join timeout before stage 0.
"""


def build_coordinator_parser(prog: str = f"{PROG} coordinator") -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=prog, usage="%(prog)s [SCENARIO] [options] -- COMMAND [ARGS...]",
        formatter_class=argparse.RawDescriptionHelpFormatter, epilog=_coordinator_epilog(),
        description=textwrap.fill(
            "Check a coordinator somebody else wrote (COMMAND, everything after '--') against docs/protocol.md: "
            "the kit is the zenoh router (tcp/127.0.0.1, a free port, multicast scouting off) and every carrier "
            "of the scenario, makes deliberate faults, and judges what the coordinator publishes, rule by rule.",
            WIDTH))
    parser.add_argument("scenario", metavar="SCENARIO", nargs="?",
                        help="scenario YAML file, or a bundled scenario's name (default: tiny, 2 carriers, 4 stages)")
    parser.add_argument("--seed", type=int, help="root seed (overrides the scenario's; {seed} tells COMMAND)")
    parser.add_argument("--faults", default=",".join(coordflight.FAULTS), metavar="LIST",
                        help=f"comma-separated faults to make (default all: {','.join(coordflight.FAULTS)}; "
                             "'none' for none)")
    parser.add_argument("--timeout", type=float, default=180.0, metavar="SECONDS",
                        help="longest flight, seconds (default 180), counted from COMMAND's start; then the kit "
                             "stops watching, stops COMMAND (SIGTERM, SIGKILL 10 s later) and judges what it saw")
    parser.add_argument("--workdir", metavar="DIR",
                        help="where COMMAND's files go, one directory per flight ({workdir} = DIR/main, "
                             "DIR/takeover); default: a new temporary directory, named in the report's last line")
    return parser


def _scenario_path(parser: argparse.ArgumentParser, name: str | None) -> str:
    """A scenario file, or a bundled scenario's name (tiny when none is given)."""
    if name is not None and Path(name).is_file():
        return name
    from scenarios import bundled_path

    path = bundled_path(name or "tiny")
    if path is None:
        parser.error(f"scenario: no such file or bundled scenario: {name}")
    return str(path)


def coordinator_main(argv: list[str], prog: str = f"{PROG} coordinator") -> int:
    """The coordinator kit on ``argv``; the exit status as :func:`main`."""
    own, command = _split(argv)
    parser = build_coordinator_parser(prog)
    try:
        args = parser.parse_args(own)
        if not command:
            parser.error("no COMMAND after -- (the coordinator under test)")
        faults = () if args.faults == "none" else tuple(x for x in args.faults.split(",") if x)
        bad = [x for x in faults if x not in coordflight.FAULTS]
        if bad:
            parser.error(f"--faults: unknown fault {bad[0]!r} (one of {', '.join(coordflight.FAULTS)})")
        kit = CoordinatorKit(_scenario_path(parser, args.scenario), command, args.seed, faults, args.timeout,
                             args.workdir)
    except SystemExit as exc:  # argparse's way out of --help and of a usage error
        return int(exc.code or 0)
    results = kit.run()
    print(table(results, COORDINATOR_RULES), flush=True)
    codes = ", ".join(f"{f.name} exit code {f.exit_code}" for f in kit.flights)
    print(f"conformance: {'PASS' if passed(results) else 'FAIL'} (coordinator: {codes}; files in {kit.workdir})",
          flush=True)
    return 0 if passed(results) else 1
