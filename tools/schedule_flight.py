"""Simulated fault schedules flown on real processes: per fault kind, the seeds whose drawn
schedule has only that kind, each simulated (``python -m mission.simulate``'s per-seed report)
and flown by ``run_fleet.py SCENARIO --schedule F.json`` (:mod:`launcher.faults`), and the
agreement table of the two: how many seeds' deployments are equal, carrier by carrier, stage by
stage (docs/fleet.md, "Fault schedules on real processes").

    python -m tools.schedule_flight                                    # every flown kind, 1 seed, two scenarios
    python -m tools.schedule_flight --kinds crash,freeze --seeds 3 --mode hybrid --json /tmp/flight.json

Scenarios: six_carriers (the one the simulator was developed on) and a generated street grid of
6 carriers (``tools.scale``'s family, seed 3). Seeds are picked in order among those whose
schedule lasts at most ``--longest`` seconds (a real flight takes as long as its faults) and
whose simulated mission has no violation.

Besides the whole deployments, the table counts the seeds whose deployments agree on the stages
whose Decisions were out before the first fault struck (what the schedule determines whatever
the timing; the last Decision recorded when it struck may still be in flight, and is not counted).
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from launcher.faults import FLOWN, OWN_DISK
from mission.modes import Mode

REPO = Path(__file__).resolve().parents[1]
SIX = REPO / "scenarios" / "six_carriers.yaml"
#: Every kind the real fleet flies, in the table's order.
KINDS = FLOWN
#: Seeds tried per kind before giving up.
TRIED = 200


def grid(path: Path, carriers: int = 6, seed: int = 3) -> Path:
    """A generated street grid (tools.scale's family), written to ``path``."""
    from tools.scale import write_scenario

    return write_scenario(carriers, path, seed=seed, planner="mcts-ssap")


def pick(fleet, kind: str, seeds: int, longest: float, shared_disk: bool = False) -> list[dict]:
    """The simulated missions (per-seed reports) of the first ``seeds`` seeds drawing only ``kind``
    whose schedule ends within ``longest`` s and whose mission has no violation; ``shared_disk``:
    only those whose standby (if any) shares the primary's mission.db, as the one-host fleet's
    does (the simulator gives half its waiting standbys a disk of their own), but for the kinds
    whose standby has its own disk in both (``launcher.faults.OWN_DISK``)."""
    from launcher.simulate import mission_json
    from mission import simulate as sim

    out = []
    for seed in range(TRIED):
        row = mission_json(fleet, seed, (kind,))
        if shared_disk and kind not in OWN_DISK and sim.Simulation(fleet, seed, kinds=(kind,)).separate:
            continue
        if not row["violations"] and max(f["until"] for f in row["faults"]) <= longest:
            out.append(row)
        if len(out) == seeds:
            break
    return out


def fly(scenario: Path, faults: list, mode: str, out: Path, timeout_s: float = 600.0) -> dict:
    """``run_fleet.py`` with the schedule ``faults`` on real processes: {deployments (carrier ->
    stages, from summary.json), decisions (summary.json's), timed_out (carrier -> the stages the
    coordinator decided without its Observation: summary.json ``missing_stages``), code, seconds,
    log (the launcher's faults.json), output}."""
    out.mkdir(parents=True, exist_ok=True)
    schedule = out.parent / f"{out.name}.schedule.json"
    schedule.write_text(json.dumps(faults, indent=1) + "\n")
    argv = [sys.executable, str(REPO / "run_fleet.py"), str(scenario), "--schedule", str(schedule), "--out", str(out),
            "--no-map", "--no-record", *(["--no-autonomy"] if mode == Mode.COORDINATED else [])]
    t0 = time.monotonic()
    proc = subprocess.run(argv, cwd=REPO, capture_output=True, text=True, timeout=timeout_s)
    summary = out / "summary.json"
    deployments = decisions = None
    timed_out: dict = {}
    if summary.exists():
        report = json.loads(summary.read_text())
        deployments = {c["id"]: sorted(d["stage"] for d in c["deployments"]) for c in report["carriers"]}
        decisions = report["decisions"]
        timed_out = {c["id"]: c["missing_stages"] for c in report["carriers"] if c.get("missing_stages")}
    log = json.loads((out / "faults.json").read_text()) if (out / "faults.json").exists() else []
    return {"deployments": deployments, "decisions": decisions, "timed_out": timed_out, "code": proc.returncode,
            "seconds": round(time.monotonic() - t0, 1),
            "log": log, "output": (proc.stdout + proc.stderr)[-4000:]}


def before(deployments: dict, stage: int) -> dict:
    """Each carrier's deployments at stages below ``stage``."""
    return {cid: [j for j in js if j < stage] for cid, js in deployments.items()}


def compare(simulated: dict, real: dict) -> dict:
    """One seed: equal deployments, and equal at the stages whose Decisions were out before the
    first fault struck (the last one recorded then may still be in flight: not counted); with the
    carriers the real coordinator timed out (``timed_out``: on a loaded host a carrier can be
    silent past the silence timeout, a timing no schedule determines)."""
    first = min(f["decided"] for f in simulated["faults"])
    got, out = real["deployments"] or {}, max(0, first - 1)
    return {"seed": simulated["seed"], "equal": got == simulated["deployments"],
            "timed_out": real.get("timed_out", {}),
            "equal_before": bool(got) and before(got, out) == before(simulated["deployments"], out),
            "first_point": first, "simulated": simulated["deployments"], "real": real["deployments"],
            "code": real["code"], "seconds": real["seconds"], "faults": simulated["faults"]}


def agreement(scenarios: dict, kinds, seeds: int, mode: str, longest: float, work: Path, progress=None,
              shared_disk: bool = False) -> list[dict]:
    """Per scenario and kind: the seeds flown and how they compare (:func:`compare`)."""
    from launcher.simulate import build_fleet

    rows = []
    for name, path in scenarios.items():
        fleet = build_fleet(str(path), mode)
        for kind in kinds:
            picked = pick(fleet, kind, seeds, longest, shared_disk)
            flown = []
            for row in picked:
                real = fly(path, row["faults"], mode, work / f"{name}-{kind}-{row['seed']}")
                flown.append(compare(row, real))
                if progress is not None:
                    progress(name, kind, flown[-1])
            rows.append({"scenario": name, "kind": kind, "mode": mode, "seeds": flown})
    return rows


def table(rows) -> str:
    lines = ["| scenario | kind | mode | seeds flown | deployments equal | equal before the first fault | wall s |",
             "| --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        s = r["seeds"]
        lines.append(f"| {r['scenario']} | {r['kind']} | {r['mode']} | {', '.join(str(x['seed']) for x in s) or '-'} "
                     f"| {sum(x['equal'] for x in s)}/{len(s)} | {sum(x['equal_before'] for x in s)}/{len(s)} "
                     f"| {sum(x['seconds'] for x in s):.0f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m tools.schedule_flight", description=__doc__.split("\n\n")[0])
    p.add_argument("--kinds", default=",".join(KINDS), help="comma-separated kinds (default: every flown kind)")
    p.add_argument("--seeds", type=int, default=1, help="seeds per kind and scenario (default 1)")
    p.add_argument("--mode", choices=(Mode.COORDINATED.value, Mode.HYBRID.value), default=Mode.COORDINATED.value,
                   help="the carriers' mode, in the simulator and on the real fleet (coordinated: --no-autonomy)")
    p.add_argument("--longest", type=float, default=30.0, help="the latest end of a fault of a seed flown (s)")
    p.add_argument("--scenario", action="append", default=None,
                   help="a scenario file (repeatable; default six_carriers and a generated 6-carrier grid)")
    p.add_argument("--shared-disk", action="store_true",
                   help="only seeds whose simulated standby shares the primary's mission.db (as the real one does)")
    p.add_argument("--json", dest="json_out", type=Path, default=None, help="write every seed's comparison here")
    args = p.parse_args(argv)
    kinds = [k for k in args.kinds.split(",") if k]
    bad = [k for k in kinds if k not in KINDS]
    if bad:
        print(f"python -m tools.schedule_flight: --kinds: expected kinds among {', '.join(KINDS)}, found {bad[0]!r}",
              file=sys.stderr)
        return 2
    work = Path(tempfile.mkdtemp(prefix="schedule-flight-"))
    scenarios = ({Path(s).stem: Path(s) for s in args.scenario} if args.scenario
                 else {"six_carriers": SIX, "grid-6": grid(work / "grid_6.yaml")})

    def progress(name, kind, r):
        print(f"{name} {kind} seed {r['seed']}: {'equal' if r['equal'] else 'DIFFERENT'} "
              f"(first fault at {r['first_point']} decided; exit {r['code']}, {r['seconds']} s)", file=sys.stderr)

    rows = agreement(scenarios, kinds, args.seeds, args.mode, args.longest, work, progress, args.shared_disk)
    print(table(rows))
    if args.json_out is not None:
        args.json_out.write_text(json.dumps(rows, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
