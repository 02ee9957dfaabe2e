"""Input files read strictly: the one place every reader opens, checks and parses what a user hands in.

Beside :mod:`avdata.outputs` (files that appear whole or not at all), this module is the input side, used by
every layer that reads user files (schema, sources, converters, eval, generators, studies):

- :func:`require_file`, :func:`require_folder`, :func:`is_present` say what is at a path instead of the
  expected file or folder (missing, a broken link, a folder, a FIFO ...), one line each;
- :func:`read_regular_file` and :func:`read_text_bytes` read a file once, refusing special files and
  files too large to be what they claim;
- :func:`unique_object` and :class:`UniqueKeyLoader` parse JSON and YAML refusing a key given twice:
  Python's ``json`` and PyYAML keep the last one without a word, so such a mapping is ambiguous (which
  value did the author mean?); a repeat with a different value is an error naming the key (and, for YAML,
  the line), the same value twice is harmless;
- :func:`c_floats` takes numbers as the C readers of KITTI's text files do.

Each function that takes a path also takes an :class:`avdata.storage.Location` in an object store (``s3://``,
``gs://``): a converter whose reading goes through these functions reads SRC from a store as from a disk, small
files whole in one request, with the same one-line errors naming the object's URI. :func:`list_names` lists a
folder either way, :func:`folder_entries` what is in it, :func:`files_under` the files under it at any depth.
"""

from __future__ import annotations

import errno
import os
import re
import stat
from collections.abc import Hashable
from pathlib import Path
from typing import Any

import yaml

from avdata.errors import InputError, file_kind
from avdata.storage import FILE, FOLDER, MISSING, Location

#: What C's ``%d`` writes, at most 10 digits (2^31 has 10).
_C_INT = re.compile(r"-?[0-9]{1,10}")

#: A local path or an object in a store.
Source = Path | Location


class DuplicateKeyError(ValueError):
    """A key given twice with different values in one JSON object or YAML mapping."""


def unique_object(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """``object_pairs_hook`` for :func:`json.load`: the object as a dict, refusing a repeated key.

    Raises:
        DuplicateKeyError: a key given twice with different values.
    """
    out = dict(pairs)
    if len(out) < len(pairs) and (conflict := first_conflict(pairs)) is not None:
        key, first, second = conflict
        raise DuplicateKeyError(f"key {key!r} given twice in one object, with values {first!r:.60} and {second!r:.60}")
    return out


def first_conflict(pairs: list[tuple[str, Any]]) -> tuple[str, Any, Any] | None:
    """(key, first value, other value) of the first key given twice with different values, None if none is.

    JSON parsers keep one of the values without a word (Python's the last), so such an object is ambiguous.
    """
    first: dict[str, Any] = {}
    for key, value in pairs:
        if key in first and first[key] != value:
            return key, first[key], value
        first.setdefault(key, value)
    return None


#: libyaml's parser when PyYAML was built with it: the pure-Python scanner is slow enough on one long line that a
#: hostile file would stall the command instead of being refused.
_SafeLoader: type = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


class UniqueKeyLoader(_SafeLoader):  # type: ignore[misc]  # the base is chosen at run time (libyaml's or Python's)
    """PyYAML's safe loader, refusing a mapping key given twice with different values (DuplicateKeyError).

    Callers also catch ``ValueError``: Python refuses to convert an integer literal of more than 4300 digits.
    """

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        """The mapping of ``node``; raises DuplicateKeyError for a key given twice with different values."""
        # The keys as written, before merge keys ("<<", which may be overridden) are flattened in.
        seen: dict[Any, Any] = {}
        for key_node, value_node in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":
                continue
            key = self.construct_object(key_node, deep=True)
            value = self.construct_object(value_node, deep=True)
            if not isinstance(key, Hashable):
                continue  # SafeLoader refuses it below
            if key in seen and seen[key] != value:
                raise DuplicateKeyError(f"line {key_node.start_mark.line + 1}: key {key!r} given twice in one mapping")
            seen[key] = value
        mapping: dict[Any, Any] = super().construct_mapping(node, deep=True)
        return mapping


UniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, UniqueKeyLoader.construct_mapping)


