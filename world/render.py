"""Map pictures (matplotlib, PNG): walls, features, paths, decision points, overlaps, deployments."""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Iterable, Mapping

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.patches import Circle, Patch, Polygon, Rectangle  # noqa: E402

from world.features import sample_features  # noqa: E402
from world.geometry import visible_region  # noqa: E402
from world.stages import stage_geometry  # noqa: E402

from world.scene import CARRIER_COLOURS, OVERLAP_COLOUR, convex_hull  # noqa: E402  (one home for colours and hulls)


def _colour(r: int) -> str:
    return CARRIER_COLOURS[r % len(CARRIER_COLOURS)]


def _nice_length(span: float) -> float:
    """A round scale-bar length near a fifth of ``span`` (m)."""
    target = span / 5
    base = 10 ** math.floor(math.log10(target))
    for m in (5, 2, 1):
        if m * base <= target:
            return m * base
    return base


def _stage_labels(ax, scenario, geo, near: float) -> None:
    """Stage numbers beside the decision points, without overlaps: a carrier's stages at one
    spot (waiting) are written once as a list or range (``0-3``), and the labels of points
    within ``near`` (m) of each other are stacked in their carriers' colours."""
    from scipy.cluster.hierarchy import fcluster, linkage

    entries = []  # (x, y, carrier, stages)
    for r in range(scenario.n_carriers):
        js = np.flatnonzero(geo.valid[r])
        groups: list[list[int]] = []
        for j in js:
            if groups and np.hypot(*(geo.positions[r, j] - geo.positions[r, groups[-1][-1]])) <= 1e-6 * max(1.0, near):
                groups[-1].append(int(j))
            else:
                groups.append([int(j)])
        for g in groups:
            entries.append((*geo.positions[r, g[0]], r, g))
    if not entries:
        return
    pts = np.array([[e[0], e[1]] for e in entries])
    cluster = fcluster(linkage(pts, "single"), near, "distance") if len(pts) > 1 else np.array([1])
    stacked: dict[int, int] = {}
    for (x, y, r, g), c in zip(entries, cluster):
        k = stacked[c] = stacked.get(c, -1) + 1
        text = str(g[0]) if len(g) == 1 else (f"{g[0]}-{g[-1]}" if g[-1] - g[0] == len(g) - 1
                                              else ",".join(map(str, g)))
        anchor = pts[cluster == c].mean(axis=0)
        ax.annotate(text, anchor, xytext=(4, 3 + 7.5 * k), textcoords="offset points", fontsize=6.5,
                    color=_colour(r), zorder=8)


def _deployment_spots(scenario, deployments: Any, positions: np.ndarray) -> list[tuple[int, tuple[float, float]]]:
    """Normalise ``deployments`` to a list of (carrier index, (x, y))."""
    if deployments is None:
        return []
    arr = np.asarray(deployments) if not isinstance(deployments, (list, tuple)) else None
    if arr is not None and arr.dtype == bool:
        return [(int(r), tuple(positions[r, j])) for r, j in np.argwhere(arr) if np.isfinite(positions[r, j]).all()]
    out = []
    for d in deployments:
        if hasattr(d, "carrier"):
            cid, pos = d.carrier, d.position
        else:
            cid, pos = d
        r = scenario.carrier_index(cid) if isinstance(cid, str) else int(cid)
        out.append((r, (float(pos[0]), float(pos[1]))))
    return out


def _trajectory_list(scenario, trajectories: Any) -> list[tuple[int, np.ndarray]]:
    if trajectories is None:
        return []
    if isinstance(trajectories, Mapping):
        items: Iterable = ((scenario.carrier_index(k) if isinstance(k, str) else int(k), v) for k, v in trajectories.items())
    else:
        items = enumerate(trajectories)
    out = []
    for r, tr in items:
        tr = np.asarray(tr, dtype=float)
        if tr.ndim == 2 and len(tr) >= 2:
            out.append((r, tr[:, -2:] if tr.shape[1] >= 3 else tr))
    return out


