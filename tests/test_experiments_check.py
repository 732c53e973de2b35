"""``python -m experiments check``: a results directory's rows are re-run from the settings its
run_info.json records and compared; a row, a setting or a column that does not come from this code
is named. Small runs of every kind of sweep (each rebuilt from its own settings), every task
re-run."""
from __future__ import annotations

import csv
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from experiments import check, run

#: The whole module flies every sweep kind end to end and then the check over it (about 25 s of
#: CPU, most of it one module fixture): the slow tier's (.ci/run).
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parent.parent
#: One small run of every sweep kind the check rebuilds, with settings away from the defaults where
#: the sweep records its own (scaling's overlaps, the urban scenario, bound's quick configuration).
RUNS = (
    ["overlap", "--trials", "2", "--iterations", "40", "--overlaps", "0,9", "--planners", "closed-loop,mcts-ssap,ssap"],
    ["scaling", "--trials", "1", "--iterations", "40", "--carriers", "2,3", "--scaling-overlaps", "4",
     "--planners", "closed-loop,random"],
    ["urban", "--urban-trials", "2", "--iterations", "40", "--planners", "ssap,closed-loop",
     "--scenario", str(ROOT / "scenarios" / "tiny.yaml")],
    ["comms", "--trials", "1", "--iterations", "40", "--losses", "0,0.5", "--planners", "dec-closed-loop,ssap"],
    ["types", "--trials", "1", "--iterations", "40"],
    ["bound", "--quick", "--iterations", "40", "--planners", "closed-loop,ssap"],
    ["coverage", "--trials", "1", "--iterations", "40", "--carriers", "4,8", "--overlaps", "0,8",
     "--planners", "closed-loop,ssap"],
)


