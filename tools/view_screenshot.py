"""Screenshot a web page (the live view) with headless Chromium over the DevTools protocol, and
drive a page as a person does (:class:`Browser`: clicks with the mouse, the page closed).

    python tools/view_screenshot.py URL OUT.png [--wait 60] [--size 1600x900]

Chromium's own ``--screenshot`` flag captures the page as soon as it loads (rerun's web viewer
is still showing its loading screen then), so this starts Chromium with a remote-debugging
port, opens the page, and takes screenshots over the DevTools protocol (``Page.captureScreenshot``)
until ``ready(png_bytes)`` says the data is drawn, or the wait is over; the last one is saved.
Software WebGL (SwiftShader) stands in for a GPU. Needs ``websocket-client`` and Pillow.
"""
from __future__ import annotations

import argparse
import base64
import io
import json
import shutil
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

CHROMIUM_FLAGS = (
    "--headless", "--no-sandbox", "--disable-gpu", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
    "--disable-background-networking", "--no-first-run", "--disable-component-update", "--disable-sync",
    "--disable-default-apps", "--mute-audio", "--hide-scrollbars",
)


def chromium_path() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable"):
        path = shutil.which(name)
        if path:
            return path
    return None


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class _Cdp:
    """A minimal DevTools protocol client over one websocket."""

    def __init__(self, ws_url: str):
        import websocket

        self.ws = websocket.create_connection(ws_url, timeout=60, suppress_origin=True)
        self.next_id = 0

    def call(self, method: str, **params):
        self.next_id += 1
        my_id = self.next_id
        self.ws.send(json.dumps({"id": my_id, "method": method, "params": params}))
        while True:
            reply = json.loads(self.ws.recv())
            if reply.get("id") == my_id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply.get("result", {})

    def close(self):
        self.ws.close()


