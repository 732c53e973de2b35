"""Command line: ``python -m world check SCENARIO.yaml``, ``python -m world render SCENARIO.yaml -o map.png``,
``python -m world export SCENARIO.yaml -o instance.json`` (the planner's instance) and ``python -m world import SOURCE --out SCENARIO.yaml ...`` (a team's own map and run:
world/importer.py).

Exit codes: 0 success, 2 bad input (each problem on one line on stderr, no traceback).
"""
from __future__ import annotations

if __name__ == "__main__":  # a forward, first: this file's body runs once, under its own name
    from launcher.scenario_check import world_command
    raise SystemExit(world_command())

import argparse
import math
import sys
from collections import Counter
from typing import Callable, Sequence

import numpy as np

from validation import Flaw
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
    from world.report import describe_links
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
    if m.storeys:
        lines.append("storeys: " + "; ".join(f"{st.name} at z {st.base:g} m ({sum(len(w) - 1 for w in st.walls)} wall "
                                             f"segments, carriers {', '.join(c.id for c in s.carriers if c.storey == st.name)})"
                                             for st in m.storeys))
    if m.voxels is not None:
        v = m.voxels
        lines.append(f"voxels: {v.path} (frontier: {v.neighbours} neighbours, kept more than {v.keep_above:g} m above "
                     f"or {v.keep_below:g} m below the carrier)")
    cl = ", ".join(f"{c.label or c.shape} ({c.density:g}/m² over {c.area:.0f} m²)" for c in s.features.clusters)
    if s.replays:
        lines.append(f"features: recorded observations (features.replay) at {int(s.valid().sum())} valid stages; "
                     f"{len(feats)} frontier cells drawn")
    elif s.features.from_map:
        lines.append(f"features: the {len(feats)} frontier cells of map.occupancy "
                     f"({s.feature_density():.3g}/m² of free cells)")
    else:
        lines.append(f"features: {len(feats)} at seed {s.seed}; background {s.features.density:g}/m²"
                     + (f"; clusters: {cl}" if cl else ""))
    if m.occupancy is not None:
        g = m.occupancy
        lines.append(f"occupancy: {g.shape[1]} x {g.shape[0]} cells of {g.resolution:g} m from {g.source}; "
                     f"carrier radius {s.carrier_radius:g} m")
    lines.append(f"stages: N = {s.stages} every {s.stage_interval:g} s from t0 = {s.first_stage_time:g} s; "
                 f"sensing radius {s.sensing_radius:g} m; conflict radius {s.conflict_radius:g} m")
    from world.stages import radii_warning

    said = radii_warning(m.bounds, s.sensing_radius, s.conflict_radius)
    if said:
        lines.append(f"warning: {said}")
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
    if s.reward == "coverage":
        lines.extend(_coverage_lines(s))
    lines.append(f"planner: {s.planner.name}, iterations {s.planner.iterations}"
                 + (f", plan_ms {s.planner.plan_ms:g}" if s.planner.plan_ms is not None else "")
                 + f", exploration {s.planner.exploration:.4g}, samples {s.planner.samples}")
    lines.append(f"prior: {_prior_text(s)}")
    lines.extend(describe_links(s))
    rep = prior_report(s, seeds=seeds)
    where = ("in the planned discs, region by region" if s.reward == "coverage"
             else "at actual positions, line of sight")
    lines.append(f"prior vs world over {rep.seeds} seeds ({rep.samples} observed counts {where}):")
    lines.append(f"  {'':<10} {'mean':>7} {'var':>7} {'q90':>5}")
    lines.append(f"  {'prior':<10} {rep.prior_mean:>7.3f} {rep.prior_var:>7.3f} {rep.prior_q90:>5g}")
    lines.append(f"  {'observed':<10} {rep.mean:>7.3f} {rep.var:>7.3f} {rep.q90:>5g}")
    lines.append("  observed mean per carrier: "
                 + ", ".join(f"{c.id} {v:.2f}" for c, v in zip(s.carriers, rep.per_carrier_mean) if not math.isnan(v)))
    return "\n".join(lines)


