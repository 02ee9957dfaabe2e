"""File I/O of the MCAP layer: the writer's ``writev``, block reservation and page cache; the reader's byte sources.

Writing: which message parts a chunk may keep by reference instead of copying them (:func:`by_reference`),
writing a list of buffers in order (:func:`write_all`), reserving a file's blocks ahead of its writes
(:class:`Reservation`), and dropping written pages from the page cache once a dataset outgrows it
(:class:`WrittenBytes`, :class:`CacheRelease`).

Reading: a scene file is a :class:`ByteSource`, a local file mapped into memory (:class:`MappedFile`) or an
object read by ranged requests through a ``pyarrow.fs`` filesystem (:class:`RangedFile`: S3, GCS), whose
requests :func:`counting_requests` counts.
"""

from __future__ import annotations

import ctypes
import hashlib
import mmap
import os
import secrets
import sys
import threading
from collections import OrderedDict
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final, Protocol

if TYPE_CHECKING:
    import pyarrow.fs

import numpy as np

from avdata.errors import InputError, one_line
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


def immutable(part: Buffer) -> bool:
    """Whether nobody can change ``part``'s bytes (a writer may keep it to write later): bytes, or a view of them."""
    return isinstance(part, bytes) or (isinstance(part, memoryview) and _frozen(part.obj))


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


# --------------------------------------------------------------------------- reading


class ByteSource(Protocol):
    """The bytes of one scene file, by offset: what :class:`~avdata.schema.mcap.reader.McapReader` reads from."""

    #: The file's path or the object's URI, as errors name it.
    name: str
    #: Its size in bytes.
    size: int
    #: True when :meth:`read_into` reads straight from the file (a local file), False when it copies.
    local: bool

    def view(self, offset: int, length: int) -> memoryview:
        """``length`` bytes from ``offset`` (read-only)."""
        ...

    def hold(self, ranges: Sequence[tuple[int, int]], keep: bool = False) -> None:
        """Makes the (offset, length) ranges available to :meth:`view` (fetched now if remote, in parallel).

        ``keep``: ranges read again and again (chunks of small messages: labels, poses, calibrations), held
        apart from those read once (a chunk of one large message), which would otherwise push them out.
        """
        ...

    def read_into(self, offset: int, target: memoryview) -> None:
        """Fills ``target`` with the bytes from ``offset`` on."""
        ...

    def close(self) -> None:
        """Releases what the source holds; it reopens on the next read."""
        ...


class MappedFile:
    """A local file mapped into memory: views are zero-copy and outlive :meth:`close` (released with the last one).

    A copy in another process (pickled, or after ``fork``) maps the file again there.
    """

    local = True

    def __init__(self, path: Path):
        self.path = path
        self.name = str(path)
        self._map: mmap.mmap | None = None
        self._map_pid = 0
        self._fd = -1
        try:
            self.size = path.stat().st_size
        except OSError as error:
            raise InputError(f"{path}: cannot read the scene file ({error.strerror})") from error

    def head(self, length: int) -> bytes:
        """The first ``length`` bytes (or fewer), read without mapping: for files too short to be MCAP."""
        with open(self.path, "rb") as stream:
            return stream.read(length)

    def data(self) -> mmap.mmap:
        """The whole file, mapped (again in a new process)."""
        if self._map is None or self._map_pid != os.getpid():
            try:
                self._fd = os.open(self.path, os.O_RDONLY)
                self._map = mmap.mmap(self._fd, 0, access=mmap.ACCESS_READ)
            except (OSError, ValueError) as error:
                raise InputError(f"{self.path}: cannot map the scene file ({one_line(error)})") from error
            self._map_pid = os.getpid()
        return self._map

    def view(self, offset: int, length: int) -> memoryview:
        """A zero-copy view of the mapping."""
        return memoryview(self.data())[offset : offset + length]

    def hold(self, ranges: Sequence[tuple[int, int]], keep: bool = False) -> None:
        """Nothing to do: every byte is mapped."""

    def read_into(self, offset: int, target: memoryview) -> None:
        """One ``preadv`` into ``target``, no intermediate copy."""
        self.data()
        read = os.preadv(self._fd, [target], offset)
        if read != target.nbytes:
            raise InputError(f"{self.path}: byte {offset}: read {read} of {target.nbytes} bytes: the file is shorter "
                             "than its index says")

    def close(self) -> None:
        """Unmaps the file (once no view is left)."""
        if self._map is not None and self._map_pid == os.getpid():
            try:
                self._map.close()
            except BufferError:
                pass  # views are alive: the mapping is released with the last of them
            os.close(self._fd)
        self._map = None

    def __getstate__(self) -> dict[str, Any]:
        return {**self.__dict__, "_map": None, "_map_pid": 0, "_fd": -1}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)


