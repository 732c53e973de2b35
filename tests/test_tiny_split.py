"""``python -m tools.tiny_split`` (docs/results.md, "Where the gap is"): the bound's and the planners'
shares of the gap on instances small enough for the exact V*."""
from __future__ import annotations

import numpy as np
import pytest

from planner import online_optimal
from tools import tiny_split


@pytest.mark.parametrize("family, groups, prior", [("paper", 6, "poisson"), ("dense", 10, "nbinom")])
def test_tiny_instances_have_the_family_density_and_fit_the_exact_solver(family, groups, prior):
    problem = tiny_split.tiny_problem(family, 2, 3)
    assert problem.n_carriers == 2 and problem.n_stages == tiny_split.STAGES
    assert len(problem.overlaps) == groups and problem.prior.dist.name == prior
    online_optimal.estimate(problem)  # admitted: raises TooLarge otherwise
    again = tiny_split.tiny_problem(family, 2, 3)
    np.testing.assert_array_equal(again.valid, problem.valid)
    np.testing.assert_array_equal(again.conflict, problem.conflict)
    assert len(tiny_split.tiny_problem(family, 2, 3, density=1.0).overlaps) == 12


@pytest.mark.parametrize("family", ["paper", "dense"])
def test_the_bound_stays_above_v_star_and_the_planners_below_it(family):
    row = tiny_split.run_trial(family, 2, 1, obs=60, iterations=200, bound_samples=60)
    assert row["bound"] >= row["v_star"] - 3 * row["bound_stderr"]
    for column, _ in tiny_split.PLANNERS:  # no online planner beats V* by more than its noise
        assert row[column + "_fraction"] <= 1 + 3 * row[column + "_fraction_sem"]
        assert row[column + "_fraction"] > 0.9
    # The optimal policy flown on the matrices earns V* up to Monte Carlo noise.
    assert abs(row["optimal_mc"] / row["v_star"] - 1) < 0.15


def test_measurement_command_prints_the_split(capsys, tmp_path):
    out = tmp_path / "rows.csv"
    assert tiny_split.main(["--family", "dense", "--trials", "0-1", "--obs", "8", "--iterations", "50",
                            "--bound-samples", "8", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert text.count("trial ") == 2 and "bound over V*" in text and "the bound's" in text and "the planner's" in text
    assert len(out.read_text().splitlines()) == 3
    png = tmp_path / "split.png"
    assert tiny_split.main(["--plot", str(png), "--rows", str(out), str(out)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    capsys.readouterr()
    for bad in (["--density", "0"], ["--plot", str(png)], ["--plot", str(png), "--rows", str(tmp_path / "none.csv")]):
        with pytest.raises(SystemExit):
            tiny_split.main(bad)
        assert "error:" in capsys.readouterr().err
