"""The solve CLI end to end in a subprocess: output, sampled observations, broken instance files."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cli_helpers import in_process
from planner.cli import solve
from planner.instance import PRIOR_KINDS, InstanceError, instance_dict, load_instance, make_prior, random_instance
from planner.problem import evaluate

REPO = Path(__file__).resolve().parents[1]

EXAMPLE = {
    "carriers": 4, "passengers": 3, "stages": 10,
    "prior": {"kind": "poisson", "mean": 3.0}, "normalize": "q90",
    "overlaps": [[[0, 2], [1, 6], [2, 5]], [[0, 5], [2, 2]]],
    "observations": [
        [2, 5, 1, None, 4, 3, 0, 2, 6, 1],
        [1, 1, 3, 4, 2, 5, 2, 0, 3, 3],
        [4, 2, 2, 3, 1, 0, 7, 2, 2, 1],
        [None, None, 3, 2, 5, 4, 1, 3, 2, 2],
    ],
}


#: The command and its earlier spelling (a forward in coordinator/): both must keep working.
SPELLINGS = ("planner.cli.solve", "coordinator.solve")


def _run(*args: str) -> subprocess.CompletedProcess:
    """The CLI in a fresh interpreter (about 1.5 s of imports each: used sparingly)."""
    return subprocess.run([sys.executable, "-m", SPELLINGS[0], *args], cwd=REPO,
                          capture_output=True, text=True, timeout=120)


def _run_many(arg_lists: list[list[str]], module: str = SPELLINGS[1]) -> list[tuple[int, str, str]]:
    """Several CLI subprocesses at once (the earlier spelling unless told): (exit code, stdout,
    stderr) each."""
    procs = [subprocess.Popen([sys.executable, "-m", module, *args], cwd=REPO,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for args in arg_lists]
    results = []
    for proc in procs:
        out, err = proc.communicate(timeout=120)
        results.append((proc.returncode, out, err))
    return results


@pytest.fixture
def cli():
    """The CLI's main() in this interpreter: same code path minus the interpreter start."""
    return lambda *args: in_process(solve.main, args)


def _write(tmp_path: Path, data, name: str = "instance.json") -> Path:
    path = tmp_path / name
    path.write_text(data if isinstance(data, str) else json.dumps(data))
    return path


@pytest.mark.parametrize("planner,extra,fresh", [("ssap", [], True), ("random", [], False),
                                                 ("mcts-ssap", ["--iterations", "60"], True)])
def test_example_instance(tmp_path, cli, planner, extra, fresh):
    path = _write(tmp_path, EXAMPLE)
    # V* (5 s here) is left out: its report is tests/test_online_optimal.py's
    proc = (_run if fresh else cli)(str(path), "--planner", planner, "--seed", "5", *extra, "--no-online-optimum")
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    assert out["planner"] == planner and out["seed"] == 5 and out["observations_sampled"] is False
    assert len(out["decision_ms"]) == 10 and all(t >= 0 for t in out["decision_ms"])
    (problem, x), _ = load_instance(path)
    deployed = np.zeros((4, 10), dtype=bool)
    for r, stages in enumerate(out["deployments"]):
        assert len(stages) == 3 and all(not np.isnan(x[r, j]) for j in stages)
        deployed[r, stages] = True
    reward, features = evaluate(problem, deployed, x)
    assert out["reward"] == pytest.approx(reward) and out["features"] == pytest.approx(features)
    assert out["reward"] == pytest.approx(out["features"] / 5.0)  # Poisson(3) q90 = 5
    assert out["clairvoyant"]["exact"] is True and out["clairvoyant"]["reward"] >= out["reward"] - 1e-12
    # Same seed, same output (decision times aside), in process too (the bounds, checked above,
    # are not computed again).
    again = json.loads(cli(str(path), "--planner", planner, "--seed", "5", *extra, "--no-clairvoyant",
                           "--no-online-optimum", "--no-upper-bound").stdout)
    assert again["deployments"] == out["deployments"] and again["reward"] == out["reward"]


def test_sampled_observations_per_carrier_passengers_and_surprises(tmp_path, cli):
    data = {"carriers": 3, "passengers": [0, 2, 5], "stages": 6, "prior": {"kind": "gamma", "shape": 2, "scale": 1.5},
            "overlaps": [[[1, 1], [1, 2]]], "valid": [[True] * 6, [False, True, True, True, True, False], [True] * 6]}
    path = _write(tmp_path, data)
    no_v_star = ("--no-online-optimum",)  # V* not asserted here
    first = json.loads(cli(str(path), "--planner", "ssap", "--seed", "9", *no_v_star).stdout)
    second = json.loads(cli(str(path), "--planner", "ssap", "--seed", "9", *no_v_star).stdout)
    other = json.loads(cli(str(path), "--planner", "ssap", "--seed", "10", *no_v_star).stdout)
    assert first["observations_sampled"] is True
    assert first["observations"] == second["observations"] != other["observations"]
    assert first["observations"][1][0] is None and first["observations"][1][5] is None
    assert [len(s) for s in first["deployments"]] == [0, 2, 5]
    # A null observation at a scheduled stage is an online surprise: the carrier adapts.
    data["observations"] = [[1.0] * 6, [None, 2.0, None, 3.0, 1.0, None], [1.0, 2.0, 3.0, None, 5.0, 6.0]]
    out = json.loads(cli(str(_write(tmp_path, data, "surprise.json")), "--planner", "ssap", *no_v_star).stdout)
    assert all(data["observations"][r][j] is not None for r, s in enumerate(out["deployments"]) for j in s)


