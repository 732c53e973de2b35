"""The coverage reward (issue 35): instance format, values and bad input."""
import json
from pathlib import Path

import numpy as np
import pytest

from planner import coverage as cov
from planner.instance import InstanceError, load_instance, load_instance_counts, parse_instance

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "coverage_tiny.json"


def test_example_observations_are_sums_of_counts_and_value_counts_each_region_once():
    (problem, x), counts, sampled = load_instance_counts(EXAMPLE)
    assert problem.reward == "coverage" and not sampled
    assert x[0].tolist()[:3] == [3.0, 5.0, 1.0] and np.isnan(x[0, 3])  # [0], [1, 2], [3]
    deployed = np.zeros((3, 4), dtype=bool)
    deployed[0, 1] = deployed[1, 2] = True  # regions {1, 2} and {2, 6}: region 2 counted once
    assert cov.value(problem.coverage, deployed, counts) == 0 + 5 + 0
    best = cov.best_weights(problem.coverage, deployed)
    assert cov.marginal_gain(problem.coverage, best, 2 * 4 + 1, counts) == 3 + 2  # regions 0, 7
    assert cov.marginal_gain(problem.coverage, best, 1 * 4 + 2, counts) == 0


def test_penalty_is_the_default_and_coverage_fields_need_the_coverage_reward():
    (problem, _), _ = load_instance(Path(__file__).parent / "golden" / "instances" / "paper-0.json")
    assert problem.reward == "penalty" and problem.coverage is None
    with pytest.raises(InstanceError, match="regions: expected only with"):
        parse_instance({"carriers": 1, "passengers": 1, "stages": 1, "regions": [{"mean": 1}]}, "i.json")


def _bad(change):
    data = json.loads(EXAMPLE.read_text())
    change(data)
    with pytest.raises(InstanceError) as err:
        parse_instance(data, "i.json")
    return str(err.value)


@pytest.mark.parametrize("change, line", [
    (lambda d: d["covers"][0].__setitem__(0, [8]), "i.json: covers[0][0][0]: expected a region index in 0..7, found 8"),
    (lambda d: d.__setitem__("valid", [[c is not None for c in row] for row in d["covers"]])
     or d["valid"][0].__setitem__(0, False), "i.json: covers[0][0]: expected null at a stage marked false in valid"),
    (lambda d: d["counts"].pop(), "i.json: counts: expected a list of 8 counts >= 0 (one per region), found a list of 7"),
    (lambda d: d["counts"].__setitem__(1, -1), "i.json: counts[1]: expected a count >= 0, found -1"),
    (lambda d: d["counts"].__setitem__(7, 5), "i.json: counts[7]: expected a count region 7's prior can produce"),
    (lambda d: d["regions"].__setitem__(0, {"prior": {"kind": "normal", "mean": 1, "std": 1}}),
     "i.json: regions[0].prior: expected a discrete prior on counts >= 0"),
    (lambda d: d.__setitem__("reward", "cover"), "i.json: reward: expected one of penalty, coverage"),
], ids=["region-index", "invalid-stage", "counts-length", "negative-count", "count-support", "region-prior", "reward"])
def test_bad_coverage_input_is_one_line_naming_the_field(change, line):
    message = _bad(change)
    assert message.startswith(line) and "\n" not in message


def test_sampled_counts_are_seeded():
    data = json.loads(EXAMPLE.read_text())
    del data["counts"]
    a = parse_instance(data, "i.json", seed=3)[0].observations
    b = parse_instance(data, "i.json", seed=3)[0].observations
    assert np.array_equal(a, b, equal_nan=True)