def refuse_special_file(path: Path | str | Location) -> None:
    """Raises InputError when ``path`` is a FIFO, socket or device (reading one can wait forever or never end).

    Missing paths, folders and regular files pass: their readers report them as before. A store has no
    special files.
    """
    if isinstance(path, Location):
        return
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return
    if not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
        raise _special_file_error(path, mode)


def _special_file_error(path: Path | str, mode: int) -> InputError:
    return InputError(f"{path}: expected a regular file, got a {file_kind(mode)}")


def read_regular_file(path: Path | str | Location, max_bytes: int | None = None) -> bytes:
    """The bytes of the regular file at ``path``, opened once.

    ``O_NONBLOCK`` makes opening a FIFO return at once instead of waiting for a writer, and the open file's
    ``fstat`` says what it is: one path lookup per file instead of a :func:`refuse_special_file` stat before
    the open (the nuScenes converter reads every sensor file, 2.6 M on trainval).

    Raises:
        InputError: a FIFO, socket or device, or a file over ``max_bytes`` bytes.
        OSError: as ``open`` raises it (FileNotFoundError, IsADirectoryError, ...), for the caller to word.
    """
    if isinstance(path, Location):
        return _read_object(path, max_bytes)
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    try:
        status = os.fstat(fd)
        if stat.S_ISDIR(status.st_mode):
            raise IsADirectoryError(errno.EISDIR, os.strerror(errno.EISDIR), str(path))
        if not stat.S_ISREG(status.st_mode):
            raise _special_file_error(path, status.st_mode)
        if max_bytes is not None and status.st_size > max_bytes:
            raise InputError(f"{path}: expected a file of at most {max_bytes} bytes, got {status.st_size} bytes")
        # os.read straight into one bytes object of the file's size, then until the end of the file (a file that
        # grew meanwhile is read whole): no file object and no intermediate buffer, for the many small files.
        data = os.read(fd, status.st_size)
        while more := os.read(fd, 1 << 20):
            data += more
        return data
    finally:
        os.close(fd)


def _read_object(path: Location, max_bytes: int | None) -> bytes:
    """The whole object at ``path``, failing as :func:`read_regular_file` does for a file."""
    try:
        return path.read_bytes(max_bytes)
    except InputError:
        found = path.info().kind  # asked only when the read failed: was anything there?
        if found == MISSING:
            raise FileNotFoundError(errno.ENOENT, os.strerror(errno.ENOENT), path.uri) from None
        if found == FOLDER:
            raise IsADirectoryError(errno.EISDIR, os.strerror(errno.EISDIR), path.uri) from None
        raise


def list_names(folder: Path | Location) -> list[str]:
    """The names in ``folder`` (``os.listdir``; one listing per 1000 objects in a store), in no set order.

    Raises:
        OSError: as ``os.listdir`` raises it (local folders).
        InputError: a store that cannot be listed, naming the URI.
    """
    if isinstance(folder, Location):
        return [entry.name for entry in folder.iterdir()]
    return os.listdir(folder)


def folder_entries(folder: Path | Location) -> list[Path | Location]:
    """What is directly in ``folder``, sorted by name; nothing when it is not a folder (missing, a file ...).

    In a store: one listing, whose entries know what they are (their ``is_dir``, ``is_file`` cost no request).
    """
    if isinstance(folder, Location):
        return list(folder.iterdir())
    return sorted(folder.iterdir(), key=lambda p: p.name) if folder.is_dir() else []


def files_under(folder: Path | Location) -> list[Path | Location]:
    """Every regular file under ``folder``, at any depth (one listing per 1000 objects in a store), in no set order."""
    if isinstance(folder, Location):
        return [folder / name for name, info in folder.listing(recursive=True).items() if info.kind == FILE]
    return [p for p in folder.rglob("*") if p.is_file()]