BROKEN = {
    "not-json": ('{"carriers": 4, "passengers": 3,', "(file): expected valid JSON"),
    "nan-literal": ('{"carriers": 1, "passengers": 1, "stages": 2, "observations": [[NaN, 1]]}',
                    "(file): expected valid JSON"),
    "top-level-list": ("[1, 2]", "(top level): expected a JSON object, found list"),
    "missing-field": ({"carriers": 2, "passengers": 1}, "stages: expected a required field, found nothing"),
    "wrong-type": ({**EXAMPLE, "carriers": "four"}, 'carriers: expected an integer >= 1, found "four"'),
    "bool-as-int": ({**EXAMPLE, "stages": True}, "stages: expected an integer >= 1, found true"),
    "row-count": ({**EXAMPLE, "observations": EXAMPLE["observations"][:3]},
                  "observations: expected a list of 4 rows (one per carrier), found a list of 3 rows"),
    "row-length": ({**EXAMPLE, "observations": [*EXAMPLE["observations"][:3], [1] * 9]},
                   "observations[3]: expected a list of 10 entries (one per stage), found 9 entries"),
    "carrier-out-of-range": ({**EXAMPLE, "overlaps": [[[0, 1], [4, 2]]]},
                             "overlaps[0][1][0]: expected a carrier index in 0..3, found 4"),
    "stage-out-of-range": ({**EXAMPLE, "overlaps": [[[0, 1]], [[1, -1]]]},
                           "overlaps[1][0][1]: expected a stage index in 0..9, found -1"),
    "unknown-prior": ({**EXAMPLE, "prior": {"kind": "zipfian", "a": 2}}, "prior.kind: expected one of"),
    "prior-parameter": ({**EXAMPLE, "prior": {"kind": "poisson", "mean": -3}},
                        "prior.mean: expected a number > 0, found -3"),
    "negative-passengers": ({**EXAMPLE, "passengers": [3, 3, -1, 3]},
                            "passengers[2]: expected an integer >= 0, found -1"),
    "negative-observation": ({**EXAMPLE, "observations": [[-2] * 10] + EXAMPLE["observations"][1:]},
                             "observations[0][0]: expected a value the prior can produce (support 0..inf), found -2"),
    "fractional-count": ({**EXAMPLE, "observations": [[2.5] * 10] + EXAMPLE["observations"][1:]},
                         "observations[0][0]: expected a value the prior can produce"),
    "unknown-field": ({**EXAMPLE, "observation": []}, "observation: expected only the fields"),
    "observation-at-invalid": ({**EXAMPLE, "valid": [[False] + [True] * 9] + [[True] * 10] * 3},
                               "observations[0][0]: expected null at a stage marked false in valid, found 2"),
    "bad-normalize": ({**EXAMPLE, "normalize": "p90"}, "normalize: expected"),
    "values-not-a-list": ({**EXAMPLE, "passenger_values": 1.0},
                          "passenger_values: expected a list of 4 lists (one per carrier), found 1.0"),
    "values-row-length": ({**EXAMPLE, "passenger_values": [[1, 0.6, 0.6]] * 3 + [[1, 0.6]]},
                          "passenger_values[3]: expected a list of 3 numbers > 0 (one per passenger of carrier 3), "
                          "found a list of 2"),
    "values-not-positive": ({**EXAMPLE, "passenger_values": [[1, 0.6, 0.6]] * 3 + [[1, 0, 0.6]]},
                            "passenger_values[3][1]: expected a number > 0, found 0"),
}


def _check_broken(path: Path, message: str, code: int, out: str, err: str) -> None:
    assert code == 2, (out, err)
    assert out == ""
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith(f"{path}: ") and message in lines[0], lines[0]


@pytest.mark.parametrize("case", list(BROKEN))
def test_broken_instance_gives_one_line_and_exit_2(tmp_path, cli, case):
    data, message = BROKEN[case]
    path = _write(tmp_path, data, f"{case}.json")
    proc = cli(str(path), "--planner", "ssap")
    _check_broken(path, message, proc.returncode, proc.stdout, proc.stderr)


#: Broken files also run through real subprocesses (no traceback escapes the interpreter).
SUBPROCESS_CASES = ["not-json", "missing-field", "wrong-type", "row-length", "carrier-out-of-range",
                    "negative-observation"]


def test_broken_instances_through_subprocesses(tmp_path):
    paths = [_write(tmp_path, BROKEN[case][0], f"{case}.json") for case in SUBPROCESS_CASES]
    results = _run_many([[str(path), "--planner", "ssap"] for path in paths])
    for case, path, (code, out, err) in zip(SUBPROCESS_CASES, paths, results):
        _check_broken(path, BROKEN[case][1], code, out, err)


