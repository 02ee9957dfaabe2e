"""One writer per dataset folder: an exclusive ``flock`` on ``DST/.avdata.lock`` that holds the writer's PID.

The kernel drops the lock when the holder's last descriptor closes, also after ``kill -9``, so a crashed
run never leaves a stale lock behind; the file itself stays (deleting it would let two writers lock two
different files of the same name).

Every writing command (convert, generate, export, index, study run) runs inside the lock, so the lock is also
where a full disk becomes one line (:class:`~avdata.errors.DiskFullError`): whichever writer, worker or engine
hit it, the run stops there; what is under a final name is complete (everything is written under a temporary
name and renamed, and a failed scene removes its temporary file), and a rerun skips it.
"""

from __future__ import annotations

import fcntl
import os
import stat
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

from avdata.errors import DiskFullError, InputError, file_kind
from avdata.outputs import is_disk_full, name_full_disk
from avdata.storage import STORE_SCHEMES

LOCK_NAME = ".avdata.lock"
#: The refusal of a URI by a command that writes local folders only.
LOCAL_FOLDERS_ONLY = ("expected a local folder (convert, generate, export, track and study run write to object stores; "
                      "demo and index write local folders only)")
#: The end of every full-disk message of a run (a nested run's message is passed on, not wrapped again).
DISK_FULL_ADVICE = "free space and rerun: what is complete is skipped"


def prepare_folder(root: Path) -> Path:
    """Creates the output folder ``root`` (and its parents); one-line errors when that is impossible."""
    root = Path(root)
    if str(root).startswith(tuple(f"{scheme}:/" for scheme in STORE_SCHEMES)):  # a URI that went through Path()
        raise InputError(f"{str(root).replace(':/', '://', 1)}: {LOCAL_FOLDERS_ONLY}")
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


def complete_scenes(root: Path) -> str:
    """What a dataset folder keeps: its complete scene files (the default ``kept`` of :func:`dataset_lock`)."""
    from avdata.schema.dataset import is_complete_scene

    scenes = Path(root) / "scenes"
    if not scenes.is_dir():
        return f"every file already under its final name in {root}"
    return f"{sum(is_complete_scene(p) for p in scenes.glob('*.mcap'))} complete scene file(s) in {scenes}"


@contextmanager
def dataset_lock(root: str | Path, kept: Callable[[Path], str] = complete_scenes) -> Iterator[Path]:
    """Holds the writer lock of the output folder ``root`` (created if missing) for the ``with`` block.

    Args:
        root: the output folder.
        kept: describes what ``root`` holds complete, for the message of a full disk.

    Raises:
        InputError: ``root`` is a file or cannot be created or written, or another process holds the
            lock (the message names its PID).
        DiskFullError: the disk filled up inside the block (an ``OSError`` ENOSPC or EDQUOT, from any writer):
            one line naming the path, what was kept and what to do.
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
        try:
            try:
                os.ftruncate(fd, 0)
                os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
            except OSError as error:
                raise name_full_disk(error, path) from None
            yield root
        except (OSError, DiskFullError) as error:
            if not is_disk_full(error) or str(error).endswith(DISK_FULL_ADVICE):
                raise
            if not isinstance(error, DiskFullError):
                error = name_full_disk(error, root)
            where = str(error) if isinstance(error, DiskFullError) else f"{error.filename}: cannot write ({error.strerror})"
            raise DiskFullError(f"{where}; the run stopped, keeping {kept(root)} and nothing partial; "
                                f"{DISK_FULL_ADVICE}") from None
    finally:
        os.close(fd)

