"""Size limits of a mission: one home for scenario validation (world/) and the wire (wire/).

The values are chosen so that any scenario that passes validation produces messages that fit in
one wire payload (tests/test_limits.py encodes each at the limits):

* a ``Decision`` names up to ``MAX_CARRIERS`` carriers (ids of up to 64 characters):
  ``MAX_CARRIERS * 66`` bytes, about 66 KiB at 1024 carriers, < ``MAX_PAYLOAD_BYTES``;
* a ``State`` reply lists at most ``MAX_STATE_CARRIERS`` carriers with their deployments (at most
  ``MAX_PASSENGERS`` stage indices below ``MAX_STAGES``): ``64 * (64 + 40 + 5 * 100)`` bytes,
  about 39 KiB. A carrier asks for its own entry only (``?carrier=<id>``); an unscoped query
  lists every carrier of a mission of at most ``MAX_STATE_CARRIERS`` carriers (as protocol
  version 1 always did), none of a larger one.

Every message of a mission of at most 64 carriers is byte for byte what it was when 64 carriers
and 64 KiB were the limits, so older version-1 peers interoperate with such missions.
"""
from __future__ import annotations

#: Largest number of stages N of a mission (count).
MAX_STAGES = 100_000
#: Largest number of carriers R of a mission (count).
MAX_CARRIERS = 1024
#: Most carriers listed in one State reply (count).
MAX_STATE_CARRIERS = 64
#: Largest number of passengers D of one carrier (count).
MAX_PASSENGERS = 100
#: Largest accepted wire payload, bytes; larger payloads are rejected before parsing.
MAX_PAYLOAD_BYTES = 128 * 1024
#: Longest free text field of a wire message (characters).
MAX_TEXT = 200
#: Most trail points [x, y] in one observation message.
MAX_TRAIL = 512
#: Most regions one decision point's disc may cover under the coverage reward (the region counts
#: of one Observation, at most 5 bytes each on the wire: 20 KiB); a scenario whose arrangement has
#: a point covering more is refused (world/regions.py).
MAX_POINT_REGIONS = 4096
#: Largest absolute coordinate on the wire, metres (scenario files are stricter).
MAX_COORD = 1e7
#: Highest coordinator epoch the wire carries (a msgpack int32). A coordinator that would need a
#: higher one refuses to open its mission (storage.missiondb.EpochsExhausted) rather than wrap.
EPOCH_MAX = 2**31 - 1
#: Largest message a Zenoh link of the fleet accepts (``transport.link.rx.max_message_size``, in
#: wire/zconfig.py and the configs of tools/gen_certs.py), bytes: four payloads, so every message
#: of the protocol (and a payload a little over the limit, which the protocol itself rejects and
#: counts as ``oversized``) passes, and a flood of megabytes is dropped by the first hop's
#: transport instead of being reassembled and routed on.
TRANSPORT_MAX_MESSAGE_BYTES = 4 * MAX_PAYLOAD_BYTES
