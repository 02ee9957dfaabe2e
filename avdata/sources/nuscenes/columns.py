"""Compact containers for the big nuScenes tables: numpy columns sized once, deflated per-scene strings."""

import array
import ctypes
import itertools
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from isal import isal_zlib

from avdata.errors import InputError
from avdata.sources.nuscenes.rowcheck import SCHEMA
from avdata.storage import Location

__all__ = ["ColumnBlocks", "SceneStrings", "grouped", "max_rows", "rank_in_group", "repeated_rows",
           "return_freed_heap", "runs",
           "s_bytes", "take"]


class ColumnBlocks:
    """Accumulates table columns as numpy arrays, a block of records at a time, into arrays sized once.

    The arrays are allocated for ``capacity`` rows, an upper bound on the table's rows (:func:`max_rows`);
    a page of an array becomes memory only when written, so the unused tail costs address space, not
    memory. Filled in place, no column is ever held twice (blocks kept and then concatenated are: at the
    concatenation the peak holds every block beside the columns).

    Args:
        dtypes: column name -> numpy dtype ("S" for byte strings of any width: the array is widened, one
            copy, when a longer value comes), in the order of the tuples given to :meth:`append`.
        capacity: the most rows expected (more are taken, the arrays then doubled).
    """

    BLOCK = 1 << 12

    def __init__(self, dtypes: dict[str, str], capacity: int):
        """An empty accumulator (see the class docstring)."""
        self.dtypes = dtypes
        self.capacity = capacity
        self.n_rows = 0
        self.pending: list[list[Any]] = [[] for _ in dtypes]
        self.pending_rows = 0
        self.arrays: dict[str, np.ndarray] = {}

    def extend(self, columns: Sequence[list[Any]]) -> None:
        """Appends rows given a column at a time: one list per dtype, in the order of ``dtypes``, equally long."""
        for pending, column in zip(self.pending, columns, strict=True):
            pending += column
        self.pending_rows += len(columns[0])
        if self.pending_rows >= self.BLOCK:
            self._flush()

    def _flush(self) -> None:
        if not self.pending_rows:
            return
        end = self.n_rows + self.pending_rows
        if end > self.capacity:  # the file grew after it was sized: doubled, one copy per column
            self.capacity = max(end, 2 * self.capacity)
        for (name, dtype), column in zip(self.dtypes.items(), self.pending, strict=True):
            block = np.asarray(column, dtype=dtype)
            array = self.arrays.get(name)
            if array is None or np.promote_types(array.dtype, block.dtype) != array.dtype or len(array) < self.capacity:
                wider = np.empty((self.capacity, *block.shape[1:]),
                                 dtype=block.dtype if array is None else np.promote_types(array.dtype, block.dtype))
                if array is not None:
                    wider[:self.n_rows] = array[:self.n_rows]
                self.arrays[name] = array = wider
            array[self.n_rows:end] = block
        self.n_rows = end
        self.pending = [[] for _ in self.dtypes]
        self.pending_rows = 0

    def columns(self) -> dict[str, np.ndarray]:
        """The columns so far, in append order (views of the arrays; the accumulator is emptied)."""
        self._flush()
        columns = {name: self.arrays[name][:self.n_rows] if name in self.arrays else np.zeros(0, dtype=dtype)
                   for name, dtype in self.dtypes.items()}
        self.arrays.clear()
        return columns


def max_rows(path: Path | Location, table: str) -> int:
    """An upper bound on the rows of ``table`` at ``path`` that pass :data:`SCHEMA`.

    Each such row's text holds every required key, quoted, with a colon and a value of at least one
    character, and two braces.
    """
    min_chars = 2 + sum(len(field) + 4 for field in SCHEMA[table])
    try:
        size = path.size() if isinstance(path, Location) else path.stat().st_size
    except (OSError, InputError):
        return 1  # a missing file or broken link: the table's reader, run next, names it
    return size // min_chars + 1