class Browser:
    """Headless Chromium driven over the DevTools protocol, one page: open a URL, run a script
    in it, click an element with the mouse as a person does, take screenshots, close the page.

    Args:
        size: viewport (width, height) in CSS pixels.
    """

    def __init__(self, size=(1600, 900)):
        chromium = chromium_path()
        if chromium is None:
            raise FileNotFoundError("no chromium found")
        self.size = size
        self.port = _free_port()
        # ignore_cleanup_errors: a browser that is still writing its profile as it exits made the
        # removal fail ("Directory not empty"), after the screenshot was taken.
        self._profile = tempfile.TemporaryDirectory(prefix="marsupial-chromium-", ignore_cleanup_errors=True)
        self.proc = subprocess.Popen(
            [chromium, *CHROMIUM_FLAGS, f"--user-data-dir={self._profile.name}", f"--remote-debugging-port={self.port}",
             f"--window-size={size[0]},{size[1]}", "about:blank"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        self.cdp = None
        try:
            deadline = time.monotonic() + 30
            page = None
            while page is None:
                try:
                    with urllib.request.urlopen(f"http://127.0.0.1:{self.port}/json/list", timeout=2) as r:
                        page = next((t for t in json.load(r) if t.get("type") == "page"), None)
                except OSError:
                    pass
                if page is None:
                    if time.monotonic() > deadline or self.proc.poll() is not None:
                        raise RuntimeError("chromium's DevTools endpoint did not come up")
                    time.sleep(0.2)
            self.page_id = page["id"]
            self.cdp = _Cdp(page["webSocketDebuggerUrl"])
            self.cdp.call("Emulation.setDeviceMetricsOverride", width=size[0], height=size[1], deviceScaleFactor=1,
                          mobile=False)
            self.cdp.call("Page.enable")
        except BaseException:
            self.close()
            raise

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def open(self, url: str) -> None:
        self.cdp.call("Page.navigate", url=url)

    def eval(self, expression: str):
        """The value of a JavaScript expression in the page (JSON-serialisable values)."""
        result = self.cdp.call("Runtime.evaluate", expression=expression, returnByValue=True, awaitPromise=True)
        if "exceptionDetails" in result:
            raise RuntimeError(f"{expression[:60]}: {result['exceptionDetails'].get('text')}")
        return result.get("result", {}).get("value")

    def wait_for(self, expression: str, timeout_s: float = 30.0, poll_s: float = 0.2):
        """Wait until ``expression`` is truthy in the page (one that throws, e.g. while the page
        loads, counts as false); its value (TimeoutError after ``timeout_s``)."""
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                value = self.eval(expression)
            except RuntimeError:
                value = None
            if value:
                return value
            if time.monotonic() > deadline:
                raise TimeoutError(f"waited {timeout_s:g} s for {expression}")
            time.sleep(poll_s)

    def click(self, selector: str) -> None:
        """A left click with the mouse at the centre of the element ``selector`` (pressed and
        released, as a person clicks); ValueError when there is no such element."""
        box = self.eval(f"(() => {{ const e = document.querySelector({json.dumps(selector)}); if (!e) return null; "
                        "e.scrollIntoView({block: 'center'}); const r = e.getBoundingClientRect(); "
                        "return [r.left + r.width / 2, r.top + r.height / 2]; })()")
        if box is None:
            raise ValueError(f"no element {selector} on the page")
        x, y = box
        self.cdp.call("Input.dispatchMouseEvent", type="mouseMoved", x=x, y=y)
        for kind in ("mousePressed", "mouseReleased"):
            self.cdp.call("Input.dispatchMouseEvent", type=kind, x=x, y=y, button="left", clickCount=1)

    def screenshot(self, out=None) -> bytes:
        png = base64.b64decode(self.cdp.call("Page.captureScreenshot", format="png")["data"])
        if out is not None:
            Path(out).parent.mkdir(parents=True, exist_ok=True)
            Path(out).write_bytes(png)
        return png

    def close_page(self) -> None:
        """Close the page (as a person closes the tab): nothing of it runs any more."""
        if self.cdp is not None:
            try:
                self.cdp.close()
            except Exception:
                pass
            self.cdp = None
        try:
            urllib.request.urlopen(f"http://127.0.0.1:{self.port}/json/close/{self.page_id}", timeout=5).read()
        except OSError:
            pass

    def close(self) -> None:
        if self.cdp is not None:
            try:
                self.cdp.close()
            except Exception:
                pass
            self.cdp = None
        self.proc.terminate()
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
        self._profile.cleanup()


def capture(url: str, out: str | Path, ready=None, wait_s: float = 60.0, size=(1600, 900), settle_s: float = 3.0,
            log=lambda line: None) -> bytes:
    """Open ``url`` in headless Chromium and save a PNG screenshot to ``out``.

    Args:
        ready: ``ready(png_bytes) -> bool``; screenshots are taken every second until it is
            true (then once more after ``settle_s`` seconds), or ``wait_s`` seconds pass.
        size: viewport (width, height) in CSS pixels.

    Returns:
        The PNG bytes saved.
    """
    with Browser(size) as browser:
        browser.open(url)
        started = time.monotonic()
        png = b""
        while True:
            time.sleep(1.0)
            png = browser.screenshot()
            if ready is None or ready(png):
                if ready is not None and settle_s > 0:
                    time.sleep(settle_s)
                    png = browser.screenshot()
                log(f"screenshot after {time.monotonic() - started:.1f} s")
                break
            if time.monotonic() - started > wait_s:
                log(f"gave up waiting after {wait_s:.0f} s; saving the last screenshot")
                break
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        Path(out).write_bytes(png)
        return png


def colour_pixels(png: bytes, colours, tolerance: int = 24, box=None) -> list[int]:
    """Per colour (``(r, g, b)`` 0..255), how many pixels of ``png`` are within ``tolerance`` on
    every channel; ``box`` = (left, top, right, bottom) limits the count to that region."""
    import numpy as np
    from PIL import Image

    img = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=int)
    if box is not None:
        left, top, right, bottom = box
        img = img[top:bottom, left:right]
    return [int((np.abs(img - np.asarray(c)).max(axis=2) <= tolerance).sum()) for c in colours]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("url")
    p.add_argument("out")
    p.add_argument("--wait", type=float, default=30.0, help="seconds to wait before the screenshot")
    p.add_argument("--size", default="1600x900", help="viewport WIDTHxHEIGHT")
    args = p.parse_args(argv)
    w, h = (int(v) for v in args.size.split("x"))
    deadline = time.monotonic() + args.wait
    capture(args.url, args.out, ready=lambda png: time.monotonic() >= deadline, wait_s=args.wait + 5, size=(w, h),
            settle_s=0, log=print)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
