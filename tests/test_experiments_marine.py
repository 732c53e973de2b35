"""``python -m experiments marine`` (experiments/marine.py): a tiny run writes its tables, plot and
rows, its arms are what they say, and ``experiments check`` re-runs its rows identically."""
from __future__ import annotations

import csv

import numpy as np
import pytest

from experiments import marine
from experiments.run import main


@pytest.mark.slow  # two generated worlds, twelve missions and a check: about 20 s of CPU
def test_marine_experiment_tiny(tmp_path, capsys):
    assert main(["marine", "--trials", "1", "--iterations", "30", "--jobs", "1", "--out", str(tmp_path),
                 "--no-progress"]) == 0
    with open(tmp_path / "marine_trials.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == len(marine.FAMILIES) * len(marine.ARMS)
    assert {r["planner"] for r in rows} == {a for a, _ in marine.ARMS}
    by = {(r["level"], r["planner"]): r for r in rows}
    for level in ("0", "1"):
        bound = float(by[level, "clairvoyant"]["reward"])
        assert all(float(by[level, a]["reward"]) <= bound + 1e-9 for a, _ in marine.ARMS)
        assert 0.0 < float(by[level, "perfect"]["link_least"]) <= float(by[level, "perfect"]["link_mean"]) <= 1.0
    # The wide family's corners fall out of the base's reach, the survey's do not.
    assert float(by["1", "perfect"]["link_least"]) < 0.5 < float(by["0", "perfect"]["link_least"])
    text = (tmp_path / "marine.md").read_text()
    assert "### wide, 4 vessels, 101 dB" in text and "| 0 (" in text and (tmp_path / "marine.png").stat().st_size > 0
    from experiments.check import main as check

    assert check(["--out", str(tmp_path), "--sample", "1", "--jobs", "1", "--no-progress"]) == 0
    assert "identical" in capsys.readouterr().out


def test_the_perfect_arm_is_the_central_loop():
    from planner.online import run_online
    from planner.registry import make_planner

    task = marine.build_tasks({"trials": 1, "iterations": 30, "seed": 0})[0]
    assert task.planner == "perfect"
    row = marine.run_task(task)
    scenario, problem, x, comms, gen, planner_seed = marine.world(0, 0, 0)
    assert row["reward"] == run_online(problem, x, make_planner("closed-loop", iterations=30), planner_seed).reward
    assert np.isfinite(comms.probability[:, 0, 1:]).any()
