"""The live view in a real browser: `run_fleet.py --view` streams a mission to rerun's web viewer,
headless Chromium opens it, and the screenshot (taken over the DevTools protocol once the data is
drawn) shows every carrier's colour inside the map view. The screenshot is kept in
tests/artifacts/live_view.png. Also: a viewer never publishes, and --save writes an .rrd file."""
from __future__ import annotations

import shutil
import signal
import subprocess
import sys
import threading
import time

import pytest

import world
from fleet_helpers import ROOT, TINY
from wire.zconfig import free_port

sys.path.insert(0, str(ROOT / "tools"))
view_screenshot = pytest.importorskip("view_screenshot")
pytest.importorskip("rerun")
pytest.importorskip("websocket")

ARTIFACTS = ROOT / "tests" / "artifacts"
RUN_FLEET = str(ROOT / "run_fleet.py")


class Launcher:
    """run_fleet.py in the background, its output collected line by line."""

    def __init__(self, args, cwd):
        self.proc = subprocess.Popen([sys.executable, RUN_FLEET, *args], stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, text=True, cwd=cwd)
        self.lines: list[str] = []
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()

    def _read(self):
        for line in self.proc.stdout:
            self.lines.append(line)

    def wait_for(self, text: str, timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        while not any(text in line for line in self.lines):
            assert self.proc.poll() is None or any(text in line for line in self.lines), "".join(self.lines)[-3000:]
            assert time.monotonic() < deadline, f"no {text!r} in: " + "".join(self.lines)[-3000:]
            time.sleep(0.2)

    def stop(self) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
        try:
            return self.proc.wait(30)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            return self.proc.wait(10)


@pytest.mark.slow
@pytest.mark.skipif(view_screenshot.chromium_path() is None, reason="chromium is not installed")
def test_the_live_view_shows_the_mission_in_a_browser(tmp_path):
    tiny = world.load_scenario(TINY)
    from world.scene import carrier_colour, rgb

    web, grpc = free_port(), free_port()
    rrd = tmp_path / "mission.rrd"
    fleet = Launcher([str(TINY), "--out", str(tmp_path / "run"), "--view", "--web-port", str(web),
                      "--grpc-port", str(grpc), "--save", str(rrd), "--linger", "120", "--no-map"], cwd=tmp_path)
    try:
        fleet.wait_for("live view at http://127.0.0.1:", 120)
        fleet.wait_for("results:", 180)
        fleet.wait_for("the live view stays at", 30)
        url = next(line for line in fleet.lines if "live view at " in line).split("live view at ")[1].strip()
        assert url.startswith(f"http://127.0.0.1:{web}/")
        colours = [rgb(carrier_colour(r)) for r in range(tiny.n_carriers)]
        width, height = 1600, 900
        box = (0, 40, int(width * 0.74), int(height * 0.68))  # the map view (left), above the time panel

        def drawn(png):
            return min(view_screenshot.colour_pixels(png, colours, box=box)) >= 40

        png = view_screenshot.capture(url, tmp_path / "live_view.png", ready=drawn, wait_s=120, size=(width, height))
        ARTIFACTS.mkdir(exist_ok=True)
        shutil.copy(tmp_path / "live_view.png", ARTIFACTS / "live_view.png")
        counts = view_screenshot.colour_pixels(png, colours, box=box)
        assert min(counts) >= 40, f"carrier colour pixels in the map view: {counts} (see {ARTIFACTS / 'live_view.png'})"
    finally:
        code = fleet.stop()
    assert code in (0, 130), "".join(fleet.lines)[-3000:]
    assert "Traceback" not in "".join(fleet.lines)
    assert rrd.stat().st_size > 10_000  # the same stream, saved


def test_a_viewer_never_publishes():
    source = (ROOT / "viewer" / "node.py").read_text() + (ROOT / "viewer" / "rerun_view.py").read_text()
    for call in (".put(", "put_raw(", ".token(", ".serve(", ".query(", "declare_publisher", "declare_token",
                 "declare_queryable"):
        assert call not in source, call
