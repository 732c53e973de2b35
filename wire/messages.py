"""Every message of the fleet protocol, with a versioned msgpack codec and strict validation.

A message on the wire is a msgpack map ``{"v": 1, "type": "<kind>", "mission": "<id>", ...}``.
:func:`encode` turns a message dataclass into bytes; :func:`decode` turns bytes back into exactly one
dataclass or raises :class:`ProtocolError` with a short ``reason`` code (used to count rejections)
and a human detail. Decoding never raises anything else, whatever the bytes.

Field types, units and meaning are documented on each dataclass and in docs/protocol.md.
"""
from __future__ import annotations

import contextvars
import functools
import math
import threading
from collections import OrderedDict
from dataclasses import Field, dataclass, field, fields
from typing import Any, Callable, TypeVar, cast, overload

import msgpack

from validation import Found, Flaw

from .keys import ID_PATTERN

#: The protocol version this code speaks; messages with any other ``v`` are rejected. ``v``
#: changes only for a change an older peer cannot be spared by negotiation (docs/protocol.md,
#: "Compatibility"): a required field added, removed or changed in meaning or type, the envelope
#: or an existing message's key changed.
PROTOCOL_VERSION = 1

#: The newest revision of version 1 this code speaks (docs/protocol.md, "Revisions"). A revision
#: only adds optional fields and message types; each side learns the other's revision (Hello
#: ``revision``, State ``revision``, the State query's ``revision`` parameter) and sends a peer
#: only what the lower of the two revisions defines (:func:`encode`'s ``revision``).
#: 1: the first published page (epochs, Own, Refusal, scoped State); 2: passenger types
#: (Decision ``passengers``, Confirm ``passenger``); 3: revisions announced, every Hello answered
#: (Accepted, Refusal reasons beyond the fingerprint), rejections visible in State; 4: End
#: ``epoch`` (a deposed coordinator cannot end a mission), the mission's clock on Accepted; 5:
#: region counts (Observation and Own ``counts``) for missions under the coverage reward; 6:
#: ballots, the coordinator's id beside its epoch (Decision, State, Accepted, End ``coordinator``).
REVISION = 6

#: What a peer that does not announce its revision speaks: revisions 1 and 2 did not announce
#: theirs, and a revision-2 peer reads every message of revision 1.
UNANNOUNCED_REVISION = 1

#: Size limits (payload, stages, carriers, trail, coordinates, text): one home, shared with the
#: scenario validation so that a valid scenario's messages always encode.
from planner.limits import (  # noqa: E402
    EPOCH_MAX, MAX_CARRIERS, MAX_COORD, MAX_PASSENGERS, MAX_PAYLOAD_BYTES, MAX_POINT_REGIONS, MAX_STAGES,
    MAX_STATE_CARRIERS, MAX_TEXT, MAX_TRAIL,
)

#: Every reason code :class:`ProtocolError` can carry (plus node-level ones in docs/protocol.md).
REASONS = (
    "oversized", "malformed", "not-a-map", "version", "unknown-type", "missing-field",
    "unknown-field", "wrong-type", "out-of-range",
)


class ProtocolError(ValueError):
    """A message that does not follow the protocol.

    Attributes:
        reason: short code, one of :data:`REASONS` or a node-level code (``wrong-mission``,
            ``key-mismatch``, ``unknown-carrier``, ``stale-stage``, ``duplicate``, ...).
        detail: one human-readable line.
    """

    def __init__(self, reason: str, detail: str = "", problem: Flaw | None = None):
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason = reason
        self.detail = detail
        self.problem = problem


def _refused(reason: str, name: str, expected: str, found: str) -> ProtocolError:
    """The error of a field that is not what its type says (``name: expected E, found F``, the
    toolkit's problem line; ``found`` is a description such as a type name)."""
    problem = Flaw(name, expected, Found(found))
    return ProtocolError(reason, problem.line(), problem)


# --------------------------------------------------------------------------- field validators
# A validator takes (value, field name) and returns the normalised value (lists become tuples)
# or raises ProtocolError.

Validator = Callable[[Any, str], Any]


def _int(lo: int, hi: int) -> Validator:
    def check(value: Any, name: str) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise _refused("wrong-type", name, "integer", type(value).__name__)
        if not lo <= value <= hi:
            raise _refused("out-of-range", name, f"{lo}..{hi}", str(value))
        return value
    return check


def _float(lo: float, hi: float) -> Validator:
    def check(value: Any, name: str) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise _refused("wrong-type", name, "number", type(value).__name__)
        value = float(value)
        if not math.isfinite(value) or not lo <= value <= hi:
            raise _refused("out-of-range", name, f"finite {lo}..{hi}", str(value))
        return value
    return check


def _positive(hi: float) -> Validator:
    """A finite number in ``(0, hi]``."""
    inner = _float(0.0, hi)

    def check(value: Any, name: str) -> float:
        value = inner(value, name)
        if value <= 0.0:
            raise _refused("out-of-range", name, f"finite > 0 and <= {hi}", str(value))
        return value
    return check


def _bool(value: Any, name: str) -> bool:
    if not isinstance(value, bool):
        raise _refused("wrong-type", name, "boolean", type(value).__name__)
    return value


def _text(max_len: int = MAX_TEXT) -> Validator:
    def check(value: Any, name: str) -> str:
        if not isinstance(value, str):
            raise _refused("wrong-type", name, "string", type(value).__name__)
        if len(value) > max_len:
            raise ProtocolError("out-of-range", f"{name}: longer than {max_len} characters")
        return value
    return check


_ID_TEXT = _text(64)


def _ident(value: Any, name: str) -> str:
    _ID_TEXT(value, name)
    if not ID_PATTERN.match(value):
        raise ProtocolError("out-of-range", f"{name}: not a valid id: {value[:40]!r}")
    return value


