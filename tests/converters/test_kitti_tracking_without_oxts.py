"""KITTI tracking sequences shared without oxts (AB3DMOT's val 0006, 0008): identity poses, stated, one warning."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from avdata.converters import ConvertConfig, run_conversion
from avdata.converters.kitti import KittiTrackingConverter
from avdata.schema import DatasetReader
from avdata.schema.validate import validate_dataset
from tests.realdata import REALDATA

_DETECTIONS = REALDATA / "kitti_tracking_detections"


def test_sequences_without_oxts_convert_with_identity_poses(tmp_path):
    for folder in ("calib", "label_02"):
        (tmp_path / "src" / "training" / folder).mkdir(parents=True)
    for seq in ("0006", "0008"):
        (tmp_path / "src" / "training" / "calib" / f"{seq}.txt").symlink_to(_DETECTIONS / "calib_object_keys" / f"{seq}.txt")
        (tmp_path / "src" / "training" / "label_02" / f"{seq}.txt").symlink_to(_DETECTIONS / "label_02" / f"{seq}.txt")
    dst = tmp_path / "out"
    result = run_conversion(KittiTrackingConverter(ConvertConfig(src=tmp_path / "src", dst=dst, quiet=True)))
    assert validate_dataset(dst) == []
    reader = DatasetReader(dst)
    frames = reader.frames().to_pydict()
    # 0006 has labels up to frame 269, 0008 up to 389 (their seqmap lengths 270 and 390)
    assert frames["scene"].count("training_0006") == 270 and frames["scene"].count("training_0008") == 390
    np.testing.assert_array_equal(frames["world_T_ego_qw"], 1.0)
    np.testing.assert_array_equal(frames["world_T_ego_x_m"], 0.0)
    assert reader.scene("training_0006").metadata["world_origin"].startswith("no oxts file")
    objects = reader.objects().to_pydict()
    np.testing.assert_array_equal(objects["x_world_m"], objects["x_ego_m"])
    oxts = [p for p in result.problems if p.message.startswith("no oxts file: every ego pose is the identity")]
    assert [(p.severity, Path(p.file).name) for p in oxts] == [("warning", "0006.txt"), ("warning", "0008.txt")]
    assert result.n_errors == 0
