"""The eval subcommands end to end through argparse (registered as avdata/cli.py registers them)."""

import argparse
import json

import pyarrow as pa
import pytest
from eval_nuscenes_synth import write_nuscenes
from eval_unified_synth import perfect_dataset

from avdata.errors import AvdataError
from avdata.eval.cli import add_eval_subparser


def _run(argv):
    parser = argparse.ArgumentParser(prog="avdata")
    add_eval_subparser(parser.add_subparsers(dest="command"))
    args = parser.parse_args(argv)
    return args.run(args)


def test_tracking_kitti_json_markdown_png(tmp_path, capsys):
    gt = tmp_path / "gt"
    (gt / "label_02").mkdir(parents=True)
    tr = tmp_path / "tr"
    tr.mkdir()
    lines, tr_lines = [], []
    for f in range(10):
        for i, x in ((0, 100), (1, 400)):
            lines.append(f"{f} {i} Car 0 0 0 {x + 5 * f} 100 {x + 5 * f + 80} 180 1 1 1 0 0 0 0")
            tr_lines.append(f"{f} {7 + i} Car 0 0 0 {x + 5 * f + 2} 100 {x + 5 * f + 82} 180 1 1 1 0 0 0 0 0.9")
        lines.append(f"{f} 2 Pedestrian 0 0 0 700 100 740 200 1 1 1 0 0 0 0")
    (gt / "label_02" / "0000.txt").write_text("\n".join(lines) + "\n")
    (gt / "evaluate_tracking.seqmap.training").write_text("0000 empty 000000 000010\n")
    (tr / "0000.txt").write_text("\n".join(tr_lines) + "\n")
    status = _run(["eval", "tracking", "--protocol", "kitti", str(gt), str(tr), "--classes", "car", "pedestrian",
                   "--json", str(tmp_path / "out.json"), "--markdown", str(tmp_path / "out.md"),
                   "--plots", str(tmp_path / "plots")])
    assert status == 0
    out = json.loads((tmp_path / "out.json").read_text())
    assert out["car"]["MOTA"] == pytest.approx(1.0) and out["car"]["IDSW"] == 0 and isinstance(out["car"]["MT"], int)
    assert out["car"]["HOTA"] > 0.9
    assert out["pedestrian"]["CLR_FN"] == 10 and out["pedestrian"]["DetRe"] == 0.0
    assert "| car |" in capsys.readouterr().out and (tmp_path / "out.md").read_text().startswith("| class |")
    assert (tmp_path / "plots" / "hota_car.png").stat().st_size > 1000


def test_detection_kitti_and_nuscenes(tmp_path):
    label, res = tmp_path / "label_2", tmp_path / "results"
    label.mkdir()
    res.mkdir()
    for k in range(3):
        (label / f"{k:06d}.txt").write_text("Car 0.00 0 0 100 100 200 200 1.5 1.6 4.0 0 1.5 10 0\n")
        (res / f"{k:06d}.txt").write_text("Car 0.00 0 0 101 100 201 200 1.5 1.6 4.0 0.05 1.5 10 0 0.9\n")
    assert _run(["eval", "detection", "--protocol", "kitti", str(tmp_path), str(res), "--classes", "Car",
                 "--json", str(tmp_path / "kitti.json"), "--plots", str(tmp_path / "p")]) == 0
    out = json.loads((tmp_path / "kitti.json").read_text())
    # 3 cars found: thresholds fill precision points 0..2 -> AP_11 = 1 / 11, AP_40 = 2 / 40 (in percent).
    assert out["Car"]["3d_moderate_AP11"] == pytest.approx(100 / 11)
    assert out["Car"]["bbox_easy_AP40"] == pytest.approx(5.0)
    nus = tmp_path / "nus"
    submission = write_nuscenes(nus, 7)
    assert _run(["eval", "detection", "--protocol", "nuscenes", str(nus / "v1.0-mini"), str(submission),
                 "--json", str(tmp_path / "nus.json")]) == 0
    out = json.loads((tmp_path / "nus.json").read_text())
    assert 0 < out["all"]["NDS"] < 1 and out["traffic_cone"]["attr_err"] is None
    assert _run(["eval", "tracking", "--protocol", "nuscenes", str(nus / "v1.0-mini"), str(nus / "tracking.json"),
                 "--json", str(tmp_path / "amota.json")]) == 0
    assert 0 < json.loads((tmp_path / "amota.json").read_text())["all"]["AMOTA"] < 1


