"""Honest resume for the nuScenes converter on the real Lyft tables (nuScenes schema): the fingerprint
covers every table and the scene's sensor files, present or missing."""

from __future__ import annotations

import json
from pathlib import Path

from avdata.converters import ConvertConfig, run_conversion
from avdata.converters.nuscenes import NuScenesConverter
from avdata.schema import SceneReader
from tests.realdata import REALDATA

LYFT = REALDATA / "nuscenes_schema" / "lyft" / "v1.01-train"
SCENE = "host-a101-lidar0-1240710366399037786-1240710391298976894"


def layout(root: Path) -> Path:
    (root / "v1.01-train").mkdir(parents=True)
    for table in (LYFT / "v1.01-train").glob("*.json"):
        (root / "v1.01-train" / table.name).symlink_to(table)
    (root / "maps").symlink_to(LYFT / "maps")
    return root


def convert(src: Path, dst: Path):
    return run_conversion(NuScenesConverter(ConvertConfig(src=src, dst=dst, quiet=True,
                                                          options=NuScenesConverter.Options(version="v1.01-train"))))


def test_nuscenes_rerun_skips_and_a_table_edit_or_a_new_sensor_file_rewrites(tmp_path: Path) -> None:
    src, dst = layout(tmp_path / "src"), tmp_path / "out"
    first = convert(src, dst)
    assert first.written == [SCENE]
    recorded = SceneReader(dst / "scenes" / f"{SCENE}.mcap").metadata["resume"]
    n_sample_data = len(json.loads((LYFT / "v1.01-train" / "sample_data.json").read_text()))
    assert recorded["task"] == "nuscenes" and recorded["n_sources"] == 13 + n_sample_data
    assert recorded["options"] == {"compression": "none", "version": "v1.01-train", "variant": "nuscenes"}
    assert convert(src, dst).complete == [SCENE]

    annotations = json.loads((LYFT / "v1.01-train" / "sample_annotation.json").read_text())
    annotations[0]["size"][0] += 0.01
    table = src / "v1.01-train" / "sample_annotation.json"
    table.unlink()
    table.write_text(json.dumps(annotations))
    assert convert(src, dst).written == [SCENE]
    assert convert(src, dst).complete == [SCENE]

    # A sensor file that was missing (a partial download) and now exists rewrites the scene.
    first_file = json.loads((LYFT / "v1.01-train" / "sample_data.json").read_text())[0]["filename"]
    assert not (LYFT / first_file).exists()
    (src / first_file).parent.mkdir(parents=True)
    (src / first_file).write_bytes(b"\xff\xd8 not really a jpeg")
    assert convert(src, dst).written == [SCENE]
