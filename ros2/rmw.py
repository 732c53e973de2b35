"""rmw_zenoh's formats (ROS 2 Jazzy and later): the keys, tokens and attachments a ROS 2 host reads.

Written from rmw_zenoh's source (ros2/rmw_zenoh; commits cited in tests/test_ros2_rmw.py):

* data key of a topic: ``<domain>/<fully qualified name without outer slashes>/<DDS type
  name>/<RIHS01 type hash>`` (``TopicInfo`` in rmw_zenoh_cpp/src/detail/liveliness_utils.cpp),
  e.g. ``0/chatter/std_msgs::msg::dds_::String_/RIHS01_df668c74…``;
* liveliness token of a node: ``@ros2_lv/<domain>/<zid>/<nid>/<nid>/NN/<enclave>/<namespace>/
  <node>``; of a publisher or subscription: ``@ros2_lv/<domain>/<zid>/<nid>/<eid>/MP|MS/
  <enclave>/<namespace>/<node>/<topic>/<type>/<hash>/<qos>``, every ``/`` inside a component
  written ``%`` (``mangle_name``), so an empty namespace or enclave (``/``) is ``%``;
* the QoS field: only the settings that differ from rmw_zenoh's defaults are written
  (``qos_to_keyexpr``; defaults in qos.cpp: reliable, volatile, keep-last 42, infinite deadline,
  lifespan and lease, automatic liveliness);
* the attachment of every sample (``AttachmentData::serialize_to_zbytes`` in
  attachment_helpers.cpp, zenoh-ext serialisation): int64 sequence number (LE), int64 source
  timestamp (ns since the Unix epoch, LE), then the 16-byte GID as a sequence (LEB128 length 16,
  then the bytes): 33 bytes. Subscribers drop samples without one (rmw_subscription_data.cpp);
* the GID of an entity (``Entity::Entity``): XXH3-128 (seed 0) of its whole liveliness token,
  the low 64 bits then the high 64 bits, each little-endian (``memcpy`` of ``low64``, ``high64``
  on a little-endian host); a publisher's samples carry it in their attachment, so a ROS 2 node
  matches a sample to the publisher its graph cache holds.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass

import xxhash

#: Prefix of every graph token (a zenoh hermetic namespace: ``*``/``**`` never match it).
ADMIN_SPACE = "@ros2_lv"
#: Entity kinds of a token.
NODE, PUBLISHER, SUBSCRIPTION, SERVICE, CLIENT = "NN", "MP", "MS", "SS", "SC"
ENTITY_KINDS = (NODE, PUBLISHER, SUBSCRIPTION, SERVICE, CLIENT)
#: Bytes of a GID (RMW_GID_STORAGE_SIZE: 16 since Iron; Humble's rmw has 24).
GID_BYTES = 16
#: Prefix of an RIHS01 type hash (REP 2011); Humble's rmw_zenoh writes ``TypeHashNotSupported``.
HASH_PREFIX = "RIHS01_"
#: Length of an attachment in this format: seq (8) + timestamp (8) + LEB128 16 (1) + GID (16).
ATTACHMENT_BYTES = 8 + 8 + 1 + GID_BYTES

# rmw_qos_*_policy_e values (rmw/types.h).
RELIABLE, BEST_EFFORT = 1, 2
TRANSIENT_LOCAL, VOLATILE = 1, 2
KEEP_LAST, KEEP_ALL = 1, 2
AUTOMATIC = 1
INFINITE = (9223372036, 854775807)  # RMW_DURATION_INFINITE as (sec, nsec)


class ForeignFormat(ValueError):
    """A ROS 2 peer speaks another rmw_zenoh format (another distribution): one line says which.
    A carrier whose robot speaks it stops with this exit reason (carriers/node.py)."""

    exit_reason = "ros2-mismatch"


@dataclass(frozen=True)
class QoS:
    """The QoS of a publisher or subscription (the subset rmw_zenoh puts in its token).

    Attributes:
        reliability: :data:`RELIABLE` or :data:`BEST_EFFORT`.
        durability: :data:`VOLATILE` or :data:`TRANSIENT_LOCAL` (late joiners get the last
            ``depth`` samples).
        history: :data:`KEEP_LAST` or :data:`KEEP_ALL`.
        depth: samples kept (KEEP_LAST).
        deadline, lifespan, lease: (sec, nsec); :data:`INFINITE` by default.
        liveliness: :data:`AUTOMATIC`.
    """

    reliability: int = RELIABLE
    durability: int = VOLATILE
    history: int = KEEP_LAST
    depth: int = 42
    deadline: tuple[int, int] = INFINITE
    lifespan: tuple[int, int] = INFINITE
    liveliness: int = AUTOMATIC
    lease: tuple[int, int] = INFINITE


#: rmw_zenoh's default QoS (qos.cpp): the reference of the token's QoS field.
DEFAULT_QOS = QoS()


def qos_keyexpr(qos: QoS) -> str:
    """The QoS field of a token (``qos_to_keyexpr``): ``rel:dur:hist,depth:dl_s,dl_ns:ls_s,ls_ns:
    live,lease_s,lease_ns`` with every value equal to the default left empty."""
    d = DEFAULT_QOS

    def v(value, default) -> str:
        return "" if value == default else str(value)

    return (f"{v(qos.reliability, d.reliability)}:{v(qos.durability, d.durability)}:"
            f"{v(qos.history, d.history)},{v(qos.depth, d.depth)}:"
            f"{v(qos.deadline[0], d.deadline[0])},{v(qos.deadline[1], d.deadline[1])}:"
            f"{v(qos.lifespan[0], d.lifespan[0])},{v(qos.lifespan[1], d.lifespan[1])}:"
            f"{v(qos.liveliness, d.liveliness)},{v(qos.lease[0], d.lease[0])},{v(qos.lease[1], d.lease[1])}")


def parse_qos(text: str) -> QoS:
    """The QoS of a token's QoS field (``keyexpr_to_qos``); ValueError if malformed."""
    parts = text.split(":")
    if len(parts) < 6:
        raise ValueError(f"QoS field {text!r}: expected 6 ':'-separated parts")
    hist, dl, ls, live = (p.split(",") for p in parts[2:6])
    if len(hist) < 2 or len(dl) < 2 or len(ls) < 2 or len(live) < 3:
        raise ValueError(f"QoS field {text!r}: too few ','-separated values")
    d = DEFAULT_QOS

    def n(s: str, default: int) -> int:
        return default if s == "" else int(s)

    return QoS(n(parts[0], d.reliability), n(parts[1], d.durability), n(hist[0], d.history), n(hist[1], d.depth),
               (n(dl[0], d.deadline[0]), n(dl[1], d.deadline[1])), (n(ls[0], d.lifespan[0]), n(ls[1], d.lifespan[1])),
               n(live[0], d.liveliness), (n(live[1], d.lease[0]), n(live[2], d.lease[1])))


