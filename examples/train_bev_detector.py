"""Train a small CenterPoint-style BEV detector on a generated dataset through avdata's loaders, on CPU.

    python examples/train_bev_detector.py /tmp/avdata-bev            # generates the data if missing
    python examples/train_bev_detector.py /tmp/avdata-bev --epochs 6 --workers 2

Data: ``avdata.generators`` with the ``v2i-intersection`` town and traffic, the ego's 64-beam lidar only
(1024 azimuth steps, no camera, no infrastructure: quick to simulate), 8 scenes x 50 frames at 10 Hz;
scenes 0-5 train, 6-7 validate. ``FrameDataset`` gives each frame's cloud and boxes in the ego frame,
keeping the objects the ego lidar saw with at least 5 returns within 40 m.

Model: points are scattered into a 0.5 m BEV grid over [-40, 40] m (4 features per cell: log count,
max height, mean height, mean intensity), a 3-level CNN, and CenterNet heads at 1 m: per-class
heatmap (focal loss), sub-cell offset, z, log size and (sin, cos) of yaw (L1).

Evaluation: nuScenes-style centre-distance AP (``avdata.eval.detection.nuscenes``) on the validation
frames, per trained class; boxes in the ego frame, so "distance to ego" is the box centre's norm.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn
from torch.utils.data import DataLoader

from avdata.eval.detection.nuscenes import DetectionBoxes, NuScenesDetectionConfig, evaluate_nuscenes_detection
from avdata.loaders import FrameDataset, FrameOptions, LabelFilter, collate_list
from avdata.schema import DatasetReader

CLASSES = ("car", "pedestrian")
RANGE_M = 40.0
CELL_M = 0.5
GRID = int(2 * RANGE_M / CELL_M)  # 160 input cells per side
STRIDE = 2  # heads at 1 m cells
OUT = GRID // STRIDE
OUT_CELL_M = CELL_M * STRIDE


def generate(root: Path, scenes: int, frames: int, seed: int) -> None:
    """The example's dataset: the v2i-intersection preset with only the ego lidar."""
    from avdata.generators.config import load_preset, scenario_from_dict
    from avdata.generators.scenario import generate as run

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


# ----------------------------------------------------------------- model
def bev_features(clouds: list[torch.Tensor]) -> torch.Tensor:
    """(B, 4, GRID, GRID) cell features from B clouds (N, >=4) x, y, z, intensity in the ego frame."""
    features = torch.zeros(len(clouds), 4, GRID * GRID)
    for b, cloud in enumerate(clouds):
        ix = ((cloud[:, 0] + RANGE_M) / CELL_M).floor().long()
        iy = ((cloud[:, 1] + RANGE_M) / CELL_M).floor().long()
        inside = (ix >= 0) & (ix < GRID) & (iy >= 0) & (iy < GRID)
        cell = (iy * GRID + ix)[inside]
        z, intensity = cloud[inside, 2], cloud[inside, 3]
        count = torch.zeros(GRID * GRID).index_add_(0, cell, torch.ones_like(z))
        safe = count.clamp(min=1.0)
        features[b, 0] = torch.log1p(count)
        features[b, 1] = torch.full((GRID * GRID,), -3.0).scatter_reduce(0, cell, z, "amax") * (count > 0)
        features[b, 2] = torch.zeros(GRID * GRID).index_add_(0, cell, z) / safe
        features[b, 3] = torch.zeros(GRID * GRID).index_add_(0, cell, intensity) / safe
    return features.view(len(clouds), 4, GRID, GRID)


def block(c_in: int, c_out: int, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(c_in, c_out, 3, stride, 1, bias=False), nn.BatchNorm2d(c_out), nn.ReLU(inplace=True),
                         nn.Conv2d(c_out, c_out, 3, 1, 1, bias=False), nn.BatchNorm2d(c_out), nn.ReLU(inplace=True))


