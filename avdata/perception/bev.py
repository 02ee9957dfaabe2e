"""A small CenterPoint-style BEV lidar detector: the baseline model of studies, trained through avdata's loaders on CPU.

Points are scattered into a 0.5 m BEV grid over [-40, 40] m (4 features per cell: log count, max height,
mean height, mean intensity), a 3-level CNN, and CenterNet heads at 1 m: per-class heatmap (focal loss),
sub-cell offset, z, log size and (sin, cos) of yaw (L1). :class:`BevDetector` wraps a trained network as a
:class:`~avdata.perception.detector.Detector` over :class:`~avdata.loaders.FrameDataset` items (every cloud of
the item, in the item's frame, which should be a z-up ego frame); :func:`save_checkpoint` /
:func:`load_checkpoint` keep it in one file (``load_checkpoint`` is the factory a study names:
``avdata.perception.bev:load_checkpoint``). ``examples/train_bev_detector.py`` trains and evaluates one.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn
from torch.utils.data import DataLoader

from avdata.errors import InputError
from avdata.frames import Boxes3D
from avdata.loaders import FrameDataset, collate_list
from avdata.perception.detections import Detections

__all__ = ["CLASSES", "RANGE_M", "BevCenterNet", "BevDetector", "bev_features", "decode", "load_checkpoint", "loss_fn",
           "save_checkpoint", "targets", "train"]

#: Checkpoint format tag: a file without it is not a checkpoint of this module.
CHECKPOINT_FORMAT = "avdata-bev-centernet-1"
CLASSES = ("car", "pedestrian")
RANGE_M = 40.0
CELL_M = 0.5
GRID = int(2 * RANGE_M / CELL_M)  # 160 input cells per side
STRIDE = 2  # heads at 1 m cells
OUT = GRID // STRIDE
OUT_CELL_M = CELL_M * STRIDE


# ----------------------------------------------------------------- model
def bev_features(clouds: Sequence[torch.Tensor]) -> torch.Tensor:
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
        assert self.heatmap.bias is not None  # Conv2d's default bias=True; for the type checker
        nn.init.constant_(self.heatmap.bias, -2.19)  # prior 0.1, as CenterNet

    def forward(self, bev: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Heatmap logits (B, C, OUT, OUT) and regression (B, 8, OUT, OUT) from BEV features."""
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


def loss_fn(heat_logits: torch.Tensor, reg_pred: torch.Tensor, heat: torch.Tensor, reg: torch.Tensor,
            mask: torch.Tensor) -> torch.Tensor:
    """CenterNet focal loss on the heatmap plus L1 on the regression at object centres."""
    p = torch.sigmoid(heat_logits).clamp(1e-4, 1 - 1e-4)
    positive = heat.eq(1.0)
    pos_loss = -(torch.log(p) * (1 - p) ** 2)[positive].sum()
    neg_loss = -(torch.log(1 - p) * p ** 2 * (1 - heat) ** 4)[~positive].sum()
    n = positive.sum().clamp(min=1)
    focal = (pos_loss + neg_loss) / n
    reg_loss = F.l1_loss(reg_pred.permute(0, 2, 3, 1)[mask], reg.permute(0, 2, 3, 1)[mask], reduction="sum") / n
    total: torch.Tensor = focal + reg_loss
    return total


@torch.no_grad()
def decode(heat_logits: torch.Tensor, reg_pred: torch.Tensor, k: int = 60, min_score: float = 0.05
           ) -> list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]:
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


def _points(item: dict[str, Any]) -> torch.Tensor:
    """Every cloud of the item as one (N, 4) x, y, z, intensity tensor (no clouds: no points)."""
    clouds = [torch.as_tensor(c)[:, :4].float() for c in (item.get("points") or {}).values()]
    return torch.cat(clouds) if clouds else torch.zeros(0, 4)


class BevDetector:
    """A trained :class:`BevCenterNet` as a batched :class:`~avdata.perception.detector.Detector`.

    Attributes:
        model: the network (kept in eval mode).
        classes: the unified class of each heatmap channel.
        min_score: detections below this heatmap peak are dropped.
        batch_size: items per forward pass in ``detect_batch``.
    """

    def __init__(self, model: BevCenterNet, classes: Sequence[str] = CLASSES, *, min_score: float = 0.05,
                 batch_size: int = 4):
        self.model = model.eval()
        self.classes = tuple(classes)
        self.min_score = min_score
        self.batch_size = batch_size

    def __call__(self, item: dict[str, Any]) -> Detections:
        """The detections of one item, in its frame."""
        return self.detect_batch([item])[0]

    @torch.no_grad()
    def detect_batch(self, items: Sequence[dict[str, Any]]) -> list[Detections]:
        """The detections of each item (one forward pass over the items that have points)."""
        clouds = [_points(item) for item in items]
        # A frame without a cloud (a sensor file missing) has nothing to detect: no pass over an empty grid.
        with_points = [i for i, cloud in enumerate(clouds) if len(cloud)]
        empty = (torch.zeros(0, 7), torch.zeros(0), torch.zeros(0, dtype=torch.long))
        decoded: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]] = [empty] * len(items)
        if with_points:
            heat_logits, reg_pred = self.model(bev_features([clouds[i] for i in with_points]))
            for i, result in zip(with_points, decode(heat_logits, reg_pred, min_score=self.min_score), strict=True):
                decoded[i] = result
        out = []
        for item, (boxes, scores, cls) in zip(items, decoded, strict=True):
            box = boxes.double().numpy()
            classes = np.array(self.classes)[cls.numpy()] if len(box) else np.zeros(0, dtype=str)
            b3 = Boxes3D.from_yaw(box[:, :3], box[:, 3:6], box[:, 6], str(item["frame"]), classes=classes)
            out.append(Detections(boxes=replace(b3, classes=classes), scores=scores.double().numpy(),
                                  sensors=np.full(len(box), "bev"), timestamp_ns=int(item["timestamp_ns"])))
        return out


