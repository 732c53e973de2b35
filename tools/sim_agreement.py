"""Simulation against the real fleet (issue 33, item 6): for each fault kind of the real-process
table (docs/fleet.md, "Faults"; its data docs/results/faults/faults.json, written by
``python -m tools.faults``), the reward the simulator keeps over the same world seeds, with the
same fault placed at the same stage, against the real table's spread.

    python -m tools.sim_agreement                   # world seeds 1..5, 3 simulated missions each
    python -m tools.sim_agreement --missions 1 --json /tmp/agreement.json

Each real fault is placed by the stage it happens at, read off a fault-free simulated mission of
the same seed (when its Decisions were published): ``coordinator-killed`` kills the coordinator
once the stage in ``killed_after_stage`` is decided (restarted only after the mission:
never, for the reward); ``coordinator-cut-off`` cuts the coordinator's host off after the stage
in ``cut_after_stage`` until the carriers have handled stage 8 (a lease plus the fault-free
time of those stages); ``carrier-cut-off`` cuts c1 off from stage 3 to stage 9;
``lossy-links`` loses 30 % of the messages on every link the whole mission. The real table's
``decentralised`` row has no counterpart (the simulator runs hybrid and coordinated carriers).

The simulator's loss drops messages; the real fleet's iptables loss drops packets that TCP
sends again: the simulated loss is the harsher of the two. A benchmark that prints figures; the
slow test tests/test_simulate_agreement.py holds its means to the real spread.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from launcher.simulate import build_fleet
from mission import simulate as sim

REPO = Path(__file__).resolve().parents[1]
REAL = REPO / "docs" / "results" / "faults" / "faults.json"
SCENARIO = REPO / "scenarios" / "six_carriers.yaml"
#: The real table's rows the simulator reproduces.
KINDS = ("coordinator-killed", "coordinator-cut-off", "carrier-cut-off", "lossy-links")
#: Simulated seconds to stand for "never" (a coordinator killed and not restarted; a whole mission).
NEVER_S = 1e6


def schedule(kind: str, decided_at: dict, real_row: dict) -> tuple[sim.Fault, ...]:
    """The simulated fault of real fault ``kind`` (a row of faults.json), placed by the stages
    of a fault-free mission whose Decisions were published at ``decided_at`` (stage -> s)."""
    eps, lease = 1e-3, sim.LEASE_S
    if kind == "coordinator-killed":
        return (sim.Fault("coordinator-crash", decided_at[real_row["killed_after_stage"]] + eps, NEVER_S, "coordinator"),)
    if kind == "coordinator-cut-off":
        at = decided_at[real_row["cut_after_stage"]] + eps
        return (sim.Fault("partition", at, at + lease + decided_at[8] - decided_at[real_row["cut_after_stage"]],
                          "coordinator"),)
    if kind == "carrier-cut-off":
        at = decided_at[2] + eps
        return (sim.Fault("partition", at, at + lease + decided_at[9] - decided_at[3], real_row["carrier"]),)
    if kind == "lossy-links":
        return (sim.Fault("loss", 0.0, NEVER_S, "", 0.3),)
    raise ValueError(f"no simulated counterpart of real fault {kind!r}")


def agreement(missions: int = 3, real_path: Path = REAL) -> list[dict]:
    """Per fault kind: the real table's kept rewards and the simulated ones (``missions`` seeds
    of each world seed of the table)."""
    real = json.loads(Path(real_path).read_text())["faults"]
    kept: dict = {kind: [] for kind in KINDS}
    for world_seed in sorted({row["seed"] for kind in KINDS for row in real[kind]}):
        fleet = build_fleet(str(SCENARIO), seed=world_seed)
        for seed in range(missions):
            base = sim.Simulation(fleet, seed, kinds=())
            reward = base.run().reward
            for kind in KINDS:
                row = next(r for r in real[kind] if r["seed"] == world_seed)
                out = sim.simulate(fleet, seed, faults=schedule(kind, base.decided_at, row))
                kept[kind].append(out.reward / reward)
    rows = []
    for kind in KINDS:
        r, s = [row["kept"] for row in real[kind]], kept[kind]
        rows.append({"fault": kind, "real": r, "sim": s, "real_mean": sum(r) / len(r), "sim_mean": sum(s) / len(s),
                     "sim_mean_in_real_spread": min(r) <= sum(s) / len(s) <= max(r)})
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m tools.sim_agreement", description=__doc__.split("\n\n")[0])
    p.add_argument("--missions", type=int, default=3, help="simulated missions per world seed (3)")
    p.add_argument("--json", dest="json_out", type=Path, default=None)
    args = p.parse_args(argv)
    rows = agreement(args.missions)
    print("| fault | real: kept (mean, min–max) | simulated: kept (mean, min–max) | simulated mean in the real spread |")
    print("| --- | --- | --- | --- |")
    for row in rows:
        r, s = row["real"], row["sim"]
        print(f"| {row['fault']} | {100 * row['real_mean']:.1f} % ({100 * min(r):.1f}–{100 * max(r):.1f}) | "
              f"{100 * row['sim_mean']:.1f} % ({100 * min(s):.1f}–{100 * max(s):.1f}) | "
              f"{'yes' if row['sim_mean_in_real_spread'] else 'no'} |")
    if args.json_out is not None:
        args.json_out.write_text(json.dumps(rows, indent=1) + "\n")
    return 0 if all(row["sim_mean_in_real_spread"] for row in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
