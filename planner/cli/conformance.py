"""Check a planner plug-in against the planner protocol (the kit is :mod:`planner.conformance`).

    python -m planner.conformance PLANNER [--option KEY=VALUE ...] [--seed S] [--instances N] [--json OUT]

``PLANNER``: an installed plug-in's entry-point name (group ``marsupial_fleet.planners``),
``package.module:Factory``, or a built-in planner's name. Prints one line per check (pass, FAIL
with its named reason, or not applicable) and a verdict. ``--json OUT`` writes the report as one
JSON object (``planner``, ``options``, ``seed``, ``instances``, ``families``, ``passed``,
``checks``: ``name``, ``outcome``, ``reason``, ``detail``).

Exit status: 0 every check passed (or does not apply); 2 a check failed, with one line on
stderr naming the plug-in and the rule it broke (its first failed check's reason), or a usage
error (bad arguments, a name that does not load, an option the registry refuses, an unwritable
``--json``), with one line on stderr.
"""
from __future__ import annotations

import json
import sys
from typing import Sequence

from planner.cli import EXIT_USAGE, OneLineParser, integer_at_least

PROG = "python -m planner.conformance"
EXIT_OK, EXIT_FAILED = 0, EXIT_USAGE  # a broken plug-in is bad input: one line, exit 2


def build_parser(prog: str = PROG) -> OneLineParser:
    from planner import conformance

    parser = OneLineParser(prog=prog, description="Check a planner plug-in against the planner protocol on "
                           f"generated instances ({', '.join(conformance.FAMILIES)}).")
    parser.add_argument("planner", metavar="PLANNER",
                        help="an entry-point name (marsupial_fleet.planners), package.module:Factory, or a built-in")
    parser.add_argument("--option", action="append", default=[], metavar="KEY=VALUE",
                        help="an option of the planner (its own or a built-in it uses), repeatable")
    parser.add_argument("--seed", type=integer_at_least(0), default=0, help="root seed of the instances and the missions (default 0)")
    parser.add_argument("--instances", type=integer_at_least(1), default=2, metavar="N",
                        help="instances per family (default 2)")
    parser.add_argument("--json", metavar="OUT", help="write the report as JSON to OUT")
    return parser


def main(argv: Sequence[str] | None = None, prog: str = PROG) -> int:
    """Run the kit on ``argv`` (``sys.argv[1:]`` when None); ``prog`` names the command in its
    messages. Returns the exit status."""
    from planner import conformance, registry

    args = build_parser(prog).parse_args(argv)
    try:
        registry.entry(args.planner)
    except registry.PluginNotFound as err:
        return _usage(prog, f"PLANNER: {err}")
    except registry.PluginError:
        pass  # a bad declaration: the kit's first check reports it
    except ValueError:
        return _usage(prog, f"PLANNER: expected an entry-point name, package.module:Factory or one of "
                            f"{', '.join(sorted(registry.known_names()))}, found {args.planner!r}")
    options = {}
    for text in args.option:
        try:
            key, value = registry.parse_option(text, args.planner)
        except registry.PluginError:
            key, value = _raw(text)  # a bad declaration: the option is reported with it
        except ValueError as err:
            return _usage(prog, f"--option: {err}")
        options[key] = value
    try:
        report = conformance.check_planner(args.planner, options, seed=args.seed, count=args.instances)
    except ValueError as err:
        return _usage(prog, f"--option: {' '.join(str(err).split())}")
    width = max(len(c.name) for c in report.checks)
    for check in report.checks:
        mark = {"pass": "pass", "fail": "FAIL", "not-applicable": "n/a "}[check.outcome]
        reason = f"[{check.reason}] " if check.reason else ""
        print(f"{mark}  {check.name:<{width}}  {reason}{check.detail}")
    failures = report.failures
    if failures:
        print(f"planner {args.planner!r}: {len(failures)} check(s) failed: "
              + ", ".join(f"{c.name} ({c.reason})" for c in failures))
    else:
        print(f"planner {args.planner!r}: conformant ({len(report.checks)} checks)")
    if args.json:
        try:
            with open(args.json, "w", encoding="utf-8") as out:
                json.dump(report.to_dict(), out, indent=1)
                out.write("\n")
        except OSError as err:
            return _usage(prog, f"--json: cannot write {args.json}: {err.strerror or err}")
    if failures:
        first = failures[0]
        print(f"{prog}: planner {args.planner!r} broke rule {first.reason} (check {first.name}): {first.detail}",
              file=sys.stderr)
        return EXIT_FAILED
    return EXIT_OK


def _raw(text: str) -> tuple[str, str]:
    key, _, value = text.partition("=")
    return key.strip().replace("-", "_"), value


def _usage(prog: str, message: str) -> int:
    print(f"{prog}: error: {message}", file=sys.stderr)
    return EXIT_USAGE


if __name__ == "__main__":
    sys.exit(main())
