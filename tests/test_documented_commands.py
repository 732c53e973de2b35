"""Every command README.md and docs/*.md show is run here, with a wall-time and a memory cap.

**What counts as a shown command** (`documented_commands`): a line of a code block — a fenced
block (```) or an indented block (4 spaces, after a blank line or a heading) — whose first word,
after an optional `$ ` prompt, is `python`, `python3`, `dask` or `/usr/bin/time`. A line ending
in `\\` goes on with the next line; a trailing `  # comment` is dropped; runs of blanks are one
blank. Commands inside prose (`like this`) are references to the commands below, not extracted.

**The table** (`CASES`): every extracted command must be a key of it, or
`test_every_documented_command_has_an_entry` fails, so a new command in the docs needs an entry
here. An entry says how the command runs:

* `Run(steps, tier, wall_s, mem_mb)`: the steps are run as shell commands from the repository
  root with this interpreter's directory first on PATH (as an activated venv does). A step is the
  documented text with explicit substitutions (outputs into `tmp_path`, free ports instead of
  7447 and the viewer's 9090/9876, `S.yaml`-style placeholders and hosts filled in) plus flags
  appended where a command would otherwise run until Ctrl-C; a size is made smaller only where
  the page itself calls it an example. Several documented commands that only work together (a
  coordinator and its carriers on "two hosts") are steps of one run, keyed by each of them. The
  run fails when a step's exit code is not the expected one, when the whole run takes more than
  `wall_s`, or when the peak resident memory of its process trees (sum over every live process,
  sampled every 0.1 s with psutil) exceeds `mem_mb`. The caps are ceilings a healthy run stays
  far below on a loaded 2-core host, not benchmarks.
* `Covered(by, why)`: the command is executed with the same arguments by the named test
  (a slow one, or `.ci/run` for the test commands themselves); the test checks that it exists.

Tiers: `default` (a few seconds: the default suite), `slow` (`-m slow`: missions, the quick
benchmark and the quick experiments) and `heavy` (`-m heavy`: the paper-size experiments, the
full benchmarks, the 1,024-carrier scale runs and the soak runs, minutes to an hour each at the
size the docs name, hours together: more than CI's limit, so neither CI tier runs them). What
the slow tier does run of them: `python -m experiments check` re-runs a seeded sample of the
tasks of every published sweep (docs/results) at the sweep's own settings and requires rows
identical to those the heavy experiment commands wrote, so their code paths and their published
output are checked on every landing.
"""
from __future__ import annotations

import ast
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import psutil
import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
COMMAND_WORDS = ("python", "python3", "dask", "/usr/bin/time")


# --------------------------------------------------------------------------- extraction

def code_lines(text: str):
    """(line number, line) of every line inside a fenced or an indented code block."""
    fenced, indented, prev_blank = False, False, True
    for n, line in enumerate(text.splitlines(), 1):
        if line.lstrip().startswith("```"):
            fenced = not fenced
            continue
        if fenced:
            yield n, line
            continue
        if line.startswith("    ") and line.strip() and (prev_blank or indented):
            indented = True
            yield n, line
        elif line.strip():
            indented = False
        prev_blank = not line.strip() or line.startswith("#")
        if not line.strip():
            continue


def normalise(command: str) -> str:
    command = re.sub(r"\s+#\s.*$", "", command)
    return " ".join(command.split())


def documented_commands() -> dict[str, list[str]]:
    """command -> the places (`page:line`) that show it."""
    found: dict[str, list[str]] = {}
    for page in PAGES:
        pending, where = None, None
        for n, line in code_lines(page.read_text()):
            text = line.strip()
            if pending is not None:
                pending += " " + text.removesuffix("\\")
                if text.endswith("\\"):
                    continue
                found.setdefault(normalise(pending), []).append(where)
                pending = None
                continue
            text = text.removeprefix("$ ")
            if text.split(" ")[0] not in COMMAND_WORDS:
                continue
            where = f"{page.relative_to(ROOT)}:{n}"
            if text.endswith("\\"):
                pending = text.removesuffix("\\")
            else:
                found.setdefault(normalise(text), []).append(where)
    return found


# --------------------------------------------------------------------------- the table's types

@dataclass(frozen=True)
class Step:
    """One shell command of a run: `doc` (a key of CASES, or None for a helper that is not a
    documented command) with `subs` (old, new) replacements applied in order, then `extra`."""
    doc: str | None
    subs: tuple = ()
    extra: str = ""
    raw: str = ""                 # a helper's command (doc is None)
    background: bool = False      # started, then the next step; waited for (or stopped) at the end
    ready: str = ""               # a background step: regex its output prints once it is ready
    stop: bool = False            # a background step: SIGINT once the foreground steps are done
    rc: tuple = (0,)              # accepted exit codes
    cwd: str = ""                 # "{copy}": a copy of the repository's tracked files

    def command(self) -> str:
        text = self.doc if self.doc is not None else self.raw
        for old, new in self.subs:
            assert old in text, f"substitution {old!r} does not apply to {text!r}"
            text = text.replace(old, new)
        return f"{text} {self.extra}".strip()


@dataclass(frozen=True)
class Run:
    name: str
    steps: tuple
    tier: str                      # default, slow or heavy
    wall_s: float
    mem_mb: float
    check: object = None           # optional callable(outputs: list[str], tmp: Path) -> None


@dataclass(frozen=True)
class Covered:
    by: str                        # "tests/test_x.py::test_y" or ".ci/run"
    why: str


def S(doc, *subs, **kw):
    return Step(doc, tuple(subs), **kw)


OUT = ("--out runs/", "--out {tmp}/runs/")

# --------------------------------------------------------------------------- the table

SIX = "python run_fleet.py scenarios/six_carriers.yaml"
TWO_HOSTS_COORD = (SIX + " --role coordinator --listen tcp/0.0.0.0:7447 --out runs/six-two-hosts")
TWO_HOSTS_CARRIER = SIX + " --role carrier --carrier $c --connect tcp/192.168.1.10:7447 --out runs/six-two-hosts &"
VIEWER = SIX + " --role viewer --connect tcp/192.168.1.10:7447"
VIEW = SIX + " --view --realtime 10"
FRESH_RUN = ("python3 -m venv .venv && . .venv/bin/activate && pip install -e . -c constraints.txt "
             "&& python -m planner.cli.compile && python run_fleet.py scenarios/six_carriers.yaml")
FRESH_TEST = ("python3 -m venv .venv && . .venv/bin/activate && pip install -e '.[test]' -c constraints.txt "
              "&& python -m planner.cli.compile && python -m pytest -q -n 3")
ROLES_COORD = "python run_fleet.py S.yaml --role coordinator --listen tcp/0.0.0.0:7447 --out runs/m1"
ROLES_ONE = "python run_fleet.py S.yaml --role carrier --carrier c2 --connect tcp/10.0.0.5:7447"
ROLES_SOME = "python run_fleet.py S.yaml --role carrier --carrier c2,c3,c4 --connect tcp/10.0.0.5:7447"
REPORT = "python run_fleet.py S.yaml --role report --out runs/m1"
REPORT_SYNOPSIS = "python run_fleet.py SCENARIO --role report --out DIR [--seed S] [--mission ID] [--no-map]"
TINY_SSAP = "python run_fleet.py scenarios/tiny.yaml --planner ssap --seed 3"
DECENTRALISED = "python run_fleet.py S.yaml --decentralised"
PROCESSES = "python run_fleet.py S.yaml --carrier-processes 8"
ROUTER = "python run_fleet.py --role router --listen tcp/0.0.0.0:7447"
ROBOT = ("python run_fleet.py scenarios/field.yaml --role carrier --carrier c3 --ros2-robot --ros2-namespace "
         "/robot1 --ros2-domain 0 --realtime 1 --connect tcp/10.0.0.5:7447 --out runs/c3")