class SceneStrings:
    """Byte strings of each scene in append order, compressed a segment at a time.

    The long strings of the big tables (tokens, filenames) are kept here, not as fixed-width columns:
    such a column holds every value at the longest one's width, and grouping it by scene copies it
    (so the peak holds it twice). Here each value goes to its scene's buffer as it is parsed (grouped
    as it comes, in table order within the scene), and each scene's buffer is deflated once it holds
    :attr:`SEGMENT` bytes (ISA-L level 1: the repetitive filenames and hex tokens shrink well, at a
    speed that keeps the compression small beside the parsing).

    Args:
        n_scenes: the number of scenes (values are appended by scene index).
    """

    SEGMENT = 1 << 14

    def __init__(self, n_scenes: int):
        """No values yet, for ``n_scenes`` scenes."""
        self._pending = [bytearray() for _ in range(n_scenes)]
        self._lengths = [array.array("I") for _ in range(n_scenes)]
        self._segments: list[list[bytes]] = [[] for _ in range(n_scenes)]

    def extend(self, scene: int, values: list[bytes]) -> None:
        """Appends ``values`` to scene ``scene``'s, in order."""
        pending = self._pending[scene]
        pending += b"".join(values)
        self._lengths[scene].extend(map(len, values))
        if len(pending) >= self.SEGMENT:
            self._segments[scene].append(isal_zlib.compress(pending, 1))
            self._pending[scene] = bytearray()

    def finish(self) -> None:
        """Deflates what is pending (after the last append)."""
        for scene, pending in enumerate(self._pending):
            if pending:
                self._segments[scene].append(isal_zlib.compress(pending, 1))
                self._pending[scene] = bytearray()

    def values(self, scene: int) -> np.ndarray:
        """(N,) the scene's values in append order as fixed-width bytes (``"S"``, as the other columns)."""
        return np.array(self._list(scene), dtype="S")

    def keep(self, scene: int, mask: np.ndarray) -> None:
        """Keeps only scene ``scene``'s values where ``mask`` (one bool per value, in order) is True."""
        kept = [value for value, keep in zip(self._list(scene), mask.tolist(), strict=True) if keep]
        self.drop(scene)
        self.extend(scene, kept)
        self.finish()

    def _list(self, scene: int) -> list[bytes]:
        data = b"".join([isal_zlib.decompress(segment) for segment in self._segments[scene]]) + self._pending[scene]
        ends = np.cumsum(self._lengths[scene], dtype=np.int64).tolist()
        starts = [0, *ends[:-1]] if ends else []
        return [data[start:end] for start, end in zip(starts, ends, strict=True)]

    def drop(self, scene: int) -> None:
        """Forgets scene ``scene``'s values."""
        self._pending[scene], self._lengths[scene], self._segments[scene] = bytearray(), array.array("I"), []


def s_bytes(value: Any) -> bytes:
    """``value`` as a fixed-width bytes column (``np.asarray(..., dtype="S")``) stores it."""
    return value.encode("ascii") if type(value) is str else np.asarray(value, dtype="S").tobytes()



def take(kept: list[int], *columns: list[Any]) -> tuple[list[Any], ...]:
    """Each list of ``columns`` reduced to the entries at ``kept``."""
    return tuple([column[i] for i in kept] for column in columns)


def runs(values: list[int]) -> Iterator[tuple[int, int, int]]:
    """(value, start, end) of each run of equal consecutive ``values`` (one run per scene in a table's order)."""
    if not values:
        return
    if values[0] == values[-1] and values.count(values[0]) == len(values):
        yield values[0], 0, len(values)
        return
    starts = [0, *(np.flatnonzero(np.diff(values)) + 1).tolist(), len(values)]
    for start, end in itertools.pairwise(starts):
        yield values[start], start, end


def rank_in_group(groups: np.ndarray) -> np.ndarray:
    """(N,) each row's place among the rows of its group, in row order (where a scene's strings hold its value)."""
    order = np.argsort(groups, kind="stable")
    rank = np.empty(len(groups), dtype=np.int64)
    rank[order] = np.arange(len(groups)) - np.searchsorted(groups[order], groups[order])
    return rank


def repeated_rows(token_hashes: np.ndarray, scenes: np.ndarray, strings: SceneStrings) -> list[tuple[int, bytes]]:
    """(row, token) of each row, in table order, whose token an earlier row has.

    Only rows whose hash another row shares are looked up, and they are compared by their tokens, so a hash
    collision drops nothing.

    Args:
        token_hashes: (N,) ``hash`` of each row's token, in table order.
        scenes: (N,) each row's scene; a row's token is its scene's ``strings`` value at its rank among the
            scene's rows.
        strings: each scene's tokens.
    """
    order = np.argsort(token_hashes, kind="stable")
    same = np.flatnonzero(token_hashes[order][1:] == token_hashes[order][:-1])
    if not len(same):
        return []
    candidates = np.unique(np.r_[order[same], order[same + 1]])  # table order: the first of a token is kept
    place = rank_in_group(scenes)[candidates]
    values: dict[int, np.ndarray] = {}
    seen: set[bytes] = set()
    repeated: list[tuple[int, bytes]] = []
    for row, k in zip(candidates.tolist(), place.tolist(), strict=True):
        scene = int(scenes[row])
        if scene not in values:
            values[scene] = strings.values(scene)
        token = bytes(values[scene][k])
        if token in seen:
            repeated.append((row, token))
        seen.add(token)
    return repeated


def grouped(columns: dict[str, np.ndarray], group: str) -> dict[str, np.ndarray]:
    """``columns`` sorted stably by their int column ``group``, in place."""
    if np.all(columns[group][1:] >= columns[group][:-1]):
        return columns  # already grouped (tables written scene by scene): no copy of every column
    order = np.argsort(columns[group], kind="stable")
    for name in columns:
        columns[name] = columns[name][order]  # replaced one at a time: the peak holds one column twice, not all
    return columns

def return_freed_heap() -> None:
    """Hands the C heap's free pages back to the kernel (glibc only; elsewhere nothing).

    The parse's decoded rows and chunks die once they are columns, but glibc keeps their pages for the
    process, and the conversion's own working set would then come on top of them in its peak memory.
    """
    try:
        trim = ctypes.CDLL(None).malloc_trim
    except (OSError, AttributeError):
        return
    trim(0)

