"""The viewer process: a passive Zenoh subscriber that streams a mission to rerun.

It subscribes to ``marsupial/<m>/**`` and nothing else: it never publishes, declares no
liveliness token and no queryable, so it cannot change a mission and no participant waits for
it. It can watch from any host that reaches the coordinator's endpoint, and sees the mission
from the moment it connects (the rerun server keeps what it received for browsers that open
the page later).

Where the data goes (rerun sinks of one ``RecordingStream``):

* **web** (default): a rerun server child process (``python -m rerun --serve-web``, the
  rerun-sdk's own binary) bound to 127.0.0.1 — a gRPC port the stream is sent to and an HTTP port
  serving the web viewer; open :attr:`Viewer.url` in a browser on this host (ssh -L for another);
  rerun's usage analytics are off (a private ``XDG_CONFIG_HOME`` holding
  ``rerun/analytics.json`` with ``analytics_enabled: false``);
* **file**: ``save=FILE.rrd`` writes the same stream to an .rrd file (``rerun FILE.rrd`` opens it).

Messages are decoded with wire.messages; anything undecodable is skipped silently (a viewer
counts nothing and answers nothing).
"""
from __future__ import annotations

import json
import os
import subprocess
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from mission.exits import STOPPED
from viewer import DEFAULT_GRPC_PORT, DEFAULT_WEB_PORT
from recording.stream import Clock, feed_message
from wire import keys
from wire.messages import ProtocolError, decode

#: Web viewer and gRPC ports when none are given.


@dataclass(frozen=True)
class ViewerConfig:
    """Settings of one viewer process.

    Attributes:
        mission: mission id; the scenario name by default.
        seed: the run's root seed (features are drawn with it), the scenario's by default.
        web: serve the web viewer (False: only ``save``).
        web_port, grpc_port: loopback ports of the web viewer (HTTP) and of the rerun gRPC server.
        save: write the stream to this .rrd file too (None: no file).
        linger_s: after End, keep serving this long (s); negative = until stopped (Ctrl-C).
        open_timeout_s: how long to keep trying to reach the Zenoh network.
        log: callable taking one line.
        ready_file: created once the subscription is declared (the launcher waits for it
            before starting the carriers, so the view misses nothing).
    """

    mission: str | None = None
    seed: int | None = None
    web: bool = True
    web_port: int = DEFAULT_WEB_PORT
    grpc_port: int = DEFAULT_GRPC_PORT
    save: str | None = None
    linger_s: float = -1.0
    open_timeout_s: float = 60.0
    log: object = None
    ready_file: str | None = None


def viewer_url(web_port: int, grpc_port: int) -> str:
    """The address to open in a browser: the web viewer, told where the stream is."""
    return f"http://127.0.0.1:{web_port}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{grpc_port}%2Fproxy"


def _analytics_off_env(tmp: Path) -> dict:
    """The environment of the rerun server child with rerun's analytics switched off."""
    config = tmp / "config" / "rerun"
    config.mkdir(parents=True, exist_ok=True)
    (config / "analytics.json").write_text(json.dumps(
        {"analytics_enabled": False, "analytics_id": "0" * 32, "metadata": {}}))
    env = dict(os.environ, XDG_CONFIG_HOME=str(tmp / "config"), XDG_DATA_HOME=str(tmp / "data"),
               RERUN_TELEMETRY_ENABLED="false", TELEMETRY_ENABLED="false")
    return env


def _rerun_binary() -> str:
    """The rerun executable shipped in rerun-sdk's ``rerun_cli`` package (run directly, so that
    stopping it stops the server: ``python -m rerun`` is a wrapper around a child process)."""
    try:
        import rerun_cli

        exe = Path(rerun_cli.__file__).parent / ("rerun.exe" if os.name == "nt" else "rerun")
        if exe.is_file():
            return str(exe)
    except ImportError:
        pass
    import shutil

    found = shutil.which("rerun")
    if found is None:
        raise RuntimeError("no rerun executable: pip install -e '.[view]'")
    return found


def _die_with_parent() -> None:
    """In the rerun server child (Linux): SIGTERM when the viewer process dies, however it dies."""
    try:
        import ctypes
        import signal

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except Exception:
        pass


def _stop_group(proc: subprocess.Popen) -> None:
    """Stop a child started in its own session, and anything it started."""
    import signal

    for sig, wait_s in ((signal.SIGTERM, 5.0), (signal.SIGKILL, 2.0)):
        try:
            os.killpg(proc.pid, sig)
        except (ProcessLookupError, PermissionError):
            return
        try:
            proc.wait(wait_s)
            return
        except subprocess.TimeoutExpired:
            continue