TIMED = '/usr/bin/time -f "real %e s" python run_fleet.py scenarios/six_carriers.yaml --out /tmp/six_p1'
CERTS_TINY = "python tools/gen_certs.py --out certs --scenario scenarios/tiny.yaml"
TLS_COORD = "python run_fleet.py scenarios/tiny.yaml --role coordinator --zenoh-config certs/coordinator.json5 &"
TLS_A = "python run_fleet.py scenarios/tiny.yaml --role carrier --carrier a --zenoh-config certs/carrier-a.json5 &"
TLS_B = "python run_fleet.py scenarios/tiny.yaml --role carrier --carrier b --zenoh-config certs/carrier-b.json5"
CERTS_SIX = ("python tools/gen_certs.py --out certs --scenario scenarios/six_carriers.yaml --hosts coord.lan "
             "10.0.0.1 --listen tls/0.0.0.0:7447 --connect tls/10.0.0.1:7447")
SOLVE = "python -m planner.cli.solve INSTANCE.json --planner NAME [--iterations K] [--plan-ms MS]"
CONFORMANCE = ("python -m wire.conformance scenarios/tiny.yaml --carrier a -- python run_fleet.py {scenario} "
               "--role carrier --carrier {carrier} --connect {endpoint} --seed {seed} --mission {mission} "
               "--no-autonomy --out {workdir}")


def _marine_simulated(outputs, tmp):
    """The simulated marine mission completes with every vessel's three passengers deployed."""
    import json

    seed = json.loads((tmp / "marine.json").read_text())["per_seed"][0]
    assert seed["completed"] and seed["reward"] > 0 and not seed["violations"], seed
    assert sorted(len(v) for v in seed["deployments"].values()) == [3, 3, 3], seed["deployments"]


def _summary(path_glob, coordinator=True):
    """The run's summary.json: every carrier released all its passengers (the rule that a carrier
    must), and a coordinator, when there was one, decided every stage and ended complete."""
    def check(outputs, tmp):
        import json
        files = sorted(tmp.glob(path_glob))
        assert files, f"no {path_glob} under {tmp}"
        summary = json.loads(files[-1].read_text())
        for carrier in summary["carriers"]:
            assert len(carrier["deployments"]) == carrier["passengers"], carrier
        if coordinator:
            assert summary["ended"] and summary["end_reason"] == "complete", summary.get("end_reason")
            assert summary["stages_decided"] == summary["stages"], summary["stages_decided"]
    return check


def _reproduces(*files):
    """The run's per-trial CSVs equal the committed ones of docs/results row for row, every column
    but the timings (experiments.check.compare): ``files`` are (committed, written) pairs, the
    written one relative to the run's directory."""
    def check(outputs, tmp):
        from experiments.check import compare

        for committed, written in files:
            with open(ROOT / committed) as f:
                rows = sum(1 for _ in f) - 1
            n, differences = compare(ROOT / committed, tmp / written)
            assert n == rows and not differences, (committed, n, rows, differences[:10])
    return check


def _solve_check(outputs, tmp):
    """The figures docs/planner.md's "Worked example" quotes for these two runs."""
    import json
    page = (ROOT / "docs" / "planner.md").read_text()
    mcts, ssap = json.loads(outputs[1]), json.loads(outputs[2])
    quoted = re.search(r"`--planner mcts-ssap --iterations 2000` ([\d.]+)", page)
    assert mcts["planner"] == "mcts-ssap" and mcts["features"] == float(quoted.group(1)), mcts
    block = page[page.index('{"planner": "ssap", "seed": 1,'):]
    assert ssap["deployments"] == json.loads(re.search(r'"deployments": (\[\[.*?\]\])', block).group(1))
    for key in ("reward", "features"):
        assert ssap[key] == float(re.search(rf'"{key}": ([\d.]+)', block).group(1)), (key, ssap[key])
    assert ssap["clairvoyant"] == json.loads(re.search(r'"clairvoyant": (\{.*?\})', block).group(1))


#: The example instance of docs/planner.md ("Worked example"), written by a helper step.
EXAMPLE_JSON = ("python -c \"import re,pathlib; t=pathlib.Path('docs/planner.md').read_text(); "
                "b=t.split('\\`example.json\\`:')[1].split('Carrier 0 is')[0]; "
                "pathlib.Path('{tmp}/example.json').write_text(b)\"")

