"""Do the committed results come from this code? ``python -m experiments check`` re-runs a seeded
sample of the tasks behind a results directory and compares their rows with the committed ones.

Every sweep recorded in ``run_info.json`` of ``--out`` (default docs/results) and of the
directories below it is rebuilt from the settings recorded there (trials, iterations, root seed,
planners, levels and the sweep's own settings: :func:`experiments.run.rebuild_settings`), which
gives the task list ``python -m experiments SWEEP`` ran. ``--sample K`` tasks per planner and
sweep are drawn with ``numpy.random.default_rng(--sample-seed)``, run, written by the sweep's own
CSV writer and compared with the committed row of the same identity (:data:`IDENTITY`) column by
column, the timing columns (:data:`experiments.report.TIMING_FIELDS`) left out.

A task is deterministic given its seeds and its budget (iterations, not time), on every machine
with the packages of constraints.txt, so a difference means that the committed row came from
other code, other settings or other library versions. The command prints each difference (row,
column, committed and re-run values) and exits 1; it exits 0 when every sampled row is identical.

A directory whose run_info.json has an ``"archive"`` entry keeps a past configuration for the
record (for instance a default changed since); it is listed with that reason and not checked.

Usage::

    python -m experiments check                       # 2 tasks per planner of every sweep
    python -m experiments check --sample 10 --out docs/results/priors
"""
from __future__ import annotations

import argparse
import csv
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from experiments import bound, coverage, marine, priors, report, run, types
from world.paths import IN_CLONE

#: The columns that name a row (which task it is); the others are its outcome.
IDENTITY = ("sweep", "case", "config", "level", "trial", "planner", "variant", "prior")
#: The per-trial CSV of each sweep and the sweep's writer of it.
TRIALS = {"overlap": report.write_trials, "scaling": report.write_trials, "urban": report.write_trials,
          "comms": report.write_trials, "types": types.write_trials, "priors": priors.write_trials,
          "bound": bound.write_trials, "coverage": coverage.write_trials, "marine": marine.write_trials}


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m experiments check", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", type=Path, default=run.SHIPPED_OUT if IN_CLONE else Path("results"),
                   help="results directory to check, with the ones below it (default "
                        + ("docs/results, the shipped results)" if IN_CLONE else "results)"))
    p.add_argument("--sample", type=int, default=2, help="tasks re-run per planner and sweep (default 2)")
    p.add_argument("--sample-seed", type=int, default=0, help="seed of the sample (default 0)")
    p.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="worker processes (default: all cores)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    return p.parse_args(argv)


def results_dirs(root: Path) -> list[Path]:
    """``root`` and every directory below it that holds a run_info.json, in path order."""
    return sorted(path.parent for path in root.rglob("run_info.json"))


def sweep_args(sweep: str, entry: dict, out: Path) -> argparse.Namespace:
    """The command line of the run a run_info.json entry records (its missing fields: the
    defaults of the revision that wrote it)."""
    argv = [sweep, "--iterations", str(entry["iterations"]), "--seed", str(entry["seed"]),
            "--planners", ",".join(entry["planners"]), "--out", str(out), *(["--quick"] if entry.get("quick") else [])]
    levels = ",".join(str(v) for v in entry["levels"])
    if sweep == "bound":
        if entry.get("bound_trials"):
            argv += ["--trials", str(entry["bound_trials"])]
        argv += ["--bound-method", str(entry.get("bound_method", "lp"))]  # lp: the default until 2026-12-07
    elif sweep == "urban":
        argv += ["--urban-trials", str(entry["trials"])]
        if "scenario" in entry:
            argv += ["--scenario", str(run.ROOT / entry["scenario"])]
    else:
        argv += ["--trials", str(entry["trials"])]
    if sweep == "overlap":
        argv += ["--overlaps", levels]
    elif sweep == "scaling":
        argv += ["--carriers", levels, "--scaling-overlaps", str(entry.get("scaling_overlaps", 10))]
    elif sweep == "comms":
        argv += ["--losses", levels, "--message-delay", str(entry.get("message_delay", 0))]
    elif sweep == "coverage":
        argv += ["--overlaps", levels, "--carriers", ",".join(str(v) for v in entry["carriers"])]
    return run.parse_args(argv)


def sample(tasks: list, per_planner: int, rng: np.random.Generator) -> list:
    """``per_planner`` tasks of each planner (all of them when it has fewer), drawn without
    replacement; planners in the order they first appear."""
    by_planner: dict[str, list] = {}
    for task in tasks:
        by_planner.setdefault(task.planner, []).append(task)
    chosen = []
    for group in by_planner.values():
        picks = rng.choice(len(group), size=min(per_planner, len(group)), replace=False)
        chosen += [group[i] for i in sorted(picks)]
    return chosen


