"""``python -m experiments coverage``: the same seeded worlds planned with coverage and with the
1/p penalty, both plans valued under true coverage. A small run (seconds) and the world generator."""
from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from experiments import coverage, run
from planner.instance import penalty_twin, random_coverage_instance
from experiments.trials import CLAIRVOYANT, Task, decode

PLANNERS = ("closed-loop", "ssap", "random")
CARRIERS, LEVELS, TRIALS = (4, 8), (0, 16), 2


def _run(out: Path) -> list[dict]:
    argv = ["coverage", "--trials", str(TRIALS), "--iterations", "60", "--carriers", ",".join(map(str, CARRIERS)),
            "--overlaps", ",".join(map(str, LEVELS)), "--planners", ",".join(PLANNERS), "--jobs", "1",
            "--no-progress", "--out", str(out)]
    assert run.main(argv) == 0
    with open(out / "coverage_trials.csv", newline="") as f:
        return list(csv.DictReader(f))


@pytest.fixture(scope="module")
def results(tmp_path_factory) -> tuple[Path, list[dict]]:
    out = tmp_path_factory.mktemp("coverage")
    return out, _run(out)


def _world(row: dict):
    task = Task("coverage", int(row["level"]), int(row["trial"]), row["planner"], int(row["seed"]), 60,
                carriers=int(row["carriers"]), overlaps=int(row["overlaps"]))
    inst, _ = coverage.world(task.seed, task.trial, task.carriers, task.overlaps, task.passengers, task.stages,
                             task.mean)
    return inst