def test_missing_file_and_bad_arguments(tmp_path, cli):
    missing = cli(str(tmp_path / "nope.json"), "--planner", "ssap")
    assert missing.returncode == 2 and len(missing.stderr.splitlines()) == 1
    assert "nope.json: (file): expected a readable UTF-8 JSON file" in missing.stderr
    path = _write(tmp_path, EXAMPLE)
    cases = ((["--planner", "greedy"], "--planner: expected one of "),
             (["--planner", "ssap", "--iterations", "0"], "expected an integer >= 1"),
             (["--planner", "ssap", "--seed", "x"], "expected an integer >= 0"),
             ([], "--planner"))
    for args, text in cases:
        proc = cli(str(path), *args)
        assert proc.returncode == 2 and proc.stdout == ""
        assert len(proc.stderr.splitlines()) == 1 and text in proc.stderr, proc.stderr
    assert all(name in cli(str(path), "--planner", "greedy").stderr for name in ("mcts-ssap", "random", "ssap"))
    code, out, err = _run_many([[str(path), "--planner", "ssap", "--iterations", "0"]])[0]
    assert code == 2 and out == "" and len(err.splitlines()) == 1 and "--iterations" in err


def test_both_spellings_run_the_same_command(tmp_path):
    """``python -m planner.cli.solve`` and the forward ``python -m coordinator.solve``: the same
    output, and each names itself in its errors."""
    path = _write(tmp_path, EXAMPLE)
    args = [str(path), "--planner", "ssap", "--no-clairvoyant", "--no-online-optimum", "--no-upper-bound"]
    outputs = []
    for module in SPELLINGS:
        (code, out, err), (bad, _, line) = _run_many([args, [str(path), "--planner", "nope"]], module)
        assert code == 0 and err == "", err
        outputs.append({k: v for k, v in json.loads(out).items() if k != "decision_ms"})
        assert bad == 2 and line.startswith(f"python -m {module}: error: --planner:"), line
    assert outputs[0] == outputs[1]


def test_every_prior_kind_builds_and_round_trips(tmp_path):
    specs = {
        "poisson": {"mean": 2.0}, "binomial": {"n": 6, "p": 0.5}, "geometric": {"p": 0.4},
        "negative_binomial": {"n": 2.5, "p": 0.5}, "discrete_uniform": {"low": 0, "high": 6},
        "table": {"values": [0, 1.5, 4], "probabilities": [0.3, 0.3, 0.4]}, "gamma": {"shape": 2, "scale": 1.0},
        "exponential": {"mean": 2.0}, "lognormal": {"mu": 0.5, "sigma": 0.4}, "normal": {"mean": 3, "std": 1},
        "uniform": {"low": 1, "high": 5},
    }
    assert set(specs) == set(PRIOR_KINDS)
    assert make_prior({"kind": "geometric", "p": 0.4}).support()[0] == 0  # failures before success
    rng = np.random.default_rng(0)
    for kind, params in specs.items():
        spec = {"kind": kind, **params}
        prior = make_prior(spec)
        problem, x = random_instance(rng, carriers=2, stages=4, overlaps=2)
        x = np.asarray(prior.rvs(size=x.shape, random_state=rng), dtype=float)
        data = instance_dict((problem, x), prior=spec)
        (loaded, y), sampled = load_instance(_write(tmp_path, data, f"{kind}.json"))
        assert not sampled and np.allclose(x, y)
        with pytest.raises(InstanceError, match=f"prior.{list(params)[0]}: expected"):
            make_prior({"kind": kind, **{k: v for k, v in list(params.items())[1:]}})


def test_passenger_values_give_released_passengers(tmp_path, cli):
    """With ``passenger_values`` the output lists each deployment's passenger; the reward is the
    weighted one; without them the output has no ``released`` (today's format)."""
    values = [[1.0, 0.6, 0.6], [0.6, 1.0, 0.6], [0.3, 0.3, 1.0], [1.0, 1.0, 1.0]]
    plain = json.loads(cli(str(_write(tmp_path, EXAMPLE, "plain.json")), "--planner", "ssap", "--seed", "1",
                           "--no-online-optimum").stdout)
    typed = json.loads(cli(str(_write(tmp_path, {**EXAMPLE, "passenger_values": values}, "typed.json")),
                           "--planner", "ssap", "--seed", "1").stdout)
    assert "released" not in plain
    # SSAP's deployments do not depend on the values; its passengers do.
    assert typed["deployments"] == plain["deployments"]
    assert [sorted(r) for r in typed["released"]] == [list(range(len(s))) for s in typed["deployments"]]
    x = typed["observations"]
    by_hand = sum(values[r][i] * x[r][j] for r, (stages, who) in enumerate(zip(typed["deployments"], typed["released"]))
                  for j, i in zip(stages, who))
    assert typed["features"] <= by_hand + 1e-9  # penalties only lower it
    assert typed["clairvoyant"]["features"] >= typed["features"] - 1e-9
    assert typed["released"][3] == [0, 1, 2]  # equal weights: index order
    assert "online_optimum" not in typed
