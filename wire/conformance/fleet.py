"""The kit's carriers, for checking a coordinator (``python -m wire.conformance coordinator``):
the scenario's truth about every carrier (:class:`World`), what each of the kit's carriers has
said and must say next (:class:`Played`), and the messages it sends, built from that state.

A kit carrier is as simple as the page allows: it answers every Decision at once and truthfully
(deployed when selected, scheduled, observed and with a passenger left; refused when selected
otherwise; idle when not selected), observes the next stage right after, and never decides a
stage itself. So whatever the coordinator under test decides can be judged against what the
carriers told it."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .. import keys
from .. import messages as wm


@dataclass(frozen=True, eq=False)
class World:
    """The scenario's truth about every carrier.

    Attributes:
        scenario_path: the scenario file, absolute; ``scenario``: loaded, with the kit's seed.
        seed: the root seed; ``mission``: the mission id (key prefix ``marsupial/<mission>/``).
        ids: the carrier ids, in the scenario's order; ``n``: stages; ``times``: t_j, s, [n].
        valid: bool [R, n], scheduled at stage j; ``x``: int or None [R][n], what each senses.
        positions: (x, y) [R][n], metres, where each is at t_j.
        passengers: passengers each starts with, [R]; ``fingerprint``: the world's.
    """

    scenario_path: str
    scenario: Any
    seed: int
    mission: str
    ids: tuple[str, ...]
    n: int
    times: tuple[float, ...]
    valid: Any
    x: tuple[tuple[int | None, ...], ...]
    positions: tuple[tuple[tuple[float, float], ...], ...]
    passengers: tuple[int, ...]
    fingerprint: str

    @classmethod
    def load(cls, scenario_path: str, seed: int | None = None, mission: str | None = None) -> World:
        import world

        path = str(Path(scenario_path).resolve())
        scenario = world.load_scenario(path)
        if seed is not None:
            scenario = scenario.with_seed(int(seed))
        trace = world.simulate_mission(scenario)
        times = tuple(float(t) for t in scenario.stage_times())
        positions = []
        for samples in trace.trajectories:  # (t, x, y) rows, one per simulated second
            at = [min(int(np.searchsorted(samples[:, 0], t)), len(samples) - 1) for t in times]
            positions.append(tuple((float(samples[k, 1]), float(samples[k, 2])) for k in at))
        x = tuple(tuple(None if np.isnan(v) else int(v) for v in row) for row in trace.x)
        return cls(scenario_path=path, scenario=scenario, seed=int(scenario.seed),
                   mission=mission or keys.mission_id_from_name(scenario.name), ids=tuple(scenario.carrier_ids),
                   n=int(scenario.stages), times=times, valid=scenario.valid(), x=x, positions=tuple(positions),
                   passengers=tuple(int(c.passengers) for c in scenario.carriers),
                   fingerprint=wm.scenario_fingerprint(scenario))

    def must_deploy(self, r: int, j: int, left: int, observed: bool) -> bool:
        """The forced rule (docs/protocol.md, [P-6]): stage j is valid (scheduled and observed),
        a passenger is left and no more valid stages remain than passengers."""
        if not (observed and self.valid[r][j] and left > 0):
            return False
        return int(np.count_nonzero(self.valid[r][j:])) <= left


@dataclass
class Played:
    """One of the kit's carriers: what it has said and where it is.

    Attributes:
        r: its index; ``cid``: its id.
        left: passengers on board; ``deployments``: stages it deployed at.
        next_stage: the stage it observes next (n after its last).
        joined: its Hello was sent (the kit waits for no answer to go on, as the page allows).
        observed: stage -> x it sent in its Observation of that stage.
        answered: stage -> its Confirm's status.
        left_before: stage -> passengers on board when it observed that stage.
        silent: it has stopped sending anything (its token stays).
        done: it said Bye.
    """

    r: int
    cid: str
    left: int
    deployments: list = field(default_factory=list)
    next_stage: int = 0
    joined: bool = False
    observed: dict = field(default_factory=dict)
    answered: dict = field(default_factory=dict)
    left_before: dict = field(default_factory=dict)
    silent: bool = False
    done: bool = False
    token: Any = None
    revision: int = wm.REVISION  # the revision it speaks (an older carrier: no Hello revision, no Progress)

    @property
    def active(self) -> bool:
        return self.joined and not self.silent and not self.done

    def hello(self, w: World, next_stage: int, epoch: int) -> wm.Hello:
        return wm.Hello(w.mission, self.cid, 0, "conformance-kit", self.left, next_stage, w.fingerprint,
                        epoch=max(1, epoch), revision=self.revision)

    def observation(self, w: World, j: int) -> wm.Observation:
        x = w.x[self.r][j] if w.valid[self.r][j] else None
        self.observed[j], self.left_before[j] = x, self.left
        return wm.Observation(w.mission, self.cid, j, w.times[j], x, w.positions[self.r][j], self.left, ())

    def confirm(self, w: World, d: wm.Decision) -> wm.Confirm:
        """Its answer to Decision ``d`` (a stage it observed), its passengers counted down."""
        j = d.stage
        selected = self.cid in d.deploy
        can = self.observed.get(j) is not None and self.left > 0
        status = "idle" if not selected else ("deployed" if can else "refused")
        if status == "deployed":
            self.left -= 1
            self.deployments.append(j)
        self.answered[j] = status
        named = d.passenger_of(self.cid) if status == "deployed" else None
        return wm.Confirm(w.mission, self.cid, j, status == "deployed", status, w.positions[self.r][j], self.left,
                          passenger=named)

    def progress(self, w: World) -> wm.Progress:
        j = min(self.next_stage, w.n)
        return wm.Progress(w.mission, self.cid, j, w.times[j - 1] if j > 0 else 0.0)

    def bye(self, w: World) -> wm.Bye:
        self.done = True
        return wm.Bye(w.mission, self.cid, tuple(sorted(self.deployments)), (), "end")

    def key(self, w: World, topic: str) -> str:
        return keys.carrier_key(w.mission, self.cid, topic)
