"""The per-message fast paths KITTI conversion takes write the bytes the plain protobuf encoding gives.

Real inputs: the calibrations and samples in ../shared/realdata/kitti/object. The scene writer encodes a
pose or camera calibration once and reuses it at later times; each message it writes is compared here with
the message built and serialised whole by protobuf, for the real sensor poses and intrinsics.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms

from avdata.converters import ConvertConfig, run_conversion
from avdata.converters.kitti import KittiObjectConverter, common
from avdata.errors import AvdataError
from avdata.frames import Boxes3D, Transform, rotations
from avdata.schema import DatasetReader, SceneWriter
from avdata.schema import scene_writer as scene_writer_module
from avdata.schema.records import encode_visibility
from avdata.sources.kitti import KittiLabels, geometry, read_calib
from tests.realdata import REALDATA
from tests.schema.test_wire import timestamp

OBJECT = REALDATA / "kitti" / "object" / "training"
#: The three real samples (named, not listed: nothing is read at import)
CALIBS = [OBJECT / "calib" / f"{name}.txt" for name in ("000000", "000001", "000002")]


def captured_writer(path: Path, monkeypatch: pytest.MonkeyPatch) -> tuple[SceneWriter, list[tuple[str, bytes]]]:
    """A scene writer whose messages are also kept as (topic, bytes)."""
    written: list[tuple[str, bytes]] = []
    original = scene_writer_module.SceneWriter._write_parts

    def keep(self: SceneWriter, topic: str, message_type: type, parts: list[Any], time_ns: int) -> None:
        written.append((topic, b"".join(bytes(part) for part in parts)))
        original(self, topic, message_type, parts, time_ns)

    monkeypatch.setattr(scene_writer_module.SceneWriter, "_write_parts", keep)
    return SceneWriter(path, "s", on_written=lambda _: None), written


def whole_transform(parent: str, child: str, pose: Transform, time_ns: int) -> bytes:
    w, x, y, z = pose.quat_wxyz().tolist()
    tx, ty, tz = pose.translation.tolist()
    message = FrameTransform(timestamp=timestamp(time_ns), parent_frame_id=parent,
                             child_frame_id=child, translation={"x": tx, "y": ty, "z": tz},
                             rotation={"x": x, "y": y, "z": z, "w": w})
    return FrameTransforms(transforms=[message]).SerializeToString()


def test_repeated_poses_are_written_as_protobuf_encodes_them(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    poses = [geometry.velo_T_sensors(read_calib(path)) for path in CALIBS]
    writer, written = captured_writer(tmp_path / "s.mcap", monkeypatch)
    expected = []
    times = [0, 1, 100_000_000, 1_000_000_007, 2**62 + 3]
    static = geometry.velo_T_sensors(read_calib(CALIBS[-1]))["imu"]
    with writer:
        writer.add_static_transform("ego", "ego/imu_static", static)
        for k, time_ns in enumerate(times):
            # The same poses again at later times (a cache hit), and another calibration's (a miss).
            for name, pose in poses[k % len(poses)].items():
                writer.add_transform("ego", f"ego/{name}", time_ns, pose)
                expected.append(whole_transform("ego", f"ego/{name}", pose, time_ns))
            writer.add_transform("world", "ego", time_ns, Transform.identity())
            expected.append(whole_transform("world", "ego", Transform.identity(), time_ns))
        writer.add_frame(0, 0, scene_writer_module.ObjectLabels.empty("world"))
        tf = [data for topic, data in written if topic == "/tf"]
        assert tf == expected
        # What the index builds its frame tree from: the same transforms, decoded.
        assert [FrameTransforms(transforms=[t]).SerializeToString() for t in writer._stamped_tfs] == expected
    assert (tmp_path / "s.mcap").is_file()
    # /tf_static (written as the first chunk goes out), stamped with the first time written (0): the same encoding.
    assert [data for topic, data in written if topic == "/tf_static"] == [whole_transform("ego", "ego/imu_static",
                                                                                        static, 0)]


def test_a_changed_pose_at_the_same_time_is_still_refused(tmp_path: Path) -> None:
    pose = geometry.velo_T_sensors(read_calib(CALIBS[0]))["cam2"]
    moved = Transform(rotation=pose.rotation, translation=pose.translation + np.array([0.0, 0.0, 1e-6]))
    with pytest.raises(AvdataError, match="two different poses of 'ego/cam2'"), SceneWriter(tmp_path / "s.mcap", "s") as writer:
        writer.add_transform("ego", "ego/cam2", 5, pose)
        writer.add_transform("ego", "ego/cam2", 5, pose)  # the same pose again is fine
        writer.add_transform("ego", "ego/cam2", 5, moved)
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("path", CALIBS, ids=[p.name for p in CALIBS])
def test_camera_calibrations_are_written_as_protobuf_encodes_them(path: Path, tmp_path: Path,
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    calib = read_calib(path)
    writer, written = captured_writer(tmp_path / "s.mcap", monkeypatch)
    expected = []
    with writer:
        for time_ns in (0, 7, 3_000_000_000):
            for i in range(4):
                K = geometry.intrinsics(calib, i)
                P = calib.P[i]
                options: list[dict[str, Any]] = [{}, {"D": np.zeros(0), "R": np.eye(3), "P": P},
                                                  {"D": np.array([0.1, -0.2, 0.0, 0.0, 0.01]),
                                                   "distortion_model": "plumb_bob"}]
                for option in options:
                    writer.add_camera_calibration(f"ego/cam{i}", time_ns, K, 1242, 375, **option)
                    D, R = option.get("D"), option.get("R", np.eye(3))
                    whole = CameraCalibration(
                        timestamp=timestamp(time_ns), frame_id=f"ego/cam{i}", width=1242,
                        height=375, distortion_model=option.get("distortion_model", "plumb_bob"),
                        D=[] if D is None else D.tolist(), K=K.ravel().tolist(), R=R.ravel().tolist(),
                        P=option.get("P", np.hstack([K, np.zeros((3, 1))])).ravel().tolist())
                    expected.append(whole.SerializeToString())
        writer.add_frame(0, 0, scene_writer_module.ObjectLabels.empty("world"))
    assert [data for topic, data in written if topic.endswith("/calibration")] == expected


def test_single_rotation_check_agrees_with_the_batched_one() -> None:
    rotations_real = np.stack([pose.rotation for path in CALIBS
                               for pose in geometry.velo_T_sensors(read_calib(path)).values()])
    batched = rotations.quat_wxyz_from_matrix(rotations_real)
    for rotation, quat in zip(rotations_real, batched, strict=True):
        np.testing.assert_array_equal(rotations.quat_wxyz_from_matrix(rotation), quat)
    reflection = rotations_real[0] @ np.diag([1.0, 1.0, -1.0])
    for improper in (reflection, reflection[None]):
        with pytest.raises(AvdataError, match=r"expected a proper rotation \(det \+1\), got an improper one"):
            rotations.quat_wxyz_from_matrix(improper)


def test_object_samples_are_listed_again_by_a_new_run(tmp_path: Path) -> None:
    src = tmp_path / "src"
    for folder in ("calib", "label_2", "velodyne", "image_2"):
        shutil.copytree(OBJECT / folder, src / "training" / folder)
    converter = KittiObjectConverter(ConvertConfig(src=src, dst=tmp_path / "out", quiet=True))
    assert not run_conversion(converter).n_errors
    assert DatasetReader(tmp_path / "out").scene("training_000000").metadata["kitti_sample_ids"] == [0, 1, 2]
    for folder, suffix in (("calib", ".txt"), ("label_2", ".txt"), ("velodyne", ".bin"), ("image_2", ".png")):
        shutil.copyfile(OBJECT / folder / f"000001{suffix}", src / "training" / folder / f"000003{suffix}")
    result = run_conversion(converter)  # the same converter: the source is listed again
    assert result.written == ["training_000000"] and not result.n_errors
    assert DatasetReader(tmp_path / "out").scene("training_000000").metadata["kitti_sample_ids"] == [0, 1, 2, 3]


def _random_labels(rng: np.random.Generator, n: int) -> KittiLabels:
    """``n`` label rows with random boxes (every third a DontCare), rotation_y over the whole circle and its edges."""
    rotation_y = rng.uniform(-np.pi, np.pi, n)
    rotation_y[::5] = rng.choice([0.0, np.pi / 2, -np.pi / 2, np.pi, -np.pi], len(rotation_y[::5]))
    cls = np.array([("DontCare" if k % 3 == 2 else "Car") for k in range(n)])
    return KittiLabels(line=np.arange(1, n + 1), frame=np.full(n, -1), track_id=np.full(n, -1), cls=cls,
                       truncated=rng.uniform(0, 1, n), occluded=rng.integers(0, 4, n), alpha=rng.uniform(-3, 3, n),
                       bbox=rng.uniform(0, 1000, (n, 4)), hwl=rng.uniform(0.3, 15, (n, 3)),
                       location=rng.uniform(-50, 50, (n, 3)), rotation_y=rotation_y, score=np.full(n, np.nan))


def test_frames_converted_in_one_batch_equal_each_frame_converted_alone() -> None:
    """camera_labels batches the frames of one transform; every array equals the frame's own conversion, bit for bit."""
    rng = np.random.default_rng(14)
    transforms = [geometry.velo_T_sensors(read_calib(path))["cam0"]
                  for path in sorted((REALDATA / "kitti" / "object" / "training" / "calib").glob("*.txt"))]
    transforms.append(Transform.from_euler("ZYX", [2.5, -0.3, 0.1], [3.0, -1.0, 40.0]))
    sizes = rng.integers(0, 30, 60)
    frames = [(_random_labels(rng, int(n)), np.array([f"{k:06d}_{j}" for j in range(n)]), transforms[k % len(transforms)])
              for k, n in enumerate(sizes)]
    extras = [{"kitti_sample": float(k)} for k in range(len(frames))]
    batched = common.camera_labels(frames, tracking=False, extras=extras)
    for frame, extra, (objects, visibility) in zip(frames, extras, batched, strict=True):
        [(alone_objects, alone_visibility)] = common.camera_labels([frame], tracking=False, extras=[extra])
        for name in ("center", "size_lwh", "quat_wxyz"):
            assert getattr(objects.boxes, name).tobytes() == getattr(alone_objects.boxes, name).tobytes(), name
        assert objects.boxes.ids.tolist() == alone_objects.boxes.ids.tolist()
        assert objects.boxes.classes.tolist() == alone_objects.boxes.classes.tolist()
        assert objects.extras == alone_objects.extras and objects.source_classes.tolist() == alone_objects.source_classes.tolist()
        assert encode_visibility("ego/cam2", 0, 0, visibility) == encode_visibility("ego/cam2", 0, 0, alone_visibility)
    # And the same as the boxes converted as the converters did before batching: one frame, one call each.
    for (labels, _, world_T_cam0), (objects, _) in zip(frames, batched, strict=True):
        rows = labels.select(labels.cls != "DontCare")
        expected = Boxes3D.from_kitti_camera(rows.hwl, rows.location, rows.rotation_y, "ego/cam0").transform(
            world_T_cam0, "world")
        assert objects.boxes.quat_wxyz.tobytes() == expected.quat_wxyz.tobytes()
        assert objects.boxes.center.tobytes() == expected.center.tobytes()
