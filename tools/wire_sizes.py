"""Print the size on the wire of every message kind for a scenario's fleet, and whether the
messages a stage needs fit its acoustic frame (docs/scenario.md, "Links").

    python -m tools.wire_sizes [SCENARIO.yaml]      (default: scenarios/six_carriers.yaml)
"""
from __future__ import annotations

import argparse
import sys

from scenarios import bundled_path
from wire.sizes import UNCHECKED_KINDS, frame_problems, message_sizes
from world.scenario import ScenarioError, load_scenario


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tools.wire_sizes", description=__doc__.splitlines()[0])
    parser.add_argument("scenario", nargs="?", default=str(bundled_path("six_carriers")))
    args = parser.parse_args(argv)
    try:
        s = load_scenario(args.scenario)
    except ScenarioError as err:
        print("\n".join(err.problems), file=sys.stderr)
        return 2
    frame = s.links.frame_bytes if s.links.model == "acoustic" else None
    print(f"scenario {s.name}: {s.n_carriers} carriers, {s.stages} stages, links {s.links.model}"
          + (f", frame {frame} bytes, {s.links.bitrate_bps:g} bit/s" if frame else ""))
    print(f"  {'kind':<10} {'bytes':>6} {'stage':>5}  {'airtime s' if frame else ''}  note")
    for m in message_sizes(s):
        air = f"{8 * m.size / s.links.bitrate_bps:>9.3f}" if frame else ""
        fits = "" if frame is None else ("  fits" if m.size <= frame else
                                         "  not sent so: see obs+fitted" if m.kind == "obs+trail" else
                                         "  not on the links" if m.kind in UNCHECKED_KINDS else "  DOES NOT FIT")
        print(f"  {m.kind:<10} {m.size:>6} {'yes' if m.stage else '':>5}  {air}  {m.note}{fits}")
    problems = frame_problems(s)
    for p in problems:
        print(p.line(s.source), file=sys.stderr)
    return 2 if problems else 0


if __name__ == "__main__":
    raise SystemExit(main())
