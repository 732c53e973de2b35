"""The shared mission model: scenario files, map, features, pymunk simulation, stage geometry.

Built identically in every process from a scenario file and its seed. Imports neither
``coordinator`` nor ``carriers``.
"""
from world.features import FEATURES_SPAWN_KEY, sample_features
from world.scenario import (
    Building, CarrierSpec, Cluster, FeatureSpec, MapSpec, PlannerSpec, PriorSpec, Scenario,
    ScenarioError, load_scenario, parse_scenario,
)
from world.sim import (
    PHYSICS_DT, SUBSTEPS, Deployment, MissionTrace, Simulation, observe_all, simulate_mission,
)
from world.stages import StageGeometry, stage_geometry


def build_problem(scenario, geometry=None):
    """The planner core's instance of a scenario (:class:`planner.problem.Problem`): schedules,
    overlaps, prior and passenger values (the planner is imported here, lazily, for processes that
    plan)."""
    from planner.problem import Problem

    geometry = stage_geometry(scenario) if geometry is None else geometry
    return Problem.build(scenario.passengers, geometry.valid, geometry.overlaps, scenario.prior_distribution(),
                         weights=scenario.passenger_values())


def render_map(scenario, path, deployments=None, trajectories=None, title=None, **kwargs):
    """Draw the map PNG; see :func:`world.render.render_map` (matplotlib is imported lazily)."""
    from world.render import render_map as _render

    return _render(scenario, path, deployments=deployments, trajectories=trajectories, title=title, **kwargs)


__all__ = [
    "Building", "CarrierSpec", "build_problem", "Cluster", "Deployment", "FEATURES_SPAWN_KEY", "FeatureSpec", "MapSpec",
    "MissionTrace", "PHYSICS_DT", "PlannerSpec", "PriorSpec", "SUBSTEPS", "Scenario", "ScenarioError",
    "Simulation", "StageGeometry", "load_scenario", "observe_all", "parse_scenario", "render_map",
    "sample_features", "simulate_mission", "stage_geometry",
]