def mangle(name: str) -> str:
    """A name as one key chunk: every ``/`` becomes ``%`` (``mangle_name``)."""
    return name.replace("/", "%")


def demangle(chunk: str) -> str:
    return chunk.replace("%", "/")


def fully_qualified(namespace: str, name: str) -> str:
    """ROS name resolution of ``name`` in ``namespace`` (absolute names stay as they are):
    ``("/c1", "pose")`` -> ``/c1/pose``, ``("/", "tf")`` -> ``/tf``, ``(_, "/tf")`` -> ``/tf``."""
    if name.startswith("/"):
        return name
    ns = "/" + namespace.strip("/") if namespace.strip("/") else ""
    return f"{ns}/{name}"


def topic_key(domain: int, topic: str, dds_type: str, type_hash: str) -> str:
    """The data key of a topic (``TopicInfo``): ``<domain>/<topic without outer slashes>/<type>/<hash>``."""
    return f"{int(domain)}/{topic.strip('/')}/{dds_type}/{type_hash}"


def node_token(domain: int, zid: str, nid: int, namespace: str, node: str, enclave: str = "/") -> str:
    """The liveliness token of a node (kind NN, its entity id is its node id)."""
    return "/".join((ADMIN_SPACE, str(int(domain)), zid, str(nid), str(nid), NODE, mangle(enclave),
                     mangle(namespace), mangle(node)))


def entity_token(domain: int, zid: str, nid: int, eid: int, kind: str, namespace: str, node: str, topic: str,
                 dds_type: str, type_hash: str, qos: QoS, enclave: str = "/") -> str:
    """The liveliness token of a publisher (MP) or subscription (MS) of node ``nid``; ``topic``
    fully qualified (``/c1/pose``)."""
    if kind not in ENTITY_KINDS or kind == NODE:
        raise ValueError(f"kind: expected one of MP, MS, SS, SC, found {kind!r}")
    return "/".join((ADMIN_SPACE, str(int(domain)), zid, str(nid), str(eid), kind, mangle(enclave),
                     mangle(namespace), mangle(node), mangle(topic), mangle(dds_type), mangle(type_hash),
                     qos_keyexpr(qos)))


