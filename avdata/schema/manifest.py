"""The dataset manifest (``avdata.json``): its name, reading and checking it, its canonical text, scene paths.

Nothing here needs pyarrow for a local dataset, so ``avdata info`` and other summary-only paths read its manifest
without loading the Parquet stack. A dataset in an object store is a :class:`~avdata.storage.Location` (pyarrow's
filesystems), which has the same ``/``, ``read_bytes`` and ``is_file`` as a ``Path``.
"""

from __future__ import annotations

import json
import os
import re
import zlib
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, overload

from avdata.errors import AvdataError, InputError, one_line
from avdata.inputs import require_file
from avdata.outputs import checked_name
from avdata.schema import topics

if TYPE_CHECKING:
    from avdata.storage import Location

#: The manifest's file name in the dataset folder.
MANIFEST = "avdata.json"
#: Key of the manifest's CRC-32 of its own canonical text (see :func:`manifest_text`).
MANIFEST_CRC = "crc32"
_SCENE_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.\-]*$")


@overload
def scene_path(root: str | Path, name: str) -> Path: ...
@overload
def scene_path(root: Location, name: str) -> Location: ...
def scene_path(root: str | Path | Location, name: str) -> Path | Location:
    """The MCAP path of scene ``name`` under dataset ``root`` (a local folder, or a prefix in a store)."""
    checked_name(name, "scene name")  # the path rule of every output name; scene names are narrower still
    if not _SCENE_NAME.match(name):
        raise AvdataError(f"expected a scene name of letters, digits, '_', '-', '.', got {name!r}")
    return (Path(root) if isinstance(root, str) else root) / "scenes" / f"{name}.mcap"


def manifest_text(manifest: Mapping[str, Any]) -> str:
    """The manifest file's text: canonical JSON with the CRC-32 of that text without ``crc32``.

    Canonical: sorted keys, 2-space indent, ASCII. The scene files and index tables carry their own
    checks; this one covers the manifest, so a changed byte anywhere in a dataset is reported: a
    value changed by it no longer matches the CRC, and a change that leaves the values alone (white
    space) no longer matches the canonical text.
    """
    body, crc = _manifest_body_crc(manifest)
    return json.dumps({**body, MANIFEST_CRC: crc}, indent=2, sort_keys=True)


def _manifest_body_crc(manifest: Mapping[str, Any]) -> tuple[dict[str, Any], int]:
    """The manifest without its ``crc32`` key, and the CRC-32 of that body's canonical text."""
    body = {key: value for key, value in manifest.items() if key != MANIFEST_CRC}
    return body, zlib.crc32(json.dumps(body, indent=2, sort_keys=True).encode())


def check_manifest_checksum(path: Path | Location, manifest: Mapping[str, Any], data: bytes | None = None) -> None:
    """Compares the manifest file at ``path`` (parsed: ``manifest``; its bytes ``data`` if read) with :func:`manifest_text`.

    Raises:
        InputError: no CRC recorded, the CRC differs from the content's, or the text is not canonical.
    """
    recorded = manifest.get(MANIFEST_CRC)
    if not isinstance(recorded, int) or isinstance(recorded, bool):
        raise InputError(f"{path}: expected the manifest's own CRC-32 under {MANIFEST_CRC!r}, got {recorded!r}; "
                         "run 'avdata index'")
    _, actual = _manifest_body_crc(manifest)
    if actual != recorded:
        raise InputError(f"{path}: expected CRC-32 {recorded} of the manifest's content, got {actual} "
                         "(a value was changed after writing)")
    if (path.read_bytes() if data is None else data) != manifest_text(manifest).encode():
        raise InputError(f"{path}: the manifest's text differs from its canonical form with the same values "
                         "(changed after writing)")


