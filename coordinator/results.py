"""What a results directory holds, written the same way by the coordinator (coordinator/node.py)
and by the report (coordinator/report.py): summary.json (atomically) and map.png from a mission
state. One home, so the two never draw or write differently."""
from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np


def write_json(path: Path, data: dict) -> None:
    """Replace ``path`` with ``data`` as JSON atomically (a reader sees the old or the new file)."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data, indent=2, default=jsonable))
    os.replace(tmp, path)


def jsonable(value):
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (np.floating,)):
        return float(value)
    if isinstance(value, np.ndarray):
        return value.tolist()
    return str(value)


def render_map(scenario, state, path, title: str, trails: dict | None = None) -> None:
    """Draw map.png of a mission state: the deployments a carrier reported (its Confirm or its
    account: ``MissionState.confirmed_deployments``, where it released them; with passenger types
    labelled with the type released) and the carriers' actual trajectories (``trails``: carrier -> points; the state's own, from the Observations'
    trails, by default). Raises what ``world.render_map`` raises."""
    import world

    spec = state.spec
    actual = state.confirmed_deployments()
    deployments = [world.Deployment(cid, spec.stage_times[j], state.deployment_position(cid, j))
                   for j in range(spec.n_stages) for r, cid in enumerate(spec.carriers) if actual[r, j]]
    labels = None
    if scenario.passenger_values() is not None:  # passenger types: which type went where
        from planner.problem import fill_releases

        released = fill_releases(spec.passengers, actual, state.releases())
        labels = [scenario.passenger_type(r, int(released[r, j])) or f"#{int(released[r, j])}"
                  for j in range(spec.n_stages) for r, cid in enumerate(spec.carriers) if actual[r, j]]
    trails = state.trails if trails is None else trails
    trajectories = {cid: np.asarray(pts, dtype=float).reshape(-1, 2) for cid, pts in trails.items() if pts}
    world.render_map(scenario, str(path), deployments=deployments, trajectories=trajectories, title=title,
                     deployment_labels=labels)
