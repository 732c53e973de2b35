"""The standard ROS 2 message types the mission uses, and their CDR encoding (no ROS needed).

Every type is a table of ``(field, type)`` in declaration order, as in its ``.msg`` file of ROS 2
Jazzy (``common_interfaces``, ``rcl_interfaces``, ``geometry2``). A field type is a primitive
(``bool``, ``int8``, ``uint8``, ``int32``, ``uint32``, ``float32``, ``float64``, ``string``), a
message type name (``geometry_msgs/msg/Point``), a sequence ``T[]`` or a fixed array ``T[n]``.
tests/test_ros2_msgs.py checks every table against rosbags' Jazzy typestore and every
:data:`RIHS01` hash against its ``hash_rihs01``.

CDR as ROS 2 writes it (XCDR1, little endian): the 4-byte encapsulation header ``00 01 00 00``,
then the fields, each primitive aligned to its size from the end of the header; a string is a
uint32 length (NUL included), its bytes and a NUL; a sequence a uint32 count then its elements; a
fixed array only its elements.

Messages are plain dicts (field -> value, nested messages as dicts, sequences as lists); a field
left out is encoded as its zero value, and :func:`decode` returns every field. An ``int8[]`` or
``uint8[]`` (an OccupancyGrid's cells, an OctoMap's tree, a PointCloud2's points) decodes as a
read-only numpy array over the payload, and an
``int8[]`` or ``uint8[]`` may be given as bytes or a numpy array: a large map is one copy, never
a loop over its cells.
"""
from __future__ import annotations

import struct

import numpy as np

