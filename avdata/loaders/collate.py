"""Collate functions for :class:`FrameDataset` and :class:`SequenceDataset` items.

Two ways to batch B items whose clouds and box sets differ in size:

- :func:`collate_list` keeps each variable-size tensor as a list of B tensors and stacks the rest.
- :func:`collate_padded` pads variable-size tensors along their first axis to (B, N_max, ...) and
  adds a boolean ``<key>_mask`` (B, N_max) beside each (True = a real entry).

Variable-size tensors are those of :data:`VARIABLE_KEYS` (points, boxes, labels, per-object
arrays); inside a dict such as ``points`` every value is variable-size. Fixed-size tensors (images,
projections, poses) are stacked when all B share a shape, else kept as a list (cameras of
different resolutions). Strings, ints and other values become lists: a small tensor costs a
shared-memory handle per batch when it leaves a DataLoader worker, which costs more than the keys
are worth.

Items of one dataset need not hold the same sensors or agents: a rate-limited agent sends only in
some frames, and converters keep a frame whose scan is missing or damaged (KITTI tracking sequences
with velodyne sweeps for some frames only). Every dict in an item (``points``, ``images``,
``calibrations``, ``sensor_timestamps_ns`` ...) is therefore batched over the union of its keys
across the batch, in order of first appearance, and an entry an item lacks is handled per key:

- :func:`collate_list`: the item's place holds ``None`` (``batch["points"]["infra_00/lidar"] ==
  [cloud, None]``); a fixed-size tensor missing from any item is not stacked, it stays a list with
  ``None``. Inside a nested dict (a camera's calibration) the ``None`` reaches every leaf.
- :func:`collate_padded`: a missing variable-size tensor is an all-padding row (its ``<key>_mask``
  row all False); a missing fixed-size tensor is zero-filled in the stack; non-tensor values are
  lists with ``None``. Every dict-valued key of tensors (``points``, ``images``, ``calibrations``,
  ``projections``) gets ``<key>_present``: name -> (B,) bool, True where the item held that name
  (always added, so a batch's structure does not depend on which items lack what; an empty cloud
  that was sent is present with a False mask row). Dicts of plain values (``point_fields``,
  ``sensor_timestamps_ns``) get none: their ``None`` entries say it. A top-level
  key missing from some items (items of differently configured datasets) gets ``<key>_present`` (B,).
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
    """Batches items, keeping variable-size tensors as lists of B tensors.

    An entry missing from some items (a sensor, an agent, a camera, a key) is ``None`` in their
    places; a fixed-size tensor missing from any item stays a list instead of being stacked.
    """
    return _collate(batch, padded=False)


def collate_padded(batch: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Batches items, padding variable-size tensors to (B, N_max, ...) with ``<key>_mask`` (B, N_max).

    Padding is 0 for float and bool tensors and -1 for integer tensors (so padded labels are -1).
    Axes after the first are padded to their largest size too (``visible_by``'s agent axis across
    scenes with different agent counts).

    An entry missing from some items (a sensor, an agent, a camera) is all padding in their rows
    (variable-size tensors, mask False) or zeros (fixed-size tensors, stacked when the present ones
    share a shape); ``<key>_present`` maps each name of a dict of tensors (``points``, ``images``,
    ``calibrations``, ``projections``) to a (B,) bool tensor, True where the item held it. Non-tensor
    values are lists with ``None`` where missing.
    """
    return _collate(batch, padded=True)


def _collate(batch: Sequence[dict[str, Any]], padded: bool) -> dict[str, Any]:
    if not batch:
        raise AvdataError("expected at least one item to collate, got an empty batch")
    out: dict[str, Any] = {}
    for key in _union(batch):
        values = [item.get(key) for item in batch]
        if key in VARIABLE_KEYS:
            if any(isinstance(v, dict) for v in values):
                inner = _entries(values)
                if padded:
                    pairs = {name: _pad(vs, key in _LAST_AXIS_KEYS) for name, vs in inner.items()}
                    out[key] = {name: pair[0] for name, pair in pairs.items()}
                    out[f"{key}_mask"] = {name: pair[1] for name, pair in pairs.items()}
                else:
                    out[key] = inner
            elif padded and any(isinstance(v, torch.Tensor) for v in values):
                out[key], out[f"{key}_mask"] = _pad(values, key in _LAST_AXIS_KEYS)
            else:
                out[key] = values
        else:
            out[key] = _fixed(values, padded)
        if padded and any(isinstance(v, dict) for v in values) and not _holds_plain_values(values):
            out[f"{key}_present"] = {name: _presence(vs) for name, vs in _entries(values).items()}
        elif padded and any(key not in item for item in batch):
            out[f"{key}_present"] = torch.tensor([key in item for item in batch])
    return out


def _union(dicts: Sequence[dict[str, Any] | None]) -> list[str]:
    """The keys of every dict (None: none), in order of first appearance."""
    return list(dict.fromkeys(key for d in dicts if d is not None for key in d))


def _entries(values: list[dict[str, Any] | None]) -> dict[str, list[Any]]:
    """The B values (None where an item lacks it) under each name, over the union of names."""
    return {name: [None if v is None else v.get(name) for v in values] for name in _union(values)}


def _presence(values: list[Any]) -> torch.Tensor:
    return torch.tensor([v is not None for v in values])


def _holds_plain_values(values: list[dict[str, Any] | None]) -> bool:
    """Whether the dicts map names to plain values (``point_fields``, ``sensor_timestamps_ns``): None marks absence."""
    return any(not isinstance(v, torch.Tensor | dict) for d in values if d for v in d.values())


def _fixed(values: list[Any], padded: bool) -> Any:
    if any(isinstance(v, dict) for v in values):
        return {name: _fixed(vs, padded) for name, vs in _entries(values).items()}
    present = [v for v in values if v is not None]
    if present and all(isinstance(v, torch.Tensor) and v.shape == present[0].shape for v in present):
        if len(present) == len(values):
            return torch.stack(values)
        if padded:
            zeros = torch.zeros_like(present[0])
            return torch.stack([zeros if v is None else v for v in values])
    return values


def _pad(values: list[torch.Tensor | None], last_axis: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """(B, N_max, ...) padded tensor and (B, N_max) mask along axis 0 (or the last axis); None: no entries."""
    if last_axis:
        stacked, mask = _pad([None if v is None else v.movedim(-1, 0) for v in values], last_axis=False)
        return stacked.movedim(1, -1), mask
    present = [v for v in values if v is not None]
    first = present[0]
    sizes = [0 if v is None else len(v) for v in values]
    trailing = [max(v.shape[axis] for v in present) for axis in range(1, first.dim())]
    fill = -1 if not (first.dtype.is_floating_point or first.dtype == torch.bool) else 0
    out = torch.full((len(values), max(sizes), *trailing), fill, dtype=first.dtype)
    mask = torch.zeros((len(values), max(sizes)), dtype=torch.bool)
    for b, value in enumerate(values):
        if value is not None:
            region: tuple[int | slice, ...] = (b, *[slice(0, n) for n in value.shape])
            out[region] = value
            mask[b, : len(value)] = True
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