class Viewer:
    """One viewer. ``run()`` returns when the mission ended (plus ``linger_s``) or on stop."""

    def __init__(self, scenario, config: ViewerConfig, zconf, stop: threading.Event | None = None):
        if config.seed is not None:
            scenario = scenario.with_seed(int(config.seed))
        self.scenario = scenario
        self.config = config
        self.zconf = zconf
        self.mission = keys.check_id(config.mission or keys.mission_id_from_name(scenario.name), "mission")
        self._stop = stop if stop is not None else threading.Event()
        self._log = config.log or (lambda line: print(line, flush=True))
        self.url = viewer_url(config.web_port, config.grpc_port) if config.web else None
        self.server: subprocess.Popen | None = None
        self.ended = False
        self.received = 0

    def log(self, line: str) -> None:
        self._log(f"viewer: {line}")

    def stop(self) -> None:
        self._stop.set()

    def _start_server(self, tmp: Path) -> None:
        """The rerun server child: gRPC on 127.0.0.1:grpc_port, the web viewer on 127.0.0.1:web_port."""
        import socket

        for flag, port in (("--grpc-port", self.config.grpc_port), ("--web-port", self.config.web_port)):
            with socket.socket() as probe:
                probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as a server binds
                try:
                    probe.bind(("127.0.0.1", port))
                except OSError:
                    raise RuntimeError(f"port {port} on 127.0.0.1 is in use: choose another with {flag}") from None
        cmd = [_rerun_binary(), "--serve-web", "--bind", "127.0.0.1",
               "--port", str(self.config.grpc_port), "--web-viewer-port", str(self.config.web_port)]
        self.server = subprocess.Popen(cmd, env=_analytics_off_env(tmp), stdout=subprocess.DEVNULL,
                                       stderr=subprocess.DEVNULL, start_new_session=True, preexec_fn=_die_with_parent)

        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            if self.server.poll() is not None:
                raise RuntimeError(f"the rerun server exited with code {self.server.returncode} "
                                   f"(ports {self.config.grpc_port}/{self.config.web_port} in use?)")
            try:
                with socket.create_connection(("127.0.0.1", self.config.grpc_port), timeout=0.5):
                    return
            except OSError:
                time.sleep(0.1)
        raise RuntimeError("the rerun server did not start within 30 s")

    def run(self) -> int:
        import rerun as rr

        from world import build_problem
        from viewer.rerun_view import RerunView, blueprint
        from wire.transport import Node
        from wire.zconfig import OpenStopped
        from world.scene import build_scene

        scene = build_scene(self.scenario)
        with tempfile.TemporaryDirectory(prefix="marsupial-viewer-") as tmp:
            rec = rr.RecordingStream("marsupial-fleet", recording_id=f"{self.mission}-{int(time.time())}",
                                     send_properties=False)
            sinks = []
            if self.config.web:
                self._start_server(Path(tmp))
                sinks.append(rr.GrpcSink(f"rerun+http://127.0.0.1:{self.config.grpc_port}/proxy"))
            if self.config.save:
                Path(self.config.save).parent.mkdir(parents=True, exist_ok=True)
                sinks.append(rr.FileSink(str(self.config.save)))
            rec.set_sinks(*sinks, default_blueprint=blueprint(voxels=len(scene.voxels) > 0))
            view = RerunView(rec, scene, build_problem(self.scenario))
            clock = Clock(scene.stage_times)
            if self.url:
                self.log(f"live view of mission {self.mission} at {self.url}")
            node = None
            try:
                try:
                    node = Node(self.zconf, open_timeout_s=self.config.open_timeout_s, stop=self._stop)
                except OpenStopped:
                    return STOPPED
                node.subscribe(f"{keys.prefix(self.mission)}/**")
                if self.config.ready_file:
                    time.sleep(0.3)  # let the declaration reach the coordinator before anyone speaks
                    Path(self.config.ready_file).write_text(str(os.getpid()))
                ended_at = None
                while not self._stop.is_set():
                    item = node.next(0.1)
                    while item is not None:
                        self._handle(item, view, clock)
                        item = node.next(0.0)
                    if self.ended and ended_at is None:
                        ended_at = time.monotonic()
                        rec.flush()
                        if self.config.save:
                            self.log(f"saved {self.config.save}")
                    if ended_at is not None and 0 <= self.config.linger_s <= time.monotonic() - ended_at:
                        break
            finally:
                rec.flush()
                if node is not None:
                    node.close(2.0)
                try:
                    rec.disconnect()
                except Exception:
                    pass
                if self.server is not None:
                    _stop_group(self.server)
        return 0 if self.ended else STOPPED

    def _handle(self, item, view, clock) -> None:
        if item.kind != "sample":
            return
        head = keys.prefix(self.mission) + "/"
        rest = item.key[len(head):].split("/") if item.key.startswith(head) else []
        wanted = (len(rest) == 3 and rest[0] == "carrier" and rest[2] in ("hello", "obs", "confirm", "bye", "pose")) or \
                 (len(rest) == 2 and rest[0] == "coordinator" and rest[1] in ("decision", "end"))
        if not wanted:
            return
        try:
            msg = decode(item.payload)
        except ProtocolError:
            return
        if getattr(msg, "mission", None) != self.mission:
            return
        if rest[0] == "carrier" and getattr(msg, "carrier", None) != rest[1]:
            return
        if rest[0] == "carrier" and msg.carrier not in self.scenario.carrier_ids:
            return
        self.received += 1
        if type(msg).TYPE == "end":
            if self.ended:
                return  # End is repeated for carriers that missed it
            self.ended = True
        feed_message(view, msg, clock)
