"""avdata's own protobuf schemas, declared in code and embedded in every MCAP file.

Declaring the ``.proto`` as a ``FileDescriptorProto`` here (instead of running ``protoc``) keeps the
install pip-only; the MCAP writer embeds the descriptor set, so any protobuf-aware MCAP tool decodes
these messages without avdata. The layout is columnar — one repeated field per attribute, N
objects each — because readers turn them straight into numpy arrays.

Equivalent ``.proto`` (package ``avdata``, proto3)::

    message ObjectLabels {              // topic /labels/objects, one per frame
      int64  timestamp_ns = 1;          // the frame's time
      string frame_id = 2;              // reference frame of every box and vector below
      uint32 frame_index = 3;           // 0, 1, 2 ... within the scene
      bool   annotated = 4;             // false: a frame whose objects were not labelled
      repeated string sensor_frames = 5;        // the sensors sampled for this frame ...
      repeated int64  sensor_timestamps_ns = 6; // ... and the time of each one's message
      repeated string ids = 7;
      repeated string classes = 8;              // unified taxonomy
      repeated string source_classes = 9;       // the source's own class string, verbatim
      repeated double center = 10;              // 3 per object, metres
      repeated double size_lwh = 11;            // 3 per object, metres
      repeated double quat_wxyz = 12;           // 4 per object
      repeated double velocity = 13;            // 3 per object or empty; NaN = unknown
      repeated double acceleration = 14;        // 3 per object or empty
      repeated double angular_velocity = 15;    // 3 per object or empty
      repeated string attributes_json = 16;     // one JSON object per object or empty
      repeated string extras_json = 17;         // source-specific numbers, one JSON object per object or empty
    }
    message VisibilityLabels {          // topic /<agent>/<sensor>/visibility
      int64  timestamp_ns = 1;
      string sensor_frame = 2;
      uint32 frame_index = 3;
      repeated string object_ids = 4;
      repeated bool   in_fov = 5;
      repeated int32  n_points = 6;              // -1 unknown
      repeated float  visible_fraction = 7;      // NaN unknown
      repeated int32  occlusion = 8;             // 0 none, 1 partly, 2 largely, 3 fully or unknown
      repeated float  truncation = 9;            // 0..1, NaN unknown
      repeated float  box2d_xyxy = 10;           // 4 per object, pixels; NaN when not in the image
      repeated float  visible_pixel_fraction = 11;
      repeated float  alpha_rad = 12;            // observation angle (KITTI), NaN unknown
      repeated float  ignore_regions_xyxy = 13;  // 4 per region (KITTI DontCare)
    }
"""

from __future__ import annotations

from google.protobuf import descriptor_pb2, descriptor_pool
from google.protobuf.message_factory import GetMessageClass

_LABEL_REPEATED = descriptor_pb2.FieldDescriptorProto.LABEL_REPEATED
_LABEL_OPTIONAL = descriptor_pb2.FieldDescriptorProto.LABEL_OPTIONAL
_T = descriptor_pb2.FieldDescriptorProto

_OBJECT_LABELS_FIELDS = [
    ("timestamp_ns", 1, _T.TYPE_INT64, False),
    ("frame_id", 2, _T.TYPE_STRING, False),
    ("frame_index", 3, _T.TYPE_UINT32, False),
    ("annotated", 4, _T.TYPE_BOOL, False),
    ("sensor_frames", 5, _T.TYPE_STRING, True),
    ("sensor_timestamps_ns", 6, _T.TYPE_INT64, True),
    ("ids", 7, _T.TYPE_STRING, True),
    ("classes", 8, _T.TYPE_STRING, True),
    ("source_classes", 9, _T.TYPE_STRING, True),
    ("center", 10, _T.TYPE_DOUBLE, True),
    ("size_lwh", 11, _T.TYPE_DOUBLE, True),
    ("quat_wxyz", 12, _T.TYPE_DOUBLE, True),
    ("velocity", 13, _T.TYPE_DOUBLE, True),
    ("acceleration", 14, _T.TYPE_DOUBLE, True),
    ("angular_velocity", 15, _T.TYPE_DOUBLE, True),
    ("attributes_json", 16, _T.TYPE_STRING, True),
    ("extras_json", 17, _T.TYPE_STRING, True),
]

_VISIBILITY_FIELDS = [
    ("timestamp_ns", 1, _T.TYPE_INT64, False),
    ("sensor_frame", 2, _T.TYPE_STRING, False),
    ("frame_index", 3, _T.TYPE_UINT32, False),
    ("object_ids", 4, _T.TYPE_STRING, True),
    ("in_fov", 5, _T.TYPE_BOOL, True),
    ("n_points", 6, _T.TYPE_INT32, True),
    ("visible_fraction", 7, _T.TYPE_FLOAT, True),
    ("occlusion", 8, _T.TYPE_INT32, True),
    ("truncation", 9, _T.TYPE_FLOAT, True),
    ("box2d_xyxy", 10, _T.TYPE_FLOAT, True),
    ("visible_pixel_fraction", 11, _T.TYPE_FLOAT, True),
    ("alpha_rad", 12, _T.TYPE_FLOAT, True),
    ("ignore_regions_xyxy", 13, _T.TYPE_FLOAT, True),
]


def _build_file() -> descriptor_pb2.FileDescriptorProto:
    file_proto = descriptor_pb2.FileDescriptorProto(name="avdata/labels.proto", package="avdata", syntax="proto3")
    for message_name, fields in (("ObjectLabels", _OBJECT_LABELS_FIELDS), ("VisibilityLabels", _VISIBILITY_FIELDS)):
        message = file_proto.message_type.add(name=message_name)
        for name, number, field_type, repeated in fields:
            message.field.add(
                name=name,
                number=number,
                type=field_type,
                label=_LABEL_REPEATED if repeated else _LABEL_OPTIONAL,
                json_name=name,
            )
    return file_proto


_POOL = descriptor_pool.DescriptorPool()
_POOL.Add(_build_file())

ObjectLabelsMsg = GetMessageClass(_POOL.FindMessageTypeByName("avdata.ObjectLabels"))
VisibilityLabelsMsg = GetMessageClass(_POOL.FindMessageTypeByName("avdata.VisibilityLabels"))
