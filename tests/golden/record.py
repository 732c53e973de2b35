"""Record the golden outputs that the planner and fleet must keep reproducing.

Run once (``python tests/golden/record.py``) on the code whose behaviour is the reference; the
test ``tests/test_golden.py`` recomputes every case with today's code and compares. Intended
changes are listed in ``CHANGED`` there and their new outputs pinned by
``python tests/golden/record.py --changed`` (into ``solve_changed.json``). Cases:

* ``instances/*.json`` — instance files (every prior kind, paper-style random instances, a
  ten-carrier one for the binary MCTS layout), solved by ``python -m coordinator.solve`` with
  every registered planner at a fixed seed and iteration budget;
* ``six_carriers.json`` — the six_carriers scenario's observations, decisions and reward from
  the offline run the fleet must reproduce.

Only public entry points are used (the solve command's ``main`` and the offline helper of the
fleet tests), so the recording survives refactors of what is behind them.
"""
from __future__ import annotations

import contextlib
import io
import json
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path.insert(0, str(ROOT))

#: Solve settings of every golden case.
SEED = 7
ITERATIONS = 1500
PLANNERS = ("random", "ssap", "mcts-random", "mcts-ssap", "closed-loop")

#: Prior specs, one per kind (a table prior with non-integer values among them).
PRIORS = {
    "poisson": {"kind": "poisson", "mean": 3.0},
    "binomial": {"kind": "binomial", "n": 8, "p": 0.4},
    "geometric": {"kind": "geometric", "p": 0.3},
    "negative_binomial": {"kind": "negative_binomial", "n": 2.0, "p": 0.4},
    "discrete_uniform": {"kind": "discrete_uniform", "low": 0, "high": 6},
    "table": {"kind": "table", "values": [0, 2.5, 5], "probabilities": [0.3, 0.4, 0.3]},
    "gamma": {"kind": "gamma", "shape": 2.0, "scale": 1.5},
    "exponential": {"kind": "exponential", "mean": 3.0},
    "lognormal": {"kind": "lognormal", "mu": 1.0, "sigma": 0.5},
    "normal": {"kind": "normal", "mean": 5.0, "std": 1.5},
    "uniform": {"kind": "uniform", "low": 0.0, "high": 6.0},
}


def instances() -> dict[str, dict]:
    """Instance JSON objects by case name (deterministic)."""
    from planner.instance import instance_dict, random_instance
    from planner.problem import Problem, sample_observations
    from planner import priors

    cases = {}
    for k in range(3):
        rng = np.random.default_rng(np.random.SeedSequence(4242, spawn_key=(k,)))
        cases[f"paper-{k}"] = instance_dict(random_instance(rng, invalid_fraction=0.1 * k))
    rng = np.random.default_rng(np.random.SeedSequence(4242, spawn_key=(100,)))
    cases["ten-carriers"] = instance_dict(random_instance(rng, carriers=10, passengers=2, stages=8, overlaps=16))
    for i, (kind, spec) in enumerate(PRIORS.items()):
        rng = np.random.default_rng(np.random.SeedSequence(4242, spawn_key=(200 + i,)))
        base = random_instance(rng, carriers=3, passengers=2, stages=8, overlaps=8)
        problem = Problem.build(base.problem.passengers, base.problem.valid, base.problem.overlaps,
                                priors.build_prior(spec))
        x = sample_observations(problem, rng)
        cases[f"prior-{kind}"] = instance_dict((problem, x), prior=spec)
    return cases


def solve(path: Path, planner: str) -> dict:
    """The solve command's output for one case (decision times dropped)."""
    from planner.cli import solve as solve_cli

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        # Left out: the online optimum (added to the output after the recording) and the
        # information-relaxation upper bound (added later too, and computed within a wall-clock
        # budget, so its sample count depends on the machine and its load).
        code = solve_cli.main([str(path), "--planner", planner, "--seed", str(SEED), "--no-online-optimum",
                               "--no-upper-bound",
                               *(["--iterations", str(ITERATIONS)] if planner.startswith(("mcts", "closed")) else [])])
    assert code == 0, (path, planner, code)
    out = json.loads(buf.getvalue())
    out.pop("decision_ms")
    return out


def six_carriers() -> dict:
    """The six_carriers scenario's offline mission (what the fleet must reproduce)."""
    import world
    sys.path.insert(0, str(ROOT / "tests"))
    from fleet_helpers import offline

    scenario = world.load_scenario(ROOT / "scenarios" / "six_carriers.yaml")
    result, x = offline(scenario)
    return {
        "observations": [[None if np.isnan(v) else float(v) for v in row] for row in x],
        "deployments": [np.flatnonzero(row).tolist() for row in result.deployed],
        "reward": result.reward,
        "features": result.features,
    }


def record_changed(cases) -> None:
    """Record today's output of the (case, planner) pairs whose change is intended (the
    ``CHANGED`` list of tests/test_golden.py) into ``solve_changed.json``; solve.json is left
    as recorded before the refactor."""
    out: dict[str, dict] = {}
    for case, planner in sorted(cases):
        out.setdefault(case, {})[planner] = solve(HERE / "instances" / f"{case}.json", planner)
    (HERE / "solve_changed.json").write_text(json.dumps(out, indent=1, sort_keys=True) + "\n")


def main() -> None:
    inst_dir = HERE / "instances"
    inst_dir.mkdir(exist_ok=True)
    solved = {}
    for name, data in instances().items():
        path = inst_dir / f"{name}.json"
        path.write_text(json.dumps(data) + "\n")
        solved[name] = {planner: solve(path, planner) for planner in PLANNERS}
        print(name, {p: round(v["reward"], 4) for p, v in solved[name].items()}, flush=True)
    (HERE / "solve.json").write_text(json.dumps(solved, indent=1, sort_keys=True) + "\n")
    (HERE / "six_carriers.json").write_text(json.dumps(six_carriers(), indent=1) + "\n")


if __name__ == "__main__":
    if sys.argv[1:] == ["--changed"]:  # after an intended change: pin the new outputs
        sys.path.insert(0, str(ROOT / "tests"))
        from test_golden import CHANGED

        record_changed(CHANGED)
    else:
        main()
