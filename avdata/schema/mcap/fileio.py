"""OS-level file I/O of the MCAP writer: ``writev`` without copies, block reservation, and the page cache.

Which message parts a chunk may keep by reference instead of copying them (:func:`by_reference`), writing a
list of buffers in order (:func:`write_all`), reserving a file's blocks ahead of its writes
(:class:`Reservation`), and dropping written pages from the page cache once a dataset outgrows it
(:class:`WrittenBytes`, :class:`CacheRelease`).
"""

from __future__ import annotations

import ctypes
import os
import sys
from collections.abc import Callable
from typing import Final

import numpy as np

from avdata.schema.mcap.records import Buffer

#: A message part at least this large that nobody can change (:func:`_frozen`) joins its chunk by reference.
BY_REFERENCE_BYTES: Final = 16 << 10
#: Buffers per writev call (the kernel's IOV_MAX is 1024).
_IOV_MAX: Final = 1024


def by_reference(part: Buffer) -> bytes | memoryview | None:
    """``part`` as bytes to keep until its chunk is written, if large and :func:`_frozen`; else None (copy it)."""
    if isinstance(part, bytes):
        return part if len(part) >= BY_REFERENCE_BYTES else None
    if not isinstance(part, memoryview) or part.nbytes < BY_REFERENCE_BYTES or not part.c_contiguous:
        return None
    if not _frozen(part.obj):
        return None
    return part if part.format == "B" and part.ndim == 1 else part.cast("B")


def _frozen(owner: object) -> bool:
    """True if nobody can change the bytes ``owner`` exports: a bytes object, or a view (numpy arrays included) of one."""
    while True:
        if isinstance(owner, bytes):
            return True
        if isinstance(owner, memoryview):
            owner = owner.obj
        elif isinstance(owner, np.ndarray) and owner.base is not None:
            owner = owner.base
        else:
            return False


def _libc_fallocate() -> Callable[[int, int, int, int], int] | None:
    """Linux's ``fallocate(2)``, or None elsewhere.

    Not ``os.posix_fallocate``: where a filesystem lacks the call, glibc emulates it by writing
    zeros and growing the file, which would cost more than it saves.
    """
    if not sys.platform.startswith("linux"):
        return None
    try:
        function = ctypes.CDLL(None, use_errno=True).fallocate
    except (OSError, AttributeError):
        return None
    function.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_int64, ctypes.c_int64]
    function.restype = ctypes.c_int
    return function


_FALLOCATE: Final = _libc_fallocate()
_FALLOC_FL_KEEP_SIZE: Final = 1


class Reservation:
    """Reserves a file's blocks ahead of its writes, without changing its size.

    Why: on ext4 (delayed allocation) every write that extends a file reserves its blocks page by
    page; with the extent reserved first, the same ``write`` calls into the page cache are markedly
    faster (docs/decisions.md gives the figures). ``FALLOC_FL_KEEP_SIZE`` leaves
    the size at what was written, so nothing reading the file, or left by a crash, sees the
    reservation; :meth:`release` gives back what was not used. Where the call fails (unsupported,
    no space for the step), reserving stops and writes go on as they would have: a full disk is
    then reported by the write itself.
    """

    #: Reserve at least this much at a time, and at most this much: steps grow with the file.
    _MIN_STEP: Final = 4 << 20
    _MAX_STEP: Final = 64 << 20

    def __init__(self, fd: int):
        self._fd = fd
        self._written = 0
        self._reserved = 0
        self._enabled = _FALLOCATE is not None

    def ahead_of(self, size: int) -> None:
        """Makes sure the next ``size`` bytes written are reserved, then counts them as written."""
        end = self._written + size
        self._written = end
        if end <= self._reserved or not self._enabled:
            return
        step = max(end - self._reserved, min(max(self._reserved, self._MIN_STEP), self._MAX_STEP))
        assert _FALLOCATE is not None
        if _FALLOCATE(self._fd, _FALLOC_FL_KEEP_SIZE, self._reserved, step) != 0:
            self._enabled = False
            return
        self._reserved += step

    def release(self) -> None:
        """Frees the blocks reserved beyond what was written (truncating to the same size does)."""
        if self._reserved > self._written:
            os.ftruncate(self._fd, os.fstat(self._fd).st_size)
        self._reserved = 0


def _physical_memory_bytes() -> int:
    """The machine's memory (0 where the platform does not say)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, ValueError, OSError):
        return 0


class WrittenBytes:
    """Bytes written so far by the writers that share this tally (one dataset's scenes in one process).

    Their files' pages leave the page cache once it passes :data:`DROP_WRITTEN_AFTER_BYTES`
    (see :class:`CacheRelease`).
    """

    def __init__(self) -> None:
        self.total = 0


#: A tenth of the machine's memory: where Linux starts writing dirty pages back by itself
#: (``vm.dirty_background_ratio``'s default); 0 where the platform does not say.
DROP_WRITTEN_AFTER_BYTES = _physical_memory_bytes() // 10


class CacheRelease:
    """Drops a file's pages from the page cache once written back, a step at a time as it grows.

    Only once the writers sharing its :class:`WrittenBytes` (a dataset's scenes) have written a
    tenth of the machine's memory. Why: nothing in avdata reads a file it is writing, and a
    large conversion writes far more than memory holds. Kept, its pages fill the page cache,
    push out what the machine had cached, and every new page must be found somewhere, which
    costs several times the system time of dropping them (docs/decisions.md). Below a tenth of
    memory a dataset's files sit in the page cache unwritten, and dropping them would add their
    write-back to the writes; above it they are being written back anyway. ``POSIX_FADV_DONTNEED``
    starts the write-back of a range's dirty pages
    and drops its clean ones, so each call drops the step whose write-back the previous call
    started, and starts the new step's. Pages still being written back are left to the kernel,
    and so is a file's last step.
    """

    _STEP: Final = 8 << 20

    def __init__(self, fd: int, written: WrittenBytes):
        self._fd = fd
        self._tally = written
        self._written = 0
        self._started = 0  # write-back started up to here (dropped before the previous call's end)
        self._dropped = 0
        self._enabled = hasattr(os, "posix_fadvise")

    def after_write(self, size: int) -> None:
        """Counts ``size`` more bytes written at the end of the file; drops and starts a step when one is full."""
        self._written += size
        self._tally.total += size
        if (self._written - self._started < self._STEP or self._tally.total <= DROP_WRITTEN_AFTER_BYTES
                or not self._enabled):
            return
        try:
            os.posix_fadvise(self._fd, self._dropped, self._written - self._dropped, os.POSIX_FADV_DONTNEED)
        except OSError:  # a file system without it: the kernel keeps the pages, as it would have
            self._enabled = False
            return
        self._dropped, self._started = self._started, self._written


def write_all(fd: int, buffers: list[Buffer], total: int) -> None:
    """Writes ``buffers`` (``total`` bytes) in order with ``os.writev``, continuing after short writes."""
    written = os.writev(fd, buffers[:_IOV_MAX])
    if written == total:
        return
    # More buffers than one call takes, or a short write (signals, > 2 GiB): go on from where it stopped.
    views = [memoryview(b).cast("B") for b in buffers]
    while True:
        done = 0
        while done < len(views) and written >= views[done].nbytes:
            written -= views[done].nbytes
            done += 1
        views = views[done:]
        if not views:
            return
        views[0] = views[0][written:]
        written = os.writev(fd, views[:_IOV_MAX])