@dataclass
class Requests:
    """Requests made to object stores while counted (:func:`counting_requests`)."""

    #: Ranged reads (one HTTP GET each).
    gets: int = 0
    #: Bytes those reads returned.
    bytes: int = 0
    #: Object metadata look-ups (one HTTP HEAD each).
    heads: int = 0
    #: Reads served by the local cache folder instead.
    cache_hits: int = 0


_COUNTERS: list[Requests] = []
_COUNTER_LOCK = threading.Lock()


@contextmanager
def counting_requests() -> Iterator[Requests]:
    """Counts the requests every :class:`RangedFile` of this process makes inside the ``with`` block."""
    counter = Requests()
    with _COUNTER_LOCK:
        _COUNTERS.append(counter)
    try:
        yield counter
    finally:
        with _COUNTER_LOCK:
            _COUNTERS.remove(counter)


def _count(gets: int = 0, nbytes: int = 0, heads: int = 0, cache_hits: int = 0) -> None:
    with _COUNTER_LOCK:
        for counter in _COUNTERS:
            counter.gets += gets
            counter.bytes += nbytes
            counter.heads += heads
            counter.cache_hits += cache_hits


#: Environment variable naming the default local cache folder of :class:`RangedFile`.
CACHE_DIR_ENV: Final = "AVDATA_CACHE_DIR"
#: Ranged reads in flight at once when several ranges are fetched together.
_PARALLEL_READS: Final = 8
#: Fetched ranges held in memory by a process, of all its objects: chunks of one large message (read once) and
#: chunks of small messages (read again and again), each kind the most recently used up to this many bytes.
_HELD_ONCE_BYTES: Final = 64 << 20
_HELD_KEPT_BYTES: Final = 256 << 20


class RangedFile:
    """An object in a store (S3, GCS, ...) read by ranged requests through a ``pyarrow.fs`` filesystem.

    Opening makes one metadata request (its size, ETag and modification time). Fetched ranges are held in
    memory (the process's most recent, :data:`_HELD_ONCE_BYTES` and :data:`_HELD_KEPT_BYTES` for all its
    objects) so that the reader's views of them cost nothing more; with
    a cache folder (``cache_dir``, else ``$AVDATA_CACHE_DIR``) every fetched range is also kept on disk under
    a key of the object's URI, size, ETag and modification time, so a changed object is fetched again, never
    served from the cache. A copy in another process opens the object again there, and refuses it if it
    changed since.

    Args:
        filesystem: the store's filesystem.
        path: the object's path in it (``bucket/key``).
        uri: the object's URI, as errors name it.
        cache_dir: the local cache folder, or None for ``$AVDATA_CACHE_DIR`` (unset: no cache).

    Raises:
        InputError: the object does not exist or cannot be opened.
    """

    local = False

    def __init__(self, filesystem: pyarrow.fs.FileSystem, path: str, uri: str, *, cache_dir: str | Path | None = None):
        self.name = uri
        self._filesystem = filesystem
        self._path = path
        self._lock = threading.Lock()
        self._handle: Any = None
        self._handle_pid = 0
        self._version: tuple[int, tuple[tuple[str, bytes], ...]] | None = None
        handle = self._open()
        self.size = int(handle.size())
        folder = cache_dir if cache_dir is not None else os.environ.get(CACHE_DIR_ENV) or None
        self._cache = None if folder is None else Path(folder) / hashlib.sha256(
            repr((uri, self._version)).encode()).hexdigest()[:40]
        self._token = secrets.token_hex(8)  # this object's ranges in the process's held ranges

    def __getstate__(self) -> dict[str, Any]:
        return {**self.__dict__, "_handle": None, "_handle_pid": 0, "_lock": None}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._lock = threading.Lock()

    def close(self) -> None:
        """Forgets the fetched ranges (views handed out keep theirs) and closes the object."""
        with _HELD_LOCK:
            for held in _HELD:
                held.drop(self._token)
        with self._lock:
            if self._handle is not None and self._handle_pid == os.getpid():
                self._handle.close()
            self._handle = None

    def _find(self, offset: int, length: int) -> memoryview | None:
        with _HELD_LOCK:
            for held in _HELD:
                found = held.find(self._token, offset, length)
                if found is not None:
                    return found
        return None

    def view(self, offset: int, length: int) -> memoryview:
        """A view of a held range holding these bytes, else of the range fetched now."""
        found = self._find(offset, length)
        if found is not None:
            return found
        self.hold([(offset, length)])
        found = self._find(offset, length)
        assert found is not None
        return found

    def hold(self, ranges: Sequence[tuple[int, int]], keep: bool = False) -> None:
        """Fetches the ranges not held yet, one request each, in parallel."""
        missing = sorted({(offset, length) for offset, length in ranges if self._find(offset, length) is None})
        if not missing:
            return
        if len(missing) == 1:
            fetched = [self._fetch(*missing[0])]
        else:
            with ThreadPoolExecutor(_PARALLEL_READS) as pool:
                fetched = list(pool.map(lambda r: self._fetch(*r), missing))
        with _HELD_LOCK:
            _HELD[keep].add(self._token, dict(zip((offset for offset, _ in missing), fetched, strict=True)))

    def read_into(self, offset: int, target: memoryview) -> None:
        """Copies the bytes from a held (or fetched) range."""
        target[:] = self.view(offset, target.nbytes)

    def _open(self) -> Any:
        with self._lock:
            if self._handle is None or self._handle_pid != os.getpid():
                try:
                    handle = self._filesystem.open_input_file(self._path)
                    # The store's metadata of the object (S3: ETag, Last-Modified): what a changed object changes.
                    version = (int(handle.size()), tuple(sorted((str(k).lower(), bytes(v))
                                                                for k, v in (handle.metadata() or {}).items())))
                except FileNotFoundError:
                    raise InputError(f"{self.name}: no such object") from None
                except (OSError, ValueError) as error:
                    raise InputError(f"{self.name}: cannot open the object ({_scrubbed(error)})") from None
                finally:
                    _count(heads=1)
                if self._version is not None and version != self._version:
                    raise InputError(f"{self.name}: the object changed while it was being read (its size, ETag or "
                                     "modification time differ from when it was opened); open the dataset again")
                self._version = version
                self._handle, self._handle_pid = handle, os.getpid()
            return self._handle

    def _fetch(self, offset: int, length: int) -> bytes:
        """The range's bytes: from the cache folder, else one ranged read (then cached)."""
        cached = None if self._cache is None else self._cache / f"{offset}-{length}"
        if cached is not None:
            try:
                data = cached.read_bytes()
            except OSError:
                data = None
            if data is not None and len(data) == length:
                _count(cache_hits=1)
                return data
        handle = self._open()
        try:
            data = handle.read_at(length, offset)
        except (OSError, ValueError) as error:
            raise InputError(f"{self.name}: byte {offset}: cannot read {length} bytes ({_scrubbed(error)})") from None
        finally:
            _count(gets=1)
        _count(nbytes=len(data))
        if len(data) != length:
            raise InputError(f"{self.name}: byte {offset}: read {len(data)} of {length} bytes: the object is shorter "
                             "than its index says")
        if cached is not None:
            _store(cached, data)
        return bytes(data)