def test_one_row_per_world_and_planner_and_the_report_files(results):
    out, rows = results
    names = (*PLANNERS, *((CLAIRVOYANT,) if coverage.coverage_clairvoyant() is not None else ()))
    expected = {(str(r), str(k), str(t), p) for r in CARRIERS for k in LEVELS for t in range(TRIALS) for p in names}
    assert {(r["carriers"], r["level"], r["trial"], r["planner"]) for r in rows} == expected
    assert len(rows) == len(expected)
    assert {r["overlaps"] for r in rows if r["carriers"] == "8" and r["level"] == "16"} == {"32"}  # k·R/4 lenses
    assert (out / "coverage.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    text = (out / "coverage.md").read_text()
    assert "| 8 | 16 (32) |" in text and "Closed-loop (ours)" in text
    with open(out / "coverage_summary.csv", newline="") as f:
        summary = list(csv.DictReader(f))
    assert len(summary) == len(CARRIERS) * len(LEVELS) * len(names)


def test_both_plans_are_valued_under_true_coverage_two_ways(results):
    from planner import coverage as cov
    from planner.problem import evaluate

    for row in results[1]:
        problem, x, counts = _world(row)
        assert row["planner_seed"] == str(coverage.world(int(row["seed"]), int(row["trial"]), int(row["carriers"]),
                                                          int(row["overlaps"]), 3, 10, 3.0)[1])
        for plan in ("coverage", "penalty"):
            if row[f"deployed_{plan}"] == "":
                continue
            deployed = decode(row[f"deployed_{plan}"], problem.n_carriers, problem.n_stages)
            assert (deployed.sum(axis=1) == 3).all()  # every passenger deployed, all stages valid
            value = cov.value(problem.coverage, deployed, counts)
            assert float(row[f"{plan}_features"]) == pytest.approx(value, abs=1e-4)
            assert float(row[f"{plan}_reward"]) == pytest.approx(
                evaluate(problem, deployed, x, counts=counts)[0], rel=1e-5)


def test_ssap_ignores_overlap_so_without_lenses_both_plans_are_the_same(results):
    """ssap never looks at overlap; under coverage its thresholds use each point's own prior (the
    sum of its regions'), which equals the pooled prior only where no point explores a lens."""
    rows = [r for r in results[1] if r["planner"] == "ssap" and r["level"] == "0"]
    assert rows and all(r["same_deployed"] == "1" and float(r["diff"]) == 0.0 for r in rows)
    assert all(r["deployed_coverage"] == r["deployed_penalty"] for r in rows)


def test_the_penalty_model_never_overvalues_and_is_exact_without_lenses(results):
    rows = [r for r in results[1] if r["planner"] != CLAIRVOYANT]
    for r in rows:
        model, true = float(r["penalty_model_reward"]), float(r["penalty_reward"])
        assert model <= true + 1e-9, r  # a region covered q times: each deployment has p >= q
        if r["level"] == "0":
            assert model == pytest.approx(true, abs=1e-9)
    # The lenses make the heuristic undervalue some plan (ssap deploys into lenses).
    assert any(float(r["penalty_model_reward"]) < float(r["penalty_reward"]) - 1e-9 for r in rows)


def test_report_only_rewrites_the_same_summary(results, tmp_path):
    import shutil

    out = tmp_path / "copy"
    shutil.copytree(results[0], out)

    def summary():
        with open(out / "coverage_summary.csv", newline="") as f:
            return [{k: v for k, v in r.items() if not k.startswith("decision_ms")} for r in csv.DictReader(f)]

    before = summary()
    assert run.main(["coverage", "--report-only", "--out", str(out)]) == 0
    assert summary() == before


# ----------------------------------------------------------------------------- the generator


def test_same_seed_same_world_and_its_penalty_twin():
    def world(seed):
        return random_coverage_instance(np.random.default_rng(seed), 4, 3, 10, 12)

    (problem, x), counts = world(7)
    (_, x2), counts2 = world(7)
    assert np.array_equal(counts, counts2) and np.array_equal(x, x2)
    assert not np.array_equal(counts, world(8)[1])
    assert problem.coverage.n_regions == 2 * 40 + 12 and len(counts) == 92
    assert np.allclose(problem.coverage.means, 1.5)  # own regions and lenses: Poisson(mean / own)
    # x is the sum of each point's region counts; the lenses are the penalty view's overlap groups.
    assert x[1, 2] == sum(counts[m] for m in problem.coverage.regions(1 * 10 + 2))
    assert len(problem.overlaps) == 12 and all(2 <= len(g) <= 3 for g in problem.overlaps)
    twin = penalty_twin(problem)
    assert twin.coverage is None and twin.scale == problem.scale and twin.overlaps == problem.overlaps


def test_a_level_adds_lenses_to_the_lower_levels_ones():
    """Level k's lenses are the first of level k + 4's (same stream): paired across levels."""
    def lenses(n):
        (problem, _), _ = random_coverage_instance(np.random.default_rng(3), 8, 3, 10, n)
        return [sorted(map(tuple, g.tolist())) for g in problem.overlaps]

    assert lenses(16)[:8] == lenses(8)


# ----------------------------------------------------------------------------- pending and bound


class _BlindToCounts:
    """Plans like SSAP on the penalty model; raises like a planner whose internals drop the counts."""

    def __init__(self, error):
        from planner.registry import make_planner

        self.inner, self.error = make_planner("ssap"), error

    def decide(self, view, rng):
        if view.counts is not None:
            raise self.error
        return self.inner.decide(view, rng)


def test_a_planner_that_cannot_plan_under_coverage_is_pending_not_invented(monkeypatch):
    coverage.world.cache_clear()
    monkeypatch.setattr(coverage, "_planner", lambda name, iterations: _BlindToCounts(ValueError("no counts\nmore")))
    row = coverage.run_task(Task("coverage", 8, 0, "blind", 0, 10, carriers=4, overlaps=8))
    assert row["error"] == "ValueError: no counts" and "coverage_reward" not in row and "diff" not in row
    assert row["penalty_reward"] > 0 and row["deployed_penalty"]
    summary = coverage.summarise([row])
    assert summary[0]["coverage_n"] == 0
    assert "pending" in "\n".join(coverage.markdown(summary))
    monkeypatch.setattr(coverage, "_planner", lambda name, iterations: _BlindToCounts(RuntimeError("a bug")))
    from planner.guard import PlannerFault

    with pytest.raises(PlannerFault, match="raises: RuntimeError"):  # only "cannot plan under coverage" is recorded
        coverage.run_task(Task("coverage", 8, 0, "blind", 0, 10, carriers=4, overlaps=8))


def test_the_clairvoyant_bound_is_read_when_it_exists(monkeypatch, tmp_path):
    """With a coverage clairvoyant (here a stand-in: every carrier's largest observations) the
    sweep adds its rows and every planner's per-trial fraction of it."""
    from planner.clairvoyant import ClairvoyantResult
    from planner.problem import evaluate

    def top_observations(problem, x, counts):
        order = np.argsort(-np.nan_to_num(x, nan=-1), axis=1, kind="stable")[:, :3]
        deployed = np.zeros(x.shape, dtype=bool)
        np.put_along_axis(deployed, order, True, axis=1)
        reward, features = evaluate(problem, deployed, x, counts=counts)
        return ClairvoyantResult(deployed, reward, features, False, 0, np.full(x.shape, -1))

    monkeypatch.setattr(coverage, "coverage_clairvoyant", lambda: top_observations)
    argv = ["coverage", "--trials", "2", "--iterations", "30", "--carriers", "4", "--overlaps", "12", "--planners",
            "ssap", "--jobs", "1", "--no-progress", "--out", str(tmp_path)]
    assert run.main(argv) == 0
    rows = coverage.read_trials(tmp_path / "coverage_trials.csv")
    bound = {r["trial"]: r["coverage_reward"] for r in rows if r["planner"] == CLAIRVOYANT}
    ssap = [r for r in rows if r["planner"] == "ssap"]
    assert len(bound) == 2 and len(ssap) == 2
    fraction = np.mean([r["coverage_reward"] / bound[r["trial"]] for r in ssap])
    summary = {r["planner"]: r for r in coverage.summarise(rows)}
    assert summary["ssap"]["coverage_fraction"] == pytest.approx(fraction)
    text = (tmp_path / "coverage.md").read_text()
    assert "fraction of the clairvoyant coverage bound (exact maximum coverage in 0 of 2 worlds" in text