@dataclass(frozen=True)
class Token:
    """A parsed graph token. ``topic``, ``dds_type``, ``type_hash`` and ``qos`` are None for a node."""

    domain: int
    zid: str
    nid: str
    eid: str
    kind: str
    enclave: str
    namespace: str
    node: str
    topic: str | None = None
    dds_type: str | None = None
    type_hash: str | None = None
    qos: QoS | None = None


def parse_token(key: str) -> Token:
    """Parse a graph token of this format (``Entity::make(keyexpr)``).

    Raises:
        ForeignFormat: the token is of another rmw_zenoh format (another ROS distribution), with
            the one line to print.
        ValueError: not a graph token at all.
    """
    parts = key.split("/")
    if not parts or parts[0] != ADMIN_SPACE:
        raise ValueError(f"not a ROS 2 graph token: {key[:120]}")
    if len(parts) < 9 or parts[5] not in ENTITY_KINDS:
        raise ForeignFormat(f"ROS 2 peer of another rmw_zenoh format (expected {ADMIN_SPACE}/<domain>/<zid>/<nid>/"
                            f"<eid>/<kind>/<enclave>/<namespace>/<node>[/...], as Jazzy and later write): {key[:160]}")
    if any(p == "" for p in parts):
        raise ValueError(f"graph token with an empty component: {key[:160]}")
    domain, zid, nid, eid, kind, enclave, ns, node = parts[1:9]
    base = dict(domain=int(domain), zid=zid, nid=nid, eid=eid, kind=kind, enclave=demangle(enclave),
                namespace=demangle(ns), node=demangle(node))
    if kind == NODE:
        return Token(**base)
    if len(parts) < 13:
        raise ForeignFormat(f"ROS 2 peer of another rmw_zenoh format ({kind} token without topic, type, hash and "
                            f"QoS): {key[:160]}")
    type_hash = demangle(parts[11])
    if not type_hash.startswith(HASH_PREFIX):
        raise ForeignFormat(f"ROS 2 peer without RIHS01 type hashes (type hash {type_hash[:40]!r}: Humble's "
                            f"rmw_zenoh?); this fleet speaks the Jazzy-and-later format")
    return Token(**base, topic=demangle(parts[9]), dds_type=demangle(parts[10]), type_hash=type_hash,
                 qos=parse_qos(parts[12]))


def gid(token: str) -> bytes:
    """The 16-byte GID of the entity with this liveliness token, as rmw_zenoh makes it (see the
    module docstring): ``low64`` then ``high64`` of XXH3-128, little-endian."""
    value = xxhash.xxh3_128_intdigest(token.encode())  # (high64 << 64) | low64
    return struct.pack("<QQ", value & 0xFFFF_FFFF_FFFF_FFFF, value >> 64)


def attachment(sequence_number: int, source_timestamp_ns: int, source_gid: bytes) -> bytes:
    """The attachment rmw_zenoh puts on every sample (33 bytes)."""
    if len(source_gid) != GID_BYTES:
        raise ValueError(f"source_gid: expected {GID_BYTES} bytes, found {len(source_gid)}")
    return struct.pack("<qqB", int(sequence_number), int(source_timestamp_ns), GID_BYTES) + bytes(source_gid)


@dataclass(frozen=True)
class Attachment:
    sequence_number: int
    source_timestamp_ns: int
    gid: bytes


def parse_attachment(data: bytes) -> Attachment:
    """The attachment of a sample from a ROS 2 publisher.

    Raises:
        ForeignFormat: not the Jazzy-and-later layout (e.g. Humble's 24-byte GIDs, or the string
            keys of rmw_zenoh's first zenoh-1.0 releases), with the one line to print.
    """
    data = bytes(data)
    if len(data) != ATTACHMENT_BYTES or data[16] != GID_BYTES:
        size = data[16] if len(data) > 16 else None
        raise ForeignFormat(f"ROS 2 sample attachment of another rmw_zenoh format ({len(data)} bytes, GID length "
                            f"{size}; expected {ATTACHMENT_BYTES} bytes with a {GID_BYTES}-byte GID, as Jazzy and "
                            f"later write)")
    seq, ts = struct.unpack_from("<qq", data)
    return Attachment(seq, ts, data[17:])
