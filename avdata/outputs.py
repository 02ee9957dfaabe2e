"""Output files that appear whole or not at all: written under a temporary name in their folder, then renamed.

Results, reports, exports and state files go through :func:`write_atomically` (scene files and the index have
their own writers), so an output path that cannot be written is one line naming it, never a traceback, and a
crash never leaves a half-written file under the final name.

Every name that becomes part of an output path (scene names, study case names, the nuScenes table folder
``--version``, exported channel and file names) goes through :func:`checked_name` first, so no output
leaves its folder.
"""

from __future__ import annotations

import errno
import os
import secrets
import stat
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from avdata.errors import DiskFullError, InputError, OutputError, file_kind, one_line

if TYPE_CHECKING:  # not imported at run time: this module stays light for every command's start-up
    from avdata.storage import Location

#: errno values of a full disk: no space left on the device, or the user's quota used up.
DISK_FULL_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT})

#: Longest name a Linux filesystem takes (NAME_MAX, in bytes).
NAME_MAX_BYTES = 255


def checked_name(name: object, what: str) -> str:
    r"""``name`` if it is safe as one component of an output path, else InputError naming ``what`` and the value.

    The one rule for every name that becomes a file or folder name: a non-empty string that is not ``.`` or
    ``..``, holds no path separator (``/``, ``\``), no NUL or other control character, does not start with ``.``
    (hidden, and the shape of this module's temporary files) and fits a file name (255 bytes). An absolute
    path fails on its separator. Names may carry a suffix after this check (``<case>__trial-0.json``).

    Args:
        name: the name as given.
        what: what it is, for the message (e.g. "--version", "study case name").
    """
    if not isinstance(name, str):
        raise InputError(f"{what}: expected a name, got {type(name).__name__} {name!r}")
    why = ("an empty name" if not name else
           "the folder itself or its parent" if name in (".", "..") else
           "a path separator" if "/" in name or "\\" in name else
           "a control character" if any(ord(c) < 32 or ord(c) == 127 for c in name) else
           "a leading '.'" if name.startswith(".") else
           f"more than {NAME_MAX_BYTES} bytes" if len(name.encode("utf-8", "surrogatepass")) > NAME_MAX_BYTES else "")
    if why:
        raise InputError(f"{what}: expected a name that stays inside its folder (no '/', '..', leading '.', "
                         f"control character or empty name), got {name!r} ({why})")
    return name


def refuse_output_in_input(out: Path | Location, inputs: Sequence[Path | Location], what: str) -> None:
    """Raises InputError when the output ``out`` (a file or folder) is one of the inputs ``inputs`` or under one.

    Output written there replaces or mixes with the input: ``eval --json GT/avdata.json`` overwrote the dataset's
    manifest, a converter read its own scenes back as source files, and the input's writers clean up what looks
    like their own leftovers in it.

    Args:
        out: the output file or folder.
        inputs: the files and folders the command reads.
        what: the inputs' argument name, for the message (e.g. "DATASET", "SRC").
    """
    target = _path_identity(out)
    for path in inputs:
        if target.startswith(source := _path_identity(path)):
            where = f"{what} itself" if target == source else f"a path inside {what} {path}"
            raise InputError(f"{out}: expected an output outside {what}, got {where}")


def _path_identity(path: Path | Location) -> str:
    """The resolved local path (links and '..' followed), or the URI in a store; with a final '/'.

    ``os.path.realpath``, not ``Path.resolve``: that raises for a symbolic-link loop, for its writer to name.
    """
    name = os.path.realpath(path) if isinstance(path, Path) else path.uri
    return f"{name.rstrip('/')}/"


def is_disk_full(error: BaseException) -> bool:
    """Whether ``error`` says the output's disk or quota is full (ours, an ``OSError``, or pyarrow's text of one)."""
    if isinstance(error, DiskFullError):
        return True
    if not isinstance(error, OSError):
        return False
    # pyarrow's writers raise OSError without errno, naming it in the text only.
    return error.errno in DISK_FULL_ERRNOS or any(os.strerror(code) in str(error) for code in DISK_FULL_ERRNOS)


def name_full_disk(error: OSError, path: str | Path) -> OSError:
    """``error`` naming ``path`` if it is a full disk without a file name (``os.writev`` on an open file has none)."""
    if is_disk_full(error) and not error.filename:
        code = error.errno if error.errno in DISK_FULL_ERRNOS else _disk_full_errno(error)
        return OSError(code, os.strerror(code), str(path))
    return error


def _disk_full_errno(error: OSError) -> int:
    return next((code for code in DISK_FULL_ERRNOS if os.strerror(code) in str(error)), errno.ENOSPC)


#: What every temporary file matches (see :func:`temporary_path`).
TEMPORARY_GLOB = ".*.tmp"


def temporary_path(path: Path, keep_suffix: bool = False) -> Path:
    """The temporary name ``path`` is written under before its rename: ``.<name>.<pid>.<random>.tmp`` beside it.

    The one naming scheme of every output written whole or not at all (this module, scene files, the index,
    exports, recordings, videos, study trial folders): hidden, so folder listings and globs for final names pass
    it over, and unique per writer (PID + random), so a retried or duplicated task never shares one.

    Args:
        path: the final path.
        keep_suffix: end the name with ``path``'s suffix too (``.tmp.mp4``), for writers that pick the file
            format by it (OpenCV's video writer).
    """
    return path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp{path.suffix if keep_suffix else ''}")


def remove_temporary_files(root: Path) -> None:
    """Deletes the temporary files an interrupted run left anywhere under ``root`` (only safe under its lock)."""
    for path in Path(root).rglob(TEMPORARY_GLOB):
        if path.is_file():
            path.unlink(missing_ok=True)


def write_atomically(path: str | Path, data: bytes | bytearray | memoryview | str) -> None:
    """Writes ``data`` (text as UTF-8) to ``path``, creating its folders, through a temporary file and a rename.

    The temporary file (:func:`temporary_path`) is created exclusively with the usual permissions.

    Raises:
        OutputError: it cannot be written there (a folder in its place, a file where its folder goes, no
            permission), naming the path and why; :class:`~avdata.errors.DiskFullError` for a full disk.
    """
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):  # a file in the way, at the parent or above it
        raise OutputError(f"{path}: cannot write this file (a file is where its folder should be)") from None
    except OSError as error:
        raise _cannot_write(path, error) from None
    _refuse_special_file(path)
    tmp = temporary_path(path)
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o666)
        with os.fdopen(fd, "wb") as stream:
            stream.write(data.encode() if isinstance(data, str) else data)
        os.replace(tmp, path)
    except OSError as error:
        raise _cannot_write(path, error) from None
    finally:
        if os.path.lexists(tmp):
            os.unlink(tmp)


def _refuse_special_file(path: Path) -> None:
    """Raises OutputError when a FIFO, socket or device is at ``path``: the rename replaced it with a file (exit 0).

    A reader waiting on the FIFO waited forever, and ``--json /dev/stdout`` run as root replaced the device link.
    """
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return  # nothing there yet, or a name the open names
    if not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):  # a folder: the rename names it
        raise OutputError(f"{path}: cannot write this file (a {file_kind(mode)} is in its place)")


def _cannot_write(path: Path, error: OSError) -> OutputError:
    if is_disk_full(error):
        return DiskFullError(f"{path}: cannot write this file ({os.strerror(_disk_full_errno(error))})")
    return OutputError(f"{path}: cannot write this file ({error.strerror or one_line(error)})")