def _identity(row: dict) -> tuple:
    return tuple((k, row[k]) for k in IDENTITY if k in row)


def _value(text: str) -> str:
    """A cell as compared: an empty cell and ``nan`` both mean no value (``--report-only``
    rewrites the one as the other)."""
    return "" if text == "nan" else text


def compare(committed: Path, rerun: Path) -> tuple[int, list[str]]:
    """(rows compared, one line per difference) between the re-run rows and the committed ones."""
    with open(committed, newline="") as f:
        known = {_identity(row): row for row in csv.DictReader(f)}
    differences, n = [], 0
    with open(rerun, newline="") as f:
        for row in csv.DictReader(f):
            n += 1
            key = _identity(row)
            name = " ".join(f"{k} {v}" for k, v in key)
            old = known.get(key)
            if old is None:
                differences.append(f"{name}: no committed row")
                continue
            for column, value in row.items():
                if column not in report.TIMING_FIELDS and _value(old.get(column, "")) != _value(value):
                    differences.append(f"{name}: {column} committed {old.get(column)!r}, re-run {value!r}")
    return n, differences


def check_sweep(sweep: str, entry: dict, out: Path, args, pool) -> list[str]:
    """Re-run the sample of one sweep; returns its differences (printed as they are found)."""
    path = out / f"{sweep}_trials.csv"
    problem = None
    if sweep not in TRIALS:
        problem = f"{out / 'run_info.json'}: sweep {sweep!r}: expected one of {', '.join(TRIALS)}"
    elif not path.is_file():
        problem = f"{path}: missing, but run_info.json records the sweep {sweep!r}"
    else:
        try:
            sweep_ns = sweep_args(sweep, entry, out)
            tasks = run.build_tasks(sweep, run.settings_of(sweep_ns), sweep_ns)
        except KeyError as err:
            problem = f"{out / 'run_info.json'}: sweep {sweep!r}: expected the field {err}, found none"
        except (run.UsageError, SystemExit) as err:
            problem = f"{out / 'run_info.json'}: sweep {sweep!r}: its settings do not make a command line: {err}"
    if problem is not None:
        print(problem)
        return [problem]
    chosen = sample(tasks, args.sample, np.random.default_rng(args.sample_seed))
    t0 = time.perf_counter()
    rows = run.run_tasks(chosen, pool, f"check {sweep}", not args.no_progress)
    with tempfile.TemporaryDirectory() as tmp:
        TRIALS[sweep](rows, Path(tmp) / path.name)
        n, differences = compare(path, Path(tmp) / path.name)
    verdict = "identical" if not differences else f"{len(differences)} difference(s)"
    print(f"{path.relative_to(args.out.parent) if path.is_relative_to(args.out.parent) else path}: "
          f"{n} of {len(tasks)} tasks re-run in {time.perf_counter() - t0:.1f} s, {verdict}")
    for line in differences:
        print(f"  {line}")
    return differences


def main(argv=None) -> int:
    args = parse_args(argv)
    for flag, value in (("--sample", args.sample), ("--jobs", args.jobs)):
        if value < 1:
            print(f"python -m experiments check: error: {flag}: expected an integer >= 1, found {value}",
                  file=sys.stderr)
            return 2
    if not args.out.is_dir() or not results_dirs(args.out):
        print(f"python -m experiments check: error: --out: expected a results directory with a run_info.json, "
              f"found none at {str(args.out)!r}", file=sys.stderr)
        return 2
    pool = run.local_pool(args.jobs, None)
    differences = []
    try:
        for out in results_dirs(args.out):
            try:
                info = json.loads((out / "run_info.json").read_text())
            except (json.JSONDecodeError, UnicodeDecodeError) as err:
                differences.append(f"{out / 'run_info.json'}: expected JSON, found a file that does not parse ({err})")
                print(differences[-1])
                continue
            if "archive" in info:
                print(f"{out}: not checked, archived: {info['archive']}")
                continue
            for sweep, entry in info.get("sweeps", {}).items():
                differences += check_sweep(sweep, entry, out, args, pool)
    finally:
        if pool is not None:
            pool.shutdown(cancel_futures=True)
    print("every sampled row is identical" if not differences else
          f"{len(differences)} difference(s): the committed results did not come from this code and these settings")
    return 0 if not differences else 1
