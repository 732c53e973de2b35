"""rmw_zenoh's formats (ros2/rmw.py) against golden strings from rmw_zenoh's own source.

Sources (GitHub ros2/rmw_zenoh, the Jazzy-and-later formats, Zenoh 1.x):

* docs/design.md @ 99a6a2bd10b949052f4f12c5854825dc005e95a5 — "Topic and Service name mapping to
  Zenoh key expressions" (the data keys of ``chatter`` with and without namespace), "Graph Cache"
  (the NN / MS / MP tokens of demo_nodes_cpp's talker and listener), "Publishers" (the attachment:
  int64 LE sequence number, int64 LE timestamp, 1 byte GID length (16), 16 bytes GID);
* rmw_zenoh_cpp/src/detail/liveliness_utils.cpp @ 3411fdec149fe0c932f24d4d79ef908eb81d7482 —
  ``ADMIN_SPACE "@ros2_lv"``, ``NN/MP/MS/SS/SC``, ``SLASH_REPLACEMENT '%'``, ``QOS_DELIMITER ':'``,
  ``QOS_COMPONENT_DELIMITER ','``, ``qos_to_keyexpr``, ``TopicInfo`` (``strip_slashes``);
* rmw_zenoh_cpp/src/detail/qos.cpp @ 7efeee2b9009b816a4bd4a3148af3cca40f753d5 — the defaults
  (KEEP_LAST 42, RELIABLE, VOLATILE, infinite durations, AUTOMATIC);
* rmw_zenoh_cpp/src/detail/attachment_helpers.cpp @ 534747dca92adf15e1b1b975123037ca278db5ba —
  ``serializer.serialize(sequence_number_); serialize(source_timestamp_); serialize(source_gid_)``
  (zenoh-ext serialisation; checked here against zenoh-python's own ``zenoh.ext.z_serialize``);
* rmw_zenoh_cpp/src/detail/rmw_subscription_data.cpp @ a72659a6a65404a4ed43b7f41a6fc514d737e602 —
  samples without an attachment are dropped ("Unable to obtain attachment");
* liveliness_utils.cpp (as above), ``Entity::Entity``: the GID is
  ``simplified_XXH3_128bits(liveliness_keyexpr_)``, ``memcpy`` of ``low64`` into bytes 0-7 and of
  ``high64`` into bytes 8-15; simplified_xxhash3.hpp @ 63133f54863361a2c579f871e90d27bd33b0c7c5
  (``low64`` is ``value & 0xFFFFFFFFFFFFFFFF``, ``high64`` is ``value >> 64``); rmw_publisher_data.cpp
  @ 3e19ec730c529035a648aec80c0ae0a056943b8c puts ``entity_->copy_gid()`` in every attachment.
  Golden values from PyPI's xxhash; the halves' order checked against xxHash's own sanity vector
  for the empty input (Cyan4973/xxHash, tests: ``{ 0x6001C324468D497FULL, 0x99AA06D3014798D8ULL }``
  as ``{low64, high64}``).
"""
from __future__ import annotations

import pytest

from ros2 import msgs, rmw

CHATTER_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
STRING_DDS = "std_msgs::msg::dds_::String_"


def test_data_keys_are_the_design_documents():
    assert msgs.dds_name("std_msgs/msg/String") == STRING_DDS
    assert msgs.type_hash("std_msgs/msg/String") == CHATTER_HASH
    assert rmw.topic_key(0, "/chatter", STRING_DDS, CHATTER_HASH) == \
        "0/chatter/std_msgs::msg::dds_::String_/RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
    assert rmw.topic_key(0, rmw.fully_qualified("/robot1", "chatter"), STRING_DDS, CHATTER_HASH) == \
        "0/robot1/chatter/std_msgs::msg::dds_::String_/RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"


def test_name_resolution():
    assert rmw.fully_qualified("/", "chatter") == "/chatter"
    assert rmw.fully_qualified("/c1", "pose") == "/c1/pose"
    assert rmw.fully_qualified("/fleet/c1/", "pose") == "/fleet/c1/pose"
    assert rmw.fully_qualified("/c1", "/tf") == "/tf"