#: Free, occupied, unknown cells (world.grid's classes) under the map.
_OCCUPANCY_COLOURS = ("#ffffff", "#4a4a4a", "#d9d6cf")
#: Largest side of the occupancy image drawn (cells): a larger grid is drawn every k-th cell.
_MAX_IMAGE_SIDE = 2000


def _draw_occupancy(ax, grid) -> None:
    """The occupancy grid under everything: each cell's class in its colour, placed by the grid's
    origin and yaw."""
    from matplotlib.colors import ListedColormap
    from matplotlib.transforms import Affine2D

    k = max(1, int(np.ceil(max(grid.shape) / _MAX_IMAGE_SIDE)))
    cls = grid.classes[::k, ::k]
    h, w = cls.shape
    x0, y0, yaw = grid.origin
    size = grid.resolution * k
    im = ax.imshow(cls, origin="lower", cmap=ListedColormap(_OCCUPANCY_COLOURS), vmin=0, vmax=2,
                   extent=(0.0, w * size, 0.0, h * size), interpolation="nearest", zorder=0.5)
    im.set_transform(Affine2D().rotate(yaw).translate(x0, y0) + ax.transData)


def _draw_links(ax, scenario) -> list:
    """The base (the coordinator's antenna or modem) and the relays the carriers drop
    (world/relays.py), when the scenario has a link model; their legend entries."""
    if scenario.links.model == "perfect":
        return []
    from world.links import LinkModel
    from world.relays import fleet_relays

    model = LinkModel(scenario)
    ax.plot(*model.base, marker="P", ms=11, color="#1a1a1a", mec="white", mew=0.8, zorder=9)
    handles = [Line2D([], [], color="none", marker="P", mfc="#1a1a1a", mec="white", ms=9,
                      label=f"base ({scenario.links.model} links)")]
    relays = fleet_relays(model)
    for relay in relays:
        ax.plot(*relay.position, marker="^", ms=8, color=_colour(scenario.carrier_index(relay.carrier)), mec="black",
                mew=0.6, zorder=9)
    if relays:
        handles.append(Line2D([], [], color="none", marker="^", mfc="#888888", mec="black", ms=7,
                              label=f"relay ({len(relays)})"))
    return handles


def _draw_candidate_discs(ax, scenario):
    """The coverage reward's candidate discs (world/regions.py), faint: where they overlap the
    shading deepens, so the arrangement's regions show. Returns the regions."""
    from matplotlib.collections import PatchCollection

    from world.regions import scenario_regions

    regions = scenario_regions(scenario)
    discs = [Circle((float(x), float(y)), scenario.sensing_radius) for x, y in regions.centres]
    ax.add_collection(PatchCollection(discs, fc=OVERLAP_COLOUR, alpha=0.08, ec=OVERLAP_COLOUR, lw=0.5, zorder=4))
    return regions


