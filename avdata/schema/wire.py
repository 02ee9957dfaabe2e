"""Protobuf wire format by hand: messages a scene holds one of per pose, box or sensor message, and bytes fields.

Point clouds and images are written as their other fields plus the data field (:func:`with_bytes_field`); a cloud's
points are read back as a view of that field (:func:`bytes_field_span`), never copied.

Built by the protobuf library, a box's viewer marker and a pose's FrameTransform are message objects filled field
by field, once per box and per pose: a visible share of a conversion's CPU that writing the bytes directly mostly
saves (figures in docs/performance.md). Field numbers are the Foxglove schemas'. Pose and timestamp encodings are
the library's byte for byte (proto3 leaves out a +0.0 double, a 0 integer and an empty string; -0.0 is written);
markers write every double, zeros included, which every proto3 reader decodes to the same message
(``tests/schema/test_wire.py`` checks both against the library).
"""

from __future__ import annotations

import functools
import math
import struct
from collections.abc import Sequence
from typing import Final

import numpy as np

from avdata.frames import Boxes3D
from avdata.schema.mcap.records import Buffer
from avdata.schema.protos import ObjectLabelsMsg
from avdata.schema.records import (
    CLASS_COLORS,
    OTHER_CLASS_COLOR,
    FrameInfo,
    ObjectLabels,
    canonical_jsons,
    required_ids_and_classes,
)

#: One-byte varints, the lengths of nearly every field here.
_SMALL_VARINTS: Final = [bytes([n]) for n in range(128)]
_XYZ: Final = struct.Struct("<BdBdBd")
_XYZW: Final = struct.Struct("<BdBdBdBd")
_DOUBLE_TAGS: Final = (0x09, 0x11, 0x19, 0x21)  # fields 1-4, wire type 1 (64-bit)


def varint(value: int) -> bytes:
    """``value`` as a protobuf varint (a negative int64 as its 10-byte two's complement, as protobuf writes it)."""
    if 0 <= value < 128:
        return _SMALL_VARINTS[value]
    value &= (1 << 64) - 1
    out = bytearray()
    while value > 0x7F:
        out.append(value & 0x7F | 0x80)
        value >>= 7
    out.append(value)
    return bytes(out)


def length_delimited(tag: bytes, body: bytes) -> bytes:
    """A length-delimited field: its tag byte(s), the body's length, the body."""
    return tag + varint(len(body)) + body


def with_bytes_field(serialized_rest: bytes, field_number: int, payload: Buffer) -> list[Buffer]:
    """Buffers encoding a message = ``serialized_rest`` plus bytes field ``field_number`` = ``payload``.

    Protobuf merges repeated top-level fields, so the concatenation is a valid encoding of the
    whole message; the payload (a point cloud's memory) is written without a copy.
    """
    size = payload.nbytes if isinstance(payload, memoryview) else len(payload)
    return [serialized_rest + varint(field_number << 3 | 2) + varint(size), payload]


def read_varint(data: memoryview, position: int) -> tuple[int, int]:
    """(value, position after it) of the varint at ``position``."""
    if position < len(data) and data[position] < 0x80:  # one-byte varints: nearly every key here
        return data[position], position + 1
    result = 0
    shift = 0
    while True:
        if position >= len(data) or shift > 63:
            raise ValueError(f"truncated or overlong varint at byte {position}")
        byte = data[position]
        position += 1
        result |= (byte & 0x7F) << shift
        if not byte & 0x80:
            return result, position
        shift += 7


def bytes_field_span(view: memoryview, field_number: int) -> tuple[bytes, int, int]:
    """(the other fields' bytes, start and end of bytes field ``field_number``'s value) of an encoded message.

    The reader's side of :func:`with_bytes_field`: walks the top-level fields, so a point cloud's data is a view
    of the file, never a copy.

    Raises:
        ValueError: a truncated or malformed encoding.
    """
    rest: list[memoryview] = []
    span = (0, 0)
    position = 0
    size = len(view)
    while position < size:
        start = position
        key, position = read_varint(view, position)
        wire_type = key & 7
        if wire_type == 0:
            _, position = read_varint(view, position)
        elif wire_type == 1:
            position += 8
        elif wire_type == 5:
            position += 4
        elif wire_type == 2:
            if position < size and view[position] < 0x80:  # the one-byte lengths of the small fields, inline
                length = view[position]
                position += 1
            else:
                length, position = read_varint(view, position)
            if key >> 3 == field_number and position + length <= len(view):
                span = (position, position + length)
                position += length
                continue
            position += length
        else:
            raise ValueError(f"unsupported protobuf wire type {wire_type} at byte {start}")
        if position > len(view):
            raise ValueError(f"field {key >> 3} at byte {start} runs past the message's end ({len(view)} bytes)")
        rest.append(view[start:position])
    return b"".join(rest), span[0], span[1]


