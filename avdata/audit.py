"""``avdata audit DATASET...``: dataset-level checks users of collaborative datasets ask for.

Each check reads the unified datasets (scene metadata, frame trees, labels) and reports one line per
finding, ``<dataset>: <scene>: <what>``:

* a scene or clip in two splits: scenes are keyed by their source clip (metadata ``scenario``, else the
  scene name), across every dataset given, so V2V4Real's published train/test overlap is caught;
* calibrations off orthonormality: residuals (max |RᵀR - I|) the converter recorded above 1e-6;
* agents without poses: an agent whose body frame cannot be placed in ``world`` at a frame's time;
* duplicate object ids within one frame.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from avdata.errors import one_line
from avdata.schema import DatasetReader

ORTHONORMAL_TOLERANCE = 1e-6


@dataclass(frozen=True, slots=True, kw_only=True)
class Finding:
    """One problem: the dataset, the scene and what is wrong."""

    dataset: str
    scene: str
    message: str

    def __str__(self) -> str:
        return f"{self.dataset}: {self.scene}: {one_line(self.message)}"


def audit(roots: Sequence[str | Path]) -> list[Finding]:
    """Every finding over the given unified datasets, in dataset then scene order."""
    findings: list[Finding] = []
    clips: dict[str, list[tuple[str, str, str]]] = defaultdict(list)  # clip -> (dataset, scene, split)
    for root in roots:
        dataset = DatasetReader(root, verify=True)
        name = str(root)
        for scene_name in dataset.scenes:
            scene = dataset.scene(scene_name)
            meta = scene.metadata
            clips[str(meta.get("scenario", scene_name))].append((name, scene_name, str(meta.get("split", ""))))
            for calibration, residual in sorted(dict(meta.get("calibration_residuals", {})).items()):
                if float(residual) > ORTHONORMAL_TOLERANCE:
                    findings.append(Finding(dataset=name, scene=scene_name, message=(
                        f"calibration {calibration}: rotation off orthonormal by {float(residual):.3g} "
                        f"(max |RᵀR - I| > {ORTHONORMAL_TOLERANCE})")))
            graph = scene.graph
            infos = scene.frame_infos()
            for agent in sorted(meta.get("agents", {})):
                missing = [info.frame_index for info in infos if not graph.can_lookup("world", agent, info.timestamp_ns)]
                if missing:
                    findings.append(Finding(dataset=name, scene=scene_name, message=(
                        f"agent {agent!r} has no pose in world at {len(missing)} of {len(infos)} frames "
                        f"(first: frame {missing[0]})")))
            for info in infos:
                _, labels = scene.labels(info.frame_index)
                ids = labels.boxes.ids if labels.boxes.ids is not None else np.zeros(0, dtype=str)
                values, counts = np.unique(ids, return_counts=True)
                if np.any(counts > 1):
                    findings.append(Finding(dataset=name, scene=scene_name, message=(
                        f"frame {info.frame_index}: duplicate object ids {values[counts > 1][:5].tolist()}")))
    for clip, where in sorted(clips.items()):
        splits = sorted({split for _, _, split in where})
        if len(splits) > 1:
            places = ", ".join(f"{dataset}:{scene} ({split or 'no split'})" for dataset, scene, split in where)
            findings.append(Finding(dataset=where[0][0], scene=where[0][1],
                                    message=f"clip {clip!r} appears in splits {splits}: {places}"))
    return findings