def save_checkpoint(detector: BevDetector, path: str | Path) -> None:
    """Writes the network's weights and classes to ``path`` (under a temporary name, then renamed)."""
    import io

    from avdata.outputs import write_atomically

    buffer = io.BytesIO()
    torch.save({"format": CHECKPOINT_FORMAT, "classes": list(detector.classes),
                "state_dict": detector.model.state_dict()}, buffer)
    write_atomically(path, buffer.getvalue())


def load_checkpoint(path: str | Path) -> BevDetector:
    """The detector saved by :func:`save_checkpoint`; anything else is one line naming the file."""
    path = Path(path)
    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
    except FileNotFoundError:
        raise InputError(f"{path}: expected a BEV detector checkpoint, got no such file") from None
    except Exception as exc:  # noqa: BLE001 - torch raises many kinds on a bad or hostile file
        raise InputError(f"{path}: expected a BEV detector checkpoint, got an unreadable file "
                         f"({exc.__class__.__name__})") from None
    if not isinstance(data, dict) or data.get("format") != CHECKPOINT_FORMAT:
        raise InputError(f"{path}: expected a checkpoint with format {CHECKPOINT_FORMAT!r}, got "
                         f"{data.get('format') if isinstance(data, dict) else type(data).__name__!r}")
    classes = data.get("classes")
    if not isinstance(classes, list) or not classes or not all(isinstance(c, str) for c in classes):
        raise InputError(f"{path}: expected 'classes' to be a non-empty list of names, got {classes!r}")
    model = BevCenterNet(len(classes))
    try:
        model.load_state_dict(data["state_dict"])
    except (KeyError, RuntimeError) as exc:
        raise InputError(f"{path}: weights do not fit the network ({str(exc).splitlines()[0]})") from None
    return BevDetector(model, classes)


def train(frames: FrameDataset, *, epochs: int, workers: int = 0, seed: int = 0, batch_size: int = 4,
          log: Any = None) -> BevDetector:
    """Trains a detector for ``CLASSES`` on ``frames`` (items in a z-up ego frame with ``boxes`` and ``labels``).

    Args:
        frames: the training frames (their label classes must be ``CLASSES``, in that order).
        epochs: passes over the data (AdamW, one-cycle learning rate up to 2e-3).
        workers: DataLoader worker processes.
        seed: seed of the initial weights and the shuffling.
        batch_size: items per step.
        log: called with one line per epoch (e.g. ``print``), or None.
    """
    if tuple(frames.classes) != CLASSES:
        raise InputError(f"bev.train: expected frames with classes {CLASSES}, got {frames.classes}")
    torch.manual_seed(seed)
    # Tiny gradients of the focal loss underflow into denormal floats, which x86 CPUs handle in slow
    # microcode: without flushing them, later epochs take several times as long as the first.
    torch.set_flush_denormal(True)
    model = BevCenterNet(len(CLASSES))
    optimiser = torch.optim.AdamW(model.parameters(), lr=2e-3, weight_decay=1e-4)
    loader = DataLoader(frames, batch_size=batch_size, shuffle=True, num_workers=workers, collate_fn=collate_list,
                        persistent_workers=workers > 0, drop_last=True,
                        generator=torch.Generator().manual_seed(seed))
    schedule = torch.optim.lr_scheduler.OneCycleLR(optimiser, max_lr=2e-3, total_steps=max(1, epochs * len(loader)))
    for epoch in range(epochs):
        model.train()
        losses = []
        for batch in loader:
            heat, reg, mask = targets(batch["boxes"], batch["labels"])
            heat_logits, reg_pred = model(bev_features([_points({"points": p}) for p in _per_item(batch)]))
            loss = loss_fn(heat_logits, reg_pred, heat, reg, mask)
            optimiser.zero_grad()
            loss.backward()  # type: ignore[no-untyped-call]  # torch 2.13 leaves Tensor.backward unannotated
            optimiser.step()
            schedule.step()
            losses.append(loss.item())
        if log is not None:
            log(f"epoch {epoch + 1}/{epochs}: loss {np.mean(losses) if losses else math.nan:.3f}")
    return BevDetector(model.eval(), CLASSES)


def _per_item(batch: dict[str, Any]) -> list[dict[str, torch.Tensor]]:
    """The clouds of each item of a ``collate_list`` batch, as {sensor: cloud} mappings."""
    points = batch.get("points") or {}
    n = len(batch["frame_index"])
    return [{sensor: clouds[i] for sensor, clouds in points.items()} for i in range(n)]