class BevCenterNet(nn.Module):
    """BEV CNN with CenterPoint-style heads: heatmap (C), offset (2), z (1), log size (3), sin/cos yaw (2)."""

    def __init__(self, n_classes: int):
        super().__init__()
        self.stem = block(4, 16)                 # 160 x 160 cells of 0.5 m
        self.down1 = block(16, 32, stride=2)     # 80
        self.down2 = block(32, 64, stride=2)     # 40
        self.fuse = block(64 + 32, 32)           # 80: heads at 1 m
        self.heatmap = nn.Conv2d(32, n_classes, 1)
        self.regression = nn.Conv2d(32, 8, 1)
        nn.init.constant_(self.heatmap.bias, -2.19)  # prior 0.1, as CenterNet

    def forward(self, bev: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        x80 = self.down1(self.stem(bev))
        x40 = self.down2(x80)
        x = self.fuse(torch.cat([x80, F.interpolate(x40, scale_factor=2.0, mode="nearest")], dim=1))
        return self.heatmap(x), self.regression(x)


# ----------------------------------------------------------------- targets, loss, decoding
def targets(boxes: list[torch.Tensor], labels: list[torch.Tensor]) -> tuple[torch.Tensor, ...]:
    """Gaussian heatmaps (B, C, OUT, OUT), regression targets (B, 8, OUT, OUT) and their mask (B, OUT, OUT)."""
    heat = torch.zeros(len(boxes), len(CLASSES), OUT, OUT)
    reg = torch.zeros(len(boxes), 8, OUT, OUT)
    mask = torch.zeros(len(boxes), OUT, OUT, dtype=torch.bool)
    ys, xs = torch.meshgrid(torch.arange(OUT, dtype=torch.float32), torch.arange(OUT, dtype=torch.float32),
                            indexing="ij")
    for b, (box, label) in enumerate(zip(boxes, labels, strict=True)):
        for (x, y, z, length, width, height, yaw), c in zip(box.tolist(), label.tolist(), strict=True):
            u, v = (x + RANGE_M) / OUT_CELL_M, (y + RANGE_M) / OUT_CELL_M
            iu, iv = int(u), int(v)
            if not (0 <= iu < OUT and 0 <= iv < OUT):
                continue
            sigma = max(0.75, 0.25 * max(length, width) / OUT_CELL_M)
            gaussian = torch.exp(-((xs - iu) ** 2 + (ys - iv) ** 2) / (2 * sigma * sigma))
            heat[b, c] = torch.maximum(heat[b, c], gaussian)
            reg[b, :, iv, iu] = torch.tensor([u - iu, v - iv, z, math.log(length), math.log(width), math.log(height),
                                              math.sin(yaw), math.cos(yaw)])
            mask[b, iv, iu] = True
    return heat, reg, mask


def loss_fn(heat_logits, reg_pred, heat, reg, mask) -> torch.Tensor:
    """CenterNet focal loss on the heatmap plus L1 on the regression at object centres."""
    p = torch.sigmoid(heat_logits).clamp(1e-4, 1 - 1e-4)
    positive = heat.eq(1.0)
    pos_loss = -(torch.log(p) * (1 - p) ** 2)[positive].sum()
    neg_loss = -(torch.log(1 - p) * p ** 2 * (1 - heat) ** 4)[~positive].sum()
    n = positive.sum().clamp(min=1)
    focal = (pos_loss + neg_loss) / n
    reg_loss = F.l1_loss(reg_pred.permute(0, 2, 3, 1)[mask], reg.permute(0, 2, 3, 1)[mask], reduction="sum") / n
    return focal + reg_loss


@torch.no_grad()
def decode(heat_logits: torch.Tensor, reg_pred: torch.Tensor, k: int = 60, min_score: float = 0.05) -> list[tuple]:
    """Per item (boxes (K, 7) x, y, z, l, w, h, yaw in the ego frame, scores (K,), class indices (K,))."""
    scores = torch.sigmoid(heat_logits)
    peaks = scores * (F.max_pool2d(scores, 3, 1, 1) == scores)
    out = []
    for b in range(len(scores)):
        top, index = peaks[b].flatten().topk(k)
        keep = top > min_score
        top, index = top[keep], index[keep]
        cls, cell = index // (OUT * OUT), index % (OUT * OUT)
        iv, iu = cell // OUT, cell % OUT
        r = reg_pred[b, :, iv, iu].T
        x = (iu + r[:, 0]) * OUT_CELL_M - RANGE_M
        y = (iv + r[:, 1]) * OUT_CELL_M - RANGE_M
        boxes = torch.stack([x, y, r[:, 2], r[:, 3].exp(), r[:, 4].exp(), r[:, 5].exp(),
                             torch.atan2(r[:, 6], r[:, 7])], dim=1)
        inside = torch.hypot(x, y) <= RANGE_M
        out.append((boxes[inside], top[inside], cls[inside]))
    return out


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


def evaluate(model: nn.Module, val: FrameDataset, workers: int) -> dict[str, dict[str, float]]:
    model.eval()
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
    args = parser.parse_args()
    torch.manual_seed(args.seed)
    # Tiny gradients of the focal loss underflow into denormal floats, which x86 CPUs handle ~100x
    # slower: without this, epochs 2-3 took ~3x as long as the first.
    torch.set_flush_denormal(True)
    if not (args.dataset / "avdata.json").is_file():
        start = time.perf_counter()
        generate(args.dataset, args.scenes, args.frames, args.seed)
        print(f"generated {args.dataset} in {time.perf_counter() - start:.0f} s")
    train, val = datasets(args.dataset)
    print(f"train frames {len(train)}, validation frames {len(val)}, classes {CLASSES}")
    model = BevCenterNet(len(CLASSES))
    optimiser = torch.optim.AdamW(model.parameters(), lr=2e-3, weight_decay=1e-4)
    loader = DataLoader(train, batch_size=4, shuffle=True, num_workers=args.workers, collate_fn=collate_list,
                        persistent_workers=args.workers > 0, drop_last=True)
    schedule = torch.optim.lr_scheduler.OneCycleLR(optimiser, max_lr=2e-3, total_steps=args.epochs * len(loader))
    start = time.perf_counter()
    for epoch in range(args.epochs):
        model.train()
        losses = []
        for batch in loader:
            heat, reg, mask = targets(batch["boxes"], batch["labels"])
            heat_logits, reg_pred = model(bev_features(batch["points"]["ego/lidar_top"]))
            loss = loss_fn(heat_logits, reg_pred, heat, reg, mask)
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            schedule.step()
            losses.append(loss.item())
        print(f"epoch {epoch + 1}/{args.epochs}: loss {np.mean(losses):.3f} ({time.perf_counter() - start:.0f} s)")
    report = evaluate(model, val, args.workers)
    print(f"trained in {time.perf_counter() - start:.0f} s; validation (nuScenes centre-distance AP, ego frame):")
    for name, metrics in report.items():
        print(f"  {name}: " + ", ".join(f"{k} {v:.3f}" if isinstance(v, float) else f"{k} {v}"
                                      for k, v in metrics.items()))


if __name__ == "__main__":
    main()
