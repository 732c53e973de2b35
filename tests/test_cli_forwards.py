"""The planner's command lines live in planner/cli/; every documented spelling still runs them:
``python -m planner.online_optimal``, ``planner.clairvoyant`` and ``planner.conformance`` (forwards
within planner/), ``python -m coordinator.solve`` and ``coordinator.bench`` (forwards above it)."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", *args], cwd=ROOT, capture_output=True, text=True, timeout=180)


@pytest.mark.parametrize("module, prog", [
    ("planner.online_optimal", "python -m planner.online_optimal"),
    ("planner.clairvoyant", "python -m planner.clairvoyant"),
    ("planner.conformance", "python -m planner.conformance"),
    ("planner.cli.solve", "python -m planner.cli.solve"),
    ("coordinator.solve", "python -m coordinator.solve"),
    ("planner.cli.bench", "python -m planner.cli.bench"),
    ("coordinator.bench", "python -m coordinator.bench"),
])
def test_every_spelling_reaches_its_command_line(module, prog):
    proc = _run(module, "--help")
    assert proc.returncode == 0 and proc.stdout.startswith(f"usage: {prog} "), proc.stdout[:200] + proc.stderr


def test_the_clairvoyant_timing_runs_through_its_forward():
    proc = _run("planner.clairvoyant", "--instances", "2", "--carriers", "2", "--stages", "4", "--overlaps", "2")
    assert proc.returncode == 0 and proc.stdout.startswith("R=2 D=3 N=4 overlaps=2: 2 instances, exact 2"), proc.stderr


def test_a_forward_keeps_the_exit_status():
    bench = _run("coordinator.bench", "--sizes", "x")
    assert bench.returncode == 2 and bench.stderr.splitlines() == [
        "bench: --sizes: expected comma-separated positive integers, found 'x'"]
    kit = _run("planner.conformance", "no_such_module_zz:P")
    assert kit.returncode == 2 and len(kit.stderr.splitlines()) == 1
