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


#: Keys of the intermediate / late layouts that hold one entry per received agent (dicts keyed by agent).
_PER_AGENT_KEYS = ("points", "agent_boxes", "agent_labels", "agent_object_ids")


def collate_intermediate(batch: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Batches items of ``Collaboration(fusion="intermediate")`` the way OpenCOOD's models take them.

    ``points`` becomes one list of R clouds, the received agents of item 0 (in ``agents`` order, the
    ego first), then of item 1, ...; ``record_len`` (B,) int64 says how many each item gave (R is its
    sum). ``pairwise_T`` (B, L, L, 4, 4) and ``agent_mask`` (B, L) are stacked (L = ``max_agents``);
    the ego's labels are padded as :func:`collate_padded` does; other keys as there.
    """
    return _collate_agents(batch, late=False)


def collate_late(batch: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Batches items of ``Collaboration(fusion="late")``: :func:`collate_intermediate`, plus per-agent labels.

    ``agent_boxes`` (R, M_max, 7) and ``agent_labels`` (R, M_max) are padded (labels with -1) with
    ``agent_boxes_mask`` (R, M_max), row r being the r-th cloud of ``points``; ``agent_object_ids`` is a
    list of R lists.
    """
    return _collate_agents(batch, late=True)


def _collate_agents(batch: Sequence[dict[str, Any]], late: bool) -> dict[str, Any]:
    if not batch:
        raise AvdataError("expected at least one item to collate, got an empty batch")
    if "pairwise_T" not in batch[0] or (late and "agent_boxes" not in batch[0]):
        raise AvdataError(f"expected items of Collaboration(fusion={'late' if late else 'intermediate'!r}), "
                          f"got keys {sorted(batch[0])}")
    rest = [{key: value for key, value in item.items() if key not in _PER_AGENT_KEYS} for item in batch]
    out = collate_padded(rest)
    received = [[a for a, m in zip(item["agents"], item["agent_mask"].tolist(), strict=False) if m] for item in batch]
    out["record_len"] = torch.tensor([len(r) for r in received], dtype=torch.int64)
    # an agent received without a cloud (a camera-only agent) gives an empty cloud, so rows stay aligned
    width = next((cloud.shape[1] for item in batch for cloud in item["points"].values()), 3)
    empty = torch.zeros((0, width), dtype=torch.float32)
    out["points"] = [item["points"].get(a, empty) for item, agents in zip(batch, received, strict=True) for a in agents]
    if late:
        boxes = [item["agent_boxes"][a] for item, agents in zip(batch, received, strict=True) for a in agents]
        labels = [item["agent_labels"][a] for item, agents in zip(batch, received, strict=True) for a in agents]
        out["agent_boxes"], out["agent_boxes_mask"] = _pad(boxes, last_axis=False)
        out["agent_labels"] = _pad(labels, last_axis=False)[0]
        out["agent_object_ids"] = [item["agent_object_ids"][a] for item, agents in zip(batch, received, strict=True)
                                   for a in agents]
    return out
