"""Signals and child processes: a stop request instead of an exception, children that cannot be
interrupted half-way through their start, and stopping our own children in steps."""
from __future__ import annotations

import os
import signal
import threading
import time

from launcher import CARRIER_NICE


def install_stop_handlers() -> threading.Event:
    """SIGINT (Ctrl-C) and SIGTERM only set the returned stop request; the process's loop
    honours it between steps (a store write or a message is never cut in half) and shuts down
    cleanly (End/Bye, summary.json). Later signals change nothing. Installed explicitly because
    a process started in the background inherits SIGINT ignored."""
    stop = threading.Event()

    def handler(signum, frame):
        stop.set()

    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)
    return stop


def ignore_sigint() -> None:
    """In a child before it runs Python: SIGINT ignored until the child's own
    :func:`install_stop_handlers` (Python keeps an inherited ignored SIGINT instead of raising
    KeyboardInterrupt), so a Ctrl-C during its start-up cannot interrupt it half-way; the
    launcher forwards the stop again once the children are up (:func:`stop_children`)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def carrier_child() -> None:
    """In a carrier process of a one-host fleet: :func:`ignore_sigint`, and a lower CPU priority
    (:data:`launcher.CARRIER_NICE`) than the coordinator and the routers."""
    ignore_sigint()
    os.nice(CARRIER_NICE)


def stop_children(procs, grace_s: float = 10.0) -> None:
    """Stop our own children: give them a moment (a terminal's Ctrl-C reached them already), then
    SIGINT once, then SIGKILL after ``grace_s`` seconds."""
    for sig, wait_s in ((None, 1.0), (signal.SIGINT, grace_s), (signal.SIGKILL, 2.0)):
        alive = [p for p in procs if p.poll() is None]
        if not alive:
            return
        if sig is not None:
            for p in alive:
                try:
                    p.send_signal(sig)
                except ProcessLookupError:
                    pass
        deadline = time.monotonic() + wait_s
        while time.monotonic() < deadline and any(p.poll() is None for p in alive):
            time.sleep(0.05)