#: Field tables (ROS 2 Jazzy).
TYPES: dict[str, tuple[tuple[str, str], ...]] = {
    "builtin_interfaces/msg/Time": (("sec", "int32"), ("nanosec", "uint32")),
    "builtin_interfaces/msg/Duration": (("sec", "int32"), ("nanosec", "uint32")),
    "std_msgs/msg/Header": (("stamp", "builtin_interfaces/msg/Time"), ("frame_id", "string")),
    "std_msgs/msg/String": (("data", "string"),),
    "std_msgs/msg/Float64": (("data", "float64"),),
    "std_msgs/msg/UInt32": (("data", "uint32"),),
    "std_msgs/msg/ColorRGBA": (("r", "float32"), ("g", "float32"), ("b", "float32"), ("a", "float32")),
    "geometry_msgs/msg/Point": (("x", "float64"), ("y", "float64"), ("z", "float64")),
    "geometry_msgs/msg/Vector3": (("x", "float64"), ("y", "float64"), ("z", "float64")),
    "geometry_msgs/msg/Quaternion": (("x", "float64"), ("y", "float64"), ("z", "float64"), ("w", "float64")),
    "geometry_msgs/msg/Pose": (("position", "geometry_msgs/msg/Point"),
                               ("orientation", "geometry_msgs/msg/Quaternion")),
    "geometry_msgs/msg/PoseStamped": (("header", "std_msgs/msg/Header"), ("pose", "geometry_msgs/msg/Pose")),
    "geometry_msgs/msg/PoseArray": (("header", "std_msgs/msg/Header"), ("poses", "geometry_msgs/msg/Pose[]")),
    "geometry_msgs/msg/Transform": (("translation", "geometry_msgs/msg/Vector3"),
                                    ("rotation", "geometry_msgs/msg/Quaternion")),
    "geometry_msgs/msg/TransformStamped": (("header", "std_msgs/msg/Header"), ("child_frame_id", "string"),
                                           ("transform", "geometry_msgs/msg/Transform")),
    "geometry_msgs/msg/Twist": (("linear", "geometry_msgs/msg/Vector3"), ("angular", "geometry_msgs/msg/Vector3")),
    "geometry_msgs/msg/PoseWithCovariance": (("pose", "geometry_msgs/msg/Pose"), ("covariance", "float64[36]")),
    "geometry_msgs/msg/TwistWithCovariance": (("twist", "geometry_msgs/msg/Twist"), ("covariance", "float64[36]")),
    "nav_msgs/msg/Odometry": (("header", "std_msgs/msg/Header"), ("child_frame_id", "string"),
                              ("pose", "geometry_msgs/msg/PoseWithCovariance"),
                              ("twist", "geometry_msgs/msg/TwistWithCovariance")),
    "tf2_msgs/msg/TFMessage": (("transforms", "geometry_msgs/msg/TransformStamped[]"),),
    "sensor_msgs/msg/CompressedImage": (("header", "std_msgs/msg/Header"), ("format", "string"),
                                        ("data", "uint8[]")),
    "visualization_msgs/msg/UVCoordinate": (("u", "float32"), ("v", "float32")),
    "visualization_msgs/msg/MeshFile": (("filename", "string"), ("data", "uint8[]")),
    "visualization_msgs/msg/Marker": (
        ("header", "std_msgs/msg/Header"), ("ns", "string"), ("id", "int32"), ("type", "int32"), ("action", "int32"),
        ("pose", "geometry_msgs/msg/Pose"), ("scale", "geometry_msgs/msg/Vector3"), ("color", "std_msgs/msg/ColorRGBA"),
        ("lifetime", "builtin_interfaces/msg/Duration"), ("frame_locked", "bool"),
        ("points", "geometry_msgs/msg/Point[]"), ("colors", "std_msgs/msg/ColorRGBA[]"),
        ("texture_resource", "string"), ("texture", "sensor_msgs/msg/CompressedImage"),
        ("uv_coordinates", "visualization_msgs/msg/UVCoordinate[]"), ("text", "string"), ("mesh_resource", "string"),
        ("mesh_file", "visualization_msgs/msg/MeshFile"), ("mesh_use_embedded_materials", "bool")),
    "visualization_msgs/msg/MarkerArray": (("markers", "visualization_msgs/msg/Marker[]"),),
    "rosgraph_msgs/msg/Clock": (("clock", "builtin_interfaces/msg/Time"),),
    "nav_msgs/msg/MapMetaData": (("map_load_time", "builtin_interfaces/msg/Time"), ("resolution", "float32"),
                                 ("width", "uint32"), ("height", "uint32"), ("origin", "geometry_msgs/msg/Pose")),
    "nav_msgs/msg/OccupancyGrid": (("header", "std_msgs/msg/Header"), ("info", "nav_msgs/msg/MapMetaData"),
                                   ("data", "int8[]")),
    "sensor_msgs/msg/PointField": (("name", "string"), ("offset", "uint32"), ("datatype", "uint8"),
                                   ("count", "uint32")),
    "sensor_msgs/msg/PointCloud2": (("header", "std_msgs/msg/Header"), ("height", "uint32"), ("width", "uint32"),
                                    ("fields", "sensor_msgs/msg/PointField[]"), ("is_bigendian", "bool"),
                                    ("point_step", "uint32"), ("row_step", "uint32"), ("data", "uint8[]"),
                                    ("is_dense", "bool")),
    # octomap_msgs (its Jazzy release; not in common_interfaces): OctoMap's tree as octomap_server
    # publishes it, ``data`` the stream of OcTree::writeBinaryData (binary) or writeData (full)
    "octomap_msgs/msg/Octomap": (("header", "std_msgs/msg/Header"), ("binary", "bool"), ("id", "string"),
                                 ("resolution", "float64"), ("data", "int8[]")),
}

#: The ``.msg`` text of the types above that rosbags' Jazzy typestore lacks (tests register them
#: there to check the tables and hashes).
MSG_TEXT = {
    "octomap_msgs/msg/Octomap": "std_msgs/Header header\nbool binary\nstring id\nfloat64 resolution\nint8[] data\n",
}