def _optional(inner: Validator) -> Validator:
    def check(value: Any, name: str) -> Any:
        return None if value is None else inner(value, name)
    return check


def _list(inner: Validator, max_len: int) -> Validator:
    def check(value: Any, name: str) -> tuple:
        if not isinstance(value, (list, tuple)):
            raise _refused("wrong-type", name, "array", type(value).__name__)
        if len(value) > max_len:
            raise ProtocolError("out-of-range", f"{name}: more than {max_len} items")
        return tuple(inner(item, f"{name}[{k}]") for k, item in enumerate(value))
    return check


_COORD = _float(-MAX_COORD, MAX_COORD)


def _plain_points(value: Any) -> tuple | None:
    """``value``'s [x, y] items as :func:`_point` returns them when every one is a pair of plain
    numbers in range; None when one is not (then :func:`_point` names the defect)."""
    out = []
    for item in value:
        if type(item) not in (list, tuple) or len(item) != 2:
            return None
        x, y = item
        if (type(x) not in (int, float) or type(y) not in (int, float)
                or not (-MAX_COORD <= x <= MAX_COORD and -MAX_COORD <= y <= MAX_COORD)):
            return None  # NaN fails the comparison too
        out.append((float(x), float(y)))
    return tuple(out)


def _point(value: Any, name: str) -> tuple[float, float]:
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise ProtocolError("wrong-type", f"{name}: expected [x, y]")
    return (_COORD(value[0], f"{name}[0]"), _COORD(value[1], f"{name}[1]"))


def _points(max_len: int) -> Validator:
    """An array of at most ``max_len`` [x, y] points (a trail): checked at once, each point named
    only when one is defective (then by :func:`_list` of :func:`_point`)."""
    one_by_one = _list(_point, max_len)

    def check(value: Any, name: str) -> tuple:
        if isinstance(value, (list, tuple)) and len(value) <= max_len:
            fast = _plain_points(value)
            if fast is not None:
                return fast
        return one_by_one(value, name)
    return check


def _unique_ids(value: Any, name: str) -> tuple:
    ids = _list(_ident, MAX_CARRIERS)(value, name)
    if len(set(ids)) != len(ids):
        raise ProtocolError("out-of-range", f"{name}: repeated carrier id")
    return ids


def _counts(value: Any, name: str) -> tuple:
    if not isinstance(value, dict):
        raise _refused("wrong-type", name, "map", type(value).__name__)
    if len(value) > 64:
        raise ProtocolError("out-of-range", f"{name}: more than 64 entries")
    return tuple(sorted(
        (_text(40)(k, f"{name} key"), _int(0, 2**53)(v, f"{name}[{k}]")) for k, v in value.items()
    ))


#: A feature count (an Observation's ``x``, a region's count).
_COUNT = _int(0, 10**9)
#: Region counts (revision 5): absent (nil) under the penalty reward and at a ∅ stage; a coverage
#: mission refuses carriers of earlier revisions (mission.coverage.COUNTS_REVISION).
_REGION_COUNTS = _optional(_list(_COUNT, MAX_POINT_REGIONS))


def _check_counts(message: Any) -> None:
    """The cross-field rule of ``counts`` (Observation, Own): only with an ``x``, and ``x`` is
    their sum (docs/protocol.md, "Observation")."""
    if message.counts is None:
        return
    if message.x is None:
        raise ProtocolError("out-of-range", "counts: expected nil when x is nil")
    if sum(message.counts) != message.x:
        raise ProtocolError("out-of-range", f"counts: expected counts summing to x ({message.x}), "
                                            f"found a sum of {sum(message.counts)}")


_STAGE = _int(0, MAX_STAGES - 1)
_STAGE_COUNT = _int(0, MAX_STAGES)
_PASSENGERS = _int(0, MAX_PASSENGERS)
_SECONDS = _float(-1e9, 1e9)
_MS = _float(0.0, 1e9)


_NO_DEFAULT = object()


def _spec(validator: Validator, as_map: bool = False, absent: Any = _NO_DEFAULT, since: int = 1,
          values: dict[Any, int] | None = None) -> Any:
    """A dataclass field carrying its wire validator in metadata; ``as_map``: a tuple of sorted
    (key, value) pairs in Python, a map on the wire. ``absent``: the field is optional on the wire
    and a missing one means this value; the encoder leaves it out when it has this value (so a
    peer written before the field existed still reads every message that does not use it).
    ``since``: the revision that added the field (docs/protocol.md, "Revisions"); only optional
    fields are added by a revision, and the encoder leaves the field out for a peer of an
    earlier revision. ``values``: an enumerated field's values, each with the revision that
    added it (a value is checked on decoding, and never sent to a peer of an earlier revision)."""
    if since > 1 and absent is _NO_DEFAULT:
        raise TypeError("a field added by a revision must be optional")
    meta = {"check": validator, "as_map": as_map, "since": since}
    if values is not None:
        meta["values"] = values
    if absent is _NO_DEFAULT:
        return field(metadata=meta)
    return field(default=absent, metadata={**meta, "absent": absent})


#: A coordinator's epoch (docs/protocol.md, "Epochs"): 1 for a fresh mission, higher after
#: every restart or takeover; absent on the wire = 1.
_EPOCH = _int(1, EPOCH_MAX)

#: The id of the coordinator that took an epoch (revision 6; docs/protocol.md, "Epochs"): with
#: the epoch, its ballot (mission.ballot). Absent on the wire = "" (not stated: revision 5 and
#: earlier; then the epoch alone ranks it).
_COORDINATOR = _ident

#: A protocol revision a peer announces (docs/protocol.md, "Revisions"); absent on the wire = 1.
_REVISION = _int(1, 2**16 - 1)