RUNS = [
    # ---- README: the main job on a fresh machine (a copy of the repository, a new venv)
    Run("fresh-venv-main-job", (S(FRESH_RUN, cwd="{copy}"),), "slow", wall_s=900, mem_mb=3000,
        check=lambda outputs, tmp: _summary("copy/runs/six_carriers-*/summary.json")(outputs, tmp)),
    # ---- docs/fleet.md, the command list at the top
    Run("tiny-ssap-then-report", (
        S(TINY_SSAP, extra="--out {tmp}/runs/m1"),
        S(REPORT, ("S.yaml", "scenarios/tiny.yaml"), OUT, extra="--seed 3"),
        S(REPORT_SYNOPSIS, ("SCENARIO", "scenarios/tiny.yaml"), ("DIR", "{tmp}/runs/m1"), ("[--seed S]", "--seed 3"),
          ("[--mission ID]", "--mission tiny"), ("[--no-map]", "--no-map")),
    ), "slow", wall_s=240, mem_mb=2000, check=_summary("runs/m1/summary.json")),
    Run("roles-on-one-host", (
        S(ROLES_COORD, ("S.yaml", "scenarios/six_carriers.yaml"), ("0.0.0.0:7447", "127.0.0.1:{port}"), OUT,
          background=True),
        S(ROLES_SOME, ("S.yaml", "scenarios/six_carriers.yaml"), ("10.0.0.5:7447", "127.0.0.1:{port}"),
          background=True),
        # the same command with another id: c2 flies in the step above
        S(ROLES_ONE, ("S.yaml", "scenarios/six_carriers.yaml"), ("10.0.0.5:7447", "127.0.0.1:{port}"),
          ("--carrier c2", "--carrier c1"), background=True),
        Step(None, raw=SIX + " --role carrier --carrier c5,c6 --connect tcp/127.0.0.1:{port}"),
    ), "slow", wall_s=300, mem_mb=2500, check=_summary("runs/m1/summary.json")),
    Run("decentralised", (S(DECENTRALISED, ("S.yaml", "scenarios/tiny.yaml"), extra="--out {tmp}/dec"),),
        "slow", wall_s=240, mem_mb=2000, check=_summary("dec/summary.json", coordinator=False)),
    Run("operator-console", (
        S("python run_fleet.py scenarios/six_carriers.yaml --operator",
          ("--operator", "--operator --operator-port 0 --operator-timeout 0.5"), extra="--out {tmp}/op1"),
        S("python run_fleet.py S.yaml --operator --operator-timeout 0", ("S.yaml", "scenarios/tiny.yaml"),
          extra="--operator-port 0 --out {tmp}/op2"),
        S("python run_fleet.py S.yaml --operator --operator-required", ("S.yaml", "scenarios/tiny.yaml"),
          extra="--operator-port 0 --stage-timeout 1 --out {tmp}/op3"),
    ), "slow", wall_s=600, mem_mb=3000, check=_summary("op3/summary.json")),
    Run("carrier-processes", (
        Step(None, raw="python -m tools.scale --write-scenario 8 {tmp}/grid_8.yaml"),
        S(PROCESSES, ("S.yaml", "{tmp}/grid_8.yaml"), extra="--out {tmp}/procs"),
    ), "slow", wall_s=300, mem_mb=3000, check=_summary("procs/summary.json")),
    Run("router", (
        S(ROUTER, ("0.0.0.0:7447", "127.0.0.1:{port}"), background=True, ready="listening on", stop=True,
          rc=(0, 130)),
        Step(None, raw="python -c \"import socket; socket.create_connection(('127.0.0.1', {port}), 5).close()\""),
    ), "default", wall_s=60, mem_mb=400),
    # ---- docs/fleet.md, "Two hosts" (one host here), with a viewer watching
    Run("two-hosts", (
        S(TWO_HOSTS_COORD, ("0.0.0.0:7447", "127.0.0.1:{port}"), OUT, background=True),
        S(VIEWER, ("192.168.1.10:7447", "127.0.0.1:{port}"), extra="--web-port {port2} --grpc-port {port3}",
          background=True, ready="live view", stop=True, rc=(0, 130)),
        S(TWO_HOSTS_CARRIER, ("$c", "{c}"), ("192.168.1.10:7447", "127.0.0.1:{port}"), OUT, ("&", ""),
          background=True),
    ), "slow", wall_s=300, mem_mb=3500, check=_summary("runs/six-two-hosts/summary.json")),
    Run("live-view", (
        S(VIEW, extra="--out {tmp}/view --web-port {port2} --grpc-port {port3}", background=True,
          ready="live view stays at", stop=True, rc=(0, 130)),
    ), "slow", wall_s=300, mem_mb=3500, check=_summary("view/summary.json")),
    # ---- docs/security.md
    Run("tls-tiny", (
        S(CERTS_TINY, ("--out certs", "--out {tmp}/certs")),
        Step(None, raw="python -c \"import pathlib; [p.write_text(p.read_text().replace('7447', '{port}')) "
                       "for p in pathlib.Path('{tmp}/certs').glob('*.json5')]\""),
        S(TLS_COORD, ("certs/", "{tmp}/certs/"), ("&", "--out {tmp}/tls"), background=True),
        S(TLS_A, ("certs/", "{tmp}/certs/"), ("&", "--out {tmp}/tls"), background=True),
        S(TLS_B, ("certs/", "{tmp}/certs/"), extra="--out {tmp}/tls"),
    ), "slow", wall_s=300, mem_mb=2000, check=_summary("tls/summary.json")),
    Run("certs-six", (S(CERTS_SIX, ("--out certs", "--out {tmp}/certs6")),), "default", wall_s=60, mem_mb=400),
    # ---- docs/protocol.md, docs/scenario.md, docs/planner.md, docs/performance.md: quick tools
    Run("sensed", (S("python -m tools.sensed SCENARIO --carrier ID [--seed S] [--out FILE]",
                     ("SCENARIO", "scenarios/tiny.yaml"), ("ID", "a"), ("[--seed S]", "--seed 1"),
                     ("[--out FILE]", "--out {tmp}/sensed.json")),), "default", wall_s=60, mem_mb=800),
    Run("marine-simulated", (S("python -m mission.simulate scenarios/marine_survey.yaml --seeds 0:1 --faults none "
                               "--json marine.json", ("marine.json", "{tmp}/marine.json")),), "slow", wall_s=90,
        mem_mb=1500, check=_marine_simulated),
    Run("world-check", (S("python -m world check SCENARIO.yaml [--seeds 200]", ("SCENARIO.yaml", "scenarios/tiny.yaml"),
                          ("[--seeds 200]", "--seeds 200")),), "default", wall_s=90, mem_mb=800),
    Run("world-render", (S("python -m world render SCENARIO.yaml -o map.png [--trajectories] [--seed S] "
                           "[--no-stage-labels]", ("SCENARIO.yaml", "scenarios/tiny.yaml"),
                           ("map.png", "{tmp}/map.png"), ("[--trajectories]", "--trajectories"),
                           ("[--seed S]", "--seed 2"), ("[--no-stage-labels]", "--no-stage-labels")),),
        "default", wall_s=90, mem_mb=800),
    Run("world-marine", (S("python -m world.marine --out SCENARIO.yaml [--seed S] [--vessels V]",
                           ("SCENARIO.yaml", "{tmp}/marine.yaml"), ("[--seed S]", "--seed 7"),
                           ("[--vessels V]", "--vessels 2")),), "default", wall_s=90, mem_mb=800),
    Run("wire-sizes", (S("python -m tools.wire_sizes [SCENARIO.yaml]",
                         ("[SCENARIO.yaml]", "scenarios/marine_survey.yaml")),), "default", wall_s=60, mem_mb=600),
    Run("world-export", (S("python -m world export SCENARIO.yaml -o instance.json [--seed S]",
                           ("SCENARIO.yaml", "scenarios/six_carriers_coverage.yaml"),
                           ("instance.json", "{tmp}/instance.json"), ("[--seed S]", "--seed 3")),),
        "default", wall_s=90, mem_mb=800),
    Run("solve-example", (
        Step(None, raw=EXAMPLE_JSON),
        S(SOLVE, ("INSTANCE.json", "{tmp}/example.json"), ("NAME", "mcts-ssap"), ("[--iterations K]", "--iterations 2000"),
          ("[--plan-ms MS]", "--seed 1")),
        S(SOLVE, ("INSTANCE.json", "{tmp}/example.json"), ("NAME", "ssap"), ("[--iterations K] ", ""),
          ("[--plan-ms MS]", "--plan-ms 20 --seed 1")),
    ), "slow", wall_s=240, mem_mb=1500, check=_solve_check),
    # docs/planner.md, "Writing a planner plug-in": the example package installed by pip into a
    # target directory (from a copy, offline), which the documented command then finds on PYTHONPATH.
    Run("plugin-conformance", (
        Step(None, raw="cp -r examples/greedy-planner {tmp}/greedy-planner && python -m pip install -q --no-deps "
                       "--no-build-isolation --no-index --target {tmp}/site {tmp}/greedy-planner"),
        S("python -m planner.conformance greedy --option q=0.8", ("python -m", "PYTHONPATH={tmp}/site python -m")),
    ), "default", wall_s=180, mem_mb=1500),
    Run("overhead-bench", (S("python -m tools.overhead_bench", extra="--carriers 16 --seconds 2 --events 100"),),
        "default", wall_s=90, mem_mb=800),
    Run("write-scenario", (S("python -m tools.scale --write-scenario 256 /tmp/grid_256.yaml",
                             ("/tmp/grid_256.yaml", "{tmp}/grid_256.yaml")),), "default", wall_s=60, mem_mb=800),
    # ---- benchmarks and experiments
    Run("bench-quick", (S("python -m coordinator.bench --quick"),), "slow", wall_s=600, mem_mb=2500),
    # its code path and table on one world per family: tests/test_bench_coverage.py (default suite)
    Run("bench-coverage", (S("python -m planner.cli.bench_coverage --instances 6"),), "heavy", wall_s=900, mem_mb=2500),
    Run("experiments-quick", (S("python -m experiments all --quick"),), "slow", wall_s=600, mem_mb=3000),
    Run("report-only", (
        Step(None, raw="cp -r docs/results {tmp}/results"),
        S("python -m experiments all --report-only --out docs/results", ("docs/results", "{tmp}/results")),
    ), "slow", wall_s=240, mem_mb=1500),
    Run("experiments-check", (S("python -m experiments check"),), "slow", wall_s=900, mem_mb=3000),
    Run("bench-full", (S("python -m coordinator.bench"),), "heavy", wall_s=3600, mem_mb=4000),
    # Compiles what is not in the machine's cache yet (NUMBA_CACHE_DIR of the run): up to a minute.
    Run("compile-kernels", (S("python -m planner.cli.compile"),), "slow", wall_s=600, mem_mb=1500),
    # Fresh venvs (pip install from its cache) and cold fleet runs: minutes each.
    Run("startup-bench", (S("python -m tools.startup_bench", extra="--work {tmp}/startup"),), "heavy",
        wall_s=3600, mem_mb=6000),
    Run("startup-bench-tree", (S("python -m tools.startup_bench --baseline none --grid 0",
                                 extra="--work {tmp}/startup"),), "heavy", wall_s=1800, mem_mb=4000),
    Run("scale-default", (S("python -m tools.scale", extra="--out {tmp}/scale"),), "heavy", wall_s=7200, mem_mb=12000),
    Run("scale-256-plot", (S("python -m tools.scale --sizes 6,32,128,256 --out runs/scale --plot docs/results/scale.png",
                             OUT, ("docs/results/scale.png", "{tmp}/scale.png")),), "heavy", wall_s=3600, mem_mb=8000),
    Run("scale-fidelity", (S("python -m tools.scale --family grid --family long-streets --sizes 6,32,128,256,1024 "
                             "--busy 0,4 --plot scale.png", ("scale.png", "{tmp}/scale.png"), extra="--out {tmp}/fidelity"),),
        "heavy", wall_s=7200, mem_mb=12000),
    Run("scale-fidelity-merge", (S("python -m tools.scale --family grid --sizes 256,1024 --merge "
                                   "docs/results/fidelity_scale.json --plot docs/results/fidelity_scale.png",
                                   ("docs/results/", "{tmp}/"), extra="--out {tmp}/merge"),),
        "heavy", wall_s=1800, mem_mb=8000),
    Run("decision-scale", (S("python -m tools.decision_scale --sizes 32,64,128,256,1024 --probes 8 --out "
                             "docs/results/decision_scale.json --plot docs/results/decision_scale.png",
                             ("docs/results/", "{tmp}/")),),
        "heavy", wall_s=3600, mem_mb=8000),
    # every sweep's code path and published rows are checked in the slow tier by experiments-check
    # (the sampled re-run); the whole published sweeps at their documented size are heavy
    Run("experiments-all", (S("python -m experiments all", extra="--out {tmp}/all"),), "heavy", wall_s=1800,
        mem_mb=4000, check=_reproduces(*((f"docs/results/{s}_trials.csv", f"all/{s}_trials.csv")
                                         for s in ("overlap", "scaling", "urban")))),
    Run("experiments-overlap", (S("python -m experiments overlap", extra="--out {tmp}/overlap"),), "heavy",
        wall_s=1800, mem_mb=4000, check=_reproduces(("docs/results/overlap_trials.csv", "overlap/overlap_trials.csv"))),
    Run("experiments-comms", (S("python -m experiments comms", extra="--out {tmp}/comms"),), "heavy",
        wall_s=3600, mem_mb=4000, check=_reproduces(("docs/results/comms_trials.csv", "comms/comms_trials.csv"))),
    Run("experiments-comms-50", (S("python -m experiments comms --trials 50 --iterations 10000 --jobs 2",
                                   extra="--out {tmp}/comms50"),), "heavy", wall_s=3600, mem_mb=4000,
        check=_reproduces(("docs/results/comms_trials.csv", "comms50/comms_trials.csv"))),
    Run("experiments-priors", (S("python -m experiments priors --trials 20 --iterations 2000 --out docs/results/priors",
                                 ("docs/results/priors", "{tmp}/priors")),), "heavy", wall_s=3600, mem_mb=4000,
        check=_reproduces(("docs/results/priors/priors_trials.csv", "priors/priors_trials.csv"))),
    Run("experiments-priors-jobs", (S("python -m experiments priors --trials 20 --iterations 2000 --jobs 2 --out "
                                      "docs/results/priors", ("docs/results/priors", "{tmp}/priors2")),),
        "heavy", wall_s=3600, mem_mb=4000,
        check=_reproduces(("docs/results/priors/priors_trials.csv", "priors2/priors_trials.csv"))),
    Run("experiments-types", (S("python -m experiments types", extra="--out {tmp}/types"),), "heavy",
        wall_s=1800, mem_mb=4000, check=_reproduces(("docs/results/types_trials.csv", "types/types_trials.csv"))),
    Run("experiments-bound", (S("python -m experiments bound", extra="--out {tmp}/bound"),), "heavy",
        wall_s=21600, mem_mb=4000, check=_reproduces(("docs/results/bound_trials.csv", "bound/bound_trials.csv"))),
    Run("experiments-coverage", (S("python -m experiments coverage", extra="--out {tmp}/coverage"),), "heavy",
        wall_s=7200, mem_mb=4000),
    Run("experiments-coverage-10", (S("python -m experiments coverage --trials 10", extra="--out {tmp}/coverage10"),),
        "heavy", wall_s=3600, mem_mb=4000,
        check=_reproduces(("docs/results/coverage_trials.csv", "coverage10/coverage_trials.csv"))),
    Run("experiments-coverage-quick", (S("python -m experiments coverage --quick"),), "slow", wall_s=300, mem_mb=3000),
    Run("experiments-operator", (S("python -m experiments operator", extra="--out {tmp}/operator"),), "heavy",
        wall_s=3600, mem_mb=3000),
    Run("experiments-operator-quick", (S("python -m experiments operator --quick"),), "slow", wall_s=300,
        mem_mb=3000),
    Run("experiments-operator-imported", (
        S("python -m tools.synthetic_run /tmp/oprooms --cells 600x400 --snapshots 16", ("/tmp/oprooms", "{tmp}/oprooms")),
        S("python -m world import /tmp/oprooms/bag --odom c0=/c0/odom --odom c1=/c1/pose --odom c2=/c2/odom "
          "--passengers c0=3 --passengers c1=3 --passengers c2=2 --radii map --replay --out /tmp/oprooms/run.yaml",
          ("/tmp/oprooms", "{tmp}/oprooms")),
        S("python -m tools.synthetic_run /tmp/opcaves --cells 600x400 --snapshots 16 --family caves --seed 1",
          ("/tmp/opcaves", "{tmp}/opcaves")),
        S("python -m world import /tmp/opcaves/bag --odom c0=/c0/odom --odom c1=/c1/pose --odom c2=/c2/odom "
          "--passengers c0=3 --passengers c1=3 --passengers c2=2 --radii map --replay --out /tmp/opcaves/run.yaml",
          ("/tmp/opcaves", "{tmp}/opcaves")),
        S("python -m experiments operator --scenario rooms=/tmp/oprooms/run.yaml --scenario caves=/tmp/opcaves/run.yaml",
          ("/tmp/oprooms", "{tmp}/oprooms"), ("/tmp/opcaves", "{tmp}/opcaves"), extra="--out {tmp}/operator"),
    ), "heavy", wall_s=900, mem_mb=3000,
        check=_reproduces(("docs/results/operator/operator_trials.csv", "operator/operator_trials.csv"))),
    Run("experiments-marine", (S("python -m experiments marine", extra="--out {tmp}/marine"),), "heavy",
        wall_s=900, mem_mb=3000, check=_reproduces(("docs/results/marine_trials.csv", "marine/marine_trials.csv"))),
    Run("coverage-report-only", (
        Step(None, raw="cp -r docs/results {tmp}/results"),
        S("python -m experiments coverage --report-only --out docs/results", ("docs/results", "{tmp}/results")),
    ), "slow", wall_s=240, mem_mb=1500),
    Run("base-policy-4", (S("python -m tools.base_policy --carriers 4 --trials 60-99"),), "slow", wall_s=600,
        mem_mb=2000),
    Run("base-policy-6", (S("python -m tools.base_policy --carriers 6 --trials 60-99"),), "slow", wall_s=900,
        mem_mb=2000),
    Run("base-policy-32", (S("python -m tools.base_policy --carriers 32 --trials 60-71"),), "heavy", wall_s=1800,
        mem_mb=3000),
    Run("base-policy-128-development", (S("python -m tools.base_policy --carriers 128 --trials 50-55"),), "heavy",
        wall_s=1800, mem_mb=3000),
    Run("base-policy-128", (S("python -m tools.base_policy --carriers 128 --trials 60-71"),), "heavy", wall_s=3600,
        mem_mb=3000),
    Run("base-policy-256", (S("python -m tools.base_policy --carriers 256 --trials 60-67"),), "heavy", wall_s=3600,
        mem_mb=4000),
    Run("base-policy-32-experiment", (S("python -m tools.base_policy --carriers 32 --trials 0-11"),), "heavy",
        wall_s=1800, mem_mb=3000),
    Run("base-policy-128-experiment", (S("python -m tools.base_policy --carriers 128 --trials 0-15"),), "heavy",
        wall_s=3600, mem_mb=3000),
    Run("base-policy-256-experiment", (S("python -m tools.base_policy --carriers 256 --trials 0-15"),), "heavy",
        wall_s=5400, mem_mb=4000),
    # The R = 256 bound rows' root nodes (docs/results.md): about 45 minutes for each half on a 2-core host.
    Run("bound-nodes-256-even", (S("python -m tools.bound_nodes --carriers 256 --trials 0,2,4,6,8,10,12,14 --out even.csv",
                                   ("--out even.csv", "--out {tmp}/even.csv")),), "heavy", wall_s=7200, mem_mb=2000),
    Run("bound-nodes-256-odd", (S("python -m tools.bound_nodes --carriers 256 --trials 1,3,5,7,9,11,13,15 --out odd.csv",
                                  ("--out odd.csv", "--out {tmp}/odd.csv")),), "heavy", wall_s=7200, mem_mb=2000),
    Run("gated-search-paper-4", (S("python -m tools.gated_search --family paper --carriers 4 --trials 20-79 --obs 8"),),
        "heavy", wall_s=900, mem_mb=2000),
    Run("gated-search-paper-6", (S("python -m tools.gated_search --family paper --carriers 6 --trials 20-59 --obs 8"),),
        "heavy", wall_s=900, mem_mb=2000),
    Run("gated-search-timing-256", (S("python -m tools.gated_search --family paper --carriers 256 --trials 20-23 --obs 1 "
                                      "--bound-samples 2"),), "heavy", wall_s=1800, mem_mb=4000),
    Run("gated-search-paper-32", (S("python -m tools.gated_search --family paper --carriers 32 --trials 20-39 --obs 8"),),
        "heavy", wall_s=1200, mem_mb=3000),
    Run("gated-search-paper-128", (S("python -m tools.gated_search --family paper --carriers 128 --trials 20-35 --obs 4"),),
        "heavy", wall_s=3600, mem_mb=3000),
    Run("gated-search-paper-256", (S("python -m tools.gated_search --family paper --carriers 256 --trials 20-27 --obs 2"),),
        "heavy", wall_s=5400, mem_mb=4000),
    Run("gated-search-dense-4", (S("python -m tools.gated_search --family dense --carriers 4 --trials 20-79 --obs 8"),),
        "heavy", wall_s=900, mem_mb=2000),
    Run("gated-search-dense-32", (S("python -m tools.gated_search --family dense --carriers 32 --trials 20-39 --obs 8"),),
        "heavy", wall_s=1200, mem_mb=3000),
    Run("gated-search-dense-32-root-a", (S("python -m tools.gated_search --family dense --carriers 32 --trials 20-29 "
                                           "--obs 8 --bound-method mixed-root"),), "heavy", wall_s=3600, mem_mb=3000),
    Run("gated-search-dense-32-root-b", (S("python -m tools.gated_search --family dense --carriers 32 --trials 30-39 "
                                           "--obs 8 --bound-method mixed-root"),), "heavy", wall_s=3600, mem_mb=3000),
    Run("gated-search-dense-128-root", (S("python -m tools.gated_search --family dense --carriers 128 --trials 20-27 "
                                          "--obs 4 --bound-method mixed-root"),), "heavy", wall_s=7200, mem_mb=3000),
    Run("gated-search-dense-256-root", (S("python -m tools.gated_search --family dense --carriers 256 --trials 20-23 "
                                          "--obs 2 --bound-method mixed-root"),), "heavy", wall_s=10800, mem_mb=4000),
    Run("gated-search-dense-128", (S("python -m tools.gated_search --family dense --carriers 128 --trials 20-35 --obs 4"),),
        "heavy", wall_s=3600, mem_mb=3000),
    Run("gated-search-dense-256", (S("python -m tools.gated_search --family dense --carriers 256 --trials 20-27 --obs 2"),),
        "heavy", wall_s=5400, mem_mb=4000),
    # docs/results.md, "Where the gap is, where V* is known": about 3 minutes each on a 2-core host.
    Run("tiny-split-paper", (S("python -m tools.tiny_split --family paper --trials 0-39 --out "
                               "docs/results/tiny_split_paper.csv", ("--out docs/results/", "--out {tmp}/")),),
        "heavy", wall_s=1200, mem_mb=2000, check=_reproduces(("docs/results/tiny_split_paper.csv", "tiny_split_paper.csv"))),
    Run("tiny-split-dense", (S("python -m tools.tiny_split --family dense --trials 0-39 --out "
                               "docs/results/tiny_split_dense.csv", ("--out docs/results/", "--out {tmp}/")),),
        "heavy", wall_s=1200, mem_mb=2000, check=_reproduces(("docs/results/tiny_split_dense.csv", "tiny_split_dense.csv"))),
    Run("tiny-split-paper-3", (S("python -m tools.tiny_split --family paper --carriers 3 --trials 0-19 --out "
                                 "docs/results/tiny_split_paper_r3.csv", ("--out docs/results/", "--out {tmp}/")),),
        "heavy", wall_s=2400, mem_mb=2000,
        check=_reproduces(("docs/results/tiny_split_paper_r3.csv", "tiny_split_paper_r3.csv"))),
    Run("tiny-split-plot", (S("python -m tools.tiny_split --plot docs/results/tiny_split.png --rows "
                              "docs/results/tiny_split_paper.csv docs/results/tiny_split_paper_r3.csv "
                              "docs/results/tiny_split_dense.csv",
                              ("--plot docs/results/", "--plot {tmp}/")),), "slow", wall_s=120, mem_mb=1000),
    Run("experiments-cluster", (
        S("dask scheduler --port 8786", ("8786", "{port}"), background=True, ready="Scheduler at", stop=True,
          rc=(0, 130, -2, 1)),
        S("dask worker tcp://SCHEDULER:8786 --nthreads 1", ("SCHEDULER:8786", "127.0.0.1:{port}"), background=True,
          stop=True, rc=(0, 130, -2, 1)),
        S("python -m experiments all --cluster tcp://SCHEDULER:8786", ("SCHEDULER:8786", "127.0.0.1:{port}"),
          extra="--out {tmp}/cluster"),
    ), "heavy", wall_s=3600, mem_mb=6000, check=_reproduces(*((f"docs/results/{s}_trials.csv", f"cluster/{s}_trials.csv")
                                                              for s in ("overlap", "scaling", "urban")))),
    Run("soak-200", (S("python tools/soak.py", extra="--out {tmp}/soak"),), "heavy", wall_s=7200, mem_mb=3000),
    Run("soak-20", (S("python tools/soak.py --missions 20 --out runs/soak", OUT),), "heavy", wall_s=1800,
        mem_mb=3000),
    Run("soak-20-paced", (S("python tools/soak.py --missions 20 -- --realtime 2",
                            ("--missions 20 --", "--missions 20 --out {tmp}/soak --")),), "heavy", wall_s=3600,
        mem_mb=3000),
]