@pytest.fixture(scope="module")
def results(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("results")
    for argv in RUNS:
        assert run.main([*argv, "--jobs", "1", "--no-progress", "--out", str(out)]) == 0, argv
    return out


def _check(out: Path, capsys, *extra) -> tuple[int, str]:
    code = check.main(["--out", str(out), "--sample", "10000", "--jobs", "1", "--no-progress", *extra])
    return code, capsys.readouterr().out


def _copy(results: Path, tmp_path: Path, keep: tuple[str, ...]) -> Path:
    """A copy of the results whose run_info.json records only the sweeps ``keep``."""
    out = tmp_path / "copy"
    shutil.copytree(results, out)
    info = json.loads((out / "run_info.json").read_text())
    info["sweeps"] = {k: v for k, v in info["sweeps"].items() if k in keep}
    (out / "run_info.json").write_text(json.dumps(info))
    return out


def _edit_row(path: Path, match: dict, column: str, value: str) -> None:
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    hits = [r for r in rows if all(r[k] == v for k, v in match.items())]
    assert len(hits) == 1, (match, len(hits))
    hits[0][column] = value
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def test_every_row_of_an_untouched_run_is_reproduced(results, capsys):
    code, out = _check(results, capsys)
    assert code == 0, out
    for name in ("overlap", "scaling", "urban", "comms", "types", "bound", "coverage"):
        line = next(line for line in out.splitlines() if f"{name}_trials.csv:" in line)
        assert line.endswith("identical"), line
        n, total = line.split(": ")[1].split(" tasks")[0].split(" of ")
        assert int(n) == int(total) > 0, line  # --sample beyond every planner's count: all re-run
    assert out.strip().endswith("every sampled row is identical")


def test_a_changed_outcome_is_named_by_row_and_column(results, tmp_path, capsys):
    out = _copy(results, tmp_path, ("overlap", "comms"))
    _edit_row(out / "overlap_trials.csv", {"level": "9", "trial": "1", "planner": "closed-loop"}, "reward", "99")
    _edit_row(out / "comms_trials.csv", {"sweep": "comms-r6", "level": "50", "trial": "0", "planner": "ssap"},
              "deployed", "0|0|0|0|0|0")
    _edit_row(out / "overlap_trials.csv", {"level": "0", "trial": "0", "planner": "ssap"}, "wall_s", "123")  # timing
    code, text = _check(out, capsys)
    assert code == 1
    diffs = [line.strip() for line in text.splitlines() if line.startswith("  ")]
    assert len(diffs) == 2, diffs
    assert diffs[0].startswith("sweep overlap level 9 trial 1 planner closed-loop: reward committed '99', re-run ")
    assert diffs[1].startswith("sweep comms-r6 level 50 trial 0 planner ssap: deployed committed '0|0|0|0|0|0'")
    assert "2 difference(s)" in text.splitlines()[-1]


def test_a_changed_coverage_plan_or_fleet_size_is_named(results, tmp_path, capsys):
    out = _copy(results, tmp_path, ("coverage",))
    _edit_row(out / "coverage_trials.csv", {"config": "R = 8", "level": "8", "planner": "ssap"},
              "deployed_penalty", "0|0|0|0|0|0|0|0")
    code, text = _check(out, capsys)
    assert code == 1 and "sweep coverage config R = 8 level 8 trial 0 planner ssap: deployed_penalty committed" in text
    info = json.loads((out / "run_info.json").read_text())
    info["sweeps"]["coverage"]["carriers"] = [4, 9]
    (out / "run_info.json").write_text(json.dumps(info))
    code, text = _check(out, capsys)
    assert code == 1 and "config R = 9 level 0 trial 0 planner closed-loop: no committed row" in text


def test_a_setting_other_than_the_recorded_one_shows_in_the_rows(results, tmp_path, capsys):
    out = _copy(results, tmp_path, ("scaling",))
    info = json.loads((out / "run_info.json").read_text())
    info["sweeps"]["scaling"]["scaling_overlaps"] = 5
    (out / "run_info.json").write_text(json.dumps(info))
    code, text = _check(out, capsys)
    assert code == 1 and "scaling_trials.csv" in text and "overlaps committed '4', re-run '5'" in text


def test_an_archived_directory_is_listed_not_checked(results, tmp_path, capsys):
    out = _copy(results, tmp_path, ("overlap",))
    _edit_row(out / "overlap_trials.csv", {"level": "9", "trial": "1", "planner": "closed-loop"}, "reward", "99")
    info = json.loads((out / "run_info.json").read_text())
    (out / "run_info.json").write_text(json.dumps({"archive": "an earlier default", **info}))
    code, text = _check(out, capsys)
    assert code == 0 and f"{out}: not checked, archived: an earlier default" in text


def test_a_missing_field_or_file_is_a_difference_that_names_it(results, tmp_path, capsys):
    out = _copy(results, tmp_path, ("overlap", "types"))
    info = json.loads((out / "run_info.json").read_text())
    del info["sweeps"]["overlap"]["iterations"]
    (out / "run_info.json").write_text(json.dumps(info))
    (out / "types_trials.csv").unlink()
    code, text = _check(out, capsys)
    assert code == 1
    assert "sweep 'overlap': expected the field 'iterations', found none" in text
    assert "types_trials.csv: missing, but run_info.json records the sweep 'types'" in text


def test_a_run_info_that_does_not_parse_is_named(tmp_path, capsys):
    (tmp_path / "run_info.json").write_text("{not json")
    code, text = _check(tmp_path, capsys)
    assert code == 1 and f"{tmp_path / 'run_info.json'}: expected JSON, found a file that does not parse" in text


@pytest.mark.parametrize("args, text", [
    (["--out", "/nonexistent/results"], "--out: expected a results directory with a run_info.json"),
    (["--sample", "0"], "--sample: expected an integer >= 1, found 0"),
], ids=["out", "sample"])
def test_bad_arguments_exit_2_with_one_line(args, text):
    proc = subprocess.run([sys.executable, "-m", "experiments", "check", *args], cwd=ROOT, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1 and text in proc.stderr, proc.stderr


def test_the_sample_takes_each_planner_alike_and_is_fixed_by_its_seed():
    import numpy as np

    tasks = run.build_tasks("overlap", run.settings_of(run.parse_args(["overlap", "--trials", "5"])),
                            run.parse_args(["overlap"]))
    a = check.sample(tasks, 3, np.random.default_rng(0))
    assert a == check.sample(tasks, 3, np.random.default_rng(0))
    assert a != check.sample(tasks, 3, np.random.default_rng(1))
    planners = [t.planner for t in a]
    assert {planners.count(p) for p in set(planners)} == {3} and len(set(planners)) == 6
