"""The kit's command line: ``python -m wire.conformance SCENARIO --carrier ID [options] -- COMMAND
[ARGS...]`` (also reached through the ``marsupial-fleet`` command, which passes its own ``prog``)."""
from __future__ import annotations

import argparse
import sys
import textwrap
from pathlib import Path

from .faults import FAULT_TEXT, FAULTS
from .harness import PLACEHOLDERS
from .kit import Kit
from .report import passed, table, verdict
from .rules import RULES

PROG = "python -m wire.conformance"
WIDTH = 100  # columns of the help's own paragraphs and tables


def _entry(name: str, text: str, column: int) -> str:
    """``name`` then ``text`` wrapped at :data:`WIDTH`, continuation lines under the text."""
    return textwrap.fill(text, WIDTH, initial_indent=f"  {name:<{column - 3}} ", subsequent_indent=" " * column)


def _epilog() -> str:
    told = "\n".join(f"  {variable:<20} {'{' + name + '}':<12} {meaning}" for variable, name, meaning in PLACEHOLDERS)
    faults = "\n".join(_entry(name, text, 14) for name, text in FAULT_TEXT.items())
    rules = "\n".join(_entry(rule, f"{text} ({section})", 28) for rule, section, text in RULES)
    return f"""\
COMMAND, the carrier under test, connects to the kit's router in zenoh client mode. It is told
where and who it is by environment variables, and by placeholders the kit replaces in ARGS:
{told}

faults (--faults; all by default):
{faults}

rules (one report line each: times exercised, pass, FAIL with the first message that broke it,
or - when not exercised; docs/protocol.md, "Conformance kit"):
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
            "Fly a third-party carrier (COMMAND, everything after '--') with the project's coordinator and the "
            "scenario's other carriers on a zenoh router of the kit's own (tcp/127.0.0.1, a free port, multicast "
            "scouting off), make deliberate faults, and check the carrier against docs/protocol.md, rule by rule.",
            WIDTH))
    parser.add_argument("scenario", metavar="SCENARIO", help="scenario YAML file")
    parser.add_argument("--carrier", required=True, metavar="ID", help="the id the carrier under test flies as")
    parser.add_argument("--seed", type=int, help="root seed (overrides the scenario's)")
    parser.add_argument("--faults", default=",".join(FAULTS), metavar="LIST",
                        help=f"comma-separated faults to make (default all: {','.join(FAULTS)}; 'none' for none)")
    parser.add_argument("--late", type=float, default=3.0, metavar="SECONDS",
                        help="seconds the late Decision is late (default 3)")
    parser.add_argument("--timeout", type=float, default=180.0, metavar="SECONDS",
                        help="longest mission, seconds (default 180): counted from the carrier under test's "
                             "start; then the kit stops watching, gives COMMAND one more second to exit "
                             "(else kills it) and judges what it saw")
    parser.add_argument("--workdir", metavar="DIR",
                        help="where the coordinator's results (DIR/run) and the logs (DIR/coordinator.log, "
                             "DIR/carriers.log) go, and COMMAND's own files ({workdir} = DIR/carrier); "
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
        return Kit(args.scenario, args.carrier, command, args.seed, faults, args.late, args.timeout, args.workdir)
    except ValueError as exc:
        parser.error(str(exc))


def main(argv: list[str] | None = None, prog: str = PROG) -> int:
    """Run the kit on ``argv`` (default ``sys.argv[1:]``); returns the exit status: 0 pass, 1 fail,
    2 usage error (one line on stderr after the usage), 0 after ``--help``."""
    argv = list(sys.argv[1:] if argv is None else argv)
    split = argv.index("--") if "--" in argv else len(argv)
    own, command = argv[:split], argv[split + 1:]
    parser = build_parser(prog)
    try:
        kit = _kit(parser, parser.parse_args(own), command)
    except SystemExit as exc:  # argparse's way out of --help and of a usage error
        return int(exc.code or 0)
    results = kit.run()
    print(table(results), flush=True)
    print(verdict(results, kit.target.cid, kit.flight.exit_code, kit.workdir), flush=True)
    return 0 if passed(results) else 1
