"""Timing figures of the world (printed, never asserted): ``python -m tools.world_bench
[SCENARIO ...]``.

For each scenario: the first ``observe_all`` (physics of every carrier plus sensing), a further
seed (features redrawn and sensed; the physics is cached) and ``stage_geometry`` (overlaps).
``--regions``: the coverage reward's arrangement (world/regions.py) of the street-grid family
(tools/scale.py) at 64 and 256 carriers and of 5,120 discs drawn at random in a crowded square.
"""
from __future__ import annotations

import sys
import time

from world.paths import SCENARIOS
from world.scenario import ScenarioError, load_scenario
from world.sim import observe_all
from world.stages import stage_geometry

DEFAULT = ["tiny", "six_carriers", "open_field", "urban_alpha"]


def regions_figures() -> None:
    """Time the coverage regions of large fleets (one arrangement each; nothing cached)."""
    import numpy as np

    from tools.scale import grid_scenario
    from world.regions import arrangement, check_size
    from world.scenario import parse_scenario
    from world.stages import planned_positions

    cases = []
    for n in (64, 256):
        s = parse_scenario(grid_scenario(n, seed=3))
        cases.append((f"grid_{n}", planned_positions(s), s.valid(), s.sensing_radius, s))
    rng = np.random.default_rng(0)
    cases.append(("random 256x20", rng.uniform(0, 300, (256, 20, 2)), np.ones((256, 20), dtype=bool), 6.0, None))
    for name, pos, valid, radius, s in cases:
        t = time.perf_counter()
        if s is not None:
            check_size(s)
        check_s = time.perf_counter() - t
        t = time.perf_counter()
        regions = arrangement(pos, valid, radius)
        arr_s = time.perf_counter() - t
        print(f"{name:14s} {int(valid.sum()):5d} points, {len(regions.centres):5d} discs: {regions.n_regions:6d} regions "
              f"in {arr_s:5.2f} s" + (f" (size check at load {check_s * 1e3:.0f} ms)" if s is not None else ""))


def main(argv: list[str]) -> int:
    if argv == ["--regions"]:
        regions_figures()
        return 0
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
