"""The processes of a conformance flight around the kit's own zenoh router: the project's
coordinator (frozen, resumed, killed and restarted on request), the scenario's other carriers,
and the carrier under test with what it is told (:data:`PLACEHOLDERS`)."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from .flight import Target

#: What the carrier under test is told, by environment variable and by ``{placeholder}`` in its
#: ARGS: (variable, placeholder, meaning). docs/protocol.md, "Conformance kit".
PLACEHOLDERS = (
    ("MARSUPIAL_ENDPOINT", "endpoint", "the endpoint to connect to (zenoh client mode)"),
    ("MARSUPIAL_CARRIER", "carrier", "the carrier id it flies as"),
    ("MARSUPIAL_SCENARIO", "scenario", "the scenario file (absolute path)"),
    ("MARSUPIAL_MISSION", "mission", "the mission id (key prefix marsupial/<mission>/)"),
    ("MARSUPIAL_SEED", "seed", "the root seed (the fingerprint's)"),
    ("MARSUPIAL_WORKDIR", "workdir", "a directory of its own for files it writes (logs)"),
)


class Harness:
    """The kit's router (mode ``router`` on ``tcp/127.0.0.1:<free port>``, multicast scouting off)
    and every process of the flight; a context manager that stops them all and closes the router.

    Args:
        target: the carrier under test (the scenario, seed and mission every process flies).
        workdir: the coordinator's results go to ``run/``, the logs to ``coordinator.log`` and
            ``carriers.log``, the carrier under test's files to ``carrier/``.
    """

    def __init__(self, target: Target, workdir: Path):
        self.target, self.workdir = target, Path(workdir)
        self.endpoint = ""
        self.node: Any = None
        self.coordinator: subprocess.Popen | None = None
        self.frozen = False  # the coordinator is stopped (SIGSTOP)
        self.thaw_at: float | None = None  # monotonic time to resume it
        self._procs: list[subprocess.Popen] = []

    def __enter__(self) -> Harness:
        from ..transport import Node
        from ..zconfig import free_port, make_config

        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        (self.workdir / "carrier").mkdir(parents=True, exist_ok=True)
        self.node = Node(make_config("router", [self.endpoint]))
        return self

    def __exit__(self, *exc: object) -> None:
        for proc in self._procs:
            if proc.poll() is None:
                try:
                    os.kill(proc.pid, signal.SIGCONT)
                except OSError:
                    pass
                proc.terminate()
                try:
                    proc.wait(10)
                except subprocess.TimeoutExpired:
                    proc.kill()
        self.node.close(3.0)

    # ------------------------------------------------------------------ the project's processes
    def _run_fleet(self, *args: str) -> list[str]:
        """A launcher command line: the clone's run_fleet.py beside this package, else (an
        installed wheel has no script) ``python -m launcher``."""
        script = Path(__file__).resolve().parents[2] / "run_fleet.py"
        launcher = [str(script)] if script.is_file() else ["-m", "launcher"]
        t = self.target
        return [sys.executable, *launcher, t.scenario_path, "--seed", str(t.seed), "--mission", t.mission,
                "--connect", self.endpoint, *args]

    def start_coordinator(self) -> None:
        self.coordinator = self._start(self._run_fleet(
            "--role", "coordinator", "--out", str(self.workdir / "run"), "--no-map", "--no-record",
            "--join-timeout", "60", "--stage-timeout", "20", "--quiet"), "coordinator.log")

    def start_other_carriers(self) -> None:
        """The scenario's carriers but the one under test, in one process, without autonomy."""
        others = [c for c in self.target.scenario.carrier_ids if c != self.target.cid]
        if others:
            self._start(self._run_fleet("--role", "carrier", "--carrier", ",".join(others), "--no-autonomy",
                                        "--quiet", "--out", str(self.workdir / "run")), "carriers.log")

    def _start(self, argv: list[str], log: str) -> subprocess.Popen:
        proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=open(self.workdir / log, "ab"))
        self._procs.append(proc)
        return proc

    def freeze(self, seconds: float | None = None) -> None:
        """Stop the coordinator (SIGSTOP); resume it after ``seconds`` (:meth:`thaw_if_due`), or at
        :meth:`thaw` or :meth:`thaw_after`."""
        assert self.coordinator is not None
        os.kill(self.coordinator.pid, signal.SIGSTOP)
        self.frozen = True
        self.thaw_at = None if seconds is None else time.monotonic() + seconds

    def thaw_after(self, seconds: float) -> None:
        self.thaw_at = time.monotonic() + seconds

    def thaw_if_due(self, now: float) -> None:
        if self.thaw_at is not None and now >= self.thaw_at:
            self.thaw()

    def thaw(self) -> None:
        """Resume the coordinator if it is stopped."""
        if self.frozen and self.coordinator is not None:
            os.kill(self.coordinator.pid, signal.SIGCONT)
        self.frozen, self.thaw_at = False, None

    def restart_coordinator(self) -> None:
        """Kill the coordinator (SIGKILL) and start it again on its mission.db (the next epoch)."""
        assert self.coordinator is not None
        self.coordinator.kill()
        self.coordinator.wait(10)
        self.start_coordinator()

    # ------------------------------------------------------------------ the carrier under test
    def values(self) -> dict[str, str]:
        """placeholder -> value, for this flight."""
        t = self.target
        return {"endpoint": self.endpoint, "carrier": t.cid, "scenario": t.scenario_path, "mission": t.mission,
                "seed": str(t.seed), "workdir": str(self.workdir / "carrier")}

    def expand(self, command: list[str]) -> list[str]:
        """COMMAND with every ``{placeholder}`` replaced by its value."""
        values = self.values()
        out = []
        for arg in command:
            for name, value in values.items():
                arg = arg.replace("{" + name + "}", value)
            out.append(arg)
        return out

    def start_under_test(self, command: list[str]) -> subprocess.Popen:
        """Start the expanded COMMAND with the environment variables of :data:`PLACEHOLDERS`; its
        stdout and stderr are kept (:meth:`finish`)."""
        values = self.values()
        env = {variable: values[name] for variable, name, _ in PLACEHOLDERS}
        proc = subprocess.Popen(command, env={**os.environ, **env}, stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT)
        self._procs.append(proc)
        return proc

    @staticmethod
    def finish(proc: subprocess.Popen, timeout_s: float) -> tuple[int, str]:
        """Wait up to ``timeout_s`` for the carrier under test to exit (then kill it): its exit
        code and the last 4000 characters of its output."""
        try:
            out, _ = proc.communicate(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            out, _ = proc.communicate()
        return proc.returncode, (out or b"").decode(errors="replace")[-4000:]
