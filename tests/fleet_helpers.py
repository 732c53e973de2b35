"""Shared helpers for the fleet tests: in-process nodes on loopback and the offline reference."""
from __future__ import annotations

import os
import sqlite3
import threading
from pathlib import Path

import numpy as np

import world
from carriers.node import Carrier, CarrierConfig
from coordinator.node import Coordinator, CoordinatorConfig
from wire.zconfig import free_port, make_config

ROOT = Path(__file__).resolve().parents[1]
TINY = ROOT / "scenarios" / "tiny.yaml"


class Quiet:
    """A log sink that keeps lines for assertions."""

    def __init__(self):
        self.lines: list[str] = []
        self._lock = threading.Lock()

    def __call__(self, line: str) -> None:
        with self._lock:
            self.lines.append(line)


def offline(scenario, planner=None, iterations=None, seed=None):
    """The planner core run over world.observe_all: what the fleet must reproduce."""
    return world.offline_mission(scenario if seed is None else scenario.with_seed(seed), planner, iterations)


class InProcessFleet:
    """A coordinator and carriers as threads of this process, each with its own Zenoh session
    on tcp/127.0.0.1:<free port> (multicast scouting off)."""

    def __init__(self, scenario, out_dir, **coordinator_options):
        self.scenario = scenario
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.log = Quiet()
        options = dict(render=False, join_timeout_s=30.0, stage_timeout_s=5.0)
        options.update(coordinator_options)
        self.coordinator = Coordinator(scenario, CoordinatorConfig(out_dir=str(out_dir), log=self.log, **options),
                                       make_config("peer", [self.endpoint]))
        self.carriers: dict[str, Carrier] = {}
        self.results: dict[str, object] = {}
        self.threads: list[threading.Thread] = []

    def _spawn(self, name, target):
        def body():
            self.results[name] = target()

        thread = threading.Thread(target=body, daemon=True, name=name)
        thread.start()
        self.threads.append(thread)

    def start_coordinator(self):
        self._spawn("coordinator", self.coordinator.run)

    def start_carrier(self, cid, **options):
        carrier = Carrier(self.scenario, CarrierConfig(cid, log=self.log, **options),
                          make_config("client", [], [self.endpoint]))
        self.carriers[cid] = carrier
        self._spawn(cid, carrier.run)
        return carrier

    def join(self, timeout_s=60.0):
        for thread in self.threads:
            thread.join(timeout_s)
            assert not thread.is_alive(), f"{thread.name} did not finish within {timeout_s} s"
        return self.results["coordinator"]


def sensed_world_file(scenario, trace, r: int, path: Path) -> Path:
    """What carrier r senses and where it is at each stage (tools.sensed: what a robot's own
    sensors would give), as the JSON file tests/revision1_carrier.py reads; ``trace`` is
    ``world.simulate_mission``'s."""
    import json

    from tools.sensed import sensed

    path.write_text(json.dumps(sensed(scenario, scenario.carrier_ids[r], trace)))
    return path


def db_rows(path, sql):
    with sqlite3.connect(str(path)) as db:
        return db.execute(sql).fetchall()


def deployed_matrix(summary, scenario) -> np.ndarray:
    out = np.zeros((scenario.n_carriers, scenario.stages), dtype=bool)
    for r, carrier in enumerate(summary["carriers"]):
        for dep in carrier["deployments"]:
            out[r, dep["stage"]] = True
    return out


def alive(pid: int) -> bool:
    """Whether process ``pid`` still exists."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True