def _coverage_lines(s: Scenario) -> list[str]:
    """``check``'s report of a coverage scenario's regions (world/regions.py)."""
    from world.regions import region_counts, region_means, scenario_regions

    regions = scenario_regions(s)
    per_point = [len(c) for row in regions.covers for c in row if c is not None]
    shared = sum(1 for sig in regions.signatures if len(sig) >= 2)
    counts = region_counts(s)
    return [f"reward: coverage; regions: {regions.n_regions} cells of the arrangement of {len(regions.centres)} "
            f"distinct discs of {s.sensing_radius:g} m ({shared} inside two or more discs)",
            f"  regions per point: min {min(per_point, default=0)}, mean {np.mean(per_point or [0]):.2f}, "
            f"max {max(per_point, default=0)}; area {regions.areas.sum():.1f} m² (union), smallest "
            f"{regions.areas.min() if regions.n_regions else 0:.3g} m²",
            f"  prior: Poisson(density x area) per region, mean total {region_means(s).sum():.2f}; "
            f"realised at seed {s.seed}: {int(counts.sum())} features in the union"]


def export(s: Scenario, seed: int | None = None) -> dict:
    """The planner's instance of a scenario (docs/planner.md, "Instance files"): schedules, the
    realised observations at ``seed`` (the scenario's by default) and, under ``reward: coverage``,
    ``reward``, ``regions`` (their Poisson means), ``covers`` and the realised ``counts``."""
    import world
    from planner.instance import Instance, instance_dict

    seed = s.seed if seed is None else int(seed)
    problem = world.build_problem(s)
    x = world.observe_all(s, seed)
    prior = ({"kind": "poisson", "mean": s.derived_prior_mean()} if s.prior.kind == "derived"
             else {"kind": s.prior.kind, **{k: list(v) if isinstance(v, tuple) else v for k, v in s.prior.params}})
    out = {"name": s.name, "comment": f"exported from {s.source or s.name} at seed {seed} (python -m world export)",
           **instance_dict(Instance(problem, x), prior)}
    if s.reward == "coverage":
        from world.regions import region_counts, region_means, scenario_regions

        for key in ("overlaps", "observations"):  # derived from covers and counts
            out.pop(key)
        out["reward"] = "coverage"
        out["regions"] = [{"mean": float(mu)} for mu in region_means(s)]
        out["covers"] = [[None if c is None else list(c) for c in row] for row in scenario_regions(s).covers]
        out["counts"] = region_counts(s, seed=seed).tolist()
    return out


def main(argv: list[str] | None = None, checks: Sequence[Callable[[Scenario], list[Flaw]]] = ()) -> int:
    """The command. ``checks``: further checks of a loaded scenario that ``check`` runs, each
    returning problems with field paths (launcher/scenario_check.py passes the wire's frame
    check, which world/ cannot import)."""
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
    p_export = sub.add_parser("export", help="write the scenario's planner instance (JSON) at a seed")
    p_export.add_argument("scenario")
    p_export.add_argument("-o", "--output", required=True, help="output JSON file")
    p_export.add_argument("--seed", type=int, default=None, help="feature seed (the scenario's by default)")
    _import_parser(sub)
    args = parser.parse_args(argv)
    if args.command == "import":
        return _run_import(args)
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
        problems = [problem for extra in checks for problem in extra(s)]
        for problem in problems:
            print(problem.line(s.source), file=sys.stderr)
        if problems:
            return EXIT_BAD_INPUT
        print(check(s, args.seeds))
        return 0
    if args.command == "export":
        import json
        from pathlib import Path

        try:
            Path(args.output).write_text(json.dumps(export(s, args.seed)) + "\n", encoding="utf-8")
        except OSError as exc:
            print(f"{args.output}: expected a writable JSON path, found {exc.strerror or exc}", file=sys.stderr)
            return EXIT_BAD_INPUT
        print(f"wrote {args.output}")
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