#: What an Accepted of revision 4 or later without ``clock``, ``silence_timeout_s``, ``realtime``
#: means: the sim clock, a 30 s silence timeout, unpaced. Protocol constants, not the command
#: line's defaults (mission.timeouts): a change of these would change what old messages mean.
ACCEPTED_ABSENT = ("sim", 30.0, 0.0)
#: The largest silence timeout and pace an Accepted carries (a sender sends at most this).
ACCEPTED_MAX = 1e9


# --------------------------------------------------------------------------- messages

@dataclass(frozen=True)
class Hello:
    """A carrier announces itself (on start and on re-join). carrier -> ``carrier/<id>/hello``.

    Attributes:
        carrier: carrier id (must equal the id in the key).
        pid: OS process id of the carrier process.
        host: host name of the carrier's machine.
        passengers_left: passengers still on board.
        next_stage: the first stage this carrier will observe.
        fingerprint: hex digest of the carrier's scenario (with its seed); must equal the
            coordinator's, else the carrier built another world and is refused.
        epoch: the highest coordinator epoch the carrier has heard (1 when none; omitted on the
            wire when 1): informative to a coordinator, which never takes an epoch from a
            carrier (docs/protocol.md [P-7.3]).
        revision: the newest protocol revision the carrier speaks (absent: 1; sent only to a
            coordinator that announced revision 3 or later in its State).
    """

    mission: str = _spec(_ident)
    carrier: str = _spec(_ident)
    pid: int = _spec(_int(0, 2**31))
    host: str = _spec(_text(255))
    passengers_left: int = _spec(_PASSENGERS)
    next_stage: int = _spec(_STAGE_COUNT)
    fingerprint: str = _spec(_text(64))
    epoch: int = _spec(_EPOCH, absent=1)
    revision: int = _spec(_REVISION, absent=UNANNOUNCED_REVISION, since=3)
    v: int = PROTOCOL_VERSION
    TYPE = "hello"


@dataclass(frozen=True)
class Observation:
    """What a carrier sensed at one stage time. carrier -> ``carrier/<id>/obs``.

    Attributes:
        carrier: carrier id (must equal the id in the key).
        stage: stage index j, 0-based.
        t: simulated mission time of the stage, seconds.
        x: features sensed (count), or None (∅) when the carrier is not scheduled at this stage.
        position: carrier position [x, y] at the stage time, metres.
        passengers_left: passengers still on board before this stage's decision.
        trail: positions [x, y] (metres) the carrier drove through since its previous observation,
            oldest first, at most 512 points (for maps only).
        counts: under the coverage reward, the feature count of each region the carrier's disc
            covers at this stage, in the order of the scenario's ``covers`` (ascending region
            index); ``x`` is their sum. None (absent) under the penalty reward and when ``x`` is
            None (revision 5).
    """

    mission: str = _spec(_ident)
    carrier: str = _spec(_ident)
    stage: int = _spec(_STAGE)
    t: float = _spec(_SECONDS)
    x: int | None = _spec(_optional(_COUNT))
    position: tuple[float, float] = _spec(_point)
    passengers_left: int = _spec(_PASSENGERS)
    trail: tuple[tuple[float, float], ...] = _spec(_points(MAX_TRAIL))
    counts: tuple[int, ...] | None = _spec(_REGION_COUNTS, absent=None, since=5)
    v: int = PROTOCOL_VERSION
    TYPE = "obs"

    def __post_init__(self) -> None:
        _check_counts(self)


@dataclass(frozen=True)
class Decision:
    """The joint decision of one stage. coordinator -> ``coordinator/decision``.

    Attributes:
        stage: stage index j.
        t: simulated mission time of the stage, seconds.
        deploy: ids of the carriers that deploy one passenger now (sorted, no repeats).
        planning_ms: wall time the planner took, milliseconds.
        epoch: the deciding coordinator's epoch (>= 1; omitted on the wire when 1): a carrier
            ignores a Decision of an epoch lower than the highest it has heard (``deposed``).
        passengers: the passenger index each carrier of ``deploy`` releases, parallel to it
            (passenger types, docs/planner.md); empty when the decision names none (omitted on
            the wire when empty).
        coordinator: the deciding coordinator's id (revision 6; "": not stated): with ``epoch``
            its ballot, compared in that order (docs/protocol.md [P-7.2]).
    """

    mission: str = _spec(_ident)
    stage: int = _spec(_STAGE)
    t: float = _spec(_SECONDS)
    deploy: tuple[str, ...] = _spec(_unique_ids)
    planning_ms: float = _spec(_MS)
    epoch: int = _spec(_EPOCH, absent=1)
    passengers: tuple[int, ...] = _spec(_list(_int(0, MAX_PASSENGERS - 1), MAX_CARRIERS), absent=(), since=2)
    coordinator: str = _spec(_COORDINATOR, absent="", since=6)
    v: int = PROTOCOL_VERSION
    TYPE = "decision"

    def __post_init__(self) -> None:
        if self.passengers and len(self.passengers) != len(self.deploy):
            raise ProtocolError("out-of-range", f"passengers: expected one per deploying carrier "
                                                f"({len(self.deploy)}) or none, found {len(self.passengers)}")

    def passenger_of(self, cid: str) -> int | None:
        """The passenger index the decision names for carrier ``cid`` (None: none named, or not
        selected)."""
        if not self.passengers or cid not in self.deploy:
            return None
        return self.passengers[self.deploy.index(cid)]


#: Confirm.status values.
CONFIRM_STATUSES = ("deployed", "idle", "late", "refused", "already")
#: The statuses that say a passenger was released (``deployed`` true); ``already`` repeats the
#: first outcome, either way.
RELEASING_STATUSES = ("deployed", "already")


