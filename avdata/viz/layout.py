"""A Foxglove layout for a unified dataset (the JSON that Foxglove's "Import layout" reads).

The layout file format (Foxglove app, Layouts > Import from file): ``configById`` maps panel ids
``"<PanelType>!<suffix>"`` to panel settings, ``layout`` is a binary split tree whose leaves are those ids
(``{"first", "second", "direction": "row" | "column", "splitPercentage"}``), plus ``globalVariables``,
``userNodes`` and ``playbackConfig``. Panels here:

* ``3D!scene``: every point cloud (coloured by its intensity field, else height), the label cubes of
  ``/labels/markers`` (coloured by class in the file itself), the frame tree, display frame = the ego;
* ``Image!<camera>``: each camera with its ``CameraCalibration`` topic, so the label cubes are projected on it;
* ``RawMessages!labels``: ``/labels/objects`` (avdata's columnar labels).
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import TypedDict

from avdata.errors import InputError
from avdata.outputs import write_atomically
from avdata.schema import DatasetReader, topics

__all__ = ["PANEL_ID", "foxglove_layout", "write_layout"]

#: Foxglove panel ids: the panel type, "!", and a suffix.
PANEL_ID = re.compile(r"^[A-Za-z0-9]+![A-Za-z0-9_-]+$")


class _Split(TypedDict):
    """A node of Foxglove's layout tree: its area split between two children."""

    first: _Node
    second: _Node
    direction: str
    splitPercentage: float


#: A leaf of the layout tree is a panel id.
_Node = str | _Split


def _split(direction: str, first: _Node, second: _Node, percentage: float) -> _Split:
    return {"first": first, "second": second, "direction": direction, "splitPercentage": percentage}


def _column(items: list[str]) -> _Node:
    """Items stacked top to bottom in equal parts."""
    if len(items) == 1:
        return items[0]
    return _split("column", items[0], _column(items[1:]), 100.0 / len(items))


def _suffix(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_-]", "_", name)


def foxglove_layout(root: str | Path, scene: str | None = None) -> dict[str, object]:
    """The layout for ``scene`` (default: the first) of the dataset at ``root``, as Foxglove's JSON document."""
    ds = DatasetReader(root)
    if not ds.scenes:
        raise InputError(f"{root}: expected at least one scene, got none")
    name = ds.scenes[0] if scene is None else scene  # not `scene or`: --scene '' is refused
    if name not in ds.scenes:
        raise InputError(f"{root}: expected a scene of {ds.scenes}, got {name!r}")
    reader = ds.scene(name)
    present = set(reader.topics)
    sensors = reader.sensors()
    display = reader.ego_frame() or "world"
    point_topics = {}
    for sensor in sorted(sensors):
        topic = topics.sensor_topic(sensor, topics.POINTS_SUFFIX)
        if topic in present:
            fields = reader.points(sensor, int(reader.times(topic)[0])).dtype.names or ()
            color_field = "intensity" if "intensity" in fields else "z"
            point_topics[topic] = {"visible": True, "pointSize": 2, "colorField": color_field, "colorMode": "colormap",
                                   "colorMap": "turbo"}
    three_d = {
        "followTf": display,
        "followMode": "follow-pose",
        "scene": {"transforms": {"showLabel": False, "axisScale": 1}},
        "transforms": {},
        "topics": {**point_topics, topics.MARKERS: {"visible": True}} if topics.MARKERS in present else point_topics,
        "layers": {"grid": {"layerId": "foxglove.Grid", "visible": True, "frameId": display, "size": 100, "divisions": 20}},
        "cameraState": {"distance": 60, "perspective": True, "phi": 50, "thetaOffset": 90, "target": [0, 0, 0],
                        "targetOffset": [0, 0, 0], "targetOrientation": [0, 0, 0, 1], "fovy": 45, "near": 0.5, "far": 5000},
    }
    config: dict[str, object] = {"3D!scene": three_d}
    images = []
    for sensor, spec in sorted(sensors.items()):
        image_topic = topics.sensor_topic(sensor, topics.IMAGE_SUFFIX)
        calibration_topic = topics.sensor_topic(sensor, topics.CALIBRATION_SUFFIX)
        if spec.get("kind") != "camera" or image_topic not in present:
            continue
        panel = f"Image!{_suffix(sensor)}"
        mode: dict[str, object] = {"imageTopic": image_topic, "annotations": {}, "synchronize": False}
        if calibration_topic in present:
            mode["calibrationTopic"] = calibration_topic
        config[panel] = {"imageMode": mode, "topics": {topics.MARKERS: {"visible": True}} if topics.MARKERS in present else {},
                         "foxglovePanelTitle": sensor}
        images.append(panel)
    right = list(images)
    if topics.OBJECTS in present:
        config["RawMessages!labels"] = {"topicPath": topics.OBJECTS, "diffEnabled": False, "diffMethod": "custom",
                                        "diffTopicPath": "", "showFullMessageForDiff": False, "expansion": "none"}
        right.append("RawMessages!labels")
    layout: _Node = "3D!scene" if not right else _split("row", "3D!scene", _column(right), 60.0)
    return {"configById": config, "globalVariables": {}, "userNodes": {}, "playbackConfig": {"speed": 1.0},
            "layout": layout}


def write_layout(root: str | Path, out: str | Path, scene: str | None = None) -> Path:
    """Writes :func:`foxglove_layout` as JSON to ``out``; returns the path."""
    out = Path(out)
    write_atomically(out, json.dumps(foxglove_layout(root, scene), indent=2) + "\n")
    return out
