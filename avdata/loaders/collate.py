"""Collate functions for :class:`FrameDataset` and :class:`SequenceDataset` items.

Two ways to batch B items whose clouds and box sets differ in size:

- :func:`collate_list` keeps each variable-size tensor as a list of B tensors and stacks the rest.
- :func:`collate_padded` pads variable-size tensors along their first axis to (B, N_max, ...) and
  adds a boolean ``<key>_mask`` (B, N_max) beside each (True = a real entry).

Variable-size tensors are those of :data:`VARIABLE_KEYS` (points, boxes, labels, per-object
arrays); inside a dict such as ``points`` every value is variable-size. Fixed-size tensors (images,
projections, poses) are stacked when all B share a shape, else kept as a list (cameras of
different resolutions). Strings, ints and other values become lists: a small tensor costs a
shared-memory handle per batch when it leaves a DataLoader worker (measured ~0.5 ms each here),
more than the keys are worth.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch

from avdata.errors import AvdataError

#: Keys whose tensors differ in length from item to item (first axis), at any nesting level.
VARIABLE_KEYS = frozenset(
    {"points", "boxes", "boxes_quat_wxyz", "labels", "object_ids", "visible_by", "past", "future", "past_valid",
     "future_valid", "object_labels"}
)
#: Keys whose variable axis is the last one (A, N): agents are fixed, objects vary.
_LAST_AXIS_KEYS = frozenset({"visible_by"})


def collate_list(batch: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Batches items, keeping variable-size tensors as lists of B tensors."""
    return _collate(batch, padded=False)


def collate_padded(batch: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Batches items, padding variable-size tensors to (B, N_max, ...) with ``<key>_mask`` (B, N_max).

    Padding is 0 for float and bool tensors and -1 for integer tensors (so padded labels are -1).
    """
    return _collate(batch, padded=True)


def _collate(batch: Sequence[dict[str, Any]], padded: bool) -> dict[str, Any]:
    if not batch:
        raise AvdataError("expected at least one item to collate, got an empty batch")
    out: dict[str, Any] = {}
    for key in batch[0]:
        values = [item[key] for item in batch]
        if key in VARIABLE_KEYS:
            if isinstance(values[0], dict):
                inner = {name: [v[name] for v in values] for name in values[0]}
                if padded:
                    pairs = {name: _pad(vs, key in _LAST_AXIS_KEYS) for name, vs in inner.items()}
                    out[key] = {name: pair[0] for name, pair in pairs.items()}
                    out[f"{key}_mask"] = {name: pair[1] for name, pair in pairs.items()}
                else:
                    out[key] = inner
            elif padded and isinstance(values[0], torch.Tensor):
                out[key], out[f"{key}_mask"] = _pad(values, key in _LAST_AXIS_KEYS)
            else:
                out[key] = values
        else:
            out[key] = _fixed(values)
    return out


def _fixed(values: list[Any]) -> Any:
    first = values[0]
    if isinstance(first, dict):
        return {name: _fixed([v[name] for v in values]) for name in first}
    if isinstance(first, torch.Tensor):
        if all(v.shape == first.shape for v in values):
            return torch.stack(values)
        return values
    return values


def _pad(values: list[torch.Tensor], last_axis: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """(B, N_max, ...) padded tensor and (B, N_max) mask along axis 0 (or the last axis)."""
    if last_axis:
        stacked, mask = _pad([v.movedim(-1, 0) for v in values], last_axis=False)
        return stacked.movedim(1, -1), mask
    sizes = [len(v) for v in values]
    n_max = max(sizes)
    first = values[0]
    fill = -1 if not (first.dtype.is_floating_point or first.dtype == torch.bool) else 0
    out = torch.full((len(values), n_max, *first.shape[1:]), fill, dtype=first.dtype)
    mask = torch.zeros((len(values), n_max), dtype=torch.bool)
    for b, (value, size) in enumerate(zip(values, sizes, strict=True)):
        out[b, :size] = value
        mask[b, :size] = True
    return out, mask
