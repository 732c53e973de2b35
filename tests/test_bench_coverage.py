"""``python -m planner.cli.bench_coverage`` (docs/performance.md, "Coverage reward: mcts-ssap
decision time") on one small world per family: the benchmark's code path and its table, in the
default suite; the documented command's full run is in the heavy tier."""
from __future__ import annotations

from planner.cli import bench_coverage


def test_one_world_per_family_gives_a_row_each_with_both_models_timed(capsys):
    assert bench_coverage.main(["--instances", "1", "--sizes", "6", "--iterations", "300", "--no-busy"]) == 0
    rows = [line.split("|")[1:-1] for line in capsys.readouterr().out.splitlines()
            if line.startswith("| as is |")]
    assert [r[2].strip() for r in rows] == ["paper", "near"]
    for r in rows:
        assert r[1].strip() == "6"
        penalty, coverage, ratio = float(r[3].split()[0]), float(r[4].split()[0]), float(r[5])
        assert penalty > 0 and coverage > 0
        # the ratio of the medians, which the table rounds to 0.1 ms (and the ratio to 0.01)
        low, high = (coverage - 0.05) / (penalty + 0.05), (coverage + 0.05) / max(penalty - 0.05, 1e-9)
        assert low - 0.005 <= ratio <= high + 0.005, (ratio, penalty, coverage)
