"""The ROS 2 message types (ros2/msgs.py) against rosbags, an independent implementation:
field tables equal its Jazzy typestore's, every hash its ``hash_rihs01``, every payload we encode
decodes with its CDR deserialiser to the same values, and equals its own serialisation."""
from __future__ import annotations

import math

import numpy as np
import pytest

rosbags_typesys = pytest.importorskip("rosbags.typesys")

from ros2 import msgs  # noqa: E402

STORE = rosbags_typesys.get_typestore(rosbags_typesys.Stores.ROS2_JAZZY)
for _name, _text in msgs.MSG_TEXT.items():  # types outside common_interfaces, from their .msg files
    STORE.register(rosbags_typesys.get_types_from_msg(_text, _name))


def _their_fields(typename: str) -> tuple:
    """rosbags' field table of a type in our notation."""

    out = []
    for name, (kind, spec) in STORE.fielddefs[typename][1]:
        out.append((name, _notation(kind, spec)))
    return tuple(out)


def _notation(kind, spec) -> str:
    k = int(kind)
    if k == 1:  # BASE
        return spec[0]
    if k == 2:  # NAME
        return spec
    inner = _notation(*spec[0])
    return f"{inner}[]" if k == 4 else f"{inner}[{spec[1]}]"


@pytest.mark.parametrize("typename", sorted(msgs.TYPES))
def test_field_tables_are_jazzys(typename):
    assert msgs.TYPES[typename] == _their_fields(typename)


@pytest.mark.parametrize("typename", sorted(msgs.RIHS01))
def test_hashes_are_rosbags(typename):
    assert msgs.type_hash(typename) == STORE.hash_rihs01(typename)


def _to_dict(obj):
    """A rosbags message object as plain values."""
    if hasattr(obj, "__dataclass_fields__"):
        fields = [name for name, _ in STORE.fielddefs[obj.__msgtype__][1]]  # not the class constants
        return {k: _to_dict(getattr(obj, k)) for k in fields}
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (list, tuple)):
        return [_to_dict(v) for v in obj]
    return obj


def _close(a, b) -> bool:
    a, b = (v.tolist() if isinstance(v, np.ndarray) else v for v in (a, b))  # an int8[] decodes as an array
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_close(a[k], b[k]) for k in a)
    if isinstance(a, list):
        return len(a) == len(b) and all(_close(x, y) for x, y in zip(a, b))
    if isinstance(a, float) or isinstance(b, float):
        return math.isclose(float(a), float(b), rel_tol=1e-6, abs_tol=1e-9)
    return a == b


def _given(given, full) -> bool:
    """Every value in ``given`` (a partial message) is in ``full`` (a decoded one)."""
    given, full = (v.tolist() if isinstance(v, np.ndarray) else v for v in (given, full))
    if isinstance(given, dict):
        return all(_given(v, full[k]) for k, v in given.items())
    if isinstance(given, list):
        return len(given) == len(full) and all(_given(g, f) for g, f in zip(given, full))
    return _close(given, full)


