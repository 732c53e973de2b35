"""What a results directory holds, written the same way by the coordinator (coordinator/node.py)
and by the report (coordinator/report.py): summary.json (atomically) and map.png from a mission
state. One home, so the two never draw or write differently."""
from __future__ import annotations

import dataclasses
import json
import os
import socket
from pathlib import Path

import numpy as np

from mission.summary import RunInfo, summary as mission_summary
from mission.timeouts import DEFAULTS

#: Rejections that are denials of a carrier's authority, counted per sender in summary.json's
#: ``denials`` (docs/protocol.md [P-13.2]): a value out of range, a message about another carrier.
DENIED = {"out-of-range": "P-13.2", "key-mismatch": "P-13.2"}


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


def result_line(summary: dict | None) -> str:
    """The picture's line of results: the reward and how it stands against its bound (the
    console's words, :func:`mission.summary.bound_text`)."""
    from mission.summary import bound_text

    if not summary:
        return ""
    return (f"reward {summary['total_reward']:.3f} (features {summary['total_features']:.1f}); "
            + bound_text(summary, short=True))


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


class Results:
    """The coordinator's results at the end of its run (summary.json, map.png): a collaborator of
    :class:`coordinator.node.Coordinator` given the run's own facts at the start (``info``, a
    :class:`mission.summary.RunInfo` without its wall time and rejections) and what it writes
    from at the end.

    Args:
        scenario: the scenario (map.png, the title); render: draw map.png; log: a callable taking
        one line; epochs: the coordinator's :class:`coordinator.epochs.Epochs` (its epoch, whether
        it was deposed); recording: its :class:`coordinator.recorder.Recording`; out: the results
        directory; problem: the planning problem (the summary's bound); answers: its
        :class:`coordinator.answers.Answers` (what it rejected of each carrier, read at the end).
    """

    def __init__(self, scenario, info: RunInfo, render: bool, log, epochs, recording, out: Path, problem, answers):
        self.scenario, self.info, self.render, self.log = scenario, info, render, log
        self.epochs, self.recording, self.out, self.problem = epochs, recording, Path(out), problem
        self.answers = answers

    def finish(self, wall_s: float, state, node, store) -> dict:
        """summary.json twice: at once without the clairvoyant bound, then with it, each write
        atomic, so a coordinator killed while the bound is computed (its launcher's grace after
        Ctrl-C is a few seconds) still leaves a complete summary.json, and mission.mcap
        (``recording``) is finalised in between; map.png; then the session (``node``) and the
        store are closed. A deposed coordinator writes no summary.json or map.png: the results
        are the newer coordinator's (which may share this --out directory)."""
        epochs, out, problem, told = self.epochs, self.out, self.problem, self.answers.counts
        deposed = epochs.deposed_by is not None
        rejected = dict(node.rejected) if node else {}
        self.planner_faults = store.planner_faults()
        if not deposed:
            write_json(out / "summary.json", self.summary(state, problem, epochs, rejected, wall_s, told,
                                                                  bound=False))
        self.recording.close()
        summary = self.summary(state, problem, epochs, rejected, wall_s, told, bound=not deposed)
        if not deposed:
            write_json(out / "summary.json", summary)
        if node is not None:
            node.close(DEFAULTS.close_s)
        if self.render and not deposed:
            self._render(state, out / "map.png", summary)
        store.close()
        return summary

    def summary(self, state, problem, epochs, rejected: dict, wall_s: float, told: dict | None = None,
                bound: bool = True) -> dict:
        """``told``: carrier id -> its messages rejected, per reason (coordinator.answers.Answers.counts)."""
        out = mission_summary(state, problem, dataclasses.replace(self.info, wall_time_s=wall_s, rejected=rejected),
                              bound=bound)
        out["epoch"] = epochs.epoch  # of the coordinator that wrote this summary (docs/fleet.md)
        # Stages a planner plug-in failed and SSAP decided (mission.decide.FALLBACK_PLANNER).
        out["planner_faults"] = list(getattr(self, "planner_faults", []))
        # Denials with their sender: carriers' claims of an epoch above this coordinator's [P-7.3],
        # and their messages refused for range or role ([P-13.2]), counted per reason.
        out["denials"] = [{"sender": cid, "rule": "P-7.3", "what": "epoch claimed in a Hello", "value": epoch}
                          for cid, epoch in sorted(epochs.claims.items())]
        out["denials"] += [{"sender": cid, "rule": DENIED[reason], "what": reason, "count": n}
                           for cid, counts in sorted((told or {}).items())
                           for reason, n in sorted(counts.items()) if reason in DENIED]
        if epochs.deposed_by is not None:
            out["deposed_by"] = epochs.deposed_by
        return out

    def _render(self, state, path: Path, summary: dict | None = None) -> None:
        try:
            render_map(self.scenario, state, path,
                       title=f"{self.scenario.name}: {self.info.planner}, seed {self.info.seed}\n"
                             + result_line(summary))
        except Exception as exc:
            self.log(f"coordinator: map.png not drawn: {type(exc).__name__}: {exc}")


def results_for(setup, config, epochs, recording, answers) -> Results:
    """The :class:`Results` of a coordinator of ``setup`` (:class:`coordinator.setup.MissionSetup`)
    and ``config`` (its ``CoordinatorConfig``: the results directory, whether to draw map.png),
    with this process's facts (pid, host). map.png is drawn from the run's scenario (its seed the
    run's: the features the carriers observed)."""
    scenario = setup.scenario
    return Results(scenario, RunInfo(
        scenario=scenario.name, scenario_file=str(setup.scenario_path), mission=setup.mission,
        planner=setup.planner_name, planner_options=setup.planner_options, seed=setup.seed, pid=os.getpid(),
        host=socket.gethostname(), passenger_types=tuple(c.passenger_types for c in scenario.carriers)),
        config.render, setup.log, epochs, recording, Path(config.out_dir), setup.problem, answers)
