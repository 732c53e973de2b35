"""Free loopback ports for tests that start several listeners at once."""

from __future__ import annotations

import socket


def distinct_free_ports(n: int, host: str = "127.0.0.1") -> list[int]:
    """`n` different TCP ports free right now on `host`.

    All are bound at the same time before being released, so, unlike calling a one-port helper
    twice (the kernel may hand the just-released port out again), no two can coincide.
    """
    socks = [socket.socket() for _ in range(n)]
    try:
        for sock in socks:
            sock.bind((host, 0))
        return [sock.getsockname()[1] for sock in socks]
    finally:
        for sock in socks:
            sock.close()