# ---- docs/scenario.md, "Your own map and runs": the worked example and the synopsis
MYRUN = ("/tmp/myrun", "{tmp}/myrun")
SYNTHETIC = "python -m tools.synthetic_run /tmp/myrun --cells 600x400 --snapshots 16"
IMPORT_REPLAY = ("python -m world import /tmp/myrun/bag --odom c0=/c0/odom --odom c1=/c1/pose --odom c2=/c2/odom "
                 "--passengers c0=3 --passengers c1=3 --passengers c2=2 --stages 19 --replay --out /tmp/myrun/run.yaml "
                 "--report /tmp/myrun/report.json")
IMPORT_STATIC = ("python -m world import /tmp/myrun/map.yaml --routes /tmp/myrun/routes.yaml --stage-spacing 2 "
                 "--out /tmp/myrun/static.yaml")
IMPORT_SYNOPSIS = ("python -m world import SOURCE --out SCENARIO.yaml [--routes ROUTES.yaml] [--map-topic TOPIC] "
                   "[--odom ID=TOPIC]... [--passengers ID=K]... [--stage-spacing METRES | --stages N (default 19)] "
                   "[--radius METRES] [--replay] [--graze-depth METRES] [--literal-thresholds] [--report REPORT.json]")
URBAN_IMPORTED = "python -m experiments urban --scenario /tmp/myrun/run.yaml --quick --out /tmp/myrun/urban"