def test_tokens_are_the_design_documents():
    listener_zid, talker_zid = "aac3178e146ba6f1fc6e6a4085e77f21", "8b20917502ee955ac4476e0266340d5c"
    assert rmw.node_token(2, listener_zid, 0, "/", "listener") == \
        "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener"
    assert rmw.entity_token(2, listener_zid, 0, 10, rmw.SUBSCRIPTION, "/", "listener", "/chatter", STRING_DDS,
                            CHATTER_HASH, rmw.QoS(depth=10)) == (
        "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/10/MS/%/%/listener/%chatter/std_msgs::msg::dds_::String_/"
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18/::,10:,:,:,,")
    assert rmw.entity_token(2, talker_zid, 0, 10, rmw.PUBLISHER, "/", "talker", "/chatter", STRING_DDS,
                            CHATTER_HASH, rmw.QoS(depth=7)) == (
        "@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/std_msgs::msg::dds_::String_/"
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18/::,7:,:,:,,")


def test_a_namespaced_token_mangles_every_slash():
    token = rmw.entity_token(0, "ab", 3, 4, rmw.PUBLISHER, "/fleet/c1", "carrier", "/fleet/c1/pose",
                             msgs.dds_name("geometry_msgs/msg/PoseStamped"),
                             msgs.type_hash("geometry_msgs/msg/PoseStamped"), rmw.QoS(depth=10))
    assert token.split("/")[6:10] == ["%", "%fleet%c1", "carrier", "%fleet%c1%pose"]
    parsed = rmw.parse_token(token)
    assert (parsed.namespace, parsed.node, parsed.topic, parsed.qos.depth) == ("/fleet/c1", "carrier",
                                                                              "/fleet/c1/pose", 10)


@pytest.mark.parametrize("qos, text", [
    (rmw.DEFAULT_QOS, "::,:,:,:,,"),
    (rmw.QoS(depth=7), "::,7:,:,:,,"),
    (rmw.QoS(durability=rmw.TRANSIENT_LOCAL, depth=1), ":1:,1:,:,:,,"),
    (rmw.QoS(reliability=rmw.BEST_EFFORT, history=rmw.KEEP_ALL, deadline=(1, 500)), "2::2,:1,500:,:,,"),
], ids=["default", "depth7", "transient-local", "best-effort-keep-all-deadline"])
def test_qos_field(qos, text):
    assert rmw.qos_keyexpr(qos) == text
    assert rmw.parse_qos(text) == qos


def test_attachment_layout():
    gid = bytes(range(16))
    data = rmw.attachment(5, 1_700_000_000_123_456_789, gid)
    assert len(data) == 33
    assert data[:8] == (5).to_bytes(8, "little")
    assert data[8:16] == (1_700_000_000_123_456_789).to_bytes(8, "little")
    assert data[16] == 16 and data[17:] == gid
    assert rmw.parse_attachment(data) == rmw.Attachment(5, 1_700_000_000_123_456_789, gid)


def test_attachment_equals_zenoh_ext_serialisation():
    """attachment_helpers.cpp serialises with zenoh-ext: the same bytes as zenoh-python's."""
    from zenoh.ext import Int64, z_serialize

    gid = bytes(range(100, 116))
    assert rmw.attachment(-3, 42, gid) == z_serialize((Int64(-3), Int64(42), gid)).to_bytes()


def test_other_formats_get_one_line():
    humble = rmw.attachment(1, 2, bytes(16))[:16] + bytes([24]) + bytes(24)  # Humble: 24-byte GIDs
    with pytest.raises(rmw.ForeignFormat, match="41 bytes, GID length 24"):
        rmw.parse_attachment(humble)
    with pytest.raises(rmw.ForeignFormat, match="RIHS01"):
        rmw.parse_token("@ros2_lv/0/ab/0/10/MP/%/%/talker/%chatter/std_msgs::msg::dds_::String_/"
                        "TypeHashNotSupported/::,7:,:,:,,")
    with pytest.raises(rmw.ForeignFormat, match="another rmw_zenoh format"):
        rmw.parse_token("@ros2_lv/0/ab/10/MP/%/talker/%chatter")  # the pre-Jazzy layout, no node id
    with pytest.raises(ValueError):
        rmw.parse_token("marsupial/m/coordinator/alive")
    for line in (str(e) for e in (rmw.ForeignFormat("x"),)):
        assert "\n" not in line


TALKER_NODE = "@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/0/NN/%/%/talker"
TALKER_PUB = ("@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/std_msgs::msg::dds_::String_/"
              "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18/::,7:,:,:,,")


@pytest.mark.parametrize("token, gid_hex", [
    # xxHash's sanity vector: low64 0x6001C324468D497F, high64 0x99AA06D3014798D8, each little-endian
    ("", "7f498d4624c30160" "d8984701d306aa99"),
    (TALKER_NODE, "8514508efc2c8f4e" "e260a1cb837a77f8"),  # 61 bytes: XXH3's 17-128 byte path
    (TALKER_PUB, "ac170f31eadcd9ff" "0cd86d7a17907d1c"),  # 184 bytes: the 129-240 byte path
], ids=["empty", "talker-node", "talker-publisher"])
def test_gid_is_rmw_zenohs_xxh3_128_of_the_token(token, gid_hex):
    import xxhash

    gid = rmw.gid(token)
    assert gid.hex() == gid_hex
    # The same bytes by another route: xxhash's canonical digest is big-endian (high64 first), so
    # rmw_zenoh's layout (low64 then high64, each little-endian) is that digest reversed.
    assert gid == xxhash.xxh3_128(token.encode()).digest()[::-1]


def test_gid_is_stable_and_distinct():
    a = rmw.gid("@ros2_lv/0/ab/0/1/MP/%/%/n/%a/t/h/::,:,:,:,,")
    assert a == rmw.gid("@ros2_lv/0/ab/0/1/MP/%/%/n/%a/t/h/::,:,:,:,,") and len(a) == 16
    assert a != rmw.gid("@ros2_lv/0/ab/0/2/MP/%/%/n/%a/t/h/::,:,:,:,,")