def _pair(kind):
    """argparse type of ``ID=VALUE`` flags (``--odom ID=TOPIC``, ``--passengers ID=K``)."""
    def parse(text: str):
        cid, sep, value = text.partition("=")
        if not sep or not cid or not value:
            raise argparse.ArgumentTypeError(f"expected ID=VALUE, found {text!r}")
        try:
            return cid, kind(value)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected ID={kind.__name__.upper()}, found {text!r}") from None
    return parse


def _positive(kind):
    def parse(text: str):
        try:
            v = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a {'number' if kind is float else 'integer'}, "
                                             f"found {text!r}") from None
        if not math.isfinite(v) or v <= 0:
            raise argparse.ArgumentTypeError(f"expected a value > 0, found {text!r}")
        return v
    return parse


def _cloud(text: str) -> tuple[str, str]:
    """``--cloud-topic [ID=]TOPIC``."""
    cid, sep, topic = text.rpartition("=")
    if not (topic or "").strip() or (sep and not cid):
        raise argparse.ArgumentTypeError(f"expected [ID=]TOPIC, found {text!r}")
    return cid, topic


def _non_negative(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, found {text!r}") from None
    if not math.isfinite(v) or v < 0:
        raise argparse.ArgumentTypeError(f"expected a value >= 0, found {text!r}")
    return v


def _import_parser(sub) -> None:
    from world import importer as imp

    p = sub.add_parser("import", help="a scenario from your own map (map_server YAML) or recorded run (ROS 2 bag)",
                       description="Import a map_server map or a ROS 2 bag as a scenario (docs/scenario.md, "
                                   "\"Your own map and runs\").")
    p.add_argument("source", metavar="SOURCE", help="a map_server map YAML, a ROS 2 bag directory (MCAP or sqlite3), "
                   "an OctoMap file (.bt/.ot) or a folder of PCD/PLY scans with poses.txt")
    p.add_argument("--out", required=True, metavar="SCENARIO.yaml", help="the scenario to write (its map is written "
                   "beside it as NAME.map.yaml and NAME.map.pgm)")
    p.add_argument("--routes", metavar="ROUTES.yaml", help="the carriers' routes: carriers: [{id, passengers, start, "
                   "speed, path}] in the map frame")
    p.add_argument("--map-topic", default="/map", metavar="TOPIC", help="the bag's nav_msgs/msg/OccupancyGrid topic "
                   "(default /map)")
    p.add_argument("--odom", action="append", type=_pair(str), default=[], metavar="ID=TOPIC",
                   help="a carrier's nav_msgs/msg/Odometry or geometry_msgs/msg/PoseStamped topic in the bag "
                        "(repeat per carrier)")
    p.add_argument("--passengers", action="append", type=_pair(int), default=[], metavar="ID=K",
                   help="passengers of a carrier (default: the routes file's, else 1)")
    spacing = p.add_mutually_exclusive_group()
    spacing.add_argument("--stage-spacing", type=_positive(float), metavar="METRES",
                         help="a candidate point every METRES of travelled distance")
    spacing.add_argument("--stages", type=_positive(int), metavar="N", help="N candidate points evenly along each "
                         f"route, first to last (default {imp.DEFAULT_STAGES}, the paper's, unless --stage-spacing)")
    p.add_argument("--radius", type=_positive(float), default=imp.DEFAULT_RADIUS, metavar="METRES",
                   help="the value of a point counts the frontier cells within this radius (default 10 m, the "
                        "paper's); also the scenario's sensing radius")
    p.add_argument("--radii", choices=("paper", "map"), default="paper",
                   help="paper (default): --radius (10 m) and --conflict-radius (3 x radius) as given; map: both "
                        "chosen from the map's size (a quarter of its shorter side, and twice that)")
    p.add_argument("--replay", action="store_true", help="the mission observes the recorded values: each point's "
                   "value in the latest map stamped at or before its time")
    p.add_argument("--report", metavar="REPORT.json", help="write the candidate points and their values")
    p.add_argument("--stage-interval", type=_positive(float), metavar="SECONDS",
                   help="the mission's stage interval (default: the median recorded time between candidates)")
    p.add_argument("--align", choices=("time", "index"), default="time",
                   help="stage of a carrier's first candidate: by its recorded time (default; staggered starts) or 0")
    p.add_argument("--name", help="scenario name (default: the file name)")
    p.add_argument("--seed", type=int, default=0, help="the scenario's root seed (default 0)")
    p.add_argument("--conflict-radius", type=_positive(float), metavar="METRES",
                   help="the scenario's conflict radius (default 3 x radius)")
    p.add_argument("--carrier-radius", type=_positive(float), metavar="METRES",
                   help="the carriers' body radius (default 0.4 m, less where a route passes closer to a wall)")
    p.add_argument("--path-tolerance", type=_positive(float), metavar="METRES",
                   help="Douglas-Peucker tolerance for the routes (default half a map cell)")
    p.add_argument("--wall-tolerance", type=_positive(float), metavar="METRES",
                   help="Douglas-Peucker tolerance for the walls traced round the occupied cells (default half a cell)")
    p.add_argument("--prior", choices=imp.PRIOR_CHOICES, default="auto",
                   help="the prior's family, fitted to the values by moments (default auto: negative binomial when "
                        "the variance exceeds the mean, else Poisson)")
    g3 = p.add_argument_group("3D sources (docs/scenario.md, \"3D maps and scans\")")
    g3.add_argument("--cloud-topic", action="append", type=_cloud, default=[], metavar="[ID=]TOPIC",
                    help="a bag's sensor_msgs/msg/PointCloud2 scans (ID=TOPIC per carrier; TOPIC alone with one carrier)")
    g3.add_argument("--keep-above", type=float, default=1.0, metavar="METRES",
                    help="count frontier voxels more than this above the carrier (default 1.0 m, the paper's)")
    g3.add_argument("--keep-below", type=float, default=0.1, metavar="METRES",
                    help="... or more than this below it (default 0.1 m; --keep-above 0 --keep-below 0 counts all)")
    g3.add_argument("--voxel", type=float, default=None, metavar="METRES",
                    help="voxel size of a map ray cast from scans (default 0.2 m; an OctoMap keeps its own)")
    g3.add_argument("--neighbours", type=int, choices=(6, 26), default=6,
                    help="a frontier voxel has an unknown one among its 6 face (default) or 26 neighbours")
    g3.add_argument("--max-range", type=float, default=-1.0, metavar="METRES",
                    help="longest ray inserted (OctoMap's maxrange; default: every ray whole)")
    g3.add_argument("--sensor-offset", type=float, nargs=3, default=(0.0, 0.0, 0.0), metavar=("X", "Y", "Z"),
                    help="the sensor's position on the carrier's base (m) when /tf_static has no mounting")
    g3.add_argument("--log-odds", type=float, nargs=5, default=(0.7, 0.4, 0.5, 0.1192, 0.971),
                    metavar=("HIT", "MISS", "OCC", "MIN", "MAX"),
                    help="OctoMap's sensor model: prob_hit, prob_miss, occupancy threshold, clamping min and max "
                         "(default OctoMap's 0.7 0.4 0.5 0.1192 0.971)")
    p.add_argument("--graze-depth", type=_non_negative, default=imp.DEFAULT_GRAZE_DEPTH, metavar="METRES",
                   help="a recorded route (a bag's poses, or recorded: true in ROUTES.yaml) may go this far into "
                        f"occupied cells and is taken as driven, with a warning (default {imp.DEFAULT_GRAZE_DEPTH:g} m; "
                        "0: no graze); a hand-written route may not enter an occupied cell")
    p.add_argument("--literal-thresholds", action="store_true",
                   help="read a map YAML's thresholds exactly as map_server does (by default a map with nav2 "
                        "map_saver's signature, trinary with free_thresh 0.25 and pixels 0/205/254, reads its 205 "
                        "pixels as unknown, as the saver meant)")
    p.add_argument("--free-level", type=int, default=None, metavar="0..100",
                   help="a bag map's cell value at or below which it is free (default 25, map_saver's)")
    p.add_argument("--occupied-level", type=int, default=None, metavar="0..100",
                   help="a bag map's cell value at or above which it is occupied (default 65, map_saver's)")


def _unwritable(path: str) -> str | None:
    """Why a file cannot be written at ``path`` (a directory there, or a file among its
    parents), or None."""
    from pathlib import Path

    p = Path(path)
    if p.is_dir():
        return f"the directory {path!r}"
    blocker = next((q for q in p.parents if q.exists() and not q.is_dir()), None)
    return None if blocker is None else f"{path!r} under the file {str(blocker)!r}"


def _run_import(args) -> int:
    from world import grid as G
    from world import importer as imp

    free = G.DEFAULT_FREE_LEVEL if args.free_level is None else args.free_level
    occupied = G.DEFAULT_OCCUPIED_LEVEL if args.occupied_level is None else args.occupied_level
    if not 0 <= free < occupied <= 100:
        print(f"--free-level, --occupied-level: expected 0 <= free < occupied <= 100, found {free}, {occupied}",
              file=sys.stderr)
        return EXIT_BAD_INPUT
    for flag, target in (("--out", args.out), ("--report", args.report)):
        problem = _unwritable(target) if target else None
        if problem:
            print(f"{flag}: expected a file path to write, found {problem}", file=sys.stderr)
            return EXIT_BAD_INPUT
    if args.stages is None and args.stage_spacing is None:
        args.stages = imp.DEFAULT_STAGES
    settings = imp.ImportSettings(
        source=args.source, out=args.out, routes=args.routes, map_topic=args.map_topic, odom=tuple(args.odom),
        passengers=tuple(args.passengers), stage_spacing=args.stage_spacing, stages=args.stages,
        radius=args.radius, replay=args.replay, report=args.report, stage_interval=args.stage_interval,
        align=args.align, name=args.name, seed=args.seed, conflict_radius=args.conflict_radius,
        carrier_radius=args.carrier_radius, path_tolerance=args.path_tolerance,
        wall_tolerance=args.wall_tolerance, prior=args.prior, free_level=free, occupied_level=occupied,
        cloud_topics=tuple(args.cloud_topic), keep_above=args.keep_above, keep_below=args.keep_below,
        voxel=args.voxel, neighbours=args.neighbours, max_range=args.max_range,
        sensor_offset=tuple(args.sensor_offset), log_odds=tuple(args.log_odds),
        graze_depth=args.graze_depth, literal_thresholds=args.literal_thresholds, radii=args.radii)
    if args.stages is not None and args.stages < 2:
        print(f"--stages: expected an integer >= 2 (the first and last point of each route), found {args.stages}",
              file=sys.stderr)
        return EXIT_BAD_INPUT
    try:
        # progress on stdout: on bad input stderr holds exactly the one line naming it
        from world import import3d

        say = lambda line: print(line, flush=True)  # noqa: E731
        if import3d.is_3d(settings):  # an OctoMap, a folder of scans or a bag's point clouds
            result = import3d.import_3d(settings, progress=say)
            written = import3d.write_outputs_3d(settings, result)
        else:
            result = imp.import_run(settings, progress=say)
            written = imp.write_outputs(settings, result)
    except G.GridError as err:
        print(str(err), file=sys.stderr)
        return EXIT_BAD_INPUT
    for line in result.summary:
        print(line)
    print("wrote " + ", ".join(written))
    return 0