def _replayed_as_reported(outputs, tmp):
    """The imported replay scenario observes exactly the report's values, in order."""
    import json

    import numpy as np

    import world

    report = json.loads((tmp / "myrun" / "report.json").read_text())
    scenario = world.load_scenario(tmp / "myrun" / "run.yaml")
    x = world.observe_all(scenario)
    for r, c in enumerate(scenario.carriers):
        values = [p["value"] for p in report["carriers"][c.id]]
        assert x[r][np.isfinite(x[r])].tolist() == values, c.id
    assert len(report["carriers"]) == 3 and report["maps"] == 16, report["maps"]


RUNS += [
    Run("world-import", (
        S(SYNTHETIC, MYRUN),
        S(IMPORT_REPLAY, MYRUN),
        S(IMPORT_STATIC, MYRUN),
        S(IMPORT_SYNOPSIS, ("SOURCE", "{tmp}/myrun/bag"), ("SCENARIO.yaml", "{tmp}/myrun/syn.yaml"),
          ("[--routes ROUTES.yaml] ", ""), ("[--map-topic TOPIC]", "--map-topic /map"),
          ("[--odom ID=TOPIC]...", "--odom c0=/c0/odom --odom c1=/c1/pose --odom c2=/c2/odom"),
          ("[--passengers ID=K]...", "--passengers c0=2"), ("[--stage-spacing METRES | --stages N (default 19)]", "--stage-spacing 2"),
          ("[--radius METRES]", "--radius 8"), ("[--replay]", "--replay"), ("[--graze-depth METRES]", "--graze-depth 0.1"),
          ("[--literal-thresholds]", ""), ("[--report REPORT.json]",
                                                                         "--report {tmp}/myrun/syn.json")),
        S("python -m world import SOURCE --out SCENARIO.yaml ...", ("SOURCE", "{tmp}/myrun/map.yaml"),
          ("SCENARIO.yaml ...", "{tmp}/myrun/short.yaml --routes {tmp}/myrun/routes.yaml --stages 5")),
    ), "slow", wall_s=120, mem_mb=1500, check=_replayed_as_reported),
    Run("world-import-urban", (
        S(SYNTHETIC, MYRUN),
        S(IMPORT_REPLAY, MYRUN),
        S(URBAN_IMPORTED, MYRUN),
    ), "slow", wall_s=600, mem_mb=3000,
        check=lambda outputs, tmp: (tmp / "myrun" / "urban" / "urban_map_mcts-ssap.png").is_file() or 1 / 0),
]