def test_avdata_protocol_through_dataset_reader(tmp_path):
    root, rows = perfect_dataset(tmp_path / "ds")
    preds = tmp_path / "dets.json"
    preds.write_text(json.dumps(rows))
    assert _run(["eval", "detection", "--protocol", "avdata", str(root), str(preds), "--json", str(tmp_path / "d.json")]) == 0
    out = json.loads((tmp_path / "d.json").read_text())
    assert out["all"]["recall"] == 1.0 and out["all"]["FP"] == 0
    import pyarrow.parquet as pq

    pq.write_table(pa.Table.from_pylist(rows), tmp_path / "tracks.parquet")
    assert _run(["eval", "tracking", "--protocol", "avdata", str(root), str(tmp_path / "tracks.parquet"),
                 "--classes", "car", "--json", str(tmp_path / "t.json")]) == 0
    assert json.loads((tmp_path / "t.json").read_text())["car"]["HOTA"] == pytest.approx(1.0)
    with pytest.raises(AvdataError, match="does not exist"):
        _run(["eval", "detection", "--protocol", "avdata", str(tmp_path / "nope"), str(preds)])


def test_outputs_that_would_replace_an_input_or_each_other_are_refused(tmp_path):
    from avdata.errors import InputError

    root, rows = perfect_dataset(tmp_path / "ds")
    preds = tmp_path / "dets.json"
    preds.write_text(json.dumps(rows))
    manifest = (root / "avdata.json").read_bytes()
    base = ["eval", "detection", "--protocol", "avdata", str(root), str(preds)]
    # --json GT/avdata.json overwrote the dataset's manifest (exit 0)
    with pytest.raises(InputError, match=f"^{root / 'avdata.json'}: expected an output outside GT, got a path inside GT {root}$"):
        _run([*base, "--json", str(root / "avdata.json")])
    with pytest.raises(InputError, match=f"^{preds}: expected an output outside PRED, got PRED itself$"):
        _run([*base, "--markdown", str(preds)])
    with pytest.raises(InputError, match=f"^{preds}: expected an output outside --tracks, got --tracks itself$"):
        _run(["eval", "safety", str(root), "--tracks", str(preds), "--json", str(preds)])
    # --json X --markdown X kept only the Markdown table
    same = tmp_path / "same"
    with pytest.raises(InputError, match=f"^--json, --markdown, --plots: expected a different path for each, got "
                                         f"--json {same} --markdown {same}$"):
        _run([*base, "--json", str(same), "--markdown", str(tmp_path / "." / "same")])
    assert (root / "avdata.json").read_bytes() == manifest and json.loads(preds.read_text()) == rows
    assert not same.exists()
    # an output at a symbolic-link loop was a RuntimeError traceback from the comparison; the link is replaced
    (tmp_path / "loop_a").symlink_to(tmp_path / "loop_b")
    (tmp_path / "loop_b").symlink_to(tmp_path / "loop_a")
    assert _run([*base, "--json", str(tmp_path / "loop_a")]) == 0
    assert json.loads((tmp_path / "loop_a").read_text())["all"]["recall"] == 1.0


def test_a_kitti_gt_folder_takes_new_outputs_but_keeps_its_files(tmp_path):
    from avdata.errors import InputError

    (tmp_path / "label_2").mkdir()
    label = tmp_path / "label_2" / "000000.txt"
    label.write_text("Car 0.00 0 0 100 100 200 200 1.5 1.6 4.0 0 1.5 10 0\n")
    with pytest.raises(InputError, match=f"^{label}: expected an output outside GT, got a path inside GT {tmp_path}$"):
        _run(["eval", "detection", "--protocol", "kitti", str(tmp_path), str(tmp_path / "results"), "--classes", "Car",
              "--markdown", str(label)])
    assert label.read_text().startswith("Car ")
