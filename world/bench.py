"""Timing figures of the world (printed, never asserted): ``python -m world.bench [SCENARIO ...]``.

For each scenario: the first ``observe_all`` (physics of every carrier plus sensing), a further
seed (features redrawn and sensed; the physics is cached) and ``stage_geometry`` (overlaps).
"""
from __future__ import annotations

import sys
import time

from world.paths import SCENARIOS
from world.scenario import ScenarioError, load_scenario
from world.sim import observe_all
from world.stages import stage_geometry

DEFAULT = ["tiny", "six_carriers", "open_field", "urban_alpha"]


def main(argv: list[str]) -> int:
    files = argv or [str(SCENARIOS / f"{n}.yaml") for n in DEFAULT]
    for f in files:
        try:
            s = load_scenario(f)
        except ScenarioError as err:
            print("\n".join(err.problems), file=sys.stderr)
            return 2
        t = time.perf_counter()
        observe_all(s)
        first = time.perf_counter() - t
        t = time.perf_counter()
        for k in range(20):
            observe_all(s, seed=k)
        per_seed = (time.perf_counter() - t) / 20
        t = time.perf_counter()
        geo = stage_geometry(s)
        geo_s = time.perf_counter() - t
        print(f"{s.name:14s} R={s.n_carriers} N={s.stages:<3d} observe_all first {first:6.2f} s, "
              f"per further seed {per_seed * 1e3:6.1f} ms, stage_geometry {geo_s * 1e3:6.1f} ms "
              f"({len(geo.overlaps)} overlaps)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