@dataclass(frozen=True)
class Confirm:
    """A carrier's answer to one stage's decision. carrier -> ``carrier/<id>/confirm``.

    Attributes:
        carrier: carrier id (must equal the id in the key).
        stage: the decision's stage.
        deployed: True if a passenger was deployed at this stage because of this decision.
        status: ``deployed``; ``idle`` (not selected); ``late`` (decision arrived after the carrier
            had moved on: not deployed); ``refused`` (selected but no passenger left or not at the
            stage: not deployed); ``already`` (a repeated decision for a stage handled before; the
            first handling stands and ``deployed`` repeats its outcome).
        position: where the passenger was released (or the carrier's position), metres.
        passengers_left: passengers on board after handling the decision.
        passenger: the index of the passenger released (None when nothing was released or the
            carrier does not say; omitted on the wire when None).
    """

    mission: str = _spec(_ident)
    carrier: str = _spec(_ident)
    stage: int = _spec(_STAGE)
    deployed: bool = _spec(_bool)
    status: str = _spec(_text(16), values=dict.fromkeys(CONFIRM_STATUSES, 1))  # in table order: [P-3.3]
    position: tuple[float, float] = _spec(_point)
    passengers_left: int = _spec(_PASSENGERS)
    passenger: int | None = _spec(_optional(_int(0, MAX_PASSENGERS - 1)), absent=None, since=2)
    v: int = PROTOCOL_VERSION
    TYPE = "confirm"

    def __post_init__(self) -> None:
        if self.status not in CONFIRM_STATUSES:  # built in code rather than decoded
            raise ProtocolError("out-of-range", f"status: expected one of {CONFIRM_STATUSES}, found {self.status!r}")
        if self.deployed and self.status not in RELEASING_STATUSES:
            raise ProtocolError("out-of-range", f"deployed: true with status {self.status!r}")
        if not self.deployed and self.status == "deployed":
            raise ProtocolError("out-of-range", "deployed: false with status 'deployed'")
        if self.passenger is not None and not self.deployed:
            raise ProtocolError("out-of-range", "passenger: named, but nothing was released")


@dataclass(frozen=True)
class Own:
    """A carrier's account of a stage it decided itself, with no decision from the coordinator
    in time (docs/protocol.md, "Deciding without the coordinator"). carrier ->
    ``carrier/<id>/own``, read by the coordinator and by the other carriers.

    Attributes:
        carrier: carrier id (must equal the id in the key).
        stage: the stage it decided.
        t: the stage's mission time, seconds.
        x: what it observed there (features), or None (∅: not scheduled).
        deployed: True if it released a passenger at this stage.
        position: where (the carrier's position at the stage time), metres.
        passengers_left: passengers on board after the stage.
        counts: the region counts behind ``x`` under the coverage reward, as in
            :class:`Observation` (revision 5).
    """

    mission: str = _spec(_ident)
    carrier: str = _spec(_ident)
    stage: int = _spec(_STAGE)
    t: float = _spec(_SECONDS)
    x: int | None = _spec(_optional(_COUNT))
    deployed: bool = _spec(_bool)
    position: tuple[float, float] = _spec(_point)
    passengers_left: int = _spec(_PASSENGERS)
    counts: tuple[int, ...] | None = _spec(_REGION_COUNTS, absent=None, since=5)
    v: int = PROTOCOL_VERSION
    TYPE = "own"

    def __post_init__(self) -> None:
        _check_counts(self)


@dataclass(frozen=True)
class End:
    """The mission is over; carriers say Bye and exit. coordinator -> ``coordinator/end``.

    Attributes:
        stages: number of stages decided.
        reason: ``complete`` or ``stopped`` (free text: a receiver acts on the End whatever it says).
        epoch: the ending coordinator's epoch (revision 4; None: not stated, as by a coordinator of
            an earlier revision or in a broadcast to carriers of one): a carrier ignores an End
            whose stated epoch is lower than the highest it has heard (a deposed coordinator
            cannot end the mission) and acts on one that states none, as before revision 4 (a
            restarted coordinator of revision 3 has epoch 2 and states none).
        coordinator: the ending coordinator's id (revision 6; "": not stated).
    """

    mission: str = _spec(_ident)
    stages: int = _spec(_STAGE_COUNT)
    reason: str = _spec(_text(40))
    epoch: int | None = _spec(_optional(_EPOCH), absent=None, since=4)
    coordinator: str = _spec(_COORDINATOR, absent="", since=6)
    v: int = PROTOCOL_VERSION
    TYPE = "end"


@dataclass(frozen=True)
class Bye:
    """A carrier's last message before it exits. carrier -> ``carrier/<id>/bye``.

    Attributes:
        carrier: carrier id.
        deployments: stages at which this carrier deployed, ascending.
        rejected: per reason, how many incoming messages this carrier rejected.
        reason: why it exits: ``end``, ``coordinator-lost``, ``stopped``, ``finished``.
    """

    mission: str = _spec(_ident)
    carrier: str = _spec(_ident)
    deployments: tuple[int, ...] = _spec(_list(_STAGE, MAX_STAGES))
    rejected: tuple[tuple[str, int], ...] = _spec(_counts, as_map=True)
    reason: str = _spec(_text(40))
    v: int = PROTOCOL_VERSION
    TYPE = "bye"


#: Refusal.reason values and the revision that added each (docs/protocol.md, "Refusal"): a
#: Refusal with a reason a peer's revision does not define is not sent to it. Since revision 3
#: every reason a Hello can be rejected for refuses it.
REFUSAL_REASONS = {
    "world-mismatch": 1,
    "unknown-carrier": 3, "key-mismatch": 3, "wrong-mission": 3, "out-of-range": 3, "wrong-type": 3,
    "missing-field": 3, "unknown-field": 3, "malformed": 3, "not-a-map": 3, "version": 3, "oversized": 3,
}


