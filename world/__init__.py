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
    if scenario.reward == "coverage":
        # The regions of the candidate discs (world/regions.py); the point prior is the derived
        # one, the mean of a point's sum of region means (density x pi r^2).
        from world.regions import coverage

        cov = coverage(scenario)
        return Problem.build(scenario.passengers, geometry.valid, cov.overlaps(scenario.stages),
                             scenario.prior_distribution(), weights=scenario.passenger_values(), coverage=cov)
    return Problem.build(scenario.passengers, geometry.valid, geometry.overlaps, scenario.prior_distribution(),
                         weights=scenario.passenger_values())


def observe_counts(scenario, seed=None):
    """int64 ``[M]``: the realised region counts of a ``reward: coverage`` scenario (the features of
    ``seed``, the scenario's by default, in each region); None under the penalty reward."""
    if scenario.reward != "coverage":
        return None
    from world.regions import region_counts

    return region_counts(scenario, seed=seed)


def offline_mission(scenario, planner=None, iterations=None, workers: int = 1, x=None):
    """``(result, x)``: what a fault-free fleet flying ``scenario`` must reproduce exactly — the
    planner core (:func:`planner.online.run_online`, the scenario's planner unless ``planner`` or
    ``iterations`` say otherwise) over the fault-free observations ``x``
    (:func:`observe_all`, the carriers' physics spread over ``workers`` processes). The fleet's
    fidelity tests hold the fleet to it (tests/test_fidelity.py, on a saturated host too).
    ``x`` given: the observations the coordinator had instead (float ``[R, N]``, NaN = ∅: a late
    or refused one), what the fleet must then reproduce."""
    import numpy as np

    from planner.online import run_online
    from planner.registry import make_planner, planner_settings

    name, options = planner_settings(scenario, planner, iterations)
    x = observe_all(scenario, workers=workers) if x is None else np.asarray(x, dtype=float)
    return run_online(build_problem(scenario), x, make_planner(name, **options), scenario.seed,
                      counts=observe_counts(scenario)), x


def render_map(scenario, path, deployments=None, trajectories=None, title=None, **kwargs):
    """Draw the map PNG; see :func:`world.render.render_map` (matplotlib is imported lazily)."""
    from world.render import render_map as _render

    return _render(scenario, path, deployments=deployments, trajectories=trajectories, title=title, **kwargs)


__all__ = [
    "Building", "CarrierSpec", "build_problem", "Cluster", "Deployment", "FEATURES_SPAWN_KEY", "FeatureSpec", "MapSpec",
    "MissionTrace", "PHYSICS_DT", "PlannerSpec", "PriorSpec", "SUBSTEPS", "Scenario", "ScenarioError",
    "Simulation", "StageGeometry", "load_scenario", "observe_all", "parse_scenario", "render_map",
    "observe_counts", "offline_mission", "sample_features", "simulate_mission", "stage_geometry",
]