class _Held:
    """Fetched ranges of a process's objects, the least recently used dropped beyond a budget of bytes."""

    def __init__(self, budget: int) -> None:
        self._budget = budget
        self._by_object: dict[str, dict[int, bytes]] = {}
        self._order: OrderedDict[tuple[str, int], int] = OrderedDict()  # (object, offset) -> size, oldest first
        self._bytes = 0

    def find(self, token: str, offset: int, length: int) -> memoryview | None:
        """A view of a held range of object ``token`` holding these bytes, or None."""
        for start, data in self._by_object.get(token, {}).items():
            if start <= offset and offset + length <= start + len(data):
                self._order.move_to_end((token, start))
                return memoryview(data)[offset - start : offset - start + length]
        return None

    def add(self, token: str, fetched: dict[int, bytes]) -> None:
        """Holds ranges just fetched (never dropped by this call), dropping the oldest beyond the budget."""
        ranges = self._by_object.setdefault(token, {})
        for offset, data in fetched.items():
            self._bytes += len(data) - len(ranges.get(offset, b""))
            ranges[offset] = data
            self._order[(token, offset)] = len(data)
            self._order.move_to_end((token, offset))
        while self._bytes > self._budget and len(self._order) > len(fetched):
            (old_token, old_offset), size = self._order.popitem(last=False)
            self._bytes -= size
            del self._by_object[old_token][old_offset]

    def drop(self, token: str) -> None:
        """Forgets every range of object ``token``."""
        for offset, data in self._by_object.pop(token, {}).items():
            self._bytes -= len(data)
            del self._order[(token, offset)]


#: The process's held ranges: (read once, kept), see :meth:`ByteSource.hold`.
_HELD: Final = (_Held(_HELD_ONCE_BYTES), _Held(_HELD_KEPT_BYTES))
_HELD_LOCK = threading.Lock()


def _scrubbed(error: BaseException) -> str:
    """The error's text on one line, any credential of the environment in it replaced (a store library's text)."""
    from avdata.storage import scrub

    return scrub(one_line(error))


def _store(path: Path, data: bytes) -> None:
    """Writes a cache entry under a temporary name, then renames it (a reader never sees half of one).

    A cache that cannot be written (full disk, no permission) only costs the next read its request.
    """
    temporary = path.with_name(f".{path.name}.{os.getpid()}.{threading.get_ident()}.tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        temporary.write_bytes(data)
        os.replace(temporary, path)
    except OSError:
        temporary.unlink(missing_ok=True)
