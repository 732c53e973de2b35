"""What a coordinator process is set up with, fixed for its run (:class:`MissionSetup`): the
scenario and the problem built from it, the mission id and the carriers, the planner, the
fingerprint, the mission machine's spec, the Zenoh config and where its lines go. The process
object (:class:`coordinator.node.Coordinator`) holds it beside what changes."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import world
from mission import state as ms
from mission.coverage import spec_options
from mission.timeouts import CLOCKS
from planner.registry import make_planner, planner_settings, used_options
from wire import keys
from wire.messages import scenario_fingerprint


@dataclass(frozen=True)
class MissionSetup:
    """A coordinator's mission, fixed for its run.

    Attributes:
        scenario: the loaded scenario (with the run's seed); scenario_path: shown in summary.json.
        seed: the scenario's root seed; mission: the mission id (key-expression prefix).
        ids: carrier ids in scenario order; problem: the planning problem built from the scenario.
        planner_name, planner_options: the planner and the options it uses (logged, stored in
            mission.db, summarised); planner: the planner object.
        fingerprint: hex digest of the scenario (with its seed); spec: the mission machine's spec.
        zconf: the Zenoh config; log: where progress lines go (one string each).
    """

    scenario: Any
    scenario_path: str
    seed: int
    mission: str
    ids: tuple
    problem: Any
    planner_name: str
    planner_options: dict
    planner: Any
    fingerprint: str
    spec: ms.MissionSpec
    zconf: Any
    log: Callable[[str], None]

    @property
    def n_stages(self) -> int:
        return self.problem.n_stages

    @classmethod
    def build(cls, scenario, config, zconf, scenario_path: str = "") -> "MissionSetup":
        """From the loaded ``scenario`` (its seed replaced by ``config.seed`` when given) and the
        coordinator's ``config`` (:class:`coordinator.node.CoordinatorConfig`; a ``ValueError``
        for a clock out of :data:`mission.timeouts.CLOCKS`)."""
        if config.clock not in CLOCKS:
            raise ValueError(f"clock must be one of {CLOCKS}, found {config.clock!r}")
        if config.seed is not None:
            scenario = scenario.with_seed(int(config.seed))
        mission = keys.check_id(config.mission or keys.mission_id_from_name(scenario.name), "mission")
        problem = world.build_problem(scenario)
        name, options = planner_settings(scenario, config.planner, config.iterations, config.plan_ms,
                                         config.planner_options)
        options = used_options(name, options)  # only the options this planner uses are kept
        fingerprint = scenario_fingerprint(scenario)
        ids = scenario.carrier_ids
        spec = ms.MissionSpec.build(ids, problem.valid, problem.passengers, scenario.stage_times(), fingerprint,
                                    **spec_options(problem))
        return cls(scenario, scenario_path or scenario.source, int(scenario.seed), mission, ids, problem, name,
                   options, make_planner(name, **options), fingerprint, spec, zconf,
                   config.log or (lambda line: print(line, flush=True)))
