"""The simulator's vocabulary: its constants, messages, clocks, faults (and their draw from a
seed), a mission's outcome and a carrier's log entry (:mod:`mission.simulate`)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: The fault kinds a schedule draws from (docs/fleet.md, "Deterministic simulation").
FAULT_KINDS = ("stale", "loss", "duplicate", "reorder", "partition", "router-lost", "crash", "coordinator-crash",
               "takeover", "dual-start", "pause", "freeze", "slow", "corrupt", "clock-jump", "standby-crash",
               "compromised")
#: Kinds under which the fleet must decide exactly like the offline planner: nothing is lost for
#: long and nobody is stuck, only slow, repeated, out of order or spoken to by strangers.
FAITHFUL_KINDS = frozenset({"duplicate", "reorder", "slow", "corrupt", "stale"})
#: Zenoh's lease: a cut-off session's tokens vanish this long after the cut (s).
LEASE_S = 10.0
#: A client opening its session retries this often while the router is out of reach (s; the
#: ``retry_s`` of wire.zconfig.open_session).
OPEN_RETRY_S = 0.2
#: The router: every message goes through it.
ROUTER = "router"


@dataclass(frozen=True)
class Msg:
    """A message on the simulated network: ``kind`` (the wire's message names), the sender's id,
    the fields. ``mission`` other than the fleet's: a foreign message; ``garbled``: it does not
    decode (both fail checks 1–3 of [P-3.3]: dropped, not heard)."""

    kind: str
    src: str
    body: tuple = ()
    mission: str = "m"
    garbled: bool = False

    def get(self, name, default=None):
        return dict(self.body).get(name, default)


def msg(kind: str, src: str, **body) -> Msg:
    return Msg(kind, src, tuple(sorted(body.items())))


@dataclass
class Clock:
    """A host's clock: ``offset + (1 + drift) * T`` plus its forward jumps (a monotonic clock
    never goes back)."""

    offset: float
    drift: float
    jumped: float = 0.0

    def now(self, t: float) -> float:
        return self.offset + (1.0 + self.drift) * t + self.jumped


@dataclass(frozen=True)
class Fault:
    """One fault of a schedule: ``kind``, ``at`` s of true time, ``until`` (its end), ``who``
    (a carrier id, or ``coordinator``), ``size`` (a probability, a factor or seconds)."""

    kind: str
    at: float
    until: float
    who: str = ""
    size: float = 0.0

    def as_json(self) -> dict:
        return {"kind": self.kind, "at": round(self.at, 6), "until": round(self.until, 6), "who": self.who,
                "size": round(self.size, 6)}


def draw_faults(rng: np.random.Generator, kinds, ids, horizon: float) -> tuple[Fault, ...]:
    """A fault schedule: 1 to 3 faults of ``kinds`` (none when empty) within ``horizon`` s."""
    kinds = tuple(kinds)
    if not kinds:
        return ()
    out = []
    for _ in range(int(rng.integers(1, 4))):
        kind = kinds[int(rng.integers(len(kinds)))]
        at = float(rng.uniform(0.0, horizon))
        length = float(rng.uniform(0.01, 1.0) if kind == "crash" else rng.uniform(2.0, 60.0))
        who = str(ids[int(rng.integers(len(ids)))])
        size = {"loss": rng.uniform(0.05, 0.5), "duplicate": rng.uniform(0.1, 0.9), "reorder": rng.uniform(5, 50),
                "slow": rng.uniform(20.0, 80.0), "corrupt": float(rng.integers(1, 20)),
                "clock-jump": rng.uniform(1.0, 90.0), "pause": rng.uniform(LEASE_S + 0.5, LEASE_S + 10.0)}.get(kind, 0.0)
        if kind == "compromised":  # ``size`` lies sent with ``who``'s credential within the window
            size = float(rng.integers(5, 60))
        if kind == "standby-crash":  # the standby dies ``size`` s after the primary, which restarts at ``until``
            size = rng.uniform(LEASE_S + 5.0, LEASE_S + 40.0)
            length += size
        if kind in ("coordinator-crash", "takeover", "dual-start", "router-lost", "pause", "standby-crash"):
            who = "coordinator"
        # as the report writes them (Fault.as_json): a schedule read back replays exactly
        out.append(Fault(kind, round(at, 6), round(at + length, 6), who, round(float(size), 6)))
    return tuple(sorted(out, key=lambda f: (f.at, f.kind, f.who)))


# --------------------------------------------------------------------------- the outcome

@dataclass
class Outcome:
    """One simulated mission: its seed, faults, the trace's hash and length, the violations
    found (each a one-line string), what each carrier deployed, the reward, simulated seconds,
    and under a link model how many messages it carried and lost (``links``)."""

    seed: int
    faults: tuple
    trace_hash: str = ""
    events: int = 0
    violations: list = field(default_factory=list)
    deployments: dict = field(default_factory=dict)
    reward: float = 0.0
    seconds: float = 0.0
    completed: bool = False
    links: dict = field(default_factory=dict)  # the link model's counts (sent, lost); empty on perfect links

    def as_json(self) -> dict:
        return {**({"links": self.links} if self.links else {}),"seed": self.seed, "trace_hash": self.trace_hash, "faults": [f.as_json() for f in self.faults],
                "deployments": self.deployments, "reward": round(self.reward, 9), "events": self.events,
                "seconds": round(self.seconds, 6), "completed": self.completed, "violations": self.violations}


@dataclass(frozen=True)
class LogEntry:
    """One stage of a carrier's durable log (the fields of ``storage.carrierlog.LogEntry`` that
    :func:`mission.report.merge` reads)."""

    stage: int
    t: float
    x: int | None = None
    observed: bool = False
    position: tuple = (0.0, 0.0)
    status: str | None = None
    deployed: bool = False
    passengers_left: int = 0