@functools.lru_cache(maxsize=256)
def timestamp_field(time_ns: int) -> bytes:
    """Field 1 = ``google.protobuf.Timestamp`` of ``time_ns``: the first field of every stamped Foxglove message.

    Cached: a frame's sensor messages, pose and labels mostly share a few times.
    """
    seconds, nanos = divmod(time_ns, 1_000_000_000)
    body = (b"\x08" + varint(seconds) if seconds else b"") + (b"\x10" + varint(nanos) if nanos else b"")
    return b"\x0a" + _SMALL_VARINTS[len(body)] + body


def _doubles(values: Sequence[float]) -> bytes:
    """Fields 1, 2, ... = ``values`` as doubles, each left out when +0.0 (bitwise), as proto3 writes them."""
    if all(values):  # no zero of either sign (the common case): one pack
        if len(values) == 3:
            x, y, z = values
            return _XYZ.pack(0x09, x, 0x11, y, 0x19, z)
        x, y, z, w = values
        return _XYZW.pack(0x09, x, 0x11, y, 0x19, z, 0x21, w)
    return b"".join(struct.pack("<Bd", tag, value) for tag, value in zip(_DOUBLE_TAGS, values, strict=False)
                    if value or math.copysign(1.0, value) < 0.0)


def frame_transform_body(parent: str, child: str, translation: Sequence[float], quat_wxyz: Sequence[float]) -> bytes:
    """A FrameTransform's fields after the timestamp: parent and child frame ids, translation, rotation."""
    w, x, y, z = quat_wxyz
    return b"".join((
        length_delimited(b"\x12", parent.encode()) if parent else b"",
        length_delimited(b"\x1a", child.encode()) if child else b"",
        length_delimited(b"\x22", _doubles(translation)),
        length_delimited(b"\x2a", _doubles((x, y, z, w))),
    ))


# ----------------------------------------------------------------------------------- labels
def object_labels(info: FrameInfo, labels: ObjectLabels) -> tuple[bytes, list[str], list[str]]:
    """(encoding, attributes JSON, extras JSON) of one frame's ObjectLabels message (avdata.schema.protos).

    The bytes of ``encode_object_labels(info, labels).SerializeToString()``. Protobuf writes fields in number
    order, each on its own, so the message is the concatenation of its parts: the scalars (proto3 leaves out
    zeros) and the packed doubles by hand, a box array as its little-endian bytes; the string fields and the
    sensor times through the library, whose C loop encodes a string faster than Python can.

    Raises:
        ValueError: a frame index outside uint32 or a time outside int64 (protobuf refuses them too).
    """
    boxes = labels.boxes
    ids, classes = required_ids_and_classes(boxes)
    time_ns, frame_index = int(info.timestamp_ns), int(info.frame_index)
    if not (0 <= frame_index < 1 << 32 and -(1 << 63) <= time_ns < 1 << 63):
        raise ValueError(f"expected a uint32 frame index and an int64 time, got frame {frame_index} at {time_ns} ns")
    attributes = [] if labels.attributes is None else canonical_jsons(labels.attributes)
    extras = [] if labels.extras is None else canonical_jsons(labels.extras)
    out = [b"\x08" + varint(time_ns) if time_ns else b"",
           length_delimited(b"\x12", boxes.frame.encode()) if boxes.frame else b"",
           b"\x18" + varint(frame_index) if frame_index else b"",
           b"\x20\x01" if info.annotated else b""]
    sensors = info.sensor_timestamps_ns
    if len(ids):
        out.append(ObjectLabelsMsg(sensor_frames=list(sensors), sensor_timestamps_ns=[int(t) for t in sensors.values()],
                                   ids=ids.tolist(), classes=classes.tolist(),
                                   source_classes=labels.source_classes.tolist()).SerializeToString())
        for tag, values in ((b"\x52", boxes.center), (b"\x5a", boxes.size_lwh), (b"\x62", boxes.quat_wxyz),
                            (b"\x6a", boxes.velocity), (b"\x72", labels.acceleration),
                            (b"\x7a", labels.angular_velocity)):
            if values is not None:
                out.append(length_delimited(tag, np.ascontiguousarray(values, dtype="<f8").tobytes()))
        if attributes or extras:
            out.append(ObjectLabelsMsg(attributes_json=attributes, extras_json=extras).SerializeToString())
    elif sensors:
        out.append(ObjectLabelsMsg(sensor_frames=list(sensors),
                                   sensor_timestamps_ns=[int(t) for t in sensors.values()]).SerializeToString())
    return b"".join(out), attributes, extras