@dataclass(frozen=True)
class Refusal:
    """The coordinator refuses a carrier's Hello. coordinator -> ``coordinator/refusal/<id>``.

    Attributes:
        carrier: the carrier whose Hello is refused (the id in the key).
        reason: why, one of :data:`REFUSAL_REASONS` (``world-mismatch``: the Hello's fingerprint
            is not the coordinator's; the others: the rejection reason of the Hello).
        fingerprint: the refused Hello's fingerprint ("" when the Hello had none that could be
            read; a carrier ignores a Refusal naming a fingerprint it did not send: someone else
            spoke with its id).
        expected: the coordinator's fingerprint.
        detail: one line saying what was wrong (revision 3; omitted when empty).
    """

    mission: str = _spec(_ident)
    carrier: str = _spec(_ident)
    reason: str = _spec(_text(40), values=REFUSAL_REASONS)
    fingerprint: str = _spec(_text(64))
    expected: str = _spec(_text(64))
    detail: str = _spec(_text(200), absent="", since=3)
    v: int = PROTOCOL_VERSION
    TYPE = "refusal"


@dataclass(frozen=True)
class Accepted:
    """The coordinator accepted a carrier's Hello (revision 3: sent only to a carrier whose
    Hello announced revision 3 or later). coordinator -> ``coordinator/accepted/<id>``.

    Attributes:
        carrier: the carrier whose Hello is accepted (the id in the key).
        fingerprint: the accepted Hello's fingerprint (the coordinator's).
        next_stage: the Hello's ``next_stage`` as the coordinator recorded it.
        collecting: the stage the coordinator collects now (its first undecided stage, N when
            all are decided).
        revision: the newest revision the coordinator speaks.
        epoch: the coordinator's epoch (omitted when 1).
        clock: the mission's clock, ``sim`` or ``wall`` (revision 4; absent = ``sim``).
        silence_timeout_s: the coordinator's silence timeout, seconds > 0 (revision 4; absent = 30).
        realtime: the mission's pace, simulated seconds per wall second, 0 = unpaced (revision 4;
            absent = 0). The three are read only from an Accepted of ``revision`` >= 4: an earlier
            coordinator says nothing of its clock.
        coordinator: the coordinator's id (revision 6; "": not stated).
    """

    mission: str = _spec(_ident)
    carrier: str = _spec(_ident)
    fingerprint: str = _spec(_text(64))
    next_stage: int = _spec(_STAGE_COUNT)
    collecting: int = _spec(_STAGE_COUNT)
    revision: int = _spec(_REVISION)
    epoch: int = _spec(_EPOCH, absent=1)
    clock: str = _spec(_text(16), absent=ACCEPTED_ABSENT[0], since=4, values={"sim": 4, "wall": 4})
    silence_timeout_s: float = _spec(_positive(ACCEPTED_MAX), absent=ACCEPTED_ABSENT[1], since=4)
    realtime: float = _spec(_float(0.0, ACCEPTED_MAX), absent=ACCEPTED_ABSENT[2], since=4)
    coordinator: str = _spec(_COORDINATOR, absent="", since=6)
    v: int = PROTOCOL_VERSION
    TYPE = "accepted"
    SINCE = 3


@dataclass(frozen=True)
class CarrierState:
    """One carrier's part of :class:`State` (a nested map, not a message of its own).

    Attributes:
        passengers_left: passengers not yet deployed according to the mission log.
        deployments: stages with a deployment decided for this carrier and not refuted by a Confirm.
        live: whether its liveliness token is currently present.
        refused: why the coordinator refused the carrier's last Hello (a :data:`REFUSAL_REASONS`
            value) when it has no accepted Hello; None otherwise (revision 3).
        rejected: per reason, how many of this carrier's messages the coordinator process
            rejected (revision 3; sorted pairs; a map on the wire).
    """

    passengers_left: int = _spec(_PASSENGERS)
    deployments: tuple[int, ...] = _spec(_list(_STAGE, MAX_STAGES))
    live: bool = _spec(_bool)
    refused: str | None = _spec(_optional(_text(40)), absent=None, since=3)
    rejected: tuple[tuple[str, int], ...] = _spec(_counts, as_map=True, absent=(), since=3)


@dataclass(frozen=True)
class State:
    """The mission state, the reply of the ``coordinator/state`` queryable.

    Attributes:
        next_stage: the first stage not decided yet (== stages when all are decided).
        stages: N, the number of stages of the mission.
        ended: True once End was published.
        carriers: per carrier id, its :class:`CarrierState` (sorted by id): only the asking
            carrier's for a query ``?carrier=<id>``; every carrier's for an unscoped query on a
            mission of at most MAX_STATE_CARRIERS carriers, none on a larger one.
        last_decision: the most recent Decision (None before stage 0 is decided).
        fingerprint: hex digest of the coordinator's scenario (see Hello).
        epoch: the answering coordinator's epoch (>= 1; omitted on the wire when 1).
        revision: the newest protocol revision the coordinator speaks (absent: 1; left out of
            the reply to a query that announced no revision 3 or later).
        coordinator: the answering coordinator's id (revision 6; "": not stated).
    """

    mission: str = _spec(_ident)
    next_stage: int = _spec(_STAGE_COUNT)
    stages: int = _spec(_STAGE_COUNT)
    fingerprint: str = _spec(_text(64))
    ended: bool = _spec(_bool)
    carriers: tuple[tuple[str, CarrierState], ...] = _spec(lambda v, n: _carrier_states(v, n), as_map=True)
    last_decision: Decision | None = _spec(lambda v, n: None if v is None else _nested(Decision, v, n))
    epoch: int = _spec(_EPOCH, absent=1)
    revision: int = _spec(_REVISION, absent=UNANNOUNCED_REVISION, since=3)
    coordinator: str = _spec(_COORDINATOR, absent="", since=6)
    v: int = PROTOCOL_VERSION
    TYPE = "state"

    def carrier(self, cid: str) -> CarrierState | None:
        return dict(self.carriers).get(cid)