# ---- docs/scenario.md, "3D maps and scans": the worked example and the synopsis
RUN3D = ("/tmp/run3d", "{tmp}/run3d")
SYNTHETIC_3D = "python -m tools.synthetic_3d /tmp/run3d --scans 40 --points 4000 --bag"
IMPORT3D_BAG = ("python -m world import /tmp/run3d/bag --cloud-topic c0=/c0/points --cloud-topic c1=/c1/points "
                "--odom c0=/c0/odom --odom c1=/c1/odom --stages 8 --replay --out /tmp/run3d/bag.yaml "
                "--report /tmp/run3d/bag.json")
IMPORT3D_FOLDER = ("python -m world import /tmp/run3d/scans --routes /tmp/run3d/routes.yaml --stages 8 --replay "
                   "--out /tmp/run3d/run.yaml")
RENDER3D = "python -m world render /tmp/run3d/run.yaml -o /tmp/run3d/map.png --trajectories"
URBAN3D = "python -m experiments urban --scenario /tmp/run3d/run.yaml --quick --out /tmp/run3d/urban"
IMPORT3D_SYNOPSIS = ("python -m world import SOURCE --out S.yaml [--routes ROUTES.yaml] [--odom ID=TOPIC]... "
                     "[--cloud-topic [ID=]TOPIC]... [--stages N | --stage-spacing M] [--radius M] [--keep-above M] "
                     "[--keep-below M] [--voxel M] [--neighbours 6|26] [--max-range M] [--sensor-offset X Y Z] "
                     "[--log-odds HIT MISS OCC MIN MAX] [--replay] [--report R.json]")


