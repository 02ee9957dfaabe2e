"""Models as detectors: the ``Detector`` protocol and how a study loads one by name.

A detector is any callable from one :class:`~avdata.loaders.FrameDataset` item (its clouds and images in
``item["frame"]``) to the :class:`~avdata.perception.detections.Detections` of that frame, in the same frame.
A detector that runs faster on a batch (a torch model) also offers ``detect_batch(items)``; the runner then
feeds it ``batch_size`` items at a time. A study names a detector by a factory ``"pkg.mod:fn"`` called with
the checkpoint path; nothing is ever downloaded, so the checkpoint is a file the user trained or has.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

from avdata.errors import InputError
from avdata.perception.detections import Detections

__all__ = ["BatchedDetector", "Detector", "detect_items", "load_callable", "load_detector"]


@runtime_checkable
class Detector(Protocol):
    """``(item) -> Detections`` in ``item["frame"]``, stamped ``item["timestamp_ns"]``."""

    def __call__(self, item: dict[str, Any]) -> Detections:
        """The detections of one item."""
        ...


@runtime_checkable
class BatchedDetector(Detector, Protocol):
    """A detector that also runs on several items at once (one forward pass of a torch model)."""

    batch_size: int

    def detect_batch(self, items: Sequence[dict[str, Any]]) -> list[Detections]:
        """The detections of each item, in order."""
        ...


def detect_items(detector: Detector, items: Sequence[dict[str, Any]]) -> list[Detections]:
    """The detections of every item, batched when the detector can be."""
    if isinstance(detector, BatchedDetector):
        out: list[Detections] = []
        for start in range(0, len(items), max(1, detector.batch_size)):
            out.extend(detector.detect_batch(items[start:start + detector.batch_size]))
        return out
    return [detector(item) for item in items]


def load_callable(spec: str, what: str) -> Callable[..., Any]:
    """The object named ``"pkg.mod:name"``; one line naming ``what`` and ``spec`` when it cannot be imported."""
    module_name, sep, attribute = spec.partition(":")
    if not sep or not module_name or not attribute:
        raise InputError(f"{what}: expected 'package.module:callable', got {spec!r}")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise InputError(f"{what}: cannot import {module_name!r} ({exc})") from None
    target = module
    for part in attribute.split("."):
        if not hasattr(target, part):
            raise InputError(f"{what}: {module_name!r} has no {attribute!r}")
        target = getattr(target, part)
    if not callable(target):
        raise InputError(f"{what}: expected {spec!r} to be callable, got {type(target).__name__}")
    return target


def load_detector(spec: str, checkpoint: str | Path | None) -> Detector:
    """The detector built by the factory ``spec`` (``"pkg.mod:fn"``) from ``checkpoint`` (or with no argument)."""
    factory = load_callable(spec, "detector.callable")
    detector = factory(Path(checkpoint)) if checkpoint is not None else factory()
    if not callable(detector):
        raise InputError(f"detector.callable: expected {spec!r} to return a detector (a callable), got "
                         f"{type(detector).__name__}")
    checked: Detector = detector
    return checked
