"""Command line: ``python -m world check SCENARIO.yaml`` and ``python -m world render SCENARIO.yaml -o map.png``.

Exit codes: 0 success, 2 bad input (each problem on one line on stderr, no traceback).
"""
from __future__ import annotations

import argparse
import math
import sys
from collections import Counter

import numpy as np

from world.scenario import Scenario, ScenarioError, load_scenario

EXIT_BAD_INPUT = 2


def _prior_text(s: Scenario) -> str:
    if s.prior.kind == "derived":
        return (f"poisson(mean={s.derived_prior_mean():.3f}), derived = {s.features.density:g}/m² x "
                f"pi x ({s.sensing_radius:g} m)² (open field; walls and clusters ignored)")
    params = ", ".join(f"{k}={v}" for k, v in s.prior.params)
    return f"{s.prior.kind}({params}), given in the file"


def check(s: Scenario, seeds: int) -> str:
    """The summary printed by ``check``."""
    from world.features import sample_features
    from world.report import prior_report
    from world.stages import stage_geometry

    geo = stage_geometry(s)
    feats = sample_features(s)
    m = s.map
    xmin, ymin, xmax, ymax = m.bounds
    lines = [f"scenario {s.name} ({s.source}): OK, seed {s.seed}"]
    bld = "none"
    if m.building is not None:
        b = m.building
        bld = (f"{b.cols} x {b.rows} rooms of {b.room_size[0]:g} x {b.room_size[1]:g} m, "
               f"corridors {b.corridor_width:g} m, doors {b.door_width:g} m, entrances {list(b.entrances)}")
    lines.append(f"map: {xmax - xmin:g} x {ymax - ymin:g} m, {len(m.segments)} wall segments, "
                 f"{len(m.obstacles)} obstacles, building: {bld}")
    cl = ", ".join(f"{c.label or c.shape} ({c.density:g}/m² over {c.area:.0f} m²)" for c in s.features.clusters)
    lines.append(f"features: {len(feats)} at seed {s.seed}; background {s.features.density:g}/m²"
                 + (f"; clusters: {cl}" if cl else ""))
    lines.append(f"stages: N = {s.stages} every {s.stage_interval:g} s from t0 = {s.first_stage_time:g} s; "
                 f"sensing radius {s.sensing_radius:g} m; conflict radius {s.conflict_radius:g} m")
    lines.append(f"carriers: {s.n_carriers}, passengers {int(s.passengers.sum())}")
    lines.append(f"  {'id':<10} {'D':>2} {'start s':>8} {'stop s':>8} {'speed':>6} {'path m':>7}  valid stages")
    for r, c in enumerate(s.carriers):
        js = np.flatnonzero(geo.valid[r])
        rng = f"{js[0]}..{js[-1]} ({len(js)})" if len(js) else "none"
        lines.append(f"  {c.id:<10} {c.passengers:>2} {c.start_time:>8g} {c.stop_time:>8.1f} {c.speed:>6g} "
                     f"{c.path_length:>7.1f}  {rng}")
    n_valid = int(geo.valid.sum())
    in_some = len({p for g in geo.overlaps for p in g})
    sizes = Counter(len(g) for g in geo.overlaps)
    pts = geo.positions[geo.valid]
    d = np.hypot(pts[:, None, 0] - pts[None, :, 0], pts[:, None, 1] - pts[None, :, 1])
    pairs = int(((d <= s.conflict_radius).sum() - len(pts)) // 2)
    lines.append(f"decision points: {n_valid} valid of {s.n_carriers * s.stages}")
    lines.append(f"overlaps: {len(geo.overlaps)} groups (size: count {dict(sorted(sizes.items()))}); "
                 f"{in_some} of {n_valid} points in some overlap; {pairs} conflicting pairs")
    lines.append(f"planner: {s.planner.name}, iterations {s.planner.iterations}"
                 + (f", plan_ms {s.planner.plan_ms:g}" if s.planner.plan_ms is not None else "")
                 + f", exploration {s.planner.exploration:.4g}, samples {s.planner.samples}")
    lines.append(f"prior: {_prior_text(s)}")
    rep = prior_report(s, seeds=seeds)
    lines.append(f"prior vs world over {rep.seeds} seeds ({rep.samples} observed counts at actual positions, "
                 f"line of sight):")
    lines.append(f"  {'':<10} {'mean':>7} {'var':>7} {'q90':>5}")
    lines.append(f"  {'prior':<10} {rep.prior_mean:>7.3f} {rep.prior_var:>7.3f} {rep.prior_q90:>5g}")
    lines.append(f"  {'observed':<10} {rep.mean:>7.3f} {rep.var:>7.3f} {rep.q90:>5g}")
    lines.append("  observed mean per carrier: "
                 + ", ".join(f"{c.id} {v:.2f}" for c, v in zip(s.carriers, rep.per_carrier_mean) if not math.isnan(v)))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m world", description="Scenario tools.")
    sub = parser.add_subparsers(dest="command", required=True)
    p_check = sub.add_parser("check", help="validate a scenario and print a summary")
    p_check.add_argument("scenario")
    p_check.add_argument("--seeds", type=int, default=200, help="seeds for the prior-vs-world report (default 200)")
    p_render = sub.add_parser("render", help="draw the scenario's map to a PNG")
    p_render.add_argument("scenario")
    p_render.add_argument("-o", "--output", required=True, help="output PNG file")
    p_render.add_argument("--trajectories", action="store_true", help="simulate and draw the actual trajectories")
    p_render.add_argument("--seed", type=int, default=None, help="feature seed (the scenario's by default)")
    p_render.add_argument("--no-stage-labels", action="store_true", help="omit stage numbers")
    args = parser.parse_args(argv)
    try:
        s = load_scenario(args.scenario)
    except ScenarioError as err:
        for line in err.problems:
            print(line, file=sys.stderr)
        return EXIT_BAD_INPUT
    if args.command == "check":
        if args.seeds < 1:
            print(f"--seeds: expected an integer >= 1, found {args.seeds}", file=sys.stderr)
            return EXIT_BAD_INPUT
        print(check(s, args.seeds))
        return 0
    from world.features import sample_features
    from world.render import render_map
    from world.sim import simulate_mission

    seed = s.seed if args.seed is None else args.seed
    trace = simulate_mission(s, seed=seed) if args.trajectories else None
    try:
        out = render_map(s, args.output, trajectories=trace.trajectories if trace else None,
                         features=sample_features(s, seed), stage_labels=not args.no_stage_labels)
    except OSError as exc:
        print(f"{args.output}: expected a writable PNG path, found {exc.strerror or exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
