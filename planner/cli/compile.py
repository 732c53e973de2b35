"""``python -m planner.cli.compile [--planner NAME ...]``: compile the planner's numba kernels for
this machine ahead of a first run (a robot host's provisioning, an image build), so that the
fleet's first run loads them instead of compiling (planner/jitcache.py: one cache per machine).

Default planners: the default (mcts-ssap, joint and binary layouts), closed-loop and the
on-board planner (dec-closed-loop), each under the paper's penalty reward and the coverage
reward; the clairvoyant bound of the summary always, each in its own process, ``--jobs`` at a time
(default: the cores, at most 4; a kernel two of them need is compiled once, under its lock).
Prints a line per kernel compiled and one at the end; kernels already cached are loaded silently.
After it a mission compiles nothing (tests/test_numba_cache.py, slow).
"""
from __future__ import annotations

import argparse
import os
import sys
import time

from planner.cli import OneLineParser


def _units(names: list[str]) -> list[str]:
    """The compile units of ``names``: ``NAME`` or ``NAME:LAYOUT`` (mcts planners, each layout),
    then ``clairvoyant`` (the summary's bound)."""
    return [f"{name}:{layout}" if layout else name for name in names
            for layout in (("joint", "binary") if name.startswith("mcts-") else (None,))] + ["clairvoyant"]


def _compile_unit(unit: str) -> None:
    """Warm one unit's kernels up in this process (each compiled, or loaded when cached)."""
    from planner import clairvoyant
    from planner.problem import warm_up_coverage_problem, warm_up_problem
    from planner.registry import make_planner

    if unit == "clairvoyant":
        clairvoyant.warm_up()
        return
    name, _, layout = unit.partition(":")
    planner = make_planner(name, **({"layout": layout} if layout else {}))
    warm = getattr(planner, "warm_up", None)
    if callable(warm):
        warm(warm_up_problem())
        warm(warm_up_coverage_problem())


def _in_processes(units: list[str], jobs: int, say) -> bool:
    """Each unit in its own ``python -m planner.cli.compile --unit U`` process, ``jobs`` at a
    time; their lines go to ``say`` as they arrive (one loop over the pipes). Processes wanting
    the same kernel compile it once (planner/jitcache.py's per-kernel lock). True when every
    process succeeded."""
    import selectors
    import subprocess

    pending, running, codes = list(units), 0, []
    with selectors.DefaultSelector() as pipes:
        while pending or running:
            while pending and running < jobs:
                proc = subprocess.Popen([sys.executable, "-m", "planner.cli.compile", "--unit", pending.pop(0)],
                                        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
                pipes.register(proc.stdout, selectors.EVENT_READ, proc)
                running += 1
            for key, _ in pipes.select():
                line = key.fileobj.readline()
                if line:
                    say(line.rstrip("\n"))
                    continue
                pipes.unregister(key.fileobj)
                key.fileobj.close()
                codes.append(key.data.wait())
                running -= 1
    return all(code == 0 for code in codes)


def main(argv=None) -> int:
    from planner import jitcache
    from planner.registry import planner_names
    from planner.settings import DEFAULT_PLANNER, ONBOARD_PLANNER

    parser = OneLineParser(prog="python -m planner.cli.compile", description=__doc__.split("\n\n")[0])
    parser.add_argument("--planner", action="append", choices=planner_names(),
                        help=f"a planner to compile (repeatable; default {DEFAULT_PLANNER}, closed-loop, "
                             f"{ONBOARD_PLANNER})")
    parser.add_argument("--jobs", type=int, default=min(4, os.cpu_count() or 1),
                        help="processes compiling at once (default: the cores, at most 4; 1: in this process)")
    parser.add_argument("--unit", help=argparse.SUPPRESS)  # one unit, in a process of --jobs
    args = parser.parse_args(argv)
    if args.jobs < 1:
        parser.error(f"--jobs: expected at least 1, got {args.jobs}")
    compiled = []

    def say(line: str) -> None:
        if line.startswith("compiling the planner's kernels") and line in compiled:
            return  # each process's heading: once
        compiled.append(line)
        print(line, flush=True)

    jitcache.report_compiles(say)
    if args.unit:
        _compile_unit(args.unit)
        return 0
    start = time.monotonic()
    units = _units(args.planner or [DEFAULT_PLANNER, "closed-loop", ONBOARD_PLANNER])
    if args.jobs == 1:
        for unit in units:
            _compile_unit(unit)
    elif not _in_processes(units, args.jobs, say):
        print("planner kernels: a compile process failed (its lines above)", file=sys.stderr, flush=True)
        return 1
    count = sum(line.startswith("compiling planner.") for line in compiled)
    print(f"planner kernels ready in {jitcache.cache_dir()}: {count} compiled, {time.monotonic() - start:.1f} s",
          flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