#: RIHS01 type hashes (REP 2011) of the types published or read, as rosidl generates them for
#: Jazzy (tests/test_ros2_msgs.py: equal to rosbags' ``hash_rihs01``).
RIHS01: dict[str, str] = {
    "std_msgs/msg/String": "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
    "std_msgs/msg/Float64": "RIHS01_705ba9c3d1a09df43737eb67095534de36fd426c0587779bda2bc51fe790182a",
    "std_msgs/msg/UInt32": "RIHS01_a5c874829b752bc5fa190024b0ad76f578cc278271e855c7d02a818b3516fb4a",
    "geometry_msgs/msg/PoseStamped": "RIHS01_10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8",
    "geometry_msgs/msg/PoseArray": "RIHS01_af0cc36d190e104d546d168d6b39df04fa4b4ccecf59cb4c9ed328d3d5004aa0",
    "tf2_msgs/msg/TFMessage": "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087",
    "visualization_msgs/msg/MarkerArray": "RIHS01_86cb8800b6fb05b5eff1abd7a56f62a5641d3ae9a1c29e78e67e704f1d067dcf",
    "nav_msgs/msg/Odometry": "RIHS01_3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0",
    "rosgraph_msgs/msg/Clock": "RIHS01_692f7a66e93a3c83e71765d033b60349ba68023a8c689a79e48078bcb5c58564",
    "nav_msgs/msg/OccupancyGrid": "RIHS01_8d348150c12913a31ee0ec170fbf25089e4745d17035792a1ba94d6f0bc0cfc7",
    "sensor_msgs/msg/PointCloud2": "RIHS01_9198cabf7da3796ae6fe19c4cb3bdd3525492988c70522628af5daa124bae2b5",
    "octomap_msgs/msg/Octomap": "RIHS01_9891a19a05b70ec20aa8f45db3f8300b9ab80afff32c61c549d25087da9625b0",
}

#: The encapsulation header of little-endian plain CDR.
CDR_LE = b"\x00\x01\x00\x00"

# Marker.type and Marker.action values.
ARROW, CUBE, SPHERE, CYLINDER, LINE_STRIP, LINE_LIST, CUBE_LIST, SPHERE_LIST, POINTS, TEXT_VIEW_FACING = range(10)
ADD, DELETE, DELETEALL = 0, 2, 3

_PRIMITIVES = {"bool": "?", "uint8": "B", "int8": "b", "int16": "h", "uint16": "H", "int32": "i", "uint32": "I",
               "int64": "q", "uint64": "Q", "float32": "f", "float64": "d"}


def dds_name(typename: str) -> str:
    """The DDS name of a type, as rmw_zenoh writes it in keys and tokens:
    ``std_msgs/msg/String`` -> ``std_msgs::msg::dds_::String_``."""
    pkg, kind, name = typename.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


def type_hash(typename: str) -> str:
    h = RIHS01.get(typename)
    if not h:
        raise KeyError(f"no RIHS01 hash for {typename}")
    return h


def _split(ftype: str) -> tuple[str, int | None]:
    """(element type, None = scalar, -1 = sequence, n = fixed array of n)."""
    if ftype.endswith("[]"):
        return ftype[:-2], -1
    if ftype.endswith("]"):
        base, n = ftype[:-1].split("[")
        return base, int(n)
    return ftype, None


def zero(ftype: str):
    """The zero value of a field type."""
    base, count = _split(ftype)
    if count == -1:
        return []
    if count is not None:
        return [zero(base)] * count
    if base == "string":
        return ""
    if base == "bool":
        return False
    if base in _PRIMITIVES:
        return 0.0 if base.startswith("float") else 0
    return {name: zero(t) for name, t in TYPES[base]}


#: Element types written in one piece from bytes or a numpy array (no alignment inside).
_BYTE_ARRAYS = {"int8": np.int8, "uint8": np.uint8}
_STRUCTS = {base: struct.Struct("<" + fmt) for base, fmt in _PRIMITIVES.items()}
#: Encodings of left-out fields: (field type, offset mod 8) -> bytes (a zero value's encoding
#: depends only on where it starts, modulo the largest alignment).
_ZERO_BYTES: dict[tuple[str, int], bytes] = {}


