"""The coordinator's mission events: everything that can change a mission's state.

Each event is a small frozen value with the time it happened as data (``at``: seconds since
the epoch, wall clock). The coordinator process makes them from decoded messages (wire/), from
liveliness changes and from its own stage clock, folds them through
:func:`mission.state.step`, persists the accepted ones in mission.db and, after a restart, folds
the stored ones again: live handling and recovery are the same function.

Field meanings and units follow docs/protocol.md (stages 0-based, positions in metres).
"""
from __future__ import annotations

from dataclasses import dataclass

Point = tuple[float, float]


@dataclass(frozen=True)
class Opened:
    """The coordinator process opened the mission (a fresh start or a restart). Liveliness is a
    property of a session: nobody is live until its token is seen again by this process."""

    at: float = 0.0


@dataclass(frozen=True)
class Hello:
    """A carrier's Hello (docs/protocol.md, "Hello")."""

    carrier: str
    pid: int
    host: str
    passengers_left: int
    next_stage: int
    fingerprint: str
    at: float = 0.0
    revision: int = 1  # the protocol revision it announced (docs/protocol.md, "Revisions"; absent: 1)


@dataclass(frozen=True)
class Observation:
    """A carrier's Observation of ``stage``: ``x`` features (None = ∅) at ``t`` seconds, at
    ``position``, having driven through ``trail`` since its previous one."""

    carrier: str
    stage: int
    t: float
    x: int | None
    position: Point
    passengers_left: int
    trail: tuple[Point, ...] = ()
    at: float = 0.0
    counts: tuple[int, ...] | None = None  # the region counts behind x (coverage reward; else None)


@dataclass(frozen=True)
class LivelinessChanged:
    """A carrier's liveliness token appeared (``alive``) or vanished."""

    carrier: str
    alive: bool
    at: float = 0.0


@dataclass(frozen=True)
class Decided:
    """The coordinator decided ``stage``: ``deploy`` carriers deploy now. Scheduled carriers
    without an observation of the stage become ∅ there (``missing``)."""

    stage: int
    deploy: tuple[str, ...]
    planning_ms: float
    at: float = 0.0
    passengers: tuple[int, ...] = ()  # the passenger each carrier of deploy releases (parallel)
    # Operator mode (docs/fleet.md, "The operator console"); all at their defaults without it.
    recommended: tuple[str, ...] | None = None  # the planner's own recommendation (None: deploy, or no operator)
    forced: tuple[str, ...] = ()  # carriers the operator forced to deploy here
    vetoed: tuple[str, ...] = ()  # carriers the operator vetoed here
    hold: str = ""  # how the operator's hold ended: approved, timeout, watching ("": no operator mode)
    gain: float | None = None  # the planner's estimate of what deploy gains over recommended (normalised)


#: What an operator can do at a stage (docs/fleet.md, "The operator console").
OPERATOR_ACTIONS = ("approve", "veto", "force")


@dataclass(frozen=True)
class OperatorAction:
    """An operator's action on ``stage``, the stage being decided: ``approve`` its recommendation
    (``carrier`` None), ``veto`` or ``force`` the deployment of ``carrier`` there. ``operator``: the
    identity it came from (the console's, or an authorised key's)."""

    stage: int
    action: str
    carrier: str | None
    operator: str
    at: float = 0.0


@dataclass(frozen=True)
class Published:
    """The decision of ``stage`` left the process (the start of the Confirm round trip)."""

    stage: int
    at: float = 0.0


@dataclass(frozen=True)
class Confirmed:
    """A carrier's Confirm of ``stage``'s decision."""

    carrier: str
    stage: int
    deployed: bool
    status: str
    position: Point
    passengers_left: int
    at: float = 0.0
    passenger: int | None = None  # the passenger released (None: none, or not said)


@dataclass(frozen=True)
class Accounted:
    """A carrier's own account of a stage it decided without the coordinator (an Own message,
    or an entry of its durable log read back by the report): what it observed (``x``, None = ∅)
    and whether it released a passenger there. A carrier's account is the truth about what it
    did: it overrides a decision it may never have received."""

    carrier: str
    stage: int
    t: float
    x: int | None
    deployed: bool
    position: Point
    passengers_left: int
    at: float = 0.0
    counts: tuple[int, ...] | None = None  # the region counts behind x (coverage reward; else None)


@dataclass(frozen=True)
class Bye:
    """A carrier's Bye: the stages it deployed at, its rejection counts, why it exits."""

    carrier: str
    deployments: tuple[int, ...]
    rejected: tuple[tuple[str, int], ...]
    reason: str
    at: float = 0.0


@dataclass(frozen=True)
class Ended:
    """The coordinator ends the mission: ``complete`` or ``stopped``."""

    reason: str
    at: float = 0.0


Event = (Opened | Hello | Observation | LivelinessChanged | Decided | Published | Confirmed | Accounted | Bye
         | Ended | OperatorAction)