def is_present(path: Path | Location) -> bool:
    """Whether anything is at ``path``, a broken symbolic link included.

    A folder, a broken link or a FIFO where a file belongs is damage for its reader to name, not an absent
    (optional or partially downloaded) file: ``Path.is_file`` cannot tell the two apart.
    """
    if isinstance(path, Location):
        return path.exists()
    return os.path.lexists(path)  # not Path.exists: it raises for a name too long (a traceback)


def require_file(path: Path | Location, what: str, missing: str | None = None) -> None:
    """Raises InputError unless ``path`` is a regular file, saying what it is: missing, a broken link, a folder ...

    Args:
        path: the file.
        what: what it should hold, e.g. "label file" (messages: "label file missing", "expected a label file,
            got a folder", "expected a regular file, got a FIFO").
        missing: the message when nothing is there (default "<what> missing"), e.g. with a hint.
    """
    if isinstance(path, Location):
        found = path.info().kind
        if found == MISSING:
            raise InputError(f"{path}: {missing or f'{what} missing'}")
        if found == FOLDER:
            raise InputError(f"{path}: expected a {what}, got a folder (prefix)")
        return
    try:
        mode = os.stat(path).st_mode
    except (FileNotFoundError, NotADirectoryError):
        if os.path.islink(path):  # a link to nowhere is damage, not an absent file
            raise InputError(f"{path}: expected a {what}, got a broken symbolic link") from None
        raise InputError(f"{path}: {missing or f'{what} missing'}") from None
    except OSError as error:  # a symbolic-link loop, a name too long, ...
        raise InputError(f"{path}: expected a {what}, got {error.strerror or error}") from None
    if stat.S_ISDIR(mode):
        raise InputError(f"{path}: expected a {what}, got a folder")
    if not stat.S_ISREG(mode):
        raise _special_file_error(path, mode)


def require_folder(path: Path | Location, what: str) -> None:
    """Raises InputError unless ``path`` is a folder, saying what is there instead: nothing, a file, a FIFO ...

    Args:
        path: the folder.
        what: what it should be, e.g. "folder of KITTI .txt files" ("expected a folder of KITTI .txt files, got a
            file").
    """
    if isinstance(path, Location):
        found = path.info().kind
        if found != FOLDER:
            raise InputError(f"{path}: expected a {what}, got {'a file' if found == FILE else 'no such folder'}")
        return
    try:
        mode = os.stat(path).st_mode
    except OSError:
        raise InputError(f"{path}: expected a {what}, got no such folder") from None
    if not stat.S_ISDIR(mode):
        raise InputError(f"{path}: expected a {what}, got a {file_kind(mode)}")


#: Largest text file read whole (a label, calibration, timestamp, pose or config file: real ones are kilobytes).
MAX_TEXT_BYTES = 64 << 20


def read_text_bytes(path: Path | Location) -> bytes:
    """The bytes of a small text file, refusing special files and files over :data:`MAX_TEXT_BYTES`.

    Raises:
        InputError: a FIFO/socket/device, a file too large to be what it claims, or an unreadable one.
    """
    try:
        return read_regular_file(path, MAX_TEXT_BYTES)
    except OSError as error:
        raise InputError(f"{path}: unreadable ({error.strerror or error})") from None


def c_floats(tokens: list[str]) -> list[float]:
    """Numbers of a text format written by C/C++ (KITTI's files), as its own readers (``sscanf``) take them.

    Python's :func:`float` also accepts ``1_000`` and non-ASCII digits (``٣``); a C reader stops there, so
    such a token is damage, not a number.

    Raises:
        ValueError: a token that is not such a number.
    """
    if not all(token.isascii() and "_" not in token for token in tokens):
        raise ValueError(tokens)
    return [float(token) for token in tokens]


def c_int(token: str) -> int | None:
    """An integer of a text format written by C/C++ (KITTI's ``%d``): ASCII digits with an optional ``-``, below 2^31.

    None for anything else: :func:`int` also takes ``1_0``, ``+1`` and ``٣``, and a 20-digit id would overflow an
    int64 column.
    """
    if _C_INT.fullmatch(token) is None:
        return None
    value = int(token)
    return value if abs(value) < 2**31 else None