class _Writer:
    def __init__(self):
        self.buf = bytearray()

    def align(self, n: int) -> None:
        pad = -len(self.buf) % n
        if pad:
            self.buf += b"\0" * pad

    def prim(self, base: str, value) -> None:
        s = _STRUCTS[base]
        pad = -len(self.buf) % s.size
        if pad:
            self.buf += b"\0" * pad
        self.buf += s.pack(value)

    def zero(self, ftype: str) -> None:
        """A left-out field: its zero value's encoding, cached."""
        key = (ftype, len(self.buf) % 8)
        data = _ZERO_BYTES.get(key)
        if data is None:
            w = _Writer()
            w.buf = bytearray(key[1])
            w.value(ftype, zero(ftype))
            data = _ZERO_BYTES[key] = bytes(w.buf[key[1]:])
        self.buf += data

    def string(self, value: str) -> None:
        data = value.encode()
        self.prim("uint32", len(data) + 1)
        self.buf += data + b"\0"

    def value(self, ftype: str, value) -> None:
        base, count = _split(ftype)
        if count is None:
            self.one(base, value)
            return
        if base in _BYTE_ARRAYS and isinstance(value, (bytes, bytearray, np.ndarray)):
            # one-byte elements need no alignment: the cells of a map go in one copy
            data = value if isinstance(value, (bytes, bytearray)) else \
                np.ascontiguousarray(value, dtype=_BYTE_ARRAYS[base]).tobytes()
            self._count(ftype, count, len(data))
            self.buf += data
            return
        items = list(value)
        self._count(ftype, count, len(items))
        for item in items:
            self.one(base, item)

    def _count(self, ftype: str, count: int, n: int) -> None:
        """A sequence's length prefix; a fixed array's length checked."""
        if count == -1:
            self.prim("uint32", n)
        elif n != count:
            raise ValueError(f"{ftype}: expected {count} values, found {n}")

    def one(self, base: str, value) -> None:
        if base == "string":
            self.string(value)
        elif base in _PRIMITIVES:
            self.prim(base, value)
        else:
            self.message(base, value)

    def message(self, typename: str, msg: dict) -> None:
        for name, ftype in TYPES[typename]:
            if name in msg:
                self.value(ftype, msg[name])
            else:
                self.zero(ftype)


def encode(typename: str, msg: dict) -> bytes:
    """The CDR payload (encapsulation header included) of ``msg``, a dict of ``typename``'s fields."""
    w = _Writer()
    w.message(typename, msg)
    return CDR_LE + bytes(w.buf)


class _Reader:
    def __init__(self, data: memoryview):
        self.data = data
        self.pos = 0

    def prim(self, base: str):
        fmt = "<" + _PRIMITIVES[base]
        size = struct.calcsize(fmt)
        self.pos += -self.pos % size
        (value,) = struct.unpack_from(fmt, self.data, self.pos)
        self.pos += size
        return value

    def one(self, base: str):
        if base == "string":
            n = self.prim("uint32")
            if n == 0 or self.pos + n > len(self.data):
                raise ValueError("CDR string out of bounds")
            text = bytes(self.data[self.pos:self.pos + n - 1]).decode()
            self.pos += n
            return text
        if base in _PRIMITIVES:
            return self.prim(base)
        return {name: self.value(ftype) for name, ftype in TYPES[base]}

    def value(self, ftype: str):
        base, count = _split(ftype)
        if count is None:
            return self.one(base)
        n = self.prim("uint32") if count == -1 else count
        if n > len(self.data):
            raise ValueError("CDR sequence longer than the payload")
        if base in _BYTE_ARRAYS:
            if self.pos + n > len(self.data):
                raise ValueError(f"CDR {base} sequence longer than the payload")
            # a read-only view of the payload: a map's cells or a cloud's points are never copied
            # or looped over
            cells = np.frombuffer(self.data, dtype=_BYTE_ARRAYS[base], count=n, offset=self.pos)
            self.pos += n
            return cells
        return [self.one(base) for _ in range(n)]


def decode(typename: str, payload: bytes) -> dict:
    """The dict of a CDR payload of ``typename`` (ValueError if it is not one: wrong header,
    truncated, malformed)."""
    payload = bytes(payload)
    if payload[:2] != CDR_LE[:2]:
        raise ValueError(f"{typename}: expected little-endian CDR (header 00 01), found {payload[:4].hex()}")
    r = _Reader(memoryview(payload)[4:])
    try:
        return r.one(typename)
    except (struct.error, UnicodeDecodeError) as exc:
        raise ValueError(f"{typename}: malformed CDR payload ({exc})") from None
