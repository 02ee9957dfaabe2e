"""``avdata audit``: split overlap (V2V4Real-style), calibration residuals, agents without poses, duplicate ids."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np

from avdata.audit import audit
from avdata.converters import ConvertConfig, run_conversion
from avdata.converters.dair_v2x import DairV2xConverter
from avdata.converters.opv2v import Opv2vConverter
from avdata.frames import Boxes3D, Transform
from avdata.schema import DatasetWriter, ObjectLabels, topics
from avdata.schema.records import FrameInfo, encode_object_labels
from tests.converters.opv2v_fixtures import build_v2v4real
from tests.converters.test_dair_v2x import build_dair


def test_audit_findings_one_line_each(tmp_path: Path) -> None:
    scenario = build_v2v4real(tmp_path / "v2v")
    shutil.copytree(scenario, tmp_path / "v2v" / "train" / scenario.name)  # the published train/test overlap
    run_conversion(Opv2vConverter(ConvertConfig(src=tmp_path / "v2v", dst=tmp_path / "v2v_out", quiet=True)))
    build_dair(tmp_path / "dair", skew=2e-5)
    run_conversion(DairV2xConverter(ConvertConfig(src=tmp_path / "dair", dst=tmp_path / "dair_out", quiet=True)))
    synthetic = tmp_path / "synthetic"
    with DatasetWriter(synthetic, source="test") as writer, writer.scene("s0", {"split": "train"}) as scene:
        scene.add_agent("ego", kind="vehicle", origin="test")
        scene.add_agent("cav_2", kind="vehicle", origin="test")  # never posed
        scene.add_transform("world", "ego", 0, Transform.identity())
        boxes = Boxes3D.from_yaw(np.zeros((2, 3)), np.ones((2, 3)), np.zeros(2), "world", ids=["7", "7"],
                                 classes=["car", "car"])
        # avdata's writer refuses duplicate ids (SceneWriter.add_frame); a file from another writer (or an older
        # avdata) can still hold them, so the label message is written the way such a writer would.
        foreign = encode_object_labels(FrameInfo(frame_index=0, timestamp_ns=0), ObjectLabels(boxes=boxes))
        scene._write_parts(topics.OBJECTS, type(foreign), [foreign.SerializeToString()], 0)
    findings = [str(f) for f in audit([tmp_path / "v2v_out", tmp_path / "dair_out", synthetic])]
    assert len(findings) == 5, findings
    assert any("clip 'testoutput_CAV_data_2022-03-15-09-54-40_0' appears in splits ['test', 'train']" in f for f in findings)
    assert sum("dair_out: coop_017314: calibration" in f and "off orthonormal" in f for f in findings) == 2
    assert any("synthetic: s0: agent 'cav_2' has no pose in world at 1 of 1 frames" in f for f in findings)
    assert any("synthetic: s0: frame 0: duplicate object ids ['7']" in f for f in findings)
    clean = run_conversion(Opv2vConverter(ConvertConfig(src=tmp_path / "v2v", dst=tmp_path / "v2v_test_only",
                                                        quiet=True, scenes=(f"test.{scenario.name}",))))
    assert clean.written and audit([tmp_path / "v2v_test_only"]) == []
    proc = subprocess.run([sys.executable, "-m", "avdata.cli", "audit", str(tmp_path / "v2v_out")],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 1 and len(proc.stdout.splitlines()) == 1 and "Traceback" not in proc.stderr
    proc = subprocess.run([sys.executable, "-m", "avdata.cli", "audit", str(tmp_path / "v2v_test_only")],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0 and proc.stdout == ""