@dataclass(frozen=True)
class Pose:
    """Where a carrier is, published at a steady rate of simulated time for viewers and recorders.
    carrier -> ``carrier/<id>/pose``. Nobody acts on it: the coordinator ignores poses (they are
    neither events of the mission nor rejections).

    Attributes:
        carrier: carrier id (must equal the id in the key).
        t: simulated mission time of the pose, seconds (a multiple of the pose interval).
        position: carrier position [x, y], metres.
        heading: direction of travel, radians counter-clockwise from +x, in [-pi, pi]
            (the last direction of motion while standing still; 0 before the first move).
        passengers_left: passengers on board at ``t``.
    """

    mission: str = _spec(_ident)
    carrier: str = _spec(_ident)
    t: float = _spec(_SECONDS)
    position: tuple[float, float] = _spec(_point)
    heading: float = _spec(_float(-math.pi - 1e-6, math.pi + 1e-6))
    passengers_left: int = _spec(_PASSENGERS)
    v: int = PROTOCOL_VERSION
    TYPE = "pose"


@dataclass(frozen=True)
class Progress:
    """A carrier is alive and working towards its next observation: sent on the sim clock at least
    every ``progress_s`` of wall time (1 s by default) while it simulates towards ``stage``.
    carrier -> ``carrier/<id>/progress``. It carries no mission fact: the coordinator (and a peer
    deciding alone) only notes when it last heard from the carrier, so that a carrier that is
    slow (a long stage, a saturated host) is waited for and only one that is silent is taken as
    stalled (docs/protocol.md, "Simulated time"). Never stored, never a rejection once decoded.

    Attributes:
        carrier: carrier id (must equal the id in the key).
        stage: the stage whose Observation the carrier is working towards (0..N: N once it has
            handled its last stage).
        t: the simulated mission time its physics has reached, seconds.
    """

    mission: str = _spec(_ident)
    carrier: str = _spec(_ident)
    stage: int = _spec(_STAGE_COUNT)
    t: float = _spec(_SECONDS)
    v: int = PROTOCOL_VERSION
    TYPE = "progress"
    SINCE = 3


def refusal(mission: str, carrier: str, reason: str, fingerprint: str, expected: str, detail: str,
            revision: int) -> Refusal:
    """The Refusal answering a refused Hello, as the carrier's ``revision`` can read it: with
    the reason and its detail from revision 3; to a carrier of an earlier revision, whose only
    reason is ``world-mismatch``, as that (it stops, as it must: docs/protocol.md, "Refusal")."""
    answer = Refusal(mission, carrier, reason, str(fingerprint)[:64], expected, str(detail)[:200])
    if not defined_in(answer, revision):
        answer = Refusal(mission, carrier, "world-mismatch", str(fingerprint)[:64], expected)
    return answer


def announced(payload: bytes) -> tuple[int, str]:
    """(revision, fingerprint) a Hello that failed to decode announced, as far as they can be
    read (:data:`UNANNOUNCED_REVISION` and "" when not): what its Refusal is written for."""
    try:
        raw = msgpack.unpackb(bytes(payload), raw=False) if len(payload) <= MAX_PAYLOAD_BYTES else None
    except Exception:
        raw = None
    if not isinstance(raw, dict):
        return UNANNOUNCED_REVISION, ""
    revision = raw.get("revision")
    fp = raw.get("fingerprint")
    revision = min(revision, REVISION) if type(revision) is int and revision >= 1 else UNANNOUNCED_REVISION
    return revision, fp[:64] if isinstance(fp, str) else ""


@dataclass(frozen=True)
class OperatorAction:
    """An operator's action on the stage being decided (revision 5). operator console ->
    ``operator/<op>/action`` (docs/protocol.md, "Operator actions"). No carrier sends or reads it.

    Attributes:
        operator: the sender's identity (the ``<op>`` of its key).
        seq: the sender's number for this action; the answer repeats it.
        stage: the stage the action is about (the one being decided).
        action: ``approve`` (the recommendation), ``veto`` or ``force`` (``carrier``'s deployment).
        carrier: the carrier vetoed or forced (absent with ``approve``).
        token: the mission's operator credential (the coordinator's ``operator.token``).
    """

    mission: str = _spec(_ident)
    operator: str = _spec(_ident)
    seq: int = _spec(_int(0, 2**31 - 1))
    stage: int = _spec(_STAGE)
    action: str = _spec(_text(16))
    carrier: str | None = _spec(_optional(_ident), absent=None)
    token: str = _spec(_text(128), absent="")
    v: int = PROTOCOL_VERSION
    TYPE = "operator"
    SINCE = 5


@dataclass(frozen=True)
class OperatorAnswer:
    """The coordinator's answer to an :class:`OperatorAction`. coordinator ->
    ``coordinator/operator/<op>``: taken (``accepted``) or refused with a reason code and its
    detail (docs/protocol.md, "Operator actions")."""

    mission: str = _spec(_ident)
    operator: str = _spec(_ident)
    seq: int = _spec(_int(0, 2**31 - 1))
    stage: int = _spec(_STAGE)
    accepted: bool = _spec(_bool)
    reason: str = _spec(_text(40), absent="")
    detail: str = _spec(_text(200), absent="")
    v: int = PROTOCOL_VERSION
    TYPE = "operator-answer"
    SINCE = 5


MESSAGE_TYPES = {cls.TYPE: cls for cls in (Hello, Observation, Decision, Confirm, Own, End, Bye, State, Refusal,
                                            Pose, Accepted, Progress, OperatorAction, OperatorAnswer)}


def fingerprint(value: object) -> str:
    """16 hex digits identifying a value by its ``repr`` (a project-internal identity, e.g. for
    a scenario built in code without a file)."""
    import hashlib

    return hashlib.sha256(repr(value).encode("utf-8")).hexdigest()[:16]


