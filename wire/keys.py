"""Key expressions of the fleet protocol: one prefix per mission, one subtree per publisher.

Layout (``<m>`` = mission id, ``<id>`` = carrier id)::

    marsupial/<m>/carrier/<id>/hello      carrier -> coordinator   Hello (put)
    marsupial/<m>/carrier/<id>/obs        carrier -> coordinator   Observation (put)
    marsupial/<m>/carrier/<id>/confirm    carrier -> coordinator   Confirm (put)
    marsupial/<m>/carrier/<id>/bye        carrier -> coordinator   Bye (put)
    marsupial/<m>/carrier/<id>/own        carrier -> coordinator, carriers   Own (put: a stage it decided itself)
    marsupial/<m>/carrier/<id>/pose       carrier -> viewers       Pose (put, steady rate; the coordinator ignores it)
    marsupial/<m>/carrier/<id>/progress   carrier -> coordinator, carriers   Progress (put, sim clock: working, not stalled)
    marsupial/<m>/carrier/<id>/alive      liveliness token of a carrier
    marsupial/<m>/coordinator/decision    coordinator -> carriers  Decision (put)
    marsupial/<m>/coordinator/end         coordinator -> carriers  End (put)
    marsupial/<m>/coordinator/refusal/<id> coordinator -> carrier  Refusal (put)
    marsupial/<m>/coordinator/accepted/<id> coordinator -> carrier Accepted (put; revision 3)
    marsupial/<m>/coordinator/state       queryable, replies State (``?carrier=<id>``: scoped)
    marsupial/<m>/coordinator/alive       liveliness token of the coordinator
    marsupial/<m>/operator/<op>/action    operator -> coordinator  OperatorAction (put)
    marsupial/<m>/coordinator/operator/<op> coordinator -> operator OperatorAnswer (put)

Invariant: everything a carrier publishes (puts, liveliness token) lies under
``marsupial/<m>/carrier/<id>/**`` and everything the coordinator publishes under
``marsupial/<m>/coordinator/**`` (an operator's under ``marsupial/<m>/operator/<op>/**``), so an
access-control rule per subtree is enough.
"""
from __future__ import annotations

import re

ROOT = "marsupial"

#: Mission and carrier ids are single key-expression chunks: no '/', wildcards or '$'.
ID_PATTERN = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]{0,63}\Z")  # \Z: no trailing newline either

#: The message kinds a carrier publishes under its own subtree.
CARRIER_TOPICS = ("hello", "obs", "confirm", "own", "bye", "pose", "progress")


def check_id(value: str, what: str = "id") -> str:
    """Return ``value`` if it is a valid mission or carrier id, else raise ValueError."""
    if not isinstance(value, str) or not ID_PATTERN.match(value):
        raise ValueError(
            f"{what} must match {ID_PATTERN.pattern} (letters, digits, '_', '.', '-'), found {value!r}"
        )
    return value


def mission_id_from_name(name: str) -> str:
    """A valid mission id derived from a free-form scenario name."""
    cleaned = re.sub(r"[^A-Za-z0-9_.-]+", "-", str(name)).strip("-.") or "mission"
    if not re.match(r"[A-Za-z0-9_]", cleaned[0]):
        cleaned = "m" + cleaned
    return cleaned[:64]


def prefix(mission: str) -> str:
    return f"{ROOT}/{check_id(mission, 'mission')}"


def carrier_key(mission: str, carrier: str, topic: str) -> str:
    """Key of one carrier topic (``hello``, ``obs``, ``confirm``, ``own``, ``bye``, ``pose``)."""
    assert topic in CARRIER_TOPICS, topic
    return f"{prefix(mission)}/carrier/{check_id(carrier, 'carrier')}/{topic}"


def carrier_topic_pattern(mission: str, topic: str) -> str:
    """Subscription pattern for one topic of every carrier."""
    assert topic in CARRIER_TOPICS, topic
    return f"{prefix(mission)}/carrier/*/{topic}"


def carrier_alive(mission: str, carrier: str) -> str:
    return f"{prefix(mission)}/carrier/{check_id(carrier, 'carrier')}/alive"


def carrier_alive_pattern(mission: str) -> str:
    return f"{prefix(mission)}/carrier/*/alive"


def decision_key(mission: str) -> str:
    return f"{prefix(mission)}/coordinator/decision"


def operator_action_key(mission: str, operator: str) -> str:
    return f"{prefix(mission)}/operator/{check_id(operator, 'operator')}/action"


def operator_actions_pattern(mission: str) -> str:
    return f"{prefix(mission)}/operator/*/action"


def operator_answer_key(mission: str, operator: str) -> str:
    return f"{prefix(mission)}/coordinator/operator/{check_id(operator, 'operator')}"


def end_key(mission: str) -> str:
    return f"{prefix(mission)}/coordinator/end"


def accepted_key(mission: str, carrier: str) -> str:
    """Where the coordinator answers an accepted Hello of ``carrier`` (revision 3)."""
    return f"{prefix(mission)}/coordinator/accepted/{check_id(carrier, 'carrier')}"


def refusal_key(mission: str, carrier: str) -> str:
    """Where the coordinator answers a refused Hello of ``carrier``."""
    return f"{prefix(mission)}/coordinator/refusal/{check_id(carrier, 'carrier')}"


def state_key(mission: str) -> str:
    return f"{prefix(mission)}/coordinator/state"


def state_selector(mission: str, carrier: str, revision: int | None = None) -> str:
    """The State query of one carrier: the state key with the parameter ``carrier=<id>``, so the
    reply lists that carrier only (its size does not grow with the fleet), and ``revision=<r>``
    (when given), the protocol revision the asking carrier speaks (docs/protocol.md,
    "Compatibility"): the reply holds only what that revision defines."""
    selector = f"{state_key(mission)}?carrier={check_id(carrier, 'carrier')}"
    return selector if revision is None else f"{selector};revision={int(revision)}"


def asked_revision(parameters: dict | None, highest: int, unannounced: int) -> int:
    """The revision to answer a State query in: the one its ``revision`` parameter announces (a
    decimal integer >= 1), at most ``highest``; ``unannounced`` for a query without a valid one."""
    text = str((parameters or {}).get("revision", ""))
    if not re.fullmatch(r"[0-9]{1,5}", text) or int(text) < 1:
        return unannounced
    return min(int(text), highest)


def coordinator_alive(mission: str) -> str:
    return f"{prefix(mission)}/coordinator/alive"


def parse_carrier_key(mission: str, key: str) -> tuple[str, str] | None:
    """``(carrier id, topic)`` of a key under ``marsupial/<m>/carrier/``, or None if it is not one."""
    head = f"{prefix(mission)}/carrier/"
    if not key.startswith(head):
        return None
    rest = key[len(head):].split("/")
    if len(rest) != 2 or not ID_PATTERN.match(rest[0]):
        return None
    return rest[0], rest[1]