def read_manifest(path: Path | Location, data: bytes | None = None) -> dict[str, Any]:
    """The manifest at ``path`` (of its bytes ``data`` when already read) as a dict, its structure checked.

    The structure: scenes, integer times and counts, objects where objects belong. Its CRC is
    :func:`check_manifest_checksum`'s.

    Raises:
        InputError: the file is unreadable, not JSON, not an avdata manifest, or of the wrong structure.
    """
    try:
        manifest = json.loads((path.read_bytes() if data is None else data).decode())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError) as error:
        raise InputError(f"{path}: unreadable manifest ({one_line(error)})") from error
    if not isinstance(manifest, dict) or manifest.get("format") != "avdata":
        raise InputError(f"{path}: expected an avdata manifest with \"format\": \"avdata\", got something else")
    scenes = manifest.get("scenes", [])
    if not isinstance(scenes, list):
        raise InputError(f"{path}: expected 'scenes' to be a list, got {type(scenes).__name__} {str(scenes)[:60]!r}")
    for i, scene in enumerate(scenes):
        if not isinstance(scene, dict) or not isinstance(scene.get("name"), str) or not _SCENE_NAME.match(scene["name"]):
            raise InputError(f"{path}: scenes[{i}]: expected an object with a scene 'name' of letters, digits, "
                             f"'_', '-', '.', got {str(scene)[:80]!r}")
        for key in ("start_ns", "end_ns", "frames"):
            value = scene.get(key)
            if value is not None and (not isinstance(value, int) or isinstance(value, bool)):
                raise InputError(f"{path}: scenes[{i}].{key}: expected an integer, got {value!r}")
    for key in ("sensors", "classes", "source", "index"):
        value = manifest.get(key)
        if value is not None and not isinstance(value, dict):
            raise InputError(f"{path}: expected {key!r} to be an object, got {str(value)[:60]!r}")
    manifest["scenes"] = scenes
    return manifest


def open_manifest(root: Path | Location, *, checksum: bool = True) -> dict[str, Any]:
    """The manifest of the dataset folder ``root``, read and checked (:func:`read_manifest`), of a readable version.

    Its own CRC is checked too (``checksum``): it costs one CRC-32 of a few kB, and every reader takes the
    dataset's scenes, sensors and index checksums from it. Only ``avdata validate``, which reports a
    damaged manifest as one problem and goes on checking the rest, reads it unchecked.

    Raises:
        InputError: the folder or its manifest is missing, unreadable or damaged.
        FormatVersionError: the dataset is of a newer major format version.
    """
    if isinstance(root, Path):
        if not os.path.exists(root):  # not Path.exists: it raises for a name too long (a traceback)
            raise InputError(f"{root}: dataset folder does not exist")
        manifest_path: Path | Location = root / MANIFEST
        require_file(root / MANIFEST, "manifest file",
                     missing="manifest missing (not an avdata dataset, or conversion unfinished)")
    # In a store a prefix without objects does not exist: one look-up of the manifest tells both.
    elif not (manifest_path := root / MANIFEST).is_file():
        raise InputError(f"{manifest_path}: manifest missing (not an avdata dataset, or conversion unfinished)")
    try:
        data = manifest_path.read_bytes()
    except OSError as error:
        raise InputError(f"{manifest_path}: unreadable manifest ({one_line(error)})") from error
    manifest = read_manifest(manifest_path, data)
    topics.check_version(manifest.get("format_version", "0"), str(manifest_path))
    if checksum:
        check_manifest_checksum(manifest_path, manifest, data)
    return manifest


def scene_file(root: Path, name: str) -> Path:
    """The MCAP file of scene ``name`` of the dataset at ``root``, which must be there.

    Raises:
        InputError: the scene's file is missing or not a regular file.
    """
    path = scene_path(root, name)
    require_file(path, "scene file", missing="scene file listed in the manifest is missing")
    return path


def dataset_size_bytes(root: Path | Location) -> int:
    """Total size on disk of the dataset folder ``root`` (in a store: of the objects under its prefix)."""
    if isinstance(root, Path):
        return sum(p.stat().st_size for p in root.rglob("*") if p.is_file())
    import pyarrow.fs

    infos = root.fs.get_file_info(pyarrow.fs.FileSelector(root.path, recursive=True, allow_not_found=True))
    return sum(int(info.size) for info in infos if info.type == pyarrow.fs.FileType.File)