def _bag_report_3d(outputs, tmp):
    """The bag's report: z and frontier_voxels, two storeys; the picture written."""
    import json

    report = json.loads((tmp / "run3d" / "bag.json").read_text())
    assert report["frontier_voxels"] > 0 and [s["carriers"] for s in report["storeys"]] == [["c0"], ["c1"]]
    assert all("z" in p for ps in report["carriers"].values() for p in ps)
    assert (tmp / "run3d" / "map.png").stat().st_size > 10_000
    assert (tmp / "run3d" / "urban" / "urban_map_mcts-ssap.png").is_file()


RUNS += [
    Run("world-import-3d", (
        S(SYNTHETIC_3D, RUN3D),
        S(IMPORT3D_BAG, RUN3D),
        S(IMPORT3D_FOLDER, RUN3D),
        S(RENDER3D, RUN3D),
        S(URBAN3D, RUN3D),
        S(IMPORT3D_SYNOPSIS, ("SOURCE", "{tmp}/run3d/bag"), ("[--routes ROUTES.yaml] ", ""),
          ("--out S.yaml", "--out {tmp}/run3d/syn.yaml"), ("[--odom ID=TOPIC]...", "--odom c0=/c0/odom --odom c1=/c1/odom"),
          ("[--cloud-topic [ID=]TOPIC]...", "--cloud-topic c0=/c0/points --cloud-topic c1=/c1/points"),
          ("[--stages N | --stage-spacing M]", "--stages 6"), ("[--radius M]", "--radius 8"),
          ("[--keep-above M]", "--keep-above 1.5"), ("[--keep-below M]", "--keep-below 0.2"),
          ("[--voxel M]", "--voxel 0.25"), ("[--neighbours 6|26]", "--neighbours 26"), ("[--max-range M]", "--max-range 30"),
          ("[--sensor-offset X Y Z]", "--sensor-offset 0 0 0.5"),
          ("[--log-odds HIT MISS OCC MIN MAX]", "--log-odds 0.7 0.4 0.5 0.1192 0.971"), ("[--replay]", "--replay"),
          ("[--report R.json]", "--report {tmp}/run3d/syn.json")),
    ), "slow", wall_s=300, mem_mb=2000, check=_bag_report_3d),
]

#: Documented commands executed elsewhere with the same arguments.
COVERED = {
    FRESH_TEST: Covered(".ci/run", "the test command itself: .ci/run runs it on a clean machine (this module "
                                   "runs inside it)"),
    "python -m pytest -q -m slow tests/test_fidelity.py": Covered(
        ".ci/run", "the slow suite (`python -m pytest -q -m slow`, run by .ci/run) runs tests/test_fidelity.py"),
    CONFORMANCE: Covered("tests/test_conformance.py::test_the_project_carrier_passes",
                         "the same kit, scenario, carrier and carrier command (plus --workdir)"),
    SIX: Covered("tests/test_documented_commands.py::test_documented_command[fresh-venv-main-job]",
                 "the README's main job ends with this exact command"),
    TIMED: Covered("tests/test_documented_commands.py::test_documented_command[fresh-venv-main-job]",
                   "the same mission (the README's main job ends with it); only the wrapper /usr/bin/time and "
                   "the results directory differ"),
}

#: docs/fleet.md, "A ROS 2 robot in a mission": the robot is tests/ros2_robot_sim.py's simulated one
#: (rmw_zenoh's format, written independently of ros2/), carrier c3 of six_carriers standing for
#: the page's own field scenario; SIGINT ends it.
ROBOT_SIM = ("python -c \"import sys, signal, threading; sys.path.insert(0, 'tests'); import world; "
             "from ros2_robot_sim import SimulatedRobot; "
             "s = world.load_scenario('scenarios/six_carriers.yaml'); stop = threading.Event(); "
             "signal.signal(signal.SIGINT, lambda *a: stop.set()); "
             "r = SimulatedRobot(s, 'c3', 'tcp/127.0.0.1:{port}', '/robot1', 0); r.run(stop); r.close()\"")
RUNS.append(Run("ros2-robot", (
    Step(None, raw=SIX + " --role coordinator --listen tcp/127.0.0.1:{port} --realtime 1 --out {tmp}/robot",
         background=True),
    Step(None, raw=ROBOT_SIM, background=True, stop=True, rc=(0, 130, -2)),
    Step(None, raw=SIX + " --role carrier --carrier c1,c2,c4,c5,c6 --realtime 1 --connect tcp/127.0.0.1:{port} "
                         "--out {tmp}/robot", background=True),
    S(ROBOT, ("scenarios/field.yaml", "scenarios/six_carriers.yaml"), ("10.0.0.5:7447", "127.0.0.1:{port}"),
      ("--out runs/c3", "--out {tmp}/robot")),
), "heavy", wall_s=900, mem_mb=3000, check=lambda outputs, tmp: _summary("robot/summary.json")(outputs, tmp)))


def _cases() -> dict[str, object]:
    cases: dict[str, object] = dict(COVERED)
    for run in RUNS:
        for step in run.steps:
            if step.doc is not None:
                cases.setdefault(step.doc, run)
    return cases


CASES = _cases()


# --------------------------------------------------------------------------- the checks of the table

def test_every_documented_command_has_an_entry():
    shown = documented_commands()
    assert len(shown) > 30, "the extraction found almost nothing: has the docs' code-block style changed?"
    missing = {cmd: where for cmd, where in shown.items() if cmd not in CASES}
    assert not missing, ("documented commands without an entry in tests/test_documented_commands.py "
                         f"(add a Run or Covered): {missing}")
    stale = sorted(set(CASES) - set(shown))
    assert not stale, f"entries for commands no page shows any more: {stale}"


def _test_function(ref: str):
    path, name = ref.split("::")
    tree = ast.parse((ROOT / path).read_text())
    for node in tree.body:
        if isinstance(node, ast.FunctionDef) and node.name == name.split("[")[0]:
            return node
    return None


