"""The deterministic simulator's campaign figures and power (docs/fleet.md, "Deterministic
simulation"): seeded missions of six_carriers and of generated 32- and 256-carrier scenarios
(tools.scale's ``grid`` and ``long-streets`` families, which the simulator was not developed on),
every fault kind, with missions and events per second and the violations found; then each known
bug class put back in turn (``--plant``) and the seeds in which the campaign finds it.

    python -m tools.sim_campaign                       # the full campaign: 10,000 missions
    python -m tools.sim_campaign --six 300 --r32 20 --r256 0 --power 20    # a short one
    python -m tools.sim_campaign --scale 0.1           # a tenth of each, the full campaign extrapolated

The campaign's mix (:data:`MIX`): 9,690 missions of six_carriers, 300 of a generated 32-carrier
``grid`` scenario and 10 of a 256-carrier ``long-streets`` one, every fault kind, the on-board
planner at 200 rollouts in all three (the invariants do not depend on how well a carrier decides
alone; its default budget costs six_carriers 1.6 times the CPU). Each row prints its wall time
and the CPU time it took (this process and its workers): on a machine others use too, the CPU
time over ``--jobs`` is what the campaign would take on idle cores (``--scale`` extrapolates from
a sample with it). A benchmark, not a test: it prints figures (and writes them as JSON with
``--json``); the power campaign (``--power``) is timed apart.
"""
from __future__ import annotations

import argparse
import json
import os
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
#: Missions of each scenario in the full campaign (10,000 in all).
MIX = {"six_carriers": 9690, "grid-32": 300, "long-streets-256": 10}
EXPOSED_BY = {"confirm-twice": "duplicate", "forget-on-restart": "crash", "older-epoch": "pause,slow",
              "slow-as-empty": "slow", "bye-without-hello": "stale"}


def _row(name: str, report: dict, build_s: float, build_cpu: float) -> dict:
    return {"scenario": name, "missions": report["missions"], "events": report["events"],
            "seconds": report["seconds"], "cpu_seconds": report["cpu_seconds"], "build_s": round(build_s, 1),
            "build_cpu_s": round(build_cpu, 1),
            "missions_per_s": report["missions_per_s"],
            "events_per_s": report["events_per_s"], "violations": len(report["violations"]),
            "failing_seeds": sorted({v["seed"] for v in report["violations"]}),
            "trace": sim.combined_hash([r["trace_hash"] for r in report["per_seed"]])}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m tools.sim_campaign", description=__doc__.split("\n\n")[0])
    p.add_argument("--six", type=int, default=None, help=f"missions of six_carriers ({MIX['six_carriers']})")
    p.add_argument("--r32", type=int, default=None, help=f"missions of a generated 32-carrier scenario ({MIX['grid-32']})")
    p.add_argument("--r256", type=int, default=None,
                   help=f"missions of a generated 256-carrier scenario ({MIX['long-streets-256']})")
    p.add_argument("--scale", type=float, default=1.0,
                   help="run this fraction of each count and extrapolate the full campaign's time from its CPU time (1)")
    p.add_argument("--power", type=int, default=200, help="seeds per planted bug class and fault mix (200)")
    p.add_argument("--jobs", type=int, default=2, help="worker processes (2)")
    p.add_argument("--onboard-iterations", type=int, default=200,
                   help="the on-board planner's rollouts, in every scenario (200)")
    p.add_argument("--json", dest="json_out", type=Path, default=None)
    args = p.parse_args(argv)
    full = {"six_carriers": MIX["six_carriers"] if args.six is None else args.six,
            "grid-32": MIX["grid-32"] if args.r32 is None else args.r32,
            "long-streets-256": MIX["long-streets-256"] if args.r256 is None else args.r256}
    counts = {name: max(1, round(n * args.scale)) if n > 0 else 0 for name, n in full.items()}
    rows, power = [], []
    with tempfile.TemporaryDirectory() as tmp:
        scenarios = [("six_carriers", str(REPO / "scenarios" / "six_carriers.yaml"), counts["six_carriers"],
                      args.onboard_iterations)]
        for n, family, count in ((32, "grid", counts["grid-32"]), (256, "long-streets", counts["long-streets-256"])):
            if count > 0:
                path = Path(tmp) / f"{family}-{n}.yaml"
                write_scenario(n, path, seed=1, family=family)
                scenarios.append((f"{family}-{n}", str(path), count, args.onboard_iterations))
        for name, path, count, onboard in scenarios:
            if count <= 0:
                continue
            t0, c0 = time.perf_counter(), time.process_time()
            fleet = build_fleet(path, onboard_iterations=onboard, workers=args.jobs)
            build_s, build_cpu = time.perf_counter() - t0, time.process_time() - c0
            report = campaign(fleet, range(count), sim.FAULT_KINDS, jobs=args.jobs)
            rows.append(_row(name, report, build_s, build_cpu))
            print(f"{name}: {report['missions']} missions, {report['events']:,} events in {report['seconds']:.1f} s "
                  f"(+{build_s:.0f} s to build the world and planners), {report['cpu_seconds']:.0f} CPU s: "
                  f"{report['missions_per_s']} missions/s, {report['events_per_s']:,} events/s; "
                  f"{len(report['violations'])} violation(s); trace {rows[-1]['trace']}", flush=True)
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
    seconds = sum(r["seconds"] + r["build_s"] for r in rows)
    cpu = sum(r["cpu_seconds"] for r in rows)
    print(f"total: {total:,} missions in {seconds:.0f} s of campaign, builds included ({total / seconds:.1f} missions/s), "
          f"{cpu:.0f} CPU s; {sum(r['violations'] for r in rows)} violation(s); "
          f"trace {sim.combined_hash([r['trace'] for r in rows])}")
    # the full campaign on idle cores: each row's CPU time per mission times its full count over
    # the workers, and the builds (in this process, one after the other)
    idle = sum(r["cpu_seconds"] / r["missions"] * full[r["scenario"]] / max(1, args.jobs) + r["build_cpu_s"]
               for r in rows if r["missions"])
    print(f"the full campaign ({sum(full.values()):,} missions) on {args.jobs} idle cores: about {idle:.0f} s "
          f"(from {cpu:.0f} CPU s of {total:,} missions; load now: {os.getloadavg()[0]:.1f})")
    if args.json_out is not None:
        args.json_out.write_text(json.dumps({"rows": rows, "power": power, "full": full,
                                             "idle_estimate_s": round(idle, 1)}, indent=1) + "\n")
    return 1 if any(r["violations"] for r in rows) or any(not p["found_with_kind"] for p in power) else 0


if __name__ == "__main__":
    sys.exit(main())
