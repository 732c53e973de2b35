"""Separate hosts on one machine: Linux network namespaces joined by a bridge (needs root;
lossy links need iptables).

    with netns.hosts(2) as (coord_host, carrier_host):
        proc = coord_host.popen([sys.executable, "run_fleet.py", ...])
        carrier_host.link(False)   # cut this host off (a partition) ...
        carrier_host.link(True)    # ... and bring it back

Every namespace, bridge and veth gets a name unique to this process and call; everything is
removed in a ``finally``, also when the body raises. :func:`unavailable` says why namespaces
cannot be used here (tests skip with that reason), or None.
"""
from __future__ import annotations

import itertools
import os
import subprocess
from contextlib import contextmanager
from dataclasses import dataclass

_COUNTER = itertools.count()


def _ip(*args: str, check: bool = True) -> subprocess.CompletedProcess:
    return subprocess.run(["ip", *args], capture_output=True, text=True, timeout=10, check=check)


@dataclass(frozen=True)
class Host:
    """One simulated host: a network namespace with one interface on the shared bridge.

    Attributes:
        ns: namespace name.
        ip: its IPv4 address on the bridge's /24.
        iface: its interface name inside the namespace.
        peer: the bridge-side end of its veth pair (in the switch namespace).
        switch: the switch namespace holding the bridge.
    """

    ns: str
    ip: str
    iface: str
    peer: str
    switch: str

    def popen(self, argv, **kwargs) -> subprocess.Popen:
        """Start ``argv`` inside this host's namespace."""
        return subprocess.Popen(["ip", "netns", "exec", self.ns, *argv], **kwargs)

    def run(self, argv, **kwargs) -> subprocess.CompletedProcess:
        return subprocess.run(["ip", "netns", "exec", self.ns, *argv], **kwargs)

    def link(self, up: bool) -> None:
        """Bring this host's link up or down (down = the host is cut off from the others)."""
        _ip("-n", self.switch, "link", "set", self.peer, "up" if up else "down")

    def drop(self, probability: float) -> None:
        """Drop each packet this host receives with ``probability`` (iptables ``statistic``
        match in its namespace; ``tc netem`` is not available everywhere); 0 removes the rule."""
        subprocess.run(["ip", "netns", "exec", self.ns, "iptables", "-F", "INPUT"], capture_output=True, timeout=10,
                       check=True)
        if probability > 0:
            subprocess.run(["ip", "netns", "exec", self.ns, "iptables", "-A", "INPUT", "-m", "statistic", "--mode",
                            "random", "--probability", f"{probability:g}", "-j", "DROP"],
                           capture_output=True, text=True, timeout=10, check=True)


def unavailable() -> str | None:
    """Why network namespaces cannot be created here, or None if they can."""
    if os.geteuid() != 0:
        return "network namespaces need root"
    name = f"mfprobe{os.getpid()}"
    try:
        result = _ip("netns", "add", name, check=False)
    except (OSError, subprocess.TimeoutExpired) as exc:
        return f"cannot run ip: {exc}"
    if result.returncode != 0:
        return f"ip netns add failed: {result.stderr.strip()}"
    _ip("netns", "del", name, check=False)
    return None


@contextmanager
def hosts(count: int = 2):
    """``count`` hosts on one /24 behind a bridge; yields the list of :class:`Host`."""
    tag = f"{os.getpid() % 100000}x{next(_COUNTER)}"
    subnet = f"10.{200 + (os.getpid() % 50)}.{(os.getpid() // 50 + next(_COUNTER)) % 250}"
    switch = f"mfsw{tag}"
    created: list[str] = []
    try:
        _ip("netns", "add", switch)
        created.append(switch)
        _ip("-n", switch, "link", "add", "br0", "type", "bridge")
        _ip("-n", switch, "link", "set", "br0", "up")
        out = []
        for k in range(count):
            ns = f"mfh{tag}h{k}"
            _ip("netns", "add", ns)
            created.append(ns)
            a, b = f"mf{tag}a{k}"[:15], f"mf{tag}b{k}"[:15]
            _ip("link", "add", a, "type", "veth", "peer", "name", b)
            _ip("link", "set", a, "netns", ns)
            _ip("link", "set", b, "netns", switch)
            _ip("-n", switch, "link", "set", b, "master", "br0")
            _ip("-n", switch, "link", "set", b, "up")
            ip = f"{subnet}.{k + 1}"
            _ip("-n", ns, "addr", "add", f"{ip}/24", "dev", a)
            _ip("-n", ns, "link", "set", a, "up")
            _ip("-n", ns, "link", "set", "lo", "up")
            out.append(Host(ns=ns, ip=ip, iface=a, peer=b, switch=switch))
        yield out
    finally:
        for ns in reversed(created):  # deleting a namespace deletes its veth ends too
            _ip("netns", "del", ns, check=False)