SAMPLES = {
    "std_msgs/msg/String": {"data": '{"stage": 3, "x": null, "carrier": "c1"}'},
    "std_msgs/msg/Float64": {"data": 12.833},
    "std_msgs/msg/UInt32": {"data": 7},
    "rosgraph_msgs/msg/Clock": {"clock": {"sec": 100, "nanosec": 5}},
    "geometry_msgs/msg/PoseStamped": {"header": {"stamp": {"sec": 12, "nanosec": 500}, "frame_id": "map"},
                                      "pose": {"position": {"x": 1.5, "y": -2.25, "z": 0.0},
                                               "orientation": {"x": 0.0, "y": 0.0, "z": 0.6, "w": 0.8}}},
    "geometry_msgs/msg/PoseArray": {"header": {"stamp": {"sec": 1, "nanosec": 0}, "frame_id": "c1/base_link"},
                                    "poses": [{"position": {"x": float(i), "y": 2.0, "z": 0.0}} for i in range(3)]},
    "tf2_msgs/msg/TFMessage": {"transforms": [
        {"header": {"stamp": {"sec": 3, "nanosec": 0}, "frame_id": "map"}, "child_frame_id": "c1",
         "transform": {"translation": {"x": 4.0, "y": 5.0, "z": 0.0}, "rotation": {"w": 1.0}}},
        {"header": {"stamp": {"sec": 3, "nanosec": 0}, "frame_id": "map"}, "child_frame_id": "c2",
         "transform": {"translation": {"x": -1.0, "y": 0.5, "z": 0.0}, "rotation": {"z": 1.0}}}]},
    "nav_msgs/msg/Odometry": {"header": {"stamp": {"sec": 9, "nanosec": 1}, "frame_id": "odom"},
                              "child_frame_id": "base_link",
                              "pose": {"pose": {"position": {"x": 3.0, "y": 4.0}, "orientation": {"w": 1.0}},
                                       "covariance": [float(i) for i in range(36)]},
                              "twist": {"twist": {"linear": {"x": 0.5}}, "covariance": [0.0] * 36}},
    "visualization_msgs/msg/MarkerArray": {"markers": [
        {"header": {"frame_id": "map"}, "ns": "paths", "id": 2, "type": msgs.LINE_STRIP, "action": msgs.ADD,
         "pose": {"orientation": {"w": 1.0}}, "scale": {"x": 0.15}, "color": {"r": 0.1, "g": 0.5, "b": 0.7, "a": 1.0},
         "frame_locked": True, "points": [{"x": 0.0, "y": 0.0}, {"x": 10.0, "y": 5.0}],
         "colors": [{"r": 1.0, "a": 1.0}], "text": "c1 (2)"},
        {"header": {"frame_id": "map"}, "ns": "", "action": msgs.DELETEALL}]},
    "nav_msgs/msg/OccupancyGrid": {
        "header": {"stamp": {"sec": 14, "nanosec": 250_000_000}, "frame_id": "map"},
        "info": {"map_load_time": {"sec": 14, "nanosec": 0}, "resolution": 0.05, "width": 3, "height": 2,
                 "origin": {"position": {"x": -10.0, "y": 2.5}, "orientation": {"z": 0.6, "w": 0.8}}},
        "data": [-1, 0, 100, 50, -1, 0]},
    "octomap_msgs/msg/Octomap": {"header": {"stamp": {"sec": 21, "nanosec": 7}, "frame_id": "map"}, "binary": True,
                                 "id": "OcTree", "resolution": 0.1, "data": [0, 3, -1, 12, 64]},
    "sensor_msgs/msg/PointCloud2": {
        "header": {"stamp": {"sec": 5, "nanosec": 0}, "frame_id": "c1/lidar"}, "height": 1, "width": 2,
        "fields": [{"name": c, "offset": 4 * i, "datatype": 7, "count": 1} for i, c in enumerate("xyz")],
        "point_step": 12, "row_step": 24, "data": list(range(24)), "is_dense": True},
}


@pytest.mark.parametrize("typename", sorted(SAMPLES))
def test_payloads_decode_with_rosbags(typename):
    ours = msgs.encode(typename, SAMPLES[typename])
    assert ours[:4] == b"\x00\x01\x00\x00"
    theirs = _to_dict(STORE.deserialize_cdr(ours, typename))
    full = msgs.decode(typename, ours)  # every field, zeros filled in
    assert _close(full, theirs)
    assert _given(SAMPLES[typename], full)  # the values we gave, as given
    # Byte for byte what rosbags itself writes for the same message.
    assert STORE.serialize_cdr(STORE.deserialize_cdr(ours, typename), typename) == ours


