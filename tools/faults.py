"""Faults against the fleet, and the reward each one keeps: real processes, real Zenoh, hosts as
network namespaces (tools/netns.py), lossy links by iptables.

    python -m tools.faults                       # every fault, 5 seeds, scenarios/six_carriers.yaml
    python -m tools.faults --seeds 2 --fault coordinator-killed --fault decentralised
    python -m tools.faults --out runs/faults      # keep every mission's files there

Every mission runs a zenoh router (the fleet's network), the coordinator (unless decentralised)
and one process per carrier, paced at ``--realtime`` (one stage per wall second, whatever the scenario),
with a zenoh lease of 3 s so that a cut link is noticed within a stage or three. Faults:

* ``coordinator-killed``: SIGKILL the coordinator once stage 4 is decided; it is never restarted.
* ``coordinator-cut-off``: the coordinator's host loses its link when stage 3 is about to be
  decided, and gets it back once the carriers have handled stage 8.
* ``carrier-cut-off``: one carrier's host (c1) loses its link from stage 3 to stage 9 (half the
  mission); the others go on with the coordinator. Also reported: the reward of the same mission
  with c1's deployments replaced by plain SSAP's on its own observations (what a carrier alone
  with SSAP would have done).
* ``lossy-links``: every carrier on a host of its own receiving with 30 % random packet loss
  (iptables ``statistic``), the whole mission.
* ``decentralised``: ``--decentralised`` (no coordinator) against the centralised ``closed-loop``
  mission.

The reward of a mission is computed from the carriers' own logs (``<out>/carriers/<id>.db``: what
each observed and did at every stage, whoever decided it), the same for every run; it is compared
with the uninterrupted mission on the same seed (the scenario's planner; ``closed-loop`` for the
decentralised row). Prints a table (docs/fleet.md, "Faults") and writes ``<out>/faults.json`` and
``<out>/faults.png``. Needs root for the namespaces.
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import sqlite3
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from world.paths import REPO_ROOT as ROOT

RUN_FLEET = str(ROOT / "run_fleet.py")
SCENARIO = ROOT / "scenarios" / "six_carriers.yaml"
#: Simulated seconds per wall second on six_carriers: one stage (20 s) per wall second; another
#: scenario flies one of its stages per wall second too (:attr:`Mission.realtime`).
REALTIME = 20.0
#: A 3 s lease (keep-alives 4 per lease) and clients retrying their connection every second at
#: most: a cut link is noticed within 3 s and a restored one rejoined within about a second.
ZENOH_CONFIG = ("{ transport: { link: { tx: { lease: 3000, keep_alive: 4 } } },\n"
                "  connect: { retry: { period_init_ms: 250, period_max_ms: 1000, period_increase_factor: 2 } } }\n")
#: Coordinator: per stage, wait this long for observations (s); carriers: wait this long for a
#: decision (s) — longer than the coordinator's wait plus its planning, so a carrier decides alone
#: only when the coordinator is really out of reach.
STAGE_TIMEOUT = ["--stage-timeout", "1.5"]
DECISION_TIMEOUT = ["--decision-timeout", "4"]
#: Fault name -> (what it does, the target it must meet as a fraction of the uninterrupted reward).
FAULTS = {
    "coordinator-killed": ("coordinator SIGKILLed at stage 4, never restarted", 0.90),
    "coordinator-cut-off": ("coordinator cut off from every carrier, stages 3 to 8", None),
    "carrier-cut-off": ("carrier c1 cut off from everybody, stages 3 to 9", None),
    "lossy-links": ("30 % random packet loss on every carrier's link, whole mission", 0.95),
    "decentralised": ("no coordinator at all (--decentralised), against centralised closed-loop", 0.97),
}


@dataclass
class Mission:
    """One mission's processes and files."""

    scenario: Path
    seed: int
    out: Path
    carriers: tuple[str, ...]
    planner: str | None = None
    decentralised: bool = False
    carrier_flags: tuple = ()  # more flags for every carrier process (e.g. --onboard-load need)
    realtime: float = REALTIME  # simulated seconds per wall second: the scenario's stage interval
    procs: dict = field(default_factory=dict)

    def start(self, name: str, argv: list[str], host=None) -> subprocess.Popen:
        logs = self.out / "logs"
        logs.mkdir(parents=True, exist_ok=True)
        with open(logs / f"{name}.log", "a") as log:
            spawn = host.popen if host is not None else subprocess.Popen
            proc = spawn([sys.executable, RUN_FLEET, *argv], stdout=log, stderr=subprocess.STDOUT, text=True,
                         cwd=str(ROOT))
        self.procs[name] = proc
        return proc

    def common(self, zconf: Path) -> list[str]:
        return [str(self.scenario), "--seed", str(self.seed), "--realtime", str(self.realtime), "--zenoh-config",
                str(zconf), "--out", str(self.out)]

    def launch(self, hosts: dict | None = None) -> None:
        """Router, coordinator and carriers; ``hosts``: role or carrier id -> netns Host (the
        router's host is ``hosts['router']``); None: all on this host's loopback."""
        from wire.zconfig import free_port

        hosts = hosts or {}
        self.out.mkdir(parents=True, exist_ok=True)
        zconf = self.out / "zenoh.json5"
        zconf.write_text(ZENOH_CONFIG)
        router = hosts.get("router")
        endpoint = f"tcp/{router.ip}:7447" if router is not None else f"tcp/127.0.0.1:{free_port()}"
        listen = "tcp/0.0.0.0:7447" if router is not None else endpoint
        self.start("router", ["--role", "router", "--listen", listen, "--zenoh-config", str(zconf)], router)
        time.sleep(0.5)
        if not self.decentralised:
            self.start("coordinator", self.common(zconf) + ["--role", "coordinator", "--connect", endpoint, "--no-map",
                                                            "--no-record", *STAGE_TIMEOUT]
                       + (["--planner", self.planner] if self.planner else []), hosts.get("coordinator"))
        for cid in self.carriers:
            self.start(cid, self.common(zconf) + ["--role", "carrier", "--carrier", cid, "--connect", endpoint,
                                                  "--quiet", *DECISION_TIMEOUT, *self.carrier_flags]
                       + (["--decentralised"] if self.decentralised else []),
                       hosts.get(cid, hosts.get("carriers")))

    # ------------------------------------------------------------------ progress
    def decided(self) -> int:
        """Highest stage the coordinator decided (-1: none)."""
        return _max(self.out / "mission.db", "SELECT MAX(stage) FROM decisions")

    def handled(self, carriers=None) -> int:
        """Lowest, over ``carriers`` (all by default), of the highest stage each has resolved."""
        return min(_max(self.out / "carriers" / f"{cid}.db", "SELECT MAX(stage) FROM stages WHERE status IS NOT NULL")
                   for cid in (carriers or self.carriers))

    def wait_until(self, what: str, condition, timeout_s: float = 120.0) -> None:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if condition():
                return
            time.sleep(0.02)
        raise RuntimeError(f"timed out waiting for {what}\n{self.output()}")

    def finish(self, timeout_s: float = 120.0) -> dict:
        """Wait for the carriers and the coordinator to exit, then stop the router; exit codes."""
        deadline = time.monotonic() + timeout_s
        codes = {}
        for name, proc in self.procs.items():
            if name == "router":
                continue
            try:
                codes[name] = proc.wait(max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                codes[name] = None
        self.stop()
        return codes

    def stop(self) -> None:
        for proc in self.procs.values():
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        for proc in self.procs.values():
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(5)

    def output(self) -> str:
        return "\n".join(f"--- {p.name}\n{p.read_text()[-2000:]}" for p in sorted((self.out / "logs").glob("*.log")))


def _max(db: Path, sql: str) -> int:
    if not db.exists():
        return -1
    try:
        with sqlite3.connect(f"file:{db}?mode=ro", uri=True) as conn:
            value = conn.execute(sql).fetchone()[0]
    except sqlite3.Error:
        return -1
    return -1 if value is None else int(value)


# ----------------------------------------------------------------------------- what a mission earned

@dataclass(frozen=True)
class Outcome:
    """What the carriers' logs say a mission did: x and deployments per carrier and stage."""

    x: np.ndarray
    deployed: np.ndarray
    reward: float
    own: int  # stages the carriers decided themselves
    unresolved: int  # scheduled (carrier, stage) pairs with no outcome in the carrier's log (passed: ∅)


def outcome(scenario, out: Path) -> Outcome:
    """The mission's reward from the carriers' logs (the planner core's evaluation)."""
    import world
    from storage.carrierlog import log_path, read_log
    from planner.problem import evaluate

    problem = world.build_problem(scenario)
    R, N = problem.valid.shape
    x = np.full((R, N), np.nan)
    deployed = np.zeros((R, N), dtype=bool)
    own, unresolved = 0, 0
    for r, cid in enumerate(scenario.carrier_ids):
        path = log_path(out, cid)
        entries = read_log(path)[1] if path.exists() else []
        resolved = {e.stage for e in entries if e.status is not None}
        unresolved += int(sum(1 for j in np.flatnonzero(problem.valid[r]) if j not in resolved))
        for e in entries:
            if e.x is not None:
                x[r, e.stage] = e.x
            deployed[r, e.stage] = e.deployed
            own += e.own
        if deployed[r].sum() > scenario.carriers[r].passengers:
            raise AssertionError(f"{cid} released {deployed[r].sum()} passengers of {scenario.carriers[r].passengers}")
    reward, _ = evaluate(problem, deployed, np.where(problem.valid, x, np.nan))
    return Outcome(x, deployed, float(reward), own, unresolved)


def ssap_substitute(scenario, result: Outcome, cid: str, out: Path) -> float:
    """The mission's reward had carrier ``cid`` run plain SSAP on its own observations from the
    first stage it decided alone to the end (its earlier deployments and the others' unchanged):
    what a carrier cut off with SSAP would have earned."""
    import world
    from storage.carrierlog import log_path, read_log
    from planner import ssap
    from planner.problem import evaluate

    problem = world.build_problem(scenario)
    r = scenario.carrier_index(cid)
    first = min((e.stage for e in read_log(log_path(out, cid))[1] if e.own), default=problem.n_stages)
    deployed = ssap.alone(problem, result.x, result.deployed, r, first)
    return float(evaluate(problem, deployed, np.where(problem.valid, result.x, np.nan))[0])


# ----------------------------------------------------------------------------- the faults

def _run(scenario_path: Path, scenario, seed: int, out: Path, *, planner=None, decentralised=False, hosts=None,
         during=None, killed=(), carrier_flags=()) -> tuple[Outcome, dict]:
    m = Mission(scenario_path, seed, out, tuple(scenario.carrier_ids), planner, decentralised, tuple(carrier_flags),
                realtime=float(scenario.stage_interval))
    try:
        m.launch(hosts)
        if during is not None:
            during(m)
        codes = m.finish()
    finally:
        m.stop()
    failed = {name: code for name, code in codes.items() if code != 0 and name not in killed}
    if failed:
        raise RuntimeError(f"{out}: exit codes {failed}\n{m.output()}")
    return outcome(scenario.with_seed(seed), out), codes


def baseline(scenario_path, scenario, seed, out, planner=None) -> Outcome:
    """The uninterrupted mission on this host."""
    return _run(scenario_path, scenario, seed, out, planner=planner)[0]


def offline_baseline(scenario, seed: int, planner=None) -> Outcome:
    """The uninterrupted mission on seed ``seed`` as the planner core decides it offline
    (:func:`world.offline_mission`): what :func:`baseline`'s fleet reproduces exactly, without
    flying it (tests/test_no_spof.py holds the two equal)."""
    import world

    result, x = world.offline_mission(scenario.with_seed(seed), planner)
    return Outcome(x, np.asarray(result.deployed, dtype=bool), float(result.reward), 0, 0)


def fault_run(name: str, scenario_path: Path, scenario, seed: int, out: Path,
              carrier_flags=()) -> tuple[Outcome, dict]:
    """Run the mission under fault ``name``; (outcome, details). ``carrier_flags``: more flags for
    every carrier (coordinator-killed only)."""
    from tools import netns

    details: dict = {}
    if name == "coordinator-killed":
        def kill(m):
            m.wait_until("stage 4 decided", lambda: m.decided() >= 3)
            m.procs["coordinator"].send_signal(signal.SIGKILL)
            details["killed_after_stage"] = m.decided()
        return _run(scenario_path, scenario, seed, out, during=kill, killed=("coordinator",),
                    carrier_flags=carrier_flags)[0], details
    if name == "decentralised":
        return _run(scenario_path, scenario, seed, out, decentralised=True)[0], details
    if name == "coordinator-cut-off":
        with netns.hosts(3) as (net, coord, fleet):
            def cut(m):
                m.wait_until("stage 3 about to be decided", lambda: m.decided() >= 1)
                coord.link(False)
                details["cut_after_stage"] = m.decided()
                m.wait_until("carriers past stage 8", lambda: m.handled() >= 7)
                coord.link(True)
            result, _ = _run(scenario_path, scenario, seed, out, hosts={"router": net, "coordinator": coord,
                                                                          "carriers": fleet}, during=cut)
        details["own_stages"] = result.own
        details["decided_after_cut"] = _decided_after(out, details["cut_after_stage"])
        return result, details
    if name == "carrier-cut-off":
        cid = scenario.carrier_ids[0]
        others = [c for c in scenario.carrier_ids if c != cid]
        with netns.hosts(3) as (net, alone, fleet):
            def cut(m):
                m.wait_until("stage 3 about to be decided", lambda: m.decided() >= 1)
                alone.link(False)
                m.wait_until("the others past stage 9", lambda: m.handled(others) >= 8)
                alone.link(True)
            result, _ = _run(scenario_path, scenario, seed, out, hosts={"router": net, "coordinator": net,
                                                                          "carriers": fleet, cid: alone}, during=cut)
        details["carrier"] = cid
        details["ssap_substitute"] = ssap_substitute(scenario.with_seed(seed), result, cid, out)
        return result, details
    if name == "lossy-links":
        with netns.hosts(2 + len(scenario.carrier_ids)) as hs:
            net, carrier_hosts = hs[0], hs[2:]
            for h in carrier_hosts:
                h.drop(0.3)
            result, _ = _run(scenario_path, scenario, seed, out, hosts={
                "router": net, "coordinator": hs[1], **dict(zip(scenario.carrier_ids, carrier_hosts))})
        details["own_stages"] = result.own
        return result, details
    raise ValueError(f"unknown fault {name!r}; expected one of {', '.join(FAULTS)}")


def _decided_after(out: Path, stage: int) -> list[int]:
    db = out / "mission.db"
    with sqlite3.connect(f"file:{db}?mode=ro", uri=True) as conn:
        return [s for (s,) in conn.execute("SELECT stage FROM decisions WHERE stage > ? ORDER BY stage", (stage,))]


# ----------------------------------------------------------------------------- the table

def measure(faults, seeds, scenario_path: Path = SCENARIO, out_root: Path | None = None, log=print) -> dict:
    """Run ``faults`` on ``seeds``; per fault the per-seed rewards, baselines and the fraction kept."""
    import world

    scenario = world.load_scenario(scenario_path)
    out_root = Path(out_root or tempfile.mkdtemp(prefix="faults-"))
    results = {name: [] for name in faults}
    for seed in seeds:
        base, base_cl = None, None
        for name in faults:
            planner = "closed-loop" if name == "decentralised" else None
            if planner is None and base is None:
                base = baseline(scenario_path, scenario, seed, out_root / f"seed{seed}" / "uninterrupted")
            if planner is not None and base_cl is None:
                base_cl = baseline(scenario_path, scenario, seed, out_root / f"seed{seed}" / "uninterrupted-closed-loop",
                                   planner)
            ref = base_cl if planner else base
            t0 = time.monotonic()
            result, details = fault_run(name, scenario_path, scenario, seed, out_root / f"seed{seed}" / name)
            kept = result.reward / ref.reward if ref.reward > 0 else float("nan")
            results[name].append({"seed": seed, "reward": result.reward, "baseline": ref.reward, "kept": kept,
                                  "own_stages": result.own, "unresolved": result.unresolved, **details})
            log(f"seed {seed} {name:<20} reward {result.reward:6.3f} of {ref.reward:6.3f} ({kept * 100:5.1f} %), "
                f"{result.own} stage(s) decided on board, {time.monotonic() - t0:4.0f} s"
                + (f"; c1 by SSAP alone {details['ssap_substitute']:.3f}" if "ssap_substitute" in details else ""))
    return {"scenario": str(scenario_path), "seeds": list(seeds), "out": str(out_root), "faults": results}


def table(report: dict) -> str:
    lines = ["| fault | reward kept (mean, min–max over seeds) | target | command |", "| --- | --- | --- | --- |"]
    for name, rows in report["faults"].items():
        kept = np.array([r["kept"] for r in rows])
        what, target = FAULTS[name]
        extra = ""
        if name == "carrier-cut-off":
            ssap = np.mean([r["ssap_substitute"] / r["baseline"] for r in rows])
            extra = f"; c1 by SSAP alone: {ssap * 100:.1f} %"
        lines.append(f"| {what} | {kept.mean() * 100:.1f} % ({kept.min() * 100:.1f}–{kept.max() * 100:.1f}){extra} | "
                     f"{'—' if target is None else f'≥ {target * 100:.0f} %'} | "
                     f"`python -m tools.faults --fault {name} --seeds {len(rows)}` |")
    return "\n".join(lines)


def plot(report: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(report["faults"])
    fig, ax = plt.subplots(figsize=(8, 3.6))
    for k, name in enumerate(names):
        kept = [r["kept"] * 100 for r in report["faults"][name]]
        ax.bar(k, np.mean(kept), color="tab:blue", alpha=0.6)
        ax.plot([k] * len(kept), kept, "o", color="black", ms=4)
        target = FAULTS[name][1]
        if target is not None:
            ax.hlines(target * 100, k - 0.4, k + 0.4, colors="tab:red", linestyles="dashed")
    ax.set_xticks(range(len(names)), [n.replace("-", "\n") for n in names])
    ax.set_ylabel("reward kept, % of uninterrupted")
    ax.set_ylim(0, 115)
    ax.set_title(f"six_carriers, {len(report['seeds'])} seeds (dots); dashed: target")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m tools.faults", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--fault", action="append", choices=tuple(FAULTS), help="a fault to run (default: all)")
    p.add_argument("--seeds", type=int, default=5, help="seeds 1..N (default %(default)s)")
    p.add_argument("--scenario", type=Path, default=SCENARIO)
    p.add_argument("--out", type=Path, help="keep the missions' files here (default: a temporary directory)")
    args = p.parse_args(argv)
    if os.geteuid() != 0 and set(args.fault or FAULTS) - {"coordinator-killed", "decentralised"}:
        print("python -m tools.faults: the network faults need root (network namespaces)", file=sys.stderr)
        return 2
    report = measure(args.fault or list(FAULTS), range(1, args.seeds + 1), args.scenario, args.out)
    out = Path(report["out"])
    (out / "faults.json").write_text(json.dumps(report, indent=2))
    plot(report, out / "faults.png")
    print(table(report))
    print(f"figures: {out}/faults.json, {out}/faults.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
