"""The marine scenario family (docs/scenario.md, "The marine family"): surface vessels on survey
transects deploy underwater robots, in a current, over clustered features, on acoustic links.

* **Vessels** split the survey area into equal strips along x, one each, and run lawnmower
  transects in their strip: lines parallel to y, ``line_spacing`` apart, joined at alternate
  ends.
* **Current**: a uniform drift plus vortices (world/current.py), drawn from the seed.
* **Features**: a Matérn cluster process. The generator draws the hotspots (the parent points:
  Poisson with ``hotspots_per_km2`` over the area) and writes each as a disc cluster of radius
  ``hotspot_radius`` holding ``hotspot_mean`` features on average; every mission seed then draws
  the features (the children: Poisson in each disc, world/features.py), so a mission's features
  are a Matérn cluster process conditional on the file's hotspots; plus a sparse background.
* **Passengers**: underwater robots of two types (``auv`` 1.0, ``glider`` 0.6).
* **Links**: acoustic, the coordinator's modem at ``base`` (the mother ship, mid-south).
* **Prior**: a negative binomial fitted by moments to what the vessels observe over
  ``prior_seeds`` seeds (world.importer.fit_prior), since the derived prior ignores clusters.

Deterministic: the same settings and seed give the same file.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

#: The generator's own stream: SeedSequence(seed, spawn_key=(MARINE_SPAWN_KEY,)).
MARINE_SPAWN_KEY = 0x4D415249  # "MARI"


@dataclass(frozen=True)
class MarineSettings:
    """What the family varies. Lengths in m, speeds in m/s, times in s."""

    name: str = "marine_survey"
    seed: int = 3600
    vessels: int = 3
    auvs: int = 2                      # auv passengers per vessel
    gliders: int = 1                   # glider passengers per vessel
    width: float = 2400.0
    height: float = 1600.0
    line_spacing: float = 200.0
    speed: float = 2.5                 # about 5 knots
    sensing_radius: float = 80.0       # a passenger's survey radius
    stage_interval: float = 120.0
    background_density: float = 1e-5   # features per m²
    hotspots_per_km2: float = 1.5
    hotspot_radius: float = 150.0
    hotspot_mean: float = 30.0         # features per hotspot, on average
    drift_speed: float = 0.15
    vortices: int = 2
    vortex_speed: float = 0.4          # peak speed of a vortex (m/s)
    bitrate_bps: float = 1200.0
    frame_bytes: int = 256
    noise_level_db: float = 98.0       # a noisy shallow-water survey (ship noise): far corners fade
    prior_seeds: int = 20


def _transects(x0: float, x1: float, height: float, spacing: float) -> list[list[float]]:
    """Lawnmower waypoints in the strip [x0, x1] x [0, height]: lines parallel to y, ``spacing``
    apart and half a spacing from the strip's sides and the area's ends."""
    xs = np.arange(x0 + spacing / 2, x1 - spacing / 2 + 1e-9, spacing)
    lo, hi = spacing / 2, height - spacing / 2
    pts = []
    for k, x in enumerate(xs):
        ends = (lo, hi) if k % 2 == 0 else (hi, lo)
        pts += [[round(float(x), 3), ends[0]], [round(float(x), 3), ends[1]]]
    return pts


def draw_hotspots(rng: np.random.Generator, st: MarineSettings) -> list[dict]:
    """The parent points of the Matérn cluster process as disc clusters (inside the area)."""
    area_km2 = st.width * st.height / 1e6
    n = int(rng.poisson(st.hotspots_per_km2 * area_km2))
    r = st.hotspot_radius
    centres = np.column_stack([rng.uniform(r, st.width - r, n), rng.uniform(r, st.height - r, n)])
    density = st.hotspot_mean / (math.pi * r * r)
    return [{"disc": {"center": [round(float(x), 2), round(float(y), 2)], "radius": r},
             "density": float(f"{density:.6g}"), "label": f"hotspot {i}"} for i, (x, y) in enumerate(centres)]


def _current(rng: np.random.Generator, st: MarineSettings) -> dict:
    heading = rng.uniform(0, 2 * math.pi)
    vortices = [{"center": [round(float(rng.uniform(0, st.width)), 1), round(float(rng.uniform(0, st.height)), 1)],
                 "radius": round(float(rng.uniform(0.15, 0.3) * min(st.width, st.height)), 1),
                 "speed": round(float(st.vortex_speed * rng.choice([-1.0, 1.0]) * rng.uniform(0.5, 1.0)), 3)}
                for _ in range(st.vortices)]
    return {"drift": [round(st.drift_speed * math.cos(heading), 4), round(st.drift_speed * math.sin(heading), 4)],
            "vortices": vortices}


def marine_document(st: MarineSettings = MarineSettings()) -> dict:
    """The scenario file (a YAML-ready mapping) of ``st``, prior included."""
    rng = np.random.default_rng(np.random.SeedSequence(st.seed, spawn_key=(MARINE_SPAWN_KEY,)))
    strip = st.width / st.vessels
    carriers, longest = [], 0.0
    for v in range(st.vessels):
        wps = _transects(v * strip, (v + 1) * strip, st.height, st.line_spacing)
        longest = max(longest, float(np.hypot(*np.diff(np.asarray(wps), axis=0).T).sum()))
        carriers.append({"id": f"vessel{v + 1}", "passengers": ["auv"] * st.auvs + ["glider"] * st.gliders,
                         "start_time": 0, "speed": st.speed, "waypoints": wps})
    stages = int(longest / st.speed // st.stage_interval) + 1
    doc = {
        "name": st.name, "seed": st.seed,
        "map": {"bounds": [0, 0, st.width, st.height]},
        "features": {"density": st.background_density, "clusters": draw_hotspots(rng, st)},
        "current": _current(rng, st),
        "links": {"model": "acoustic", "base": [st.width / 2, 0.0], "bitrate_bps": st.bitrate_bps,
                  "frame_bytes": st.frame_bytes, "noise_level_db": st.noise_level_db},
        "passenger_types": {"auv": 1.0, "glider": 0.6},
        "sensing_radius": st.sensing_radius, "stage_interval": st.stage_interval, "stages": stages,
        "carriers": carriers,
        "planner": {"name": "mcts-ssap", "iterations": 500},
    }
    doc["prior"] = _fitted_prior(doc, st)
    return doc


def _fitted_prior(doc: dict, st: MarineSettings) -> dict:
    """The prior fitted by moments to the counts the vessels observe over ``prior_seeds`` seeds
    (the mission's seed and the ones after it)."""
    from world.importer import fit_prior
    from world.scenario import parse_scenario
    from world.sim import simulate_mission

    s = parse_scenario(doc, "<marine>")
    values = np.concatenate([simulate_mission(s, seed=st.seed + k).x.ravel() for k in range(st.prior_seeds)])
    values = values[~np.isnan(values)]
    return fit_prior(values) if values.any() else "derived"  # nothing seen: the background's prior


_HEADER = """\
# Marine survey (issue 36): {vessels} surface vessels run lawnmower transects and deploy
# underwater robots (auv, glider) over hotspots of a Matern cluster process, in a current, on
# acoustic links. Generated by world/marine.py; to write it again:
#   python -m world.marine --out scenarios/{name}.yaml --seed {seed}
# The fleet and the simulator apply the link model (docs/fleet.md, "Links the physics decides").
"""


def write_marine(path: str | Path, st: MarineSettings = MarineSettings()) -> Path:
    """Write the scenario of ``st`` to ``path``; returns the path."""
    out = Path(path)
    doc = marine_document(st)

    def dump(part: dict) -> str:
        return yaml.safe_dump(part, sort_keys=False, default_flow_style=None, width=110)

    feats = doc["features"]
    # one line per hotspot (a block dump spreads each over five)
    hotspots = "".join(f"  - {yaml.safe_dump(c, default_flow_style=True, width=200).strip()}\n"
                       for c in feats["clusters"])
    head = {k: doc[k] for k in ("name", "seed", "map")}
    rest = {k: v for k, v in doc.items() if k not in head and k != "features"}
    text = (_HEADER.format(**dataclasses.asdict(st)) + dump(head)
            + f"features:\n  density: {feats['density']:.6e}\n  clusters:\n{hotspots}" + dump(rest))
    out.write_text(text, encoding="utf-8")
    return out


def main(argv: list[str] | None = None) -> int:
    import argparse

    p = argparse.ArgumentParser(prog="python -m world.marine", description="Write a marine survey scenario.")
    p.add_argument("--out", required=True, metavar="SCENARIO.yaml")
    p.add_argument("--seed", type=int, default=MarineSettings.seed, help="the generator's and the mission's seed")
    p.add_argument("--vessels", type=int, default=MarineSettings.vessels)
    p.add_argument("--name", default=MarineSettings.name)
    args = p.parse_args(argv)
    if args.seed < 0 or not 1 <= args.vessels <= 64:
        print(f"--seed, --vessels: expected a seed >= 0 and 1 to 64 vessels, found {args.seed}, {args.vessels}")
        return 2
    st = MarineSettings(name=args.name, seed=args.seed, vessels=args.vessels)
    print(f"wrote {write_marine(args.out, st)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