def render_map(scenario, path: str | Path, deployments: Any = None, trajectories: Any = None,
               title: str | None = None, positions: np.ndarray | None = None,
               features: np.ndarray | None = None, stage_labels: bool = True, dpi: int = 130,
               deployment_labels: Any = None) -> Path:
    """Draw the scenario's map to a PNG.

    Args:
        scenario: the mission.
        path: output file (.png).
        deployments: bool ``[R, N]`` (drawn at ``positions``, the planned points by default) or a
            sequence of :class:`world.Deployment` / ``(carrier_id, (x, y))``.
        trajectories: actual paths, ``{carrier_id: [K, 2 or 3]}`` or a sequence in carrier order
            (e.g. ``MissionTrace.trajectories``; the last two columns are x, y in m).
        title: figure title (the scenario name by default).
        positions: float ``[R, N, 2]`` actual decision-point positions for bool deployments (m).
        features: float ``[F, 2]`` (sampled from the scenario's seed by default).
        stage_labels: write the stage number next to each decision point.
        dpi: resolution.
        deployment_labels: text written next to each deployment of a sequence ``deployments``,
            in the same order (passenger types: the released passenger's type); None: none.

    Returns:
        The path written.
    """
    if scenario.map.voxels is not None or scenario.map.storeys:
        return render_map_3d(scenario, path, deployments, trajectories, title, positions, dpi)
    geo = stage_geometry(scenario)
    feats = sample_features(scenario) if features is None else np.asarray(features)
    xmin, ymin, xmax, ymax = scenario.map.bounds
    w, h = xmax - xmin, ymax - ymin
    fig_w = 11.0
    fig_h = max(4.5, min(11.0, 8.2 * h / w + 1.2))
    fig, ax = plt.subplots(figsize=(fig_w, fig_h))
    ax.set_aspect("equal")
    ax.set_xlim(xmin - 0.02 * w, xmax + 0.02 * w)
    ax.set_ylim(ymin - 0.02 * h, ymax + 0.02 * h)
    ax.set_facecolor("#fbfbf8")
    ax.add_patch(Rectangle((xmin, ymin), w, h, fill=False, ec="#999999", lw=0.8, ls=":"))
    if scenario.map.occupancy is not None:
        _draw_occupancy(ax, scenario.map.occupancy)

    # clusters (denser feature regions)
    for cl in scenario.features.clusters:
        if cl.shape == "disc":
            cx, cy, rad = cl.params
            ax.add_patch(Circle((cx, cy), rad, color="#f4c542", alpha=0.25, lw=0))
            lx, ly = cx, cy + rad
        else:
            x1, y1, x2, y2 = cl.params
            ax.add_patch(Rectangle((x1, y1), x2 - x1, y2 - y1, color="#f4c542", alpha=0.22, lw=0))
            lx, ly = (x1 + x2) / 2, y2
        if cl.label:
            ax.text(lx, ly, cl.label, ha="center", va="bottom", fontsize=7, color="#8a6d00", style="italic")

    # obstacles and walls
    for poly in scenario.map.obstacles:
        ax.add_patch(Polygon(poly, closed=True, fc="#c9c9c9", ec="#333333", lw=1.2))
    segs = scenario.map.segments
    if len(segs):
        from matplotlib.collections import LineCollection

        ax.add_collection(LineCollection(segs.reshape(-1, 2, 2), colors="#222222", linewidths=1.8, zorder=3))

    # features
    if len(feats):
        ax.scatter(feats[:, 0], feats[:, 1], s=5, c="#6b6b6b", alpha=0.7, lw=0, zorder=2)

    # overlap groups: translucent hulls (3+ points) or thick bands (2 or collinear points); under
    # the coverage reward the candidate discs instead, lightly: their overlaps are the regions
    pos = geo.positions
    regions = _draw_candidate_discs(ax, scenario) if scenario.reward == "coverage" else None
    for group in (geo.overlaps if regions is None else ()):
        pts = np.array([pos[r, j] for r, j in group])
        hull = convex_hull(pts)
        if np.ptp(pts, axis=0).max() < 0.01 * max(w, h):
            # (nearly) coincident points: a ring round them
            ax.plot(*pts.mean(axis=0), marker="o", ms=15, mfc=OVERLAP_COLOUR, alpha=0.25, mec=OVERLAP_COLOUR,
                    mew=1.5, zorder=4)
        elif hull is not None:
            ax.add_patch(Polygon(hull, closed=True, fc=OVERLAP_COLOUR, alpha=0.10, ec=OVERLAP_COLOUR, lw=0.8,
                                 zorder=4))
        else:
            order = np.lexsort((pts[:, 1], pts[:, 0]))
            ax.plot(pts[order, 0], pts[order, 1], color=OVERLAP_COLOUR, alpha=0.35, lw=7,
                    solid_capstyle="round", zorder=4)

    # planned paths and decision points; start labels of carriers sharing a start are stacked
    starts_seen: dict[tuple[float, float], int] = {}
    for r, c in enumerate(scenario.carriers):
        col = _colour(r)
        wp = np.asarray(c.waypoints)
        ax.plot(wp[:, 0], wp[:, 1], color=col, lw=1.4, alpha=0.55, zorder=5)
        ax.plot(wp[0, 0], wp[0, 1], marker="s", ms=7, color=col, mec="black", mew=0.6, zorder=7)
        key = (round(float(wp[0, 0]), 3), round(float(wp[0, 1]), 3))
        k = starts_seen[key] = starts_seen.get(key, -1) + 1
        left = wp[0, 0] - xmin < 0.1 * w  # near the left edge the label goes right of the start, inside
        ax.annotate(c.id, wp[0], xytext=(5 if left else -5, -4 - 10 * k), textcoords="offset points",
                    ha="left" if left else "right", va="top", fontsize=8, fontweight="bold", color=col, zorder=8)
        ok = geo.valid[r]
        if ok.any():
            ax.scatter(pos[r, ok, 0], pos[r, ok, 1], s=26, c=col, edgecolors="white", linewidths=0.7, zorder=6)
    if stage_labels:
        _stage_labels(ax, scenario, geo, 0.012 * max(w, h))

    link_handles = _draw_links(ax, scenario)

    # actual trajectories
    for r, tr in _trajectory_list(scenario, trajectories):
        ax.plot(tr[:, 0], tr[:, 1], color=_colour(r), lw=1.0, ls="--", alpha=0.9, zorder=6)

    # deployments with the passenger's sensing disc
    spot_pos = geo.positions if positions is None else np.asarray(positions)
    spots = _deployment_spots(scenario, deployments, spot_pos)
    labels = list(deployment_labels) if deployment_labels is not None else []
    for k, (r, (x, y)) in enumerate(spots):
        col = _colour(r)
        # what the passenger senses: the disc cut by the walls (line of sight, as the world counts)
        seen = visible_region((x, y), scenario.sensing_radius, segs)
        ax.add_patch(Polygon(seen, closed=True, fc=col, alpha=0.15, ec=col, lw=1.2, ls="--", zorder=5))
        ax.plot(x, y, marker="*", ms=14, color=col, mec="black", mew=0.7, zorder=9)
        if k < len(labels) and labels[k]:
            ax.text(x + 0.012 * w, y - 0.012 * h, str(labels[k]), fontsize=8, fontweight="bold", color="black",
                    ha="left", va="top", zorder=10,
                    bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": col, "lw": 0.8, "alpha": 0.85})

    # scale bar: outside the map, under the legend, so that it hides nothing
    from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar

    bar = _nice_length(w)
    ax.add_artist(AnchoredSizeBar(ax.transData, bar, f"{bar:g} m", loc="lower left", bbox_to_anchor=(1.02, 0.0),
                                  bbox_transform=ax.transAxes, frameon=False, size_vertical=0.006 * h,
                                  borderpad=0.0, sep=4, fontproperties={"size": 9, "weight": "bold"}))

    # legend
    handles = [Line2D([], [], color=_colour(r), lw=2, marker="o", ms=5, label=f"{c.id} ({c.passengers} pass.)")
               for r, c in enumerate(scenario.carriers)]
    handles += [
        Line2D([], [], color="none", marker="s", mfc="white", mec="black", ms=7, label="start"),
        Line2D([], [], color="none", marker="o", mfc="#888888", mec="white", ms=6, label="decision point (stage no.)"),
        Line2D([], [], color="none", marker="o", mfc="#6b6b6b", mec="none", ms=3,
               label=(f"frontier cell ({len(feats)})" if scenario.features.from_map or scenario.replays
                      else f"feature ({len(feats)})")),
        Patch(fc=OVERLAP_COLOUR, alpha=0.25, ec=OVERLAP_COLOUR, label=f"overlap group ({len(geo.overlaps)})")
        if regions is None else
        Patch(fc=OVERLAP_COLOUR, alpha=0.08, ec=OVERLAP_COLOUR, label=f"candidate disc ({len(regions.centres)}; "
                                                                        f"{regions.n_regions} regions)"),
    ]
    if len(segs):
        handles.append(Line2D([], [], color="#222222", lw=2, label="wall"))
    if scenario.map.obstacles:
        handles.append(Patch(fc="#c9c9c9", ec="#333333", label="obstacle"))
    if scenario.features.clusters:
        handles.append(Patch(fc="#f4c542", alpha=0.4, label="feature cluster"))
    if scenario.map.occupancy is not None:
        handles += [Patch(fc=_OCCUPANCY_COLOURS[k], ec="#999999", lw=0.4, label=f"{name} cell")
                    for k, name in ((0, "free"), (2, "unknown"), (1, "occupied"))]
    handles += link_handles
    if trajectories is not None:
        handles.append(Line2D([], [], color="#444444", lw=1, ls="--", label="actual trajectory"))
    if spots:
        handles.append(Line2D([], [], color="none", marker="*", mfc="#888888", mec="black", ms=12,
                              label=f"deployment ({len(spots)}) + sensing disc"))
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False,
              borderaxespad=0.0)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.tick_params(labelsize=8)
    n_valid = int(geo.valid.sum())
    sub = (f"R = {scenario.n_carriers}, N = {scenario.stages} stages every {scenario.stage_interval:g} s, "
           f"{n_valid} decision points, sensing {scenario.sensing_radius:g} m, conflict {scenario.conflict_radius:g} m")
    ax.set_title(f"{title or scenario.name}\n{sub}", fontsize=10)
    fig.tight_layout()
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=dpi, bbox_inches="tight", pad_inches=0.15)  # nothing clipped: labels, legend, bar
    plt.close(fig)
    return out


