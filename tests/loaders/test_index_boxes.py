"""The Parquet index's boxes (``avdata.schema.index``, owned with the loaders): full orientation in
world and ego, equal to Boxes3D moved through the graph, and no silent NaN when a lookup fails."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from avdata.errors import InputError
from avdata.frames import Boxes3D, Transform
from avdata.schema import DatasetReader, DatasetWriter, ObjectLabels
from tests.loaders.conftest import PERIOD_NS, T0_NS, boxes_world, world_T_ego


def test_index_boxes_equal_boxes_moved_through_the_graph(dataset: Path) -> None:
    reader = DatasetReader(dataset)
    objects = reader.objects().to_pydict()
    for scene in ("v2i", "offset"):
        graph = reader.frame_graph(scene)
        rows = [i for i, s in enumerate(objects["scene"]) if s == scene]
        assert rows
        for k in range(3):
            t = T0_NS + k * PERIOD_NS
            mine = [i for i in rows if objects["frame_index"][i] == k]
            expected_world = boxes_world(k)
            expected_ego = expected_world.to("ego", graph, t)
            for suffix, expected in (("world", expected_world), ("ego", expected_ego)):
                center = np.array([[objects[f"{a}_{suffix}_m"][i] for a in "xyz"] for i in mine])
                quat = np.array([[objects[f"q{c}_{suffix}"][i] for c in "wxyz"] for i in mine])
                yaw = np.array([objects[f"yaw_{suffix}_rad"][i] for i in mine])
                np.testing.assert_allclose(center, expected.center, atol=1e-9)
                np.testing.assert_allclose(np.abs(np.sum(quat * expected.quat_wxyz, axis=1)), 1.0, atol=1e-12)
                np.testing.assert_allclose(np.cos(yaw), np.cos(expected.yaw()), atol=1e-12)
                np.testing.assert_allclose(np.sin(yaw), np.sin(expected.yaw()), atol=1e-12)


def test_index_keeps_roll_and_pitch_of_tilted_boxes(tmp_path: Path) -> None:
    world_T_box = Transform.from_euler("ZYX", np.array([[0.3, 0.25, -0.15]]))
    boxes = Boxes3D(center=[[5.0, 1.0, 0.5]], size_lwh=[[4.0, 2.0, 1.5]], quat_wxyz=world_T_box.quat_wxyz(),
                    frame="world", ids=["tilted"], classes=["car"])
    ego_pose = Transform.from_euler("ZYX", np.array([1.0, 0.0, 0.1]), np.array([2.0, 3.0, 0.0]))
    with DatasetWriter(tmp_path / "ds", source="test") as writer, writer.scene("s") as scene:
        scene.add_agent("ego", kind="vehicle", origin="rear axle")
        scene.add_transform("world", "ego", T0_NS, ego_pose)
        scene.add_frame(0, T0_NS, ObjectLabels(boxes=boxes), {})
    row = DatasetReader(tmp_path / "ds").objects().to_pylist()[0]
    for suffix, rotation in (("world", world_T_box.rotation[0]),
                             ("ego", ego_pose.rotation.T @ world_T_box.rotation[0])):
        quat = np.array([row[f"q{c}_{suffix}"] for c in "wxyz"])
        np.testing.assert_allclose(Transform.from_quat_wxyz(quat).rotation, rotation, atol=1e-12)
        assert row[f"yaw_{suffix}_rad"] == pytest.approx(np.arctan2(rotation[1, 0], rotation[0, 0]), abs=1e-12)


def test_a_frame_outside_the_ego_poses_is_an_error_naming_scene_frame_and_time(tmp_path: Path) -> None:
    late_ns = T0_NS + 5 * PERIOD_NS
    # The writer refuses the frame (the index could not place it) before anything of it is written.
    with pytest.raises(InputError, match=rf"gap.mcap: frame 1 at {late_ns} ns: the ego frame 'ego' cannot be placed: "
                                         rf"no pose of 'ego' in 'world' at {late_ns} ns"):
        with DatasetWriter(tmp_path / "ds", source="test") as writer, writer.scene("gap") as scene:
            scene.add_agent("ego", kind="vehicle", origin="rear axle")
            scene.add_transform("world", "ego", T0_NS, world_T_ego(T0_NS))
            scene.add_transform("world", "ego", T0_NS + PERIOD_NS, world_T_ego(T0_NS + PERIOD_NS))
            scene.add_frame(0, T0_NS, ObjectLabels(boxes=boxes_world(0)), {})
            scene.add_frame(1, late_ns, ObjectLabels(boxes=boxes_world(1)), {})