# ----------------------------------------------------------------------------------- markers
#: Per box, the fixed-size parts of its marker: the cube's pose and size, then the label's pose. Each double
#: follows its tag byte; the runs of bytes are the submessages' tags and lengths.
_MARKER_LAYOUT: Final = np.dtype([
    ("cube_pose", "u1", 4),  # CubePrimitive.pose (67 bytes), Pose.position (27 bytes)
    ("center", [("tag", "u1"), ("value", "<f8")], 3),
    ("orientation_head", "u1", 2),  # Pose.orientation (36 bytes)
    ("quat_xyzw", [("tag", "u1"), ("value", "<f8")], 4),
    ("size_head", "u1", 2),  # CubePrimitive.size (27 bytes)
    ("size", [("tag", "u1"), ("value", "<f8")], 3),
    ("text_pose", "u1", 4),  # TextPrimitive.pose (40 bytes), Pose.position (27 bytes)
    ("label_position", [("tag", "u1"), ("value", "<f8")], 3),
    ("text_orientation", "u1", 11),  # Pose.orientation = (w 1.0)
])
_CUBE_BYTES: Final = 98  # cube_pose .. size
_MARKER_BYTES: Final = _MARKER_LAYOUT.itemsize
_TEXT_ORIENTATION: Final = b"\x12\x09" + struct.pack("<Bd", 0x21, 1.0)
#: TextPrimitive fields 2-5: billboard, font size 12, scale invariant, white.
_TEXT_STYLE: Final = (b"\x10\x01" + struct.pack("<Bd", 0x19, 12.0) + b"\x20\x01"
                      + length_delimited(b"\x2a", _XYZW.pack(0x09, 1.0, 0x11, 1.0, 0x19, 1.0, 0x21, 1.0)))


def _color_field(rgb: tuple[float, float, float]) -> bytes:
    """CubePrimitive field 3 = Color(r, g, b, a 0.4)."""
    return length_delimited(b"\x1a", _doubles((*rgb, 0.4)))


def scene_update(time_ns: int, boxes: Boxes3D) -> bytes:
    """The viewer markers of a frame's labelled boxes at ``time_ns``, as a SceneUpdate.

    It deletes every entity, then draws each box as a cube in its class's colour with a "<class> <id>"
    label above it.
    """
    ids, classes = required_ids_and_classes(boxes)
    center, quat_wxyz, size_lwh = boxes.center, boxes.quat_wxyz, boxes.size_lwh
    stamp = timestamp_field(time_ns)
    out = [length_delimited(b"\x0a", stamp + b"\x10\x01")]  # deletions: SceneEntityDeletion(type ALL)
    n = len(boxes)
    if not n:
        return out[0]
    packed = np.empty(n, dtype=_MARKER_LAYOUT)
    packed["cube_pose"] = (0x0A, 67, 0x0A, 27)
    packed["orientation_head"] = (0x12, 36)
    packed["size_head"] = (0x12, 27)
    packed["text_pose"] = (0x0A, 40, 0x0A, 27)
    packed["text_orientation"] = np.frombuffer(_TEXT_ORIENTATION, dtype=np.uint8)
    for name in ("center", "size", "label_position"):
        packed[name]["tag"] = _DOUBLE_TAGS[:3]
    packed["quat_xyzw"]["tag"] = _DOUBLE_TAGS
    packed["center"]["value"] = center
    packed["quat_xyzw"]["value"] = quat_wxyz[:, [1, 2, 3, 0]]
    packed["size"]["value"] = size_lwh
    packed["label_position"]["value"] = center
    packed["label_position"]["value"][:, 2] = center[:, 2] + size_lwh[:, 2] / 2.0 + 0.3
    fixed = packed.tobytes()
    # Every entity starts with the same timestamp and frame id (SceneEntity fields 1, 2).
    entity_head = stamp + (length_delimited(b"\x12", boxes.frame.encode()) if boxes.frame else b"")
    color_fields: dict[str, bytes] = {}
    start = 0
    for object_id, cls in zip([str(i) for i in ids.tolist()], [str(c) for c in classes.tolist()], strict=True):
        color = color_fields.get(cls)
        if color is None:
            color = color_fields[cls] = _color_field(CLASS_COLORS.get(cls, OTHER_CLASS_COLOR))
        label = f"{cls} {object_id}".encode()
        cube = fixed[start:start + _CUBE_BYTES] + color
        text = fixed[start + _CUBE_BYTES:start + _MARKER_BYTES] + _TEXT_STYLE + length_delimited(b"\x32", label)
        start += _MARKER_BYTES
        body = b"".join((entity_head, length_delimited(b"\x1a", object_id.encode()), length_delimited(b"\x42", cube),
                         length_delimited(b"\x6a", text)))
        out.append(length_delimited(b"\x12", body))
    return b"".join(out)
