"""Train a small CenterPoint-style BEV detector on a generated dataset through avdata's loaders, on CPU.

    python examples/train_bev_detector.py /tmp/avdata-bev            # generates the data if missing
    python examples/train_bev_detector.py /tmp/avdata-bev --epochs 6 --workers 2

Data: ``avdata.generators`` with the ``v2i-intersection`` town and traffic, the ego's 64-beam lidar only
(1024 azimuth steps, no camera, no infrastructure: quick to simulate), 8 scenes x 50 frames at 10 Hz;
scenes 0-5 train, 6-7 validate. ``FrameDataset`` gives each frame's cloud and boxes in the ego frame,
keeping the objects the ego lidar saw with at least 5 returns within 40 m.

Model: ``avdata.perception.bev`` (a CenterPoint-style BEV CNN; ``--checkpoint FILE`` saves it for studies,
which load it with ``avdata.perception.bev:load_checkpoint``).

Evaluation: nuScenes-style centre-distance AP (``avdata.eval.detection.nuscenes``) on the validation
frames, per trained class; boxes in the ego frame, so "distance to ego" is the box centre's norm.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from torch.utils.data import DataLoader

from avdata.eval.detection.nuscenes import DetectionBoxes, NuScenesDetectionConfig, evaluate_nuscenes_detection
from avdata.loaders import FrameDataset, FrameOptions, LabelFilter, collate_list
from avdata.perception.bev import CLASSES, RANGE_M, BevDetector, bev_features, decode, save_checkpoint, train
from avdata.schema import DatasetReader


def generate(root: Path, scenes: int, frames: int, seed: int) -> None:
    """The example's dataset: the v2i-intersection preset with only the ego lidar."""
    from avdata.generators.config import load_preset, scenario_from_dict
    from avdata.generators.driver import generate as run

    config = load_preset("v2i-intersection").to_dict()
    config.update(scenes=scenes, frames=frames, seed=seed)
    lidar = next(s for s in config["egos"][0]["sensors"] if s["kind"] == "lidar")
    lidar["lidar"]["azimuth_steps"] = 1024
    config["egos"][0]["sensors"] = [lidar]
    config["infrastructure"]["count"] = 0
    run(scenario_from_dict(config, "train_bev_detector"), root, workers=1, progress=True)


def datasets(root: Path) -> tuple[FrameDataset, FrameDataset]:
    scenes = sorted(DatasetReader(root).scenes)
    options = FrameOptions(sensors=("ego/lidar_top",), frame="ego",
                           labels=LabelFilter(classes=CLASSES, max_range_m=RANGE_M, visible_to="ego/lidar_top", min_points=5))
    return FrameDataset(root, options, scenes=scenes[:-2]), FrameDataset(root, options, scenes=scenes[-2:])


def detection_boxes(samples: list[str], boxes: list[np.ndarray], classes: list[np.ndarray],
                    scores: list[np.ndarray] | None) -> DetectionBoxes:
    box = np.concatenate(boxes).astype(np.float64).reshape(-1, 7)
    n = len(box)
    return DetectionBoxes(
        sample=np.concatenate([[s] * len(b) for s, b in zip(samples, boxes, strict=True)]).astype(str).reshape(n),
        translation_m=box[:, :3], size_m=box[:, 3:6], yaw_rad=box[:, 6], velocity_mps=np.full((n, 2), np.nan),
        name=np.array(CLASSES)[np.concatenate(classes).astype(np.int64)].reshape(n),
        score=np.concatenate(scores).astype(np.float64) if scores is not None else np.full(n, -1.0),
        attribute=np.full(n, "", dtype=object), num_points=np.full(n, 1 if scores is None else -1),
        ego_translation_m=box[:, :3],
    )


def evaluate(detector: BevDetector, val: FrameDataset, workers: int) -> dict[str, dict[str, float]]:
    model = detector.model.eval()
    samples, gt_boxes, gt_classes, pred_boxes, pred_classes, pred_scores = [], [], [], [], [], []
    for batch in DataLoader(val, batch_size=4, num_workers=workers, collate_fn=collate_list):
        heat_logits, reg_pred = model(bev_features(batch["points"]["ego/lidar_top"]))
        for i, (boxes, scores, cls) in enumerate(decode(heat_logits, reg_pred)):
            samples.append(f"{batch['scene'][i]}/{batch['frame_index'][i]}")
            gt_boxes.append(batch["boxes"][i].numpy())
            gt_classes.append(batch["labels"][i].numpy())
            pred_boxes.append(boxes.numpy())
            pred_classes.append(cls.numpy())
            pred_scores.append(scores.numpy())
    result = evaluate_nuscenes_detection(detection_boxes(samples, gt_boxes, gt_classes, None),
                                         detection_boxes(samples, pred_boxes, pred_classes, pred_scores),
                                         NuScenesDetectionConfig())
    summary = result.summary()
    report = {c: {k: summary[c][k] for k in ("AP", "AP@0.5", "AP@1", "AP@2", "AP@4", "trans_err", "scale_err",
                                             "orient_err")} for c in CLASSES}
    report["mean over trained classes"] = {"AP": float(np.mean([report[c]["AP"] for c in CLASSES]))}
    report["counts"] = {"val frames": len(samples), "gt boxes": int(sum(len(b) for b in gt_boxes)),
                        "predictions": int(sum(len(b) for b in pred_boxes))}
    return report


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("dataset", type=Path, help="dataset folder (generated there if it does not exist)")
    parser.add_argument("--epochs", type=int, default=6)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--scenes", type=int, default=8, help="scenes to generate (the last 2 validate)")
    parser.add_argument("--frames", type=int, default=50, help="frames per generated scene")
    parser.add_argument("--seed", type=int, default=11)
    parser.add_argument("--checkpoint", type=Path, help="save the trained detector here (avdata.perception.bev)")
    args = parser.parse_args()
    if not (args.dataset / "avdata.json").is_file():
        start = time.perf_counter()
        generate(args.dataset, args.scenes, args.frames, args.seed)
        print(f"generated {args.dataset} in {time.perf_counter() - start:.0f} s")
    train_frames, val = datasets(args.dataset)
    print(f"train frames {len(train_frames)}, validation frames {len(val)}, classes {CLASSES}")
    start = time.perf_counter()
    detector = train(train_frames, epochs=args.epochs, workers=args.workers, seed=args.seed, log=print)
    if args.checkpoint is not None:
        save_checkpoint(detector, args.checkpoint)
        print(f"wrote {args.checkpoint}")
    report = evaluate(detector, val, args.workers)
    print(f"trained in {time.perf_counter() - start:.0f} s; validation (nuScenes centre-distance AP, ego frame):")
    for name, metrics in report.items():
        print(f"  {name}: " + ", ".join(f"{k} {v:.3f}" if isinstance(v, float) else f"{k} {v}"
                                      for k, v in metrics.items()))


if __name__ == "__main__":
    main()
