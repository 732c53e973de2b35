"""``python -m planner.cli.compile [--planner NAME ...]``: compile the planner's numba kernels for
this machine ahead of a first run (a robot host's provisioning, an image build), so that the
fleet's first run loads them instead of compiling (planner/jitcache.py: one cache per machine).

Default planners: the default (mcts-ssap, joint and binary layouts), closed-loop and the
on-board planner (dec-closed-loop), each under the paper's penalty reward and the coverage
reward; the clairvoyant bound of the summary always. Prints a line per kernel compiled and one at
the end; kernels already cached are loaded silently. After it a mission compiles nothing
(tests/test_numba_cache.py, slow).
"""
from __future__ import annotations

import sys
import time

from planner.cli import OneLineParser


def main(argv=None) -> int:
    from planner import jitcache
    from planner.registry import planner_names
    from planner.settings import DEFAULT_PLANNER, ONBOARD_PLANNER

    parser = OneLineParser(prog="python -m planner.cli.compile", description=__doc__.split("\n\n")[0])
    parser.add_argument("--planner", action="append", choices=planner_names(),
                        help=f"a planner to compile (repeatable; default {DEFAULT_PLANNER}, closed-loop, "
                             f"{ONBOARD_PLANNER})")
    args = parser.parse_args(argv)
    names = args.planner or [DEFAULT_PLANNER, "closed-loop", ONBOARD_PLANNER]
    compiled = []
    jitcache.report_compiles(lambda line: (compiled.append(line), print(line, flush=True)))
    start = time.monotonic()

    from planner import clairvoyant
    from planner.problem import warm_up_coverage_problem, warm_up_problem
    from planner.registry import make_planner

    for name in names:
        layouts = ("joint", "binary") if name.startswith("mcts-") else (None,)
        for layout in layouts:
            planner = make_planner(name, **({} if layout is None else {"layout": layout}))
            warm = getattr(planner, "warm_up", None)
            if callable(warm):
                warm(warm_up_problem())
                warm(warm_up_coverage_problem())
    clairvoyant.warm_up()
    count = sum(line.startswith("compiling planner.") for line in compiled)
    print(f"planner kernels ready in {jitcache.cache_dir()}: {count} compiled, {time.monotonic() - start:.1f} s",
          flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
