"""Helpers of the export tests: an export's files, and a digest of them that does not depend on where the dataset is."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from avdata.exporters.nuscenes import _token


def export_files(root: Path) -> dict[str, bytes]:
    """Every file of an export but the writer lock (it holds a PID) and the resume markers (they hold mtimes)."""
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(Path(root).rglob("*"))
            if p.is_file() and p.name != ".avdata.lock" and ".avdata-export" not in p.relative_to(root).parts}


def export_digest(root: Path, dataset: Path) -> str:
    """SHA-256 over an export's files (``errors.jsonl`` left out), with the dataset path and the map token
    derived from it (both written into the export) replaced by placeholders, and every float of a JSON table
    rounded to 10 significant digits.

    The rounding is for last-bit noise: the same code may compute calibration and pose floats differently in
    their last bits on another machine, and the nuScenes tables print floats in full.
    """
    replacements = {_token("map", str(dataset)): "<MAP>", str(dataset): "<DATASET>"}
    digest = hashlib.sha256()
    for name, data in export_files(root).items():
        if name == "errors.jsonl":
            continue
        for old, new in replacements.items():
            name = name.replace(old, new)
            data = data.replace(old.encode(), new.encode())
        if name.endswith(".json"):
            data = json.dumps(json.loads(data, parse_float=lambda text: float(f"{float(text):.10g}")),
                              sort_keys=True).encode()
        digest.update(f"{name}\0{len(data)}\0".encode() + data)
    return digest.hexdigest()