#: The header the scenario fingerprint hashes before the scenario file (docs/protocol.md,
#: "Fingerprint"): ``FINGERPRINT_HEADER.format(seed=...)`` encoded as UTF-8.
FINGERPRINT_HEADER = "marsupial-fleet/1 seed={seed}\n"


def fingerprint_bytes(scenario_bytes: bytes, seed: int) -> str:
    """The scenario fingerprint: the first 16 lowercase hex digits of SHA-256 over
    ``b"marsupial-fleet/1 seed=<seed>\\n"`` followed by the scenario file's bytes as stored.

    Args:
        scenario_bytes: the scenario YAML file, byte for byte.
        seed: the root seed the process runs with (the file's ``seed``, or ``--seed``), decimal.
    """
    import hashlib

    header = FINGERPRINT_HEADER.format(seed=int(seed)).encode("utf-8")
    return hashlib.sha256(header + bytes(scenario_bytes)).hexdigest()[:16]


def scenario_fingerprint(scenario: Any) -> str:
    """Identifies the world a process built: its scenario file's bytes and its seed
    (:func:`fingerprint_bytes`), so the same file with the same seed matches on any host, in any
    language. A scenario built in code (no file) falls back to its content's ``repr``."""
    import dataclasses
    from pathlib import Path

    source = getattr(scenario, "source", "")
    if source and Path(source).is_file():
        return fingerprint_bytes(Path(source).read_bytes(), scenario.seed)
    if dataclasses.is_dataclass(scenario) and any(f.name == "source" for f in dataclasses.fields(scenario)):
        scenario = dataclasses.replace(cast(Any, scenario), source="")  # an instance (is_dataclass admits classes)
    return fingerprint(scenario)


# --------------------------------------------------------------------------- codec

def _on_wire(f: Field[Any], value: Any, revision: int) -> bool:
    """Whether field ``f`` with ``value`` is sent to a peer of ``revision``: not when the peer's
    revision predates the field, nor when it has its ``absent`` value."""
    if f.metadata.get("since", 1) > revision:
        return False
    return "absent" not in f.metadata or value != f.metadata["absent"]


def _to_wire(value: Any, as_map: bool = False, revision: int = REVISION) -> Any:
    """Dataclasses become maps (with ``type`` for messages) of the fields ``revision`` defines;
    (key, value) pair tuples of fields marked ``as_map`` become maps; other tuples become arrays."""
    if hasattr(value, "__dataclass_fields__"):
        out = {f.name: _to_wire(getattr(value, f.name), f.metadata.get("as_map", False), revision)
               for f in fields(value) if _on_wire(f, getattr(value, f.name), revision)}
        if hasattr(type(value), "TYPE"):
            out["type"] = type(value).TYPE
        return out
    if as_map:
        return {k: _to_wire(v, revision=revision) for k, v in value}
    if isinstance(value, (tuple, list)):
        return [_to_wire(v, revision=revision) for v in value]
    return value


def defined_in(message: Any, revision: int) -> bool:
    """Whether a peer of ``revision`` can be sent ``message``: its type and its enumerated
    values exist in that revision (later optional fields are left out by :func:`encode`)."""
    if getattr(type(message), "SINCE", 1) > revision:
        return False
    return all(f.metadata["values"].get(getattr(message, f.name), REVISION + 1) <= revision
               for f in fields(message) if "values" in f.metadata and f.metadata["since"] <= revision)


def encode(message: Any, revision: int = REVISION) -> bytes:
    """Serialise one message dataclass to msgpack bytes (validated on the way out).

    Args:
        message: a message dataclass.
        revision: the revision of the peer it is for (docs/protocol.md, "Revisions"): fields a
            later revision added are left out (an optional field's absence has a documented
            meaning in every revision), so that peer reads every byte of it.

    Raises:
        ProtocolError: if the message would not pass :func:`decode` (a bug in the sender).
        ValueError: the message type does not exist in ``revision`` (a bug in the sender: it
            must not send it to that peer).
    """
    if not defined_in(message, revision):
        raise ValueError(f"a {type(message).TYPE} message as {message!r:.120} does not exist in revision {revision}")
    data = msgpack.packb(_to_wire(message, revision=revision), use_bin_type=True)
    if len(data) > MAX_PAYLOAD_BYTES:
        raise ProtocolError("oversized", f"{len(data)} bytes > {MAX_PAYLOAD_BYTES}")
    decode(data, revision=revision)  # what we send must pass the receiver's checks of its revision
    return data


@functools.cache
def _fields_of(cls: Any, revision: int) -> tuple[frozenset, tuple]:
    """The wire fields of ``cls`` a receiver of ``revision`` reads: their names, and per field in
    order (name, validator, optional, enumerated values or None)."""
    specs = tuple((f.name, f.metadata["check"], "absent" in f.metadata, f.metadata.get("values"))
                  for f in fields(cls) if f.name != "v" and f.metadata.get("since", 1) <= revision)
    return frozenset(name for name, *_ in specs), specs


def _build(cls: Any, data: dict, where: str, revision: int = REVISION) -> Any:
    names, specs = _fields_of(cls, revision)
    if not names.issuperset(data):
        unknown = set(data) - names
        raise ProtocolError("unknown-field", f"{where}: unexpected field {sorted(map(str, unknown))[0]!r}")
    values = {}
    for name, check, optional, allowed in specs:
        if name not in data or (optional and data[name] is None):
            if optional:
                # Optional: the dataclass default is the documented meaning of absent, and nil
                # there means absent too (docs/protocol.md, [P-1.3]).
                continue
            raise ProtocolError("missing-field", f"{where}: missing field {name!r}")
        values[name] = check(data[name], f"{where}.{name}")
        if allowed is not None and allowed.get(values[name], REVISION + 1) > revision:
            choices = sorted(k for k, since in allowed.items() if since <= revision)
            raise ProtocolError("out-of-range", f"{where}.{name}: expected one of {choices}, "
                                                f"found {str(values[name])[:40]!r}")
    return cls(**values)


