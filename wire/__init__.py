"""What crosses the network: key expressions, message types, the msgpack codec and Zenoh config helpers.

See docs/protocol.md for the protocol, field by field.
"""
from .keys import check_id, mission_id_from_name
from .messages import (
    CONFIRM_STATUSES, MAX_PAYLOAD_BYTES, PROTOCOL_VERSION, Bye, CarrierState, Confirm, Decision,
    End, Hello, Observation, Own, Pose, ProtocolError, Refusal, State, decode, encode, fingerprint,
)

__all__ = [
    "CONFIRM_STATUSES", "MAX_PAYLOAD_BYTES", "PROTOCOL_VERSION", "Bye", "CarrierState", "Confirm",
    "Decision", "End", "Hello", "Observation", "Own", "Pose", "ProtocolError", "Refusal", "State", "check_id", "decode",
    "encode", "fingerprint", "mission_id_from_name",
]
