"""The deterministic simulator's campaign figures and power (docs/fleet.md, "Deterministic
simulation"): seeded missions of six_carriers and of generated 32- and 256-carrier scenarios
(tools.scale's ``grid`` and ``long-streets`` families, which the simulator was not developed on),
every fault kind, with missions and events per second and the violations found; then each known
bug class put back in turn (``--plant``) and the seeds in which the campaign finds it.

    python -m tools.sim_campaign                       # the full campaign (about 10 minutes on 2 cores)
    python -m tools.sim_campaign --six 300 --r32 20 --r256 0 --power 20    # a short one

A benchmark, not a test: it prints figures (and writes them as JSON with ``--json``).
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

from launcher.simulate import build_fleet, campaign
from mission import simulate as sim
from tools.scale import write_scenario

REPO = Path(__file__).resolve().parents[1]
#: Each planted bug class and the fault kind whose schedules expose it (the power campaign draws
#: from that kind and from every kind).
EXPOSED_BY = {"confirm-twice": "duplicate", "forget-on-restart": "crash", "older-epoch": "pause,slow",
              "slow-as-empty": "slow", "bye-without-hello": "stale"}


def _row(name: str, report: dict, build_s: float) -> dict:
    return {"scenario": name, "missions": report["missions"], "events": report["events"],
            "seconds": report["seconds"], "build_s": round(build_s, 1), "missions_per_s": report["missions_per_s"],
            "events_per_s": report["events_per_s"], "violations": len(report["violations"]),
            "failing_seeds": sorted({v["seed"] for v in report["violations"]})}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m tools.sim_campaign", description=__doc__.split("\n\n")[0])
    p.add_argument("--six", type=int, default=9000, help="missions of six_carriers (9000)")
    p.add_argument("--r32", type=int, default=800, help="missions of a generated 32-carrier scenario (800)")
    p.add_argument("--r256", type=int, default=200, help="missions of a generated 256-carrier scenario (200)")
    p.add_argument("--power", type=int, default=200, help="seeds per planted bug class and fault mix (200)")
    p.add_argument("--jobs", type=int, default=2, help="worker processes (2)")
    p.add_argument("--onboard-iterations", type=int, default=200,
                   help="the on-board planner's budget in the generated fleets (200)")
    p.add_argument("--json", dest="json_out", type=Path, default=None)
    args = p.parse_args(argv)
    rows, power = [], []
    with tempfile.TemporaryDirectory() as tmp:
        scenarios = [("six_carriers", str(REPO / "scenarios" / "six_carriers.yaml"), args.six, None)]
        for n, family, count in ((32, "grid", args.r32), (256, "long-streets", args.r256)):
            if count > 0:
                path = Path(tmp) / f"{family}-{n}.yaml"
                write_scenario(n, path, seed=1, family=family)
                scenarios.append((f"{family}-{n}", str(path), count, args.onboard_iterations))
        for name, path, count, onboard in scenarios:
            if count <= 0:
                continue
            t0 = time.perf_counter()
            fleet = build_fleet(path, onboard_iterations=onboard)
            build_s = time.perf_counter() - t0
            report = campaign(fleet, range(count), sim.FAULT_KINDS, jobs=args.jobs)
            rows.append(_row(name, report, build_s))
            print(f"{name}: {report['missions']} missions, {report['events']:,} events in {report['seconds']:.1f} s "
                  f"(+{build_s:.0f} s to build the world and planners): {report['missions_per_s']} missions/s, "
                  f"{report['events_per_s']:,} events/s; {len(report['violations'])} violation(s)", flush=True)
            if name == "six_carriers" and args.power > 0:
                for plant, kind in EXPOSED_BY.items():
                    found = {}
                    for mix, kinds in ((kind, tuple(kind.split(","))), ("all", sim.FAULT_KINDS)):
                        rep = campaign(fleet, range(args.power), kinds, plant=plant, jobs=args.jobs)
                        found[mix] = len({v["seed"] for v in rep["violations"]})
                    power.append({"plant": plant, "kind": kind, "seeds": args.power, "found_with_kind": found[kind],
                                  "found_with_all": found["all"]})
                    print(f"  power: {plant}: found in {found[kind]}/{args.power} seeds of {kind} faults, "
                          f"{found['all']}/{args.power} of all kinds", flush=True)
    total = sum(r["missions"] for r in rows)
    seconds = sum(r["seconds"] for r in rows)
    print(f"total: {total:,} missions in {seconds:.0f} s of campaign ({total / seconds:.1f} missions/s); "
          f"{sum(r['violations'] for r in rows)} violation(s)")
    if args.json_out is not None:
        args.json_out.write_text(json.dumps({"rows": rows, "power": power}, indent=1) + "\n")
    return 1 if any(r["violations"] for r in rows) or any(not p["found_with_kind"] for p in power) else 0


if __name__ == "__main__":
    sys.exit(main())