def _nested(cls: Any, value: Any, name: str) -> Any:
    if not isinstance(value, dict):
        raise _refused("wrong-type", name, "map", type(value).__name__)
    data = dict(value)
    if cls is not CarrierState:
        if data.pop("v", PROTOCOL_VERSION) != PROTOCOL_VERSION or data.pop("type", cls.TYPE) != cls.TYPE:
            raise ProtocolError("wrong-type", f"{name}: not a {cls.TYPE} message")
    return _build(cls, data, name, _DECODING.get())


def _carrier_states(value: Any, name: str) -> tuple:
    if not isinstance(value, dict):
        raise _refused("wrong-type", name, "map", type(value).__name__)
    if len(value) > MAX_STATE_CARRIERS:
        raise ProtocolError("out-of-range", f"{name}: more than {MAX_STATE_CARRIERS} carriers")
    return tuple(sorted(
        (_ident(k, f"{name} key"), _nested(CarrierState, v, f"{name}[{k}]")) for k, v in value.items()
    ))


#: The revision a :func:`decode` in progress reads (for the maps nested in a State).
_DECODING: contextvars.ContextVar[int] = contextvars.ContextVar("decoding_revision", default=REVISION)


_M = TypeVar("_M")


@overload
def decode(data: bytes, expected: type[_M], revision: int = REVISION) -> _M: ...
@overload
def decode(data: bytes, expected: tuple[type, ...] | None = None, revision: int = REVISION) -> Any: ...


def decode(data: bytes, expected: type | tuple[type, ...] | None = None, revision: int = REVISION) -> Any:
    """Parse and validate one message.

    Args:
        data: the payload bytes.
        expected: message class(es) acceptable here; another valid type is rejected as
            ``unknown-type``.
        revision: read as a receiver of this revision does (docs/protocol.md, "Revisions"): a
            field or message type a later revision added is ``unknown-field`` /
            ``unknown-type``. This code itself receives at :data:`REVISION`.

    Returns:
        A frozen message dataclass.

    Raises:
        ProtocolError: for any defect, with the reason code of the first one found.
    """
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise ProtocolError("malformed", f"payload is {type(data).__name__}, not bytes")
    if len(data) > MAX_PAYLOAD_BYTES:
        raise ProtocolError("oversized", f"{len(data)} bytes > {MAX_PAYLOAD_BYTES}")
    try:
        raw = msgpack.unpackb(
            bytes(data), raw=False, strict_map_key=True, use_list=True,
        )
    except Exception as exc:  # msgpack raises several exception types for bad input
        raise ProtocolError("malformed", f"not msgpack: {type(exc).__name__}") from None
    if not isinstance(raw, dict):
        raise ProtocolError("not-a-map", f"top level is {type(raw).__name__}")
    version = raw.pop("v", None)
    if version is None:
        raise ProtocolError("missing-field", "missing field 'v'")
    if type(version) is not int or version != PROTOCOL_VERSION:  # 1.0 and true are not 1
        raise ProtocolError("version", f"unsupported protocol version {str(version)[:20]!r}, this is {PROTOCOL_VERSION}")
    kind = raw.pop("type", None)
    if kind is None:  # nil as absent ([P-1.3])
        raise ProtocolError("missing-field", "missing field 'type'")
    cls = MESSAGE_TYPES.get(kind) if isinstance(kind, str) else None
    if cls is None or getattr(cls, "SINCE", 1) > revision:
        raise ProtocolError("unknown-type", f"unknown message type {str(kind)[:40]!r}")
    if expected is not None:
        allowed = expected if isinstance(expected, tuple) else (expected,)
        if cls not in allowed:
            raise ProtocolError("unknown-type", f"a {kind} message is not accepted here")
    token = _DECODING.set(revision)
    try:
        return _build(cls, raw, kind, revision)
    except ProtocolError:
        raise
    except Exception as exc:  # defensive: a validator bug must still not crash a node
        raise ProtocolError("malformed", f"{kind}: {type(exc).__name__}") from None
    finally:
        _DECODING.reset(token)


class SharedDecoder:
    """Decodes a broadcast once for all the receivers of one process.

    A Decision names about a third of the fleet, so decoding and validating it costs O(R); it reaches every carrier session of a process with the
    same bytes, and decoding it per carrier made that O(R) per carrier, O(R²/K) per process of K
    processes (docs/performance.md, "Fleet scale"). This decodes each distinct payload once and
    gives every receiver the same frozen message, or a fresh :class:`ProtocolError` with the same
    reason and detail as :func:`decode` raises: what a receiver sees is exactly what its own
    :func:`decode` would give. Thread-safe; remembers the last ``capacity`` payloads.
    """

    def __init__(self, capacity: int = 8):
        self.capacity = int(capacity)
        self._lock = threading.Lock()
        self._seen: "OrderedDict[tuple, tuple]" = OrderedDict()

    def decode(self, data: bytes, expected: type | tuple[type, ...] | None = None) -> Any:
        """:func:`decode` (``revision`` :data:`REVISION`) of ``data``, computed once per distinct
        payload and ``expected``."""
        key = (bytes(data), expected)
        with self._lock:  # the others wait for the first decoder instead of decoding too
            found = self._seen.get(key)
            if found is None:
                try:
                    found = (decode(key[0], expected), None)
                except ProtocolError as exc:
                    found = (None, (exc.reason, exc.detail))
                self._seen[key] = found
                if len(self._seen) > self.capacity:
                    self._seen.popitem(last=False)
            else:
                self._seen.move_to_end(key)
        message, error = found
        if error is not None:
            raise ProtocolError(*error)
        return message
