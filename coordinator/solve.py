"""Run one planner online over one instance file and print the outcome as one JSON object.

    python -m coordinator.solve INSTANCE.json --planner NAME [--iterations K] [--plan-ms MS]
                                [--seed S] [--exploration C] [--samples M] [--no-clairvoyant]

Output (stdout, one JSON object)::

    {"planner": NAME, "seed": S, "deployments": [[stage, ...] per carrier],
     "reward": normalised total with penalties, "features": raw total (sum of x / p),
     "decision_ms": [wall time per stage], "observations": [[x or null, ...] per carrier],
     "observations_sampled": bool,
     "clairvoyant": {"reward": ..., "features": ..., "exact": bool}}

Exit codes: 0 success; 2 bad input (unreadable or invalid instance file, bad arguments, unknown
planner) with one line on stderr; 1 the planner could not be built (e.g. its module is missing).
The instance format is documented in docs/planner.md.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
from typing import Sequence

import numpy as np

from coordinator.instance import InstanceError, load_instance
from coordinator.planners import make_planner, planner_names
from coordinator.problem import run_online

EXIT_OK = 0
EXIT_PLANNER = 1
EXIT_INPUT = 2


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (exit code 2)."""

    def error(self, message: str):  # noqa: D401 - argparse hook
        self.exit(EXIT_INPUT, f"{self.prog}: error: {message}\n")


def _number(kind: type, minimum: float, strict: bool):
    """An argparse type: a finite ``kind`` (int or float) > ``minimum`` (``strict``) or >= it."""
    expected = f"expected {'an integer' if kind is int else 'a number'} {'>' if strict else '>='} {minimum:g}"

    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{expected}, found {text!r}") from None
        if not math.isfinite(value) or value < minimum or (strict and value == minimum):
            raise argparse.ArgumentTypeError(f"{expected}, found {text!r}")
        return value

    return parse


_positive_int = _number(int, 1, strict=False)
_positive_float = _number(float, 0, strict=True)
_nonnegative_float = _number(float, 0, strict=False)


def _seed(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, found {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, found {text!r}")
    return value


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="python -m coordinator.solve",
        description="Run a deployment planner online over an instance file; print one JSON object.",
    )
    parser.add_argument("instance", help="instance JSON file (format: docs/planner.md)")
    parser.add_argument("--planner", required=True, help=f"planner name: {', '.join(planner_names())}")
    parser.add_argument("--iterations", type=_positive_int, help="MCTS iterations per stage")
    parser.add_argument("--plan-ms", type=_positive_float, help="MCTS time budget per stage, milliseconds")
    parser.add_argument("--exploration", type=_nonnegative_float, help="MCTS UCT constant c (default 0.05*sqrt(2))")
    parser.add_argument("--samples", type=_positive_int, help="MCTS Monte Carlo samples per rollout")
    parser.add_argument("--seed", type=_seed, default=0,
                        help="root seed: the planner's streams, and the observations when the file has none")
    parser.add_argument("--no-clairvoyant", action="store_true", help="skip the clairvoyant bound")
    return parser


def solve_instance(planner, args: argparse.Namespace) -> dict:
    """Load the instance, run ``planner`` online and evaluate; returns the output object.

    Raises:
        InstanceError: a bad instance file.
    """
    (problem, x), sampled = load_instance(args.instance, seed=args.seed)
    result = run_online(problem, x, planner, args.seed)
    out = {
        "planner": args.planner,
        "seed": args.seed,
        "deployments": [np.flatnonzero(row).tolist() for row in result.deployed],
        "reward": result.reward,
        "features": result.features,
        "decision_ms": [round(t, 3) for t in result.decision_ms],
        "observations": [[None if np.isnan(v) else float(v) for v in row] for row in x],
        "observations_sampled": sampled,
    }
    if not args.no_clairvoyant:
        from coordinator import clairvoyant  # numba: loaded only when needed

        bound = clairvoyant.solve(problem, x)
        out["clairvoyant"] = {"reward": bound.reward, "features": bound.features, "exact": bound.exact}
    return out


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    prog = "python -m coordinator.solve"
    if args.planner not in planner_names():
        print(f"{prog}: error: --planner: expected one of {', '.join(planner_names())}, found {args.planner!r}",
              file=sys.stderr)
        return EXIT_INPUT
    try:
        planner = make_planner(
            args.planner, iterations=args.iterations, plan_ms=args.plan_ms,
            exploration=args.exploration, samples=args.samples,
        )
    except ImportError as err:
        print(f"{prog}: error: planner {args.planner!r} is not available: {err}", file=sys.stderr)
        return EXIT_PLANNER
    except (TypeError, ValueError) as err:
        # Options the chosen planner rejects (e.g. a budget it cannot use).
        print(f"{prog}: error: planner {args.planner!r}: {err}", file=sys.stderr)
        return EXIT_INPUT
    try:
        out = solve_instance(planner, args)
    except InstanceError as err:
        print(str(err), file=sys.stderr)
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