def test_rosbags_payloads_decode_with_ours():
    """What a ROS 2 robot sends (here: rosbags' serialisation of an Odometry) reads back."""
    Odometry = STORE.types["nav_msgs/msg/Odometry"]
    m = STORE.types
    odom = Odometry(
        header=m["std_msgs/msg/Header"](stamp=m["builtin_interfaces/msg/Time"](sec=40, nanosec=250_000_000),
                                        frame_id="odom"),
        child_frame_id="base_link",
        pose=m["geometry_msgs/msg/PoseWithCovariance"](
            pose=m["geometry_msgs/msg/Pose"](position=m["geometry_msgs/msg/Point"](x=12.5, y=-3.0, z=0.0),
                                             orientation=m["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)),
            covariance=np.zeros(36)),
        twist=m["geometry_msgs/msg/TwistWithCovariance"](
            twist=m["geometry_msgs/msg/Twist"](linear=m["geometry_msgs/msg/Vector3"](x=1.0, y=0.0, z=0.0),
                                               angular=m["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)),
            covariance=np.zeros(36)))
    got = msgs.decode("nav_msgs/msg/Odometry", STORE.serialize_cdr(odom, "nav_msgs/msg/Odometry"))
    assert got["header"]["stamp"] == {"sec": 40, "nanosec": 250_000_000}
    assert got["pose"]["pose"]["position"] == {"x": 12.5, "y": -3.0, "z": 0.0}


@pytest.mark.parametrize("bad", [b"", b"\x00\x01\x00\x00", b"\x00\x00\x00\x00\x01", b"\x00\x01\x00\x00\xff\xff\xff\x7f"])
def test_bad_payloads_are_value_errors(bad):
    with pytest.raises(ValueError):
        msgs.decode("nav_msgs/msg/Odometry", bad)


def test_a_large_map_decodes_at_once_as_an_int8_array():
    """A 10^7-cell OccupancyGrid that rosbags serialised: its cells come back as one numpy int8
    array over the payload (a per-cell loop would take seconds), equal to rosbags' own."""
    import time

    m = STORE.types
    cells = np.random.default_rng(5).integers(-1, 101, size=10_000_000).astype(np.int8)
    grid = m["nav_msgs/msg/OccupancyGrid"](
        header=m["std_msgs/msg/Header"](stamp=m["builtin_interfaces/msg/Time"](sec=3, nanosec=7), frame_id="map"),
        info=m["nav_msgs/msg/MapMetaData"](
            map_load_time=m["builtin_interfaces/msg/Time"](sec=0, nanosec=0), resolution=0.05, width=4000,
            height=2500, origin=m["geometry_msgs/msg/Pose"](
                position=m["geometry_msgs/msg/Point"](x=-50.0, y=-20.0, z=0.0),
                orientation=m["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0))),
        data=cells)
    payload = bytes(STORE.serialize_cdr(grid, "nav_msgs/msg/OccupancyGrid"))
    start = time.perf_counter()
    got = msgs.decode("nav_msgs/msg/OccupancyGrid", payload)
    assert time.perf_counter() - start < 0.5
    assert isinstance(got["data"], np.ndarray) and got["data"].dtype == np.int8
    np.testing.assert_array_equal(got["data"], cells)
    assert (got["info"]["width"], got["info"]["height"]) == (4000, 2500)
    assert got["header"]["stamp"] == {"sec": 3, "nanosec": 7}
    start = time.perf_counter()
    assert msgs.encode("nav_msgs/msg/OccupancyGrid", got) == payload  # and back, in one copy
    assert time.perf_counter() - start < 0.5


def _map_payload(cells: int = 6) -> bytes:
    return msgs.encode("nav_msgs/msg/OccupancyGrid", {"info": {"width": cells, "height": 1},
                                                      "data": np.zeros(cells, dtype=np.int8)})


@pytest.mark.parametrize("bad", [
    _map_payload()[:-10] + (7).to_bytes(4, "little") + bytes(6),  # 7 cells announced, 6 there
    _map_payload()[:-2],                                          # cut in the cells
    _map_payload()[:30],                                          # cut in the header
], ids=["more-cells-announced", "cut-in-cells", "cut-in-header"])
def test_bad_maps_are_value_errors(bad):
    assert msgs.decode("nav_msgs/msg/OccupancyGrid", _map_payload())["data"].tolist() == [0] * 6
    with pytest.raises(ValueError, match="longer than the payload|malformed"):
        msgs.decode("nav_msgs/msg/OccupancyGrid", bad)