def test_a_view_holds_only_the_counts_its_observations_reveal():
    """An observation reveals the counts of its disc's regions; the rest stay unknown (NaN), and a
    future keeps what is known and draws the rest (issue 35: the observation model)."""
    from planner.problem import make_view
    (problem, x), counts, _ = load_instance_counts(EXAMPLE)
    deployed = np.zeros(problem.valid.shape, dtype=bool)
    view = make_view(problem, 0, x, deployed, counts=counts)
    # stage 0 observed: carrier 0 -> region 0, carrier 1 -> region 4 (carrier 2 is ∅ there)
    assert np.flatnonzero(~np.isnan(view.counts)).tolist() == [0, 4]
    assert view.counts[[0, 4]].tolist() == [counts[0], counts[4]]
    later = make_view(problem, 1, x, deployed, counts=counts)
    assert np.flatnonzero(~np.isnan(later.counts)).tolist() == [0, 1, 2, 4, 5, 7]
    future = cov.sample_counts_given(problem.coverage, later.counts, np.random.default_rng(3))
    assert np.array_equal(future[[0, 1, 2, 4, 5, 7]], counts[[0, 1, 2, 4, 5, 7]])
    with pytest.raises(ValueError, match="region counts"):
        make_view(problem, 0, x, deployed)


def test_coverage_evaluation_counts_each_region_once():
    from planner.problem import evaluate
    (problem, x), counts, _ = load_instance_counts(EXAMPLE)
    deployed = np.zeros(problem.valid.shape, dtype=bool)
    deployed[0, 1] = deployed[1, 2] = True  # both explore region 2 (count 5)
    reward, features = evaluate(problem, deployed, x, counts=counts)
    assert features == counts[[1, 2, 6]].sum()
    assert reward == pytest.approx(features / problem.scale)


def _set_region(m, region):
    return lambda d: d["regions"].__setitem__(m, region)


@pytest.mark.parametrize("change, line", [
    (lambda d: d["covers"][1].__setitem__(0, [-1]), "i.json: covers[1][0][0]: expected a region index in 0..7, found -1"),
    (lambda d: d["covers"][1].__setitem__(0, [1.5]), "i.json: covers[1][0]: expected a list of region indices or null"),
    (lambda d: d.__setitem__("valid", [[True] * 4] * 3),
     "i.json: covers[0][3]: expected a list of region indices at a stage marked true in valid, found null"),
    (lambda d: d["counts"].append(1), "i.json: counts: expected a list of 8 counts >= 0 (one per region), found a list of 9"),
    (lambda d: d.__setitem__("counts", 5), "i.json: counts: expected a list of 8 counts >= 0 (one per region), found 5"),
    (lambda d: d["counts"].__setitem__(0, "3"), 'i.json: counts[0]: expected a count >= 0, found "3"'),
    (lambda d: d["counts"].__setitem__(0, 1.5), "i.json: counts[0]: expected a count region 0's prior can produce"),
    (_set_region(0, {"mean": 0}), "i.json: regions[0].mean: expected a number > 0, found 0"),
    (_set_region(0, {"mu": 1}), 'i.json: regions[0]: expected an object {"mean": MU} or {"prior": {...}}'),
    (_set_region(0, {"prior": {"kind": "discrete_uniform", "low": -1, "high": 3}}),
     "i.json: regions[0].prior: expected a discrete prior on counts >= 0"),
    (_set_region(0, {"prior": {"kind": "table", "values": [-1, 2], "probabilities": [0.5, 0.5]}}),
     "i.json: regions[0].prior: expected a discrete prior on counts >= 0"),
    (_set_region(0, {"prior": {"kind": "poison", "mean": 1}}), "i.json: regions[0].prior.kind: expected one of poisson"),
], ids=["negative-region-index", "non-integer-region-index", "null-at-a-valid-stage", "counts-too-long",
        "counts-not-a-list", "count-not-a-number", "count-off-the-support", "region-mean-not-positive",
        "region-unknown-field", "region-prior-negative-support", "region-table-negative", "region-prior-kind"])
def test_more_bad_coverage_input_is_one_line_naming_the_field(change, line):
    """Issue 35 item 8: every way a region, a cover list or the counts can be wrong."""
    message = _bad(change)
    assert message.startswith(line) and "\n" not in message
