"""What a simulated carrier senses, for clients written in another language (docs/protocol.md,
"Where observations come from"): per stage, t_j, whether the carrier is scheduled, x and its
position at t_j, from the project's world model (features drawn with numpy's generators, the
body driven by pymunk), as one JSON document.

    python -m tools.sensed scenarios/tiny.yaml --carrier a [--seed 7] [--out a.json]

Output: ``{"scenario": path, "seed": int, "carrier": id, "fingerprint": hex, "passengers": D,
"stage_times": [t_j], "scheduled": [bool], "x": [int or null], "positions": [[x, y]]}`` (x null
where the carrier is not scheduled; positions in metres; the body's position at t_j, also where
it is not scheduled). tests/revision1_carrier.py reads this file (``--world``).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np


def sensed(scenario, cid: str, trace=None) -> dict:
    """The document above for carrier ``cid``; ``trace``: ``world.simulate_mission(scenario)``
    when the caller has it already."""
    import world
    from wire.messages import scenario_fingerprint

    trace = world.simulate_mission(scenario) if trace is None else trace
    r = scenario.carrier_index(cid)
    samples = trace.trajectories[r]  # (t, x, y) rows, one per simulated second
    times = [float(t) for t in scenario.stage_times()]
    positions = []
    for t in times:
        k = min(int(np.searchsorted(samples[:, 0], t)), len(samples) - 1)
        positions.append([float(samples[k, 1]), float(samples[k, 2])])
    return {"scenario": str(scenario.source), "seed": int(scenario.seed), "carrier": cid,
            "fingerprint": scenario_fingerprint(scenario), "passengers": int(scenario.carriers[r].passengers),
            "stage_times": times, "scheduled": [bool(v) for v in scenario.valid()[r]],
            "x": [None if np.isnan(v) else int(v) for v in trace.x[r]], "positions": positions}


def main(argv=None) -> int:
    import world

    parser = argparse.ArgumentParser(prog="python -m tools.sensed", description=__doc__.splitlines()[0])
    parser.add_argument("scenario", help="scenario YAML file")
    parser.add_argument("--carrier", required=True, help="carrier id")
    parser.add_argument("--seed", type=int, help="root seed (overrides the scenario's)")
    parser.add_argument("--out", help="write the JSON here (default: standard output)")
    args = parser.parse_args(argv)
    try:
        scenario = world.load_scenario(args.scenario)
    except (OSError, ValueError) as exc:
        print(f"tools.sensed: {exc}", file=sys.stderr)
        return 2
    if args.seed is not None:
        scenario = scenario.with_seed(args.seed)
    if args.carrier not in scenario.carrier_ids:
        print(f"tools.sensed: --carrier: {args.carrier!r} is not a carrier of {args.scenario} "
              f"({', '.join(scenario.carrier_ids)})", file=sys.stderr)
        return 2
    text = json.dumps(sensed(scenario, args.carrier))
    if args.out:
        Path(args.out).write_text(text + "\n")
    else:
        print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
