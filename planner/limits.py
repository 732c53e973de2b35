"""Size limits of a mission: one home for scenario validation (world/) and the wire (wire/).

The values are chosen so that any scenario that passes validation produces messages that fit in
one wire payload: the largest message is the coordinator's ``State`` reply, which lists every
carrier (id of up to 64 characters) with its deployments (at most ``MAX_PASSENGERS`` stage
indices below ``MAX_STAGES``): ``MAX_CARRIERS * (64 + 40 + 5 * MAX_PASSENGERS)`` bytes is about
39 KiB < ``MAX_PAYLOAD_BYTES`` (tests/test_limits.py encodes such a State).
"""
from __future__ import annotations

#: Largest number of stages N of a mission (count).
MAX_STAGES = 100_000
#: Largest number of carriers R of a mission (count).
MAX_CARRIERS = 64
#: Largest number of passengers D of one carrier (count).
MAX_PASSENGERS = 100
#: Largest accepted wire payload, bytes; larger payloads are rejected before parsing.
MAX_PAYLOAD_BYTES = 64 * 1024
#: Longest free text field of a wire message (characters).
MAX_TEXT = 200
#: Most trail points [x, y] in one observation message.
MAX_TRAIL = 512
#: Largest absolute coordinate on the wire, metres (scenario files are stricter).
MAX_COORD = 1e7
