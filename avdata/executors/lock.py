"""One writer per dataset folder: an exclusive ``flock`` on ``DST/.avdata.lock`` that holds the writer's PID.

The kernel drops the lock when the holder's last descriptor closes, also after ``kill -9``, so a crashed
run never leaves a stale lock behind; the file itself stays (deleting it would let two writers lock two
different files of the same name).
"""

from __future__ import annotations

import fcntl
import os
import stat
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from avdata.errors import InputError, file_kind

LOCK_NAME = ".avdata.lock"


def prepare_folder(root: Path) -> Path:
    """Creates the output folder ``root`` (and its parents); one-line errors when that is impossible."""
    root = Path(root)
    try:
        mode = os.stat(root).st_mode
    except FileNotFoundError:
        if os.path.islink(root):
            raise InputError(f"{root}: expected a folder to write into, got a broken symbolic link") from None
        mode = None
    except OSError as error:  # a symbolic-link loop, a file where a parent folder should be ...
        raise InputError(f"{root}: cannot create the output folder ({error.strerror})") from None
    if mode is not None and not stat.S_ISDIR(mode):
        raise InputError(f"{root}: expected a folder to write into, got a {file_kind(mode)}")
    try:
        root.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise InputError(f"{root}: cannot create the output folder ({error.strerror})") from error
    if not os.access(root, os.W_OK | os.X_OK):
        raise InputError(f"{root}: expected a writable folder, got one without write permission")
    return root


@contextmanager
def dataset_lock(root: str | Path) -> Iterator[Path]:
    """Holds the writer lock of the output folder ``root`` (created if missing) for the ``with`` block.

    Raises:
        InputError: ``root`` is a file or cannot be created or written, or another process holds the
            lock (the message names its PID).
    """
    root = prepare_folder(Path(root))
    path = root / LOCK_NAME
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as error:
        raise InputError(f"{path}: cannot open the writer lock ({error.strerror})") from error
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 32, 0).decode("ascii", "replace").strip() or "unknown"
            raise InputError(f"{root}: another avdata process (PID {holder}) is writing this folder; "
                             f"wait for it to end or stop it") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        yield root
    finally:
        os.close(fd)
