"""Run one planner online over one instance file and print the outcome as one JSON object.

    python -m planner.cli.solve INSTANCE.json --planner NAME [--planner-option KEY=VALUE ...] [--iterations K] [--plan-ms MS]
                              [--seed S] [--exploration C] [--samples M] [--layout L]
                              [--learn-prior [true|false]] [--no-clairvoyant] [--no-online-optimum]
                              [--no-upper-bound] [--message-loss P] [--message-delay K] [--groups 0,1/2,3]

A thin command line: planner names, options, their ranges and defaults come from
:mod:`planner.registry` (one flag per built-in option; ``--planner-option KEY=VALUE`` for any
option by name, a plug-in's own ones included), the work from :func:`planner.solve.solve_instance`.
``--planner`` takes a plug-in too: an entry point's name or ``package.module:Factory``.

Output (stdout, one JSON object)::

    {"planner": NAME, "seed": S, "deployments": [[stage, ...] per carrier],
     "reward": normalised total with penalties, "features": raw total (sum of x / p),
     "decision_ms": [wall time per stage], "observations": [[x or null, ...] per carrier],
     "observations_sampled": bool,
     "clairvoyant": {"reward": ..., "features": ..., "exact": bool},
     "online_optimum": {"expected_reward": V*, "exact": bool, "atoms": K,
                        "planner_expected_reward": ...},
     "upper_bound": {"expected_reward": ..., "stderr": ..., "method": ..., "samples": M}}

``upper_bound`` (planner/duality.py) bounds the expected reward of every online policy from above
(an expectation over the prior, like V*, with its standard error), present only when it fits its
time budget (``planner.duality.DEFAULT_BUDGET_S``, judged from the instance's sizes).

``online_optimum`` (planner/online_optimal.py) is the expected reward of the Bayes-optimal online
policy, present when the planner is ``online-optimal`` (the V* it computed) or the instance is small
enough (``planner.online_optimal.auto_admit``); ``planner_expected_reward``
is the exact expected reward of the planner run, for ``ssap``, ``random`` and ``online-optimal``.
Communication (planner/comms.py, docs/planner.md): ``--message-loss P`` drops every message
(observation, intent, decision) with probability P in [0, 1]; ``--message-delay K`` delivers the
others K stages late; ``--groups 0,1/2,3`` splits the carriers (indices, groups separated by ``/``)
into groups that cannot hear each other, the coordinator hearing the first group only. The
defaults (0, 0, one group) run exactly as without the flags; any other value adds
``"comms": {"loss", "delay", "groups"}`` to the output.

``--planner online-optimal`` on an instance beyond the exact solver's limits exits 2 with one line.

Exit codes: 0 success; 2 bad input (unreadable or invalid instance file, bad arguments, unknown
planner) with one line on stderr, or a planner that broke a rule while deciding (it raised,
returned an infeasible action, or ran past ``plan_ms``: planner/guard.py), with one line naming
the planner, the rule and the stage; 1 the planner could not be built (e.g. its module is missing).
The instance format is documented in docs/planner.md. ``python -m coordinator.solve`` (the
earlier spelling) runs this same command.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
from typing import Sequence

from planner.cli import OneLineParser, integer_at_least
from planner.guard import PlannerFault
from planner.instance import InstanceError
from planner.learning import UnsupportedPrior
from planner.online_optimal import TooLarge
from planner.registry import OPTIONS, Option, PluginError, entry, known_names, make_planner, parse_option
from planner.solve import solve_instance

#: The command's name in its messages (``python -m coordinator.solve`` forwards here).
PROG = "python -m planner.cli.solve"
EXIT_OK = 0
EXIT_PLANNER = 1
EXIT_INPUT = 2


def _option_type(option: Option):
    """An argparse type checking one registry option (type and range) with its own message."""

    def parse(text: str):
        try:
            return option.parse(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {option.expected()}, found {text!r}") from None

    return parse


def _loss(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"expected a probability in [0, 1], found {text!r}")
    return value


def _groups(text: str):
    from planner.comms import parse_groups

    try:
        return parse_groups(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def build_parser(prog: str = PROG) -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog=prog,
        description="Run a deployment planner online over an instance file; print one JSON object.",
    )
    parser.add_argument("instance", help="instance JSON file (format: docs/planner.md)")
    parser.add_argument("--planner", required=True,
                        help=f"planner name: {', '.join(known_names())}, or a plug-in's package.module:Factory")
    parser.add_argument("--planner-option", action="append", default=[], metavar="KEY=VALUE",
                        help="a planner option by name, a plug-in's own options included (repeatable)")
    for option in OPTIONS.values():
        if option.kind is bool:  # --learn-prior alone means true; --learn-prior false also reads
            parser.add_argument("--" + option.name.replace("_", "-"), type=_option_type(option), nargs="?",
                                const=True, metavar="true|false", help=option.help)
            continue
        parser.add_argument("--" + option.name.replace("_", "-"), type=_option_type(option), help=option.help)
    parser.add_argument("--seed", type=integer_at_least(0), default=0,
                        help="root seed: the planner's streams, and the observations when the file has none")
    parser.add_argument("--no-clairvoyant", action="store_true", help="skip the clairvoyant bound")
    parser.add_argument("--no-online-optimum", action="store_true",
                        help="skip the exact online optimum (computed only for small instances anyway)")
    parser.add_argument("--no-upper-bound", action="store_true",
                        help="skip the information-relaxation upper bound (computed only within its time budget)")
    parser.add_argument("--message-loss", type=_loss, default=0.0, metavar="P",
                        help="probability in [0, 1] that a message is dropped (default 0)")
    parser.add_argument("--message-delay", type=integer_at_least(0, "stages"), default=0, metavar="K",
                        help="stages every delivered message is late (default 0)")
    parser.add_argument("--groups", type=_groups, default=(), metavar="0,1/2,3",
                        help="carrier groups that cannot hear each other; the coordinator hears the first")
    return parser


def main(argv: Sequence[str] | None = None, prog: str = PROG) -> int:
    """Run the command on ``argv`` (``sys.argv[1:]`` when None); ``prog`` names it in messages.
    Returns the exit code."""
    args = build_parser(prog).parse_args(argv)
    try:
        entry(args.planner)
    except PluginError as err:
        print(f"{prog}: error: --planner: {err}", file=sys.stderr)
        return EXIT_INPUT
    except ValueError:
        print(f"{prog}: error: --planner: expected one of {', '.join(sorted(known_names()))} or package.module:Factory, "
              f"found {args.planner!r}", file=sys.stderr)
        return EXIT_INPUT
    options = {name: getattr(args, name) for name in OPTIONS}
    for text in args.planner_option:
        try:
            key, value = parse_option(text, args.planner)
        except ValueError as err:
            print(f"{prog}: error: --planner-option: {err}", file=sys.stderr)
            return EXIT_INPUT
        options[key] = value
    try:
        planner = make_planner(args.planner, **options)
    except ImportError as err:
        print(f"{prog}: error: planner {args.planner!r} is not available: {err}", file=sys.stderr)
        return EXIT_PLANNER
    except (TypeError, ValueError) as err:
        # Options the chosen planner rejects (e.g. a budget it cannot use).
        print(f"{prog}: error: planner {args.planner!r}: {err}", file=sys.stderr)
        return EXIT_INPUT
    from planner.comms import CommsSpec

    comms = CommsSpec(args.message_loss, args.message_delay, args.groups)
    try:
        out = solve_instance(args.instance, planner, args.planner, args.seed, clairvoyant=not args.no_clairvoyant,
                             online_optimum=not args.no_online_optimum, comms=None if comms.perfect else comms,
                             upper_bound=not args.no_upper_bound)
    except (InstanceError, TooLarge, UnsupportedPrior) as err:
        print(str(err), file=sys.stderr)
        return EXIT_INPUT
    except PlannerFault as fault:
        print(f"{PROG}: {fault.line(args.planner)}", file=sys.stderr)
        return EXIT_INPUT
    try:
        sys.stdout.write(json.dumps(out) + "\n")
        sys.stdout.flush()
    except BrokenPipeError:
        # The reader went away (e.g. `| head`): not an error of ours; silence the exit flush.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    return EXIT_OK


if __name__ == "__main__":
    sys.exit(main())