#: A storey's top view draws the occupied voxels from 0.1 m to this height above its base (m).
TOP_VIEW_HEIGHT = 2.5


def render_map_3d(scenario, path: str | Path, deployments: Any = None, trajectories: Any = None,
                  title: str | None = None, positions: np.ndarray | None = None, dpi: int = 130) -> Path:
    """A 3D import's map (``map.voxels``, ``map.storeys``) as a top view, one panel per storey:
    the occupied voxels from 0.1 m to TOP_VIEW_HEIGHT above the storey's base (under the next
    storey) coloured by their highest voxel's height, the storey's walls, the frontier voxels its carriers' values retain (within
    the sensing radius of one of its decision points and passing the height filter; the others of
    that height range in grey), and its carriers' routes, decision points and deployments."""
    from scipy.spatial import cKDTree

    from world import voxels as V

    geo = stage_geometry(scenario)
    m = scenario.map
    grid = V.read_octomap(m.voxels.path) if m.voxels is not None else None
    storeys = list(m.storeys) or [None]
    n = len(storeys)
    xmin, ymin, xmax, ymax = m.bounds
    w, h = xmax - xmin, ymax - ymin
    fig, axes = plt.subplots(1, n, figsize=(min(7.0 * n, 20.0) + 2.0, max(4.0, min(9.0, 6.0 * h / w + 1.5))),
                             squeeze=False)
    pos = geo.positions if positions is None else np.asarray(positions)
    spots = _deployment_spots(scenario, deployments, pos)
    tracks = dict(_trajectory_list(scenario, trajectories))
    front = zc = None
    if grid is not None:
        front = grid.centres(V.frontier_mask(grid.classes, m.voxels.neighbours))
        zc = grid.lower[2] + (np.arange(grid.shape[2]) + 0.5) * grid.resolution
    image = None
    for k, (ax, st) in enumerate(zip(axes[0], storeys)):
        base = st.base if st is not None else -np.inf
        top = storeys[k + 1].base if st is not None and k + 1 < n else np.inf
        ax.set_aspect("equal")
        ax.set_xlim(xmin, xmax)
        ax.set_ylim(ymin, ymax)
        ax.set_facecolor("#fbfbf8")
        mine = [r for r, c in enumerate(scenario.carriers) if st is None or c.storey == st.name]
        if grid is not None:
            # below the ceiling: the storey's walls and what stands on its floor
            band = (zc > base + 0.1) & (zc < min(top, base + TOP_VIEW_HEIGHT)) if st is not None else zc > -np.inf
            occ = grid.classes[:, :, band] == V.OCCUPIED
            height = np.where(occ.any(axis=2), zc[band][np.argmax(occ[:, :, ::-1], axis=2) * -1 + occ.shape[2] - 1],
                              np.nan)
            x0, y0, _, x1, y1, _ = grid.extent
            image = ax.imshow(height.T, origin="lower", extent=(x0, x1, y0, y1), cmap="viridis", alpha=0.85, vmin=float(zc[0]), vmax=float(zc[-1]),
                              interpolation="nearest", zorder=1)
            inside = front[(front[:, 2] >= base - 1.0) & (front[:, 2] < top)] if st is not None else front
            pts = np.array([[pos[r, j, 0], pos[r, j, 1], base if st is not None else 0.0]
                            for r in mine for j in np.flatnonzero(geo.valid[r])]).reshape(-1, 3)
            keep = np.zeros(len(front), dtype=bool)
            if len(pts):
                near = cKDTree(pts).query(front, distance_upper_bound=scenario.sensing_radius)[0] <= scenario.sensing_radius
                keep = near & V.kept(front[:, 2] - (base if st is not None else 0.0), m.voxels.keep_above,
                                     m.voxels.keep_below)
            ax.scatter(inside[:, 0], inside[:, 1], s=0.8, c="#9a9a9a", lw=0, alpha=0.4, zorder=2)
            ax.scatter(front[keep, 0], front[keep, 1], s=1.0, c="#d62728", lw=0, alpha=0.35, zorder=2)
            ax.text(0.01, 0.01, f"frontier voxels retained: {int(keep.sum())}", transform=ax.transAxes, fontsize=8,
                    va="bottom", bbox={"fc": "white", "ec": "none", "alpha": 0.8}, zorder=10)
        segs = m.carrier_segments(st.name if st is not None else "")
        if len(segs):
            from matplotlib.collections import LineCollection

            ax.add_collection(LineCollection(segs.reshape(-1, 2, 2), colors="#222222", linewidths=1.2, zorder=3))
        for r in mine:
            c = scenario.carriers[r]
            col = _colour(r)
            wp = np.asarray(c.waypoints)
            ax.plot(wp[:, 0], wp[:, 1], color=col, lw=1.6, alpha=0.8, zorder=5, label=f"{c.id} ({c.passengers} pass.)")
            ok = geo.valid[r]
            ax.scatter(pos[r, ok, 0], pos[r, ok, 1], s=22, c=col, edgecolors="white", linewidths=0.7, zorder=6)
            if r in tracks:
                ax.plot(tracks[r][:, 0], tracks[r][:, 1], color=col, lw=1.0, ls="--", zorder=6)
        for r, (x, y) in spots:
            if r in mine:
                ax.plot(x, y, marker="*", ms=14, color=_colour(r), mec="black", mew=0.7, zorder=9)
        name = f"storey {st.name} (base z {st.base:g} m)" if st is not None else "map"
        ax.set_title(name, fontsize=10)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.tick_params(labelsize=8)
        if mine:
            ax.legend(loc="upper right", fontsize=7, framealpha=0.8)
    if image is not None:
        fig.colorbar(image, ax=list(axes[0]), shrink=0.8, label="highest occupied voxel (m)")
    fig.suptitle(f"{title or scenario.name}: top view; red = frontier voxels the values retain "
                 f"(> {m.voxels.keep_above:g} m above or > {m.voxels.keep_below:g} m below the carrier), "
                 "stars = deployments" if m.voxels is not None else (title or scenario.name), fontsize=10)
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=dpi)
    plt.close(fig)
    return out