def test_covered_commands_are_run_by_what_the_table_names():
    ci = (ROOT / ".ci" / "run").read_text()
    for doc, covered in COVERED.items():
        if covered.by == ".ci/run":
            assert "python -m pytest -q" in ci, doc
            if "pip install" in doc:
                assert "python3 -m venv .venv" in ci and ". .venv/bin/activate" in ci
                assert doc.split(" && ", 2)[2] in ci  # the install, the kernels' compile step and the suite
            if "-m slow" in doc:
                assert "python -m pytest -q -m slow" in ci
                target = doc.split()[-1]
                assert "pytest.mark.slow" in (ROOT / target).read_text(), target
            continue
        node = _test_function(covered.by)
        assert node is not None, f"{covered.by} (for {doc!r}) does not exist"
        if covered.by.startswith("tests/test_documented_commands.py"):
            run_name = covered.by.split("[")[1].rstrip("]")
            assert any(r.name == run_name for r in RUNS), covered.by
        else:
            marks = [ast.unparse(d) for d in node.decorator_list]
            assert "pytest.mark.slow" in marks, f"{covered.by} is not a slow test"


def test_the_table_is_well_formed():
    names = [r.name for r in RUNS]
    assert len(names) == len(set(names))
    for run in RUNS:
        assert run.tier in ("default", "slow", "heavy") and run.wall_s > 0 and run.mem_mb > 0, run.name
        for step in run.steps:
            step.command()  # every substitution applies


# --------------------------------------------------------------------------- running a command

def _free_ports(n: int) -> list[int]:
    socks = [socket.socket() for _ in range(n)]
    try:
        for s in socks:
            s.bind(("127.0.0.1", 0))
        return [s.getsockname()[1] for s in socks]
    finally:
        for s in socks:
            s.close()


class _Proc:
    """A step's shell in its own process group, its output collected by a thread."""

    def __init__(self, command: str, cwd: Path, env: dict):
        self.command = command
        self.popen = subprocess.Popen(["bash", "-c", command], cwd=cwd, env=env, stdout=subprocess.PIPE,
                                      stderr=subprocess.STDOUT, text=True, start_new_session=True)
        self.lines: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self):
        for line in self.popen.stdout:
            self.lines.append(line)

    @property
    def output(self) -> str:
        return "".join(self.lines)

    def tree_rss(self) -> int:
        try:
            root = psutil.Process(self.popen.pid)
            procs = [root, *root.children(recursive=True)]
        except psutil.NoSuchProcess:
            return 0
        total = 0
        for p in procs:
            try:
                total += p.memory_info().rss
            except psutil.NoSuchProcess:
                pass
        return total

    def signal(self, sig):
        try:
            os.killpg(self.popen.pid, sig)
        except ProcessLookupError:
            pass

    def finish(self, timeout: float) -> int:
        rc = self.popen.wait(timeout=max(timeout, 0.1))
        self._reader.join(timeout=5)
        return rc


def _finish_within(run: Run, step: Step, proc: _Proc, deadline: float) -> None:
    """Wait for ``proc`` until the run's wall-time cap; its exit code must be one ``step`` allows."""
    try:
        rc = proc.finish(deadline - time.monotonic())
    except subprocess.TimeoutExpired:
        pytest.fail(f"{run.name}: over the wall-time cap of {run.wall_s} s in {proc.command!r}\n"
                    f"{proc.output[-3000:]}")
    assert rc in step.rc, f"{proc.command!r} exited {rc}:\n{proc.output[-3000:]}"


def _copy_repository(dest: Path) -> None:
    files = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    for rel in filter(None, files.decode().split("\0")):
        src = ROOT / rel
        if src.is_file():
            (dest / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / rel)


def execute(run: Run, tmp: Path) -> list[str]:
    """Run every step of `run`; fail on an exit code, the wall-time cap or the memory cap."""
    port, port2, port3 = _free_ports(3)
    env = dict(os.environ, PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}",
               PYTHONUNBUFFERED="1")
    env.pop("VIRTUAL_ENV", None)
    fill = {"{tmp}": str(tmp), "{port}": str(port), "{port2}": str(port2), "{port3}": str(port3)}
    deadline = time.monotonic() + run.wall_s
    peak = [0]
    live: list[_Proc] = []
    stop_sampling = threading.Event()

    def sample():
        while not stop_sampling.wait(0.1):
            peak[0] = max(peak[0], sum(p.tree_rss() for p in live if p.popen.poll() is None))

    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    started: list[tuple[Step, _Proc]] = []
    try:
        for step in run.steps:
            commands = [step.command()]
            if "{c}" in commands[0]:  # the two-hosts loop: `for c in c1 c2 c3 c4 c5 c6`
                commands = [commands[0].replace("{c}", c) for c in ("c1", "c2", "c3", "c4", "c5", "c6")]
            for command in commands:
                for key, value in fill.items():
                    command = command.replace(key, value)
                cwd = ROOT
                if step.cwd == "{copy}":
                    cwd = tmp / "copy"
                    _copy_repository(cwd)
                proc = _Proc(command, cwd, env)
                live.append(proc)
                started.append((step, proc))
                if step.background:
                    while step.ready and not re.search(step.ready, proc.output):
                        assert proc.popen.poll() is None, f"{command!r} exited early:\n{proc.output[-3000:]}"
                        assert time.monotonic() < deadline, f"{run.name}: over {run.wall_s} s waiting for {step.ready!r}"
                        time.sleep(0.1)
                    continue
                _finish_within(run, step, proc, deadline)
        for step, proc in started:
            if step.background and not step.stop:
                _finish_within(run, step, proc, deadline)
        for step, proc in started:
            if step.stop:
                proc.signal(signal.SIGINT)
                try:
                    rc = proc.finish(min(30.0, max(deadline - time.monotonic(), 5.0)))
                except subprocess.TimeoutExpired:
                    pytest.fail(f"{proc.command!r} did not stop on SIGINT:\n{proc.output[-3000:]}")
                assert rc in step.rc, f"{proc.command!r} exited {rc} on SIGINT:\n{proc.output[-3000:]}"
    finally:
        stop_sampling.set()
        sampler.join(timeout=2)
        for _, proc in started:
            if proc.popen.poll() is None:
                proc.signal(signal.SIGKILL)
                proc.popen.wait(timeout=10)
    peak_mb = peak[0] / 2**20
    assert peak_mb <= run.mem_mb, f"{run.name}: peak resident memory {peak_mb:.0f} MB over the cap of {run.mem_mb} MB"
    assert time.monotonic() <= deadline, f"{run.name}: over the wall-time cap of {run.wall_s} s"
    for step, proc in started:
        # A step stopped by SIGINT (a server: the router, the viewer, dask's scheduler and worker)
        # may print its own shutdown noise; every other step must end without a traceback.
        assert step.stop or "Traceback (most recent call last)" not in proc.output, proc.output[-3000:]
    outputs = [proc.output for _, proc in started]
    print(f"{run.name}: {run.wall_s - (deadline - time.monotonic()):.1f} s, peak {peak_mb:.0f} MB")
    return outputs


_MARKS = {"default": (), "slow": (pytest.mark.slow,), "heavy": (pytest.mark.heavy,)}


# A run's own wall-time cap is its limit (plus a minute to stop and report), not the suite's
# per-test timeout.
@pytest.mark.parametrize("run", [pytest.param(r, id=r.name,
                                              marks=(*_MARKS[r.tier], pytest.mark.timeout(r.wall_s + 60)))
                                 for r in RUNS])
def test_documented_command(run, tmp_path):
    outputs = execute(run, tmp_path)
    if run.check is not None:
        run.check(outputs, tmp_path)
